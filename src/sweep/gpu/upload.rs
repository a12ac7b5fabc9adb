//! The frame set's uploads through one staging buffer kept from set to set (issue 35): the
//! caller's images (and a level's plane ranges) are written into its mapped range, copied to
//! their buffers at the start of the set's command buffer, and the buffer is mapped again for
//! writing right after the submission, so that it is mapped once more when the set's one wait
//! ends. `Queue::write_buffer` instead makes a fresh staging buffer per call, whose memory the
//! host faults in anew every set (lavapipe: 1.2 MB of images per set at the paper's size, 6 MB
//! for the 9-camera rig). A staging buffer still being mapped, or one lost to an error, falls
//! back to `write_buffer` for that set.

use std::sync::mpsc;

use rayon::prelude::*;

use super::copies::{HostCopies, PIECE};

/// One write: `data` at `offset` bytes into `target`.
pub(super) struct Part<'a> {
    pub target: &'a wgpu::Buffer,
    pub offset: u64,
    pub data: &'a [u8],
}

enum State {
    /// Mapped for writing: the set's writes so far end at `cursor` bytes.
    Mapped { cursor: u64 },
    /// `map_async` asked for after a submission; the callback's answer comes on the channel.
    Mapping(mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>),
    /// Unmapped for a submission: mapped again right after it.
    Unmapped,
}

/// The staging buffer and what it is doing.
pub(super) struct Uploads {
    staging: Option<(wgpu::Buffer, State)>,
    /// Staging buffers made so far: the engine's own, and one per `write_buffer` fallback.
    made: u64,
}

/// Bytes of `part` in the staging buffer (copies need multiples of 4).
fn padded(part: &Part<'_>) -> u64 {
    (part.data.len() as u64).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT)
}

impl Uploads {
    pub fn new() -> Self {
        Self {
            staging: None,
            made: 0,
        }
    }

    /// Staging buffers made so far (the engine's, and one per write through `write_buffer`).
    pub fn made(&self) -> u64 {
        self.made
    }

    /// Writes `parts` into the staging buffer after the set's earlier writes and records their
    /// copies into `encoder` (or, when it is not mapped yet, writes them with
    /// `Queue::write_buffer`, which lands before the submission's commands).
    pub fn write(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        parts: &[Part<'_>],
        copies: HostCopies,
    ) {
        let bytes: u64 = parts.iter().map(padded).sum();
        if bytes == 0 {
            return;
        }
        let written = match (self.room(device, bytes), &mut self.staging) {
            (Some(at), Some((staging, State::Mapped { cursor }))) => {
                let split = copies.split(bytes as usize);
                write_pieces(staging, at, bytes, parts, split).then(|| {
                    *cursor = at + bytes;
                    (&*staging, at)
                })
            }
            _ => None,
        };
        let Some((staging, at)) = written else {
            // Not mapped (yet): through wgpu's own staging, one buffer per write.
            for part in parts {
                queue.write_buffer(part.target, part.offset, part.data);
                self.made += 1;
            }
            return;
        };
        // One copy per run of parts that follow each other in their target too (a rig's
        // images: one copy for all of them).
        let mut from = at;
        let mut run: Option<(&wgpu::Buffer, u64, u64, u64)> = None;
        for part in parts {
            let len = padded(part);
            run = match run {
                Some((target, src, dst, n))
                    if std::ptr::eq(target, part.target) && dst + n == part.offset =>
                {
                    Some((target, src, dst, n + len))
                }
                _ => {
                    if let Some((target, src, dst, n)) = run {
                        encoder.copy_buffer_to_buffer(staging, src, target, dst, n);
                    }
                    Some((part.target, from, part.offset, len))
                }
            };
            from += len;
        }
        if let Some((target, src, dst, n)) = run {
            encoder.copy_buffer_to_buffer(staging, src, target, dst, n);
        }
    }

    /// Where `bytes` more go in the mapped staging buffer (None: it is not mapped yet), at a
    /// multiple of `wgpu::MAP_ALIGNMENT` (where a mapped range may start). With
    /// nothing of it written in this set, one that is too small, failed to map or is missing
    /// is made anew, mapped.
    fn room(&mut self, device: &wgpu::Device, bytes: u64) -> Option<u64> {
        if let Some((_, state @ State::Mapping(_))) = &mut self.staging {
            let State::Mapping(receiver) = &*state else {
                return None;
            };
            let answer = match receiver.try_recv() {
                Err(mpsc::TryRecvError::Empty) => {
                    // Its submission is done once the set's wait ended; the callback comes
                    // with the next poll.
                    let _ = {
                        let _poll = super::record::device_poll_lock();
                        device.poll(wgpu::PollType::Poll)
                    };
                    receiver.try_recv()
                }
                answer => answer,
            };
            match answer {
                Ok(Ok(())) => *state = State::Mapped { cursor: 0 },
                Err(mpsc::TryRecvError::Empty) => return None,
                Ok(Err(_)) | Err(mpsc::TryRecvError::Disconnected) => self.staging = None,
            }
        }
        match &mut self.staging {
            Some((buffer, State::Mapped { cursor }))
                if cursor.next_multiple_of(wgpu::MAP_ALIGNMENT) + bytes <= buffer.size() =>
            {
                return Some(cursor.next_multiple_of(wgpu::MAP_ALIGNMENT))
            }
            // Copies from it are recorded already: it stays.
            Some((_, State::Mapped { cursor })) if *cursor > 0 => return None,
            Some((_, State::Mapping(_))) => return None,
            Some((buffer, state @ State::Unmapped)) => {
                // Unmapped for a set that was not submitted after all: mapped again for the
                // next one.
                *state = Self::map(buffer);
                return None;
            }
            _ => {}
        }
        self.staging = Some((
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("uploads"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_WRITE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: true,
            }),
            State::Mapped { cursor: 0 },
        ));
        self.made += 1;
        Some(0)
    }

    /// Before a submission (after the set's last write): unmaps the staging buffer if the set
    /// wrote into it.
    pub fn submitting(&mut self) {
        if let Some((buffer, state @ State::Mapped { cursor: 1.. })) = &mut self.staging {
            buffer.unmap();
            *state = State::Unmapped;
        }
    }

    /// After a submission: maps the staging buffer again (for the next set) if it was
    /// unmapped; the mapping completes with the wait for that submission.
    pub fn submitted(&mut self) {
        if let Some((buffer, state @ State::Unmapped)) = &mut self.staging {
            *state = Self::map(buffer);
        }
    }

    /// Asks for `buffer` to be mapped for writing (after the submissions that use it).
    fn map(buffer: &wgpu::Buffer) -> State {
        let (sender, receiver) = mpsc::channel();
        buffer.map_async(wgpu::MapMode::Write, .., move |r| {
            let _ = sender.send(r);
        });
        State::Mapping(receiver)
    }

    /// A frame set's command buffer was dropped unsubmitted: its copies never run, and the
    /// staging buffer, still mapped, is free again.
    pub fn abandoned(&mut self) {
        if let Some((_, State::Mapped { cursor })) = &mut self.staging {
            *cursor = 0;
        }
    }
}

/// Writes `parts` (each at its padded place from `at`, `bytes` in all) into the mapped
/// `staging`: in one mapped range, or (`split`) in `PIECE`s on rayon's threads, each piece
/// mapped on its own. False where a range could not be mapped (nothing recorded: the caller
/// writes the parts another way).
fn write_pieces(
    staging: &wgpu::Buffer,
    at: u64,
    bytes: u64,
    parts: &[Part<'_>],
    split: bool,
) -> bool {
    let starts: Vec<u64> = parts
        .iter()
        .scan(0, |next, part| {
            let start = *next;
            *next += padded(part);
            Some(start)
        })
        .collect();
    // The bytes [from, to) of the parts, into a range mapped from `from`.
    let piece = |(from, to): (u64, u64)| match staging.get_mapped_range_mut(at + from..at + to) {
        Ok(mut view) => {
            for (part, &start) in parts.iter().zip(&starts) {
                let end = start + part.data.len() as u64;
                let (a, b) = (start.max(from), end.min(to));
                if a < b {
                    view.slice((a - from) as usize..(b - from) as usize)
                        .copy_from_slice(&part.data[(a - start) as usize..(b - start) as usize]);
                }
            }
            true
        }
        Err(_) => false,
    };
    if split {
        let pieces: Vec<(u64, u64)> = (0..bytes)
            .step_by(PIECE)
            .map(|from| (from, (from + PIECE as u64).min(bytes)))
            .collect();
        pieces.into_par_iter().all(piece)
    } else {
        piece((0, bytes))
    }
}

//! The frame set's uploads through one staging buffer kept from set to set (issue 35): the
//! caller's images (and a level's plane ranges) are written into its mapped range, copied to
//! their buffers at the start of the set's command buffer, and the buffer is mapped again for
//! writing right after the submission, so that it is mapped once more when the set's one wait
//! ends (sets submitted one after the other without a wait take one each).
//! `Queue::write_buffer` instead makes a fresh staging buffer per call, whose memory the host
//! faults in anew every set (lavapipe: 1.2 MB of images per set at the paper's size, 6 MB for
//! the 9-camera rig). A staging buffer still being mapped, or one lost to an error, falls
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

/// The staging buffers and what each is doing: one, but for the frame sets submitted without
/// a wait between them (the references of a set, `pending.rs`), whose next one writes into
/// another while the last is still in flight.
pub(super) struct Uploads {
    staging: Vec<(wgpu::Buffer, State)>,
    /// The one the current frame set writes into.
    active: Option<usize>,
    /// Staging buffers made so far: the engine's own, and one per `write_buffer` fallback.
    made: u64,
}

/// Staging buffers kept at most (the frame sets in flight at once; more write through
/// `Queue::write_buffer`).
const MAX_STAGING: usize = 4;

/// Bytes of `part` in the staging buffer (copies need multiples of 4).
fn padded(part: &Part<'_>) -> u64 {
    (part.data.len() as u64).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT)
}

impl Uploads {
    pub fn new() -> Self {
        Self {
            staging: Vec::new(),
            active: None,
            made: 0,
        }
    }

    /// Staging buffers made so far (the engine's, and one per write through `write_buffer`).
    pub fn made(&self) -> u64 {
        self.made
    }

    /// Writes `parts` into the staging buffer after the set's earlier writes and records their
    /// copies into `encoder` (or, when none is mapped yet, writes them with
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
        let written = self.room(device, bytes).and_then(|(i, at)| {
            let (staging, state) = &mut self.staging[i];
            let split = copies.split(bytes as usize);
            write_pieces(staging, at, bytes, parts, split).then(|| {
                *state = State::Mapped { cursor: at + bytes };
                (&*staging, at)
            })
        });
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

    /// Which staging buffer takes `bytes` more and where (None: none is mapped), at a multiple
    /// of `wgpu::MAP_ALIGNMENT` (where a mapped range may start): the set's own once it wrote
    /// into one, else the smallest mapped one that holds them; one that is too small, failed
    /// to map or is missing is made anew, mapped.
    fn room(&mut self, device: &wgpu::Device, bytes: u64) -> Option<(usize, u64)> {
        if let Some(i) = self.active {
            return match &self.staging[i] {
                (buffer, State::Mapped { cursor })
                    if cursor.next_multiple_of(wgpu::MAP_ALIGNMENT) + bytes <= buffer.size() =>
                {
                    Some((i, cursor.next_multiple_of(wgpu::MAP_ALIGNMENT)))
                }
                // Copies from it are recorded already: it stays.
                _ => None,
            };
        }
        self.settle_mappings(device);
        let free = |(_, (buffer, state)): &(usize, &(wgpu::Buffer, State))| {
            matches!(state, State::Mapped { cursor: 0 }) && buffer.size() >= bytes
        };
        let fitting = self.staging.iter().enumerate().filter(free);
        if let Some((i, _)) = fitting.min_by_key(|(_, (buffer, _))| buffer.size()) {
            self.active = Some(i);
            return Some((i, 0));
        }
        for (buffer, state) in &mut self.staging {
            if matches!(state, State::Unmapped) {
                // Unmapped for a set that was not submitted after all: mapped again.
                *state = Self::map(buffer);
            }
        }
        // A mapped one too small for this set is replaced; else one more while there is room.
        let slot = match self
            .staging
            .iter()
            .position(|(_, state)| matches!(state, State::Mapped { cursor: 0 }))
        {
            Some(i) => i,
            None if self.staging.len() < MAX_STAGING => self.staging.len(),
            None => return None,
        };
        let made = (
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("uploads"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_WRITE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: true,
            }),
            State::Mapped { cursor: 0 },
        );
        match self.staging.get_mut(slot) {
            Some(old) => *old = made,
            None => self.staging.push(made),
        }
        self.made += 1;
        self.active = Some(slot);
        Some((slot, 0))
    }

    /// The staging buffers mapped again since their submissions ended (one poll, without
    /// waiting), and those whose mapping failed dropped.
    fn settle_mappings(&mut self, device: &wgpu::Device) {
        let mapping = |state: &State| matches!(state, State::Mapping(_));
        if !self.staging.iter().any(|(_, s)| mapping(s)) {
            return;
        }
        // Their submissions are done once the set's wait ended; the callbacks come with a poll.
        let _ = {
            let _poll = super::record::device_poll_lock();
            device.poll(wgpu::PollType::Poll)
        };
        let mut failed = Vec::new();
        for (i, (_, state)) in self.staging.iter_mut().enumerate() {
            let State::Mapping(receiver) = &*state else {
                continue;
            };
            match receiver.try_recv() {
                Ok(Ok(())) => *state = State::Mapped { cursor: 0 },
                Err(mpsc::TryRecvError::Empty) => {}
                Ok(Err(_)) | Err(mpsc::TryRecvError::Disconnected) => failed.push(i),
            }
        }
        // No set writes into one between sets (`active` is None here).
        for i in failed.into_iter().rev() {
            self.staging.remove(i);
        }
    }

    /// Before a submission (after the set's last write): unmaps the set's staging buffer if it
    /// wrote into it.
    pub fn submitting(&mut self) {
        let active = self.active.and_then(|i| self.staging.get_mut(i));
        if let Some((buffer, state @ State::Mapped { cursor: 1.. })) = active {
            buffer.unmap();
            *state = State::Unmapped;
        }
    }

    /// After a submission: maps the set's staging buffer again (for a set after it) if it was
    /// unmapped; the mapping completes once that submission is done.
    pub fn submitted(&mut self) {
        let active = self.active.take().and_then(|i| self.staging.get_mut(i));
        if let Some((buffer, state @ State::Unmapped)) = active {
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

    /// A frame set's command buffer was dropped unsubmitted: its copies never run, and its
    /// staging buffer, still mapped, is free again.
    pub fn abandoned(&mut self) {
        let active = self.active.take().and_then(|i| self.staging.get_mut(i));
        if let Some((_, State::Mapped { cursor })) = active {
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

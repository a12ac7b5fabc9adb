//! The WGSL engine's big host copies on several threads (issue 56, item 3): the caller's images
//! into the mapped staging buffer (`upload.rs`), the maps out of the mapped readback
//! (`SweepPlan::unpack_map_sections`) and into their `32FC1` messages (`out_messages.rs`). At
//! a megapixel these are about 20 MB each way per frame
//! set, most of the host's time, and one thread copies far below what a many-core host's
//! memory moves. Split in `PIECE`s over rayon's threads, each piece of the staging buffer
//! mapped on its own (wgpu's mapped views do not cross threads; disjoint ranges may be mapped
//! at once). The bytes are the same either way; only the time differs.

use rayon::prelude::*;

/// Whether the host copies of a frame set run on several threads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum HostCopies {
    /// Split where the set copies at least `AUTO_BYTES` and rayon has at least `AUTO_THREADS`
    /// threads (a GPU host; a 2-core machine copies on one thread: split, it lost there).
    #[default]
    Auto,
    /// One thread.
    Serial,
    /// Split always (tests; `bench --host-copies` to compare).
    Parallel,
}

/// Bytes per piece of a split copy (a multiple of `wgpu::MAP_ALIGNMENT`).
pub(super) const PIECE: usize = 1 << 20;

/// `HostCopies::Auto` splits copies of at least this many bytes...
const AUTO_BYTES: usize = 4 << 20;
/// ...where rayon has at least this many threads.
const AUTO_THREADS: usize = 8;

impl HostCopies {
    /// Whether a copy of `bytes` is split.
    pub fn split(self, bytes: usize) -> bool {
        match self {
            HostCopies::Serial => false,
            HostCopies::Parallel => true,
            HostCopies::Auto => bytes >= AUTO_BYTES && rayon::current_num_threads() >= AUTO_THREADS,
        }
    }
}

/// `values.to_vec()`, split over rayon's threads with `split` (a piece at a time).
pub fn to_vec<T: Copy + Send + Sync>(values: &[T], split: bool) -> Vec<T> {
    if split {
        let piece = (PIECE / std::mem::size_of::<T>().max(1)).max(1);
        values.par_iter().with_min_len(piece).copied().collect()
    } else {
        values.to_vec()
    }
}

/// One byte per value, `f` mapping a run of values to as many bytes; split
/// over rayon's threads with `split`.
pub fn to_bytes(values: &[f32], split: bool, f: impl Fn(&[f32], &mut [u8]) + Sync) -> Vec<u8> {
    let mut out = vec![0u8; values.len()];
    if split {
        // A piece of the values (4 bytes each) at a time.
        out.par_chunks_mut(PIECE / 4)
            .zip(values.par_chunks(PIECE / 4))
            .for_each(|(o, v)| f(v, o));
    } else {
        f(values, &mut out);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_copies_equal_the_serial_ones() {
        let values: Vec<f32> = (0..(PIECE + 77))
            .map(|i| {
                if i % 97 == 0 {
                    f32::NAN
                } else {
                    i as f32 * 0.37 - 50.0
                }
            })
            .collect();
        let (a, b) = (to_vec(&values, true), to_vec(&values, false));
        assert_eq!(a.len(), values.len());
        assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
        // Bytes (a message's data) likewise.
        let bytes: &[u8] = bytemuck::cast_slice(&values);
        assert_eq!(to_vec(bytes, true), bytes);
        let f = |v: &[f32], o: &mut [u8]| {
            for (o, v) in o.iter_mut().zip(v) {
                *o = *v as u8;
            }
        };
        let (a, b) = (to_bytes(&values, true, f), to_bytes(&values, false, f));
        assert_eq!(a, b);
        assert_eq!(a[3], values[3] as u8);
        assert!(!HostCopies::Serial.split(usize::MAX));
        assert!(HostCopies::Parallel.split(0));
        assert!(!HostCopies::Auto.split(AUTO_BYTES - 1));
    }
}

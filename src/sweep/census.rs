//! The census transform of the camera images (Zabih & Woodfill 1994), made once per frame set
//! on the host for both engines: the CPU engine reads it beside the colours, the WGSL engine
//! finds it in the `images` buffer after the pixels (`Params.census_offset`). Pair costs with
//! `cost = census | ad_census` compare these words (`cpu/census.rs`, `shaders/cost.wgsl`).
//!
//! A texel's word holds one bit per neighbour of its 5 x 5 window (the centre left out, row by
//! row from the top left, the first neighbour in bit 23): set when the neighbour's grey is below
//! the centre's. Grey is the integer luma 77 R + 150 G + 29 B (no rounding, so both engines see
//! the same bits); neighbours past the border repeat the edge texel.

use rayon::prelude::*;

use super::cpu::common::vectorised_fn;

/// Window radius: 5 x 5 texels.
pub const RADIUS: usize = 2;
/// Bits of a census word: the window less its centre.
pub const BITS: u32 = ((2 * RADIUS + 1) * (2 * RADIUS + 1) - 1) as u32;

/// Integer grey of an RGBA8 pixel packed as in the `images` buffer (red in the low byte).
#[inline(always)]
pub fn luma(pixel: u32) -> u32 {
    (pixel & 0xff) * 77 + ((pixel >> 8) & 0xff) * 150 + ((pixel >> 16) & 0xff) * 29
}

/// The census words of one image (`pixels` row-major, `width` x `height`), appended to `out`.
pub fn transform(width: usize, height: usize, pixels: &[u32], out: &mut Vec<u32>) {
    let start = out.len();
    out.resize(start + width * height, 0);
    if width == 0 || height == 0 {
        return;
    }
    // Grey with the edges repeated RADIUS texels outwards, so every window is a plain slice.
    let r = RADIUS;
    let padded_width = width + 2 * r;
    let mut padded = vec![0i32; padded_width * (height + 2 * r)];
    padded
        .par_chunks_mut(padded_width)
        .enumerate()
        .for_each(|(py, line)| {
            let y = py.saturating_sub(r).min(height - 1);
            let src = &pixels[y * width..(y + 1) * width];
            for (d, &p) in line[r..r + width].iter_mut().zip(src) {
                // At most 255 x 256: an i32 compares in one vector instruction.
                *d = luma(p) as i32;
            }
            let (first, last) = (line[r], line[r + width - 1]);
            line[..r].fill(first);
            line[r + width..].fill(last);
        });
    out[start..]
        .par_chunks_mut(width)
        .enumerate()
        .for_each(|(y, words)| census_row(&padded, padded_width, y, words));
}

vectorised_fn! {
/// The words of output row `y` from the padded grey image, in loops that vectorise.
fn census_row(padded: &[i32], padded_width: usize, y: usize, words: &mut [u32]) {
    let width = words.len();
    // CHUNK pixels at a time, their words built in registers over all 24 neighbours (the
    // row's words were loaded and stored once per neighbour); the rest of the row as before.
    let full = width - width % CHUNK;
    for x0 in (0..full).step_by(CHUNK) {
        census_chunk(padded, padded_width, y, x0, &mut words[x0..x0 + CHUNK]);
    }
    census_span(padded, padded_width, y, full, &mut words[full..]);
}
}

/// Pixels per chunk of [`census_chunk`]: its words fill four AVX-512 registers.
const CHUNK: usize = 64;

/// The words of the CHUNK pixels from column `x0` of output row `y`.
#[inline(always)]
fn census_chunk(padded: &[i32], padded_width: usize, y: usize, x0: usize, words: &mut [u32]) {
    let r = RADIUS;
    let at = |dy: usize, dx: usize| {
        let o = (y + dy) * padded_width + dx + x0;
        &padded[o..o + CHUNK]
    };
    let centre = at(r, r);
    let mut acc = [0u32; CHUNK];
    for dy in 0..=2 * r {
        for dx in 0..=2 * r {
            if dy == r && dx == r {
                continue;
            }
            let neighbour = at(dy, dx);
            for i in 0..CHUNK {
                acc[i] = (acc[i] << 1) | u32::from(neighbour[i] < centre[i]);
            }
        }
    }
    words[..CHUNK].copy_from_slice(&acc);
}

/// The words of the pixels from column `x0` of output row `y` (`words.len()` of them): one
/// pass over them per neighbour.
#[inline(always)]
fn census_span(padded: &[i32], padded_width: usize, y: usize, x0: usize, words: &mut [u32]) {
    let r = RADIUS;
    let len = words.len();
    let at = |dy: usize, dx: usize| {
        let o = (y + dy) * padded_width + dx + x0;
        &padded[o..o + len]
    };
    let centre = at(r, r);
    words.fill(0);
    for dy in 0..=2 * r {
        for dx in 0..=2 * r {
            if dy == r && dx == r {
                continue;
            }
            for ((w, &n), &c) in words.iter_mut().zip(at(dy, dx)).zip(centre) {
                *w = (*w << 1) | u32::from(n < c);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grey(v: u8) -> u32 {
        u32::from(v) * 0x0001_0101
    }

    #[test]
    fn a_texel_brighter_than_its_window_sets_every_bit() {
        let (w, h) = (7, 6);
        let mut pixels = vec![grey(10); w * h];
        pixels[3 * w + 3] = grey(200);
        let mut out = Vec::new();
        transform(w, h, &pixels, &mut out);
        assert_eq!(out[3 * w + 3], (1 << BITS) - 1);
        // Its neighbour to the right sees one brighter texel (bit clear everywhere: none below).
        assert_eq!(out[3 * w + 4], 0);
        // A dark texel among bright ones: no neighbour is below it.
        pixels.fill(grey(200));
        pixels[0] = grey(0);
        out.clear();
        transform(w, h, &pixels, &mut out);
        assert_eq!(out[0], 0);
        // The texel right of it: the dark one is its left neighbour, and the edges repeat it
        // (column -1 clamps to 0, rows -2 and -1 to row 0): 2 columns x 3 rows of bits set.
        assert_eq!(out[1].count_ones(), 6);
        // Bit order: the centre row's left neighbour is bit 12 (neighbours 11 of 24 before it).
        assert_ne!(out[1] & (1 << 12), 0);
    }

    /// Rows wider than a chunk (two chunks of 64 and a rest of 22): every word is the
    /// definition's, each neighbour compared one texel at a time with the edges repeated.
    #[test]
    fn chunked_rows_give_every_word_of_the_definition() {
        let (w, h) = (150usize, 7usize);
        let pixels: Vec<u32> = (0..w * h)
            .map(|i| {
                let v = (i as u32).wrapping_mul(2_654_435_761) >> 8;
                v & 0x00ff_ffff
            })
            .collect();
        let mut out = Vec::new();
        transform(w, h, &pixels, &mut out);
        let r = RADIUS as isize;
        let grey_at = |x: isize, y: isize| {
            let (x, y) = (x.clamp(0, w as isize - 1), y.clamp(0, h as isize - 1));
            luma(pixels[y as usize * w + x as usize])
        };
        let mut set_bits = 0;
        for y in 0..h as isize {
            for x in 0..w as isize {
                let centre = grey_at(x, y);
                let mut word = 0u32;
                for dy in -r..=r {
                    for dx in -r..=r {
                        if (dx, dy) != (0, 0) {
                            word = (word << 1) | u32::from(grey_at(x + dx, y + dy) < centre);
                        }
                    }
                }
                assert_eq!(out[y as usize * w + x as usize], word, "x {x}, y {y}");
                set_bits += word.count_ones();
            }
        }
        // Not vacuous: about half the comparisons set their bit.
        assert!(set_bits > (w * h) as u32 * BITS / 4, "{set_bits} bits set");
    }

    #[test]
    fn the_words_are_appended_per_image() {
        let mut out = vec![7u32];
        transform(3, 2, &[grey(1); 6], &mut out);
        assert_eq!(out.len(), 7);
        assert_eq!(out[0], 7);
        assert!(out[1..].iter().all(|&w| w == 0));
    }
}

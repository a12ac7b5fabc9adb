//! The gather loop of `cost::sample_row`: bilinear colours at scattered positions from the
//! interleaved texels (`PlanarImage::texels`) and, from the same loads, the census distances
//! of the samples to the reference's words. A chunk of samples at a time, in three loops: the
//! texel indices and weights (vectorises), the loads of the four 8-byte texels of each sample
//! into arrays on the stack (scalar: the only scattered part), then the colour mixes and the
//! census distances of the whole chunk (vectorise: eight samples at a time, the popcounts of
//! eight XORs per instruction sequence). Same floats as `PlanarImage::sample_with_words`
//! (the tests below compare with it).

use super::common::PlanarImage;

/// Samples per chunk: indices, weights and texels on the stack.
const GATHER_CHUNK: usize = 64;

/// One half of the four texels (00, 10, 01, 11) of a chunk's samples: `half[k][j]` is the
/// colour bytes (or the census word) of texel `k` of sample `j` (`PlanarImage::texels`), in
/// arrays of their own so that the vectorised loops read them with no gaps (a loop reading
/// one lane of pairs ends in a scalar iteration or eight).
type ChunkTexels = [[u32; GATHER_CHUNK]; 4];

/// `v as u32` for a whole number `0 <= v < 2^23` (a seen sample's floor: at most the camera
/// image's last column or row): the integer is the low mantissa bits of `v + 2^23`. Lane
/// operations that vectorise; the saturating `as` casts, which must handle NaN and values out
/// of range, compile into scalar conversions with compares per lane.
#[inline(always)]
fn whole(v: f32) -> u32 {
    const MAGIC: f32 = 8_388_608.0;
    (v + MAGIC).to_bits().wrapping_sub(MAGIC.to_bits())
}

/// The bilinear colours at `xs`, `ys` (NaN in `xs`: not seen; else a position that `inside`
/// accepted) into `out` (NaN where not seen; R alone for a grey image, whose G and B equal
/// it and are not read), and with `census` (the reference row's words,
/// the distances out) the census distances of the samples (not written where not seen).
/// Returns whether it made distances.
#[inline(always)]
pub fn gather_row(
    image: &PlanarImage,
    xs: &[f32],
    ys: &[f32],
    out: [&mut [f32]; 3],
    census: Option<(&[u32], &mut [f32])>,
) -> bool {
    let width = xs.len();
    let ys = &ys[..width];
    let [out_r, out_g, out_b] = out;
    let (out_r, out_g, out_b) = (
        &mut out_r[..width],
        &mut out_g[..width],
        &mut out_b[..width],
    );
    let (iw, ih) = (image.width as u32, image.height as u32);
    let t = image.texels.as_slice();
    let mut census =
        census.map(|(reference, distances)| (&reference[..width], &mut distances[..width]));
    let sampled = census.is_some();
    let mut colours: ChunkTexels = [[0; GATHER_CHUNK]; 4];
    let mut words: ChunkTexels = [[0; GATHER_CHUNK]; 4];
    let mut start = 0;
    while start < width {
        let n = GATHER_CHUNK.min(width - start);
        let (cx, cy) = (&xs[start..start + n], &ys[start..start + n]);
        // Texel 00's index, the offsets to texels 10 and 01 (0 at the image's last column or
        // row, as `Bilinear::at` clamps), the weights; texel 0 for samples not seen (read,
        // never used).
        let mut base = [0u32; GATHER_CHUNK];
        let mut right = [0u32; GATHER_CHUNK];
        let mut down = [0u32; GATHER_CHUNK];
        let mut wx = [0f32; GATHER_CHUNK];
        let mut wy = [0f32; GATHER_CHUNK];
        for j in 0..n {
            let (px, py) = (cx[j], cy[j]);
            let seen = !px.is_nan();
            let (bx, by) = (px.floor(), py.floor());
            let (x0, y0) = if seen { (whole(bx), whole(by)) } else { (0, 0) };
            base[j] = y0.wrapping_mul(iw).wrapping_add(x0);
            right[j] = (x0 + 1).min(iw - 1).wrapping_sub(x0);
            down[j] = (y0 + 1).min(ih - 1).wrapping_sub(y0).wrapping_mul(iw);
            wx[j] = px - bx;
            wy[j] = py - by;
        }
        // The scattered loads, nothing else.
        for j in 0..n {
            let i00 = base[j] as usize;
            let (r, d) = (right[j] as usize, down[j] as usize);
            let texels = [t[i00], t[i00 + r], t[i00 + d], t[i00 + d + r]];
            for k in 0..4 {
                [colours[k][j], words[k][j]] = texels[k];
            }
        }
        let at = start..start + n;
        let (wx, wy) = (&wx[..n], &wy[..n]);
        mix_chunk(&colours, cx, wx, wy, &mut out_r[at.clone()], 0);
        if !image.grey {
            mix_chunk(&colours, cx, wx, wy, &mut out_g[at.clone()], 8);
            mix_chunk(&colours, cx, wx, wy, &mut out_b[at.clone()], 16);
        }
        if let Some((reference, distances)) = census.as_mut() {
            let (reference, distances) = (&reference[at.clone()], &mut distances[at]);
            distance_chunk(&words, reference, cx, wx, wy, distances);
        }
        start += n;
    }
    sampled
}

/// [`gather_row`] for samples that all lie on camera row `y0` (`ys` all `y0`: the fine
/// sweep's hypotheses on a rectified pair, `Mapping::GivenRow`): the same floats, from two
/// texels per sample instead of four (with the vertical weight 0 the bilinear mix of
/// `Bilinear::mix` is its top row's: `top + (bottom - top) 0` is `top`).
#[inline(always)]
pub fn gather_row_along(
    image: &PlanarImage,
    xs: &[f32],
    y0: usize,
    out: [&mut [f32]; 3],
    census: Option<(&[u32], &mut [f32])>,
) -> bool {
    let width = xs.len();
    let [out_r, out_g, out_b] = out;
    let (out_r, out_g, out_b) = (
        &mut out_r[..width],
        &mut out_g[..width],
        &mut out_b[..width],
    );
    let iw = image.width as u32;
    let row = &image.texels[y0 * image.width..(y0 + 1) * image.width];
    let mut census =
        census.map(|(reference, distances)| (&reference[..width], &mut distances[..width]));
    let sampled = census.is_some();
    let mut colours: [[u32; GATHER_CHUNK]; 2] = [[0; GATHER_CHUNK]; 2];
    let mut words: [[u32; GATHER_CHUNK]; 2] = [[0; GATHER_CHUNK]; 2];
    let mut start = 0;
    while start < width {
        let n = GATHER_CHUNK.min(width - start);
        let cx = &xs[start..start + n];
        let mut base = [0u32; GATHER_CHUNK];
        let mut right = [0u32; GATHER_CHUNK];
        let mut wx = [0f32; GATHER_CHUNK];
        for j in 0..n {
            let px = cx[j];
            let bx = px.floor();
            let x0 = if px.is_nan() { 0 } else { whole(bx) };
            base[j] = x0;
            right[j] = (x0 + 1).min(iw - 1);
            wx[j] = px - bx;
        }
        for j in 0..n {
            [colours[0][j], words[0][j]] = row[base[j] as usize];
            [colours[1][j], words[1][j]] = row[right[j] as usize];
        }
        let at = start..start + n;
        let wx = &wx[..n];
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        let channels = if image.grey { 1 } else { 3 };
        for (out, shift) in [
            (&mut out_r[at.clone()], 0),
            (&mut out_g[at.clone()], 8),
            (&mut out_b[at.clone()], 16),
        ]
        .into_iter()
        .take(channels)
        {
            let channel = |colour: u32| ((colour >> shift) & 0xff) as i32 as f32;
            let (t0, t1) = (&colours[0][..n], &colours[1][..n]);
            for j in 0..n {
                let v = lerp(channel(t0[j]), channel(t1[j]), wx[j]);
                out[j] = if cx[j].is_nan() { f32::NAN } else { v };
            }
        }
        if let Some((reference, distances)) = census.as_mut() {
            let (reference, distances) = (&reference[at.clone()], &mut distances[at]);
            let (t0, t1) = (&words[0][..n], &words[1][..n]);
            for j in 0..n {
                let r = reference[j];
                let ones = |word: u32| (word ^ r).count_ones() as f32;
                let d = lerp(ones(t0[j]), ones(t1[j]), wx[j]);
                distances[j] = if cx[j].is_nan() { distances[j] } else { d };
            }
        }
        start += n;
    }
    sampled
}

/// One colour channel of a chunk's samples (the byte at `shift` of the texels' colours, as
/// f32: the channel's value): `Bilinear::mix` of their four texels' values, NaN where the
/// sample is not seen (NaN in `cx`).
#[inline(always)]
fn mix_chunk(
    colours: &ChunkTexels,
    cx: &[f32],
    wx: &[f32],
    wy: &[f32],
    out: &mut [f32],
    shift: u32,
) {
    let n = out.len();
    let (cx, wx, wy) = (&cx[..n], &wx[..n], &wy[..n]);
    let [t00, t10, t01, t11] = colours;
    let (t00, t10, t01, t11) = (&t00[..n], &t10[..n], &t01[..n], &t11[..n]);
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let channel = |colour: u32| ((colour >> shift) & 0xff) as i32 as f32;
    for j in 0..n {
        let top = lerp(channel(t00[j]), channel(t10[j]), wx[j]);
        let bottom = lerp(channel(t01[j]), channel(t11[j]), wx[j]);
        let v = lerp(top, bottom, wy[j]);
        out[j] = if cx[j].is_nan() { f32::NAN } else { v };
    }
}

/// The census distances of a chunk's samples: `Bilinear::mix` of the Hamming distances of
/// their four texels' words to the reference's; samples not seen (NaN in `cx`) keep their
/// value.
#[inline(always)]
fn distance_chunk(
    words: &ChunkTexels,
    reference: &[u32],
    cx: &[f32],
    wx: &[f32],
    wy: &[f32],
    distances: &mut [f32],
) {
    let n = distances.len();
    let (reference, cx, wx, wy) = (&reference[..n], &cx[..n], &wx[..n], &wy[..n]);
    let [t00, t10, t01, t11] = words;
    let (t00, t10, t01, t11) = (&t00[..n], &t10[..n], &t01[..n], &t11[..n]);
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    for j in 0..n {
        let r = reference[j];
        let ones = |word: u32| (word ^ r).count_ones() as f32;
        let top = lerp(ones(t00[j]), ones(t10[j]), wx[j]);
        let bottom = lerp(ones(t01[j]), ones(t11[j]), wx[j]);
        let d = lerp(top, bottom, wy[j]);
        // A select, not a masked store: the loop stays vectorised.
        distances[j] = if cx[j].is_nan() { distances[j] } else { d };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sweep::cpu::common::Bilinear;

    /// A small deterministic generator (xorshift).
    struct Rng(u32);

    impl Rng {
        fn next(&mut self) -> u32 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 17;
            self.0 ^= self.0 << 5;
            self.0
        }

        /// In [0, 1).
        fn unit(&mut self) -> f32 {
            (self.next() >> 8) as f32 / (1 << 24) as f32
        }
    }

    /// The gather along one row is the general gather of samples on that row, bit for bit
    /// (colours and census distances; the last column clamped; samples not seen).
    #[test]
    fn gather_row_along_is_gather_row_on_one_row() {
        let (w, h) = (37, 5);
        let mut rng = Rng(0x1234_5679);
        let pixels: Vec<u32> = (0..w * h).map(|_| rng.next()).collect();
        let words: Vec<u32> = (0..w * h).map(|_| rng.next()).collect();
        let mut image = PlanarImage::default();
        image.fill_from_packed(w, h, &pixels, false, true, Some(&words));
        let last_x = (w - 1) as f32;
        for (y0, width) in [(0, 1), (2, 63), (4, 64), (3, 150)] {
            let xs: Vec<f32> = (0..width)
                .map(|i| match i % 5 {
                    0 => f32::NAN,
                    1 => last_x,
                    2 => (rng.next() % w as u32) as f32,
                    _ => rng.unit() * last_x,
                })
                .collect();
            let ys = vec![y0 as f32; width];
            let reference: Vec<u32> = (0..width).map(|_| rng.next()).collect();
            let run = |along: bool| {
                let mut out = [vec![0.0; width], vec![0.0; width], vec![0.0; width]];
                let mut distances = vec![-7.25f32; width];
                let colours = out.each_mut().map(|c| c.as_mut_slice());
                let census = Some((reference.as_slice(), distances.as_mut_slice()));
                if along {
                    gather_row_along(&image, &xs, y0, colours, census);
                } else {
                    gather_row(&image, &xs, &ys, colours, census);
                }
                let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                (out.map(|c| bits(&c)), bits(&distances))
            };
            assert_eq!(run(true), run(false), "row {y0}, width {width}");
        }
    }

    /// The chunked gather (vectorised mixes and distances) against the scalar sample of each
    /// position (`sample_with_words`, and `Bilinear::mix` of the words' distances as
    /// `census::distance_row`), bit for bit: random positions, whole texels, the last column
    /// and row (clamped neighbours), samples not seen; rows longer than a chunk and not a
    /// multiple of it.
    #[test]
    fn gather_row_is_the_scalar_sample_bit_for_bit() {
        let (w, h) = (37, 23);
        let mut rng = Rng(0x9e37_79b9);
        let pixels: Vec<u32> = (0..w * h).map(|_| rng.next()).collect();
        let words: Vec<u32> = (0..w * h).map(|_| rng.next()).collect();
        let mut image = PlanarImage::default();
        image.fill_from_packed(w, h, &pixels, false, true, Some(&words));
        let (last_x, last_y) = ((w - 1) as f32, (h - 1) as f32);
        for width in [1, 63, 64, 150, 200] {
            let mut xs = Vec::with_capacity(width);
            let mut ys = Vec::with_capacity(width);
            for i in 0..width {
                let (x, y) = match i % 7 {
                    0 => (f32::NAN, rng.unit() * last_y),
                    1 => (last_x, rng.unit() * last_y),
                    2 => (rng.unit() * last_x, last_y),
                    3 => (last_x, last_y),
                    4 => (
                        (rng.next() % w as u32) as f32,
                        (rng.next() % h as u32) as f32,
                    ),
                    _ => (rng.unit() * last_x, rng.unit() * last_y),
                };
                xs.push(x);
                ys.push(y);
            }
            let reference: Vec<u32> = (0..width).map(|_| rng.next()).collect();
            let sentinel = -7.25f32;
            let mut out = [vec![0.0; width], vec![0.0; width], vec![0.0; width]];
            let mut distances = vec![sentinel; width];
            let sampled = gather_row(
                &image,
                &xs,
                &ys,
                out.each_mut().map(|c| c.as_mut_slice()),
                Some((&reference, &mut distances)),
            );
            assert!(sampled);
            let mut colours_only = [vec![0.0; width], vec![0.0; width], vec![0.0; width]];
            let colours = colours_only.each_mut().map(|c| c.as_mut_slice());
            assert!(!gather_row(&image, &xs, &ys, colours, None));
            for x in 0..width {
                let (colour, want_distance) = if xs[x].is_nan() {
                    ([f32::NAN; 3], sentinel)
                } else {
                    let pixel = [xs[x], ys[x]];
                    let (colour, _, _) = image.sample_with_words(pixel);
                    let r = reference[x];
                    let distance =
                        Bilinear::at(w, h, pixel).mix(|i| (words[i] ^ r).count_ones() as f32);
                    (colour, distance)
                };
                for c in 0..3 {
                    assert_eq!(
                        out[c][x].to_bits(),
                        colour[c].to_bits(),
                        "x {x} channel {c}"
                    );
                    assert_eq!(colours_only[c][x].to_bits(), colour[c].to_bits());
                }
                assert_eq!(
                    distances[x].to_bits(),
                    want_distance.to_bits(),
                    "x {x} at ({}, {})",
                    xs[x],
                    ys[x]
                );
            }
        }
    }
}

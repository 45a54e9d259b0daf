//! Pre-packed int8 and int16 weights for the panel kernels, and the reference kernels that
//! define them.
//!
//! A blob stores a layer's weights as `[out][in]` rows: what a matrix-vector kernel wants, and
//! what an MCU runs. A wide SIMD kernel wants something else: `vpdpbusd` multiplies 64 unsigned
//! bytes by 64 signed bytes and sums each group of four into one of 16 i32 lanes. With rows in
//! the lanes, every output needs a horizontal sum at the end. Re-laid out so that the 16 lanes
//! are 16 *outputs*, each lane holding four consecutive inputs of its output, one instruction
//! computes four inputs of 16 outputs for a point whose four input bytes are broadcast, and the
//! sums land in the output's own lane: no horizontal sums, one contiguous store per 16 outputs.
//! This is what oneDNN and onnxruntime do when they "pre-pack" weights at session creation; the
//! host packs once per model load ([`Packed::pack`] into a buffer the caller owns).
//!
//! The i16 first layer (the coded points, five inputs) gets the same layout with two inputs per
//! lane, the pair `vpdpwssd`/`vpmaddwd` sums: [`PackedI16`]. Row-major, its five-input rows cost
//! a matrix-vector kernel a horizontal sum per output, more than the products themselves.
//!
//! # Layout
//!
//! Rows are taken [`GROUP_ROWS`] (64) at a time; the inputs [`Lane::STEP`] at a time (a
//! *step*: four int8 or two int16 inputs, the four bytes of one 32-bit lane). For row group `g`
//! and step `s`, one block of [`BLOCK_BYTES`] (256) bytes holds, at bytes
//! `(o mod 64)·4 + r·size`, the weight of row `o = 64g + (o mod 64)` and input
//! `j = Lane::STEP·s + r`.
//! An int8 weight is stored as the unsigned byte `w + 128` (`w ^ 0x80`), the operand `vpdpbusd`
//! wants unsigned; an int16 weight as itself, little-endian. Blocks are ordered by group, then
//! step: a kernel streams a group's blocks front to back. Rows past the last and inputs past
//! `K` are padding, stored as `w = 0`.
//!
//! With int8 weights offset by 128, a kernel computes `Σ (w + 128)·x = Σ w·x + 128·Σ x` and
//! subtracts `128·Σ x` once per point (shared by every row). Everything is exact modulo 2^32
//! (each group of four products is at most 4 · 255 · 128 < 2^31 in magnitude), the residue the
//! reference's wrapping sums give. An int16 pair sums into i32 exactly except
//! (−32768)·(−32768)·2 = 2^31, which wraps to −2^31: again the residue modulo 2^32.

use core::marker::PhantomData;

/// Rows (outputs) per group: four 16-lane registers.
pub const GROUP_ROWS: usize = 64;

/// Inputs per step of the int8 layout: the four bytes `vpdpbusd` sums into one lane.
pub const STEP: usize = <i8 as Lane>::STEP;

/// Bytes of one lane: one step of one row.
pub const LANE_BYTES: usize = 4;

/// Bytes of one block: one step of one row group.
pub const BLOCK_BYTES: usize = GROUP_ROWS * LANE_BYTES;

/// One block of packed weights.
pub type Block = [u8; BLOCK_BYTES];

/// A weight type the packed layout holds: `i8` (four inputs per lane, stored `w + 128`) or
/// `i16` (two inputs per lane, stored as is). Sealed: the kernels know exactly these two.
pub trait Lane: Copy + Default + Into<i32> + sealed::Sealed {
    /// Inputs per lane (per step).
    const STEP: usize;
    /// Writes `self` as stored in a lane, into `size_of::<Self>()` bytes.
    fn store(self, bytes: &mut [u8]);
    /// Reads a weight back from its stored bytes.
    fn load(bytes: &[u8]) -> Self;
    /// A point's inputs of one step as the 32-bit lane value a kernel broadcasts: the inputs'
    /// little-endian bytes, zero where `inputs` is short (the padding past `K`).
    fn lane_bits(inputs: &[Self]) -> i32;
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for i8 {}
    impl Sealed for i16 {}
}

impl Lane for i8 {
    const STEP: usize = 4;
    #[inline]
    fn store(self, bytes: &mut [u8]) {
        if let Some(b) = bytes.first_mut() {
            *b = self as u8 ^ 0x80;
        }
    }
    #[inline]
    fn load(bytes: &[u8]) -> Self {
        bytes.first().map_or(0, |&b| (b ^ 0x80) as i8)
    }
    #[inline]
    fn lane_bits(inputs: &[Self]) -> i32 {
        let mut b = [0u8; 4];
        for (d, &v) in b.iter_mut().zip(inputs) {
            *d = v as u8;
        }
        i32::from_le_bytes(b)
    }
}

impl Lane for i16 {
    const STEP: usize = 2;
    #[inline]
    fn store(self, bytes: &mut [u8]) {
        for (d, s) in bytes.iter_mut().zip(self.to_le_bytes()) {
            *d = s;
        }
    }
    #[inline]
    fn load(bytes: &[u8]) -> Self {
        match bytes {
            [lo, hi, ..] => i16::from_le_bytes([*lo, *hi]),
            _ => 0,
        }
    }
    #[inline]
    fn lane_bits(inputs: &[Self]) -> i32 {
        let lo = inputs.first().map_or(0, |&v| v as u16 as u32);
        let hi = inputs.get(1).map_or(0, |&v| v as u16 as u32);
        (lo | hi << 16) as i32
    }
}

/// Bytes the packed int8 form of a `rows × k` layer takes (whole blocks; 0 if either is 0), or
/// `None` if that does not fit in a `usize`.
pub const fn packed_len(rows: usize, k: usize) -> Option<usize> {
    packed_len_steps(rows, k, STEP)
}

/// [`packed_len`] for weights of type `T`.
pub const fn packed_len_of<T: Lane>(rows: usize, k: usize) -> Option<usize> {
    packed_len_steps(rows, k, T::STEP)
}

const fn packed_len_steps(rows: usize, k: usize, step: usize) -> Option<usize> {
    match rows.div_ceil(GROUP_ROWS).checked_mul(k.div_ceil(step)) {
        Some(blocks) => blocks.checked_mul(BLOCK_BYTES),
        None => None,
    }
}

/// A layer's weights in the packed layout (see the [module docs](self)), borrowed from a
/// buffer the caller owns. Built by [`Packed::pack`], so its size always matches its shape.
#[derive(Debug)]
pub struct Packed<'a, T> {
    blocks: &'a [Block],
    rows: usize,
    k: usize,
    lane: PhantomData<T>,
}

impl<T> Clone for Packed<'_, T> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<T> Copy for Packed<'_, T> {}

/// A layer's int8 weights, packed.
pub type PackedI8<'a> = Packed<'a, i8>;

/// A layer's int16 weights (the first layer of an int8 model), packed.
pub type PackedI16<'a> = Packed<'a, i16>;

impl<'a, T: Lane> Packed<'a, T> {
    /// Packs the `[rows][k]` weights `w` into the front of `buf`, returning the packed view and
    /// the unused rest of `buf`. `None` if `rows == 0`, `k == 0`, `w.len() != rows · k`, or
    /// `buf` holds fewer than [`packed_len_of`]`::<T>(rows, k)` bytes.
    pub fn pack(w: &[T], rows: usize, k: usize, buf: &'a mut [u8]) -> Option<(Self, &'a mut [u8])> {
        if rows == 0 || k == 0 || rows.checked_mul(k) != Some(w.len()) {
            return None;
        }
        let len = packed_len_of::<T>(rows, k).filter(|&len| len <= buf.len())?;
        let (head, rest) = buf.split_at_mut(len);
        let (blocks, _) = head.as_chunks_mut::<BLOCK_BYTES>();
        let steps = k.div_ceil(T::STEP);
        let size = LANE_BYTES / T::STEP;
        for (b, block) in blocks.iter_mut().enumerate() {
            let (g, s) = (b / steps, b % steps);
            for (i, lane) in block.as_chunks_mut::<LANE_BYTES>().0.iter_mut().enumerate() {
                for (r, bytes) in lane.chunks_exact_mut(size).enumerate() {
                    let (o, j) = (g * GROUP_ROWS + i, s * T::STEP + r);
                    let v = if o < rows && j < k {
                        w[o * k + j]
                    } else {
                        T::default()
                    };
                    v.store(bytes);
                }
            }
        }
        let blocks: &'a [Block] = blocks;
        Some((Self::new(blocks, rows, k), rest))
    }

    const fn new(blocks: &'a [Block], rows: usize, k: usize) -> Self {
        Self {
            blocks,
            rows,
            k,
            lane: PhantomData,
        }
    }

    /// Views bytes already packed by [`Packed::pack`] for a `rows × k` layer (e.g. kept in a
    /// buffer between calls). `None` unless `rows > 0`, `k > 0` and `bytes` is exactly
    /// [`packed_len_of`]`::<T>(rows, k)` long. The bytes are not checked further: any bytes are some
    /// weights.
    pub fn from_packed(bytes: &'a [u8], rows: usize, k: usize) -> Option<Self> {
        if k == 0 || rows == 0 || packed_len_of::<T>(rows, k) != Some(bytes.len()) {
            return None;
        }
        let (blocks, _) = bytes.as_chunks::<BLOCK_BYTES>();
        Some(Self::new(blocks, rows, k))
    }

    /// Bytes of the packed form ([`packed_len_of`] its shape).
    pub const fn byte_len(&self) -> usize {
        self.blocks.len() * BLOCK_BYTES
    }

    /// Output rows.
    pub const fn rows(&self) -> usize {
        self.rows
    }

    /// Inputs per row (`K`).
    pub const fn k(&self) -> usize {
        self.k
    }

    /// Steps of [`Lane::STEP`] inputs per row group (the last one padded when `K` is not a
    /// multiple).
    pub const fn steps(&self) -> usize {
        self.k.div_ceil(T::STEP)
    }

    /// The blocks of row group `g` (`steps()` of them), or an empty slice past the last group.
    pub fn group(&self, g: usize) -> &'a [Block] {
        let steps = self.steps();
        self.blocks.get(g * steps..(g + 1) * steps).unwrap_or(&[])
    }

    /// Row groups.
    pub const fn groups(&self) -> usize {
        self.rows.div_ceil(GROUP_ROWS)
    }

    /// Weight of row `o`, input `j` (`0` outside the matrix), read back from the packed bytes.
    pub fn weight(&self, o: usize, j: usize) -> T {
        if o >= self.rows || j >= self.k {
            return T::default();
        }
        let size = LANE_BYTES / T::STEP;
        let block = &self.group(o / GROUP_ROWS)[j / T::STEP];
        T::load(&block[(o % GROUP_ROWS) * LANE_BYTES + (j % T::STEP) * size..])
    }
}

/// The packed int8 kernel's signature: `(w, x, x_stride, points, bias, out, out_stride)`,
/// computing for `(P, O) =` [`packed_dims`] (and [`MatmatPackedI16`] the same for int16)
///
/// `out[p·out_stride + o] = bias[o] + Σ_{j<K} w[o][j] · x[p·x_stride + j]` for `p < P`, `o < O`,
///
/// exact modulo 2^32, writing nothing else. Point rows may overlap or leave gaps in `x` (the
/// engine passes its activation rows in place, each layer's inputs a slice of a wider row).
pub type MatmatPackedI8 = fn(&PackedI8<'_>, &[i8], usize, usize, &[i32], &mut [i32], usize);

/// [`MatmatPackedI8`] for int16 weights and inputs.
pub type MatmatPackedI16 = fn(&PackedI16<'_>, &[i16], usize, usize, &[i32], &mut [i32], usize);

/// The pooled int8 kernel's signature: `(w, x, x_stride, points, bias, requant, max, sum)`,
/// a [`MatmatPackedI8`] call whose outputs go straight into the engine's pooling instead of
/// to memory: for `(P, O) =` [`pool_dims`] and each `p < P`, `o < O`,
///
/// `v = requantize(bias[o] + Σ_{j<K} w[o][j] · x[p·x_stride + j], requant.scales[o], leaky)`,
/// `max[o] = max(max[o], v)`, `sum[o] += v` (wrapping),
///
/// with [`crate::quant::requantize`]: the engine's last point layer, requantized and pooled
/// while its sums are still in registers. [`matmat_packed_pool_i8`] is its specification.
pub type MatmatPackedPoolI8 = fn(
    &PackedI8<'_>,
    &[i8],
    usize,
    usize,
    &[i32],
    crate::quant::Requant<'_>,
    &mut [i8],
    &mut [i32],
);

/// `(P, O)`, the points and rows a [`MatmatPackedPoolI8`] kernel pools: [`packed_dims`] with
/// `O` also limited by the lengths of `scales`, `max` and `sum`, and no output rows to fit.
pub const fn pool_dims(
    w: &PackedI8<'_>,
    x_len: usize,
    x_stride: usize,
    points: usize,
    bias_len: usize,
    pooled_len: usize,
) -> (usize, usize) {
    let o = min(bias_len, pooled_len);
    // Rows `o` apart in an `out` without end: only `x` limits the points.
    packed_dims(w, x_len, x_stride, points, o, usize::MAX, o)
}

/// `(P, O)`, the points and rows a [`MatmatPackedI8`] kernel computes.
///
/// `O = min(w.rows(), bias_len, out_stride)`. `P` is `points`, limited to the rows whose inputs
/// lie inside `x` (`p·x_stride + K ≤ x_len`) and whose outputs lie inside `out`
/// (`p·out_stride + O ≤ out_len`). `(0, 0)` when either is 0.
pub const fn packed_dims<T>(
    w: &Packed<'_, T>,
    x_len: usize,
    x_stride: usize,
    points: usize,
    bias_len: usize,
    out_len: usize,
    out_stride: usize,
) -> (usize, usize) {
    let o = min(min(w.rows, bias_len), out_stride);
    if o == 0 || x_len < w.k || out_len < o {
        return (0, 0);
    }
    let fit_x = match (x_len - w.k).checked_div(x_stride) {
        Some(n) => n + 1,
        None => points,
    };
    // o ≥ 1 implies out_stride ≥ 1.
    let fit_out = (out_len - o) / out_stride + 1;
    let p = min(points, min(fit_x, fit_out));
    (p, if p == 0 { 0 } else { o })
}

/// [`packed_dims`] of a kernel call's own arguments (the slices' lengths).
#[inline]
pub fn call_dims<T, X>(
    w: &Packed<'_, T>,
    x: &[X],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    out: &[i32],
    out_stride: usize,
) -> (usize, usize) {
    let (x_len, b_len, o_len) = (x.len(), bias.len(), out.len());
    packed_dims(w, x_len, x_stride, points, b_len, o_len, out_stride)
}

const fn min(a: usize, b: usize) -> usize {
    if a < b {
        a
    } else {
        b
    }
}

/// The specification of [`MatmatPackedI8`]: plain scalar loops over the packed bytes.
pub fn matmat_packed_i8(
    w: &PackedI8<'_>,
    x: &[i8],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    matmat_packed(w, x, x_stride, points, bias, out, out_stride)
}

/// The specification of [`MatmatPackedI16`]: plain scalar loops over the packed bytes.
pub fn matmat_packed_i16(
    w: &PackedI16<'_>,
    x: &[i16],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    matmat_packed(w, x, x_stride, points, bias, out, out_stride)
}

/// The specification of [`MatmatPackedPoolI8`]: [`matmat_packed_i8`]'s sums, one at a time,
/// through [`crate::quant::requantize`] into `max` and `sum`.
#[allow(clippy::too_many_arguments)]
pub fn matmat_packed_pool_i8(
    w: &PackedI8<'_>,
    x: &[i8],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    requant: crate::quant::Requant<'_>,
    max: &mut [i8],
    sum: &mut [i32],
) {
    let pooled = min(requant.scales.len(), min(max.len(), sum.len()));
    let (points, rows) = pool_dims(w, x.len(), x_stride, points, bias.len(), pooled);
    for p in 0..points {
        let x = &x[p * x_stride..][..w.k];
        for o in 0..rows {
            let acc = x.iter().enumerate().fold(bias[o], |acc, (j, &x)| {
                acc.wrapping_add(i32::from(w.weight(o, j)).wrapping_mul(i32::from(x)))
            });
            let v = crate::quant::requantize(acc, requant.scales[o], requant.leaky);
            max[o] = max[o].max(v);
            sum[o] = sum[o].wrapping_add(i32::from(v));
        }
    }
}

fn matmat_packed<T: Lane>(
    w: &Packed<'_, T>,
    x: &[T],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    let (points, rows) = call_dims(w, x, x_stride, points, bias, out, out_stride);
    for p in 0..points {
        let x = &x[p * x_stride..][..w.k];
        for (o, (y, &b)) in out[p * out_stride..][..rows]
            .iter_mut()
            .zip(bias)
            .enumerate()
        {
            *y = x.iter().enumerate().fold(b, |acc, (j, &x)| {
                acc.wrapping_add(w.weight(o, j).into().wrapping_mul(x.into()))
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pack_round_trips_every_weight_and_pads_with_zero() {
        for (rows, k) in [(1, 1), (3, 5), (64, 4), (65, 7), (130, 64)] {
            let w: [i8; 130 * 64] = core::array::from_fn(|i| (i as i32 * 37 % 256 - 128) as i8);
            let w = &w[..rows * k];
            let mut buf = [0u8; 3 * 16 * BLOCK_BYTES];
            let (p, rest) = PackedI8::pack(w, rows, k, &mut buf).unwrap();
            assert_eq!(Some(3 * 16 * BLOCK_BYTES - rest.len()), packed_len(rows, k));
            for o in 0..p.groups() * GROUP_ROWS {
                for j in 0..p.steps() * STEP {
                    let want = if o < rows && j < k { w[o * k + j] } else { 0 };
                    assert_eq!(p.weight(o, j), want, "rows {rows} k {k} o {o} j {j}");
                    let block = &p.group(o / GROUP_ROWS)[j / STEP];
                    assert_eq!(block[(o % GROUP_ROWS) * STEP + j % STEP], want as u8 ^ 0x80);
                }
            }
        }
    }

    #[test]
    fn pack_rejects_wrong_shapes_and_short_buffers() {
        let w = [1i8; 12];
        let mut buf = [0u8; BLOCK_BYTES];
        assert!(PackedI8::pack(&w, 3, 4, &mut buf).is_some());
        assert!(PackedI8::pack(&w, 3, 5, &mut buf).is_none());
        assert!(PackedI8::pack(&w, 0, 0, &mut buf).is_none());
        assert!(PackedI8::pack(&w, 3, 4, &mut buf[..BLOCK_BYTES - 1]).is_none());
        assert!(PackedI8::pack(&[1; 13 * 4], 13, 4, &mut [0; BLOCK_BYTES]).is_some());
        assert!(PackedI8::pack(&[1; 65 * 4], 65, 4, &mut [0; BLOCK_BYTES]).is_none());
        assert!(PackedI8::from_packed(&buf, 3, 4).is_some());
        assert!(PackedI8::from_packed(&buf, 3, 5).is_none());
        assert!(PackedI8::from_packed(&buf[1..], 3, 4).is_none());
        assert!(PackedI8::from_packed(&buf, 0, 4).is_none());
        assert!(PackedI8::pack(&[], 0, 4, &mut buf).is_none());
        // Shapes whose size overflows are refused, not wrapped.
        assert_eq!(packed_len(usize::MAX, 4), None);
        assert_eq!(packed_len(usize::MAX / 2, usize::MAX / 2), None);
        assert!(PackedI8::from_packed(&buf, (1 << 62) + 1, 4).is_none());
    }

    #[test]
    fn reference_matches_the_row_major_matvec() {
        let (rows, k) = (70, 9);
        let w: [i8; 70 * 9] = core::array::from_fn(|i| (i as i32 * 91 % 255 - 127) as i8);
        let x: [i8; 3 * 11] = core::array::from_fn(|i| (i as i32 * 53 % 255 - 127) as i8);
        let bias: [i32; 70] = core::array::from_fn(|i| i as i32 * 1000 - 7);
        let mut buf = [0u8; 2 * 3 * BLOCK_BYTES];
        let (p, _) = PackedI8::pack(&w, rows, k, &mut buf).unwrap();
        let mut out = [-1; 3 * 72];
        matmat_packed_i8(&p, &x, 11, 3, &bias, &mut out, 72);
        for pt in 0..3 {
            let mut want = [0; 70];
            super::super::reference::matvec_i8(&w, &x[pt * 11..][..k], &bias, &mut want);
            assert_eq!(out[pt * 72..][..70], want);
            assert_eq!(out[pt * 72 + 70..][..2], [-1, -1]);
        }
    }

    #[test]
    fn i16_pack_round_trips_and_matches_the_row_major_matvec() {
        let (rows, k) = (70, 5);
        let w: [i16; 70 * 5] = core::array::from_fn(|i| (i as i32 * 7919 % 8191 - 4095) as i16);
        let x: [i16; 3 * 8] = core::array::from_fn(|i| (i as i32 * 4099 % 8191 - 4095) as i16);
        let bias: [i32; 70] = core::array::from_fn(|i| i as i32 * 1000 - 7);
        let mut buf = [0u8; 2 * 3 * BLOCK_BYTES];
        assert_eq!(packed_len_of::<i16>(rows, k), Some(buf.len()));
        let (p, _) = PackedI16::pack(&w, rows, k, &mut buf).unwrap();
        for o in 0..128 {
            for j in 0..6 {
                let want = if o < rows && j < k { w[o * k + j] } else { 0 };
                assert_eq!(p.weight(o, j), want, "o {o} j {j}");
            }
        }
        let mut out = [-1; 3 * 72];
        matmat_packed_i16(&p, &x, 8, 3, &bias, &mut out, 72);
        for pt in 0..3 {
            let mut want = [0; 70];
            super::super::reference::matvec_i16(&w, &x[pt * 8..][..k], &bias, &mut want);
            assert_eq!(out[pt * 72..][..70], want);
            assert_eq!(out[pt * 72 + 70..][..2], [-1, -1]);
        }
        assert_eq!(i16::lane_bits(&[-2, 3]), 0x0003_fffe);
        assert_eq!(i16::lane_bits(&[-2]), 0x0000_fffe);
        assert_eq!(i8::lane_bits(&[1, -1, 2]), 0x0002_ff01);
    }

    #[test]
    fn dims_follow_the_buffers() {
        let mut buf = [0u8; BLOCK_BYTES];
        let (p, _) = PackedI8::pack(&[0; 8], 2, 4, &mut buf).unwrap();
        assert_eq!(packed_dims(&p, 12, 4, 9, 2, 6, 2), (3, 2)); // x holds 3 rows
        assert_eq!(packed_dims(&p, 12, 4, 2, 2, 6, 2), (2, 2)); // asked for 2
        assert_eq!(packed_dims(&p, 12, 4, 9, 2, 5, 3), (2, 2)); // out holds 2 rows of 3
        assert_eq!(packed_dims(&p, 12, 4, 9, 1, 6, 2), (3, 1)); // bias has 1 row
        assert_eq!(packed_dims(&p, 4, 0, 5, 2, 10, 2), (5, 2)); // one shared x row
        assert_eq!(packed_dims(&p, 3, 4, 9, 2, 6, 2), (0, 0)); // x shorter than K
        assert_eq!(packed_dims(&p, 12, 4, 9, 2, 6, 0), (0, 0));
    }
}

//! Portable scalar kernels: the definition every optimized kernel is checked against.

/// `out[o] = bias[o] + Σ_k w[o·K + k] · x[k]` in i32, `K = x.len()`, for int8 operands.
/// Exact: |product| ≤ 2^14, so any K below 2^17 cannot overflow.
pub fn matvec_i8(w: &[i8], x: &[i8], bias: &[i32], out: &mut [i32]) {
    let k = x.len();
    for ((o, row), &b) in out.iter_mut().zip(w.chunks_exact(k)).zip(bias) {
        *o = row
            .iter()
            .zip(x)
            .fold(b, |acc, (&w, &x)| acc + i32::from(w) * i32::from(x));
    }
}

/// [`matvec_i8`] for each of several points: the specification of
/// [`super::MatmatI8`]. With `(P, O) =` [`super::matmat_dims`], point `p` (`x[p·K..][..K]`,
/// `K = k`) goes to `out[p·out_stride..][..O]`; `K = 0` gives `bias` (where [`matvec_i8`] would
/// panic). Nothing else in `out` is written.
pub fn matmat_i8(w: &[i8], k: usize, x: &[i8], bias: &[i32], out: &mut [i32], out_stride: usize) {
    let (points, rows) = super::matmat_dims(k, w.len(), x.len(), bias.len(), out.len(), out_stride);
    for p in 0..points {
        let y = &mut out[p * out_stride..][..rows];
        if k == 0 {
            y.copy_from_slice(&bias[..rows]);
        } else {
            matvec_i8(w, &x[p * k..][..k], bias, y);
        }
    }
}

/// The same for the i16 first layer (|w| ≤ 1023, |x| ≤ 2047 keep every sum below 2^24).
pub fn matvec_i16(w: &[i16], x: &[i16], bias: &[i32], out: &mut [i32]) {
    let k = x.len();
    for ((o, row), &b) in out.iter_mut().zip(w.chunks_exact(k)).zip(bias) {
        *o = row
            .iter()
            .zip(x)
            .fold(b, |acc, (&w, &x)| acc + i32::from(w) * i32::from(x));
    }
}

/// f32 version: the dot product summed in index order, then the bias added.
pub fn matvec_f32(w: &[f32], x: &[f32], bias: &[f32], out: &mut [f32]) {
    let k = x.len();
    for ((o, row), &b) in out.iter_mut().zip(w.chunks_exact(k)).zip(bias) {
        *o = row.iter().zip(x).fold(0.0, |acc, (&w, &x)| acc + w * x) + b;
    }
}

//! The int8 kernel over packed weights on Intel AMX (`tdpbsud`, tile registers), and what it
//! takes to be allowed to run it.
//!
//! An AMX tile is up to 16 rows of 64 bytes; `tdpbsud C, A, B` adds to each i32 of the
//! 16 × 16 tile `C` the dot products of a row of `A` (16 × 64 signed bytes: 16 points, 64
//! inputs) with a column of `B` (16 × 64 unsigned bytes: 16 steps of four inputs for each of 16
//! outputs), 16,384 multiply-accumulates in one instruction. `B`'s layout, four consecutive
//! inputs of one output per 32-bit column, is the [packed](crate::kernels::packed) layout's:
//! step `s` of a row group is one 256-byte block (64 outputs × 4 bytes), so 16 outputs of 16
//! consecutive steps are a tile of rows 256 bytes apart in the packed buffer, loaded as they
//! lie. The weights are stored as `w + 128`, the unsigned operand, and the `128·Σx` this adds
//! is subtracted once per point, as in the VNNI kernels. Each tile's four products are summed
//! into i32 exactly (4 · 128 · 255 < 2^31), and the sums wrap: the reference's residue modulo
//! 2^32.
//!
//! The `asm!` blocks declare the tiles they write (`tmm` clobbers); the tiles hold their values
//! from one block to the next because nothing between them calls out or touches tiles (no
//! function call in the chunk loop: the pooled epilogue that runs there is inlined and fills
//! its vectors without `memcpy`; the disassembly shows no `call` between the blocks). Rust's
//! inline-assembly rules do not promise registers an `asm!` block does not name, so this rests
//! on the compiler never touching tile registers itself, which it cannot: it has no tile types.
//!
//! Registers, per block of up to 32 points:
//!
//! | tile | holds |
//! |---|---|
//! | `tmm0`, `tmm1` | sums of points 0–15 for outputs 0–15, 16–31 of a 32-output slice |
//! | `tmm2`, `tmm3` | the same for points 16–31 |
//! | `tmm4`, `tmm5` | 64 inputs of points 0–15 and 16–31 (rows of `x`, read in place) |
//! | `tmm6`, `tmm7` | 16 steps of outputs 0–15 and 16–31 of the slice (packed weights, in place) |
//!
//! so every weight tile serves 32 points and every input tile 32 outputs: four `tdpbsud` per
//! four tile loads. The sums go through two 4 KiB buffers on the stack, where the bias and the
//! correction are added on the way to `out`: a slice's sums wait in one while the next slice's
//! products run, and that epilogue is spread over the next slice's chunks, a few points per
//! chunk, so that the vector units do it while the tile unit multiplies.
//!
//! The engine's last point layer (the paper model's conv5) does not go to memory at all:
//! [`matmat_packed_pool_i8_amx`]'s epilogue requantizes the sums and reduces them into the
//! running max and sum in registers, where the other tables write int32 rows, requantize them
//! to int8 rows and pool those (measured on the paper model, 2,048 points, one thread on a
//! Xeon with AMX-INT8: 2.54–2.93 ms before, 2.17–2.20 ms with this epilogue, fastest runs).
//!
//! The kernel takes layers whose `K` is a multiple of 64 (a tile's row) and at least
//! [`MIN_K`] (128): the others (most of the small MCU model's, the paper model's conv2 and
//! conv3) run the AVX-512 VNNI kernel, as does the int16 first layer (AMX has no int16
//! product). In the paper model the tiles run conv4 (128 inputs, 256 outputs) and conv5 (512
//! inputs, 1,024 outputs), 98 % of its MACs.
//!
//! # Permission
//!
//! AMX's tile data is 8 KiB of register state, which Linux (5.16 and later) saves only for a
//! process that asked for it: until then the first tile instruction raises `SIGILL`.
//! [`request_tile_data`] asks (`arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`, a
//! system call made directly, as the core has no `std`); [`super::Features::detect`] offers AMX
//! only where the CPU has it, the OS enabled it in `XCR0` and the request succeeded (Linux
//! refuses it, for one, where a thread's alternate signal stack is too small for the larger
//! signal frame; the table is then AVX-512 VNNI's). On other systems the core does not offer
//! AMX.

use core::arch::asm;
use core::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};

use core::ops::Range;

use super::vnni_corrections;
use super::{matmat_packed_i8_avx512vnni, matmat_packed_pool_i8_avx512vnni};
use crate::kernels::packed::{call_dims, pool_dims, PackedI8, GROUP_ROWS};
use crate::quant::{requantize_wide, Requant};

/// Inputs per tile row: 64 bytes.
pub const TILE_K: usize = 64;

/// The smallest `K` the tiles take. With the engine's activation rows on cache lines
/// (`infer::ALIGN_WORDS`), the paper model ran about 3 % faster with its 128-input conv4 on
/// tiles (1.97–2.21 against 2.03–2.19 ms in eight alternating rounds on an Emerald Rapids VM;
/// 64 gave the same as 128), and the bundled pipeline (the MCU model, whose 128-input layer
/// then runs on tiles) no slower (21–30 against 20–23 M events/s in five rounds). Before the
/// rows were aligned, 256: `K` = 64 ran at 91–181 GMAC/s on tiles against 141 on AVX-512 VNNI.
pub const MIN_K: usize = 128;

/// Points (tile rows) per tile.
const TILE_ROWS: usize = 16;

/// Points per block: two tiles of rows.
const BLOCK_POINTS: usize = 2 * TILE_ROWS;

/// Outputs per slice: two tiles of 16 columns.
const SLICE: usize = 32;

/// Steps (four inputs) per tile: the rows of a weight tile.
const TILE_STEPS: usize = TILE_K / 4;

/// Bytes between a weight tile's rows: one packed block.
const B_STRIDE: usize = crate::kernels::packed::BLOCK_BYTES;

/// The 64-byte operand of `ldtilecfg` (palette 1).
#[repr(C, align(64))]
struct TileConfig([u8; 64]);

impl TileConfig {
    /// Tiles for a block of `r0` (1..=16) and `r1` (0..=16) points: see the module docs. A tile
    /// of 0 rows stays unconfigured (and unused).
    fn new(r0: usize, r1: usize) -> Self {
        let mut c = [0u8; 64];
        c[0] = 1; // palette 1
        let rows = [r0, r0, r1, r1, r0, r1, TILE_STEPS, TILE_STEPS];
        for (t, &r) in rows.iter().enumerate() {
            if r > 0 {
                // Bytes per row (u16, little-endian) at 16 + 2t, rows at 48 + t.
                c[16 + 2 * t] = 64;
                c[48 + t] = r as u8;
            }
        }
        Self(c)
    }

    /// `ldtilecfg`: configures the tiles (and zeroes them all).
    ///
    /// # Safety
    /// AMX-TILE and the tile-data permission.
    #[inline(always)]
    unsafe fn load(&self) {
        // SAFETY: the caller guarantees AMX; `new` made a valid palette-1 configuration (rows
        // ≤ 16, 64 bytes per row, unused tiles and reserved bytes 0), 64 bytes read from `self`.
        unsafe {
            asm!(
                "ldtilecfg [{}]",
                in(reg) self.0.as_ptr(),
                out("tmm0") _, out("tmm1") _, out("tmm2") _, out("tmm3") _,
                out("tmm4") _, out("tmm5") _, out("tmm6") _, out("tmm7") _,
                options(nostack, readonly, preserves_flags),
            )
        };
    }
}

/// `XFEATURE_XTILEDATA`: the tile data's bit in `XCR0`.
const XTILEDATA: u64 = 18;

/// Asks Linux for permission to use the AMX tile data in this process (every thread, now and
/// later); `true` if granted (or already granted). Idempotent; one system call.
#[cfg(target_os = "linux")]
pub fn request_tile_data() -> bool {
    const SYS_ARCH_PRCTL: i64 = 158;
    const ARCH_REQ_XCOMP_PERM: i64 = 0x1023;
    let ret: i64;
    // SAFETY: `arch_prctl(ARCH_REQ_XCOMP_PERM, 18)` reads and writes no memory of ours; it
    // only changes which register state the kernel saves for this process. The `syscall`
    // instruction clobbers `rcx` and `r11`, declared here; the stack is not touched.
    unsafe {
        asm!(
            "syscall",
            inlateout("rax") SYS_ARCH_PRCTL => ret,
            in("rdi") ARCH_REQ_XCOMP_PERM,
            in("rsi") XTILEDATA as i64,
            lateout("rcx") _,
            lateout("r11") _,
            options(nostack, preserves_flags),
        );
    }
    ret == 0
}

/// On systems other than Linux the core does not ask, and does not offer AMX.
#[cfg(not(target_os = "linux"))]
pub fn request_tile_data() -> bool {
    false
}

/// Whether `cpuid`'s leaf 7 (`edx`) and `XCR0` say the CPU has AMX-TILE and AMX-INT8 and the OS
/// enabled the tile state (both `XCR0` bits, 17 and 18).
pub(super) fn cpu_has_amx(leaf7_edx: u32, xcr0: u64) -> bool {
    let tile = leaf7_edx & (1 << 24) != 0;
    let int8 = leaf7_edx & (1 << 25) != 0;
    tile && int8 && xcr0 & (0b11 << 17) == 0b11 << 17
}

/// [`crate::kernels::packed::matmat_packed_i8`], bit-exact, on AMX tiles where `K` is a
/// multiple of 64 and at least [`AMX_MIN_K`](super::AMX_MIN_K) (and with
/// [`matmat_packed_i8_avx512vnni`] otherwise).
///
/// # Safety
/// The CPU must support AVX-512 (F, BW, VL, VNNI) and AMX-INT8, and this process must hold
/// the tile-data permission: what [`super::Features::detect`]'s `amx` says.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
pub unsafe fn matmat_packed_i8_amx(
    w: &PackedI8<'_>,
    x: &[i8],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    out: &mut [i32],
    out_stride: usize,
) {
    if !takes(w) {
        // SAFETY: the caller guarantees AVX-512 VNNI.
        return unsafe {
            matmat_packed_i8_avx512vnni(w, x, x_stride, points, bias, out, out_stride)
        };
    }
    let (n, o) = call_dims(w, x, x_stride, points, bias, out, out_stride);
    let mut store = Store {
        bias,
        out,
        stride: out_stride,
    };
    // SAFETY: AMX per the caller; `call_dims` checked that `n` points of `x` and `o` outputs
    // of `bias` and of `n` rows of `out` are there.
    unsafe { tiles(w, x, x_stride, n, o, &mut store) }
}

/// [`crate::kernels::packed::matmat_packed_pool_i8`], bit-exact, on AMX tiles: the last point
/// layer's sums requantized and pooled from the tile stores' buffer, never written to memory
/// as int32 rows, nor as int8 ones. Where the tiles do not take `w` (`takes`: `K` a multiple of
/// 64 from [`MIN_K`]) it runs [`matmat_packed_pool_i8_avx512vnni`].
///
/// # Safety
/// As [`matmat_packed_i8_amx`].
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
#[allow(clippy::too_many_arguments)]
pub unsafe fn matmat_packed_pool_i8_amx(
    w: &PackedI8<'_>,
    x: &[i8],
    x_stride: usize,
    points: usize,
    bias: &[i32],
    requant: Requant<'_>,
    max: &mut [i8],
    sum: &mut [i32],
) {
    if !takes(w) {
        // SAFETY: the caller guarantees AVX-512 VNNI.
        return unsafe {
            matmat_packed_pool_i8_avx512vnni(w, x, x_stride, points, bias, requant, max, sum)
        };
    }
    let pooled = requant.scales.len().min(max.len()).min(sum.len());
    let (n, o) = pool_dims(w, x.len(), x_stride, points, bias.len(), pooled);
    let mut pool = Pool {
        bias,
        requant,
        max,
        sum,
    };
    // SAFETY: AMX per the caller; `pool_dims` checked that `n` points of `x` and `o` outputs of
    // `bias`, `scales`, `max` and `sum` are there.
    unsafe { tiles(w, x, x_stride, n, o, &mut pool) }
}

/// Whether the tiles take `w`: `K` a multiple of 64 and at least [`MIN_K`].
pub fn takes(w: &PackedI8<'_>) -> bool {
    w.k() >= MIN_K && w.k().is_multiple_of(TILE_K)
}

/// Where a slice's sums go once the tiles are stored.
trait Epilogue {
    /// For the points `rows` of the block that starts at point `p0`, and the `cols` outputs of
    /// the slice from `c0`: the sums `sums[i][..cols]` plus the bias, minus the point's
    /// correction `corr[i]` (wrapping), are that point's outputs.
    fn finish(
        &mut self,
        sums: &Sums,
        rows: Range<usize>,
        corr: &[i32; BLOCK_POINTS],
        p0: usize,
        c0: usize,
        cols: usize,
    );
}

/// [`matmat_packed_i8_amx`]'s epilogue: the outputs to `out`, rows `stride` apart.
struct Store<'a> {
    bias: &'a [i32],
    out: &'a mut [i32],
    stride: usize,
}

impl Epilogue for Store<'_> {
    #[inline(always)]
    fn finish(
        &mut self,
        sums: &Sums,
        rows: Range<usize>,
        corr: &[i32; BLOCK_POINTS],
        p0: usize,
        c0: usize,
        cols: usize,
    ) {
        let bias = &self.bias[c0..][..cols];
        for i in rows {
            let (row, c) = (&sums.0[i], corr[i]);
            let y = &mut self.out[(p0 + i) * self.stride + c0..][..cols];
            for ((y, &s), &b) in y.iter_mut().zip(row).zip(bias) {
                *y = s.wrapping_add(b).wrapping_sub(c);
            }
        }
    }
}

/// [`matmat_packed_pool_i8_amx`]'s epilogue: the outputs requantized to int32 values in
/// `-128..=127` ([`requantize_wide`]) and reduced over the points in registers (a max and a
/// sum per output, all 32 outputs of the slice in four vectors), then merged into the running
/// max and sum. Max and sum of the wide values are those of the int8 values.
struct Pool<'a> {
    bias: &'a [i32],
    requant: Requant<'a>,
    max: &'a mut [i8],
    sum: &'a mut [i32],
}

impl Epilogue for Pool<'_> {
    #[inline(always)]
    fn finish(
        &mut self,
        sums: &Sums,
        rows: Range<usize>,
        corr: &[i32; BLOCK_POINTS],
        _p0: usize,
        c0: usize,
        cols: usize,
    ) {
        // The slice's bias and scales as whole vectors (columns past `cols`: 0, and ignored).
        // A fixed-trip loop of selects, not `copy_from_slice`: that became two `memcpy`
        // calls, and this runs between tile instructions while tiles hold live sums (which a
        // call may clobber under the x86-64 psABI; see the module docs).
        let (mut bias, mut scales) = ([0i32; SLICE], [0f32; SLICE]);
        let (b, s) = (
            self.bias.get(c0..).unwrap_or_default(),
            self.requant.scales.get(c0..).unwrap_or_default(),
        );
        for j in 0..SLICE {
            if j < cols {
                bias[j] = b.get(j).copied().unwrap_or(0);
                scales[j] = s.get(j).copied().unwrap_or(0.0);
            }
        }
        let alpha = self.requant.leaky.unwrap_or(1.0);
        let (mut mx, mut sm) = ([-128i32; SLICE], [0i32; SLICE]);
        for i in rows {
            let (row, c) = (&sums.0[i], corr[i]);
            for j in 0..SLICE {
                let a = row[j].wrapping_add(bias[j]).wrapping_sub(c);
                let v = requantize_wide(a, scales[j], alpha);
                mx[j] = mx[j].max(v);
                sm[j] = sm[j].wrapping_add(v);
            }
        }
        let (max, sum) = (&mut self.max[c0..][..cols], &mut self.sum[c0..][..cols]);
        for (((m, s), &v), &t) in max.iter_mut().zip(sum).zip(&mx).zip(&sm) {
            // `v` is in -128..=127: the cast is exact.
            *m = (*m).max(v as i8);
            *s = s.wrapping_add(t);
        }
    }
}

/// The tile loop shared by both kernels: the first `n` points of `x` (rows `x_stride` apart)
/// through the first `o` outputs of `w`, each slice's sums handed to `epilogue`.
///
/// # Safety
/// As [`matmat_packed_i8_amx`], and [`takes`]`(w)`; `x` holds `n` rows of `w.k()` bytes
/// `x_stride` apart, `o ≤ w.rows()`, and `epilogue` accepts every point below `n` and output
/// below `o`.
#[inline(always)]
unsafe fn tiles<E: Epilogue>(
    w: &PackedI8<'_>,
    x: &[i8],
    x_stride: usize,
    n: usize,
    o: usize,
    epilogue: &mut E,
) {
    if n == 0 || o == 0 {
        return;
    }
    let k = w.k();
    let chunks = k / TILE_K;
    // Two stores' buffers: a slice's sums wait in one while the next slice's products run,
    // and their epilogue is spread over that slice's chunks, where it runs beside the tile
    // instructions instead of after them.
    let mut sums = [
        Sums([[0; SLICE]; BLOCK_POINTS]),
        Sums([[0; SLICE]; BLOCK_POINTS]),
    ];
    let mut p0 = 0;
    while p0 < n {
        let m = (n - p0).min(BLOCK_POINTS);
        let (r0, r1) = (m.min(TILE_ROWS), m.saturating_sub(TILE_ROWS));
        // Before the tiles are configured, per block: the tile state does not survive calls
        // (the x86-64 psABI), and this loop may call out.
        let mut corr = [0i32; BLOCK_POINTS];
        // SAFETY: AMX's CPUs have AVX2 ([`matmat_packed_i8_amx`]'s features).
        unsafe { vnni_corrections(x, x_stride, p0, k, &mut corr[..m]) };
        // The slice whose sums wait in `sums[pending.0]`: its first output and width.
        let mut pending: Option<(usize, usize, usize)> = None;
        // Points of the pending epilogue per chunk: all of them over the chunk loop.
        let rows_per_chunk = m.div_ceil(chunks);
        // SAFETY: AMX permission per the caller.
        unsafe { TileConfig::new(r0, r1).load() };
        // The block's input rows: points p0.. of `x`.
        let a0 = &x[p0 * x_stride..][..(r0 - 1) * x_stride + k];
        let a1 = (r1 > 0).then(|| &x[(p0 + TILE_ROWS) * x_stride..][..(r1 - 1) * x_stride + k]);
        let mut slot = 0;
        for g in 0..w.groups() {
            let blocks = w.group(g);
            for half in 0..GROUP_ROWS / SLICE {
                let c0 = g * GROUP_ROWS + half * SLICE;
                if c0 >= o {
                    break;
                }
                // SAFETY: tiles configured above for this block (r1 = 0: tiles 2, 3 and 5 are
                // not configured and not used).
                unsafe {
                    asm!(
                        "tilezero tmm0",
                        "tilezero tmm1",
                        out("tmm0") _, out("tmm1") _, options(nostack, nomem, preserves_flags)
                    );
                    if r1 > 0 {
                        asm!(
                            "tilezero tmm2",
                            "tilezero tmm3",
                            out("tmm2") _, out("tmm3") _, options(nostack, nomem, preserves_flags)
                        );
                    }
                }
                for c in 0..chunks {
                    let b = &blocks[c * TILE_STEPS..][..TILE_STEPS];
                    // SAFETY: tiles configured above for this block. Every load reads inside
                    // a slice: `a0`/`a1` hold r rows of `k` ≥ 64(c + 1) bytes `x_stride`
                    // apart, and `b` the 16 blocks (256 bytes each) of steps 16c..16c + 16 <
                    // steps, of which each tile row reads 64 bytes at offset 128·half or
                    // 128·half + 64 (< 256).
                    unsafe {
                        let b0 = b.as_ptr().cast::<u8>().add(half * 2 * 64);
                        let a = a0.as_ptr().add(c * TILE_K);
                        // The next chunk's weight rows, on their way from L2 while these
                        // multiply (measured: 6–12 % faster on conv5's shape).
                        if let Some(next) = blocks.get((c + 1) * TILE_STEPS..(c + 2) * TILE_STEPS) {
                            for blk in next {
                                let p = blk.as_ptr().add(half * 2 * 64);
                                _mm_prefetch::<_MM_HINT_T0>(p.cast());
                                _mm_prefetch::<_MM_HINT_T0>(p.add(64).cast());
                            }
                        }
                        match a1 {
                            Some(a1) => asm!(
                                "tileloadd tmm4, [{a} + {s}*1]",
                                "tileloadd tmm6, [{b} + {bs}*1]",
                                "tdpbsud tmm0, tmm4, tmm6",
                                "tileloadd tmm7, [{b} + {bs}*1 + 64]",
                                "tdpbsud tmm1, tmm4, tmm7",
                                "tileloadd tmm5, [{a1} + {s}*1]",
                                "tdpbsud tmm2, tmm5, tmm6",
                                "tdpbsud tmm3, tmm5, tmm7",
                                a = in(reg) a,
                                a1 = in(reg) a1.as_ptr().add(c * TILE_K),
                                s = in(reg) x_stride,
                                b = in(reg) b0,
                                bs = in(reg) B_STRIDE,
                                out("tmm0") _, out("tmm1") _, out("tmm2") _, out("tmm3") _,
                                out("tmm4") _, out("tmm5") _, out("tmm6") _, out("tmm7") _,
                                options(nostack, readonly, preserves_flags),
                            ),
                            None => asm!(
                                "tileloadd tmm4, [{a} + {s}*1]",
                                "tileloadd tmm6, [{b} + {bs}*1]",
                                "tdpbsud tmm0, tmm4, tmm6",
                                "tileloadd tmm7, [{b} + {bs}*1 + 64]",
                                "tdpbsud tmm1, tmm4, tmm7",
                                a = in(reg) a,
                                s = in(reg) x_stride,
                                b = in(reg) b0,
                                bs = in(reg) B_STRIDE,
                                out("tmm0") _, out("tmm1") _, out("tmm4") _, out("tmm6") _,
                                out("tmm7") _,
                                options(nostack, readonly, preserves_flags),
                            ),
                        }
                    }
                    // The previous slice's epilogue, a few points per chunk.
                    if let Some((prev, pc0, cols)) = pending {
                        let rows = (c * rows_per_chunk).min(m)..((c + 1) * rows_per_chunk).min(m);
                        epilogue.finish(&sums[prev], rows, &corr, p0, pc0, cols);
                    }
                }
                // SAFETY: tiles configured above for this block. The stores write the 32 rows
                // of 32 i32 (128 bytes apart) of `sums[slot]`, which no pending epilogue
                // reads (that one, in the other slot, is done): the tiles of points 0–15 at
                // rows 0–15 (columns 0–15 and 16–31), points 16–31 at rows 16–31.
                unsafe {
                    let s = sums[slot].0.as_mut_ptr().cast::<i32>();
                    asm!(
                        "tilestored [{p} + {s}*1], tmm0",
                        "tilestored [{p} + {s}*1 + 64], tmm1",
                        p = in(reg) s,
                        s = in(reg) SLICE * 4,
                        options(nostack, preserves_flags),
                    );
                    if r1 > 0 {
                        asm!(
                            "tilestored [{p} + {s}*1], tmm2",
                            "tilestored [{p} + {s}*1 + 64], tmm3",
                            p = in(reg) s.add(TILE_ROWS * SLICE),
                            s = in(reg) SLICE * 4,
                            options(nostack, preserves_flags),
                        );
                    }
                }
                pending = Some((slot, c0, (o - c0).min(SLICE)));
                slot ^= 1;
            }
        }
        // The block's last slice.
        if let Some((prev, pc0, cols)) = pending {
            epilogue.finish(&sums[prev], 0..m, &corr, p0, pc0, cols);
        }
        p0 += m;
    }
    // SAFETY: AMX permission per the caller.
    unsafe { release_tiles() };
}

/// The tile stores' buffer: 32 points × 32 outputs, rows 128 bytes apart.
#[repr(C, align(64))]
struct Sums([[i32; SLICE]; BLOCK_POINTS]);

/// Runs `iters` rounds of six independent `tdpbssd` ([`TILE_MACS`] each) on zeroed tiles, for
/// [`super::peak_loop`].
///
/// # Safety
/// As [`matmat_packed_i8_amx`]: AMX-INT8 and the tile-data permission.
pub(super) unsafe fn peak(iters: u64) {
    let mut out = [[0i32; 16]; 16];
    // SAFETY: the caller guarantees AMX; tiles 0–7 are configured with 16 rows of 64 bytes; the
    // one store writes `out`'s 16 rows of 64 bytes.
    unsafe {
        TileConfig::new(TILE_ROWS, TILE_ROWS).load();
        asm!(
            "tilezero tmm0",
            "tilezero tmm1",
            "tilezero tmm2",
            "tilezero tmm3",
            "tilezero tmm4",
            "tilezero tmm5",
            "tilezero tmm6",
            "tilezero tmm7",
            out("tmm0") _, out("tmm1") _, out("tmm2") _, out("tmm3") _,
            out("tmm4") _, out("tmm5") _, out("tmm6") _, out("tmm7") _,
            options(nostack, nomem, preserves_flags),
        );
        for _ in 0..iters {
            asm!(
                "tdpbssd tmm0, tmm6, tmm7",
                "tdpbssd tmm1, tmm6, tmm7",
                "tdpbssd tmm2, tmm6, tmm7",
                "tdpbssd tmm3, tmm6, tmm7",
                "tdpbssd tmm4, tmm6, tmm7",
                "tdpbssd tmm5, tmm6, tmm7",
                out("tmm0") _, out("tmm1") _, out("tmm2") _, out("tmm3") _,
                out("tmm4") _, out("tmm5") _,
                options(nostack, nomem, preserves_flags),
            );
        }
        asm!(
            "tilestored [{}+{}*1], tmm0",
            in(reg) out.as_mut_ptr(),
            in(reg) 64usize,
            options(nostack, preserves_flags),
        );
        release_tiles();
    }
    core::hint::black_box(out);
}

/// MACs of one `tdpbssd`/`tdpbsud` on full tiles: 16 × 16 × 64.
pub(super) const TILE_MACS: u64 = (TILE_ROWS * TILE_ROWS * TILE_K) as u64;

/// `tilerelease`: every tile back to its initial state, the configuration cleared.
///
/// # Safety
/// AMX-TILE and the tile-data permission.
#[inline(always)]
unsafe fn release_tiles() {
    // SAFETY: the caller guarantees AMX; the instruction touches no memory.
    unsafe {
        asm!(
            "tilerelease",
            out("tmm0") _, out("tmm1") _, out("tmm2") _, out("tmm3") _,
            out("tmm4") _, out("tmm5") _, out("tmm6") _, out("tmm7") _,
            options(nostack, nomem, preserves_flags),
        )
    };
}

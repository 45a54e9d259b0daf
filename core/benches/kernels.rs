//! Matrix-vector and matrix-matrix kernels, reference against every kernel this CPU runs.
//!
//! Throughput is in MACs (criterion's "elements"): `K × out` per call (`× P` points for
//! matmat).
//! `cargo bench -p evpose-core --bench kernels`; add `-- --quick` for a short run.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use evpose_core::kernels::{packed, Isa, Kernels, PackedI8};

/// Deterministic pseudo-random values (xorshift).
fn values<T>(n: usize, seed: u64, f: impl Fn(u64) -> T) -> Vec<T> {
    let mut s = seed | 1;
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            f(s)
        })
        .collect()
}

fn kernels_here() -> Vec<Kernels> {
    Isa::ALL.iter().filter_map(|isa| isa.kernels()).collect()
}

fn matvec_i8(c: &mut Criterion) {
    // conv5 (per point) and fc1 (once per window) of the paper's PointNet; conv2 and the heads.
    for (name, k, n) in [
        ("conv5", 512, 1024),
        ("fc1", 2048, 1024),
        ("conv2", 64, 64),
        ("head_x", 128, 346),
    ] {
        let w = values(k * n, 1, |v| v as i8);
        let x = values(k, 2, |v| v as i8);
        let bias = values(n, 3, |v| (v as i32) >> 8);
        let mut out = vec![0; n];
        let mut g = c.benchmark_group(format!("matvec_i8/{name} K={k} out={n}"));
        g.throughput(Throughput::Elements((k * n) as u64));
        for kern in kernels_here() {
            g.bench_function(kern.name(), |b| {
                b.iter(|| kern.matvec_i8(black_box(&w), black_box(&x), &bias, &mut out))
            });
        }
        g.finish();
    }
}

fn matvec_i16(c: &mut Criterion) {
    // conv1 (K = 5, the engines' only i16 layer), and a wide shape for peak throughput.
    for (name, k, n) in [("conv1", 5, 64), ("wide", 512, 1024)] {
        let w = values(k * n, 4, |v| (v % 2047) as i16 - 1023);
        let x = values(k, 5, |v| (v % 4095) as i16 - 2047);
        let bias = values(n, 6, |v| (v as i32) >> 8);
        let mut out = vec![0; n];
        let mut g = c.benchmark_group(format!("matvec_i16/{name} K={k} out={n}"));
        g.throughput(Throughput::Elements((k * n) as u64));
        for kern in kernels_here() {
            g.bench_function(kern.name(), |b| {
                b.iter(|| kern.matvec_i16(black_box(&w), black_box(&x), &bias, &mut out))
            });
        }
        g.finish();
    }
}

fn matmat_i8(c: &mut Criterion) {
    // conv5 (K = 512 → 1024, 512 KiB of weights) for blocks of P points, against the best
    // matvec called once per point (`matvec×P/<isa>`: the weights read P times), and the best
    // kernel over pre-packed weights (`packed/<isa>`, where the CPU has one).
    let (k, n) = (512, 1024);
    let w = values(k * n, 7, |v| v as i8);
    let bias = values(n, 9, |v| (v as i32) >> 8);
    for p in [1, 4, 8, 16] {
        let x = values(p * k, 8, |v| v as i8);
        let mut out = vec![0; p * n];
        let mut g = c.benchmark_group(format!("matmat_i8/conv5 K={k} out={n} P={p}"));
        g.throughput(Throughput::Elements((k * n * p) as u64));
        for kern in kernels_here() {
            g.bench_function(kern.name(), |b| {
                b.iter(|| kern.matmat_i8(black_box(&w), k, black_box(&x), &bias, &mut out, n))
            });
        }
        let best = Kernels::detect();
        if best.has_packed() {
            let mut buf = vec![0u8; packed::packed_len(n, k).expect("fits")];
            let (pw, _) = PackedI8::pack(&w, n, k, &mut buf).expect("pack");
            g.bench_function(format!("packed/{}", best.name()), |b| {
                b.iter(|| best.matmat_packed_i8(&pw, black_box(&x), k, p, &bias, &mut out, n))
            });
        }
        g.bench_function(format!("matvec×P/{}", best.name()), |b| {
            b.iter(|| {
                for (xp, y) in black_box(&x).chunks_exact(k).zip(out.chunks_exact_mut(n)) {
                    best.matvec_i8(black_box(&w), xp, &bias, y);
                }
            })
        });
        g.finish();
    }
}

fn packed_layers(c: &mut Criterion) {
    // The paper model's int8 point layers as the engine runs them on a CPU with native packed
    // kernels, in 24-point calls (one pass of the VNNI kernels' four register tiles; the
    // engine's blocks, `Plan::block`, hold up to four), every packed kernel family this CPU has.
    let p = 24;
    for (k, n) in [(64, 64), (64, 128), (128, 256), (512, 1024)] {
        let w = values(k * n, 7, |v| v as i8);
        let bias = values(n, 9, |v| (v as i32) >> 8);
        let x = values(p * k, 8, |v| v as i8);
        let mut out = vec![0; p * n];
        let mut buf = vec![0u8; packed::packed_len(n, k).expect("fits")];
        let (pw, _) = PackedI8::pack(&w, n, k, &mut buf).expect("pack");
        let mut g = c.benchmark_group(format!("packed_i8/K={k} out={n} P={p}"));
        g.throughput(Throughput::Elements((k * n * p) as u64));
        for kern in kernels_here().into_iter().filter(Kernels::has_packed) {
            g.bench_function(kern.name(), |b| {
                b.iter(|| kern.matmat_packed_i8(&pw, black_box(&x), k, p, &bias, &mut out, n))
            });
        }
        g.finish();
    }
}

fn pooled_conv5(c: &mut Criterion) {
    // The paper model's last point layer (conv5) as the engine runs it, in a 24-point call (a
    // quarter of the largest `Plan::block`): the packed kernel's int32 rows requantized and
    // pooled in two more passes, against the table's pooled kernel
    // (`Kernels::packed_pool_i8`), where it has one.
    use evpose_core::quant::Requant;
    let (k, n, p) = (512, 1024, 24);
    let w = values(k * n, 7, |v| v as i8);
    let bias = values(n, 9, |v| (v as i32) >> 12);
    let x = values(p * k, 8, |v| (v as i8) / 2);
    let scales = values(n, 3, |v| 1e-4 + (v % 100) as f32 * 1e-6);
    let requant = Requant {
        scales: &scales,
        leaky: Some(0.1),
    };
    let mut buf = vec![0u8; packed::packed_len(n, k).expect("fits")];
    let (pw, _) = PackedI8::pack(&w, n, k, &mut buf).expect("pack");
    let (mut acc, mut y) = (vec![0; p * n], vec![0i8; p * n]);
    let (mut max, mut sum) = (vec![i8::MIN; n], vec![0i32; n]);
    let mut g = c.benchmark_group(format!("pooled_i8/conv5 K={k} out={n} P={p}"));
    g.throughput(Throughput::Elements((k * n * p) as u64));
    for kern in kernels_here().into_iter().filter(Kernels::has_packed) {
        g.bench_function(format!("store+requant+pool/{}", kern.name()), |b| {
            b.iter(|| {
                kern.matmat_packed_i8(&pw, black_box(&x), k, p, &bias, &mut acc, n);
                for (a, y) in acc.chunks_exact(n).zip(y.chunks_exact_mut(n)) {
                    kern.requantize(a, requant, y);
                    kern.pool_i8(&mut max, &mut sum, y);
                }
            })
        });
        if let Some(pooled) = kern.packed_pool_i8(&pw) {
            g.bench_function(format!("pooled/{}", kern.name()), |b| {
                b.iter(|| pooled(&pw, black_box(&x), k, p, &bias, requant, &mut max, &mut sum))
            });
        }
    }
    g.finish();
}

fn matmat_f32(c: &mut Criterion) {
    // The f32 engine's point layers that read earlier layers, as it runs them: a block of 24
    // points (each point's activations in one row) through a tile of rows (`F32_TILE_WEIGHTS`,
    // 4,096 weights), by `matvec_f32` point by point and by each table's `matmat_f32`.
    use evpose_core::kernels::PointRows;
    let p = 24;
    for (k, n) in [(64, 64), (128, 32), (512, 8)] {
        let w = values(k * n, 7, |v| (v % 2001) as f32 / 1000.0 - 1.0);
        let bias = values(n, 9, |v| (v % 201) as f32 / 100.0 - 1.0);
        let stride = k + n;
        let mut rows = values(p * stride, 8, |v| (v % 401) as f32 / 200.0 - 1.0);
        let at = PointRows {
            stride,
            points: p,
            x: 0..k,
            out: k,
        };
        let mut g = c.benchmark_group(format!("matmat_f32/K={k} out={n} P={p}"));
        g.throughput(Throughput::Elements((k * n * p) as u64));
        for kern in kernels_here() {
            g.bench_function(format!("matvec×P/{}", kern.name()), |b| {
                b.iter(|| {
                    for row in rows.chunks_mut(stride) {
                        let (x, y) = row.split_at_mut(k);
                        kern.matvec_f32(&w, black_box(x), &bias, y);
                    }
                })
            });
            g.bench_function(kern.name(), |b| {
                b.iter(|| kern.matmat_f32(&w, &bias, black_box(&mut rows), &at))
            });
        }
        g.finish();
    }
}

criterion_group!(
    benches,
    matvec_i8,
    matvec_i16,
    matmat_i8,
    packed_layers,
    pooled_conv5,
    matmat_f32
);
criterion_main!(benches);

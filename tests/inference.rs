//! Inference against independent engines.
//!
//! - f32: the core's f32 engine and tract against onnxruntime's outputs (shared reference
//!   files): max |Δ| ≤ 1e-4 · max|logit| per output and identical argmax for every joint and
//!   axis. The tolerance covers f32 summation order (onnxruntime blocks its GEMMs; the core
//!   sums each dot product in 16 partial sums, in a fixed order); the observed difference is
//!   below 1e-5.
//! - int8: the core's int8 engine against tract running the quantized ONNX graph: identical
//!   int32 accumulators, compared with `==`.
//!
//! The small model and its references are bundled; the 18 MB paper model is read from
//! `../shared/reference` when present (CI has it) and its tests say so and return otherwise.

use std::path::{Path, PathBuf};

use evpose_host::array;
use evpose_host::model::{self, quantize, AlignedBlob, Logits, TractModel};
use evpose_host::parity::argmax_agreement;
use evpose_tests::{assert_close, assert_int8_core_equals_tract, fixtures, shared, street_windows};

struct Case {
    model: PathBuf,
    /// Input point clouds, one per window.
    inputs: Vec<Vec<[f32; 5]>>,
    /// onnxruntime's outputs per window.
    reference: Vec<Logits<f32>>,
}

fn load_case(dir: &Path, model: &str, input: &str, key: &str) -> Case {
    let mut inputs = Vec::new();
    let mut reference = Vec::new();
    for w in street_windows() {
        inputs.push(model::read_points(&dir.join(format!("{w}.{input}.npy"))).unwrap());
        let (sx, x) =
            array::read_exact::<f32>(&dir.join(format!("{w}.{key}.simdr_x.npy"))).unwrap();
        let (_, y) = array::read_exact::<f32>(&dir.join(format!("{w}.{key}.simdr_y.npy"))).unwrap();
        reference.push(Logits {
            joints: sx[0] as usize,
            x,
            y,
        });
    }
    Case {
        model: dir.join(model),
        inputs,
        reference,
    }
}

/// `net` quantized with the ranges of `calibration`, as an int8 blob.
fn int8_blob(net: &model::FloatNet, calibration: &[Vec<[f32; 5]>]) -> AlignedBlob {
    let ranges = quantize::calibrate(net, calibration).unwrap();
    AlignedBlob::new(&quantize::quantize(net, &ranges).unwrap().blob().unwrap())
}

fn small() -> Case {
    load_case(&fixtures(), "pointnet-small.onnx", "points", "small")
}

fn paper() -> Option<Case> {
    let dir = shared()?.join("reference");
    if !dir.join("pointnet-paper.onnx").exists() {
        return None;
    }
    Some(load_case(&dir, "pointnet-paper.onnx", "input2048", "paper"))
}

fn check_float(case: &Case) {
    let blob = model::load_blob(&case.model).unwrap();
    let mut tract = TractModel::load(&case.model).unwrap();
    let (mut core_worst, mut tract_worst) = (0f32, 0f32);
    for (i, (input, want)) in case.inputs.iter().zip(&case.reference).enumerate() {
        let core = model::run_core_f32(&blob, input).unwrap();
        core_worst = core_worst.max(assert_close(&core, want, &format!("core f32, window {i}")));
        let t = tract.run(input).unwrap();
        tract_worst = tract_worst.max(assert_close(&t, want, &format!("tract, window {i}")));
    }
    eprintln!(
        "{}: max|Δ|/max|logit| vs onnxruntime: core f32 {core_worst:.2e}, tract {tract_worst:.2e}",
        case.model.display()
    );
}

fn check_int8(case: &Case, tag: &str) {
    let net = model::import_onnx(&case.model).unwrap();
    let (close, total) = assert_int8_core_equals_tract(&net, &case.inputs[..3], &case.inputs, tag);
    eprintln!("{tag}: int8 argmax within 1 px of float on {close}/{total} joint axes");
}

#[test]
fn small_model_float_engines_match_onnxruntime() {
    check_float(&small());
}

#[test]
fn small_model_int8_core_equals_tract_exactly() {
    check_int8(&small(), "small");
}

#[test]
fn paper_model_float_engines_match_onnxruntime() {
    let Some(case) = paper() else {
        eprintln!(
            "NOTE: ../shared/reference/pointnet-paper.onnx not present; paper-model check not run"
        );
        return;
    };
    check_float(&case);
}

#[test]
fn paper_model_int8_core_equals_tract_exactly() {
    let Some(case) = paper() else {
        eprintln!(
            "NOTE: ../shared/reference/pointnet-paper.onnx not present; paper-model check not run"
        );
        return;
    };
    check_int8(&case, "paper");
}

#[test]
fn importer_reads_the_family_shape() {
    let net = model::import_onnx(&fixtures().join("pointnet-small.onnx")).unwrap();
    let widths: Vec<_> = net
        .point
        .iter()
        .map(|l| (l.in_dim, l.out_dim, l.sources))
        .collect();
    assert_eq!(
        widths,
        [
            (5, 32, 1),
            (32, 32, 2),
            (32, 64, 4),
            (64, 128, 8),
            (256, 256, 0b11110)
        ]
    );
    assert_eq!(
        net.fc
            .iter()
            .map(|l| (l.in_dim, l.out_dim))
            .collect::<Vec<_>>(),
        [(512, 256), (256, 832)]
    );
    assert_eq!(
        (
            net.joints,
            net.head_dim(),
            net.head_x.out_dim,
            net.head_y.out_dim
        ),
        (13, 64, 346, 260)
    );
    assert_eq!(net.points, None, "dynamic point count");
    assert!(net
        .point
        .iter()
        .chain(&net.fc)
        .all(|l| l.leaky == Some(0.01)));
}

#[test]
fn quantized_argmax_tracks_float_reasonably() {
    // Not a quality gate (the weights are random): a sanity floor that catches broken scales.
    let case = small();
    let net = model::import_onnx(&case.model).unwrap();
    let blob = int8_blob(&net, &case.inputs[..3]);
    let float = AlignedBlob::new(&model::f32_blob(&net).unwrap());
    let (mut close, mut total) = (0, 0);
    for input in &case.inputs {
        let (c, t) = argmax_agreement(
            &model::run_core_i8(&blob, input).unwrap(),
            &model::run_core_f32(&float, input).unwrap(),
        );
        close += c;
        total += t;
    }
    assert!(
        close * 10 >= total * 8,
        "only {close}/{total} joint axes within 1 px"
    );
}

/// The kernel sets this CPU runs, saying which it skips.
fn supported_kernel_sets(
) -> impl Iterator<Item = (evpose_core::kernels::Isa, evpose_core::kernels::Kernels)> {
    evpose_core::kernels::Isa::ALL
        .into_iter()
        .filter_map(|isa| {
            let k = isa.kernels();
            if k.is_none() {
                eprintln!(
                    "kernel set {} not supported on this CPU; not tested",
                    isa.name()
                );
            }
            Some((isa, k?))
        })
}

#[test]
fn int8_engine_gives_identical_integers_with_every_kernel_set() {
    use evpose_core::kernels::Kernels;
    let case = small();
    let net = model::import_onnx(&case.model).unwrap();
    let blob = int8_blob(&net, &case.inputs[..1]);
    let reference: Vec<_> = case.inputs[..3]
        .iter()
        .map(|i| model::run_core_i8_with(&Kernels::reference(), &blob, i).unwrap())
        .collect();
    for (isa, k) in supported_kernel_sets() {
        for (input, want) in case.inputs[..3].iter().zip(&reference) {
            assert_eq!(
                &model::run_core_i8_with(&k, &blob, input).unwrap(),
                want,
                "{}",
                isa.name()
            );
        }
    }
}

#[test]
fn packed_int8_engine_gives_identical_integers_with_every_kernel_set_and_block() {
    // The packed path with every table: native packed kernels where the CPU has them, the
    // packed reference elsewhere (so this runs on any CI machine), against the row-major
    // engine with the reference kernels. Three kinds of heads, which run packed too: the small
    // model's 15-bit heads (D = 128), the bundled MCU model's (D = 32) and a version 1 blob's
    // int8 heads.
    use evpose_core::kernels::Kernels;
    use evpose_core::{pack_layers, packed_bytes, scratch_words_for_block, Model, Plan};
    let case = small();
    let net = model::import_onnx(&case.model).unwrap();
    let small_blob = int8_blob(&net, &case.inputs[..1]);
    let mcu_blob = AlignedBlob::new(evpose_host::assets::DEFAULT_MODEL);
    let v1_blob =
        AlignedBlob::new(&std::fs::read(fixtures().join("pointnet-small-v1.evq")).unwrap());
    let input = &case.inputs[4][..1000];
    let mut tested = Vec::new();
    for (name, blob) in [("small", &small_blob), ("mcu", &mcu_blob), ("v1", &v1_blob)] {
        let m = Model::parse(blob.bytes()).unwrap();
        let mut buf = vec![0u8; packed_bytes(&m)];
        let layout = pack_layers(&m, &mut buf).unwrap();
        let packed = layout.weights(&m, &buf).unwrap();
        let words = scratch_words_for_block(&m, 1);
        let reference = Plan::new(&m, Kernels::reference(), words).unwrap();
        let outputs = || {
            (
                vec![0; reference.out_x_len()],
                vec![0; reference.out_y_len()],
            )
        };
        let (mut wx, mut wy) = outputs();
        reference
            .run_i8(input, &mut vec![0; words], &mut wx, &mut wy)
            .unwrap();
        for (_, k) in supported_kernel_sets() {
            // Up to `MAX_BLOCK` (96): blocks of whole AMX tile pairs (32, 96) and not.
            for block in [1, 2, 5, 6, 7, 13, 24, 32, 96] {
                let (mut x, mut y) = outputs();
                let mut scratch = vec![0; scratch_words_for_block(&m, block)];
                let plan = Plan::packed(&m, k, &packed, scratch.len()).unwrap();
                assert!(plan.is_packed() && plan.block() == block);
                plan.run_i8(input, &mut scratch, &mut x, &mut y).unwrap();
                // `assert!`, not `assert_eq!`: a failure names the case, not 8,000 integers.
                assert!(x == wx && y == wy, "{name}, {} block {block}", k.name());
            }
            // Scratch that starts at different offsets from a cache line, exactly the plan's
            // words (the activation rows stay where they fall) and `ALIGN_WORDS` more (the
            // engine moves them to a line): the integers stay the same.
            let words = scratch_words_for_block(&m, 96);
            let plan = Plan::packed(&m, k, &packed, words).unwrap();
            let mut big = vec![0; words + evpose_core::infer::ALIGN_WORDS + 16];
            for skip in [0, 1, 3, 7, 12, 16] {
                for lent in [words, words + evpose_core::infer::ALIGN_WORDS] {
                    let (mut x, mut y) = outputs();
                    let scratch = &mut big[skip..][..lent];
                    plan.run_i8(input, scratch, &mut x, &mut y).unwrap();
                    assert!(
                        x == wx && y == wy,
                        "{name}, {}, skip {skip}, {lent} words",
                        k.name()
                    );
                }
            }
            tested.push(format!(
                "{name} {}{}",
                k.name(),
                if k.has_packed() { " (native)" } else { "" }
            ));
        }
    }
    eprintln!("packed engine tested with: {}", tested.join(", "));
}

#[test]
fn widened_int8_engine_gives_identical_integers_on_every_block() {
    // The Cortex-M DSP kernel's widened weights, through its portable emulation here (the
    // instructions themselves run under QEMU in `firmware_qemu`): the small model (point
    // layers wider than the kernel's 128-input chunk) and the bundled MCU model, every block
    // size against the row-major engine with the reference kernels.
    use evpose_core::kernels::Kernels;
    use evpose_core::{scratch_words_for_block, widen_point_layers, widened_words, Model, Plan};
    let case = small();
    let net = model::import_onnx(&case.model).unwrap();
    let small_blob = int8_blob(&net, &case.inputs[..1]);
    let mcu_blob = AlignedBlob::new(evpose_host::assets::DEFAULT_MODEL);
    for (name, blob) in [("small", &small_blob), ("mcu", &mcu_blob)] {
        let m = Model::parse(blob.bytes()).unwrap();
        let point_i8: usize = (1..m.point_layer_count())
            .map(|i| m.layer(i).desc.in_dim as usize / 4 * 4 * m.layer(i).desc.out_dim as usize)
            .sum();
        assert_eq!(
            widened_words(&m),
            point_i8 / 2,
            "{name}: two words per four weights"
        );
        let mut buf = vec![0u32; widened_words(&m)];
        let widened = widen_point_layers(&m, &mut buf).unwrap();
        let input = &case.inputs[4][..300];
        let (j, w, h) = (m.joints(), m.width(), m.height());
        let outputs = || (vec![0; j * w], vec![0; j * h]);
        let (mut wx, mut wy) = outputs();
        let words = scratch_words_for_block(&m, 1);
        Plan::new(&m, Kernels::reference(), words)
            .unwrap()
            .run_i8(input, &mut vec![0; words], &mut wx, &mut wy)
            .unwrap();
        for block in [1, 3, 4, 5, 8, 13, 24] {
            let (mut x, mut y) = outputs();
            let mut scratch = vec![0; scratch_words_for_block(&m, block)];
            let plan = Plan::widened(&m, Kernels::best(), &widened, scratch.len()).unwrap();
            assert!(plan.is_widened() && !plan.is_packed() && plan.block() == block);
            plan.run_i8(input, &mut scratch, &mut x, &mut y).unwrap();
            assert_eq!((&x, &y), (&wx, &wy), "{name}, block {block}");
        }
    }
}

/// The small model quantized with two calibrations, parsed: two int8 models of one shape
/// whose checksums differ, handed to `f`.
fn with_two_small_models<R>(
    f: impl FnOnce(&evpose_core::Model<'_>, &evpose_core::Model<'_>) -> R,
) -> R {
    let case = small();
    let net = model::import_onnx(&case.model).unwrap();
    let blob_of = |i: usize| int8_blob(&net, &case.inputs[i..i + 1]);
    let (a, b) = (blob_of(0), blob_of(1));
    assert_ne!(a.bytes(), b.bytes(), "two calibrations, two blobs");
    let (ma, mb) = (
        evpose_core::Model::parse(a.bytes()).unwrap(),
        evpose_core::Model::parse(b.bytes()).unwrap(),
    );
    f(&ma, &mb)
}

#[test]
fn widened_weights_of_another_model_or_a_short_buffer_are_errors() {
    use evpose_core::kernels::Kernels;
    use evpose_core::{scratch_words, widen_point_layers, widened_words, InferError, Plan};
    with_two_small_models(|ma, mb| {
        let need = widened_words(ma);
        assert!(need > 0);
        assert_eq!(
            widen_point_layers(ma, &mut vec![0; need - 1]).unwrap_err(),
            InferError::WidenBuffer {
                needed: need,
                got: need - 1
            }
        );
        // A longer buffer is fine; the weights of model a do not plan model b.
        let mut buf = vec![0u32; need + 5];
        let widened = widen_point_layers(ma, &mut buf).unwrap();
        assert!(Plan::widened(ma, Kernels::best(), &widened, scratch_words(ma)).is_ok());
        assert_eq!(
            Plan::widened(mb, Kernels::best(), &widened, scratch_words(mb)).unwrap_err(),
            InferError::PackedModel
        );
    });
}

#[test]
fn host_runner_over_row_major_weights_gives_the_packed_runners_integers() {
    // `CoreRunner::row_major`, what `evpose bench infer` times beside the packed engine, runs
    // the same kernel family unpacked and must give the same logits.
    use evpose_host::model::CoreRunner;
    let case = small();
    let net = model::import_onnx(&case.model).unwrap();
    let blob = int8_blob(&net, &case.inputs[..1]);
    let input = &case.inputs[3];
    for (_, k) in supported_kernel_sets() {
        let mut packed = CoreRunner::with_kernels(&blob, &k).unwrap();
        let mut row_major = CoreRunner::row_major(&blob, &k).unwrap();
        assert_eq!(packed.is_packed(), k.has_packed(), "{}", k.name());
        assert!(!row_major.is_packed(), "{}", k.name());
        let (a, b) = (
            packed.run_i8(input).unwrap(),
            row_major.run_i8(input).unwrap(),
        );
        assert_eq!((a.x, a.y), (b.x, b.y), "{}", k.name());
    }
}

#[test]
fn packed_weights_of_another_model_or_in_another_buffer_are_errors() {
    use evpose_core::kernels::Kernels;
    use evpose_core::{pack_layers, packed_bytes, scratch_words, InferError, Plan};
    with_two_small_models(|ma, mb| {
        let need = packed_bytes(ma);
        assert!(need > 0);
        assert_eq!(
            pack_layers(ma, &mut vec![0; need - 1]).unwrap_err(),
            InferError::PackBuffer {
                needed: need,
                got: need - 1
            }
        );
        let mut buf = vec![0u8; need];
        let layout = pack_layers(ma, &mut buf).unwrap();
        // The layout of model a, asked for model b.
        assert_eq!(
            layout.weights(mb, &buf).unwrap_err(),
            InferError::PackedModel
        );
        // Another buffer: shorter, or a copy of the right length (its contents could be anything).
        assert_eq!(
            layout.weights(ma, &buf[..need / 2]).unwrap_err(),
            InferError::PackedBuffer
        );
        let copy = buf.clone();
        assert_eq!(
            layout.weights(ma, &copy).unwrap_err(),
            InferError::PackedBuffer
        );
        // Weights of model a, run with model b.
        let packed = layout.weights(ma, &buf).unwrap();
        let (mut x, mut y) = (vec![0; 13 * 346], vec![0; 13 * 260]);
        let mut scratch = vec![0; scratch_words(mb)];
        let case = small();
        let input = &case.inputs[0][..10];
        let k = Kernels::detect();
        assert_eq!(
            Plan::packed(mb, k, &packed, scratch.len()).unwrap_err(),
            InferError::PackedModel
        );
        Plan::packed(ma, k, &packed, scratch.len())
            .unwrap()
            .run_i8(input, &mut scratch, &mut x, &mut y)
            .unwrap();
    });
}

#[test]
fn int8_engine_gives_identical_integers_for_every_block_size() {
    use evpose_core::kernels::Kernels;
    use evpose_core::{scratch_words_for_block, Model, Plan};
    let case = small();
    let net = model::import_onnx(&case.model).unwrap();
    let blob = int8_blob(&net, &case.inputs[..1]);
    let m = Model::parse(blob.bytes()).unwrap();
    let input = &case.inputs[4][..1000]; // 1000 points: not a multiple of most block sizes
    let run = |words: usize| {
        let (mut x, mut y) = (vec![0; 13 * 346], vec![0; 13 * 260]);
        Plan::new(&m, Kernels::best(), words)
            .unwrap()
            .run_i8(input, &mut vec![0; words], &mut x, &mut y)
            .unwrap();
        (x, y)
    };
    let one = run(scratch_words_for_block(&m, 1));
    for block in [2, 3, 7, 8, 16, 24] {
        assert_eq!(
            run(scratch_words_for_block(&m, block)),
            one,
            "block {block}"
        );
    }
    // Scratch between two block sizes uses the smaller block.
    assert_eq!(run(scratch_words_for_block(&m, 5) + 3), one);
}

#[test]
fn f32_engine_gives_identical_bits_with_every_kernel_set_and_block_size() {
    use evpose_core::kernels::Kernels;
    use evpose_core::{scratch_words_for_block, Model, Plan};
    let case = small();
    let blob = model::load_blob(&case.model).unwrap();
    let m = Model::parse(blob.bytes()).unwrap();
    let input = &case.inputs[4][..1000]; // 1000 points: not a multiple of most block sizes
    let run = |k: &Kernels, words: usize| {
        let (mut x, mut y) = (vec![0f32; 13 * 346], vec![0f32; 13 * 260]);
        Plan::new(&m, *k, words)
            .unwrap()
            .run_f32(input, &mut vec![0.0; words], &mut x, &mut y)
            .unwrap();
        let bits = |v: Vec<f32>| v.into_iter().map(f32::to_bits).collect::<Vec<_>>();
        (bits(x), bits(y))
    };
    let want = run(&Kernels::reference(), scratch_words_for_block(&m, 1));
    for (isa, k) in supported_kernel_sets() {
        for block in [1, 2, 3, 7, 16, 24] {
            let got = run(&k, scratch_words_for_block(&m, block));
            assert!(got == want, "{} block {block}", isa.name());
        }
    }
    // Scratch between two block sizes uses the smaller block.
    assert!(run(&Kernels::detect(), scratch_words_for_block(&m, 5) + 3) == want);
}

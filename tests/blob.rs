//! The model blob: corrupt, truncated or misaligned blobs are typed errors, never panics.

use evpose_core::kernels::Kernels;
use evpose_core::model::{Model, ModelError};
use evpose_core::{scratch_words, InferError, Plan};
use evpose_host::model::{self, quantize, AlignedBlob};
use evpose_tests::fixtures;

fn small_i8_blob() -> Vec<u8> {
    let net = model::import_onnx(&fixtures().join("pointnet-small.onnx")).unwrap();
    let input = model::read_points(&fixtures().join("street-00.points.npy")).unwrap();
    let q = quantize::quantize(&net, &quantize::calibrate(&net, &[input]).unwrap()).unwrap();
    q.blob().unwrap()
}

#[test]
fn valid_blob_parses_with_the_right_shape() {
    let blob = AlignedBlob::new(&small_i8_blob());
    let m = Model::parse(blob.bytes()).unwrap();
    assert_eq!(
        (m.joints(), m.width(), m.height(), m.head_dim()),
        (13, 346, 260, 64)
    );
    assert_eq!(m.point_layer_count(), 5);
    assert_eq!(
        m.macs_per_point(),
        5 * 32 + 32 * 32 + 32 * 64 + 64 * 128 + 256 * 256
    );
}

#[test]
fn every_truncation_is_an_error() {
    let bytes = small_i8_blob();
    // Every prefix up to the header, then a stride through the rest.
    let cuts = (0..200).chain((200..bytes.len()).step_by(997));
    for cut in cuts {
        let blob = AlignedBlob::new(&bytes[..cut]);
        assert!(
            Model::parse(blob.bytes()).is_err(),
            "prefix of {cut} bytes parsed"
        );
    }
}

#[test]
fn flipped_bits_are_caught_by_the_checksum_or_the_header_checks() {
    let bytes = small_i8_blob();
    for at in (0..bytes.len()).step_by(1_201).chain(0..64) {
        let mut b = bytes.clone();
        b[at] ^= 0x10;
        let blob = AlignedBlob::new(&b);
        assert!(
            Model::parse(blob.bytes()).is_err(),
            "flip at byte {at} accepted"
        );
    }
}

#[test]
fn header_problems_have_their_own_errors() {
    let bytes = small_i8_blob();
    let mut b = bytes.clone();
    b[0] = b'X';
    assert_eq!(
        Model::parse(AlignedBlob::new(&b).bytes()).err(),
        Some(ModelError::BadMagic)
    );
    let mut b = bytes.clone();
    b[4] = 9;
    assert_eq!(
        Model::parse(AlignedBlob::new(&b).bytes()).err(),
        Some(ModelError::Version(9))
    );
    assert!(matches!(
        Model::parse(AlignedBlob::new(&bytes[..10]).bytes()),
        Err(ModelError::Truncated {
            needed: 64,
            got: 10
        })
    ));
    // One byte off a 16-byte boundary.
    let mut shifted = vec![0u8; 1];
    shifted.extend_from_slice(&bytes);
    let a = AlignedBlob::new(&shifted);
    assert_eq!(
        Model::parse(&a.bytes()[1..]).err(),
        Some(ModelError::Misaligned)
    );
}

#[test]
fn too_little_scratch_and_no_points_are_errors() {
    let blob = AlignedBlob::new(&small_i8_blob());
    let m = Model::parse(blob.bytes()).unwrap();
    let (mut x, mut y) = (vec![0; 13 * 346], vec![0; 13 * 260]);
    let need = scratch_words(&m);
    // Planned for too little scratch, or run with less than planned.
    assert_eq!(
        Plan::new(&m, Kernels::best(), need - 1).unwrap_err(),
        InferError::Scratch {
            needed: need,
            got: need - 1
        }
    );
    let plan = Plan::new(&m, Kernels::best(), need).unwrap();
    assert_eq!(
        plan.run_i8(&[[1.0; 5]], &mut vec![0; need - 1], &mut x, &mut y),
        Err(InferError::Scratch {
            needed: need,
            got: need - 1
        })
    );
    let mut scratch = vec![0; need];
    assert_eq!(
        plan.run_i8(&[], &mut scratch, &mut x, &mut y),
        Err(InferError::NoPoints)
    );
    assert!(matches!(
        plan.run_i8(&[[1.0; 5]], &mut scratch, &mut x[..5], &mut y),
        Err(InferError::Output { .. })
    ));
    // The engine is the model's: an int8 plan does not run f32.
    let (mut fx, mut fy) = (vec![0.0; 13 * 346], vec![0.0; 13 * 260]);
    assert_eq!(
        plan.run_f32(&[[1.0; 5]], &mut vec![0.0; need], &mut fx, &mut fy),
        Err(InferError::DType)
    );
    assert!(plan
        .run_i8(&[[1.0; 5]], &mut scratch, &mut x, &mut y)
        .is_ok());
}

#[test]
fn the_preprocessing_contract_travels_with_the_model() {
    use evpose_core::model::{header, Preprocessing, CRC};
    // A blob written now (version 3) records what it was given.
    let net = model::import_onnx(&fixtures().join("pointnet-small.onnx")).unwrap();
    let input = model::read_points(&fixtures().join("street-00.points.npy")).unwrap();
    let mut q = quantize::quantize(&net, &quantize::calibrate(&net, &[input]).unwrap()).unwrap();
    let want = Preprocessing {
        points: 1024,
        window_events: 30_000,
        slices: 4,
    };
    q.preprocessing = want;
    let bytes = q.blob().unwrap();
    let blob = AlignedBlob::new(&bytes);
    assert_eq!(Model::parse(blob.bytes()).unwrap().preprocessing(), want);
    // Version 1 blobs (the earlier default model, int8 heads without scales) still parse,
    // stating nothing and giving no confidences.
    let v1 = AlignedBlob::new(&std::fs::read(fixtures().join("pointnet-small-v1.evq")).unwrap());
    assert_eq!(u16::from_le_bytes([v1.bytes()[4], v1.bytes()[5]]), 1);
    let m = Model::parse(v1.bytes()).unwrap();
    assert_eq!(m.preprocessing(), Preprocessing::default());
    assert_eq!(m.head_scales(), None);
    // Version 3: 15-bit heads with their logit scale (positive, one per head).
    let m3 = Model::parse(blob.bytes()).unwrap();
    let [sx, sy] = m3.head_scales().unwrap();
    assert!(sx > 0.0 && sy > 0.0);
    let hx = m3.layer(m3.head_x_index());
    assert!(matches!(hx.weights, evpose_core::model::Weights::I16(_)));
    // More time slices than the rasterizer has, or a non-zero reserved byte, are errors (the
    // CRC recomputed, so that the field is what fails).
    let reseal = |mut b: Vec<u8>| {
        let crc = CRC.checksum(&b[header::CRC_FROM..]);
        b[header::CRC..header::CRC + 4].copy_from_slice(&crc.to_le_bytes());
        AlignedBlob::new(&b)
    };
    let mut bad = bytes.clone();
    bad[header::SLICES] = 9;
    assert!(matches!(
        Model::parse(reseal(bad).bytes()),
        Err(ModelError::Header(_))
    ));
    let mut bad = bytes.clone();
    bad[header::SLICES + 3] = 1;
    assert!(matches!(
        Model::parse(reseal(bad).bytes()),
        Err(ModelError::Header(_))
    ));
    // Version 2 had no i16 heads and no head scales: the same bytes labelled 2 are corrupt.
    let mut bad = bytes.clone();
    bad[header::VERSION] = 2;
    assert!(matches!(
        Model::parse(reseal(bad).bytes()),
        Err(ModelError::Layer { .. })
    ));
    // A version 1 blob with preprocessing fields is corrupt.
    let mut bad = bytes;
    bad[header::VERSION] = 1;
    assert!(matches!(
        Model::parse(reseal(bad).bytes()),
        Err(ModelError::Header(_))
    ));
}

/// The `fuzz/` target `blob` parses each input as is and with its length and CRC-32 made right;
/// inputs it found that crashed are kept in `tests/fixtures/fuzz/` and must stay errors.
#[test]
fn blobs_found_by_the_fuzzer_are_errors() {
    use evpose_core::model::{header, CRC};
    let fixed = |bytes: &[u8]| {
        let mut b = bytes.to_vec();
        let total = (b.len() as u32).to_le_bytes();
        b[header::TOTAL..header::TOTAL + 4].copy_from_slice(&total);
        let crc = CRC.checksum(&b[header::CRC_FROM..]).to_le_bytes();
        b[header::CRC..header::CRC + 4].copy_from_slice(&crc);
        b
    };
    // An int8 point layer reading the input features with i8 weights: the engine reads the
    // input only through i16 weights, and indexed the activations at -1 (a panic) before parse
    // refused it.
    let bytes = std::fs::read(fixtures().join("fuzz/blob-int8-layer-on-input.evq")).unwrap();
    let blob = AlignedBlob::new(&fixed(&bytes));
    match Model::parse(blob.bytes()) {
        Err(ModelError::Layer { reason, .. }) => {
            assert!(
                reason.contains("input features take i16 weights"),
                "{reason}"
            )
        }
        other => panic!("expected a layer error, got {other:?}"),
    }
}

/// Requantization scales must be finite: the Cortex-M7 requantization (`kernels::arm`) rounds
/// before it saturates, which equals the reference's clamp-then-round only for numbers.
#[test]
fn non_finite_requantization_scales_are_errors() {
    use evpose_core::model::{entry, header, CRC, ENTRY_LEN};
    let bytes = small_i8_blob();
    let u32_at = |b: &[u8], o: usize| u32::from_le_bytes(b[o..o + 4].try_into().unwrap()) as usize;
    let table = u32_at(&bytes, header::TABLE);
    let layers = usize::from(u16::from_le_bytes([
        bytes[header::LAYERS],
        bytes[header::LAYERS + 1],
    ]));
    // Every layer that requantizes (point and FC layers, kinds 0 and 1; the heads' scales are
    // their logit scales), one bad value each time.
    let with_scales: Vec<usize> = (0..layers)
        .map(|i| table + i * ENTRY_LEN)
        .filter(|&e| bytes[e + entry::KIND] <= 1)
        .map(|e| u32_at(&bytes, e + entry::SCALES))
        .collect();
    assert_eq!(with_scales.len(), 7, "{with_scales:?}");
    for &off in &with_scales {
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let mut b = bytes.clone();
            b[off + 4..off + 8].copy_from_slice(&bad.to_le_bytes());
            let crc = CRC.checksum(&b[header::CRC_FROM..]);
            b[header::CRC..header::CRC + 4].copy_from_slice(&crc.to_le_bytes());
            match Model::parse(AlignedBlob::new(&b).bytes()) {
                Err(ModelError::Layer { reason, .. }) => {
                    assert!(reason.contains("not finite"), "{reason}")
                }
                Err(other) => panic!("scale {bad} at {off}: {other:?}"),
                Ok(_) => panic!("scale {bad} at {off} accepted"),
            }
        }
    }
}

/// A model whose training diverged (NaN or infinite weights), NaN or infinite calibration
/// features, and a quantized net the core would refuse are errors where they arise: in the
/// import, the calibration and the writing of the blob, never a plausible-looking blob.
#[test]
fn non_finite_models_and_calibration_inputs_are_refused() {
    let onnx = std::fs::read(fixtures().join("pointnet-small.onnx")).unwrap();
    let net = model::import_onnx(&fixtures().join("pointnet-small.onnx")).unwrap();
    // The x head's first weight (a plain Linear: no BatchNorm folded into it), found by its
    // bytes in the ONNX file (its initializer holds the raw little-endian floats) and made
    // NaN, then infinite.
    let w = net.head_x.w[0].to_le_bytes();
    let at: Vec<usize> = onnx
        .windows(4)
        .enumerate()
        .filter(|(_, b)| *b == w)
        .map(|(i, _)| i)
        .collect();
    assert_eq!(at.len(), 1, "the weight's bytes are not unique in the file");
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"));
    for bad in [f32::NAN, f32::INFINITY] {
        let mut b = onnx.clone();
        b[at[0]..at[0] + 4].copy_from_slice(&bad.to_le_bytes());
        let path = dir.join("pointnet-small-non-finite.onnx");
        std::fs::write(&path, &b).unwrap();
        let err = format!("{:#}", model::import_onnx(&path).unwrap_err());
        assert!(
            err.contains("layer 7 (head_x) has a non-finite weight or bias"),
            "{err}"
        );
    }
    let input = model::read_points(&fixtures().join("street-00.points.npy")).unwrap();
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mut points = input.clone();
        points[17][2] = bad;
        let err = quantize::calibrate(&net, &[input.clone(), points]).unwrap_err();
        assert_eq!(
            err.to_string(),
            "calibration window 1, point 17: a non-finite feature"
        );
    }
    let mut q = quantize::quantize(&net, &quantize::calibrate(&net, &[input]).unwrap()).unwrap();
    q.layers[2].scales[3] = f32::INFINITY;
    let err = q.blob().unwrap_err().to_string();
    assert!(
        err.starts_with("the model would not load:") && err.contains("not finite"),
        "{err}"
    );
}

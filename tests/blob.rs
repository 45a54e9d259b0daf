//! The model blob: corrupt, truncated or misaligned blobs are typed errors, never panics.

use evpose_core::model::{Model, ModelError};
use evpose_core::{run_i8, scratch_words, InferError};
use evpose_host::model::{self, quant, AlignedBlob};
use evpose_tests::fixtures;

fn small_i8_blob() -> Vec<u8> {
    let net = model::import_onnx(&fixtures().join("pointnet-small.onnx")).unwrap();
    let input = model::read_points(&fixtures().join("street-00.points.npy")).unwrap();
    let q = quant::quantize(&net, &quant::calibrate(&net, &[input]).unwrap()).unwrap();
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
    let mut scratch = vec![0; need - 1];
    assert_eq!(
        run_i8(&m, &[[1.0; 5]], &mut scratch, &mut x, &mut y),
        Err(InferError::Scratch {
            needed: need,
            got: need - 1
        })
    );
    let mut scratch = vec![0; need];
    assert_eq!(
        run_i8(&m, &[], &mut scratch, &mut x, &mut y),
        Err(InferError::NoPoints)
    );
    assert!(matches!(
        run_i8(&m, &[[1.0; 5]], &mut scratch, &mut x[..5], &mut y),
        Err(InferError::Output { .. })
    ));
    assert!(run_i8(&m, &[[1.0; 5]], &mut scratch, &mut x, &mut y).is_ok());
}

//! DHP19 cameras from the bundled `.npy` files.
#![allow(dead_code)]

use evpose_core::geometry::Camera;

/// Reads a small little-endian float64 C-order `.npy` file: its values and shape.
pub fn read_npy(name: &str) -> (Vec<f64>, Vec<usize>) {
    let path = format!("{}/../assets/dhp19/{name}", env!("CARGO_MANIFEST_DIR"));
    let b = std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    assert_eq!(&b[..6], b"\x93NUMPY", "{path}: not .npy");
    let (hlen, start) = if b[6] == 1 {
        (usize::from(u16::from_le_bytes([b[8], b[9]])), 10)
    } else {
        (u32::from_le_bytes([b[8], b[9], b[10], b[11]]) as usize, 12)
    };
    let header = std::str::from_utf8(&b[start..start + hlen]).unwrap();
    assert!(
        header.contains("'<f8'") && header.contains("'fortran_order': False"),
        "{header}"
    );
    let shape_txt = header
        .split("'shape': (")
        .nth(1)
        .unwrap()
        .split(')')
        .next()
        .unwrap();
    let shape: Vec<usize> = shape_txt
        .split(',')
        .filter_map(|s| s.trim().parse().ok())
        .collect();
    let data: Vec<f64> = b[start + hlen..]
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(data.len(), shape.iter().product::<usize>());
    (data, shape)
}

/// The four DHP19 cameras in channel order: 0 → P4, 1 → P1, 2 → P3, 3 → P2 (centres: rows 3,
/// 0, 2, 1 of `camera_positions.npy`).
pub fn dhp19_cameras() -> [Camera; 4] {
    let (centres, shape) = read_npy("camera_positions.npy");
    assert_eq!(shape, [4, 3]);
    let map = [(4, 3), (1, 0), (3, 2), (2, 1)];
    map.map(|(p, row)| {
        let (m, shape) = read_npy(&format!("P{p}.npy"));
        assert_eq!(shape, [3, 4]);
        let proj: [[f64; 4]; 3] = core::array::from_fn(|r| core::array::from_fn(|c| m[r * 4 + c]));
        let c = [centres[row * 3], centres[row * 3 + 1], centres[row * 3 + 2]];
        Camera::new(proj, c, 346, 260).unwrap()
    })
}

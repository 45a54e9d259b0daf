//! Geometry: projection and two-view triangulation of 2-D joints to 3-D, as in DHP19's reference
//! evaluation.
//!
//! A [`Camera`] is a 3 × 4 projection matrix `P`, its camera centre and the image size. The
//! conventions are DHP19's (image y grows downwards, `H` is the image height):
//!
//! - projection: `[u', v', w] = P · [X, Y, Z, 1]`, `u = u'/w`, `v = H − v'/w`
//!   ([`Camera::project`]); a joint is visible when `u ∈ (0, W]` and `v ∈ (0, H]`
//!   ([`Camera::is_visible`]);
//! - back-projection: `(u, H − v, 1)` times the Moore–Penrose pseudo-inverse `P⁺` (4 × 3) is a
//!   homogeneous 3-D point; dehomogenized, it lies on the joint's ray, which runs from the camera
//!   centre through it ([`Camera::back_project`]);
//! - triangulation: the least-squares intersection of the two rays, the point `p` that minimizes
//!   the summed squared distances to both lines, from the normal equations
//!   `Σᵢ (I − nᵢnᵢᵀ) p = Σᵢ (I − nᵢnᵢᵀ) cᵢ` (`cᵢ` a ray's origin, `nᵢ` its unit direction); for two
//!   rays it is the midpoint of their closest approach ([`triangulate`], [`triangulate_joints`]).
//!
//! DHP19's calibration: aedat camera channel 0 is `P4.npy`, 1 is `P1`, 2 is `P3`, 3 is `P2`
//! (centres in rows 3, 0, 2, 1 of `camera_positions.npy`); `evpose_host::dhp19` reads them, and
//! the host binary bundles them (`assets/dhp19`). An MCU builds its [`Camera`]s from those
//! twelve numbers and three centre coordinates each.
//!
//! `P⁺` is computed once, by SVD, in [`Camera::new`]. Everything is `f64`; nothing allocates,
//! and bad input (NaN, a rank-deficient `P`, a back-projected point at infinity, parallel rays)
//! is a [`GeometryError`], never a panic or a NaN result.
//!
//! The method needs the back-projected point's `w` away from 0. Since `P⁺x` is orthogonal to
//! `P`'s null vector `(C, 1)`, `w = −(P⁺x)_xyz · C`: it vanishes for a camera at the world origin
//! and along one line of the image plane. For the DHP19 cameras that line is 1,300–1,900 pixels
//! below the image, so every pixel back-projects.
//!
//! ```
//! use evpose_core::geometry::{triangulate, Camera};
//!
//! // Two cameras 1 m in front of the origin, 500 mm apart, looking along +Z (f = 300 px).
//! let camera = |cx: f64| {
//!     let (f, u0, v0, tz) = (300.0, 173.0, 130.0, 1000.0);
//!     let p = [
//!         [f, 0.0, u0, -f * cx + u0 * tz],
//!         [0.0, f, v0, v0 * tz],
//!         [0.0, 0.0, 1.0, tz],
//!     ];
//!     Camera::new(p, [cx, 0.0, -tz], 346, 260).unwrap()
//! };
//! let (a, b) = (camera(0.0), camera(500.0));
//! let joint = [100.0, -50.0, 200.0];
//! let (ja, jb) = (a.project(joint).unwrap(), b.project(joint).unwrap());
//! assert!(a.is_visible(ja) && b.is_visible(jb));
//! let x = triangulate(&a, ja, &b, jb).unwrap();
//! assert!((0..3).all(|i| (x[i] - joint[i]).abs() < 1e-9));
//! ```

use core::fmt;

use nalgebra::{Matrix3, Matrix3x4, Matrix4x3, Vector3, Vector4, SVD};

/// Singular values of `P` at or below this fraction of the largest make it rank-deficient
/// ([`GeometryError::RankDeficient`]): `4·ε`, numpy's `pinv` cut-off for a 3 × 4 matrix
/// (`max(M, N)·ε`), so that every matrix accepted here has all three singular values inverted,
/// as numpy inverts them.
pub const RANK_TOLERANCE: f64 = 4.0 * f64::EPSILON;

/// A back-projected homogeneous point `(x, y, z, w)` with `|w| ≤ AT_INFINITY · max(|x|, |y|, |z|)`
/// is at infinity ([`GeometryError::PointAtInfinity`]): dehomogenized, it would lie more than
/// 10¹² world units (10⁹ km in millimetres) from the origin.
pub const AT_INFINITY: f64 = 1e-12;

/// Rays whose directions have a sine below this are parallel ([`GeometryError::ParallelRays`]):
/// the normal equations' condition number grows as `4 / sin²`, so below 10⁻⁶ (0.2 arc seconds)
/// they would keep fewer than 4 of `f64`'s 16 digits.
pub const MIN_RAY_SINE: f64 = 1e-6;

/// Iterations the SVD of `P` may take before it is declared not to converge (a 3 × 4 matrix
/// takes a handful).
const SVD_MAX_ITERATIONS: usize = 1_000;

/// Why a camera could not be built or a joint could not be triangulated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum GeometryError {
    /// A matrix entry, camera centre or image coordinate is NaN or infinite.
    NonFinite,
    /// The image width or height is 0.
    ImageSize,
    /// `P` has rank below 3 (see [`RANK_TOLERANCE`]), or its SVD did not converge.
    RankDeficient,
    /// The back-projected homogeneous point has `w ≈ 0` (see [`AT_INFINITY`]).
    PointAtInfinity,
    /// The back-projected point coincides with the camera centre: the ray has no direction.
    DegenerateRay,
    /// The two rays are parallel (see [`MIN_RAY_SINE`]): they have no unique closest point.
    ParallelRays,
    /// The cameras' centres coincide (the same calibration twice): their rays meet at that
    /// centre whatever they see, so there is no baseline to triangulate from.
    NoBaseline,
    /// Fewer than two views with a positive weight ([`triangulate_views`]).
    TooFewViews {
        /// Views with a positive weight.
        views: usize,
    },
    /// Joint and output slices of different lengths.
    Length {
        /// Joints from the first camera.
        a: usize,
        /// Joints from the second camera.
        b: usize,
        /// Output slots.
        out: usize,
    },
}

impl fmt::Display for GeometryError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::NonFinite => write!(f, "a matrix entry, centre or coordinate is not finite"),
            Self::ImageSize => write!(f, "image width and height must be positive"),
            Self::RankDeficient => write!(f, "projection matrix has rank below 3"),
            Self::PointAtInfinity => write!(f, "back-projected point is at infinity (w = 0)"),
            Self::DegenerateRay => {
                write!(f, "back-projected point coincides with the camera centre")
            }
            Self::ParallelRays => write!(f, "the two rays are parallel"),
            Self::NoBaseline => write!(f, "the cameras' centres coincide: no baseline"),
            Self::TooFewViews { views } => write!(
                f,
                "{views} view(s) with a positive weight; triangulation needs two"
            ),
            Self::Length { a, b, out } => write!(
                f,
                "joint counts differ: {a} and {b} joints, {out} output slots"
            ),
        }
    }
}

impl core::error::Error for GeometryError {}

/// A calibrated camera: projection matrix, its pseudo-inverse, centre and image size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    projection: Matrix3x4<f64>,
    pseudo_inverse: Matrix4x3<f64>,
    centre: Vector3<f64>,
    width: u16,
    height: u16,
}

impl Camera {
    /// Builds a camera from its 3 × 4 projection matrix `P` (row-major, world units to pixels,
    /// DHP19: millimetres), its centre in world units and its image size in pixels; computes
    /// `P⁺` once.
    ///
    /// The centre is taken as given, as the reference evaluation does (for the DHP19 cameras it
    /// is `P`'s null vector); rays start there.
    ///
    /// # Errors
    /// [`GeometryError::NonFinite`] for a NaN or infinite entry, [`GeometryError::ImageSize`]
    /// for a zero width or height, [`GeometryError::RankDeficient`] when `P` has rank below 3.
    pub fn new(
        projection: [[f64; 4]; 3],
        centre: [f64; 3],
        width: u16,
        height: u16,
    ) -> Result<Self, GeometryError> {
        let projection = Matrix3x4::from_fn(|r, c| projection[r][c]);
        let centre = Vector3::from(centre);
        if !all_finite(projection.iter()) || !all_finite(centre.iter()) {
            return Err(GeometryError::NonFinite);
        }
        if width == 0 || height == 0 {
            return Err(GeometryError::ImageSize);
        }
        let svd = SVD::try_new(projection, true, true, f64::EPSILON, SVD_MAX_ITERATIONS)
            .ok_or(GeometryError::RankDeficient)?;
        let s = svd.singular_values;
        let cutoff = RANK_TOLERANCE * s.max();
        // (A NaN singular value gives a non-finite P⁺, caught below.)
        if s.min() <= cutoff {
            return Err(GeometryError::RankDeficient);
        }
        let pseudo_inverse = svd
            .pseudo_inverse(cutoff)
            .map_err(|_| GeometryError::RankDeficient)?;
        if !all_finite(pseudo_inverse.iter()) {
            return Err(GeometryError::RankDeficient);
        }
        Ok(Self {
            projection,
            pseudo_inverse,
            centre,
            width,
            height,
        })
    }

    /// The projection matrix `P`, row-major.
    pub fn projection(&self) -> [[f64; 4]; 3] {
        core::array::from_fn(|r| core::array::from_fn(|c| self.projection[(r, c)]))
    }

    /// The Moore–Penrose pseudo-inverse `P⁺` (4 × 3), row-major.
    pub fn pseudo_inverse(&self) -> [[f64; 3]; 4] {
        core::array::from_fn(|r| core::array::from_fn(|c| self.pseudo_inverse[(r, c)]))
    }

    /// The camera centre, world units.
    pub fn centre(&self) -> [f64; 3] {
        self.centre.into()
    }

    /// Image width `W`, pixels.
    pub fn width(&self) -> u16 {
        self.width
    }

    /// Image height `H`, pixels.
    pub fn height(&self) -> u16 {
        self.height
    }

    /// Projects a world point: `[u', v', w] = P · [X, Y, Z, 1]`, `(u'/w, H − v'/w)`.
    ///
    /// `None` when the point is not finite or lies on the camera's principal plane (`w` zero
    /// up to rounding: `|w|` within `4·ε` of the sum of its terms' magnitudes). Points behind
    /// the camera project too; [`Camera::is_visible`] checks the image bounds.
    pub fn project(&self, point: [f64; 3]) -> Option<(f64, f64)> {
        let x = Vector4::new(point[0], point[1], point[2], 1.0);
        if !all_finite(x.iter()) {
            return None;
        }
        let h = self.projection * x;
        let scale: f64 = self
            .projection
            .row(2)
            .iter()
            .zip(x.iter())
            .map(|(p, x)| (p * x).abs())
            .sum();
        // `w` is rounding noise when it is within a few ε of the magnitudes that summed to it.
        if h[2].abs() <= 4.0 * f64::EPSILON * scale {
            return None;
        }
        let (u, v) = (h[0] / h[2], f64::from(self.height) - h[1] / h[2]);
        (u.is_finite() && v.is_finite()).then_some((u, v))
    }

    /// Whether an image point lies in the image: `u ∈ (0, W]` and `v ∈ (0, H]` (DHP19's mask;
    /// NaN is outside).
    pub fn is_visible(&self, (u, v): (f64, f64)) -> bool {
        u > 0.0 && u <= f64::from(self.width) && v > 0.0 && v <= f64::from(self.height)
    }

    /// Back-projects an image point: `P⁺ · (u, H − v, 1)`, dehomogenized. The result lies on
    /// the point's ray, which runs from [`Camera::centre`] through it.
    ///
    /// # Errors
    /// [`GeometryError::NonFinite`] for a NaN or infinite coordinate,
    /// [`GeometryError::PointAtInfinity`] when `w ≈ 0` (see [`AT_INFINITY`]).
    pub fn back_project(&self, (u, v): (f64, f64)) -> Result<[f64; 3], GeometryError> {
        if !u.is_finite() || !v.is_finite() {
            return Err(GeometryError::NonFinite);
        }
        let h = self.pseudo_inverse * Vector3::new(u, f64::from(self.height) - v, 1.0);
        let xyz = h.xyz();
        if h[3].abs() <= AT_INFINITY * xyz.amax() {
            return Err(GeometryError::PointAtInfinity);
        }
        let point = xyz / h[3];
        if !all_finite(point.iter()) {
            return Err(GeometryError::PointAtInfinity);
        }
        Ok(point.into())
    }

    /// The unit direction of an image point's ray, from the centre through the back-projected
    /// point.
    fn ray(&self, joint: (f64, f64)) -> Result<Vector3<f64>, GeometryError> {
        let d = Vector3::from(self.back_project(joint)?) - self.centre;
        let norm = d.norm();
        if !(norm > 0.0 && norm.is_finite()) {
            return Err(GeometryError::DegenerateRay);
        }
        Ok(d / norm)
    }
}

/// Triangulates one joint seen by two cameras at image points `a` and `b` (`(u, v)`, pixels,
/// DHP19's convention): the least-squares intersection of the two back-projected rays, in world
/// units.
///
/// Agrees with DHP19's numpy evaluation (`numpy.linalg.pinv`, `numpy.linalg.lstsq`) to within
/// round-off: on the DHP19 cameras, 10⁻⁶ mm or better (`tests/geometry.rs`).
///
/// # Errors
/// Those of [`Camera::back_project`] for either point, [`GeometryError::DegenerateRay`] when a
/// back-projected point is the camera centre, [`GeometryError::ParallelRays`] when the rays are
/// parallel (see [`MIN_RAY_SINE`]).
pub fn triangulate(
    cam_a: &Camera,
    a: (f64, f64),
    cam_b: &Camera,
    b: (f64, f64),
) -> Result<[f64; 3], GeometryError> {
    triangulate_views(&[(cam_a, a, 1.0), (cam_b, b, 1.0)])
}

/// Triangulates one joint seen by two or more cameras, each view `(camera, (u, v), weight)`
/// weighted (e.g. by the joint's confidence in that camera): the point `p` that minimizes
/// `Σᵢ wᵢ |(I − nᵢnᵢᵀ)(p − cᵢ)|²`, the weighted summed squared distances to the rays. With
/// equal weights and two views it is [`triangulate`]; a heavier view pulls the point towards
/// its ray (for two skew rays, along their common perpendicular, to the fraction
/// `w_b / (w_a + w_b)` of the way from ray A's closest point).
///
/// Views with weight 0 are ignored. Fixed memory: no allocation for any number of views.
///
/// # Errors
/// [`GeometryError::NonFinite`] for a negative or non-finite weight, [`GeometryError::TooFewViews`]
/// when fewer than two views have a positive weight, those of [`Camera::back_project`] for any
/// used point, [`GeometryError::DegenerateRay`], [`GeometryError::ParallelRays`] when no two
/// used rays are at least [`MIN_RAY_SINE`] apart, and [`GeometryError::NoBaseline`] when they
/// are but the used cameras all have the same centre.
pub fn triangulate_views(views: &[(&Camera, (f64, f64), f64)]) -> Result<[f64; 3], GeometryError> {
    if views.iter().any(|v| !(v.2.is_finite() && v.2 >= 0.0)) {
        return Err(GeometryError::NonFinite);
    }
    let used = views.iter().filter(|v| v.2 > 0.0).count();
    if used < 2 {
        return Err(GeometryError::TooFewViews { views: used });
    }
    // The weights relative to the largest, so that extreme finite weights (f64::MAX, or
    // subnormal ones) neither overflow R nor vanish in it; the minimizer is the same. Equal
    // weights all become exactly 1.
    let heaviest = views.iter().fold(0.0f64, |m, v| m.max(v.2));
    // Normal equations of min_p Σ wᵢ |(I − nᵢnᵢᵀ)(p − cᵢ)|²: R p = q.
    let (mut r, mut q) = (Matrix3::zeros(), Vector3::zeros());
    let mut first: Option<(Vector3<f64>, Vector3<f64>)> = None;
    let (mut spread, mut baseline) = (false, false);
    for &(cam, point, w) in views.iter().filter(|v| v.2 > 0.0) {
        let n = cam.ray(point)?;
        match first {
            None => first = Some((n, cam.centre)),
            Some((f, c)) => {
                spread |= f.cross(&n).norm() >= MIN_RAY_SINE;
                baseline |= cam.centre != c;
            }
        }
        let proj = projector(&n);
        let w = w / heaviest;
        r += proj * w;
        q += proj * cam.centre * w;
    }
    if !spread {
        return Err(GeometryError::ParallelRays);
    }
    if !baseline {
        return Err(GeometryError::NoBaseline);
    }
    let p = r.cholesky().ok_or(GeometryError::ParallelRays)?.solve(&q);
    if !all_finite(p.iter()) {
        return Err(GeometryError::ParallelRays);
    }
    Ok(p.into())
}

/// Triangulates a set of joints seen by two cameras: `out[j]` is [`triangulate`] of
/// `joints_a[j]` and `joints_b[j]`, each joint succeeding or failing on its own.
///
/// # Errors
/// [`GeometryError::Length`] (and nothing written) when the three slices differ in length.
pub fn triangulate_joints(
    cam_a: &Camera,
    joints_a: &[(f64, f64)],
    cam_b: &Camera,
    joints_b: &[(f64, f64)],
    out: &mut [Result<[f64; 3], GeometryError>],
) -> Result<(), GeometryError> {
    if joints_a.len() != joints_b.len() || joints_a.len() != out.len() {
        return Err(GeometryError::Length {
            a: joints_a.len(),
            b: joints_b.len(),
            out: out.len(),
        });
    }
    for ((o, &a), &b) in out.iter_mut().zip(joints_a).zip(joints_b) {
        *o = triangulate(cam_a, a, cam_b, b);
    }
    Ok(())
}

/// `I − n nᵀ`: projects onto the plane orthogonal to the unit vector `n`.
fn projector(n: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::identity() - n * n.transpose()
}

fn all_finite<'a>(mut values: impl Iterator<Item = &'a f64>) -> bool {
    values.all(|v| v.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: u16 = 346;
    const H: u16 = 260;

    /// A pinhole camera at `centre` looking at `target` (world up +Z), focal length `f` px,
    /// principal point at the image centre, in DHP19's convention (`v' = H − v` grows upwards).
    fn look_at(centre: [f64; 3], target: [f64; 3], f: f64) -> Camera {
        let c = Vector3::from(centre);
        let forward = (Vector3::from(target) - c).normalize();
        let right = forward.cross(&Vector3::z()).normalize();
        let up = right.cross(&forward);
        // Camera axes: x right, y up (v' grows upwards), z forward.
        let rot = Matrix3::from_rows(&[right.transpose(), up.transpose(), forward.transpose()]);
        let k = Matrix3::new(
            f,
            0.0,
            f64::from(W) / 2.0,
            0.0,
            f,
            f64::from(H) / 2.0,
            0.0,
            0.0,
            1.0,
        );
        let t = -(rot * c);
        let mut rt = Matrix3x4::zeros();
        rt.fixed_view_mut::<3, 3>(0, 0).copy_from(&rot);
        rt.set_column(3, &t);
        let p = k * rt;
        Camera::new(
            core::array::from_fn(|r| core::array::from_fn(|col| p[(r, col)])),
            centre,
            W,
            H,
        )
        .unwrap()
    }

    /// Two cameras 4 m apart, 3 m from the origin, both aimed at it (like DHP19's front pair).
    fn pair() -> (Camera, Camera) {
        (
            look_at([2000.0, -2500.0, 2000.0], [0.0; 3], 250.0),
            look_at([-2000.0, -2500.0, 2000.0], [0.0; 3], 250.0),
        )
    }

    fn max_abs_diff(x: [f64; 3], y: [f64; 3]) -> f64 {
        (0..3).map(|i| (x[i] - y[i]).abs()).fold(0.0, f64::max)
    }

    #[test]
    fn pseudo_inverse_is_a_right_inverse() {
        let (a, _) = pair();
        let p = Matrix3x4::from_fn(|r, c| a.projection()[r][c]);
        let pinv = Matrix4x3::from_fn(|r, c| a.pseudo_inverse()[r][c]);
        let eye = p * pinv;
        // Round-off bound: a few ε times the condition number (Frobenius norms), ~1e6 here.
        let bound = 16.0 * f64::EPSILON * p.norm() * pinv.norm();
        let err = (eye - Matrix3::identity()).amax();
        assert!(err < bound, "|P P⁺ − I| = {err:e}, bound {bound:e}");
    }

    #[test]
    fn project_then_triangulate_round_trips() {
        let (a, b) = pair();
        let mut worst = 0.0f64;
        let mut seen = 0;
        for i in -5..=5 {
            for j in -5..=5 {
                for k in -5..=5 {
                    let x = [
                        200.0 * f64::from(i),
                        200.0 * f64::from(j),
                        200.0 * f64::from(k),
                    ];
                    let (ja, jb) = (a.project(x).unwrap(), b.project(x).unwrap());
                    if !(a.is_visible(ja) && b.is_visible(jb)) {
                        continue;
                    }
                    seen += 1;
                    let got = triangulate(&a, ja, &b, jb).unwrap();
                    worst = worst.max(max_abs_diff(got, x));
                }
            }
        }
        assert!(seen > 500, "only {seen} points visible in both views");
        // f64 round-off through P⁺ and a 3 × 3 solve at a 1,000 mm scale: ~1e-12 relative.
        assert!(worst < 1e-9, "worst error {worst} mm");
    }

    #[test]
    fn weighted_views_pull_towards_the_surer_ray() {
        let (a, b) = pair();
        let c = look_at([0.0, -3500.0, 1500.0], [0.0; 3], 250.0);
        let x = [150.0, -80.0, 400.0];
        let (ja, jb, jc) = (
            a.project(x).unwrap(),
            b.project(x).unwrap(),
            c.project(x).unwrap(),
        );
        // Exact views: any positive weights, any number of views give the point.
        for views in [
            &[(&a, ja, 1.0), (&b, jb, 1.0)][..],
            &[(&a, ja, 0.2), (&b, jb, 0.9), (&c, jc, 0.5)][..],
        ] {
            assert!(max_abs_diff(triangulate_views(views).unwrap(), x) < 1e-9);
        }
        // Equal weights are `triangulate`, bit for bit, whatever their size (the extremes
        // of f64 included: they overflowed or vanished in the normal equations before the
        // weights were taken relative to the largest).
        let jb_off = (jb.0 + 6.0, jb.1 - 4.0);
        let two = triangulate(&a, ja, &b, jb_off).unwrap();
        for w in [1.0, 0.3, 1e300, f64::MAX, f64::MIN_POSITIVE, 5e-324] {
            assert_eq!(
                triangulate_views(&[(&a, ja, w), (&b, jb_off, w)]).unwrap(),
                two,
                "weight {w}"
            );
        }
        // Scaling every weight by one factor moves nothing (to round-off).
        let scaled = |k: f64| {
            triangulate_views(&[(&a, ja, 0.2 * k), (&b, jb_off, 0.9 * k), (&c, jc, 0.5 * k)])
                .unwrap()
        };
        for k in [1e-300, 1e300, f64::MAX] {
            assert!(max_abs_diff(scaled(k), scaled(1.0)) < 1e-9, "factor {k}");
        }
        // B's point is 7 px off, A's and C's are exact: trusting B less (weight 0.1 against
        // 1) lands far closer (under half the error) to the truth than trusting all three equally, trusting B more
        // lands farther. (With two views only the rays' common perpendicular is weighted.)
        let err = |wb: f64| {
            let p = triangulate_views(&[(&a, ja, 1.0), (&b, jb_off, wb), (&c, jc, 1.0)]).unwrap();
            (0..3).map(|i| (p[i] - x[i]).powi(2)).sum::<f64>().sqrt()
        };
        let (unsure_b, equal, sure_b) = (err(0.1), err(1.0), err(10.0));
        assert!(
            unsure_b < 0.5 * equal && equal < sure_b,
            "{unsure_b} {equal} {sure_b}"
        );
        // A zero weight drops a view; one view left is too few; weights must be finite, ≥ 0.
        assert_eq!(
            triangulate_views(&[(&a, ja, 1.0), (&b, jb_off, 0.0), (&c, jc, 1.0)]).unwrap(),
            triangulate(&a, ja, &c, jc).unwrap()
        );
        assert_eq!(
            triangulate_views(&[(&a, ja, 1.0), (&b, jb, 0.0)]),
            Err(GeometryError::TooFewViews { views: 1 })
        );
        for w in [-1.0, f64::NAN, f64::INFINITY] {
            assert_eq!(
                triangulate_views(&[(&a, ja, 1.0), (&b, jb, w)]),
                Err(GeometryError::NonFinite)
            );
        }
        // The same ray twice is parallel.
        assert_eq!(
            triangulate_views(&[(&a, ja, 1.0), (&a, ja, 1.0)]),
            Err(GeometryError::ParallelRays)
        );
    }

    #[test]
    fn projection_follows_the_dhp19_convention() {
        let (a, _) = pair();
        // The target is on the optical axis: the principal point, (W/2, H − H/2).
        let (u, v) = a.project([0.0; 3]).unwrap();
        assert!(
            (u - 173.0).abs() < 1e-9 && (v - 130.0).abs() < 1e-9,
            "{u} {v}"
        );
        // A point above the target (+Z, world up) has a smaller v (image y grows downwards).
        let (_, v_up) = a.project([0.0, 0.0, 100.0]).unwrap();
        assert!(v_up < v);
        // The back-projected point of a pixel projects back to it.
        let x = a.back_project((40.5, 250.25)).unwrap();
        let (u, v) = a.project(x).unwrap();
        assert!(
            (u - 40.5).abs() < 1e-9 && (v - 250.25).abs() < 1e-9,
            "{u} {v}"
        );
    }

    #[test]
    fn visibility_is_half_open() {
        let (a, _) = pair();
        let (w, h) = (f64::from(W), f64::from(H));
        assert!(a.is_visible((w, h)));
        assert!(a.is_visible((1e-9, 1e-9)));
        assert!(!a.is_visible((0.0, 10.0)));
        assert!(!a.is_visible((10.0, 0.0)));
        assert!(!a.is_visible((w + 1e-9, 10.0)));
        assert!(!a.is_visible((10.0, h + 1e-9)));
        assert!(!a.is_visible((f64::NAN, 10.0)));
    }

    #[test]
    fn points_on_the_principal_plane_do_not_project() {
        let (a, _) = pair();
        // The camera centre itself, and a point beside it in the principal plane.
        let c = a.centre();
        assert_eq!(a.project(c), None);
        let right = Vector3::from(c)
            .cross(&Vector3::z())
            .normalize()
            .scale(500.0);
        assert_eq!(
            a.project([c[0] + right[0], c[1] + right[1], c[2] + right[2]]),
            None
        );
        assert_eq!(a.project([f64::NAN, 0.0, 0.0]), None);
        assert_eq!(a.project([f64::INFINITY, 0.0, 0.0]), None);
    }

    #[test]
    fn bad_cameras_are_errors() {
        let (a, _) = pair();
        let p = a.projection();
        let c = a.centre();
        let mut nan = p;
        nan[1][2] = f64::NAN;
        assert_eq!(Camera::new(nan, c, W, H), Err(GeometryError::NonFinite));
        assert_eq!(
            Camera::new(p, [0.0, f64::INFINITY, 0.0], W, H),
            Err(GeometryError::NonFinite)
        );
        assert_eq!(Camera::new(p, c, 0, H), Err(GeometryError::ImageSize));
        assert_eq!(Camera::new(p, c, W, 0), Err(GeometryError::ImageSize));
        let mut rank2 = p;
        rank2[2] = p[0];
        assert_eq!(
            Camera::new(rank2, c, W, H),
            Err(GeometryError::RankDeficient)
        );
        assert_eq!(
            Camera::new([[0.0; 4]; 3], c, W, H),
            Err(GeometryError::RankDeficient)
        );
        let mut tiny = p;
        tiny[2] = [p[2][0] * 1e-20, p[2][1] * 1e-20, p[2][2] * 1e-20, 0.0];
        assert_eq!(
            Camera::new(tiny, c, W, H),
            Err(GeometryError::RankDeficient)
        );
    }

    #[test]
    fn degenerate_triangulations_are_errors() {
        let (a, b) = pair();
        let j = a.project([100.0, 200.0, 300.0]).unwrap();
        // Non-finite image points.
        for bad in [
            (f64::NAN, 1.0),
            (1.0, f64::INFINITY),
            (f64::NEG_INFINITY, 1.0),
        ] {
            assert_eq!(triangulate(&a, bad, &b, j), Err(GeometryError::NonFinite));
            assert_eq!(triangulate(&a, j, &b, bad), Err(GeometryError::NonFinite));
        }
        // One camera twice: the same ray twice.
        assert_eq!(triangulate(&a, j, &a, j), Err(GeometryError::ParallelRays));
        // Two cameras on one line of sight, the same point: collinear rays.
        let near = look_at([1000.0, -1250.0, 1000.0], [0.0; 3], 250.0);
        let x = [0.0; 3];
        let (ja, jn) = (a.project(x).unwrap(), near.project(x).unwrap());
        assert_eq!(
            triangulate(&a, ja, &near, jn),
            Err(GeometryError::ParallelRays)
        );
        // Pixels far outside the image still triangulate or fail cleanly, never NaN.
        for u in [-1e300, -1e6, 0.0, 1e6, 1e300] {
            for v in [-1e300, -1e6, 0.0, 1e6, 1e300] {
                if let Ok(p) = triangulate(&a, (u, v), &b, j) {
                    assert!(all_finite(p.iter()), "{u} {v}: {p:?}");
                }
            }
        }
    }

    #[test]
    fn a_camera_at_the_origin_back_projects_to_infinity() {
        // P = K [I | 0]: P⁺'s last row is 0, so w = 0 for every pixel (the reference method's
        // blind spot).
        let p = [
            [250.0, 0.0, 173.0, 0.0],
            [0.0, 250.0, 130.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ];
        let origin = Camera::new(p, [0.0; 3], W, H).unwrap();
        let (_, b) = pair();
        assert_eq!(
            origin.back_project((100.0, 100.0)),
            Err(GeometryError::PointAtInfinity)
        );
        assert_eq!(
            triangulate(&origin, (100.0, 100.0), &b, (100.0, 100.0)),
            Err(GeometryError::PointAtInfinity)
        );
    }

    #[test]
    fn a_centre_on_the_back_projected_point_is_a_degenerate_ray() {
        let (a, b) = pair();
        let j = (100.0, 100.0);
        let wrong = Camera::new(a.projection(), a.back_project(j).unwrap(), W, H).unwrap();
        assert_eq!(
            triangulate(&wrong, j, &b, j),
            Err(GeometryError::DegenerateRay)
        );
    }

    #[test]
    fn joints_triangulate_one_by_one() {
        let (a, b) = pair();
        let xs = [
            [0.0, 0.0, 0.0],
            [300.0, -200.0, 500.0],
            [-400.0, 100.0, 900.0],
        ];
        let ja: [(f64, f64); 3] = core::array::from_fn(|i| a.project(xs[i]).unwrap());
        let mut jb: [(f64, f64); 3] = core::array::from_fn(|i| b.project(xs[i]).unwrap());
        jb[1] = (f64::NAN, 0.0);
        let mut out = [Ok([0.0; 3]); 3];
        triangulate_joints(&a, &ja, &b, &jb, &mut out).unwrap();
        assert!(max_abs_diff(out[0].unwrap(), xs[0]) < 1e-9);
        assert_eq!(out[1], Err(GeometryError::NonFinite));
        assert!(max_abs_diff(out[2].unwrap(), xs[2]) < 1e-9);
        let mut short = [Ok([0.0; 3]); 2];
        assert_eq!(
            triangulate_joints(&a, &ja, &b, &jb, &mut short),
            Err(GeometryError::Length { a: 3, b: 3, out: 2 })
        );
        assert_eq!(
            triangulate_joints(&a, &ja[..2], &b, &jb, &mut out),
            Err(GeometryError::Length { a: 2, b: 3, out: 3 })
        );
    }

    #[test]
    fn errors_display() {
        let e = GeometryError::Length {
            a: 13,
            b: 12,
            out: 13,
        };
        assert_eq!(
            e.to_string(),
            "joint counts differ: 13 and 12 joints, 13 output slots"
        );
        assert!(!GeometryError::ParallelRays.to_string().is_empty());
    }
}

//! The subject: a 13-joint skeleton in DHP19's joint order, anthropometric segment lengths, and
//! a volumetric body of capsules and a head sphere posed by forward kinematics.
//!
//! # Frames
//!
//! World units are millimetres in DHP19's Vicon frame: **+Z is up and the floor is `z = 0`**
//! (the four cameras sit about 2 m above it, pitched down 17–30°). A [`Pose`] places the body
//! with a point on the floor under the pelvis ([`Pose::ground`]) and a heading (the direction
//! the subject faces, radians from +X towards +Y). Inside the body, FK works in a local frame
//! with x forward, y to the subject's left and z up, origin at the pelvis centre; the pelvis
//! height is chosen so that the lower ankle stays at ankle height above the floor (plus
//! [`Pose::lift`] for jumps), so squats and steps keep a foot on the ground.
//!
//! # Segments
//!
//! Lengths are fractions of the height `H` (Drillis & Contini / Winter), each jittered
//! uniformly by ±10 % per subject: upper arm 0.186, forearm 0.146, hand 0.108, thigh 0.245,
//! shank 0.246, foot 0.152, shoulder width 0.259, hip width 0.191, shoulder height 0.818, hip
//! height 0.530; head centre 0.117 H above the shoulder line, ankle height 0.039 H. Capsule
//! radii follow MuJoCo's humanoid (for a 1.7 m body), scaled by `H / 1.7 m` and by a
//! per-subject girth factor in `[0.85, 1.25]`.

use crate::rng::{tag, Rng};
use crate::v3::{add, axpy, cross, normalize, scale, V3};

pub use evpose_core::skeleton::{JOINTS, JOINT_NAMES};

/// Index of the head in a joint array.
pub const HEAD: usize = 0;
/// Index of the right shoulder (the left one follows it; likewise for the other pairs).
pub const SHOULDER_R: usize = 1;
/// Index of the right elbow.
pub const ELBOW_R: usize = 3;
/// Index of the right hip.
pub const HIP_R: usize = 5;
/// Index of the right hand.
pub const HAND_R: usize = 7;
/// Index of the right knee.
pub const KNEE_R: usize = 9;
/// Index of the right foot (the ankle).
pub const FOOT_R: usize = 11;

/// Rigid bones `(parent, child)` between joints: their lengths never change for a subject.
pub const BONES: [(usize, usize); 8] = [
    (SHOULDER_R, ELBOW_R),
    (SHOULDER_R + 1, ELBOW_R + 1),
    (ELBOW_R, HAND_R),
    (ELBOW_R + 1, HAND_R + 1),
    (HIP_R, KNEE_R),
    (HIP_R + 1, KNEE_R + 1),
    (KNEE_R, FOOT_R),
    (KNEE_R + 1, FOOT_R + 1),
];

/// Segment lengths of one subject, millimetres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Segments {
    /// Shoulder to elbow.
    pub upper_arm: f64,
    /// Elbow to wrist.
    pub forearm: f64,
    /// Wrist to fingertip (the hand joint sits halfway).
    pub hand: f64,
    /// Hip to knee.
    pub thigh: f64,
    /// Knee to ankle.
    pub shank: f64,
    /// Heel to toe.
    pub foot: f64,
    /// Between the shoulder joints.
    pub shoulder_width: f64,
    /// Between the hip joints.
    pub hip_width: f64,
    /// Pelvis centre to the shoulder line (upright).
    pub torso: f64,
    /// Shoulder line to the head centre.
    pub neck_head: f64,
    /// Ankle above the floor.
    pub ankle_height: f64,
}

/// Greyscale clothing and skin appearance: albedos in `(0, 1)` and a surface texture of bands
/// around each limb plus patches (a hashed checkerboard in surface coordinates).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Clothing {
    /// Skin (face, hands, forearms when `short_sleeves`).
    pub skin: f32,
    /// Hair (top and back of the head).
    pub hair: f32,
    /// Shirt.
    pub top: f32,
    /// Trousers.
    pub bottom: f32,
    /// Shoes.
    pub shoes: f32,
    /// Whether forearms are bare.
    pub short_sleeves: bool,
    /// Period of the bands on the shirt, millimetres.
    pub top_period: f32,
    /// Period of the bands on the trousers, millimetres.
    pub bottom_period: f32,
    /// Relative albedo change of the bands, `[0.15, 0.7]`.
    pub band_contrast: f32,
    /// Relative albedo change of the patches, `[0.15, 0.6]`.
    pub patch_contrast: f32,
}

/// Surface appearance of one primitive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Base albedo in `(0, 1)`.
    pub albedo: f32,
    /// Period of bands along the capsule axis, millimetres (0: none).
    pub band_period: f32,
    /// Relative albedo change of the bands.
    pub band_contrast: f32,
    /// Relative albedo change of the patches.
    pub patch_contrast: f32,
    /// Seed of the patch pattern.
    pub patch_seed: u32,
}

/// A capsule (the points within `radius` of segment `a`–`b`); a sphere when `a == b`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Capsule {
    /// One end of the axis, world mm.
    pub a: [f64; 3],
    /// The other end of the axis, world mm.
    pub b: [f64; 3],
    /// Radius, mm.
    pub radius: f64,
    /// Appearance.
    pub material: Material,
}

/// Range-of-motion limits, degrees, `(min, max)` (AAOS; flexion positive).
pub mod limits {
    /// Trunk forward lean.
    pub const TRUNK_LEAN: (f64, f64) = (-15.0, 60.0);
    /// Shoulder flexion (forward raise; negative is extension).
    pub const SHOULDER_FLEX: (f64, f64) = (-60.0, 180.0);
    /// Shoulder abduction (sideways raise).
    pub const SHOULDER_ABD: (f64, f64) = (-10.0, 180.0);
    /// Humeral rotation of the elbow's bending plane.
    pub const SHOULDER_ROT: (f64, f64) = (-90.0, 90.0);
    /// Elbow flexion.
    pub const ELBOW: (f64, f64) = (0.0, 150.0);
    /// Hip flexion (negative is extension).
    pub const HIP_FLEX: (f64, f64) = (-30.0, 120.0);
    /// Hip abduction.
    pub const HIP_ABD: (f64, f64) = (-15.0, 45.0);
    /// Knee flexion.
    pub const KNEE: (f64, f64) = (0.0, 130.0);
}

/// Joint angles, radians; arrays are `[right, left]`.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Angles {
    /// Trunk forward lean.
    pub trunk_lean: f64,
    /// Shoulder flexion.
    pub shoulder_flex: [f64; 2],
    /// Shoulder abduction.
    pub shoulder_abd: [f64; 2],
    /// Humeral rotation: turns the elbow's bending plane about the upper arm (positive lifts
    /// the forearm of an abducted arm).
    pub shoulder_rot: [f64; 2],
    /// Elbow flexion.
    pub elbow: [f64; 2],
    /// Hip flexion.
    pub hip_flex: [f64; 2],
    /// Hip abduction.
    pub hip_abd: [f64; 2],
    /// Knee flexion.
    pub knee: [f64; 2],
}

impl Angles {
    /// Relaxed standing: arms hanging slightly away from the body, elbows a little bent.
    pub fn neutral() -> Self {
        let d = f64::to_radians;
        Self {
            trunk_lean: d(2.0),
            shoulder_flex: [d(3.0); 2],
            shoulder_abd: [d(8.0); 2],
            shoulder_rot: [0.0; 2],
            elbow: [d(12.0); 2],
            hip_flex: [d(2.0); 2],
            hip_abd: [d(3.0); 2],
            knee: [d(3.0); 2],
        }
    }

    /// Every angle with its name and limits (degrees), for checks.
    pub fn named(&self) -> Vec<(&'static str, f64, (f64, f64))> {
        use limits::*;
        let mut v = vec![("trunk_lean", self.trunk_lean.to_degrees(), TRUNK_LEAN)];
        for s in 0..2 {
            v.push((
                "shoulder_flex",
                self.shoulder_flex[s].to_degrees(),
                SHOULDER_FLEX,
            ));
            v.push((
                "shoulder_abd",
                self.shoulder_abd[s].to_degrees(),
                SHOULDER_ABD,
            ));
            v.push((
                "shoulder_rot",
                self.shoulder_rot[s].to_degrees(),
                SHOULDER_ROT,
            ));
            v.push(("elbow", self.elbow[s].to_degrees(), ELBOW));
            v.push(("hip_flex", self.hip_flex[s].to_degrees(), HIP_FLEX));
            v.push(("hip_abd", self.hip_abd[s].to_degrees(), HIP_ABD));
            v.push(("knee", self.knee[s].to_degrees(), KNEE));
        }
        v
    }

    /// The first angle outside its limits (name, degrees), if any.
    pub fn violation(&self) -> Option<(&'static str, f64)> {
        self.named()
            .into_iter()
            .find(|&(_, a, (lo, hi))| !(lo - 1e-9..=hi + 1e-9).contains(&a))
            .map(|(n, a, _)| (n, a))
    }
}

/// A body pose: where, which way and how.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Floor point under the pelvis, world mm (`z` is ignored: the floor is `z = 0`).
    pub ground: [f64; 3],
    /// Facing direction, radians from +X towards +Y.
    pub heading: f64,
    /// Height of the lower ankle above its resting height, mm (jumps, hops).
    pub lift: f64,
    /// Joint angles.
    pub angles: Angles,
}

/// One simulated person.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Subject {
    /// The seed it was drawn from.
    pub seed: u64,
    /// Its index under that seed.
    pub index: u32,
    /// Standing height, mm, in `[1500, 1950]`.
    pub height: f64,
    /// Segment lengths, mm.
    pub segments: Segments,
    /// Girth factor scaling every capsule radius, `[0.85, 1.25]`.
    pub girth: f64,
    /// Appearance.
    pub clothing: Clothing,
}

/// Side sign in the body frame: right is −y, left is +y.
const SIDE: [f64; 2] = [-1.0, 1.0];

/// Direction of a limb from flexion `f` (towards +x) and abduction `a` (towards side `s`),
/// from hanging straight down: `(sin f, s·cos f·sin a, −cos f·cos a)`.
fn limb_dir(f: f64, a: f64, s: f64) -> V3 {
    [f.sin(), s * f.cos() * a.sin(), -f.cos() * a.cos()]
}

/// The same two rotations applied to the bending direction `p0` (in the x–z plane).
fn bend_dir(f: f64, a: f64, s: f64, p0x: f64) -> V3 {
    // flexion: x' = x cos f − z sin f, z' = x sin f + z cos f (z = 0 here)
    let (x, z) = (p0x * f.cos(), p0x * f.sin());
    // abduction: y' = −s z sin a, z' = z cos a
    [x, -s * z * a.sin(), z * a.cos()]
}

impl Subject {
    /// The subject `index` of `seed`, drawn deterministically. Distinct `(seed, index)` pairs
    /// use distinct random streams (the stream selector is injective in both), so two seeds
    /// never share a subject; the subject's identity is the pair itself.
    pub fn from_seed(seed: u64, index: u32) -> Self {
        let mut r = Rng::new(seed, index, tag::SUBJECT, 0);
        let height = r.uniform(1500.0, 1950.0);
        let mut seg = |frac: f64| frac * height * r.uniform(0.9, 1.1);
        let segments = Segments {
            upper_arm: seg(0.186),
            forearm: seg(0.146),
            hand: seg(0.108),
            thigh: seg(0.245),
            shank: seg(0.246),
            foot: seg(0.152),
            shoulder_width: seg(0.259),
            hip_width: seg(0.191),
            torso: seg(0.818 - 0.530),
            neck_head: seg(0.117),
            ankle_height: seg(0.039),
        };
        let girth = r.uniform(0.85, 1.25);
        let mut albedo = |lo: f64, hi: f64| r.uniform(lo, hi) as f32;
        let clothing = Clothing {
            skin: albedo(0.15, 0.7),
            hair: albedo(0.03, 0.6),
            top: albedo(0.04, 0.9),
            bottom: albedo(0.04, 0.8),
            shoes: albedo(0.04, 0.9),
            short_sleeves: r.coin(),
            top_period: r.uniform(20.0, 120.0) as f32,
            bottom_period: r.uniform(30.0, 200.0) as f32,
            band_contrast: r.uniform(0.15, 0.7) as f32,
            patch_contrast: r.uniform(0.15, 0.6) as f32,
        };
        Self {
            seed,
            index,
            height,
            segments,
            girth,
            clothing,
        }
    }

    /// Body-local positions (x forward, y left, z up; pelvis centre at the origin) of the 13
    /// joints plus the wrists, the feet's toe direction and the neck base.
    #[allow(clippy::needless_range_loop)] // several parallel arrays share the index
    fn local(&self, a: &Angles) -> Local {
        let s = &self.segments;
        let (sl, cl) = a.trunk_lean.sin_cos();
        let up = [sl, 0.0, cl];
        let fwd = [cl, 0.0, -sl];
        let left = [0.0, 1.0, 0.0];
        let torso = |v: V3| add(add(scale(fwd, v[0]), scale(left, v[1])), scale(up, v[2]));
        let neck = scale(up, s.torso);
        let mut j = [[0.0; 3]; JOINTS];
        j[HEAD] = axpy(neck, up, s.neck_head);
        let mut wrist = [[0.0; 3]; 2];
        let mut toe_dir = [[0.0; 3]; 2];
        let mut hand_dir = [[0.0; 3]; 2];
        for side in 0..2 {
            let sg = SIDE[side];
            let sh = axpy(neck, left, sg * s.shoulder_width / 2.0);
            let (f, ab, rot) = (
                a.shoulder_flex[side],
                a.shoulder_abd[side],
                a.shoulder_rot[side],
            );
            let d = limb_dir(f, ab, sg);
            let p = bend_dir(f, ab, sg, 1.0);
            // Humeral rotation about d: p' = p cos ψ − s (d × p) sin ψ.
            let p = normalize(axpy(scale(p, rot.cos()), cross(d, p), -sg * rot.sin()));
            let (se, ce) = a.elbow[side].sin_cos();
            let fore = add(scale(d, ce), scale(p, se));
            let (d, fore) = (torso(d), torso(fore));
            let elbow = axpy(sh, d, s.upper_arm);
            let w = axpy(elbow, fore, s.forearm);
            j[SHOULDER_R + side] = sh;
            j[ELBOW_R + side] = elbow;
            j[HAND_R + side] = axpy(w, fore, 0.5 * s.hand);
            wrist[side] = w;
            hand_dir[side] = fore;

            let hip = [0.0, sg * s.hip_width / 2.0, 0.0];
            let (f, ab) = (a.hip_flex[side], a.hip_abd[side]);
            let d = limb_dir(f, ab, sg);
            let p = bend_dir(f, ab, sg, -1.0);
            let (sk, ck) = a.knee[side].sin_cos();
            let shank = add(scale(d, ck), scale(p, sk));
            let q = add(scale(d, -sk), scale(p, ck)); // further along the bend: backwards
            let knee = axpy(hip, d, s.thigh);
            j[HIP_R + side] = hip;
            j[KNEE_R + side] = knee;
            j[FOOT_R + side] = axpy(knee, shank, s.shank);
            toe_dir[side] = scale(q, -1.0);
        }
        Local {
            joints: j,
            wrist,
            hand_dir,
            toe_dir,
            neck,
            up,
        }
    }

    /// Maps body-local points to the world for `pose`.
    fn placer(&self, pose: &Pose, local: &Local) -> impl Fn(V3) -> V3 {
        let min_ankle = local.joints[FOOT_R][2].min(local.joints[FOOT_R + 1][2]);
        let pelvis_z = self.segments.ankle_height - min_ankle + pose.lift;
        let (sh, ch) = pose.heading.sin_cos();
        let g = pose.ground;
        move |v: V3| {
            [
                g[0] + ch * v[0] - sh * v[1],
                g[1] + sh * v[0] + ch * v[1],
                pelvis_z + v[2],
            ]
        }
    }

    /// The 13 joints of `pose`, world mm, in DHP19 order.
    pub fn joints(&self, pose: &Pose) -> [[f64; 3]; JOINTS] {
        let local = self.local(&pose.angles);
        let place = self.placer(pose, &local);
        local.joints.map(place)
    }

    /// The body as capsules for `pose`, world mm: torso (two), chest, pelvis, neck, head
    /// sphere, upper arms, forearms, hands, thighs, shanks, feet.
    pub fn capsules(&self, pose: &Pose) -> Vec<Capsule> {
        let local = self.local(&pose.angles);
        let place = self.placer(pose, &local);
        let j = local.joints.map(&place);
        let k = self.height / 1700.0 * self.girth;
        let c = &self.clothing;
        let key = (self.seed as u32) ^ self.index.wrapping_mul(0x9e37_79b9);
        let mat = |albedo: f32, period: f32, band: f32, patch: f32, n: u32| Material {
            albedo,
            band_period: period,
            band_contrast: band,
            patch_contrast: patch,
            patch_seed: key.wrapping_add(n.wrapping_mul(0x85eb_ca6b)),
        };
        let top = mat(c.top, c.top_period, c.band_contrast, c.patch_contrast, 1);
        let bottom = mat(
            c.bottom,
            c.bottom_period,
            c.band_contrast * 0.7,
            c.patch_contrast,
            2,
        );
        let skin = mat(c.skin, 0.0, 0.0, 0.1, 3);
        let hair = mat(c.hair, 0.0, 0.0, 0.6, 4);
        let shoes = mat(c.shoes, 0.0, 0.0, 0.2, 5);
        let arm_lower = if c.short_sleeves { skin } else { top };
        let cap = |a: V3, b: V3, r: f64, m: Material| Capsule {
            a,
            b,
            radius: r * k,
            material: m,
        };
        let neck = place(local.neck);
        let up = local.up;
        let s = &self.segments;
        let mut v = Vec::with_capacity(20);
        // Torso: two vertical capsules from the hips to below the shoulders, a chest bar.
        for (side, sg) in SIDE.into_iter().enumerate() {
            let hip_in = axpy(local.joints[HIP_R + side], up, 0.25 * s.torso);
            let sh_in = axpy(
                axpy(
                    local.joints[SHOULDER_R + side],
                    [0.0, 1.0, 0.0],
                    -sg * 0.35 * s.shoulder_width / 2.0,
                ),
                up,
                -0.12 * s.torso,
            );
            v.push(cap(place(hip_in), place(sh_in), 80.0, top));
        }
        v.push(cap(
            place(axpy(local.joints[SHOULDER_R], up, -0.12 * s.torso)),
            place(axpy(local.joints[SHOULDER_R + 1], up, -0.12 * s.torso)),
            70.0,
            top,
        ));
        v.push(cap(j[HIP_R], j[HIP_R + 1], 90.0, bottom));
        v.push(cap(
            neck,
            place(axpy(local.neck, up, 0.45 * s.neck_head)),
            45.0,
            skin,
        ));
        v.push(cap(
            j[HEAD],
            place(axpy(local.joints[HEAD], up, 25.0)),
            90.0,
            hair,
        ));
        for side in 0..2 {
            v.push(cap(j[SHOULDER_R + side], j[ELBOW_R + side], 45.0, top));
            let w = place(local.wrist[side]);
            v.push(cap(j[ELBOW_R + side], w, 35.0, arm_lower));
            let tip = place(axpy(local.wrist[side], local.hand_dir[side], 0.75 * s.hand));
            v.push(cap(w, tip, 33.0, skin));
            v.push(cap(j[HIP_R + side], j[KNEE_R + side], 65.0, bottom));
            v.push(cap(j[KNEE_R + side], j[FOOT_R + side], 50.0, bottom));
            let ankle = local.joints[FOOT_R + side];
            let sole = axpy(ankle, [0.0, 0.0, 1.0], -0.3 * s.ankle_height);
            let heel = axpy(sole, local.toe_dir[side], -0.15 * s.foot);
            let toe = axpy(sole, local.toe_dir[side], 0.65 * s.foot);
            v.push(cap(place(heel), place(toe), 38.0, shoes));
        }
        v
    }
}

/// FK output in the body frame.
struct Local {
    joints: [V3; JOINTS],
    wrist: [V3; 2],
    hand_dir: [V3; 2],
    toe_dir: [V3; 2],
    neck: V3,
    up: V3,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::v3::dist;

    fn pose(a: Angles) -> Pose {
        Pose {
            ground: [100.0, -50.0, 0.0],
            heading: 0.7,
            lift: 0.0,
            angles: a,
        }
    }

    #[test]
    fn neutral_pose_is_upright_and_proportioned() {
        let s = Subject::from_seed(3, 1);
        let j = s.joints(&pose(Angles::neutral()));
        assert!(j[HEAD][2] > j[SHOULDER_R][2] && j[SHOULDER_R][2] > j[HIP_R][2]);
        assert!(j[HIP_R][2] > j[KNEE_R][2] && j[KNEE_R][2] > j[FOOT_R][2]);
        assert!(j[HAND_R][2] < j[ELBOW_R][2]);
        let head_h = j[HEAD][2];
        assert!(
            (0.8 * s.height..s.height).contains(&head_h),
            "head at {head_h}, height {}",
            s.height
        );
        // Right is to the subject's right: heading 0.7 rad, right = heading − 90°.
        let right = [
            (0.7f64 - core::f64::consts::FRAC_PI_2).cos(),
            (0.7f64 - core::f64::consts::FRAC_PI_2).sin(),
        ];
        let d = [
            j[SHOULDER_R][0] - j[SHOULDER_R + 1][0],
            j[SHOULDER_R][1] - j[SHOULDER_R + 1][1],
        ];
        assert!(d[0] * right[0] + d[1] * right[1] > 0.0);
    }

    #[test]
    fn arm_raises_go_where_named() {
        let s = Subject::from_seed(1, 0);
        let mut a = Angles::neutral();
        a.shoulder_flex[1] = 90f64.to_radians();
        a.elbow[1] = 0.0;
        let mut p = pose(a);
        p.heading = 0.0;
        let j = s.joints(&p);
        // Left arm straight forward (+x), at shoulder height.
        assert!(
            j[HAND_R + 1][0] - j[SHOULDER_R + 1][0]
                > 0.9 * (s.segments.upper_arm + s.segments.forearm)
        );
        assert!((j[HAND_R + 1][2] - j[SHOULDER_R + 1][2]).abs() < 30.0);
        a.shoulder_flex[1] = 0.0;
        a.shoulder_abd[1] = 90f64.to_radians();
        p.angles = a;
        let j = s.joints(&p);
        assert!(
            j[HAND_R + 1][1] - j[SHOULDER_R + 1][1]
                > 0.9 * (s.segments.upper_arm + s.segments.forearm)
        );
    }

    #[test]
    fn bones_are_rigid_and_feet_stay_on_the_floor() {
        let s = Subject::from_seed(9, 4);
        let base = s.joints(&pose(Angles::neutral()));
        let mut a = Angles::neutral();
        a.hip_flex = [1.5, 0.2];
        a.knee = [2.0, 0.1];
        a.elbow = [2.5, 0.0];
        a.shoulder_abd = [2.0, 0.5];
        a.shoulder_rot = [1.0, -1.0];
        a.trunk_lean = 0.5;
        let j = s.joints(&pose(a));
        for (p, c) in BONES {
            assert!((dist(j[p], j[c]) - dist(base[p], base[c])).abs() < 1e-6);
        }
        let ankle = j[FOOT_R][2].min(j[FOOT_R + 1][2]);
        assert!((ankle - s.segments.ankle_height).abs() < 1e-9);
        assert_eq!(s.capsules(&pose(a)).len(), 18);
    }

    #[test]
    fn subjects_differ_and_repeat() {
        let a = Subject::from_seed(1, 0);
        assert_eq!(a, Subject::from_seed(1, 0));
        assert_ne!(a.height, Subject::from_seed(1, 1).height);
        assert_ne!(a.height, Subject::from_seed(2, 0).height);
        for i in 0..50 {
            let s = Subject::from_seed(i, i as u32);
            assert!((1500.0..1950.0).contains(&s.height));
            assert!((0.85..1.25).contains(&s.girth));
        }
    }
}

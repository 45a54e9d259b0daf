//! Parametric versions of DHP19's 33 movements, plus a scene without a person.
//!
//! Every recording draws a [`Motion`] from its own random stream: a tempo (frequency `f`), an
//! amplitude factor `A ∈ [0.75, 1]`, a placement within 250 mm of the stage centre (the floor
//! point under the cameras' common fixation point, [`Stage`]) and a heading within ±25° of the
//! direction towards the front cameras (channels 2 and 3). The subject stands still for an
//! onset of 0.1–0.4 s, ramps into the movement with a smoothstep envelope `e(t)` over
//! 0.25–0.6 s, and ramps back to rest before the end (rest 0.1–0.4 s). Joint angles are
//! `neutral + e·shape(φ)` with phase `φ = 2π f (t − onset)`; `w = (1 − cos φ)/2` rises from 0
//! to 1 and back once per cycle; `b(τ; a, c)` is a `sin²` bump on `τ ∈ [a, c]` of a cycle.
//! All angles stay inside the AAOS ranges of [`crate::body::limits`].
//!
//! | movement | f (Hz) | shape (degrees; `s` = the named side) |
//! |---|---|---|
//! | `arm-abduction-{left,right}` | 0.3–0.6 | shoulder abduction 8 → 160·A·w |
//! | `leg-abduction-{left,right}` | 0.3–0.6 | hip abduction 3 → 40·A·w |
//! | `bicep-curl-{left,right}` | 0.4–0.9 | elbow 12 → 140·A·w, shoulder flexion 10 |
//! | `knee-lift-{left,right}` | 0.3–0.7 | hip flexion → 100·A·w, knee → 100·A·w |
//! | `walk-in-place` | 0.7–1.1 | per leg `l = max(0, sin(φ + side·π))`: hip 55·A·l, knee 70·A·l; counter-swinging arms ±25·A |
//! | `single-jump` | 1/(1.6–2.4) | crouch `b(τ;0,.35)+b(τ;.5,.8)`: knee 80·A, hip 70·A, lean 30; flight `b(τ;.3,.55)`: lift 150–300 mm, arms up 120 |
//! | `jump-forward` | 1/(1.6–2.4) | as `single-jump`, ground moves 250–450 mm forward in flight and steps back at τ ∈ [.75, 1] |
//! | `multiple-jumps` | 1.1–1.6 | as `single-jump`, continuous |
//! | `hop-{left,right}` | 1.4–2 | other leg held (hip 35, knee 80); stance knee 25·crouch; lift 60–150 mm |
//! | `punch-forward-{left,right}` | 0.6–1.3 | guard (flex 25, elbow 120) → flex 90·A, elbow 5, pulse `w` |
//! | `punch-up-{left,right}` | 0.5–1.1 | guard → flex 165·A, elbow 5 |
//! | `punch-down-{left,right}` | 0.6–1.2 | guard → flex 10, elbow 5, lean 20·w |
//! | `wave-{left,right}` | 1.5–3 | arm raised (abd 100·A, flex 20, rotation 75), elbow 60 ± 30·sin φ |
//! | `circle-hand-{left,right}` | 0.5–1 | flex 80 + 40·A·cos φ, abd 35 + 28·A·(±sin φ) (left clockwise, right counter-clockwise) |
//! | `figure-8-{left,right}` | 0.4–0.8 | flex 80 + 35·A·sin 2φ, abd 35 + 28·A·sin φ |
//! | `run-in-place` | 1.3–1.9 | per leg as walking, hip 70·A, knee 110·A; elbows 80; bounce 30·A mm |
//! | `jumping-jacks` | 0.8–1.2 | arms abd 8 → 160·A·w, hips abd 3 → 30·A·w, lift 50·A·sin² φ mm |
//! | `squats` | 0.3–0.6 | hip 100·A·w, knee 110·A·w, lean 35·w, arms forward 80·w |
//! | `kick-forward` | 0.5–0.8 | legs alternate per cycle: hip 85·A·w, knee 60·4w(1−w) |
//! | `side-kick` | 0.5–0.8 | legs alternate per cycle: hip abd 42·A·w, knee 40·4w(1−w), lean 10·w |
//! | `boxing` | 0.8–1.5 | both guard; punches forward alternate (`max(0, ±sin φ)²`), bounce 15 mm |
//! | `arm-circles` | 0.6–1.2 | both arms abd 90 + 25·A·cos φ, flex 25·A·sin φ |
//! | `no-person` | — | no body: 1–3 bouncing balls (r 60–180 mm, 0.8–3 m/s) and a spinning stick cross the stage |

use core::fmt;
use core::str::FromStr;

use evpose_core::geometry::Camera;

use crate::body::{Angles, Capsule, Material, Pose};
use crate::rng::{smoothstep, tag, Rng};
use crate::v3::{add, axpy, normalize, scale, sub, V3};

macro_rules! movements {
    ($($variant:ident => $name:literal,)*) => {
        /// A movement of DHP19's protocol (33 of them) or a scene without a person.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        pub enum Movement {
            $(
                #[doc = concat!("`", $name, "`")]
                $variant,
            )*
        }

        impl Movement {
            /// Every movement, in DHP19's session order, `NoPerson` last.
            pub const ALL: &'static [Movement] = &[$(Movement::$variant,)*];

            /// The kebab-case name (what [`FromStr`] parses).
            pub fn name(self) -> &'static str {
                match self {
                    $(Movement::$variant => $name,)*
                }
            }
        }
    };
}

movements! {
    ArmAbductionLeft => "arm-abduction-left",
    ArmAbductionRight => "arm-abduction-right",
    LegAbductionLeft => "leg-abduction-left",
    LegAbductionRight => "leg-abduction-right",
    BicepCurlLeft => "bicep-curl-left",
    BicepCurlRight => "bicep-curl-right",
    KneeLiftLeft => "knee-lift-left",
    KneeLiftRight => "knee-lift-right",
    WalkInPlace => "walk-in-place",
    SingleJump => "single-jump",
    JumpForward => "jump-forward",
    MultipleJumps => "multiple-jumps",
    HopLeft => "hop-left",
    HopRight => "hop-right",
    PunchForwardLeft => "punch-forward-left",
    PunchForwardRight => "punch-forward-right",
    PunchUpLeft => "punch-up-left",
    PunchUpRight => "punch-up-right",
    PunchDownLeft => "punch-down-left",
    PunchDownRight => "punch-down-right",
    WaveLeft => "wave-left",
    WaveRight => "wave-right",
    CircleHandLeft => "circle-hand-left",
    CircleHandRight => "circle-hand-right",
    Figure8Left => "figure-8-left",
    Figure8Right => "figure-8-right",
    RunInPlace => "run-in-place",
    JumpingJacks => "jumping-jacks",
    Squats => "squats",
    KickForward => "kick-forward",
    SideKick => "side-kick",
    Boxing => "boxing",
    ArmCircles => "arm-circles",
    NoPerson => "no-person",
}

impl fmt::Display for Movement {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A name that is no movement's.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UnknownMovement(pub String);

impl fmt::Display for UnknownMovement {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "unknown movement {:?}; known: ", self.0)?;
        for (i, m) in Movement::ALL.iter().enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            f.write_str(m.name())?;
        }
        Ok(())
    }
}

impl std::error::Error for UnknownMovement {}

impl FromStr for Movement {
    type Err = UnknownMovement;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Movement::ALL
            .iter()
            .copied()
            .find(|m| m.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| UnknownMovement(s.to_string()))
    }
}

impl Movement {
    /// Position in [`Movement::ALL`].
    pub fn index(self) -> u16 {
        Movement::ALL.iter().position(|&m| m == self).unwrap_or(0) as u16
    }

    /// The side a one-sided movement uses: 0 right, 1 left, `None` for both or none.
    fn side(self) -> Option<usize> {
        let n = self.name();
        if n.ends_with("-right") {
            Some(0)
        } else if n.ends_with("-left") {
            Some(1)
        } else {
            None
        }
    }

    /// Tempo range, Hz.
    fn tempo(self) -> (f64, f64) {
        use Movement::*;
        match self {
            ArmAbductionLeft | ArmAbductionRight | LegAbductionLeft | LegAbductionRight => {
                (0.3, 0.6)
            }
            BicepCurlLeft | BicepCurlRight => (0.4, 0.9),
            KneeLiftLeft | KneeLiftRight => (0.3, 0.7),
            WalkInPlace => (0.7, 1.1),
            SingleJump | JumpForward => (1.0 / 2.4, 1.0 / 1.6),
            MultipleJumps => (1.1, 1.6),
            HopLeft | HopRight => (1.4, 2.0),
            PunchForwardLeft | PunchForwardRight => (0.6, 1.3),
            PunchUpLeft | PunchUpRight => (0.5, 1.1),
            PunchDownLeft | PunchDownRight => (0.6, 1.2),
            WaveLeft | WaveRight => (1.5, 3.0),
            CircleHandLeft | CircleHandRight => (0.5, 1.0),
            Figure8Left | Figure8Right => (0.4, 0.8),
            RunInPlace => (1.3, 1.9),
            JumpingJacks => (0.8, 1.2),
            Squats => (0.3, 0.6),
            KickForward | SideKick => (0.5, 0.8),
            Boxing => (0.8, 1.5),
            ArmCircles => (0.6, 1.2),
            NoPerson => (1.0, 1.0),
        }
    }
}

/// Where the cameras look: the floor point under their common fixation point and the
/// direction a subject faces to look at the front cameras.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stage {
    /// Floor point (`z = 0`) under the least-squares intersection of the cameras' central
    /// rays, world mm.
    pub centre: [f64; 3],
    /// Height of that intersection above the floor, mm (about 0.8–1 m for DHP19).
    pub fixation_height: f64,
    /// Heading (radians from +X towards +Y) from the centre towards the midpoint of cameras 2
    /// and 3 (DHP19's front pair).
    pub facing: f64,
}

impl Stage {
    /// Derives the stage from the four cameras (DHP19 channel order). For DHP19 the central
    /// rays meet about 0.8 m above the floor near the Vicon origin, and the front cameras stand
    /// towards −Y.
    pub fn from_cameras(cameras: &[Camera; 4]) -> Self {
        // Least squares: Σ (I − d dᵀ) x = Σ (I − d dᵀ) c.
        let mut a = [[0.0; 3]; 3];
        let mut b = [0.0; 3];
        for cam in cameras {
            let c = cam.centre();
            let centre_px = (f64::from(cam.width()) / 2.0, f64::from(cam.height()) / 2.0);
            let Ok(p) = cam.back_project(centre_px) else {
                continue;
            };
            let d = normalize(sub(p, c));
            for r in 0..3 {
                for k in 0..3 {
                    let m = f64::from(u8::from(r == k)) - d[r] * d[k];
                    a[r][k] += m;
                    b[r] += m * c[k];
                }
            }
        }
        let x = solve3(a, b).unwrap_or([0.0, 0.0, 900.0]);
        let front = scale(add(cameras[2].centre(), cameras[3].centre()), 0.5);
        Self {
            centre: [x[0], x[1], 0.0],
            fixation_height: x[2],
            facing: (front[1] - x[1]).atan2(front[0] - x[0]),
        }
    }
}

/// Solves a 3 × 3 system by Cramer's rule; `None` when singular.
fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    if d.abs() < 1e-12 {
        return None;
    }
    Some(core::array::from_fn(|i| {
        let mut m = a;
        for r in 0..3 {
            m[r][i] = b[r];
        }
        det(m) / d
    }))
}

/// One moving object of a [`Movement::NoPerson`] scene.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Object {
    start: V3,
    velocity: V3,
    radius: f64,
    bounce_height: f64,
    bounce_hz: f64,
    /// Half length of a stick (0: a ball).
    half_length: f64,
    spin_hz: f64,
    period: f64,
    material: Material,
}

/// A movement with its per-recording parameters: evaluate it at any time.
#[derive(Clone, Debug, PartialEq)]
pub struct Motion {
    /// The movement.
    pub movement: Movement,
    /// Tempo, Hz.
    pub frequency: f64,
    /// Amplitude factor in `[0.75, 1]`.
    pub amplitude: f64,
    /// Floor point under the pelvis at rest, world mm.
    pub ground: [f64; 3],
    /// Facing direction, radians from +X towards +Y.
    pub heading: f64,
    /// Rest before the movement starts, s.
    pub onset: f64,
    /// Duration of the smoothstep ramps in and out, s.
    pub ramp: f64,
    /// Rest after the movement ends, s.
    pub rest: f64,
    /// Recording length, s.
    pub seconds: f64,
    /// Jump height or hop height, mm.
    jump: f64,
    /// Jump distance (jump-forward), mm.
    reach: f64,
    objects: Vec<Object>,
}

impl Motion {
    /// Draws the parameters of `movement` for the recording `(seed, subject)` of `seconds`.
    pub fn sample(
        movement: Movement,
        seed: u64,
        subject: u32,
        stage: &Stage,
        seconds: f64,
    ) -> Self {
        let mut r = Rng::new(seed, subject, tag::MOTION, movement.index() << 8);
        let (lo, hi) = movement.tempo();
        let frequency = r.uniform(lo, hi);
        let amplitude = r.uniform(0.75, 1.0);
        let dist = 250.0 * r.unit().sqrt();
        let ang = r.uniform(0.0, core::f64::consts::TAU);
        let ground = [
            stage.centre[0] + dist * ang.cos(),
            stage.centre[1] + dist * ang.sin(),
            0.0,
        ];
        let heading = stage.facing + r.uniform(-25.0, 25.0).to_radians();
        let onset = r.uniform(0.1, 0.4);
        let ramp = r.uniform(0.25, 0.6);
        let rest = r.uniform(0.1, 0.4);
        let jump = match movement {
            Movement::HopLeft | Movement::HopRight => r.uniform(60.0, 150.0),
            _ => r.uniform(150.0, 300.0),
        };
        let reach = r.uniform(250.0, 450.0);
        let mut objects = Vec::new();
        if movement == Movement::NoPerson {
            let n = 1 + r.below(3) as usize;
            for i in 0..=n {
                let stick = i == n;
                let dir_ang = r.uniform(0.0, core::f64::consts::TAU);
                let speed = r.uniform(800.0, 3000.0);
                let dir = [dir_ang.cos(), dir_ang.sin(), 0.0];
                let span = 3000.0;
                let radius = if stick {
                    r.uniform(25.0, 60.0)
                } else {
                    r.uniform(60.0, 180.0)
                };
                let z0 = if stick {
                    r.uniform(500.0, 1600.0)
                } else {
                    radius
                };
                let start = add(
                    axpy(stage.centre, dir, -span / 2.0 + r.uniform(-300.0, 300.0)),
                    [0.0, 0.0, z0],
                );
                objects.push(Object {
                    start: axpy(start, [-dir[1], dir[0], 0.0], r.uniform(-400.0, 400.0)),
                    velocity: scale(dir, speed),
                    radius,
                    bounce_height: if stick { 0.0 } else { r.uniform(0.0, 900.0) },
                    bounce_hz: r.uniform(0.8, 2.5),
                    half_length: if stick { r.uniform(150.0, 400.0) } else { 0.0 },
                    spin_hz: r.uniform(0.3, 2.0),
                    period: span / speed + r.uniform(0.0, 1.0),
                    material: Material {
                        albedo: r.uniform(0.05, 0.9) as f32,
                        band_period: r.uniform(30.0, 120.0) as f32,
                        band_contrast: r.uniform(0.0, 0.6) as f32,
                        patch_contrast: r.uniform(0.1, 0.6) as f32,
                        patch_seed: r.below(1 << 32) as u32,
                    },
                });
            }
        }
        Self {
            movement,
            frequency,
            amplitude,
            ground,
            heading,
            onset,
            ramp,
            rest,
            seconds,
            jump,
            reach,
            objects,
        }
    }

    /// The movement envelope `e(t)` in `[0, 1]`.
    pub fn envelope(&self, t: f64) -> f64 {
        smoothstep((t - self.onset) / self.ramp)
            * smoothstep((self.seconds - self.rest - t) / self.ramp)
    }

    /// The body pose at `t` seconds; `None` for [`Movement::NoPerson`].
    pub fn pose(&self, t: f64) -> Option<Pose> {
        use Movement::*;
        if self.movement == NoPerson {
            return None;
        }
        let d = f64::to_radians;
        let e = self.envelope(t);
        let a_ = self.amplitude;
        let phi = core::f64::consts::TAU * self.frequency * (t - self.onset).max(0.0);
        let w = (1.0 - phi.cos()) / 2.0;
        let tau = (phi / core::f64::consts::TAU).fract();
        let cycle = (phi / core::f64::consts::TAU).floor() as i64;
        let bump = |a: f64, c: f64| {
            if tau > a && tau < c {
                (core::f64::consts::PI * (tau - a) / (c - a)).sin().powi(2)
            } else {
                0.0
            }
        };
        let lerp = |from: f64, to: f64, k: f64| from + (to - from) * k;
        let n = Angles::neutral();
        let mut a = n;
        let mut lift = 0.0;
        let mut forward = 0.0;
        let side = self.movement.side().unwrap_or(0);
        let guard = |a: &mut Angles, s: usize, k: f64| {
            a.shoulder_flex[s] = lerp(n.shoulder_flex[s], d(25.0), k);
            a.shoulder_abd[s] = lerp(n.shoulder_abd[s], d(12.0), k);
            a.elbow[s] = lerp(n.elbow[s], d(120.0), k);
        };
        match self.movement {
            ArmAbductionLeft | ArmAbductionRight => {
                a.shoulder_abd[side] = lerp(n.shoulder_abd[side], d(160.0 * a_), e * w);
            }
            LegAbductionLeft | LegAbductionRight => {
                a.hip_abd[side] = lerp(n.hip_abd[side], d(40.0 * a_), e * w);
            }
            BicepCurlLeft | BicepCurlRight => {
                a.shoulder_flex[side] = lerp(n.shoulder_flex[side], d(10.0), e);
                a.elbow[side] = lerp(n.elbow[side], d(140.0 * a_), e * w);
            }
            KneeLiftLeft | KneeLiftRight => {
                a.hip_flex[side] = lerp(n.hip_flex[side], d(100.0 * a_), e * w);
                a.knee[side] = lerp(n.knee[side], d(100.0 * a_), e * w);
            }
            WalkInPlace | RunInPlace => {
                let run = self.movement == RunInPlace;
                let (hip, knee, swing) = if run {
                    (70.0, 110.0, 35.0)
                } else {
                    (55.0, 70.0, 25.0)
                };
                for s in 0..2 {
                    let l = (phi + s as f64 * core::f64::consts::PI).sin().max(0.0);
                    a.hip_flex[s] = lerp(n.hip_flex[s], d(hip * a_), e * l);
                    a.knee[s] = lerp(n.knee[s], d(knee * a_), e * l);
                    let arm = (phi + (1 - s) as f64 * core::f64::consts::PI).sin();
                    a.shoulder_flex[s] = n.shoulder_flex[s] + e * d(swing * a_) * arm;
                    if run {
                        a.elbow[s] = lerp(n.elbow[s], d(80.0), e);
                    }
                }
                if run {
                    lift = e * 30.0 * a_ * (2.0 * phi).sin().max(0.0);
                }
            }
            SingleJump | JumpForward | MultipleJumps => {
                let crouch = e * (bump(0.0, 0.35) + bump(0.5, 0.8));
                let flight = e * bump(0.3, 0.55);
                for s in 0..2 {
                    a.knee[s] = lerp(n.knee[s], d(80.0 * a_), crouch);
                    a.hip_flex[s] = lerp(n.hip_flex[s], d(70.0 * a_), crouch);
                    a.shoulder_flex[s] = n.shoulder_flex[s] - d(30.0) * crouch + d(120.0) * flight;
                }
                a.trunk_lean = lerp(n.trunk_lean, d(30.0), crouch);
                lift = self.jump * a_ * flight;
                if self.movement == JumpForward {
                    let go = smoothstep((tau - 0.3) / 0.25) - smoothstep((tau - 0.75) / 0.25);
                    forward = e * self.reach * go;
                }
            }
            HopLeft | HopRight => {
                let held = 1 - side;
                a.hip_flex[held] = lerp(n.hip_flex[held], d(35.0), e);
                a.knee[held] = lerp(n.knee[held], d(80.0), e);
                let crouch = e * (bump(0.0, 0.3) + bump(0.7, 1.0));
                a.knee[side] = lerp(n.knee[side], d(25.0), crouch);
                a.hip_flex[side] = lerp(n.hip_flex[side], d(15.0), crouch);
                lift = e * self.jump * bump(0.25, 0.75);
                for s in 0..2 {
                    a.shoulder_abd[s] = lerp(n.shoulder_abd[s], d(25.0), e);
                }
            }
            PunchForwardLeft | PunchForwardRight | PunchUpLeft | PunchUpRight | PunchDownLeft
            | PunchDownRight => {
                guard(&mut a, 0, e);
                guard(&mut a, 1, e);
                let (flex, lean) = match self.movement {
                    PunchForwardLeft | PunchForwardRight => (90.0 * a_, 0.0),
                    PunchUpLeft | PunchUpRight => (165.0 * a_, 0.0),
                    _ => (10.0, 20.0),
                };
                let k = e * w;
                a.shoulder_flex[side] = lerp(a.shoulder_flex[side], d(flex), k);
                a.shoulder_abd[side] = lerp(a.shoulder_abd[side], d(5.0), k);
                a.elbow[side] = lerp(a.elbow[side], d(5.0), k);
                a.trunk_lean = lerp(n.trunk_lean, d(lean), k);
            }
            WaveLeft | WaveRight => {
                a.shoulder_abd[side] = lerp(n.shoulder_abd[side], d(100.0 * a_), e);
                a.shoulder_flex[side] = lerp(n.shoulder_flex[side], d(20.0), e);
                a.shoulder_rot[side] = lerp(0.0, d(75.0), e);
                a.elbow[side] = lerp(n.elbow[side], d(60.0 + 30.0 * phi.sin()), e);
            }
            CircleHandLeft | CircleHandRight | Figure8Left | Figure8Right => {
                let eight = matches!(self.movement, Figure8Left | Figure8Right);
                let dir = if side == 1 { 1.0 } else { -1.0 };
                let (f, ab) = if eight {
                    (
                        80.0 + 35.0 * a_ * (2.0 * phi).sin(),
                        35.0 + 28.0 * a_ * phi.sin(),
                    )
                } else {
                    (
                        80.0 + 40.0 * a_ * phi.cos(),
                        35.0 + 28.0 * a_ * dir * phi.sin(),
                    )
                };
                a.shoulder_flex[side] = lerp(n.shoulder_flex[side], d(f), e);
                a.shoulder_abd[side] = lerp(n.shoulder_abd[side], d(ab), e);
                a.elbow[side] = lerp(n.elbow[side], d(15.0), e);
            }
            JumpingJacks => {
                for s in 0..2 {
                    a.shoulder_abd[s] = lerp(n.shoulder_abd[s], d(160.0 * a_), e * w);
                    a.hip_abd[s] = lerp(n.hip_abd[s], d(30.0 * a_), e * w);
                }
                lift = e * 50.0 * a_ * phi.sin().powi(2);
            }
            Squats => {
                for s in 0..2 {
                    a.hip_flex[s] = lerp(n.hip_flex[s], d(100.0 * a_), e * w);
                    a.knee[s] = lerp(n.knee[s], d(110.0 * a_), e * w);
                    a.shoulder_flex[s] = lerp(n.shoulder_flex[s], d(80.0), e * w);
                }
                a.trunk_lean = lerp(n.trunk_lean, d(35.0), e * w);
            }
            KickForward | SideKick => {
                let s = (cycle.rem_euclid(2)) as usize;
                let bend = 4.0 * w * (1.0 - w);
                if self.movement == KickForward {
                    a.hip_flex[s] = lerp(n.hip_flex[s], d(85.0 * a_), e * w);
                    a.knee[s] = lerp(n.knee[s], d(60.0), e * bend);
                } else {
                    a.hip_abd[s] = lerp(n.hip_abd[s], d(42.0 * a_), e * w);
                    a.knee[s] = lerp(n.knee[s], d(40.0), e * bend);
                    a.trunk_lean = lerp(n.trunk_lean, d(10.0), e * w);
                }
                for s in 0..2 {
                    a.shoulder_abd[s] = lerp(n.shoulder_abd[s], d(30.0), e);
                }
            }
            Boxing => {
                guard(&mut a, 0, e);
                guard(&mut a, 1, e);
                for (s, sign) in [(0, 1.0), (1, -1.0)] {
                    let p = e * (sign * phi.sin()).max(0.0).powi(2);
                    a.shoulder_flex[s] = lerp(a.shoulder_flex[s], d(90.0 * a_), p);
                    a.elbow[s] = lerp(a.elbow[s], d(10.0), p);
                }
                a.trunk_lean = lerp(n.trunk_lean, d(10.0), e);
                lift = e * 15.0 * (2.0 * phi).sin().abs();
            }
            ArmCircles => {
                for s in 0..2 {
                    a.shoulder_abd[s] = lerp(n.shoulder_abd[s], d(90.0 + 25.0 * a_ * phi.cos()), e);
                    a.shoulder_flex[s] = lerp(n.shoulder_flex[s], d(25.0 * a_ * phi.sin()), e);
                    a.elbow[s] = lerp(n.elbow[s], d(5.0), e);
                }
            }
            NoPerson => unreachable!("handled above"),
        }
        let (sh, ch) = self.heading.sin_cos();
        Some(Pose {
            ground: [
                self.ground[0] + ch * forward,
                self.ground[1] + sh * forward,
                0.0,
            ],
            heading: self.heading,
            lift,
            angles: a,
        })
    }

    /// The moving objects of a [`Movement::NoPerson`] scene at `t` (empty for a person).
    pub fn objects(&self, t: f64) -> Vec<Capsule> {
        self.objects
            .iter()
            .map(|o| {
                let tt = t.rem_euclid(o.period);
                let mut c = axpy(o.start, o.velocity, tt);
                c[2] += o.bounce_height * (core::f64::consts::PI * o.bounce_hz * t).sin().abs();
                let spin = core::f64::consts::TAU * o.spin_hz * t;
                let axis = [spin.cos() * 0.5, spin.sin() * 0.5, spin.cos() * 0.7];
                let h = scale(normalize(axis), o.half_length);
                Capsule {
                    a: sub(c, h),
                    b: add(c, h),
                    radius: o.radius,
                    material: o.material,
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stage() -> Stage {
        Stage {
            centre: [0.0, 0.0, 0.0],
            fixation_height: 900.0,
            facing: -core::f64::consts::FRAC_PI_2,
        }
    }

    #[test]
    fn names_round_trip_and_are_unique() {
        assert_eq!(Movement::ALL.len(), 34);
        for m in Movement::ALL {
            assert_eq!(m.name().parse::<Movement>().unwrap(), *m);
        }
        let mut names: Vec<_> = Movement::ALL.iter().map(|m| m.name()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), Movement::ALL.len());
        assert!("moonwalk".parse::<Movement>().is_err());
    }

    #[test]
    fn angles_stay_within_limits_and_rest_at_the_ends() {
        for (i, &m) in Movement::ALL.iter().enumerate() {
            if m == Movement::NoPerson {
                continue;
            }
            for seed in 0..4 {
                let mo = Motion::sample(m, seed, i as u32, &stage(), 4.0);
                let mut moved = 0.0f64;
                let rest = mo.pose(0.0).unwrap().angles;
                for k in 0..=400 {
                    let t = k as f64 * 0.01;
                    let p = mo.pose(t).unwrap();
                    if let Some((name, v)) = p.angles.violation() {
                        panic!("{m} seed {seed} t {t}: {name} = {v}");
                    }
                    let diff = p
                        .angles
                        .named()
                        .iter()
                        .zip(rest.named())
                        .map(|(a, b)| (a.1 - b.1).abs())
                        .fold(0.0, f64::max);
                    moved = moved.max(diff);
                }
                assert!(moved > 10.0, "{m}: moves only {moved} degrees");
                assert_eq!(
                    mo.pose(0.0).unwrap().angles,
                    Angles::neutral(),
                    "{m} starts at rest"
                );
                assert_eq!(
                    mo.pose(4.0).unwrap().angles,
                    Angles::neutral(),
                    "{m} ends at rest"
                );
            }
        }
    }

    #[test]
    fn no_person_has_objects_and_no_pose() {
        let mo = Motion::sample(Movement::NoPerson, 1, 0, &stage(), 2.0);
        assert!(mo.pose(1.0).is_none());
        assert!(mo.objects(1.0).len() >= 2);
        assert_ne!(mo.objects(0.0), mo.objects(0.1));
    }
}

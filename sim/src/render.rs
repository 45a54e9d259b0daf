//! Intensity rendering for one camera: a static textured room and analytic ray casting of
//! capsules and spheres.
//!
//! # Pixel convention
//!
//! The event at column `x`, row `y` (top-left origin, [`evpose_core::Event`]) is the pixel
//! covering image coordinates `u ∈ [x, x + 1)`, `v ∈ [y, y + 1)` in the convention of
//! [`Camera::project`] (`v = H − v'/w`); its ray runs from [`Camera::centre`] through
//! [`Camera::back_project`]`((x + 0.5, y + 0.5))`. So a 3-D point that projects to `(u, v)`
//! lights pixel `(⌊u⌋, ⌊v⌋)`, which is also DHP19's integer label `int(u), int(v)`.
//!
//! # Scene
//!
//! The room is a box around the cameras (floor `z = 0`, ceiling, four walls 0.3–2 m beyond the
//! outermost camera), textured with tiles and blocky two-scale noise; it never changes during a
//! recording, so only the noise model makes events there. Bodies and objects are capsules,
//! shaded Lambertian (ambient 0.25–0.6 plus one directional light from above) with bands along
//! each capsule's axis and hashed patches in (axis, angle) surface coordinates, so that edges
//! inside the silhouette make events too. Intensities are linear in `[0, ~1]`; the sensor takes
//! their logarithm. Rendering touches only the projected bounding boxes of the capsules.

use evpose_core::geometry::Camera;

use crate::body::Capsule;
use crate::rng::{mix64, tag, Rng};
use crate::v3::{cross, dot, normalize, sub, V3};

/// A pixel rectangle `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Rect {
    /// First column.
    pub x0: usize,
    /// One past the last column.
    pub x1: usize,
    /// First row.
    pub y0: usize,
    /// One past the last row.
    pub y1: usize,
}

impl Rect {
    /// Whether it holds no pixel.
    pub fn is_empty(&self) -> bool {
        self.x0 >= self.x1 || self.y0 >= self.y1
    }

    /// The pixels in both.
    pub fn intersect(self, o: Rect) -> Rect {
        Rect {
            x0: self.x0.max(o.x0),
            x1: self.x1.min(o.x1),
            y0: self.y0.max(o.y0),
            y1: self.y1.min(o.y1),
        }
    }

    /// The smallest rectangle holding both.
    pub fn union(self, o: Rect) -> Rect {
        if self.is_empty() {
            return o;
        }
        if o.is_empty() {
            return self;
        }
        Rect {
            x0: self.x0.min(o.x0),
            x1: self.x1.max(o.x1),
            y0: self.y0.min(o.y0),
            y1: self.y1.max(o.y1),
        }
    }
}

/// The static room and the lighting of one recording (shared by its cameras).
#[derive(Clone, Debug, PartialEq)]
pub struct Room {
    /// Wall planes `x = min.0`, `x = max.0`, `y = min.1`, `y = max.1`; ceiling `z = max.2`.
    pub min: [f64; 3],
    /// See [`Room::min`].
    pub max: [f64; 3],
    /// Floor tile size, mm.
    pub tile: f64,
    /// Base albedo of floor, ceiling and walls.
    pub albedo: [f32; 3],
    /// Relative contrast of floor tiles and of the noise.
    pub contrast: [f32; 2],
    /// Overall illumination in `[0.35, 1]` (scales every intensity).
    pub illumination: f32,
    /// Ambient share of the body shading, `[0.25, 0.6]`.
    pub ambient: f32,
    /// Unit direction towards the light.
    pub light: [f64; 3],
    seed: u32,
}

impl Room {
    /// Draws the room and light for `(seed, index, stream)` around `cameras` (the recording
    /// uses `stream = movement · 256`).
    pub fn sample(seed: u64, index: u32, stream: u16, cameras: &[Camera; 4]) -> Self {
        let mut r = Rng::new(seed, index, tag::SCENE, stream);
        let mut min = [f64::INFINITY; 3];
        let mut max = [f64::NEG_INFINITY; 3];
        for c in cameras {
            let c = c.centre();
            for k in 0..3 {
                min[k] = min[k].min(c[k]);
                max[k] = max[k].max(c[k]);
            }
        }
        for k in 0..2 {
            min[k] -= r.uniform(300.0, 2000.0);
            max[k] += r.uniform(300.0, 2000.0);
        }
        min[2] = 0.0;
        max[2] += r.uniform(400.0, 1200.0);
        let elev = r.uniform(40.0, 80.0).to_radians();
        let az = r.uniform(0.0, core::f64::consts::TAU);
        Self {
            min,
            max,
            tile: r.uniform(200.0, 700.0),
            albedo: [
                r.uniform(0.1, 0.7) as f32,
                r.uniform(0.4, 0.9) as f32,
                r.uniform(0.15, 0.85) as f32,
            ],
            contrast: [r.uniform(0.05, 0.5) as f32, r.uniform(0.05, 0.4) as f32],
            illumination: r.uniform(0.35, 1.0) as f32,
            ambient: r.uniform(0.25, 0.6) as f32,
            light: [elev.cos() * az.cos(), elev.cos() * az.sin(), elev.sin()],
            seed: r.below(1 << 32) as u32,
        }
    }

    /// Intensity seen along the ray `o + t·d` (the first room surface it hits).
    pub fn intensity(&self, o: V3, d: V3) -> f32 {
        let mut best = (f64::INFINITY, 0usize, 0.0, 0.0);
        for axis in 0..3 {
            if d[axis].abs() < 1e-12 {
                continue;
            }
            for (plane, bound) in [(0, self.min[axis]), (1, self.max[axis])] {
                let t = (bound - o[axis]) / d[axis];
                if t > 0.0 && t < best.0 {
                    let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
                    let (a, b) = match axis {
                        0 => (p[1], p[2]),
                        1 => (p[0], p[2]),
                        _ => (p[0], p[1]),
                    };
                    best = (t, axis * 2 + plane, a, b);
                }
            }
        }
        let (t, surface, a, b) = best;
        if !t.is_finite() {
            return 0.1 * self.illumination;
        }
        let kind = match surface {
            4 => 0, // floor
            5 => 1, // ceiling
            _ => 2, // walls
        };
        let mut alb = self.albedo[kind];
        let s = self.seed ^ (surface as u32).wrapping_mul(0x27d4_eb2d);
        if kind == 0 {
            let checker =
                ((a / self.tile).floor() as i64 + (b / self.tile).floor() as i64).rem_euclid(2);
            alb *= 1.0 + self.contrast[0] * if checker == 0 { 1.0 } else { -1.0 };
        }
        let n1 = hash_unit((a / 450.0).floor() as i64, (b / 450.0).floor() as i64, s);
        let n2 = hash_unit(
            (a / 130.0).floor() as i64,
            (b / 130.0).floor() as i64,
            s ^ 0xabcd,
        );
        alb *= 1.0 + self.contrast[1] * (0.7 * n1 + 0.3 * n2);
        let shade = [0.9f32, 0.6, 0.75][kind];
        (alb * shade * self.illumination).clamp(0.0, 1.0)
    }
}

/// A hash of `(a, b, seed)` uniform in `[-1, 1]`.
fn hash_unit(a: i64, b: i64, seed: u32) -> f32 {
    let h = mix64(
        (a as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
            ^ (b as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f)
            ^ u64::from(seed),
    );
    (h >> 40) as f32 / (1u64 << 23) as f32 - 1.0
}

/// One camera's renderer: per-pixel rays and the static background.
#[derive(Clone, Debug)]
pub struct View {
    width: usize,
    height: usize,
    centre: V3,
    projection: [[f64; 4]; 3],
    rays: Vec<V3>,
    background: Vec<f32>,
    ambient: f32,
    light: V3,
    illumination: f32,
}

/// Scratch and output of [`View::render`]: the current intensity image.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Linear intensity per pixel, row-major, `width × height`.
    pub intensity: Vec<f32>,
    depth: Vec<f64>,
    hit: Vec<u16>,
    /// Bounds of everything drawn.
    last: Rect,
    /// The capsules drawn and their bounds.
    capsules: Vec<Capsule>,
    rects: Vec<Rect>,
}

const NO_HIT: u16 = u16::MAX;

impl View {
    /// Precomputes the rays of every pixel and the room's image for `camera`.
    pub fn new(camera: &Camera, room: &Room) -> Self {
        let (w, h) = (usize::from(camera.width()), usize::from(camera.height()));
        let centre = camera.centre();
        let projection = camera.projection();
        let fwd = [projection[2][0], projection[2][1], projection[2][2]];
        let mut rays = Vec::with_capacity(w * h);
        let mut background = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let p = camera
                    .back_project((x as f64 + 0.5, y as f64 + 0.5))
                    .unwrap_or([centre[0], centre[1], centre[2] - 1.0]);
                let mut d = normalize(sub(p, centre));
                if dot(d, fwd) < 0.0 {
                    d = [-d[0], -d[1], -d[2]];
                }
                rays.push(d);
                background.push(room.intensity(centre, d));
            }
        }
        Self {
            width: w,
            height: h,
            centre,
            projection,
            rays,
            background,
            ambient: room.ambient,
            light: room.light,
            illumination: room.illumination,
        }
    }

    /// Image width, pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Image height, pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The static background intensity, row-major.
    pub fn background(&self) -> &[f32] {
        &self.background
    }

    /// A frame showing only the background.
    pub fn frame(&self) -> Frame {
        Frame {
            intensity: self.background.clone(),
            depth: vec![f64::INFINITY; self.background.len()],
            hit: vec![NO_HIT; self.background.len()],
            last: Rect::default(),
            capsules: Vec::new(),
            rects: Vec::new(),
        }
    }

    /// Projects a world point to `(u, v)` (same as [`Camera::project`]); `None` behind the
    /// camera.
    pub fn project(&self, p: V3) -> Option<(f64, f64)> {
        let r = |i: usize| {
            self.projection[i][0] * p[0]
                + self.projection[i][1] * p[1]
                + self.projection[i][2] * p[2]
                + self.projection[i][3]
        };
        let w = r(2);
        (w > 1e-9).then(|| (r(0) / w, self.height as f64 - r(1) / w))
    }

    /// The capsule's image footprint: a 2-D stadium (its axis' projection widened by the
    /// projected radius, plus a margin), `None` when an end is behind the camera.
    fn footprint(&self, c: &Capsule) -> Option<Stadium> {
        let pa = self.project(c.a)?;
        let pb = self.project(c.b)?;
        let radius_px = |p: V3, (u, v): (f64, f64)| -> Option<f64> {
            // σ_max of the projection's Jacobian (finite differences of r along each axis).
            let mut jjt = [0.0; 3];
            for k in 0..3 {
                let mut q = p;
                q[k] += c.radius;
                let (uq, vq) = self.project(q)?;
                let (du, dv) = (uq - u, vq - v);
                jjt[0] += du * du;
                jjt[1] += du * dv;
                jjt[2] += dv * dv;
            }
            let (a, b, d) = (jjt[0], jjt[1], jjt[2]);
            let l = (a + d) / 2.0 + (((a - d) / 2.0).powi(2) + b * b).sqrt();
            Some(l.sqrt())
        };
        let r = radius_px(c.a, pa)?.max(radius_px(c.b, pb)?) * 1.05 + 1.0;
        Some(Stadium { a: pa, b: pb, r })
    }

    /// Pixel rectangle that holds the projection of a capsule, clipped to the image; empty when
    /// off-image or behind the camera.
    pub fn bounds(&self, c: &Capsule) -> Rect {
        let Some(st) = self.footprint(c) else {
            return Rect::default();
        };
        let clip = |x: f64, n: usize| x.clamp(0.0, n as f64) as usize;
        Rect {
            x0: clip((st.a.0.min(st.b.0) - st.r).floor(), self.width),
            x1: clip((st.a.0.max(st.b.0) + st.r).floor() + 1.0, self.width),
            y0: clip((st.a.1.min(st.b.1) - st.r).floor(), self.height),
            y1: clip((st.a.1.max(st.b.1) + st.r).floor() + 1.0, self.height),
        }
    }

    /// Renders `capsules` over the background into `frame`; returns the rectangle whose pixels
    /// may have changed since the previous call. Incremental: when the capsule count is the
    /// same as last time, only the old and new bounds of the capsules that changed are redrawn
    /// (a one-arm movement redraws the arm's sweep only).
    pub fn render(&self, capsules: &[Capsule], frame: &mut Frame) -> Rect {
        let w = self.width;
        let rects: Vec<Rect> = capsules.iter().map(|c| self.bounds(c)).collect();
        let all = rects.iter().fold(Rect::default(), |a, &r| a.union(r));
        // Only where a capsule moved (its old and new bounds) can a pixel change; with another
        // capsule count, everywhere any capsule was or is.
        let region = if frame.capsules.len() == capsules.len() {
            capsules
                .iter()
                .zip(&frame.capsules)
                .zip(rects.iter().zip(&frame.rects))
                .filter(|((now, before), _)| now != before)
                .fold(Rect::default(), |a, (_, (&r, &q))| a.union(r).union(q))
        } else {
            frame.last.union(all)
        };
        frame.capsules.clear();
        frame.capsules.extend_from_slice(capsules);
        frame.last = all;
        if region.is_empty() {
            frame.rects = rects;
            return region;
        }
        for y in region.y0..region.y1 {
            let (a, b) = (y * w + region.x0, y * w + region.x1);
            frame.intensity[a..b].copy_from_slice(&self.background[a..b]);
            frame.depth[a..b].fill(f64::INFINITY);
            frame.hit[a..b].fill(NO_HIT);
        }
        let prepared: Vec<Prepared> = capsules
            .iter()
            .map(|c| Prepared::new(c, self.centre))
            .collect();
        for (k, (p, r)) in prepared.iter().zip(&rects).enumerate() {
            let r = r.intersect(region);
            if r.is_empty() {
                continue;
            }
            let Some(st) = self.footprint(&capsules[k]) else {
                continue;
            };
            for y in r.y0..r.y1 {
                let row = y * w;
                let Some((xa, xb)) = st.row_span(y as f64 + 0.5) else {
                    continue;
                };
                let (lo, hi) = (r.x0 as f64, r.x1 as f64);
                let xa = (xa - 0.5).ceil().clamp(lo, hi) as usize;
                let xb = ((xb - 0.5).floor() + 1.0).clamp(lo, hi) as usize;
                for x in xa..xb {
                    let i = row + x;
                    if let Some(t) = p.intersect(self.rays[i]) {
                        if t < frame.depth[i] {
                            frame.depth[i] = t;
                            frame.hit[i] = k as u16;
                        }
                    }
                }
            }
        }
        for y in region.y0..region.y1 {
            let row = y * w;
            for x in region.x0..region.x1 {
                let i = row + x;
                let k = frame.hit[i];
                if k != NO_HIT {
                    let p = &prepared[usize::from(k)];
                    let s = p.shade(
                        self.rays[i],
                        frame.depth[i],
                        &capsules[usize::from(k)],
                        self.light,
                        self.ambient,
                    );
                    frame.intensity[i] = (s * self.illumination).clamp(0.0, 1.0);
                }
            }
        }
        frame.rects = rects;
        region
    }
}

/// A 2-D stadium: points within `r` of the segment `a`–`b` (image coordinates).
#[derive(Clone, Copy, Debug)]
struct Stadium {
    a: (f64, f64),
    b: (f64, f64),
    r: f64,
}

impl Stadium {
    /// The `u` interval where the line `v = vc` crosses the stadium.
    fn row_span(&self, vc: f64) -> Option<(f64, f64)> {
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for (u, v) in [self.a, self.b] {
            let dy = vc - v;
            if dy.abs() <= self.r {
                let h = (self.r * self.r - dy * dy).sqrt();
                lo = lo.min(u - h);
                hi = hi.max(u + h);
            }
        }
        // The band: parallelogram a ± r n, b ± r n.
        let (dx, dy) = (self.b.0 - self.a.0, self.b.1 - self.a.1);
        let len = dx.hypot(dy);
        if len > 1e-9 {
            let n = (-dy / len * self.r, dx / len * self.r);
            let q = [
                (self.a.0 + n.0, self.a.1 + n.1),
                (self.b.0 + n.0, self.b.1 + n.1),
                (self.b.0 - n.0, self.b.1 - n.1),
                (self.a.0 - n.0, self.a.1 - n.1),
            ];
            for i in 0..4 {
                let (p0, p1) = (q[i], q[(i + 1) % 4]);
                if (p0.1 - vc) * (p1.1 - vc) <= 0.0 && p0.1 != p1.1 {
                    let u = p0.0 + (vc - p0.1) / (p1.1 - p0.1) * (p1.0 - p0.0);
                    lo = lo.min(u);
                    hi = hi.max(u);
                }
            }
        }
        (lo <= hi).then_some((lo, hi))
    }
}

/// A capsule in camera-relative coordinates with the ray-independent terms of the
/// intersection precomputed (ray origin = camera centre = 0).
struct Prepared {
    a: V3,
    b: V3,
    ba: V3,
    baba: f64,
    baoa: f64,
    oaoa: f64,
    rr: f64,
    /// `|b|² − r²`, for the far cap.
    bb: f64,
    u_ref: V3,
    v_ref: V3,
}

impl Prepared {
    fn new(c: &Capsule, centre: V3) -> Self {
        let a = sub(c.a, centre);
        let b = sub(c.b, centre);
        let ba = sub(b, a);
        let oa = [-a[0], -a[1], -a[2]];
        let baba = dot(ba, ba);
        let axis = if baba > 1e-12 {
            normalize(ba)
        } else {
            [0.0, 0.0, 1.0]
        };
        let mut u_ref = cross(axis, [0.0, 0.0, 1.0]);
        if dot(u_ref, u_ref) < 1e-6 {
            u_ref = cross(axis, [1.0, 0.0, 0.0]);
        }
        let u_ref = normalize(u_ref);
        let v_ref = cross(axis, u_ref);
        Self {
            a,
            b,
            ba,
            baba,
            baoa: dot(ba, oa),
            oaoa: dot(oa, oa),
            rr: c.radius * c.radius,
            bb: dot(b, b) - c.radius * c.radius,
            u_ref,
            v_ref,
        }
    }

    /// Distance along the unit ray `d` from the camera centre to the first hit.
    #[inline]
    fn intersect(&self, d: V3) -> Option<f64> {
        let rdoa = -dot(d, self.a);
        if self.baba > 1e-12 {
            let bard = dot(self.ba, d);
            let ka = self.baba - bard * bard;
            let kb = self.baba * rdoa - self.baoa * bard;
            let kc = self.baba * self.oaoa - self.baoa * self.baoa - self.rr * self.baba;
            let h = kb * kb - ka * kc;
            if h < 0.0 {
                return None;
            }
            if ka > 1e-12 {
                let t = (-kb - h.sqrt()) / ka;
                let y = self.baoa + t * bard;
                if y > 0.0 && y < self.baba {
                    return (t > 0.0).then_some(t);
                }
                // Caps.
                let (bq, cq) = if y <= 0.0 {
                    (rdoa, self.oaoa - self.rr)
                } else {
                    (-dot(d, self.b), self.bb)
                };
                let h = bq * bq - cq;
                if h > 0.0 {
                    let t = -bq - h.sqrt();
                    return (t > 0.0).then_some(t);
                }
                return None;
            }
        }
        // Sphere at `a` (or a ray along the axis: the nearer cap).
        let cq = self.oaoa - self.rr;
        let h = rdoa * rdoa - cq;
        if h > 0.0 {
            let t = -rdoa - h.sqrt();
            (t > 0.0).then_some(t)
        } else {
            None
        }
    }

    /// Shaded albedo at the hit at distance `t` along `d`.
    fn shade(&self, d: V3, t: f64, c: &Capsule, light: V3, ambient: f32) -> f32 {
        let p = [d[0] * t, d[1] * t, d[2] * t];
        let s = if self.baba > 1e-12 {
            (dot(sub(p, self.a), self.ba) / self.baba).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let q = [
            self.a[0] + s * self.ba[0],
            self.a[1] + s * self.ba[1],
            self.a[2] + s * self.ba[2],
        ];
        let n = normalize(sub(p, q));
        let lambert = dot(n, light).max(0.0) as f32;
        let m = &c.material;
        let along = s * self.baba.sqrt() + dot(n, normalize(self.ba)) * c.radius;
        // Diamond angle (monotonic in the angle, cheap): in (−1, 3), π/2 per unit.
        let (cu, cv) = (dot(n, self.u_ref), dot(n, self.v_ref));
        let p = cv / (cu.abs() + cv.abs()).max(1e-12);
        let angle = if cu >= 0.0 { p } else { 2.0 - p };
        let around = angle * core::f64::consts::FRAC_PI_2 * c.radius;
        let mut alb = m.albedo;
        if m.band_period > 0.0 && m.band_contrast > 0.0 {
            let phase = (along / f64::from(m.band_period)).rem_euclid(1.0);
            alb *= 1.0 + m.band_contrast * if phase < 0.5 { 1.0 } else { -1.0 };
        }
        if m.patch_contrast > 0.0 {
            let cell = 50.0;
            alb *= 1.0
                + m.patch_contrast
                    * hash_unit(
                        (along / cell).floor() as i64,
                        (around / cell).floor() as i64,
                        m.patch_seed,
                    );
        }
        alb * (ambient + (1.0 - ambient) * lambert)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::Material;

    /// A pinhole camera at `c` looking at `target`, f = 340 px, principal point at the centre.
    fn camera(c: V3, target: V3) -> Camera {
        let f = normalize(sub(target, c));
        let r = normalize(cross(f, [0.0, 0.0, 1.0]));
        let u = cross(r, f); // up
        let row = |a: V3, k: f64, o: f64| {
            let v = [
                k * a[0] + o * f[0],
                k * a[1] + o * f[1],
                k * a[2] + o * f[2],
            ];
            [v[0], v[1], v[2], -dot(v, c)]
        };
        let p = [
            row(r, 340.0, 173.0),
            row(u, 340.0, 130.0),
            row([0.0; 3], 0.0, 1.0),
        ];
        Camera::new(p, c, 346, 260).unwrap()
    }

    #[test]
    fn footprint_holds_every_hit_pixel() {
        let cam = camera([2500.0, -2500.0, 2000.0], [0.0, 0.0, 900.0]);
        let room = Room::sample(1, 0, 0, &[cam; 4]);
        let view = View::new(&cam, &room);
        let mut rng = Rng::new(3, 0, 0, 0);
        let mut hits = 0;
        for _ in 0..40 {
            let p = |r: &mut Rng| {
                [
                    r.uniform(-900.0, 900.0),
                    r.uniform(-900.0, 900.0),
                    r.uniform(0.0, 1900.0),
                ]
            };
            let c = Capsule {
                a: p(&mut rng),
                b: p(&mut rng),
                radius: rng.uniform(10.0, 200.0),
                material: Material {
                    albedo: 0.9,
                    band_period: 0.0,
                    band_contrast: 0.0,
                    patch_contrast: 0.0,
                    patch_seed: 0,
                },
            };
            let mut frame = view.frame();
            view.render(&[c], &mut frame);
            let pc = Prepared::new(&c, view.centre);
            hits += frame.hit.iter().filter(|&&h| h != NO_HIT).count();
            for i in 0..view.rays.len() {
                let hit = pc.intersect(view.rays[i]).is_some();
                assert_eq!(hit, frame.hit[i] != NO_HIT, "pixel {i}: brute force {hit}");
            }
        }
        assert!(hits > 10_000, "{hits} pixels hit");
    }

    #[test]
    fn incremental_render_equals_a_fresh_one() {
        let cam = camera([-2000.0, -2600.0, 2100.0], [0.0, 0.0, 900.0]);
        let room = Room::sample(2, 0, 0, &[cam; 4]);
        let view = View::new(&cam, &room);
        let subject = crate::body::Subject::from_seed(4, 2);
        let mut frame = view.frame();
        let mut changed_total = 0;
        for k in 0..30 {
            let mut angles = crate::body::Angles::neutral();
            angles.shoulder_abd[1] = 0.05 * f64::from(k);
            angles.elbow[0] = 0.02 * f64::from(k % 7);
            let pose = crate::body::Pose {
                ground: [0.0; 3],
                heading: -1.5,
                lift: 0.0,
                angles,
            };
            let caps = subject.capsules(&pose);
            let before = frame.intensity.clone();
            let region = view.render(&caps, &mut frame);
            let mut fresh = view.frame();
            view.render(&caps, &mut fresh);
            assert!(frame.intensity == fresh.intensity, "step {k}");
            for (i, (a, b)) in before.iter().zip(&frame.intensity).enumerate() {
                if a != b {
                    changed_total += 1;
                    let (x, y) = (i % view.width, i / view.width);
                    assert!(x >= region.x0 && x < region.x1 && y >= region.y0 && y < region.y1);
                }
            }
        }
        assert!(changed_total > 1000);
    }
}

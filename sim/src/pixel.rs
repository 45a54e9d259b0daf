//! DVS pixel model (after ESIM and v2e) on log intensity, with noise.
//!
//! Per pixel: log intensity `L = ln I` above `I₀ = 0.02` and linear below it (v2e's lin-log,
//! continuous with its slope), a first-order photoreceptor low-pass whose cut-off scales with
//! intensity (`f_c · clamp(I / 0.2, 0.1, 1)`, implicit Euler per render step), a memorized
//! level `m` and ON/OFF thresholds `C±` with per-pixel mismatch fixed for the recording. Between
//! two renders the filtered level moves linearly; every crossing of `m + k·C+` (or `m − k·C−`)
//! is an event, timestamped by linear interpolation to the crossing, and moves `m` to the
//! crossed level. A crossing within the refractory period of the pixel's previous event is
//! held, as a DVS pixel holds it while its reset lasts: it fires when the period ends, if the
//! level is still beyond it then (a pixel behind a large change catches up at the refractory
//! rate). Pixels whose photoreceptor has not settled, or that hold a crossing, keep being
//! updated after the image stops changing there, until they are at rest.
//!
//! # Versions ([`PixelModel`])
//! [`PixelModel::V2`], above, is the default. [`PixelModel::V1`] is the model the shipped models'
//! training and test data were made with (kept so that `train/recipe.sh` reproduces them): a
//! crossing held by the refractory period was retried only at the next render step, so it fired
//! at that step's start (render steps are up to 4 ms: in a camera with a long refractory period
//! many events shared a few timestamps), and a pixel was updated for 20 ms after the image last
//! changed there, settled or not (a dim pixel's photoreceptor, whose time constant reaches
//! 10 ms, could freeze before its last events).
//!
//! Noise: leak drifts `m` down by `leak · C+` per second (ON events at about `leak` Hz on a
//! static pixel, random phase: `m` starts a uniform fraction of `C+` below `L`); shot noise is
//! a Poisson process of `shot` Hz per pixel with random polarity; hot pixels fire ON events
//! as Poisson processes of 50–800 Hz. Static pixels are advanced lazily and analytically.
//!
//! # Randomized ranges ([`SensorParams::sample`], DAVIS346-like; one draw per camera)
//!
//! | parameter | range |
//! |---|---|
//! | `c_on` (ln units) | uniform 0.15–0.45 |
//! | `c_off` | `c_on · N(1, 0.1)`, clamped to 0.1–0.6 |
//! | `mismatch` σ (ln units, per pixel, both thresholds, clamped ≥ 0.03) | uniform 0.02–0.05 |
//! | `cutoff_hz` (photoreceptor at full brightness) | log-uniform 150–1500 |
//! | `refractory_us` | log-uniform 100–1000 |
//! | `leak_hz` | log-uniform 0.01–0.2 |
//! | `shot_hz` | log-uniform 0.001–1 |
//! | `hot_pixels` | 0–5, each 50–800 Hz |

use evpose_core::Event;

use crate::render::Rect;
use crate::rng::{tag, Rng};

/// Which version of the pixel model a recording uses (module docs, "Versions").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum PixelModel {
    /// The model of the shipped models' data: held crossings fire at the next render step's
    /// start, pixels are updated for 20 ms after their image last changed.
    V1,
    /// Held crossings fire when the refractory period ends; pixels are updated until they are
    /// at rest.
    #[default]
    V2,
}

impl PixelModel {
    /// Every version, oldest first.
    pub const ALL: [Self; 2] = [Self::V1, Self::V2];

    /// The version's name (`v1`, `v2`), as manifests and the CLI write it.
    pub fn name(self) -> &'static str {
        match self {
            Self::V1 => "v1",
            Self::V2 => "v2",
        }
    }

    /// The version named `name` ([`PixelModel::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// DVS parameters of one camera for one recording.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorParams {
    /// Mean ON threshold, ln units.
    pub c_on: f64,
    /// Mean OFF threshold, ln units.
    pub c_off: f64,
    /// Per-pixel threshold standard deviation, ln units.
    pub mismatch: f64,
    /// Photoreceptor cut-off at full brightness, Hz.
    pub cutoff_hz: f64,
    /// Refractory period, µs.
    pub refractory_us: f64,
    /// Leak event rate per pixel, Hz.
    pub leak_hz: f64,
    /// Shot-noise event rate per pixel, Hz.
    pub shot_hz: f64,
    /// Number of hot pixels.
    pub hot_pixels: u32,
}

impl SensorParams {
    /// Draws the parameters for `(seed, index, stream)` from the ranges above (the recording
    /// uses `stream = movement · 256 + camera`).
    pub fn sample(seed: u64, index: u32, stream: u16) -> Self {
        let mut r = Rng::new(seed, index, tag::SENSOR, stream);
        let log_uniform = |r: &mut Rng, lo: f64, hi: f64| (r.uniform(lo.ln(), hi.ln())).exp();
        let c_on = r.uniform(0.15, 0.45);
        let c_off = (c_on * (1.0 + 0.1 * r.normal())).clamp(0.1, 0.6);
        Self {
            c_on,
            c_off,
            mismatch: r.uniform(0.02, 0.05),
            cutoff_hz: log_uniform(&mut r, 150.0, 1500.0),
            refractory_us: log_uniform(&mut r, 100.0, 1000.0),
            leak_hz: log_uniform(&mut r, 0.01, 0.2),
            shot_hz: log_uniform(&mut r, 0.001, 1.0),
            hot_pixels: r.below(6) as u32,
        }
    }
}

/// Log intensity with v2e's linear segment below `I₀`.
#[inline]
pub fn log_intensity(i: f32) -> f32 {
    const I0: f32 = 0.02;
    if i >= I0 {
        i.ln()
    } else {
        I0.ln() + (i - I0) / I0
    }
}

/// The state of one camera's pixel array.
#[derive(Clone, Debug)]
pub struct Sensor {
    params: SensorParams,
    width: usize,
    thr_on: Vec<f32>,
    thr_off: Vec<f32>,
    /// Last rendered linear intensity.
    input: Vec<f32>,
    /// Its log.
    target: Vec<f32>,
    /// Photoreceptor output (log).
    filtered: Vec<f32>,
    /// Memorized level.
    memory: Vec<f32>,
    /// Time of the last event, µs.
    last_event: Vec<f64>,
    /// Time up to which the pixel has been advanced, µs.
    clock: Vec<f64>,
    /// The pixel model's version.
    model: PixelModel,
    /// Pixels not at rest after their last update ([`PixelModel::V2`]).
    unsettled: Vec<u32>,
    /// Whether each pixel is in `unsettled`.
    live: Vec<bool>,
    rng: Rng,
}

/// One render step's constants.
struct Step {
    /// Start and end, µs.
    t0: f64,
    t1: f64,
    /// `2π f_c Δt` at full brightness.
    w_full: f32,
    /// Leak drift over the step, in units of the ON threshold.
    drift_rate: f32,
}

impl Sensor {
    /// A sensor at rest on `image` (linear intensities, row-major, `width` columns) at `t = 0`;
    /// `(seed, index, stream)` seeds its mismatch and noise.
    pub fn new(
        params: SensorParams,
        model: PixelModel,
        image: &[f32],
        width: usize,
        seed: u64,
        index: u32,
        stream: u16,
    ) -> Self {
        let mut rng = Rng::new(seed, index, tag::NOISE, stream);
        let n = image.len();
        let thr = |c: f64, rng: &mut Rng| -> Vec<f32> {
            (0..n)
                .map(|_| (c + params.mismatch * rng.normal()).max(0.03) as f32)
                .collect()
        };
        let thr_on = thr(params.c_on, &mut rng);
        let thr_off = thr(params.c_off, &mut rng);
        let target: Vec<f32> = image.iter().map(|&i| log_intensity(i)).collect();
        let memory = target
            .iter()
            .zip(&thr_on)
            .map(|(&l, &c)| l - c * (rng.unit() as f32) * 0.999)
            .collect();
        Self {
            params,
            width,
            thr_on,
            thr_off,
            input: image.to_vec(),
            filtered: target.clone(),
            target,
            memory,
            last_event: vec![f64::NEG_INFINITY; n],
            clock: vec![0.0; n],
            model,
            unsettled: Vec::new(),
            live: vec![false; n],
            rng,
        }
    }

    /// The parameters.
    pub fn params(&self) -> &SensorParams {
        &self.params
    }

    /// Emits the leak events of a static pixel up to `t` µs (its input constant, its
    /// photoreceptor settled since its clock).
    fn advance_static(&mut self, i: usize, t: f64, out: &mut Vec<Event>) {
        let t0 = self.clock[i];
        if t <= t0 {
            return;
        }
        let rate = self.params.leak_hz;
        let c = self.thr_on[i];
        let drift = rate * f64::from(c) * 1e-6; // ln units per µs
        let gap = f64::from(self.memory[i] - (self.filtered[i] - c)); // ≥ 0 while no event is due
        let mut te = t0 + gap.max(0.0) / drift;
        let period = 1e6 / rate;
        let mut fired = 0u32;
        while te < t {
            if te - self.last_event[i] < self.params.refractory_us {
                match self.model {
                    // V1 skipped the event.
                    PixelModel::V1 => {
                        te += period;
                        continue;
                    }
                    // Held until the refractory period ends (fired then, without testing the
                    // period again: `(a + b) − a` may round below `b`).
                    PixelModel::V2 => {
                        te = self.last_event[i] + self.params.refractory_us;
                        if te >= t {
                            break;
                        }
                    }
                }
            }
            out.push(self.event(i, te, true));
            self.last_event[i] = te;
            fired += 1;
            te += period;
        }
        self.memory[i] =
            (f64::from(self.memory[i]) - drift * (t - t0) + f64::from(fired) * f64::from(c)) as f32;
        self.clock[i] = t;
    }

    fn event(&self, i: usize, t: f64, on: bool) -> Event {
        Event::new(
            (i % self.width) as u16,
            (i / self.width) as u16,
            t.floor() as i64,
            on,
        )
    }

    /// Advances the pixels in `rect` from `t0` to `t1` µs, the scene now showing `image`.
    /// Pixels outside `rect` must not have changed since the last step. With
    /// [`PixelModel::V2`] the pixels not at rest after an earlier step (photoreceptor not
    /// settled, a crossing held) are advanced too, wherever they are; with [`PixelModel::V1`]
    /// only `rect`'s (the caller passes the pixels changed in the last 20 ms).
    pub fn step(&mut self, t0: f64, t1: f64, image: &[f32], rect: Rect, out: &mut Vec<Event>) {
        let dt = (t1 - t0) * 1e-6; // s (this form keeps V1's bits)
        let step = Step {
            t0,
            t1,
            w_full: std::f32::consts::TAU * self.params.cutoff_hz as f32 * dt as f32,
            drift_rate: (self.params.leak_hz * dt) as f32,
        };
        for y in rect.y0..rect.y1 {
            let row = y * self.width;
            let pixels = image.iter().enumerate().take(row + rect.x1);
            for (i, &input) in pixels.skip(row + rect.x0) {
                self.update(i, &step, input, out);
                if self.model == PixelModel::V2 && !self.at_rest(i) && !self.live[i] {
                    self.live[i] = true;
                    self.unsettled.push(i as u32);
                }
            }
        }
        if self.model == PixelModel::V2 {
            // Pixels that were not at rest: those outside `rect` still show the same image.
            let mut unsettled = core::mem::take(&mut self.unsettled);
            unsettled.retain(|&i| {
                let i = i as usize;
                let (x, y) = (i % self.width, i / self.width);
                if !(rect.x0..rect.x1).contains(&x) || !(rect.y0..rect.y1).contains(&y) {
                    self.update(i, &step, image[i], out);
                }
                let keep = !self.at_rest(i);
                self.live[i] = keep;
                keep
            });
            self.unsettled = unsettled;
        }
    }

    /// Whether pixel `i` needs no update while its input stays the same: photoreceptor settled,
    /// no crossing due (leak is advanced lazily).
    fn at_rest(&self, i: usize) -> bool {
        let d = self.filtered[i] - self.memory[i];
        (self.filtered[i] - self.target[i]).abs() < 1e-4
            && d < self.thr_on[i]
            && -d < self.thr_off[i]
    }

    /// Advances pixel `i` over `step`, its input now `input`.
    fn update(&mut self, i: usize, step: &Step, input: f32, out: &mut Vec<Event>) {
        if input == self.input[i] && self.at_rest(i) {
            return; // static, nothing pending: handled lazily
        }
        let (t0, t1) = (step.t0, step.t1);
        self.advance_static(i, t0, out);
        if input != self.input[i] {
            self.input[i] = input;
            self.target[i] = log_intensity(input);
        }
        let wdt = step.w_full * (input / 0.2).clamp(0.1, 1.0);
        let alpha = wdt / (1.0 + wdt);
        let l0 = self.filtered[i];
        let l1 = l0 + alpha * (self.target[i] - l0);
        self.filtered[i] = l1;
        let on_thr = self.thr_on[i];
        let mut m = self.memory[i] - step.drift_rate * on_thr;
        let span = l1 - l0;
        let off_thr = self.thr_off[i];
        if self.model == PixelModel::V2 {
            // A crossing held from an earlier step fires when the refractory period ends if
            // the level is beyond it then, even where it turns back before the step ends (the
            // loop below sees only the step's end).
            loop {
                let free = self.last_event[i] + self.params.refractory_us;
                if !(t0..t1).contains(&free) {
                    break;
                }
                let level = l0 + ((free - t0) / (t1 - t0)) as f32 * span;
                let on = level - m >= on_thr && l1 - m < on_thr;
                let off = m - level >= off_thr && m - l1 < off_thr;
                if !(on || off) {
                    break;
                }
                out.push(self.event(i, free, on));
                self.last_event[i] = free;
                m = if on { m + on_thr } else { m - off_thr };
            }
        }
        // Crossings of `m ± k·C` in order, ON while the level ends above `m + C+`, else OFF.
        let on = l1 - m >= on_thr;
        let thr = if on { on_thr } else { off_thr };
        let sign = if on { 1.0 } else { -1.0 };
        while sign * (l1 - m) >= thr {
            let level = m + sign * thr;
            // The crossing's time on the step's line; a level already passed at `t0` (held
            // from an earlier step) is crossed at `t0`.
            let frac = if sign * span > 0.0 {
                ((level - l0) / span).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let mut t = t0 + f64::from(frac) * (t1 - t0);
            if t - self.last_event[i] < self.params.refractory_us {
                let free = self.last_event[i] + self.params.refractory_us;
                match self.model {
                    PixelModel::V1 => break,
                    // Fires when the refractory period ends, within this step or a later one.
                    PixelModel::V2 if free < t1 => t = free,
                    PixelModel::V2 => break,
                }
            }
            out.push(self.event(i, t, on));
            self.last_event[i] = t;
            m = level;
        }
        self.memory[i] = m;
        self.clock[i] = t1;
    }

    /// Ends the recording at `t_end` µs: leak events of every pixel up to then, shot noise and
    /// hot pixels over `[0, t_end)`.
    pub fn finish(&mut self, t_end: f64, out: &mut Vec<Event>) {
        for i in 0..self.memory.len() {
            self.advance_static(i, t_end, out);
        }
        let n = self.memory.len() as u64;
        let seconds = t_end * 1e-6;
        let shots = self.rng.poisson(self.params.shot_hz * n as f64 * seconds);
        for _ in 0..shots {
            let i = self.rng.below(n) as usize;
            let t = self.rng.uniform(0.0, t_end);
            let on = self.rng.coin();
            out.push(self.event(i, t, on));
        }
        for _ in 0..self.params.hot_pixels {
            let i = self.rng.below(n) as usize;
            let rate = self.rng.uniform(50.0, 800.0);
            let mut t = self.rng.exponential(rate) * 1e6;
            while t < t_end {
                out.push(self.event(i, t, true));
                t += (self.params.refractory_us).max(self.rng.exponential(rate) * 1e6);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> SensorParams {
        SensorParams {
            c_on: 0.2,
            c_off: 0.2,
            mismatch: 0.0,
            cutoff_hz: 1e7,
            refractory_us: 0.0,
            leak_hz: 1e-9,
            shot_hz: 0.0,
            hot_pixels: 0,
        }
    }

    #[test]
    fn a_brightness_step_gives_the_right_number_of_events() {
        let img = vec![0.1f32; 4];
        let mut s = Sensor::new(params(), PixelModel::V2, &img, 2, 1, 0, 0);
        s.memory = s.target.clone();
        let mut out = Vec::new();
        let brighter: Vec<f32> = img.iter().map(|i| i * 3.0).collect(); // ln 3 = 1.0986 → 5 ON
        let all = Rect {
            x0: 0,
            x1: 2,
            y0: 0,
            y1: 2,
        };
        s.step(0.0, 1000.0, &brighter, all, &mut out);
        s.step(1000.0, 2000.0, &brighter, all, &mut out);
        assert_eq!(out.len(), 4 * 5);
        assert!(out.iter().all(|e| e.on && e.t < 1000));
        // Linear interpolation: the k-th crossing at k·0.2/1.0986 of the step.
        let mut ts: Vec<i64> = out
            .iter()
            .filter(|e| e.x == 0 && e.y == 0)
            .map(|e| e.t)
            .collect();
        ts.sort_unstable();
        assert_eq!(ts[0], (0.2f64 / 3f64.ln() * 1000.0).floor() as i64);
        out.clear();
        // Down to 0.08: the memorized level sits 1.0 above ln 0.1, so ln(0.1/0.08) + 1.0 = 1.22
        // below it → 6 OFF events per pixel.
        s.step(2000.0, 3000.0, &[0.08; 4], all, &mut out);
        assert_eq!(out.iter().filter(|e| !e.on).count(), 4 * 6);
        assert_eq!(out.len(), 4 * 6);
    }

    /// One pixel, no mismatch or noise, instant photoreceptor unless `cutoff_hz` is given.
    fn one_pixel(model: PixelModel, refractory_us: f64, cutoff_hz: f64) -> Sensor {
        let mut p = params();
        p.refractory_us = refractory_us;
        p.cutoff_hz = cutoff_hz;
        let mut s = Sensor::new(p, model, &[0.1], 1, 1, 0, 0);
        s.memory = s.target.clone();
        s
    }

    const ONE: Rect = Rect {
        x0: 0,
        x1: 1,
        y0: 0,
        y1: 1,
    };

    #[test]
    fn held_crossings_fire_when_the_refractory_period_ends() {
        // 0.1 → 0.5 at once: ln 5 = 1.609, eight crossings of 0.2, the first at 0.2 / 1.609 of
        // the first step (124.3 µs); 600 µs refractory.
        let times = |model| {
            let mut s = one_pixel(model, 600.0, 1e7);
            let mut out = Vec::new();
            s.step(0.0, 1000.0, &[0.5], ONE, &mut out);
            s.step(1000.0, 2000.0, &[0.5], ONE, &mut out);
            out.iter().map(|e| e.t).collect::<Vec<_>>()
        };
        // V2: every 600 µs from the first, across the step boundary.
        assert_eq!(times(PixelModel::V2), [124, 724, 1324, 1924]);
        // V1: a held crossing waited for the next step's start.
        assert_eq!(times(PixelModel::V1), [124, 1000]);
    }

    #[test]
    fn a_held_crossing_fires_even_where_the_level_turns_back_later_in_the_step() {
        // Up to 0.5 (two ON, the third held to 1324 µs), then back down to 0.1 in the next
        // step: at 1324 µs the level is still above the held one (it falls below at about
        // 1627 µs), so the ON fires then; the OFF crossings that follow wait for the
        // refractory period (the first, due at 1752 µs, fires at 1924).
        let mut s = one_pixel(PixelModel::V2, 600.0, 1e7);
        let mut out = Vec::new();
        s.step(0.0, 1000.0, &[0.5], ONE, &mut out);
        s.step(1000.0, 2000.0, &[0.1], ONE, &mut out);
        let got: Vec<(i64, bool)> = out.iter().map(|e| (e.t, e.on)).collect();
        assert_eq!(got, [(124, true), (724, true), (1324, true), (1924, false)]);
    }

    #[test]
    fn pixels_settle_after_their_image_stops_changing() {
        // 0.1 → 0.3 (ln 3 = 1.099: five crossings of 0.2) through a 10 Hz photoreceptor
        // (τ = 16 ms): about one crossing in the first 4 ms step, the rest over the next
        // ~100 ms, when no render touches the pixel any more (empty rectangles).
        let run = |model| {
            let mut s = one_pixel(model, 0.0, 10.0);
            let mut out = Vec::new();
            s.step(0.0, 4000.0, &[0.3], ONE, &mut out);
            for k in 1..100 {
                let t = f64::from(k) * 4000.0;
                s.step(t, t + 4000.0, &[0.3], Rect::default(), &mut out);
            }
            out
        };
        let v2 = run(PixelModel::V2);
        assert_eq!(v2.len(), 5);
        assert!(v2.iter().all(|e| e.on));
        assert!(v2.windows(2).all(|w| w[0].t < w[1].t));
        assert!(v2[4].t > 20_000, "{v2:?}");
        // V1 froze the pixel with its photoreceptor a fifth of the way there.
        assert_eq!(run(PixelModel::V1).len(), 1);
    }

    #[test]
    fn a_leak_event_held_by_the_refractory_period_fires_when_it_ends() {
        // A static pixel whose leak event is due 100 µs after an event, refractory 500 µs.
        let mut p = params();
        p.refractory_us = 500.0;
        p.leak_hz = 1.0;
        let mut s = Sensor::new(p, PixelModel::V2, &[0.1], 1, 1, 0, 0);
        // Memory 100 µs of drift (0.2 · 1e-4 ln units) above the ON threshold's reach.
        s.memory[0] = s.filtered[0] - 0.2 + 0.2 * 1e-4;
        s.last_event[0] = 0.0;
        let mut out = Vec::new();
        s.advance_static(0, 2000.0, &mut out);
        assert_eq!(out.iter().map(|e| e.t).collect::<Vec<_>>(), [500]);
        // Times where `(last + refractory) − last < refractory` in f64: the held event still
        // fires, once (the loop tested the period again, and spun forever).
        let (last, refractory) = (1_527_549.237_953_228, 329.562_123_165_479_53);
        assert!((last + refractory) - last < refractory);
        s.params.refractory_us = refractory;
        s.memory[0] = s.filtered[0] - 0.2 + 0.2 * 1e-4;
        s.clock[0] = last;
        s.last_event[0] = last;
        out.clear();
        s.advance_static(0, last + 2000.0, &mut out);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].t, (last + refractory).floor() as i64);
    }

    #[test]
    fn static_pixels_leak_and_noise_at_the_set_rates() {
        let n = 10_000;
        let img = vec![0.3f32; n];
        let mut p = params();
        p.leak_hz = 0.1;
        p.shot_hz = 0.05;
        p.hot_pixels = 0;
        let mut s = Sensor::new(p, PixelModel::V2, &img, 100, 3, 0, 0);
        let mut out = Vec::new();
        s.finish(10e6, &mut out);
        let on = out.len() as f64;
        // leak ≈ 0.1 Hz · 10 s · 10⁴ = 10⁴, shot ≈ 0.05 · 10 · 10⁴ = 5·10³
        assert!((on - 15_000.0).abs() < 1_000.0, "{on} events");
        assert!(out.iter().all(|e| e.t >= 0 && e.t < 10_000_000));
    }
}

//! DVS pixel model (after ESIM and v2e) on log intensity, with noise.
//!
//! Per pixel: log intensity `L = ln I` above `I₀ = 0.02` and linear below it (v2e's lin-log,
//! continuous with its slope), a first-order photoreceptor low-pass whose cut-off scales with
//! intensity (`f_c · clamp(I / 0.2, 0.1, 1)`, implicit Euler per render step), a memorized
//! level `m` and ON/OFF thresholds `C±` with per-pixel mismatch fixed for the recording. Between
//! two renders the filtered level moves linearly; every crossing of `m + k·C+` (or `m − k·C−`)
//! is an event, timestamped by linear interpolation to the crossing, and moves `m` to the
//! crossed level. An event within the refractory period of the pixel's previous one is dropped
//! together with the rest of that step's crossings (the pixel catches up later, rate-limited).
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
    rng: Rng,
}

impl Sensor {
    /// A sensor at rest on `image` (linear intensities, row-major, `width` columns) at `t = 0`;
    /// `(seed, index, stream)` seeds its mismatch and noise.
    pub fn new(
        params: SensorParams,
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
            if te - self.last_event[i] >= self.params.refractory_us {
                out.push(self.event(i, te, true));
                self.last_event[i] = te;
                fired += 1;
            }
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
    /// Pixels outside `rect` must not have changed since their last update.
    #[allow(clippy::needless_range_loop)] // several parallel arrays share the index
    pub fn step(&mut self, t0: f64, t1: f64, image: &[f32], rect: Rect, out: &mut Vec<Event>) {
        let dt = (t1 - t0) * 1e-6;
        let w_full = std::f32::consts::TAU * self.params.cutoff_hz as f32 * dt as f32;
        let drift_rate = (self.params.leak_hz * dt) as f32;
        let refractory = self.params.refractory_us;
        for y in rect.y0..rect.y1 {
            for i in y * self.width + rect.x0..y * self.width + rect.x1 {
                let input = image[i];
                let settled = (self.filtered[i] - self.target[i]).abs() < 1e-4;
                let d = self.filtered[i] - self.memory[i];
                if input == self.input[i] && settled && d < self.thr_on[i] && -d < self.thr_off[i] {
                    continue; // static, nothing pending: handled lazily
                }
                self.advance_static(i, t0, out);
                if input != self.input[i] {
                    self.input[i] = input;
                    self.target[i] = log_intensity(input);
                }
                let wdt = w_full * (input / 0.2).clamp(0.1, 1.0);
                let alpha = wdt / (1.0 + wdt);
                let l0 = self.filtered[i];
                let l1 = l0 + alpha * (self.target[i] - l0);
                self.filtered[i] = l1;
                let on_thr = self.thr_on[i];
                let mut m = self.memory[i] - drift_rate * on_thr;
                let span = l1 - l0;
                if l1 - m >= on_thr {
                    while l1 - m >= on_thr {
                        let level = m + on_thr;
                        let frac = if span > 0.0 {
                            ((level - l0) / span).clamp(0.0, 1.0)
                        } else {
                            0.0
                        };
                        let t = t0 + f64::from(frac) * (t1 - t0);
                        if t - self.last_event[i] < refractory {
                            break;
                        }
                        out.push(self.event(i, t, true));
                        self.last_event[i] = t;
                        m = level;
                    }
                } else {
                    let off_thr = self.thr_off[i];
                    while m - l1 >= off_thr {
                        let level = m - off_thr;
                        let frac = if span < 0.0 {
                            ((level - l0) / span).clamp(0.0, 1.0)
                        } else {
                            0.0
                        };
                        let t = t0 + f64::from(frac) * (t1 - t0);
                        if t - self.last_event[i] < refractory {
                            break;
                        }
                        out.push(self.event(i, t, false));
                        self.last_event[i] = t;
                        m = level;
                    }
                }
                self.memory[i] = m;
                self.clock[i] = t1;
            }
        }
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
        let mut s = Sensor::new(params(), &img, 2, 1, 0, 0);
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

    #[test]
    fn refractory_period_limits_the_rate() {
        let img = vec![0.1f32; 1];
        let mut p = params();
        p.refractory_us = 600.0;
        let mut s = Sensor::new(p, &img, 1, 1, 0, 0);
        s.memory = s.target.clone();
        let mut out = Vec::new();
        let all = Rect {
            x0: 0,
            x1: 1,
            y0: 0,
            y1: 1,
        };
        s.step(0.0, 1000.0, &[0.5], all, &mut out);
        assert_eq!(out.len(), 1);
        s.step(1000.0, 2000.0, &[0.5], all, &mut out);
        assert_eq!(out.len(), 2);
    }

    #[test]
    fn static_pixels_leak_and_noise_at_the_set_rates() {
        let n = 10_000;
        let img = vec![0.3f32; n];
        let mut p = params();
        p.leak_hz = 0.1;
        p.shot_hz = 0.05;
        p.hot_pixels = 0;
        let mut s = Sensor::new(p, &img, 100, 3, 0, 0);
        let mut out = Vec::new();
        s.finish(10e6, &mut out);
        let on = out.len() as f64;
        // leak ≈ 0.1 Hz · 10 s · 10⁴ = 10⁴, shot ≈ 0.05 · 10 · 10⁴ = 5·10³
        assert!((on - 15_000.0).abs() < 1_000.0, "{on} events");
        assert!(out.iter().all(|e| e.t >= 0 && e.t < 10_000_000));
    }
}

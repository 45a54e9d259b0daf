//! MCU latency from measured instruction counts: `evpose budget --target cortex-m7@480`.
//!
//! The firmware counts the instructions of every pipeline stage under QEMU (`-icount`, exact to
//! one SysTick tick; `tests/firmware_qemu.rs`). Those counts, reduced to per-unit costs
//! (instructions per rasterized event, per point-layer MAC, per MAC after pooling, per sampled
//! point, per SimDR bin decoded), are stored with the commit and model they were measured on in
//! `firmware/measured.json`, embedded here. A model's latency on a target is then
//! `instructions × CPI / f`, with a stated cycles-per-instruction assumption per core: QEMU
//! counts instructions, not cycles, and no cycle-accurate model of these cores is at hand.
//!
//! | core | CPI assumed | why |
//! |---|---|---|
//! | Cortex-M7 | 1.0 | dual-issue, 6-stage; the int8 loops are load + SMLAD pairs from TCM: one per cycle, no credit taken for dual issue |
//! | Cortex-M4 | 1.25 | single-issue, 3-stage; loads take 2 cycles, one load per 2–3 instructions in the kernels |
//! | Cortex-M33 | 1.2 | single-issue, 3-stage like the M4, with the DSP extension (assumed present) |
//!
//! The M4 and M33 cannot run the M7's assembly requantization (`VMAXNM`, `VCVTN`; feature
//! `arm-fpv5`; they run an FPv4 form of it) and have no double-precision FPU: their
//! rasterization, point layers and FC layers take the costs of the firmware built for the
//! Cortex-M4 (`-C target-cpu=cortex-m4`, `arm-dsp` alone, so f64 in software and the
//! rasterizer's integer slice fractions), measured on QEMU's Cortex-M4 beside the M7's
//! (`tests/firmware_qemu.rs`, `cortex_m4_build_matches_the_host_core_under_qemu`). Their input
//! decoding, sampling, decoding and confidences take the M7's counts: the M4 build's were
//! within 5.1 % of them at stop 30 (input 317.6–329.8 k against 317.8–329.9 k per window,
//! sampling 120.2–121.9 k against 117.2–118.9 k, decoding 47.4 k against 48.6 k, confidences
//! 327.6 k against 311.8 k; at stop 29 input 414.2–428.5 k against 398.0–413.2 k). The M33
//! runs the M4 build's instructions (ARMv8-M Mainline with the DSP extension), not a build of
//! its own.
//! Caches and flash wait states are not modelled.
//!
//! The input stage is the firmware's own `EVS1` stream by default; `--input evt3|evt21` takes
//! the core's decoding of a Prophesee sensor's words instead ([`Input`]), as the boot check
//! measured it on both builds (the M4 build's own counts for the M4 and M33).

use anyhow::{anyhow, bail, Result};
use serde::{Deserialize, Serialize};

use crate::budget::ModelBudget;

/// The paper's real-time criterion: the shortest DHP19 test window spans about 36 ms.
pub const REAL_TIME_MS: f64 = 36.0;

/// Per-unit instruction costs the firmware measured under QEMU.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Measured {
    /// Commit of the firmware that was measured.
    pub commit: String,
    /// The model it ran.
    pub model: String,
    /// Events per window in the measurement.
    pub window_events: u64,
    /// Reading the firmware's input stream (`EVS1` words → events), instructions per event.
    pub instructions_per_input_event: f64,
    /// Decoding a Prophesee sensor's EVT 3.0 words ([`evpose_core::evt`]), instructions per
    /// event: the boot check's words of the first street window (faery's; 2.9 words an event,
    /// as sparse events rarely share a row; vector-heavy data was not measured).
    pub instructions_per_evt3_event: f64,
    /// Decoding EVT 2.1 words in a GenX320's byte order, instructions per event: the boot
    /// check's (evutils's words; one event each, and a time-high word per 64 µs with events:
    /// 1.37 words an event).
    pub instructions_per_evt21_event: f64,
    /// EVT 3.0 decoding in the firmware built for the Cortex-M4, instructions per event.
    pub instructions_per_evt3_event_without_arm_fpv5: f64,
    /// EVT 2.1 decoding in the firmware built for the Cortex-M4, instructions per event.
    pub instructions_per_evt21_event_without_arm_fpv5: f64,
    /// Rasterization, instructions per event (window close included).
    pub instructions_per_event: f64,
    /// Rasterization on a core without the M7's FPU (M4, M33): the firmware built for the
    /// Cortex-M4, instructions per event.
    pub instructions_per_event_without_arm_fpv5: f64,
    /// Point layers, instructions per MAC (`per_point / macs_per_point`), over widened weights
    /// (`evpose_core::Plan::widened`, what the firmware runs).
    pub instructions_per_point_mac: f64,
    /// Point layers over the row-major weights (`evpose_core::Plan::new`: no extra RAM),
    /// instructions per MAC ([`Weights::RowMajor`]).
    pub instructions_per_point_mac_row_major: f64,
    /// After pooling (FC layers and heads), instructions per MAC.
    pub instructions_per_vector_mac: f64,
    /// Point layers on a core that cannot build the `arm-fpv5` requantization (M4, M33),
    /// instructions per MAC: the firmware built for the Cortex-M4 with `arm-dsp` alone (over
    /// widened weights, as the M7's figure).
    pub instructions_per_point_mac_without_arm_fpv5: f64,
    /// After pooling on such a core, instructions per MAC.
    pub instructions_per_vector_mac_without_arm_fpv5: f64,
    /// Point layers over the row-major weights on such a core, instructions per MAC.
    pub instructions_per_point_mac_row_major_without_arm_fpv5: f64,
    /// Sampling, instructions per window whatever `N` (drawing from the window's `M` points,
    /// M ≈ 2,900): fitted, with the per-point figure, through two firmware runs on the same
    /// windows, 113,680 instructions at N = 256 (this model) and 209,360 at N = 2,048 (the
    /// earlier 2,048-point model); re-based on the 123,920 that the same windows measure at
    /// N = 256 since e0ea59f (the slope kept). Since 700217b a point's slice and row are split
    /// from its row bin when it is read: the same windows measure 129,200 at N = 256, all of
    /// the 5,280 more counted per sampled point (+20.6), this intercept kept. Re-based at
    /// 9ac3718 on the 117,693 they measure at N = 256 since the selection loop writes through
    /// an iterator (the slope kept), and at 7f9ef15 on 135,640: the same code, inlined
    /// differently after unrelated changes to the image (stage counts move by up to 15 % so),
    /// at 3b0810e on 119,480, and at 49667e0 on 115,040.
    pub sample_instructions_per_window: f64,
    /// Sampling, instructions per sampled point.
    pub instructions_per_sampled_point: f64,
    /// SimDR decoding, instructions per logit.
    pub instructions_per_bin: f64,
    /// Joint confidences ([`evpose_core::confidence`]), instructions per logit.
    pub confidence_instructions_per_bin: f64,
}

/// The measurement shipped with this build (`firmware/measured.json`).
pub fn measured() -> Result<Measured> {
    serde_json::from_str(include_str!("../../firmware/measured.json"))
        .map_err(|e| anyhow!("firmware/measured.json: {e}"))
}

/// A Cortex-M core this estimate knows.
#[derive(Clone, Copy, Debug, Serialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum Core {
    /// Cortex-M7.
    CortexM7,
    /// Cortex-M4 (with FPU and DSP).
    CortexM4,
    /// Cortex-M33 (with the DSP extension).
    CortexM33,
}

impl Core {
    /// Cycles per instruction assumed (module documentation).
    pub fn cpi(self) -> f64 {
        match self {
            Core::CortexM7 => 1.0,
            Core::CortexM4 => 1.25,
            Core::CortexM33 => 1.2,
        }
    }
    /// Whether the core runs the assembly requantization of `kernels::arm` (feature
    /// `arm-fpv5`): the M7 only. The M4's FPv4 lacks `VMAXNM`; the M33's single-precision FPv5
    /// has it, but Rust's inline assembly takes FPU register operands only where rustc
    /// reports `vfp2` (a double-precision FPU).
    pub fn fpv5_kernels(self) -> bool {
        self == Core::CortexM7
    }
    /// The name `--target` takes.
    pub fn name(self) -> &'static str {
        match self {
            Core::CortexM7 => "cortex-m7",
            Core::CortexM4 => "cortex-m4",
            Core::CortexM33 => "cortex-m33",
        }
    }
}

/// A core at a clock.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct Target {
    /// The core.
    pub core: Core,
    /// Clock, MHz.
    pub mhz: f64,
}

impl std::str::FromStr for Target {
    type Err = anyhow::Error;
    /// `cortex-m7@480`, `cortex-m4@168`, `cortex-m33@160` (core, then the clock in MHz).
    fn from_str(s: &str) -> Result<Self> {
        let (core, mhz) = s
            .split_once('@')
            .ok_or_else(|| anyhow!("target {s:?}: expected CORE@MHZ, e.g. cortex-m7@480"))?;
        let core = [Core::CortexM7, Core::CortexM4, Core::CortexM33]
            .into_iter()
            .find(|c| c.name() == core.to_ascii_lowercase())
            .ok_or_else(|| {
                anyhow!("target {s:?}: unknown core {core:?} (cortex-m7, cortex-m4, cortex-m33)")
            })?;
        let mhz: f64 = mhz
            .parse()
            .map_err(|_| anyhow!("target {s:?}: clock {mhz:?} is not a number of MHz"))?;
        if !(mhz.is_finite() && mhz > 0.0) {
            bail!("target {s:?}: the clock must be positive");
        }
        Ok(Target { core, mhz })
    }
}

impl std::fmt::Display for Target {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}@{}", self.core.name(), self.mhz)
    }
}

/// The stream an MCU reads its events from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Input {
    /// The firmware's own `EVS1` words (what its QEMU runs read; 4 bytes an event).
    #[default]
    Evs1,
    /// A Prophesee sensor's EVT 3.0 words (an IMX636's default encoding), decoded by the core.
    Evt3,
    /// EVT 2.1 words in a GenX320's byte order (its default encoding), decoded by the core.
    Evt21,
}

impl Input {
    /// Instructions per event on a core with (`fpv5`: the M7's build) or without it.
    pub fn per_event(self, k: &Measured, fpv5: bool) -> f64 {
        match (self, fpv5) {
            // The M4 build's EVS1 decoding was within 5 % of the M7's (module documentation).
            (Input::Evs1, _) => k.instructions_per_input_event,
            (Input::Evt3, true) => k.instructions_per_evt3_event,
            (Input::Evt3, false) => k.instructions_per_evt3_event_without_arm_fpv5,
            (Input::Evt21, true) => k.instructions_per_evt21_event,
            (Input::Evt21, false) => k.instructions_per_evt21_event_without_arm_fpv5,
        }
    }
}

/// The point layers' weights an estimate assumes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Weights {
    /// Widened once at start-up (`evpose_core::Plan::widened`, what the firmware runs): the
    /// fastest, for twice the int8 point layers' weight bytes in RAM.
    #[default]
    Widened,
    /// The blob's row-major int8 weights, read in place (`evpose_core::Plan::new`): no RAM
    /// beyond the scratch.
    RowMajor,
}

/// One window's estimated cost on a target.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Latency {
    /// The target.
    pub target: String,
    /// The point layers' weights assumed.
    pub weights: Weights,
    /// The input stream assumed.
    pub input_stream: Input,
    /// Cycles per instruction assumed.
    pub cpi: f64,
    /// Instructions per window, by stage: reading the input.
    pub input: f64,
    /// Rasterization.
    pub rasterize: f64,
    /// Sampling.
    pub sample: f64,
    /// Inference.
    pub infer: f64,
    /// Decoding.
    pub decode: f64,
    /// Joint confidences.
    pub confidence: f64,
    /// All stages.
    pub instructions: f64,
    /// Milliseconds per window.
    pub ms: f64,
    /// Whether `ms` ≤ [`REAL_TIME_MS`].
    pub real_time: bool,
    /// Largest point count whose window meets [`REAL_TIME_MS`] (0: none does).
    pub max_real_time_points: u64,
}

/// The cost of one window of `window_events` events read from `input` through the model of `m`
/// (at `m.points` points) on `target` with the point layers over `weights`, from the per-unit
/// costs `k`.
pub fn estimate(
    m: &ModelBudget,
    (window_events, input): (u64, Input),
    k: &Measured,
    target: Target,
    weights: Weights,
) -> Latency {
    let fpv5 = target.core.fpv5_kernels();
    let point_mac = match (fpv5, weights) {
        (true, Weights::Widened) => k.instructions_per_point_mac,
        (true, Weights::RowMajor) => k.instructions_per_point_mac_row_major,
        (false, Weights::Widened) => k.instructions_per_point_mac_without_arm_fpv5,
        (false, Weights::RowMajor) => k.instructions_per_point_mac_row_major_without_arm_fpv5,
    };
    let vector_mac = if fpv5 {
        k.instructions_per_vector_mac
    } else {
        k.instructions_per_vector_mac_without_arm_fpv5
    };
    let per_point = point_mac * m.macs_per_point as f64 + k.instructions_per_sampled_point;
    let bins = (m.joints * (m.width + m.height)) as f64;
    let input_stream = input;
    let input = input_stream.per_event(k, fpv5) * window_events as f64;
    let per_event = if fpv5 {
        k.instructions_per_event
    } else {
        k.instructions_per_event_without_arm_fpv5
    };
    let rasterize = per_event * window_events as f64;
    let fixed = input
        + rasterize
        + k.sample_instructions_per_window
        + vector_mac * m.macs_after_pooling as f64
        + (k.instructions_per_bin + k.confidence_instructions_per_bin) * bins;
    let instructions = fixed + per_point * m.points as f64;
    let cycles_per_ms = target.mhz * 1e3 / target.core.cpi();
    let ms = instructions / cycles_per_ms;
    let spare = REAL_TIME_MS * cycles_per_ms - fixed;
    let max_real_time_points = if spare > 0.0 && per_point > 0.0 {
        (spare / per_point).floor() as u64
    } else {
        0
    };
    Latency {
        target: target.to_string(),
        weights,
        input_stream,
        cpi: target.core.cpi(),
        input,
        rasterize,
        sample: k.sample_instructions_per_window
            + k.instructions_per_sampled_point * m.points as f64,
        infer: point_mac * (m.macs_per_point * m.points) as f64
            + vector_mac * m.macs_after_pooling as f64,
        decode: k.instructions_per_bin * bins,
        confidence: k.confidence_instructions_per_bin * bins,
        instructions,
        ms,
        real_time: ms <= REAL_TIME_MS,
        max_real_time_points,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_parse_and_reject() {
        let t: Target = "cortex-m7@480".parse().unwrap();
        assert_eq!((t.core, t.mhz), (Core::CortexM7, 480.0));
        assert_eq!(t.to_string(), "cortex-m7@480");
        for bad in ["cortex-m7", "cortex-m0@48", "cortex-m4@fast", "cortex-m4@0"] {
            assert!(bad.parse::<Target>().is_err(), "{bad}");
        }
    }

    #[test]
    fn shipped_measurement_parses() {
        let k = measured().unwrap();
        assert!(k.instructions_per_point_mac > 0.0 && k.instructions_per_event > 0.0);
    }

    /// The estimate adds up the stages, scales with the clock and the CPI, and the largest
    /// real-time point count is the boundary.
    #[test]
    fn estimate_adds_up_and_finds_the_boundary() {
        let k = Measured {
            commit: "test".into(),
            model: "test".into(),
            window_events: 100,
            instructions_per_input_event: 1.0,
            instructions_per_evt3_event: 4.0,
            instructions_per_evt21_event: 6.0,
            instructions_per_evt3_event_without_arm_fpv5: 5.0,
            instructions_per_evt21_event_without_arm_fpv5: 7.0,
            instructions_per_event: 10.0,
            instructions_per_event_without_arm_fpv5: 30.0,
            instructions_per_point_mac: 2.0,
            instructions_per_point_mac_row_major: 2.5,
            instructions_per_point_mac_row_major_without_arm_fpv5: 3.5,
            instructions_per_vector_mac: 1.0,
            instructions_per_point_mac_without_arm_fpv5: 3.0,
            instructions_per_vector_mac_without_arm_fpv5: 2.0,
            sample_instructions_per_window: 50.0,
            instructions_per_sampled_point: 5.0,
            instructions_per_bin: 1.0,
            confidence_instructions_per_bin: 3.0,
        };
        let blob = crate::assets::default_blob();
        let model = evpose_core::Model::parse(blob.bytes()).unwrap();
        let m = crate::budget::model_budget(&model, 256);
        let t: Target = "cortex-m7@480".parse().unwrap();
        let l = estimate(&m, (7500, Input::Evs1), &k, t, Weights::Widened);
        let bins = (m.joints * (m.width + m.height)) as f64;
        let want = 7500.0 * 11.0
            + 50.0
            + 256.0 * 5.0
            + 2.0 * (m.macs_per_point * 256) as f64
            + m.macs_after_pooling as f64
            + 4.0 * bins;
        assert!(
            (l.instructions - want).abs() < 1e-6,
            "{} vs {want}",
            l.instructions
        );
        let sum = l.input + l.rasterize + l.sample + l.infer + l.decode + l.confidence;
        assert!((sum - want).abs() < 1e-6);
        assert!((l.ms - want / 480e3).abs() < 1e-9);
        // The M4 takes the M4 build's costs: the rasterizer's and the per-MAC ones.
        let t4: Target = "cortex-m4@240".parse().unwrap();
        let m4 = estimate(&m, (7500, Input::Evs1), &k, t4, Weights::Widened);
        let want4 =
            want + 7500.0 * 20.0 + (m.macs_per_point * 256) as f64 + m.macs_after_pooling as f64;
        assert!((m4.ms - want4 * 1.25 / 240e3).abs() < 1e-9);
        // Over row-major weights the point layers take their own per-MAC costs, with and
        // without the FPv5 requantization; nothing else changes.
        let point = (m.macs_per_point * 256) as f64;
        let rm = estimate(&m, (7500, Input::Evs1), &k, t, Weights::RowMajor);
        assert!((rm.instructions - (want + 0.5 * point)).abs() < 1e-6);
        assert_eq!(rm.weights, Weights::RowMajor);
        let rm4 = estimate(&m, (7500, Input::Evs1), &k, t4, Weights::RowMajor);
        assert!((rm4.ms - (want4 + 0.5 * point) * 1.25 / 240e3).abs() < 1e-9);
        // A Prophesee sensor's words change the input stage alone: the M7's decoding costs on
        // the M7, the M4 build's on the M4.
        for (input, m7, m4) in [(Input::Evt3, 4.0, 5.0), (Input::Evt21, 6.0, 7.0)] {
            let e7 = estimate(&m, (7500, input), &k, t, Weights::Widened);
            assert!((e7.instructions - (want + 7500.0 * (m7 - 1.0))).abs() < 1e-6);
            assert_eq!((e7.input, e7.input_stream), (7500.0 * m7, input));
            let e4 = estimate(&m, (7500, input), &k, t4, Weights::Widened);
            assert!((e4.ms - (want4 + 7500.0 * (m4 - 1.0)) * 1.25 / 240e3).abs() < 1e-9);
        }
        // At the largest real-time count the window fits in 36 ms; one point more does not.
        let at = |n: u64| {
            let mut mb = m.clone();
            mb.points = n;
            estimate(&mb, (7500, Input::Evs1), &k, t, Weights::Widened).ms
        };
        let n = l.max_real_time_points;
        assert!(
            n > 0 && at(n) <= REAL_TIME_MS && at(n + 1) > REAL_TIME_MS,
            "{n}"
        );
    }
}

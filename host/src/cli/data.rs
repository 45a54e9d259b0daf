//! `evpose dataset` and `evpose eval`: arguments, progress and tables; the work is in
//! [`crate::dataset`] and [`crate::eval`].

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Result};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};

use crate::dataset::{self, Dataset, DatasetOptions, LabelRule, SplitFilter};
use crate::eval::{self, EvalReport};
use crate::run::setup::EngineKind;
use crate::{dhp19, model};
use evpose_core::smooth::{LagParams, SmoothParams};

/// Arguments of `evpose dataset` (stable: scripts call them).
#[derive(Args, Debug)]
pub struct DatasetArgs {
    /// Directory of recordings with ground truth: an `evpose sim` output, or DHP19 files
    /// (`S<subject>_<session>_<movement>.aedat` with its Vicon `.mat`).
    #[arg(long)]
    pub recordings: PathBuf,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Window rule: `mean` (30,000 events over all cameras, mean label) or `last` (7,500 per
    /// camera, label at the last event).
    #[arg(long, value_enum, default_value_t = LabelRule::Mean)]
    pub label: LabelRule,
    /// Points per sample.
    #[arg(long, default_value_t = evpose_core::pipeline::DEFAULT_POINTS)]
    pub points: usize,
    /// Camera channels, comma-separated (DHP19's front pair by default).
    #[arg(long, value_delimiter = ',', default_value = "2,3")]
    pub cameras: Vec<u8>,
    /// Recordings of which subjects: `train` drops windows under 1,024 points, as the paper.
    #[arg(long, value_enum, default_value_t = SplitFilter::All)]
    pub split: SplitFilter,
    /// Seed of the point sampler.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// DHP19's preprocessing (hot pixels ≥ 10,000 events dropped, 70 ms background-activity
    /// filter): `on`/`off`; default on for real DHP19 files, off for simulated ones.
    #[arg(long)]
    pub dhp19_filters: Option<OnOff>,
    /// Also write the windows of recordings without a person (the simulator's `no-person`
    /// scenes) with `person.npy` = 0, a zero label and every joint masked, for training a
    /// model to spread its SimDR mass when it sees no body. Without it they are skipped.
    #[arg(long)]
    pub person_free: bool,
}

/// A switch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum OnOff {
    /// On.
    On,
    /// Off.
    Off,
}

fn bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{{bar:40}} {{pos}}/{{len}} {what} {{elapsed}} (eta {{eta}})"
        ))
        .expect("valid template"),
    );
    bar
}

/// Runs `evpose dataset`.
pub fn dataset(a: &DatasetArgs) -> Result<()> {
    let opts = DatasetOptions {
        label: a.label,
        points: a.points,
        cameras: a.cameras.clone(),
        split: a.split,
        seed: a.seed,
        dhp19_filters: a.dhp19_filters.map(|s| s == OnOff::On),
        person_free: a.person_free,
    };
    let start = Instant::now();
    let bar = bar(0, "recordings");
    let m = dataset::build(&a.recordings, &a.out, &opts, |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })?;
    bar.finish_and_clear();
    eprintln!(
        "wrote {} samples ({} windows dropped under {} points) from {} recordings to {} in {:.1} s",
        m.samples,
        m.dropped_short,
        dataset::MIN_TRAIN_POINTS,
        m.recordings.len(),
        a.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Arguments of `evpose eval` (stable: scripts call them).
#[derive(Args, Debug)]
#[command(group(clap::ArgGroup::new("predictor").required(true).args(["model", "baseline"])))]
pub struct EvalArgs {
    /// The dataset (`evpose dataset --out`).
    #[arg(long)]
    pub data: PathBuf,
    /// The model: `.onnx` (tract, f32) or `.evq` (i8, f32).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Engine (default: i8 for an `.evq`, f32 otherwise).
    #[arg(long, value_enum, conflicts_with = "baseline")]
    pub engine: Option<EngineKind>,
    /// Instead of a model: predict the mean pose of this training dataset (a sanity check).
    #[arg(long, conflicts_with = "model")]
    pub baseline: Option<PathBuf>,
    /// Write the report as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write a PNG bar chart of the error per joint (2-D px and 3-D mm).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Also measure the predictions after the temporal filters (`evpose_core::smooth`: the
    /// causal One-Euro and the fixed-lag mean), run over each recording's windows in order.
    #[arg(long)]
    pub smooth: bool,
    /// Filter cut-off at rest, Hz (with --smooth).
    #[arg(long, default_value_t = SmoothParams::DEFAULT.min_cutoff_hz, requires = "smooth")]
    pub min_cutoff: f32,
    /// Filter cut-off increase per px/s of motion (with --smooth).
    #[arg(long, default_value_t = SmoothParams::DEFAULT.beta, requires = "smooth")]
    pub beta: f32,
    /// Confidence at which a joint takes the filter's full step (with --smooth).
    #[arg(long, default_value_t = SmoothParams::DEFAULT.full_confidence, requires = "smooth")]
    pub full_confidence: f32,
    /// Windows each side of the fixed-lag filter (with --smooth).
    #[arg(long, default_value_t = LagParams::DEFAULT.lag, value_parser = super::lag_in_range,
          requires = "smooth")]
    pub lag: usize,
}

impl EvalArgs {
    /// The filter parameters of `--smooth`, or why they make no filter.
    pub fn smooth_params(&self) -> Result<SmoothParams> {
        let p = SmoothParams {
            min_cutoff_hz: self.min_cutoff,
            beta: self.beta,
            full_confidence: self.full_confidence,
            ..SmoothParams::DEFAULT
        };
        p.check().map_err(|e| {
            let option = match e.field {
                "min_cutoff_hz" => "--min-cutoff",
                "beta" => "--beta",
                "full_confidence" => "--full-confidence",
                other => other,
            };
            anyhow::anyhow!("{option}: {e}")
        })?;
        Ok(p)
    }
}

/// Says so when the model records another point count than the dataset's samples have: the
/// figures are then not those `evpose run` would give (it samples the model's count).
fn warn_points(blob: &model::AlignedBlob, ds: &Dataset) {
    let recorded = evpose_core::Model::parse(blob.bytes()).map_or(0, |m| m.preprocessing().points);
    let have = ds.manifest.points;
    if recorded != 0 && recorded as usize != have {
        eprintln!(
            "warning: the model takes {recorded} points, the dataset's samples have {have}: \
             these figures are not those of `evpose run` (build the dataset with --points {recorded})"
        );
    }
}

/// Runs `evpose eval`.
pub fn eval(a: &EvalArgs) -> Result<()> {
    // Before any work: parameters that make no filter are refused.
    let smooth = a.smooth.then(|| a.smooth_params()).transpose()?;
    let ds = Dataset::open(&a.data)?;
    if ds.is_empty() {
        bail!("{}: no samples", a.data.display());
    }
    let front = dhp19::FRONT_CHANNELS.map(|c| dhp19::bundled_camera(c).map(|cam| (c, cam)));
    let [Ok(fa), Ok(fb)] = front else {
        bail!("cannot load the DHP19 front cameras");
    };
    let start = Instant::now();
    let bar = bar(ds.len() as u64, "samples");
    let (predictions, predictor) = match (&a.baseline, &a.model) {
        (Some(train), _) => (
            eval::mean_pose(&Dataset::open(train)?, &ds)?
                .into_iter()
                .map(|joints| eval::Prediction {
                    joints,
                    confidence: [1.0; dataset::JOINTS],
                })
                .collect(),
            format!("mean pose of {}", train.display()),
        ),
        (None, Some(path)) => {
            let is_onnx = path.extension().is_some_and(|e| e == "onnx");
            let engine = a.engine.unwrap_or(if is_onnx {
                EngineKind::F32
            } else {
                EngineKind::I8
            });
            let progress = |n: usize| bar.set_position(n as u64);
            let p = match engine {
                EngineKind::Tract => tract(&ds, path, progress)?,
                EngineKind::F32 | EngineKind::I8 => {
                    let blob = model::load_blob(path)?;
                    let dtype = evpose_core::Model::parse(blob.bytes())
                        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?
                        .dtype();
                    let want = if engine == EngineKind::I8 {
                        evpose_core::DType::I8
                    } else {
                        evpose_core::DType::F32
                    };
                    if dtype != want {
                        bail!(
                            "{}: an {dtype} model, not for --engine {engine}",
                            path.display()
                        );
                    }
                    warn_points(&blob, &ds);
                    eval::predict_core(&ds, &blob, progress)?
                }
            };
            (p, format!("{} (engine {engine})", path.display()))
        }
        (None, None) => bail!("give --model or --baseline"),
    };
    bar.finish_and_clear();
    let secs = start.elapsed().as_secs_f64();
    let rate = if a.baseline.is_some() {
        0.0
    } else {
        ds.len() as f64 / secs
    };
    let front = [(fa.0, &fa.1), (fb.0, &fb.1)];
    let joints: Vec<eval::Joints2d> = predictions.iter().map(|p| p.joints).collect();
    // The baseline has no confidences (they are all 1): no weighted figure.
    let confidence: Vec<[f32; dataset::JOINTS]> =
        predictions.iter().map(|p| p.confidence).collect();
    let weights = a.baseline.is_none().then_some(confidence.as_slice());
    let mut report = eval::evaluate(&ds, &joints, weights, front, predictor.clone(), rate)?;
    if ds.manifest.label == dataset::LabelRule::Last {
        eprintln!("note: --label last cuts each camera's windows on their own: no 3-D figure");
    }
    if a.baseline.is_none() {
        let sum: f64 = predictions
            .iter()
            .flat_map(|p| p.confidence)
            .map(f64::from)
            .sum();
        report.mean_confidence = Some(sum / (predictions.len() * dataset::JOINTS) as f64);
    }
    if let Some(p) = smooth {
        let smoothed = eval::smooth(&ds, &predictions, p)?;
        let name = format!(
            "{predictor}, causal One-Euro filter (min cut-off {} Hz, beta {}, full confidence {})",
            p.min_cutoff_hz, p.beta, p.full_confidence
        );
        report.smoothed = Some(Box::new(eval::evaluate(
            &ds, &smoothed, weights, front, name, rate,
        )?));
        let lag = LagParams {
            lag: a.lag,
            ..LagParams::DEFAULT
        };
        let lagged = eval::smooth_fixed_lag(&ds, &predictions, lag)?;
        let name = format!(
            "{predictor}, fixed-lag filter (confidence-weighted mean of {} windows, {} windows' \
             latency)",
            2 * lag.lag + 1,
            lag.lag
        );
        report.fixed_lag = Some(Box::new(eval::evaluate(
            &ds, &lagged, weights, front, name, rate,
        )?));
    }
    if let Some(path) = &a.json {
        std::fs::write(path, serde_json::to_string_pretty(&report)?)?;
    }
    if let Some(path) = &a.plot {
        crate::render::save(&eval::per_joint_chart(&report)?, path)?;
    }
    print_report(&report);
    Ok(())
}

#[cfg(feature = "onnx")]
fn tract(
    ds: &Dataset,
    path: &std::path::Path,
    progress: impl Fn(usize) + Sync,
) -> Result<Vec<eval::Prediction>> {
    eval::predict_tract(ds, path, progress)
}

#[cfg(not(feature = "onnx"))]
fn tract(
    _: &Dataset,
    _: &std::path::Path,
    _: impl Fn(usize) + Sync,
) -> Result<Vec<eval::Prediction>> {
    bail!("this evpose was built without tract (cargo feature `onnx`)")
}

fn fmt(v: Option<f64>) -> String {
    v.map_or_else(|| "-".into(), |v| format!("{v:.2}"))
}

fn print_report(r: &EvalReport) {
    println!("{}", r.predictor);
    if r.synthetic {
        let pixel = match r.pixel_models.as_slice() {
            [] => String::new(),
            models => format!(", pixel model {}", models.join(" + ")),
        };
        println!("data: synthetic (evpose sim{pixel}): these are not DHP19 figures");
    }
    println!(
        "MPJPE2D {} px over {} samples; MPJPE3D {} mm over {} windows{}",
        fmt(r.mpjpe2d_px),
        r.samples,
        fmt(r.mpjpe3d_mm),
        r.windows,
        if r.samples_per_second > 0.0 {
            format!("; {:.1} samples/s", r.samples_per_second)
        } else {
            String::new()
        }
    );
    if let Some(w) = r.mpjpe3d_weighted_mm {
        println!("  MPJPE3D with confidence-weighted triangulation: {w:.2} mm");
    }
    for (c, m) in &r.per_camera {
        println!("  camera {c}: {} px", fmt(m.mpjpe2d_px));
    }
    // One name column for both tables, as wide as the longest name (`arm-abduction-right`).
    let names = r.per_movement.keys().map(String::as_str);
    let width = names
        .chain(evpose_core::skeleton::JOINT_NAMES.iter().copied())
        .map(str::len)
        .max()
        .unwrap_or(0)
        .max(8);
    let row = |name: &str, m: &eval::Mpjpe| {
        println!(
            "  {name:<width$} {:>8} {:>9}",
            fmt(m.mpjpe2d_px),
            fmt(m.mpjpe3d_mm)
        )
    };
    println!("  {:<width$} {:>8} {:>9}", "movement", "2-D px", "3-D mm");
    for (name, m) in &r.per_movement {
        row(name, m);
    }
    println!("  {:<width$} {:>8} {:>9}", "joint", "2-D px", "3-D mm");
    for (name, m) in evpose_core::skeleton::JOINT_NAMES.iter().zip(&r.per_joint) {
        row(name, m);
    }
    if let Some(c) = r.mean_confidence {
        println!("mean joint confidence {c:.3}");
    }
    let gain = |a: Option<f64>, b: Option<f64>| match (a, b) {
        (Some(a), Some(b)) if a > 0.0 => format!(" ({:+.1} %)", 100.0 * (b - a) / a),
        _ => String::new(),
    };
    for s in [&r.smoothed, &r.fixed_lag].into_iter().flatten() {
        println!("\n{}", s.predictor);
        println!(
            "MPJPE2D {} px{}; MPJPE3D {} mm{}; confidence-weighted {} mm{}",
            fmt(s.mpjpe2d_px),
            gain(r.mpjpe2d_px, s.mpjpe2d_px),
            fmt(s.mpjpe3d_mm),
            gain(r.mpjpe3d_mm, s.mpjpe3d_mm),
            fmt(s.mpjpe3d_weighted_mm),
            gain(r.mpjpe3d_weighted_mm, s.mpjpe3d_weighted_mm)
        );
    }
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::super::{Cli, Command};
    use crate::dhp19;

    #[test]
    fn dataset_cameras_default_to_the_front_pair() {
        let cli =
            Cli::try_parse_from(["evpose", "dataset", "--recordings", "r", "--out", "o"]).unwrap();
        let Command::Dataset(a) = cli.command else {
            panic!("not dataset");
        };
        assert_eq!(a.cameras, dhp19::FRONT_CHANNELS);
        // Given the way the help shows the default.
        let cli = Cli::try_parse_from([
            "evpose",
            "dataset",
            "--recordings",
            "r",
            "--out",
            "o",
            "--cameras",
            "2,3",
        ])
        .unwrap();
        let Command::Dataset(b) = cli.command else {
            panic!("not dataset");
        };
        assert_eq!(b.cameras, a.cameras);
    }
}

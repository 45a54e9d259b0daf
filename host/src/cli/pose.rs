//! `evpose pose`: arguments and printing; the pipeline is [`crate::pose`].

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

use crate::model::{self, CoreRunner};
use crate::pipeline::Windowing;
use crate::pose::{self, PoseOptions};
use crate::{assets, io};

/// Arguments of `evpose pose`.
#[derive(Args, Debug)]
pub struct PoseArgs {
    /// Event recording (any supported format).
    #[arg(long)]
    pub events: PathBuf,
    /// Model: an int8 `.evq` blob (i8 engine) or a float `.onnx` / f32 blob (f32 engine).
    /// Default: the bundled small model, quantized.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Camera to use in multi-camera recordings.
    #[arg(long, default_value_t = 0)]
    pub camera: u8,
    /// Count --window-events over the events of all cameras, using only --camera's, so that
    /// every camera gets the same windows (DHP19's evaluation: `--window-events 30000`); a
    /// window in which the camera has no event gives the joints of an all-zero input.
    #[arg(long)]
    pub all_camera_windows: bool,
    /// Events per window (default: what the model records, else 7,500).
    #[arg(long)]
    pub window_events: Option<u32>,
    /// Points per network input (default: what the model records, else 2,048; 0 keeps all).
    #[arg(long)]
    pub points: Option<usize>,
    /// Seed of the point sampler.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print JSON lines (one object per window).
    #[arg(long)]
    pub json: bool,
    /// How to read the recording.
    #[command(flatten)]
    pub input: super::InputArgs,
}

/// Runs `evpose pose`: the whole pipeline on a recording.
pub fn pose(a: &PoseArgs) -> Result<()> {
    let blob = match &a.model {
        Some(path) => model::load_blob(path)?,
        None => assets::default_blob(),
    };
    let runner = CoreRunner::new(&blob).with_context(|| match &a.model {
        Some(path) => path.display().to_string(),
        None => assets::DEFAULT_MODEL_NAME.into(),
    })?;
    let mut opts = PoseOptions::for_model(runner.model());
    opts.window_events = a.window_events.unwrap_or(opts.window_events);
    opts.points = a.points.unwrap_or(opts.points);
    opts.seed = a.seed;
    opts.size = a.input.options().size;
    opts.windowing = Windowing {
        camera: a.camera,
        shared_events: a.all_camera_windows.then_some(opts.window_events),
    };
    let mut reader = io::open_with(&a.events, &a.input.options())?;
    let (mut windows, mut no_body) = (0usize, 0usize);
    pose::poses(reader.as_mut(), &runner, &opts, |p| {
        windows += 1;
        no_body += usize::from(p.no_body() == Some(true));
        if a.json {
            println!("{}", serde_json::to_string(&p)?);
        } else {
            let js: Vec<String> = p.joints.iter().map(|(x, y)| format!("({x},{y})")).collect();
            let conf = p
                .mean_confidence()
                .map_or(String::new(), |c| format!("  confidence {c:.3}"));
            println!(
                "window {:>3}  {} points{conf}  joints {}",
                p.window,
                p.points,
                js.join(" ")
            );
        }
        Ok(())
    })
    .with_context(|| a.events.display().to_string())?;
    if windows > 0 && 2 * no_body > windows {
        eprintln!(
            "no body seen: {no_body} of {windows} windows have a mean joint confidence below {} \
             (the joints above are guesses)",
            pose::NO_BODY_CONFIDENCE
        );
    }
    Ok(())
}

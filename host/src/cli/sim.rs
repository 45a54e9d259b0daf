//! `evpose sim`: arguments, progress and the summary; generation is [`crate::simulate`].

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use clap::Args;
use evpose_sim::PixelModel;
use indicatif::{ProgressBar, ProgressStyle};

use crate::simulate::{self, SimOptions, Split};

/// Arguments of `evpose sim` (stable: scripts call them).
#[derive(Args, Debug)]
pub struct SimArgs {
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Seed: selects the subjects and everything random; two seeds never share a subject.
    #[arg(long)]
    pub seed: u64,
    /// Subjects per seed.
    #[arg(long, default_value_t = 1)]
    pub subjects: u32,
    /// Seconds per recording.
    #[arg(long, default_value_t = 4.0)]
    pub seconds: f64,
    /// Movements: `all`, or comma-separated names (e.g. `jumping-jacks,squats,no-person`).
    #[arg(long, default_value = "all")]
    pub movements: String,
    /// The subject split this set belongs to (`evpose dataset --split` selects by it).
    #[arg(long, value_enum, default_value_t = Split::Train)]
    pub split: Split,
    /// The pixel model: `v2` (held crossings fire when the refractory period ends, pixels
    /// settle), or `v1`, the model the shipped models' data were made with (`train/recipe.sh`).
    #[arg(long, default_value = "v2",
          value_parser = clap::builder::PossibleValuesParser::new(PixelModel::ALL.map(PixelModel::name)))]
    pub pixel_model: String,
}

/// Runs `evpose sim`.
pub fn sim(a: &SimArgs) -> Result<()> {
    let opts = SimOptions {
        seed: a.seed,
        subjects: a.subjects,
        seconds: a.seconds,
        movements: simulate::parse_movements(&a.movements)?,
        split: a.split,
        pixel: PixelModel::from_name(&a.pixel_model).expect("clap checked the name"),
    };
    let total = opts.subjects as u64 * opts.movements.len() as u64;
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} recordings {elapsed} (eta {eta})")
            .expect("valid template"),
    );
    let start = Instant::now();
    let m = simulate::generate(&a.out, &opts, |done, _| bar.set_position(done as u64))?;
    bar.finish_and_clear();
    let events: u64 = m
        .recordings
        .iter()
        .map(|r| r.events.iter().sum::<u64>())
        .sum();
    let secs = start.elapsed().as_secs_f64();
    eprintln!(
        "wrote {} recordings ({} events, {:.1} M events/s, pixel model {}) to {} in {:.1} s; \
         synthetic data, not DHP19",
        m.recordings.len(),
        events,
        events as f64 / secs / 1e6,
        m.pixel_model,
        a.out.display(),
        secs
    );
    Ok(())
}

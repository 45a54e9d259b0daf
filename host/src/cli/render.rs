//! `evpose render`: an event frame of a simulated recording's window with its ground truth
//! (and a model's prediction) drawn on it; the drawing is [`crate::render`].

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

use crate::model::{self, CoreRunner};
use crate::render;

/// Arguments of `evpose render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// A recording of an `evpose sim` directory (its manifest gives the ground truth).
    #[arg(long)]
    pub recording: PathBuf,
    /// Camera channel (DHP19's four: 0 to 3).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(0..=3))]
    pub camera: u8,
    /// Mean Label window index.
    #[arg(long, default_value_t = 0)]
    pub window: usize,
    /// Also draw this model's prediction (orange; the ground truth is green).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Magnification.
    #[arg(long, default_value_t = 2)]
    pub scale: u32,
    /// Output PNG.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `evpose render`.
pub fn render(a: &RenderArgs) -> Result<()> {
    let blob = a.model.as_deref().map(model::load_blob).transpose()?;
    // The window sampled to the model's point count, as `evpose run` samples it.
    let points = match &blob {
        Some(b) => evpose_core::Model::parse(b.bytes())
            .map_err(|e| anyhow::anyhow!("{e}"))?
            .input_points(),
        None => evpose_core::pipeline::DEFAULT_POINTS,
    };
    let (mut img, sample) =
        render::ground_truth_frame(&a.recording, a.camera, a.window, a.scale, points)?;
    if let (Some(path), Some(blob)) = (&a.model, &blob) {
        let mut runner = CoreRunner::new(blob).with_context(|| path.display().to_string())?;
        let m = *runner.model();
        let mut joints = [evpose_core::Joint2d::default(); render_joints()];
        if m.dtype() == evpose_core::DType::I8 {
            let l = runner.run_i8(&sample.points)?;
            evpose_core::decode(&l.x, &l.y, m.width(), m.height(), &mut joints)?;
        } else {
            let l = runner.run_f32(&sample.points)?;
            evpose_core::decode(&l.x, &l.y, m.width(), m.height(), &mut joints)?;
        }
        let p = joints.map(|j| [f32::from(j.x), f32::from(j.y)]);
        render::draw_skeleton(
            &mut img,
            &p,
            &[1; render_joints()],
            a.scale,
            render::PREDICTION,
        );
    }
    render::save(&img, &a.out)?;
    eprintln!(
        "wrote {} (camera {}, window {}, {} points; ground truth green{})",
        a.out.display(),
        a.camera,
        a.window,
        sample.cloud_points,
        if a.model.is_some() {
            ", prediction orange"
        } else {
            ""
        }
    );
    Ok(())
}

const fn render_joints() -> usize {
    crate::dataset::JOINTS
}

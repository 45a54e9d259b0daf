//! Pictures of windows: an event frame (ON events light, OFF events dark, on grey) with
//! skeletons drawn on it, to look at data and predictions. Drawing is `imageproc`'s.

use anyhow::{bail, Context, Result};
use evpose_core::Event;
use image::{Rgb, RgbImage};
use imageproc::drawing::{draw_filled_circle_mut, draw_line_segment_mut};

use crate::dataset::JOINTS;

pub use evpose_core::skeleton::LINES as SKELETON;

/// Ground truth's colour.
pub const GROUND_TRUTH: Rgb<u8> = Rgb([40, 220, 60]);
/// A prediction's colour.
pub const PREDICTION: Rgb<u8> = Rgb([250, 170, 20]);

/// An event frame of `width × height` pixels, magnified `scale` times: ON events white, OFF
/// events black, on grey (the last event of a pixel wins).
pub fn event_frame(events: &[Event], width: u16, height: u16, scale: u32) -> Result<RgbImage> {
    if width == 0 || height == 0 || !(1..=8).contains(&scale) {
        bail!("bad frame size {width}x{height} or scale {scale}");
    }
    let (w, h) = (u32::from(width), u32::from(height));
    let mut img = RgbImage::from_pixel(w * scale, h * scale, Rgb([128, 128, 128]));
    for e in events {
        let (x, y) = (u32::from(e.x), u32::from(e.y));
        if x >= w || y >= h {
            continue;
        }
        let c = if e.on {
            Rgb([255, 255, 255])
        } else {
            Rgb([0, 0, 0])
        };
        for dy in 0..scale {
            for dx in 0..scale {
                img.put_pixel(x * scale + dx, y * scale + dy, c);
            }
        }
    }
    Ok(img)
}

/// Draws a skeleton: joints `(u, v)` in sensor pixels (drawn at pixel centres), lines between
/// visible joints, in `colour`.
pub fn draw_skeleton(
    img: &mut RgbImage,
    joints: &[[f32; 2]; JOINTS],
    visible: &[u8; JOINTS],
    scale: u32,
    colour: Rgb<u8>,
) {
    let at = |j: usize| {
        (
            (joints[j][0] + 0.5) * scale as f32,
            (joints[j][1] + 0.5) * scale as f32,
        )
    };
    for &(a, b) in &SKELETON {
        if visible[a] != 0 && visible[b] != 0 {
            draw_line_segment_mut(img, at(a), at(b), colour);
        }
    }
    for (j, _) in visible.iter().enumerate().filter(|(_, &v)| v != 0) {
        let (x, y) = at(j);
        draw_filled_circle_mut(img, (x as i32, y as i32), 2 * scale as i32, colour);
    }
}

/// Saves a PNG.
pub fn save(img: &RgbImage, path: &std::path::Path) -> Result<()> {
    img.save(path)
        .with_context(|| format!("cannot write {}", path.display()))
}

/// The event frame of Mean Label window `window` of camera `camera` of a simulated recording
/// (`events`, its file in an `evpose sim` directory), with the projected ground truth drawn on
/// it; also the window's labelled sample (for predictions).
pub fn ground_truth_frame(
    events_file: &std::path::Path,
    camera: u8,
    window: usize,
    scale: u32,
) -> Result<(RgbImage, crate::dataset::Sample)> {
    use crate::dataset::{self, DatasetOptions, LabelRule, SplitFilter, MEAN_WINDOW_EVENTS};
    let dir = events_file.parent().unwrap_or(std::path::Path::new("."));
    let source = dataset::sources(dir)?
        .into_iter()
        .find(|s| s.events.file_name() == events_file.file_name())
        .with_context(|| {
            format!(
                "{} is not in its directory's manifest",
                events_file.display()
            )
        })?;
    let events = dataset::read_events(&source.events)?;
    let cam = crate::simulate::dhp19_cameras()?[usize::from(camera & 3)];
    let opts = DatasetOptions {
        label: LabelRule::Mean,
        points: evpose_core::pipeline::DEFAULT_POINTS,
        cameras: vec![camera],
        split: SplitFilter::All,
        seed: 0,
        dhp19_filters: Some(false),
    };
    let samples = dataset::windows(&source, &events, &[(camera, cam)], &opts, 0)?;
    let Some(sample) = samples.into_iter().find(|s| s.window as usize == window) else {
        bail!(
            "{} has no Mean Label window {window} with ground truth",
            events_file.display()
        );
    };
    let chunk = &events[window * MEAN_WINDOW_EVENTS..(window + 1) * MEAN_WINDOW_EVENTS];
    let mine: Vec<Event> = chunk
        .iter()
        .filter(|(c, _)| *c == camera)
        .map(|&(_, e)| e)
        .collect();
    let mut img = event_frame(&mine, cam.width(), cam.height(), scale)?;
    draw_skeleton(&mut img, &sample.label2d, &sample.mask, scale, GROUND_TRUTH);
    Ok((img, sample))
}

/// The font of charts: DejaVu Sans Mono (Bitstream Vera licence, `assets/fonts/`), embedded.
const FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSansMono.ttf");

/// One panel of a bar chart: a title, a unit and one value per bar (`None`: no bar).
pub struct Panel<'a> {
    /// Title above the panel.
    pub title: &'a str,
    /// The values, one per label.
    pub values: &'a [Option<f64>],
    /// Bar colour.
    pub colour: Rgb<u8>,
}

/// A bar chart of panels stacked vertically, sharing the labels under every panel, values
/// written above their bars.
pub fn bar_chart(title: &str, labels: &[&str], panels: &[Panel<'_>]) -> Result<RgbImage> {
    use ab_glyph::FontRef;
    use imageproc::drawing::{draw_filled_rect_mut, draw_text_mut};
    use imageproc::rect::Rect;
    let font = FontRef::try_from_slice(FONT).context("the embedded chart font")?;
    let (bar_w, gap, left, panel_h, top) = (44u32, 12u32, 16u32, 230u32, 40u32);
    let width = left * 2 + labels.len() as u32 * (bar_w + gap);
    let height = top + panels.len() as u32 * (panel_h + 50);
    let mut img = RgbImage::from_pixel(width.max(320), height, Rgb([255, 255, 255]));
    let ink = Rgb([20, 20, 20]);
    draw_text_mut(&mut img, ink, left as i32, 8, 20.0, &font, title);
    for (p, panel) in panels.iter().enumerate() {
        if panel.values.len() != labels.len() {
            bail!("{} values for {} labels", panel.values.len(), labels.len());
        }
        let y0 = top + p as u32 * (panel_h + 50);
        draw_text_mut(
            &mut img,
            ink,
            left as i32,
            y0 as i32,
            16.0,
            &font,
            panel.title,
        );
        let max = panel.values.iter().flatten().fold(0f64, |m, &v| m.max(v));
        let base = y0 + panel_h;
        for (i, v) in panel.values.iter().enumerate() {
            let x = left + i as u32 * (bar_w + gap);
            if let Some(v) = *v {
                let h = if max > 0.0 {
                    ((v / max) * f64::from(panel_h - 50)).round() as u32
                } else {
                    0
                };
                if h > 0 {
                    let rect = Rect::at(x as i32, (base - h) as i32).of_size(bar_w, h);
                    draw_filled_rect_mut(&mut img, rect, panel.colour);
                }
                let text = format!("{v:.1}");
                draw_text_mut(
                    &mut img,
                    ink,
                    x as i32,
                    (base - h) as i32 - 16,
                    13.0,
                    &font,
                    &text,
                );
            }
            // Six characters fit under a bar: "shoulderR" becomes "shouR".
            let l = labels[i];
            let label = if l.chars().count() > 6 && (l.ends_with('R') || l.ends_with('L')) {
                format!("{}{}", &l[..4], &l[l.len() - 1..])
            } else {
                l.chars().take(6).collect()
            };
            draw_text_mut(
                &mut img,
                ink,
                x as i32,
                base as i32 + 4,
                13.0,
                &font,
                &label,
            );
        }
    }
    Ok(img)
}

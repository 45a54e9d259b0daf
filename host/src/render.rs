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

/// The event frame of Mean Label window `window` of camera `camera` (0 to 3) of a simulated
/// recording (`events`, its file in an `evpose sim` directory), with the projected ground truth
/// drawn on it; also the window's labelled sample of `points` points (for predictions: the
/// model's count).
pub fn ground_truth_frame(
    events_file: &std::path::Path,
    camera: u8,
    window: usize,
    scale: u32,
    points: usize,
) -> Result<(RgbImage, crate::dataset::Sample)> {
    if camera > 3 {
        bail!("camera {camera}: DHP19's cameras are 0 to 3");
    }
    use crate::dataset::{self, DatasetOptions, LabelRule, SplitFilter, MEAN_WINDOW_EVENTS};
    // A bare file name's parent is "": its directory is the current one.
    let dir = events_file
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
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
    let cam = crate::simulate::dhp19_cameras()?[usize::from(camera)];
    let opts = DatasetOptions {
        label: LabelRule::Mean,
        points,
        cameras: vec![camera],
        split: SplitFilter::All,
        seed: 0,
        dhp19_filters: Some(false),
        person_free: false,
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

/// Where the frames of a run go.
enum FrameSink {
    /// One animated GIF, and its path.
    Gif(
        Box<image::codecs::gif::GifEncoder<std::io::BufWriter<std::fs::File>>>,
        std::path::PathBuf,
    ),
    /// Numbered PNG files: the path with `-000`, `-001`, … before the extension.
    Png(std::path::PathBuf),
}

/// Milliseconds each GIF frame shows.
pub const GIF_FRAME_MS: u32 = 150;

/// Height of the text strip above each frame, pixels.
const STRIP: u32 = 20;

/// The pictures of `evpose run --render`: per window, each camera's event frame with the
/// predicted skeleton (orange) and the ground truth's (green) drawn over it, and with 3-D
/// joints a front (x–z) and a side (y–z) view of the 3-D skeletons; written as an animated
/// GIF (`.gif`) or as numbered PNG frames (`.png`), one frame per window, as the run goes.
pub struct RunRenderer {
    sink: FrameSink,
    scale: u32,
    sizes: Vec<(u16, u16)>,
    show3d: bool,
    /// The 3-D views' horizontal centres (x, y), mm: the first window's pose.
    centre: Option<[f64; 2]>,
    font: ab_glyph::FontRef<'static>,
    frames: usize,
}

/// The 3-D views span this many mm on each side of their centre, and up from the floor.
const VIEW_HALF_MM: f64 = 1_100.0;
const VIEW_TOP_MM: f64 = 2_100.0;

impl RunRenderer {
    /// Frames into `path` (`.gif` or `.png`) for cameras of `sizes` (sensor pixels), magnified
    /// `scale` times, with the 3-D views when `show3d`.
    pub fn create(
        path: &std::path::Path,
        sizes: &[(u16, u16)],
        scale: u32,
        show3d: bool,
    ) -> Result<Self> {
        if !(1..=4).contains(&scale) {
            bail!("render scale {scale}: 1 to 4");
        }
        let sink = match path.extension().and_then(|e| e.to_str()) {
            Some("gif") => {
                let file = std::fs::File::create(path)
                    .with_context(|| format!("cannot create {}", path.display()))?;
                let mut enc = image::codecs::gif::GifEncoder::new_with_speed(
                    std::io::BufWriter::new(file),
                    10,
                );
                enc.set_repeat(image::codecs::gif::Repeat::Infinite)?;
                FrameSink::Gif(Box::new(enc), path.to_path_buf())
            }
            Some("png") => {
                // The frames are written as the run goes: a missing directory is an error now,
                // not after the first window.
                let dir = path
                    .parent()
                    .filter(|d| !d.as_os_str().is_empty())
                    .unwrap_or(std::path::Path::new("."));
                if !dir.is_dir() {
                    bail!(
                        "{}: no directory {} to write the frames into",
                        path.display(),
                        dir.display()
                    );
                }
                FrameSink::Png(path.to_path_buf())
            }
            _ => bail!("{}: render to a .gif or .png file", path.display()),
        };
        Ok(Self {
            sink,
            scale,
            sizes: sizes.to_vec(),
            show3d,
            centre: None,
            font: ab_glyph::FontRef::try_from_slice(FONT).context("the embedded font")?,
            frames: 0,
        })
    }

    /// Frames written.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// What was written, for a message: the GIF's path, or the first and last PNG frame's
    /// (`f-000.png … f-011.png` for `--render f.png`).
    pub fn written(&self) -> String {
        match &self.sink {
            FrameSink::Gif(_, path) => path.display().to_string(),
            FrameSink::Png(path) => match self.frames {
                0 => path.display().to_string(),
                1 => png_frame(path, 0).display().to_string(),
                n => format!(
                    "{} … {}",
                    png_frame(path, 0).display(),
                    png_frame(path, n - 1).display()
                ),
            },
        }
    }

    /// Draws one window's frame and writes it.
    pub fn add(
        &mut self,
        w: &crate::run::RunWindow,
        events: &crate::run::windows::WindowEvents<'_>,
        truth: Option<&crate::run::WindowTruth>,
    ) -> Result<()> {
        use imageproc::drawing::draw_text_mut;
        let s = self.scale;
        let h = self
            .sizes
            .iter()
            .map(|&(_, h)| u32::from(h))
            .max()
            .unwrap_or(1)
            * s;
        let panel3d = h;
        let width = self
            .sizes
            .iter()
            .map(|&(w, _)| u32::from(w) * s)
            .sum::<u32>()
            + if self.show3d { 2 * panel3d } else { 0 };
        let mut img = RgbImage::from_pixel(width, h + 2 * STRIP, Rgb([40, 40, 40]));
        let ink = Rgb([235, 235, 235]);
        let mut x0 = 0u32;
        for (i, cam) in w.cameras.iter().enumerate() {
            let (cw, ch) = self.sizes[i];
            let mut evs = Vec::new();
            events.extend_camera(cam.camera, &mut evs, Some);
            let mut frame = event_frame(&evs, cw, ch, s)?;
            if let Some(t) = truth {
                let (label, mask) = &t.cameras[i];
                draw_skeleton(&mut frame, label, mask, s, GROUND_TRUTH);
            }
            let pred = joints_array(&cam.joints);
            draw_skeleton(&mut frame, &pred, &[1; JOINTS], s, PREDICTION);
            image::imageops::overlay(&mut img, &frame, i64::from(x0), i64::from(STRIP));
            let conf = cam
                .mean_confidence()
                .map_or(String::new(), |c| format!("  conf {c:.2}"));
            let text = format!("camera {}  {} ev{conf}", cam.camera, cam.events);
            draw_text_mut(&mut img, ink, x0 as i32 + 4, 2, 14.0, &self.font, &text);
            x0 += u32::from(cw) * s;
        }
        if self.show3d {
            self.draw_3d(&mut img, w, truth, x0, panel3d);
        }
        let mut caption = format!(
            "window {}  t {:.3}-{:.3} s",
            w.window,
            w.t_us[0] as f64 * 1e-6,
            w.t_us[1] as f64 * 1e-6
        );
        if let Some(e) = w.error.as_ref().and_then(|e| e.mpjpe3d_mm) {
            caption += &format!("  3-D error {e:.0} mm");
        }
        caption += if truth.is_some() {
            "  orange: prediction, green: ground truth"
        } else {
            "  orange: prediction"
        };
        if w.no_body == Some(true) {
            caption += "  NO BODY SEEN";
        }
        draw_text_mut(
            &mut img,
            ink,
            4,
            (h + STRIP + 2) as i32,
            14.0,
            &self.font,
            &caption,
        );
        self.write(img)
    }

    fn draw_3d(
        &mut self,
        img: &mut RgbImage,
        w: &crate::run::RunWindow,
        truth: Option<&crate::run::WindowTruth>,
        x0: u32,
        side: u32,
    ) {
        use imageproc::drawing::{draw_hollow_rect_mut, draw_text_mut};
        let pred: Vec<Option<[f64; 3]>> = w.joints3d.clone().unwrap_or_default();
        if self.centre.is_none() {
            let pts: Vec<[f64; 3]> = match truth {
                Some(t) => t.joints3d.iter().map(|p| p.map(f64::from)).collect(),
                None => pred.iter().flatten().copied().collect(),
            };
            if !pts.is_empty() {
                let n = pts.len() as f64;
                self.centre = Some([
                    pts.iter().map(|p| p[0]).sum::<f64>() / n,
                    pts.iter().map(|p| p[1]).sum::<f64>() / n,
                ]);
            }
        }
        let centre = self.centre.unwrap_or([0.0; 2]);
        for (v, (axis, name)) in [(0usize, "front (x-z)"), (1, "side (y-z)")]
            .into_iter()
            .enumerate()
        {
            let left = x0 + v as u32 * side;
            let to_px = |p: [f64; 3]| -> (f32, f32) {
                let f = f64::from(side) / (2.0 * VIEW_HALF_MM);
                let u = (p[axis] - centre[axis] + VIEW_HALF_MM) * f;
                let r = (VIEW_TOP_MM - p[2]) * f64::from(side) / (VIEW_TOP_MM + 100.0);
                ((f64::from(left) + u) as f32, (f64::from(STRIP) + r) as f32)
            };
            let rect = imageproc::rect::Rect::at(left as i32, STRIP as i32).of_size(side, side);
            draw_hollow_rect_mut(img, rect, Rgb([90, 90, 90]));
            let mut draw = |joints: &[Option<[f64; 3]>], colour: Rgb<u8>| {
                for &(a, b) in &SKELETON {
                    if let (Some(Some(pa)), Some(Some(pb))) = (joints.get(a), joints.get(b)) {
                        draw_line_segment_mut(img, to_px(*pa), to_px(*pb), colour);
                    }
                }
                for p in joints.iter().flatten() {
                    let (x, y) = to_px(*p);
                    draw_filled_circle_mut(img, (x as i32, y as i32), 2, colour);
                }
            };
            if let Some(t) = truth {
                let g: Vec<Option<[f64; 3]>> =
                    t.joints3d.iter().map(|p| Some(p.map(f64::from))).collect();
                draw(&g, GROUND_TRUTH);
            }
            draw(&pred, PREDICTION);
            let ink = Rgb([235, 235, 235]);
            draw_text_mut(img, ink, left as i32 + 4, 2, 14.0, &self.font, name);
        }
    }

    fn write(&mut self, img: RgbImage) -> Result<()> {
        match &mut self.sink {
            FrameSink::Gif(enc, _) => {
                let rgba = image::DynamicImage::ImageRgb8(img).into_rgba8();
                let delay = image::Delay::from_numer_denom_ms(GIF_FRAME_MS, 1);
                enc.encode_frame(image::Frame::from_parts(rgba, 0, 0, delay))
                    .context("writing the GIF")?;
            }
            FrameSink::Png(path) => save(&img, &png_frame(path, self.frames))?,
        }
        self.frames += 1;
        Ok(())
    }
}

/// Joints as the fixed-size array the drawing takes (missing joints at 0).
fn joints_array(joints: &[[f32; 2]]) -> [[f32; 2]; JOINTS] {
    std::array::from_fn(|j| joints.get(j).copied().unwrap_or_default())
}

/// PNG frame `i` of `--render F.png`: `F-000.png`, `F-001.png`, … beside `F.png`.
fn png_frame(path: &std::path::Path, i: usize) -> std::path::PathBuf {
    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("frame");
    path.with_file_name(format!("{stem}-{i:03}.png"))
}

//! `evpose dataset`: labelled windows a trainer reads with numpy alone.
//!
//! Two window rules, as in the paper's code (`shared/docs/simulation-notes.md`):
//!
//! - **Mean Label**: a window closes when [`MEAN_WINDOW_EVENTS`] (30,000) events have arrived
//!   over the four cameras together; each selected camera's share of them is rasterized and
//!   sampled; the label is the mean of the 100 Hz ground-truth samples whose time lies in the
//!   window's span `[t_first, t_last]` (the nearest sample when none does).
//! - **Last Label**: each camera's own windows of [`LAST_WINDOW_EVENTS`] (7,500) events; the
//!   label is the sample nearest the window's last event.
//!
//! The 3-D label is projected into each camera with DHP19's convention
//! ([`evpose_core::geometry::Camera::project`]), truncated to integer pixels, and masked where
//! the joint falls outside `(0, W] × (0, H]`. Rasterization and sampling are the core's
//! (`Rasterizer`, `sample_window`: what the firmware runs), so training sees the deployed
//! preprocessing. Windows with fewer than [`MIN_TRAIN_POINTS`] points are dropped from the
//! training split only, as the paper does.
//!
//! Recordings without a person (the simulator's `no-person` scenes) have no label and are
//! skipped, unless [`DatasetOptions::person_free`] asks for their windows: then each is written
//! with `person = 0`, a zero label and an all-zero mask, for a trainer that teaches the network
//! what a scene without a body looks like (`train.py` gives them uniform SimDR targets).
//!
//! Output, a directory (row `i` of every array is one window of one camera):
//!
//! | file | shape, dtype | |
//! |---|---|---|
//! | `points.npy` | (W, N, 5) f32 | `[x, y, t_avg, p_acc, cnt]` |
//! | `label2d.npy` | (W, J, 2) f32 | integer pixels `(u, v)` |
//! | `mask.npy` | (W, J) u8 | 1 = visible |
//! | `gt3d.npy` | (W, J, 3) f32 | mm, DHP19's world frame |
//! | `camera.npy` | (W,) u8 | aedat channel |
//! | `subject.npy` | (W,) i64 | subject id |
//! | `movement.npy` | (W,) u16 | index into the manifest's `movements` |
//! | `recording.npy` | (W,) u32 | index into the manifest's `recordings` |
//! | `window.npy` | (W,) u32 | the window's index in its recording (with `--label mean`, cameras of one window share it; with `last`, each camera counts its own windows) |
//! | `span_us.npy` | (W, 2) i64 | first and last event time of the window, µs |
//! | `person.npy` | (W,) u8 | 1 = a person is in the scene; 0 = a person-free window (`--person-free`) |
//! | `manifest.json` | | rule, N, cameras, split, counts, movements, recordings |
//!
//! Recordings are processed in parallel (rayon) and written in order; memory holds one
//! recording per thread.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use evpose_core::geometry::Camera;
use evpose_core::raster::DEFAULT_SLICES;
use evpose_core::sample::{rng_from_seed, sample_window};
use evpose_core::{Event, Rasterizer};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::array::{self, NpyAppender};
use crate::io::{self, Format, OpenOptions};
use crate::pipeline::VecStorage;
use crate::simulate::{self, Split};

pub use evpose_core::skeleton::JOINTS;
/// Events over all cameras per Mean Label window.
pub const MEAN_WINDOW_EVENTS: usize = 30_000;
/// Events per camera per Last Label window.
pub const LAST_WINDOW_EVENTS: usize = 7_500;
/// Training windows with fewer points are dropped.
pub const MIN_TRAIN_POINTS: usize = 1_024;
/// Ground-truth period, µs (Vicon, 100 Hz).
pub const GT_PERIOD_US: f64 = 10_000.0;

/// The window rule and its label.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum LabelRule {
    /// 30,000 events over all cameras; mean of the samples in the window.
    Mean,
    /// 7,500 events per camera; the sample nearest the last event.
    Last,
}

/// Which recordings to take.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum SplitFilter {
    /// Training subjects only (short windows dropped).
    Train,
    /// Test subjects only.
    Test,
    /// Everything (nothing dropped).
    All,
}

/// How a dataset is built.
#[derive(Clone, Debug)]
pub struct DatasetOptions {
    /// Window rule.
    pub label: LabelRule,
    /// Points per sample `N`.
    pub points: usize,
    /// Camera channels to write (DHP19 trains and evaluates on the front pair, 2 and 3).
    pub cameras: Vec<u8>,
    /// Which recordings.
    pub split: SplitFilter,
    /// Seed of the point sampler (per recording: this seed and the recording's index).
    pub seed: u64,
    /// DHP19's preprocessing ([`dhp19_filter`]): `None` applies it to real DHP19 recordings
    /// only.
    pub dhp19_filters: Option<bool>,
    /// Also write the windows of recordings without a person (`person = 0`, zero labels, all
    /// joints masked); otherwise such recordings are skipped.
    pub person_free: bool,
}

/// A recording with ground truth, wherever it came from.
#[derive(Clone, Debug)]
pub struct Source {
    /// Event file.
    pub events: PathBuf,
    /// Ground truth, mm, one pose per 10 ms from `gt_t0_us` (empty: no person).
    pub gt: Vec<[[f32; 3]; JOINTS]>,
    /// Time of the first ground-truth sample on the events' clock, µs; `None`: the first
    /// event's time. For a real DHP19 recording `build` sets it from the recording's trigger
    /// events ([`dhp19_span`]).
    pub gt_t0_us: Option<i64>,
    /// Subject id.
    pub subject: i64,
    /// Movement name.
    pub movement: String,
    /// Its split.
    pub split: Split,
    /// A real DHP19 recording (DHP19's preprocessing applies by default).
    pub real: bool,
    /// The simulator's pixel model of a synthetic recording (`v1`, `v2`; its sim manifest's).
    pub pixel_model: Option<String>,
}

/// One labelled window of one camera.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    /// Network input, `N` rows.
    pub points: Vec<[f32; 5]>,
    /// Points in the rasterized window (before sampling).
    pub cloud_points: usize,
    /// Integer pixel labels `(u, v)`.
    pub label2d: [[f32; 2]; JOINTS],
    /// 1 where the joint is visible.
    pub mask: [u8; JOINTS],
    /// 3-D label, mm.
    pub gt3d: [[f32; 3]; JOINTS],
    /// Camera channel.
    pub camera: u8,
    /// Window index in the recording.
    pub window: u32,
    /// First and last event time, µs.
    pub span_us: [i64; 2],
    /// Whether a person is in the scene (false: a person-free window, no label).
    pub person: bool,
}

/// The manifest of a dataset (`manifest.json`).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct DatasetManifest {
    /// `"evpose dataset"`.
    pub generator: String,
    /// Window rule.
    pub label: LabelRule,
    /// Points per sample.
    pub points: usize,
    /// Camera channels.
    pub cameras: Vec<u8>,
    /// Recordings taken.
    pub split: SplitFilter,
    /// Samples written (rows).
    pub samples: u64,
    /// Training windows dropped for having fewer than 1,024 points.
    pub dropped_short: u64,
    /// Movement names, by the index `movement.npy` holds.
    pub movements: Vec<String>,
    /// Event files, by the index `recording.npy` holds.
    pub recordings: Vec<String>,
    /// Whether the data is synthetic (`evpose sim`), not DHP19.
    pub synthetic: bool,
    /// Samples of person-free windows among `samples` (`--person-free`).
    #[serde(default)]
    pub person_free: u64,
    /// The simulator's pixel models of the synthetic recordings (`evpose sim --pixel-model`),
    /// each once; empty for real data and for datasets made before the field existed.
    #[serde(default)]
    pub pixel_models: Vec<String>,
}

/// The recordings of a directory: an `evpose sim` set (its manifest), or real DHP19 files
/// ([`dhp19_sources`]).
pub fn sources(dir: &Path) -> Result<Vec<Source>> {
    if !dir.join(simulate::MANIFEST).exists() {
        return dhp19_sources(dir);
    }
    let m = simulate::read_manifest(dir)?;
    m.recordings
        .iter()
        .map(|r| {
            Ok(Source {
                events: dir.join(&r.file),
                gt: match &r.gt {
                    Some(g) => simulate::read_gt(&dir.join(g))?,
                    None => Vec::new(),
                },
                gt_t0_us: Some(0),
                subject: r.subject as i64,
                movement: r.movement.clone(),
                split: m.split,
                real: false,
                pixel_model: Some(m.pixel_model.clone()),
            })
        })
        .collect()
}

/// Real DHP19 recordings in `dir`: every `S<subject>_<session>_<movement>.aedat` (DHP19's
/// naming) with its Vicon file `S<subject>_<session>_<movement>.mat` beside it (`XYZPOS`, read
/// by [`crate::dhp19::mat`], joints by name). DHP19's split: subjects 1–12 train, 13–17 test.
///
/// Pixels are where DHP19's own code puts them (x = 345 − x_raw, y = 259 − y_raw: see
/// [`crate::io::aedat2`]), so labels projected with DHP19's P matrices land on the events, and
/// [`build`] starts each recording's Vicon clock at its triggers as DHP19 does
/// ([`dhp19_span`]). Not verified against real DHP19 files (none are available to this
/// project). See the README.
pub fn dhp19_sources(dir: &Path) -> Result<Vec<Source>> {
    let mut out = Vec::new();
    let mut names: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("aedat"))
        })
        .collect();
    names.sort();
    for events in names {
        let stem = events
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or_default()
            .to_string();
        let parts: Vec<&str> = stem.trim_start_matches(['S', 's']).split('_').collect();
        let (Some(subject), Some(movement)) = (
            parts.first().and_then(|s| s.parse::<i64>().ok()),
            parts.get(2),
        ) else {
            bail!(
                "{}: not named S<subject>_<session>_<movement>.aedat",
                events.display()
            );
        };
        let gt = crate::dhp19::vicon_poses(&events.with_extension("mat"))?;
        out.push(Source {
            events,
            gt,
            gt_t0_us: None,
            subject,
            movement: format!("{}-{}", parts.get(1).unwrap_or(&"?"), movement),
            split: if subject <= 12 {
                Split::Train
            } else {
                Split::Test
            },
            real: true,
            pixel_model: None,
        });
    }
    if out.is_empty() {
        bail!(
            "{}: neither an evpose sim directory (manifest.json) nor DHP19 files (S*_*_*.aedat with .mat)",
            dir.display()
        );
    }
    Ok(out)
}

/// What [`dhp19_filter`] removed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FilterStats {
    /// Events of hot pixels (≥ [`HOT_PIXEL_EVENTS`] events in the recording).
    pub hot: u64,
    /// Events without a neighbour within [`BACKGROUND_WINDOW_US`].
    pub background: u64,
}

/// A pixel with at least this many events in a recording is hot (DHP19's preprocessing).
pub const HOT_PIXEL_EVENTS: u32 = 10_000;
/// DHP19's background-activity filter: an event needs a neighbour event this recent, µs.
pub const BACKGROUND_WINDOW_US: i64 = 70_000;

/// DHP19's preprocessing: drops hot pixels' events, then every event none of whose 8
/// neighbours (same camera) fired within the last 70 ms (jAER's background-activity filter:
/// each event stamps its neighbours; an event passes if its own stamp is recent).
pub fn dhp19_filter(events: &mut Vec<(u8, Event)>, width: u16, height: u16) -> FilterStats {
    let (w, h) = (usize::from(width), usize::from(height));
    let at = |c: u8, e: &Event| (usize::from(c & 3) * h + usize::from(e.y)) * w + usize::from(e.x);
    let inside = |e: &Event| usize::from(e.x) < w && usize::from(e.y) < h;
    let mut counts = vec![0u32; 4 * w * h];
    for (c, e) in events.iter().filter(|(_, e)| inside(e)) {
        counts[at(*c, e)] += 1;
    }
    let before = events.len();
    events.retain(|(c, e)| inside(e) && counts[at(*c, e)] < HOT_PIXEL_EVENTS);
    let hot = (before - events.len()) as u64;
    let mut stamp = vec![i64::MIN; 4 * w * h];
    let before = events.len();
    events.retain(|(c, e)| {
        let keep = stamp[at(*c, e)] != i64::MIN && e.t - stamp[at(*c, e)] <= BACKGROUND_WINDOW_US;
        let (x, y) = (i32::from(e.x), i32::from(e.y));
        for dy in -1..=1 {
            for dx in -1..=1 {
                let (nx, ny) = (x + dx, y + dy);
                if (dx, dy) != (0, 0)
                    && nx >= 0
                    && ny >= 0
                    && (nx as usize) < w
                    && (ny as usize) < h
                {
                    let n = (usize::from(*c & 3) * h + ny as usize) * w + nx as usize;
                    stamp[n] = e.t;
                }
            }
        }
        keep
    });
    FilterStats {
        hot,
        background: (before - events.len()) as u64,
    }
}

/// All events of a multi-camera recording, `(camera, event)` in the reader's order ([`crate::io::read_all`]).
pub fn read_events(path: &Path) -> Result<Vec<(u8, Event)>> {
    read_recording(path).map(|(events, _)| events)
}

/// [`read_events`], and what the reader noted (the special events' times among it).
pub fn read_recording(path: &Path) -> Result<(Vec<(u8, Event)>, io::ReadNotes)> {
    let opts = OpenOptions {
        format: Some(Format::Aedat2Dhp19),
        ..OpenOptions::default()
    };
    let mut reader = io::open_with(path, &opts)?;
    let events = io::read_all(reader.as_mut()).with_context(|| path.display().to_string())?;
    Ok((events, reader.notes()))
}

/// The stretch `(start, stop)` µs of a real DHP19 recording that its Vicon samples cover, as
/// DHP19's `Generate_DHP19.m` decides it from the recording's special (trigger) events
/// `specials`, its first and last event times and `gt_len` Vicon samples (`n = 10 ms · gt_len`):
/// - none: `(first, last)` (DHP19's fallback);
/// - 1, 2 or 4: the first trigger `s` ends the recording when it lies nearer the last event
///   than the first (`(s − n, s)`), else starts it (`(s, s + n)`);
/// - 3 or 5: `(first trigger, last trigger)`;
/// - more: `None` (DHP19 skips such files as corrupt).
///
/// The Vicon clock starts at `start` (row 0); DHP19 keeps the events strictly inside.
pub fn dhp19_span(specials: &[i64], first: i64, last: i64, gt_len: usize) -> Option<(i64, i64)> {
    let n = gt_len as i64 * GT_PERIOD_US as i64;
    match specials {
        [] => Some((first, last)),
        [s] | [s, _] | [s, _, _, _] => Some(if s - first > last - s {
            (s - n, *s)
        } else {
            (*s, s + n)
        }),
        [s, _, e] | [s, _, _, _, e] => Some((*s, *e)),
        _ => None,
    }
}

/// Mean of the ground-truth samples whose time lies in `[t0, t1]` µs (the nearest sample when
/// none does); `None` without ground truth.
pub fn mean_label(
    gt: &[[[f32; 3]; JOINTS]],
    gt_t0_us: i64,
    (t0, t1): (i64, i64),
) -> Option<[[f32; 3]; JOINTS]> {
    if gt.is_empty() {
        return None;
    }
    let k = |t: i64| (t - gt_t0_us) as f64 / GT_PERIOD_US;
    let first = k(t0).ceil().max(0.0) as usize;
    let last = (k(t1).floor().max(-1.0) + 1.0) as usize; // exclusive
    let range = first..last.min(gt.len());
    if range.is_empty() {
        return Some(gt[nearest_sample(gt.len(), gt_t0_us, (t0 + t1) / 2)]);
    }
    let n = range.len() as f64;
    let mut sum = [[0f64; 3]; JOINTS];
    for pose in &gt[range] {
        for (s, p) in sum.iter_mut().zip(pose) {
            for a in 0..3 {
                s[a] += f64::from(p[a]);
            }
        }
    }
    Some(std::array::from_fn(|j| {
        std::array::from_fn(|a| (sum[j][a] / n) as f32)
    }))
}

/// Whether ground truth of `len` samples from `gt_t0_us` covers a window spanning `(t0, t1)`
/// µs: the window's middle lies within one sample period of the samples' span. A recording
/// longer than its ground truth has windows it does not cover, which have no label.
pub fn covers(len: usize, gt_t0_us: i64, (t0, t1): (i64, i64)) -> bool {
    let mid = (t0 as f64 + t1 as f64) / 2.0;
    let (first, last) = (
        gt_t0_us as f64,
        gt_t0_us as f64 + len.saturating_sub(1) as f64 * GT_PERIOD_US,
    );
    len > 0 && mid >= first - GT_PERIOD_US && mid <= last + GT_PERIOD_US
}

/// Index of the ground-truth sample nearest `t` µs (clamped to the recording).
pub fn nearest_sample(len: usize, gt_t0_us: i64, t: i64) -> usize {
    let k = ((t - gt_t0_us) as f64 / GT_PERIOD_US).round();
    k.clamp(0.0, len.saturating_sub(1) as f64) as usize
}

/// Projects a 3-D label into a camera: integer pixels (truncated, as DHP19's labels) and the
/// visibility mask (`(0, W] × (0, H]`).
pub fn project_label(
    camera: &Camera,
    pose: &[[f32; 3]; JOINTS],
) -> ([[f32; 2]; JOINTS], [u8; JOINTS]) {
    let mut label = [[0f32; 2]; JOINTS];
    let mut mask = [0u8; JOINTS];
    for (j, p) in pose.iter().enumerate() {
        let x = [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])];
        if let Some((u, v)) = camera.project(x) {
            if camera.is_visible((u, v)) {
                label[j] = [u.trunc() as f32, v.trunc() as f32];
                mask[j] = 1;
            }
        }
    }
    (label, mask)
}

/// Rasterizes one camera's events of a window as one window with the core's rasterizer
/// (`raster`, reused across a recording's windows: its capacity is the rule's largest window)
/// and samples `n` points.
fn cloud(
    raster: &mut Rasterizer<VecStorage>,
    events: &[Event],
    n: usize,
    rng: &mut evpose_core::sample::SampleRng,
) -> Result<(Vec<[f32; 5]>, usize)> {
    // A window of the full capacity closes by count; any other is closed by the flush.
    let closed = raster.extend(events).1.is_some();
    let window = if closed {
        raster.last_window().unwrap_or_default()
    } else {
        raster.flush()
    };
    let mut idx = vec![0u32; n.max(window.len())];
    let mut rows = vec![[0f32; 5]; n.max(1)];
    let picked = sample_window(&window, n, rng, &mut idx, &mut rows)?;
    Ok((picked.to_vec(), window.len()))
}

/// The labelled windows of one recording (`index` seeds its sampler); none for a recording
/// without a person unless [`DatasetOptions::person_free`] asks for them.
pub fn windows(
    source: &Source,
    events: &[(u8, Event)],
    cameras: &[(u8, Camera)],
    opts: &DatasetOptions,
    index: usize,
) -> Result<Vec<Sample>> {
    // A recording without a person has no label: its windows only on request.
    if source.gt.is_empty() && !opts.person_free {
        return Ok(Vec::new());
    }
    let mut rng = rng_from_seed(opts.seed ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let capacity = match opts.label {
        LabelRule::Mean => MEAN_WINDOW_EVENTS,
        LabelRule::Last => LAST_WINDOW_EVENTS,
    };
    let size = (crate::dhp19::WIDTH, crate::dhp19::HEIGHT);
    let mut raster = crate::pipeline::rasterizer(size, DEFAULT_SLICES, capacity as u32)?;
    let gt_t0 = source
        .gt_t0_us
        .unwrap_or_else(|| events.first().map_or(0, |(_, e)| e.t));
    let mut out = Vec::new();
    let mut push = |window: u32,
                    (t0, t1): (i64, i64),
                    camera: u8,
                    cam: &Camera,
                    evs: &[Event],
                    label: Option<[[f32; 3]; JOINTS]>,
                    rng: &mut evpose_core::sample::SampleRng|
     -> Result<()> {
        let (points, cloud_points) = cloud(&mut raster, evs, opts.points, rng)?;
        // A person-free window: no label, every joint masked.
        let (label2d, mask) = label.map_or(([[0.0; 2]; JOINTS], [0; JOINTS]), |l| {
            project_label(cam, &l)
        });
        out.push(Sample {
            points,
            cloud_points,
            label2d,
            mask,
            gt3d: label.unwrap_or_default(),
            camera,
            window,
            span_us: [t0, t1],
            person: label.is_some(),
        });
        Ok(())
    };
    match opts.label {
        LabelRule::Mean => {
            for (w, chunk) in events.chunks(MEAN_WINDOW_EVENTS).enumerate() {
                if chunk.len() < MEAN_WINDOW_EVENTS {
                    break; // a short tail is not a window
                }
                let span = (chunk[0].1.t, chunk[chunk.len() - 1].1.t);
                // A window the ground truth does not cover (a recording longer than its
                // labels) has no label to learn from: left out, not labelled with the last pose.
                if !source.gt.is_empty() && !covers(source.gt.len(), gt_t0, span) {
                    continue;
                }
                let label = mean_label(&source.gt, gt_t0, span);
                for (c, cam) in cameras {
                    let evs: Vec<Event> = chunk
                        .iter()
                        .filter(|(k, _)| k == c)
                        .map(|&(_, e)| e)
                        .collect();
                    push(w as u32, span, *c, cam, &evs, label, &mut rng)?;
                }
            }
        }
        LabelRule::Last => {
            for (c, cam) in cameras {
                let mine: Vec<Event> = events
                    .iter()
                    .filter(|(k, _)| k == c)
                    .map(|&(_, e)| e)
                    .collect();
                for (w, chunk) in mine.chunks(LAST_WINDOW_EVENTS).enumerate() {
                    if chunk.len() < LAST_WINDOW_EVENTS {
                        break;
                    }
                    let span = (chunk[0].t, chunk[chunk.len() - 1].t);
                    if !source.gt.is_empty() && !covers(source.gt.len(), gt_t0, span) {
                        continue;
                    }
                    let label = (!source.gt.is_empty())
                        .then(|| source.gt[nearest_sample(source.gt.len(), gt_t0, span.1)]);
                    push(w as u32, span, *c, cam, chunk, label, &mut rng)?;
                }
            }
        }
    }
    Ok(out)
}

/// The arrays of a dataset directory, open for appending.
struct Writers {
    points: NpyAppender<f32>,
    label2d: NpyAppender<f32>,
    mask: NpyAppender<u8>,
    gt3d: NpyAppender<f32>,
    camera: NpyAppender<u8>,
    subject: NpyAppender<i64>,
    movement: NpyAppender<u16>,
    recording: NpyAppender<u32>,
    window: NpyAppender<u32>,
    span: NpyAppender<i64>,
    person: NpyAppender<u8>,
}

impl Writers {
    fn create(out: &Path, n: usize) -> Result<Self> {
        let j = JOINTS as u64;
        Ok(Self {
            points: NpyAppender::create(&out.join("points.npy"), &[n as u64, 5])?,
            label2d: NpyAppender::create(&out.join("label2d.npy"), &[j, 2])?,
            mask: NpyAppender::create(&out.join("mask.npy"), &[j])?,
            gt3d: NpyAppender::create(&out.join("gt3d.npy"), &[j, 3])?,
            camera: NpyAppender::create(&out.join("camera.npy"), &[])?,
            subject: NpyAppender::create(&out.join("subject.npy"), &[])?,
            movement: NpyAppender::create(&out.join("movement.npy"), &[])?,
            recording: NpyAppender::create(&out.join("recording.npy"), &[])?,
            window: NpyAppender::create(&out.join("window.npy"), &[])?,
            span: NpyAppender::create(&out.join("span_us.npy"), &[2])?,
            person: NpyAppender::create(&out.join("person.npy"), &[])?,
        })
    }

    fn append(&mut self, s: &Sample, subject: i64, movement: u16, recording: u32) -> Result<()> {
        self.points.append(s.points.as_flattened())?;
        self.label2d.append(s.label2d.as_flattened())?;
        self.mask.append(&s.mask)?;
        self.gt3d.append(s.gt3d.as_flattened())?;
        self.camera.append(&[s.camera])?;
        self.subject.append(&[subject])?;
        self.movement.append(&[movement])?;
        self.recording.append(&[recording])?;
        self.window.append(&[s.window])?;
        self.span.append(&s.span_us)?;
        self.person.append(&[u8::from(s.person)])
    }

    fn finish(self) -> Result<u64> {
        let n = self.points.finish()?;
        for rows in [
            self.label2d.finish()?,
            self.mask.finish()?,
            self.gt3d.finish()?,
            self.camera.finish()?,
            self.subject.finish()?,
            self.movement.finish()?,
            self.recording.finish()?,
            self.window.finish()?,
            self.span.finish()?,
            self.person.finish()?,
        ] {
            if rows != n {
                bail!("dataset arrays disagree on their row count");
            }
        }
        Ok(n)
    }
}

/// Builds a dataset from the recordings in `dir` into `out`, calling `progress(done, total)`
/// per recording.
pub fn build(
    dir: &Path,
    out: &Path,
    opts: &DatasetOptions,
    progress: impl Fn(usize, usize) + Sync,
) -> Result<DatasetManifest> {
    if opts.points == 0 {
        bail!("--points must be at least 1");
    }
    let all = sources(dir)?;
    let sources: Vec<&Source> = all
        .iter()
        .filter(|s| match opts.split {
            SplitFilter::All => true,
            SplitFilter::Train => s.split == Split::Train,
            SplitFilter::Test => s.split == Split::Test,
        })
        .collect();
    // The set's calibration (an `evpose sim` directory has one), else the bundled DHP19 one.
    let calibration = simulate::read_manifest(dir)
        .ok()
        .map(|m| dir.join(m.calibration));
    let cameras: Vec<(u8, Camera)> = opts
        .cameras
        .iter()
        .map(|&c| {
            let cam = match &calibration {
                Some(d) => crate::dhp19::camera(d, c)?,
                None => crate::dhp19::bundled_camera(c)?,
            };
            Ok((c, cam))
        })
        .collect::<Result<_>>()?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut movements: Vec<String> = Vec::new();
    for s in &sources {
        if !movements.contains(&s.movement) {
            movements.push(s.movement.clone());
        }
    }
    let mut writers = Writers::create(out, opts.points)?;
    let mut dropped = 0u64;
    let mut person_free = 0u64;
    let done = std::sync::atomic::AtomicUsize::new(0);
    // Parallel over recordings, written in order, a few recordings at a time.
    let chunk = 2 * rayon::current_num_threads().max(1);
    for (c, group) in sources.chunks(chunk).enumerate() {
        let results: Vec<Result<Vec<Sample>>> = group
            .par_iter()
            .enumerate()
            .map(|(i, s)| {
                let (mut events, notes) = read_recording(&s.events)?;
                // A real recording's Vicon clock starts where DHP19's code starts it (its
                // triggers), and only the events it covers count; before any filtering.
                let mut aligned: std::borrow::Cow<'_, Source> = std::borrow::Cow::Borrowed(s);
                if s.real {
                    let (first, last) = match (events.first(), events.last()) {
                        (Some(f), Some(l)) => (f.1.t, l.1.t),
                        _ => (0, 0),
                    };
                    match dhp19_span(&notes.special_times, first, last, s.gt.len()) {
                        Some((start, stop)) => {
                            events.retain(|(_, e)| e.t > start && e.t < stop);
                            aligned.to_mut().gt_t0_us = Some(start);
                        }
                        // DHP19 skips files with more than five triggers as corrupt.
                        None => events.clear(),
                    }
                }
                if opts.dhp19_filters.unwrap_or(s.real) {
                    dhp19_filter(&mut events, crate::dhp19::WIDTH, crate::dhp19::HEIGHT);
                }
                let r = windows(&aligned, &events, &cameras, opts, c * chunk + i);
                progress(
                    done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1,
                    sources.len(),
                );
                r.with_context(|| s.events.display().to_string())
            })
            .collect();
        for (i, (s, samples)) in group.iter().zip(results).enumerate() {
            let movement = movements.iter().position(|m| *m == s.movement).unwrap_or(0) as u16;
            for sample in samples? {
                if opts.split == SplitFilter::Train && sample.cloud_points < MIN_TRAIN_POINTS {
                    dropped += 1;
                    continue;
                }
                person_free += u64::from(!sample.person);
                writers.append(&sample, s.subject, movement, (c * chunk + i) as u32)?;
            }
        }
    }
    let samples = writers.finish()?;
    let manifest = DatasetManifest {
        generator: "evpose dataset".into(),
        label: opts.label,
        points: opts.points,
        cameras: opts.cameras.clone(),
        split: opts.split,
        samples,
        dropped_short: dropped,
        movements,
        recordings: sources
            .iter()
            .map(|s| s.events.display().to_string())
            .collect(),
        synthetic: sources.iter().all(|s| !s.real),
        person_free,
        pixel_models: {
            let mut m: Vec<String> = sources
                .iter()
                .filter_map(|s| s.pixel_model.clone())
                .collect();
            m.sort();
            m.dedup();
            m
        },
    };
    let path = out.join("manifest.json");
    std::fs::write(&path, serde_json::to_string_pretty(&manifest)?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(manifest)
}

/// A dataset read back (everything but the points, which [`Dataset::points_range`] reads).
#[derive(Clone, Debug)]
pub struct Dataset {
    /// Its directory.
    pub dir: PathBuf,
    /// The manifest.
    pub manifest: DatasetManifest,
    /// Labels, `(u, v)` integer pixels per joint.
    pub label2d: Vec<[[f32; 2]; JOINTS]>,
    /// Visibility.
    pub mask: Vec<[u8; JOINTS]>,
    /// 3-D labels, mm.
    pub gt3d: Vec<[[f32; 3]; JOINTS]>,
    /// Camera channel per row.
    pub camera: Vec<u8>,
    /// Movement index per row.
    pub movement: Vec<u16>,
    /// Recording index per row.
    pub recording: Vec<u32>,
    /// Window index per row.
    pub window: Vec<u32>,
    /// First and last event time of each row's window, µs (all `[0, 0]` in a dataset written
    /// before `span_us.npy` existed).
    pub span_us: Vec<[i64; 2]>,
    /// 1 where a person is in the scene, 0 for a person-free window (all 1 in a dataset
    /// written before `person.npy` existed).
    pub person: Vec<u8>,
}

impl Dataset {
    /// Opens a dataset directory.
    pub fn open(dir: &Path) -> Result<Self> {
        let path = dir.join("manifest.json");
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        let manifest: DatasetManifest = serde_json::from_str(&text)
            .with_context(|| format!("{}: not an evpose dataset manifest", path.display()))?;
        let read = |name: &str| array::read_f64(&dir.join(name)).map(|(_, v)| v);
        let rows = |v: Vec<f64>, k: usize| -> Vec<Vec<f64>> {
            v.chunks_exact(k).map(<[f64]>::to_vec).collect()
        };
        let l2 = rows(read("label2d.npy")?, 2 * JOINTS);
        let g3 = rows(read("gt3d.npy")?, 3 * JOINTS);
        let mk = rows(read("mask.npy")?, JOINTS);
        let ds = Self {
            dir: dir.to_path_buf(),
            label2d: l2
                .iter()
                .map(|r| std::array::from_fn(|j| [r[2 * j] as f32, r[2 * j + 1] as f32]))
                .collect(),
            mask: mk
                .iter()
                .map(|r| std::array::from_fn(|j| r[j] as u8))
                .collect(),
            gt3d: g3
                .iter()
                .map(|r| std::array::from_fn(|j| std::array::from_fn(|a| r[3 * j + a] as f32)))
                .collect(),
            camera: read("camera.npy")?.into_iter().map(|v| v as u8).collect(),
            movement: read("movement.npy")?
                .into_iter()
                .map(|v| v as u16)
                .collect(),
            recording: read("recording.npy")?
                .into_iter()
                .map(|v| v as u32)
                .collect(),
            window: read("window.npy")?.into_iter().map(|v| v as u32).collect(),
            // µs timestamps are below 2^53: exact through f64. A dataset written before
            // `span_us.npy` existed has none: all [0, 0] (the filters refuse it).
            span_us: if dir.join("span_us.npy").exists() {
                read("span_us.npy")?
                    .chunks_exact(2)
                    .map(|t| [t[0] as i64, t[1] as i64])
                    .collect()
            } else {
                vec![[0, 0]; manifest.samples as usize]
            },
            person: if dir.join("person.npy").exists() {
                read("person.npy")?.into_iter().map(|v| v as u8).collect()
            } else {
                vec![1; manifest.samples as usize]
            },
            manifest,
        };
        let n = ds.manifest.samples as usize;
        if [
            ds.label2d.len(),
            ds.mask.len(),
            ds.gt3d.len(),
            ds.camera.len(),
            ds.movement.len(),
            ds.recording.len(),
            ds.window.len(),
            ds.span_us.len(),
            ds.person.len(),
        ]
        .iter()
        .any(|&l| l != n)
        {
            bail!(
                "{}: arrays and manifest disagree on the sample count",
                dir.display()
            );
        }
        Ok(ds)
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.camera.len()
    }

    /// Whether the dataset has no sample.
    pub fn is_empty(&self) -> bool {
        self.camera.is_empty()
    }

    /// The network inputs of samples `start..start + count` (`N` rows each), read from
    /// `points.npy` without loading the rest.
    pub fn points_range(&self, start: usize, count: usize) -> Result<Vec<Vec<[f32; 5]>>> {
        use std::io::{Read, Seek, SeekFrom};
        let path = self.dir.join("points.npy");
        let mut f = std::fs::File::open(&path)
            .with_context(|| format!("cannot open {}", path.display()))?;
        let mut head = [0u8; 12];
        f.read_exact(&mut head)
            .with_context(|| format!("{}: truncated header", path.display()))?;
        if &head[..6] != b"\x93NUMPY" {
            bail!("{}: not an .npy file", path.display());
        }
        let data = match head[6] {
            1 => 10 + u64::from(u16::from_le_bytes([head[8], head[9]])),
            _ => 12 + u64::from(u32::from_le_bytes([head[8], head[9], head[10], head[11]])),
        };
        let n = self.manifest.points;
        if start + count > self.len() {
            bail!("samples {start}..{} of {}", start + count, self.len());
        }
        let row = (n * 5 * 4) as u64;
        f.seek(SeekFrom::Start(data + start as u64 * row))?;
        let mut bytes = vec![0u8; count * row as usize];
        f.read_exact(&mut bytes)
            .with_context(|| format!("{}: truncated", path.display()))?;
        Ok(bytes
            .chunks_exact(row as usize)
            .map(|r| {
                r.chunks_exact(20)
                    .map(|p| {
                        std::array::from_fn(|k| {
                            f32::from_le_bytes(p[4 * k..4 * k + 4].try_into().unwrap_or_default())
                        })
                    })
                    .collect()
            })
            .collect())
    }
}

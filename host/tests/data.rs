//! Ground truth end to end: `evpose sim` files read back by the readers, the Mean/Last Label
//! arithmetic on a hand-built recording, and MPJPE on hand-computed cases.

use evpose_core::geometry::Camera;
use evpose_core::Event;
use evpose_host::dataset::{
    self, mean_label, nearest_sample, project_label, Dataset, DatasetManifest, DatasetOptions,
    LabelRule, Source, SplitFilter, JOINTS,
};
use evpose_host::eval;
use evpose_host::simulate::{self, dhp19_cameras, SimOptions, Split};
use evpose_host::summary::summarize_with;
use evpose_sim::{Movement, PixelModel};

/// Mean Label windows of 256 points from the front cameras, seed 1.
fn mean_options(dhp19_filters: Option<bool>) -> DatasetOptions {
    DatasetOptions {
        label: LabelRule::Mean,
        points: 256,
        cameras: vec![2, 3],
        split: SplitFilter::All,
        seed: 1,
        dhp19_filters,
        person_free: false,
    }
}

fn pose(v: f32) -> [[f32; 3]; JOINTS] {
    [[v, 2.0 * v, 1000.0 + v]; JOINTS]
}

/// The shipped models and the bundled clip were made with the V1 pixel model; `evpose sim
/// --pixel-model v1` (what `train/recipe.sh` runs) must keep making the same bytes.
#[test]
fn the_v1_pixel_model_remakes_the_bundled_clip_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let opts = SimOptions {
        seed: 4242,
        subjects: 1,
        seconds: 2.0,
        movements: vec![Movement::SideKick],
        split: Split::Test,
        pixel: PixelModel::V1,
    };
    let m = simulate::generate(dir.path(), &opts, |_, _| {}).unwrap();
    assert_eq!(m.pixel_model, "v1");
    let file = |name: &str| std::fs::read(dir.path().join(name)).unwrap();
    assert!(file("S4242-00_side-kick.aedat") == evpose_host::assets::CLIP);
    assert!(file("S4242-00_side-kick.gt.npy") == evpose_host::assets::CLIP_GT);
}

#[test]
fn simulated_recordings_read_back_with_their_per_camera_counts() {
    let dir = tempfile::tempdir().unwrap();
    let opts = SimOptions {
        seed: 3,
        subjects: 1,
        seconds: 0.25,
        movements: vec![Movement::JumpingJacks, Movement::NoPerson],
        split: Split::Test,
        pixel: PixelModel::V2,
    };
    let m = simulate::generate(dir.path(), &opts, |_, _| {}).unwrap();
    assert_eq!(m.recordings.len(), 2);
    for r in &m.recordings {
        let s = summarize_with(&dir.path().join(&r.file), &Default::default()).unwrap();
        assert_eq!(s.format.name(), "aedat2-dhp19", "{}", r.file);
        let counts: Vec<u64> = (0..4)
            .map(|c| {
                s.cameras
                    .iter()
                    .find(|x| x.camera == c)
                    .map_or(0, |x| x.events)
            })
            .collect();
        assert_eq!(counts, r.events.to_vec(), "{}", r.file);
        assert!(
            r.events.iter().all(|&n| n > 0),
            "{}: {:?}",
            r.file,
            r.events
        );
        assert!(s
            .cameras
            .iter()
            .all(|c| (c.width, c.height) == (Some(346), Some(260))));
    }
    // Ground truth: 100 Hz for the person, none without one; the manifest reads back.
    assert!(m.recordings[0].gt.is_some() && m.recordings[1].gt.is_none());
    let gt = simulate::read_gt(&dir.path().join(m.recordings[0].gt.as_ref().unwrap())).unwrap();
    assert_eq!(gt.len(), 25);
    assert_eq!(simulate::read_manifest(dir.path()).unwrap(), m);
    // Heights in metres, as the field says (the body model's are in mm).
    assert!(m
        .recordings
        .iter()
        .all(|r| (1.5..=1.95).contains(&r.height_m)));
    // The same seed writes the same bytes.
    let again = tempfile::tempdir().unwrap();
    simulate::generate(again.path(), &opts, |_, _| {}).unwrap();
    for r in &m.recordings {
        assert!(
            std::fs::read(dir.path().join(&r.file)).unwrap()
                == std::fs::read(again.path().join(&r.file)).unwrap(),
            "{} differs between two runs with one seed",
            r.file
        );
    }
}

#[test]
fn mean_label_averages_the_samples_inside_the_window() {
    let gt: Vec<_> = (0..10).map(|k| pose(k as f32)).collect();
    // Samples at 0, 10, …, 90 ms. [15 ms, 42 ms] holds samples 2, 3 and 4: mean 3.
    assert_eq!(mean_label(&gt, 0, (15_000, 42_000)), Some(pose(3.0)));
    // Boundaries are inclusive: [20 ms, 40 ms] is samples 2..=4 as well.
    assert_eq!(mean_label(&gt, 0, (20_000, 40_000)), Some(pose(3.0)));
    // With the first sample at 5 ms on the events' clock, [15, 42] holds samples 1..=3.
    assert_eq!(mean_label(&gt, 5_000, (15_000, 42_000)), Some(pose(2.0)));
    // No sample inside (a 3 ms window between two samples): the nearest to its middle.
    assert_eq!(mean_label(&gt, 0, (21_000, 24_000)), Some(pose(2.0)));
    assert_eq!(mean_label(&gt, 0, (26_000, 29_000)), Some(pose(3.0)));
    // Past the end: the last sample. No ground truth: no label.
    assert_eq!(mean_label(&gt, 0, (500_000, 600_000)), Some(pose(9.0)));
    assert_eq!(mean_label(&[], 0, (0, 1)), None);
    assert_eq!(nearest_sample(10, 0, 44_999), 4);
    assert_eq!(nearest_sample(10, 0, 45_001), 5);
    assert_eq!(nearest_sample(10, 0, -7), 0);
}

/// A hand-built recording: camera 2 and 3 events at a known place, a pose moving linearly.
fn hand_built() -> (Source, Vec<(u8, Event)>) {
    let gt: Vec<_> = (0..101).map(|k| pose(k as f32)).collect(); // 1 s at 100 Hz
    let source = Source {
        events: "hand-built".into(),
        gt,
        gt_t0_us: Some(0),
        subject: 7,
        movement: "test".into(),
        split: Split::Train,
        real: false,
        pixel_model: None,
    };
    // 65,000 events over 1 s: cameras 0..=3 in turn, 15.4 µs apart.
    let events = (0..65_000u32)
        .map(|i| {
            let t = i64::from(i) * 1_000_000 / 65_000;
            (
                (i % 4) as u8,
                Event::new((i % 300) as u16, (i / 300 % 200) as u16, t, i % 2 == 0),
            )
        })
        .collect();
    (source, events)
}

/// DHP19's front cameras and the options the hand-built recording's tests cut it with.
fn hand_built_setup(label: LabelRule) -> (Vec<(u8, Camera)>, DatasetOptions) {
    let cams = dhp19_cameras().unwrap();
    let options = DatasetOptions {
        label,
        points: 64,
        cameras: vec![2, 3],
        split: SplitFilter::All,
        seed: 0,
        dhp19_filters: None,
        person_free: false,
    };
    (vec![(2, cams[2]), (3, cams[3])], options)
}

#[test]
fn mean_and_last_label_windows_of_a_hand_built_recording() {
    let (source, events) = hand_built();
    let (cameras, mut opts) = hand_built_setup(LabelRule::Mean);
    // Mean Label: two full 30,000-event windows (the 5,000-event tail is not one), each in
    // cameras 2 and 3: 7,500 events each.
    let s = dataset::windows(&source, &events, &cameras, &opts, 0).unwrap();
    assert_eq!(s.len(), 4);
    for (i, sample) in s.iter().enumerate() {
        let w = i / 2;
        assert_eq!(sample.window as usize, w);
        assert_eq!(sample.camera, [2, 3][i % 2]);
        assert_eq!(sample.points.len(), 64);
        let (first, last) = (events[w * 30_000].1.t, events[w * 30_000 + 29_999].1.t);
        assert_eq!(sample.span_us, [first, last]);
        assert_eq!(Some(sample.gt3d), mean_label(&source.gt, 0, (first, last)));
        // The label is the mean of the samples in the span: the pose at the span's middle
        // sample index, as the pose grows linearly.
        let k0 = (first as f64 / 10_000.0).ceil();
        let k1 = (last as f64 / 10_000.0).floor();
        assert!((sample.gt3d[0][0] - ((k0 + k1) / 2.0) as f32).abs() < 1e-4);
        let (label, mask) = project_label(&cameras[i % 2].1, &sample.gt3d);
        assert_eq!((sample.label2d, sample.mask), (label, mask));
    }
    // Last Label: per camera, 16,250 events → two 7,500-event windows; the label is the sample
    // nearest the last event.
    opts.label = LabelRule::Last;
    let s = dataset::windows(&source, &events, &cameras, &opts, 0).unwrap();
    assert_eq!(s.len(), 4);
    for sample in &s {
        let k = nearest_sample(source.gt.len(), 0, sample.span_us[1]);
        assert_eq!(sample.gt3d, source.gt[k]);
        assert!(sample.cloud_points > 0);
    }
    let mine: Vec<i64> = events
        .iter()
        .filter(|(c, _)| *c == 3)
        .map(|(_, e)| e.t)
        .collect();
    assert_eq!(s[3].span_us, [mine[7_500], mine[14_999]]);
}

/// Windows the ground truth does not cover (labels shorter than the recording) are left out
/// under both rules, not labelled with the last pose.
#[test]
fn windows_beyond_the_ground_truth_are_left_out() {
    let (mut source, events) = hand_built();
    source.gt.truncate(40); // 0.39 s of labels for 1 s of events
    for rule in [LabelRule::Mean, LabelRule::Last] {
        let (cameras, opts) = hand_built_setup(rule);
        let s = dataset::windows(&source, &events, &cameras, &opts, 0).unwrap();
        assert!(!s.is_empty(), "{rule:?}");
        for sample in &s {
            let mid = (sample.span_us[0] + sample.span_us[1]) / 2;
            assert!(mid <= 400_000, "{rule:?}: a window around {mid} µs kept");
        }
        let full = dataset::windows(&hand_built().0, &events, &cameras, &opts, 0).unwrap();
        assert!(s.len() < full.len(), "{rule:?}");
    }
}

/// A recording without a person is skipped unless `person_free` asks for its windows; then
/// each is written unlabelled (`person` false, every joint masked), under both window rules.
#[test]
fn person_free_windows_only_on_request() {
    let (mut source, events) = hand_built();
    source.gt.clear();
    for label in [LabelRule::Mean, LabelRule::Last] {
        let (cameras, mut opts) = hand_built_setup(label);
        let s = dataset::windows(&source, &events, &cameras, &opts, 0).unwrap();
        assert!(
            s.is_empty(),
            "{label:?}: {} samples without a person",
            s.len()
        );
        opts.person_free = true;
        let s = dataset::windows(&source, &events, &cameras, &opts, 0).unwrap();
        assert_eq!(s.len(), 4, "{label:?}");
        for sample in &s {
            assert!(!sample.person);
            assert_eq!(sample.mask, [0; JOINTS]);
            assert_eq!(sample.points.len(), 64);
            assert!(sample.cloud_points > 0);
        }
    }
}

fn tiny_dataset(label2d: Vec<[[f32; 2]; JOINTS]>, mask: Vec<[u8; JOINTS]>) -> Dataset {
    let n = label2d.len();
    Dataset {
        dir: "unused".into(),
        manifest: DatasetManifest {
            generator: "test".into(),
            label: LabelRule::Mean,
            points: 1,
            cameras: vec![2, 3],
            split: SplitFilter::All,
            samples: n as u64,
            dropped_short: 0,
            movements: vec!["m".into()],
            recordings: vec!["r".into()],
            synthetic: true,
            person_free: 0,
            pixel_models: Vec::new(),
        },
        label2d,
        mask,
        gt3d: vec![pose(0.0); n],
        camera: (0..n).map(|i| [2, 3][i % 2]).collect(),
        movement: vec![0; n],
        recording: vec![0; n],
        window: (0..n).map(|i| (i / 2) as u32).collect(),
        // Windows 33 ms apart, the two cameras of a window sharing its span.
        span_us: (0..n)
            .map(|i| [(i / 2) as i64 * 33_000, (i / 2) as i64 * 33_000 + 30_000])
            .collect(),
        person: vec![1; n],
    }
}

/// The temporal filter lowers the error of predictions that jitter around a still pose, and
/// an unconfident outlier barely moves it.
#[test]
fn smoothing_reduces_jitter_and_ignores_unconfident_outliers() {
    use evpose_core::smooth::SmoothParams;
    let n = 40;
    let ds = tiny_dataset(vec![[[100.0, 100.0]; JOINTS]; n], vec![[1; JOINTS]; n]);
    let preds: Vec<eval::Prediction> = (0..n)
        .map(|i| {
            let w = i / 2;
            // ±6 px jitter; window 10 an outlier 80 px off that the network is unsure of.
            let x = if w == 10 {
                180.0
            } else if w % 2 == 0 {
                106.0
            } else {
                94.0
            };
            eval::Prediction {
                joints: [[x, 100.0]; JOINTS],
                confidence: [if w == 10 { 0.02 } else { 0.8 }; JOINTS],
            }
        })
        .collect();
    let raw: Vec<eval::Joints2d> = preds.iter().map(|p| p.joints).collect();
    let smoothed = eval::smooth(&ds, &preds, SmoothParams::DEFAULT).unwrap();
    let err = |p: &[eval::Joints2d]| -> f32 {
        p.iter().map(|j| (j[0][0] - 100.0).abs()).sum::<f32>() / p.len() as f32
    };
    assert!(
        err(&smoothed) < 0.5 * err(&raw),
        "{} vs {}",
        err(&smoothed),
        err(&raw)
    );
    // The outlier (rows 20, 21) moves the filtered joint by a few pixels, not 80.
    assert!(
        (smoothed[20][0][0] - 100.0).abs() < 10.0,
        "{:?}",
        smoothed[20][0]
    );
}

/// The fixed-lag filter averages each camera's own windows, centred, fewer at the ends, and
/// weighs joints by confidence.
#[test]
fn fixed_lag_filter_averages_each_cameras_neighbours() {
    use evpose_core::smooth::LagParams;
    let n = 10; // five windows of cameras 2 and 3
    let ds = tiny_dataset(vec![[[0.0, 0.0]; JOINTS]; n], vec![[1; JOINTS]; n]);
    // Camera 2 (even rows) at x = window; camera 3 (odd rows) at x = 100 + 10 · window.
    let preds: Vec<eval::Prediction> = (0..n)
        .map(|i| {
            let w = (i / 2) as f32;
            eval::Prediction {
                joints: [[if i % 2 == 0 { w } else { 100.0 + 10.0 * w }, 7.0]; JOINTS],
                confidence: [0.5; JOINTS],
            }
        })
        .collect();
    let lag1 = LagParams {
        lag: 1,
        ..LagParams::DEFAULT
    };
    let c = eval::smooth_fixed_lag(&ds, &preds, lag1).unwrap();
    let x = |i: usize| c[i][0][0];
    // Window 0: windows 0 and 1; window 2: 1, 2, 3; window 4: 3 and 4 (equal weights).
    let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(b).all(|(a, b)| (a - b).abs() < 1e-4);
    assert!(close([x(0), x(4), x(8)], [0.5, 2.0, 3.5]), "{c:?}");
    assert!(close([x(1), x(5), x(9)], [105.0, 120.0, 135.0]), "{c:?}");
    assert!(c
        .iter()
        .all(|p| p.iter().all(|j| (j[1] - 7.0).abs() < 1e-4)));
    assert!(eval::smooth_fixed_lag(&ds, &preds[1..], lag1).is_err());
    // An unsure window 500 px off moves its neighbours by well under a pixel (weights c²:
    // 0.0004 against 0.25); a plain mean would move them by 166 px. Without it window 1 is
    // the mean of windows 0 and 1 (0.5), window 3 of 3 and 4 (3.5).
    let mut outlier = preds.clone();
    outlier[4].joints[0][0] = 500.0;
    outlier[4].confidence[0] = 0.02;
    let o = eval::smooth_fixed_lag(&ds, &outlier, lag1).unwrap();
    assert!(
        (o[2][0][0] - 0.5).abs() < 0.5 && (o[6][0][0] - 3.5).abs() < 0.5,
        "{:?} {:?}",
        o[2][0],
        o[6][0]
    );
}

/// Under the last rule each camera counts its own windows, so their window numbers do not
/// pair views of one time: no 3-D figure. Without window times (a dataset older than
/// `span_us.npy`) the filters refuse to run.
#[test]
fn the_last_rule_has_no_3d_figure_and_filters_need_window_times() {
    let cams = dhp19_cameras().unwrap();
    let front = [(2u8, &cams[2]), (3u8, &cams[3])];
    let label = [[100.0, 100.0]; JOINTS];
    let mut ds = tiny_dataset(vec![label; 4], vec![[1; JOINTS]; 4]);
    let pred = vec![label; 4];
    let r = eval::evaluate(&ds, &pred, None, front, "test".into(), 0.0).unwrap();
    assert_eq!(r.windows, 2);
    ds.manifest.label = LabelRule::Last;
    let r = eval::evaluate(&ds, &pred, None, front, "test".into(), 0.0).unwrap();
    assert_eq!((r.windows, r.mpjpe3d_mm), (0, None));
    assert_eq!(r.mpjpe2d_px, Some(0.0));
    ds.span_us = vec![[0, 0]; 4];
    let preds: Vec<eval::Prediction> = pred
        .iter()
        .map(|&joints| eval::Prediction {
            joints,
            confidence: [1.0; JOINTS],
        })
        .collect();
    let err = eval::smooth(&ds, &preds, evpose_core::smooth::SmoothParams::DEFAULT).unwrap_err();
    assert!(err.to_string().contains("no window times"), "{err}");
}

#[test]
fn mpjpe_on_hand_computed_cases() {
    let cams = dhp19_cameras().unwrap();
    let front = [(2u8, &cams[2]), (3u8, &cams[3])];
    let label = [[100.0, 100.0]; JOINTS];
    // Sample 0 (camera 2): every joint off by (3, 4) → 5 px. Sample 1 (camera 3): exact, but
    // joint 0 masked out. MPJPE2D = (13 · 5 + 12 · 0) / 25.
    let ds = tiny_dataset(
        vec![label, label],
        vec![[1; JOINTS], {
            let mut m = [1; JOINTS];
            m[0] = 0;
            m
        }],
    );
    let pred = vec![[[103.0, 104.0]; JOINTS], label];
    let r = eval::evaluate(&ds, &pred, None, front, "test".into(), 0.0).unwrap();
    assert_eq!(r.mpjpe3d_weighted_mm, None);
    assert!((r.mpjpe2d_px.unwrap() - 65.0 / 25.0).abs() < 1e-12);
    assert_eq!(r.per_camera[&2].mpjpe2d_px, Some(5.0));
    assert_eq!(r.per_camera[&3].mpjpe2d_px, Some(0.0));
    assert_eq!(r.per_joint[0].joints2d, 1);
    assert_eq!(r.per_joint[1].mpjpe2d_px, Some(2.5));
    // 3-D: the two cameras' projections of a known point triangulate back onto it: 0 mm.
    let x = [100.0f32, -50.0, 900.0];
    let mut ds = tiny_dataset(vec![label, label], vec![[1; JOINTS]; 2]);
    ds.gt3d = vec![[x; JOINTS]; 2];
    let proj = |c: &evpose_core::geometry::Camera| {
        let (u, v) = c.project([100.0, -50.0, 900.0]).unwrap();
        [[u as f32, v as f32]; JOINTS]
    };
    let r = eval::evaluate(
        &ds,
        &[proj(&cams[2]), proj(&cams[3])],
        None,
        front,
        "t".into(),
        0.0,
    )
    .unwrap();
    assert_eq!(r.windows, 1);
    assert!(r.mpjpe3d_mm.unwrap() < 0.5, "{:?}", r.mpjpe3d_mm);
    // A person-free window (`--person-free`: no label, every joint masked) stays out of the 3-D
    // error: counted, its zero label would be ~900 mm from these joints.
    let mut mixed = tiny_dataset(
        vec![label; 4],
        vec![[1; JOINTS], [1; JOINTS], [0; JOINTS], [0; JOINTS]],
    );
    mixed.gt3d = vec![[x; JOINTS], [x; JOINTS], pose(0.0), pose(0.0)];
    mixed.person = vec![1, 1, 0, 0];
    let views = [proj(&cams[2]), proj(&cams[3])];
    let r = eval::evaluate(&mixed, &views.repeat(2), None, front, "t".into(), 0.0).unwrap();
    assert_eq!(r.windows, 1);
    assert!(r.mpjpe3d_mm.unwrap() < 0.5, "{:?}", r.mpjpe3d_mm);
    // Confidence-weighted: exact views stay exact whatever the weights; with camera 3's view
    // off by 8 px, trusting camera 2 (0.9 against 0.1) is closer than trusting both equally.
    let conf = [[0.9f32; JOINTS], [0.1; JOINTS]];
    let r = eval::evaluate(
        &ds,
        &[proj(&cams[2]), proj(&cams[3])],
        Some(&conf),
        front,
        "t".into(),
        0.0,
    )
    .unwrap();
    assert!(r.mpjpe3d_weighted_mm.unwrap() < 0.5);
    let mut off = proj(&cams[3]);
    for p in &mut off {
        p[0] += 8.0;
    }
    let [equal, weighted] = [None, Some(&conf[..])]
        .map(|c| eval::evaluate(&ds, &[proj(&cams[2]), off], c, front, "t".into(), 0.0).unwrap());
    assert_eq!(
        equal.mpjpe3d_mm, weighted.mpjpe3d_mm,
        "the plain figure ignores weights"
    );
    assert!(
        weighted.mpjpe3d_weighted_mm.unwrap() < equal.mpjpe3d_mm.unwrap(),
        "{weighted:?} {equal:?}"
    );
    // Moved 100 mm along z, the error is 100 mm.
    ds.gt3d = vec![[[100.0, -50.0, 1000.0]; JOINTS]; 2];
    let r = eval::evaluate(
        &ds,
        &[proj(&cams[2]), proj(&cams[3])],
        None,
        front,
        "t".into(),
        0.0,
    )
    .unwrap();
    assert!((r.mpjpe3d_mm.unwrap() - 100.0).abs() < 0.5);
    // The mean-pose baseline predicts the training set's mean visible label per camera.
    let train = tiny_dataset(
        vec![
            [[10.0, 20.0]; JOINTS],
            [[0.0; 2]; JOINTS],
            [[30.0, 40.0]; JOINTS],
            [[1.0; 2]; JOINTS],
        ],
        vec![[1; JOINTS]; 4],
    );
    let p = eval::mean_pose(&train, &ds).unwrap();
    assert_eq!(p[0], [[20.0, 30.0]; JOINTS]);
    assert_eq!(p[1], [[1.0, 1.0]; JOINTS]);
}

#[test]
fn a_dataset_round_trips_through_its_files() {
    let dir = tempfile::tempdir().unwrap();
    let sim = dir.path().join("sim");
    let opts = SimOptions {
        seed: 5,
        subjects: 1,
        seconds: 0.6,
        movements: vec![Movement::JumpingJacks],
        split: Split::Train,
        pixel: PixelModel::V2,
    };
    simulate::generate(&sim, &opts, |_, _| {}).unwrap();
    let out = dir.path().join("ds");
    let dopts = mean_options(None);
    let m = dataset::build(&sim, &out, &dopts, |_, _| {}).unwrap();
    assert_eq!(
        m.pixel_models,
        ["v2"],
        "the sim manifest's pixel model carries over"
    );
    let ds = Dataset::open(&out).unwrap();
    assert_eq!(ds.len() as u64, m.samples);
    assert!(ds.len() >= 2, "{} samples", ds.len());
    // Row i of the files is what the library computes for that window.
    let source = &dataset::sources(&sim).unwrap()[0];
    let events = dataset::read_events(&source.events).unwrap();
    let cams = dhp19_cameras().unwrap();
    let cameras = vec![(2, cams[2]), (3, cams[3])];
    // `evpose eval` names the pixel model with the figures.
    let front = [(2u8, &cams[2]), (3u8, &cams[3])];
    let r = eval::evaluate(&ds, &ds.label2d, None, front, "labels".into(), 0.0).unwrap();
    assert_eq!(
        (r.pixel_models.as_slice(), r.synthetic),
        (&["v2".to_string()][..], true)
    );
    let want = dataset::windows(source, &events, &cameras, &dopts, 0).unwrap();
    assert_eq!(want.len(), ds.len());
    let points = ds.points_range(0, ds.len()).unwrap();
    for (i, w) in want.iter().enumerate() {
        assert_eq!(points[i], w.points, "row {i}");
        assert_eq!(
            (ds.label2d[i], ds.mask[i], ds.gt3d[i]),
            (w.label2d, w.mask, w.gt3d)
        );
        assert_eq!((ds.camera[i], ds.window[i]), (w.camera, w.window));
        assert_eq!(ds.person[i], u8::from(w.person));
    }
    // The test split of a training set is empty.
    let test = dataset::build(
        &sim,
        &dir.path().join("t"),
        &DatasetOptions {
            split: SplitFilter::Test,
            ..dopts
        },
        |_, _| {},
    )
    .unwrap();
    assert_eq!(test.samples, 0);
}

#[test]
fn dhp19_filters_drop_hot_pixels_and_isolated_events() {
    use evpose_host::dataset::{dhp19_filter, BACKGROUND_WINDOW_US, HOT_PIXEL_EVENTS};
    let e = |x: u16, y: u16, t: i64| Event::new(x, y, t, true);
    let mut events = vec![
        (2, e(10, 10, 0)),                                // no neighbour before it: dropped
        (2, e(11, 10, 1_000)),                            // (10, 10) fired 1 ms ago: kept
        (3, e(12, 10, 2_000)), // another camera: its neighbours are camera 3's: dropped
        (2, e(12, 11, 3_000)), // (11, 10) is a neighbour: kept
        (2, e(40, 40, 4_000)), // isolated: dropped
        (2, e(41, 41, 4_000 + BACKGROUND_WINDOW_US)), // exactly 70 ms: kept
        (2, e(42, 42, 4_000 + 3 * BACKGROUND_WINDOW_US)), // too late: dropped
    ];
    // A hot pixel with 10,000 events (and a neighbour that keeps the rest alive).
    let hot: Vec<(u8, Event)> = (0..HOT_PIXEL_EVENTS as i64)
        .map(|i| (1u8, e(100, 100, 10 * i)))
        .collect();
    events.extend(hot);
    events.sort_by_key(|(_, e)| e.t);
    let stats = dhp19_filter(&mut events, 346, 260);
    assert_eq!(stats.hot, u64::from(HOT_PIXEL_EVENTS));
    assert_eq!(stats.background, 4);
    let kept: Vec<(u16, u16)> = events.iter().map(|(_, e)| (e.x, e.y)).collect();
    assert_eq!(kept, vec![(11, 10), (12, 11), (41, 41)]);
}

/// A MATLAB v5 file (uncompressed, little-endian) with `XYZPOS`: one (T, 3) double field per
/// joint, column-major, written by hand from the format's specification.
fn mat_file(names: &[&str], t: usize, value: impl Fn(usize, usize, usize) -> f64) -> Vec<u8> {
    fn tag(out: &mut Vec<u8>, ty: u32, bytes: &[u8]) {
        out.extend_from_slice(&ty.to_le_bytes());
        out.extend_from_slice(&(bytes.len() as u32).to_le_bytes());
        out.extend_from_slice(bytes);
        out.resize(out.len().next_multiple_of(8), 0);
    }
    fn matrix(class: u32, dims: &[i32], name: &str, body: &[u8]) -> Vec<u8> {
        let mut m = Vec::new();
        tag(
            &mut m,
            6,
            &[class.to_le_bytes(), 0u32.to_le_bytes()].concat(),
        );
        tag(
            &mut m,
            5,
            &dims
                .iter()
                .flat_map(|d| d.to_le_bytes())
                .collect::<Vec<u8>>(),
        );
        tag(&mut m, 1, name.as_bytes());
        m.extend_from_slice(body);
        let mut out = Vec::new();
        tag(&mut out, 14, &m);
        out
    }
    let mut body = Vec::new();
    // Field name length (packed small element), then the names, 32 bytes each.
    body.extend_from_slice(&((4u32 << 16) | 5).to_le_bytes());
    body.extend_from_slice(&32u32.to_le_bytes());
    let mut names_bytes = Vec::new();
    for n in names {
        let mut b = n.as_bytes().to_vec();
        b.resize(32, 0);
        names_bytes.extend(b);
    }
    tag(&mut body, 1, &names_bytes);
    for j in 0..names.len() {
        let mut data = Vec::new();
        for axis in 0..3 {
            for row in 0..t {
                data.extend_from_slice(&value(j, row, axis).to_le_bytes());
            }
        }
        let mut field = Vec::new();
        tag(&mut field, 9, &data);
        body.extend(matrix(6, &[t as i32, 3], "", &field));
    }
    let mut file = vec![b' '; 116];
    file[..19].copy_from_slice(b"MATLAB 5.0 MAT-file");
    file.extend_from_slice(&[0; 8]);
    file.extend_from_slice(&0x0100u16.to_le_bytes());
    file.extend_from_slice(b"IM");
    file.extend(matrix(2, &[1, 1], "XYZPOS", &body));
    file
}

#[test]
fn real_dhp19_files_are_read_with_their_vicon_mat() {
    let dir = tempfile::tempdir().unwrap();
    // A simulated recording stands in for DHP19's events (same AEDAT 2.0 layout), named as
    // DHP19 names them; its ground truth goes into a .mat with the fields out of order.
    let sim = dir.path().join("sim");
    let opts = SimOptions {
        seed: 9,
        subjects: 1,
        seconds: 1.2,
        movements: vec![Movement::Squats],
        split: Split::Train,
        pixel: PixelModel::V2,
    };
    let m = simulate::generate(&sim, &opts, |_, _| {}).unwrap();
    let gt = simulate::read_gt(&sim.join(m.recordings[0].gt.as_ref().unwrap())).unwrap();
    let real = dir.path().join("dhp19");
    std::fs::create_dir_all(&real).unwrap();
    std::fs::copy(sim.join(&m.recordings[0].file), real.join("S14_2_3.aedat")).unwrap();
    let mut names = evpose_sim::JOINT_NAMES.to_vec();
    names.swap(5, 6); // hipL before hipR, as one public loader has it: read by name
    let order: Vec<usize> = names
        .iter()
        .map(|n| evpose_sim::JOINT_NAMES.iter().position(|m| m == n).unwrap())
        .collect();
    let mat = mat_file(&names, gt.len(), |j, row, axis| {
        f64::from(gt[row][order[j]][axis])
    });
    std::fs::write(real.join("S14_2_3.mat"), mat).unwrap();
    let sources = dataset::sources(&real).unwrap();
    assert_eq!(sources.len(), 1);
    let s = &sources[0];
    assert_eq!((s.subject, s.split, s.real), (14, Split::Test, true));
    assert_eq!(s.gt, gt);
    assert_eq!(s.gt_t0_us, None);
    // A directory with neither kind of recording is an error, not an empty dataset.
    assert!(dataset::sources(dir.path()).is_err());

    // A trigger 10 ms in starts the Vicon clock, as in DHP19's files: no window before it,
    // and the labels follow the trigger's clock (the windows differ from the fallback's).
    let build = |name: &str| {
        let out = dir.path().join(name);
        dataset::build(&real, &out, &mean_options(Some(false)), |_, _| {}).unwrap();
        Dataset::open(&out).unwrap()
    };
    let fallback = build("ds-fallback");
    let path = real.join("S14_2_3.aedat");
    let bytes = std::fs::read(&path).unwrap();
    let end = b"#End Of ASCII Header\r\n";
    let body = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
    let ts = |i: usize| {
        u32::from_be_bytes(
            bytes[body + 8 * i + 4..body + 8 * i + 8]
                .try_into()
                .unwrap(),
        )
    };
    let trigger = ts(0) + 10_000;
    let at = (0..(bytes.len() - body) / 8)
        .find(|&i| ts(i) >= trigger)
        .unwrap();
    let mut with = bytes[..body + 8 * at].to_vec();
    with.extend_from_slice(&0x400u32.to_be_bytes());
    with.extend_from_slice(&trigger.to_be_bytes());
    with.extend_from_slice(&bytes[body + 8 * at..]);
    std::fs::write(&path, with).unwrap();
    let triggered = build("ds-trigger");
    assert!(!triggered.is_empty());
    assert!(
        triggered.span_us.iter().all(|s| s[0] > i64::from(trigger)),
        "a window starts before the trigger"
    );
    assert!(fallback.span_us.iter().any(|s| s[0] < i64::from(trigger)));
}

/// DHP19's `Generate_DHP19.m` decides where a recording's Vicon clock starts from its special
/// (trigger) events; `dhp19_span` follows it case by case.
#[test]
fn dhp19_span_follows_dhp19s_trigger_cases() {
    use evpose_host::dataset::dhp19_span;
    let (first, last, len) = (1_000, 9_001_000, 500); // n = 500 samples = 5 s
    let n = 5_000_000;
    // No trigger: the first and the last event (DHP19's fallback).
    assert_eq!(dhp19_span(&[], first, last, len), Some((first, last)));
    // One trigger near the start starts the recording; near the end, it ends it.
    assert_eq!(
        dhp19_span(&[2_000], first, last, len),
        Some((2_000, 2_000 + n))
    );
    assert_eq!(
        dhp19_span(&[9_000_000], first, last, len),
        Some((9_000_000 - n, 9_000_000))
    );
    // Two or four: the first one decides, the same way.
    assert_eq!(
        dhp19_span(&[2_000, 9_000_000], first, last, len),
        Some((2_000, 2_000 + n))
    );
    assert_eq!(
        dhp19_span(&[8_000_000, 1, 2, 3], first, last, len),
        Some((8_000_000 - n, 8_000_000))
    );
    // Three or five: the first and the last.
    assert_eq!(dhp19_span(&[5, 6, 7], first, last, len), Some((5, 7)));
    assert_eq!(dhp19_span(&[5, 6, 7, 8, 9], first, last, len), Some((5, 9)));
    // More: skipped, as DHP19 skips its corrupt files.
    assert_eq!(dhp19_span(&[1; 6], first, last, len), None);
}

#[test]
fn the_per_joint_chart_draws_one_bar_per_joint_and_figure() {
    let cams = dhp19_cameras().unwrap();
    let label = [[100.0, 100.0]; JOINTS];
    let ds = tiny_dataset(vec![label, label], vec![[1; JOINTS]; 2]);
    // Joint j off by j pixels in both cameras: bar heights grow with j.
    let pred: [[f32; 2]; JOINTS] = std::array::from_fn(|j| [100.0 + j as f32, 100.0]);
    let r = eval::evaluate(
        &ds,
        &[pred, pred],
        None,
        [(2, &cams[2]), (3, &cams[3])],
        "t".into(),
        0.0,
    )
    .unwrap();
    let img = eval::per_joint_chart(&r).unwrap();
    let blue = image::Rgb([70u8, 120, 200]);
    // Pixels of each 2-D bar, left to right: joint 0 has none, then strictly more.
    let column_height = |x: u32| {
        (0..img.height())
            .filter(|&y| *img.get_pixel(x, y) == blue)
            .count()
    };
    let heights: Vec<usize> = (0..JOINTS as u32)
        .map(|j| column_height(16 + j * 56 + 20))
        .collect();
    assert_eq!(heights[0], 0);
    assert!(
        heights.windows(2).skip(1).all(|w| w[0] < w[1]),
        "{heights:?}"
    );
}

/// DHP19 Vicon MAT-files written by an independent writer (SciPy's `savemat`,
/// `scripts/make-mat-fixtures.py`): uncompressed and zlib-compressed Level 5, doubles and
/// singles, a NaN, and variables of classes the reader skips beside `XYZPOS`.
#[test]
fn vicon_mat_files_written_by_scipy_read_back() {
    use evpose_host::dhp19::mat::{read_variables, read_xyzpos, Value};
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/mat");
    let read = |name: &str| std::fs::read(dir.join(name)).unwrap();
    let value = |j: usize, r: usize, a: usize, offset: f64| (100 * j + 10 * r + a) as f64 + offset;
    for (name, t, offset) in [
        ("xyzpos-v6.mat", 4, 0.5),
        ("xyzpos-v7.mat", 4, 0.5),
        ("xyzpos-single-extra.mat", 3, 0.0),
    ] {
        let bytes = read(name);
        let frames = read_xyzpos(&bytes)
            .and_then(|v| v.dhp19_frames())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(frames.len(), t, "{name}");
        for (r, frame) in frames.iter().enumerate() {
            for (j, joint) in frame.iter().enumerate() {
                for (a, &v) in joint.iter().enumerate() {
                    if name.contains("extra") && (j, r, a) == (0, 1, 1) {
                        assert!(v.is_nan(), "{name}: {v}");
                    } else {
                        assert_eq!(
                            v,
                            value(j, r, a, offset),
                            "{name} joint {j} row {r} axis {a}"
                        );
                    }
                }
            }
        }
    }
    // The other variables are there, skipped or read as what they are.
    let vars = read_variables(&read("xyzpos-single-extra.mat")).unwrap();
    let names: Vec<&str> = vars.iter().map(|v| v.name.as_str()).collect();
    assert_eq!(names, ["note", "XYZPOS", "cells", "k"]);
    assert!(matches!(vars[0].value, Value::Unsupported { .. }));
    assert!(matches!(vars[2].value, Value::Unsupported { .. }));
    assert!(matches!(vars[3].value, Value::Numeric(_)));
}

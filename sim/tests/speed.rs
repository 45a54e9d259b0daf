//! Throughput (ignored: run with `cargo test --release --test speed -- --ignored --nocapture`,
//! `RAYON_NUM_THREADS=1` for one core).

mod common;

use evpose_sim::{simulate_many, Movement, PixelModel, RecordingSpec};

#[test]
#[ignore = "timing; run in release"]
fn events_per_second() {
    let cams = common::dhp19_cameras();
    let specs: Vec<RecordingSpec> = [
        Movement::JumpingJacks,
        Movement::Boxing,
        Movement::WalkInPlace,
        Movement::ArmAbductionLeft,
    ]
    .iter()
    .enumerate()
    .map(|(i, &movement)| RecordingSpec {
        seed: 100 + i as u64,
        subject: i as u32,
        movement,
        seconds: 4.0,
        pixel: PixelModel::V2,
    })
    .collect();
    let start = std::time::Instant::now();
    let events = std::sync::atomic::AtomicUsize::new(0);
    simulate_many(&specs, &cams, |i, r| {
        let per_cam: Vec<usize> = (0..4).map(|c| r.channel(c).count()).collect();
        println!(
            "{}: {} events, per camera {per_cam:?}, {} steps",
            specs[i].movement,
            r.events.len(),
            r.steps
        );
        events.fetch_add(r.events.len(), std::sync::atomic::Ordering::Relaxed);
    });
    let s = start.elapsed().as_secs_f64();
    let n = events.into_inner() as f64;
    let threads = rayon::current_num_threads();
    let rate = n / s / threads as f64;
    println!(
        "{n} events in {s:.2} s on {threads} thread(s): {rate:.0} events/s per thread; 6e8 events on 2 cores: {:.1} min",
        6e8 / (2.0 * rate) / 60.0
    );
}

#[test]
#[ignore = "survey; run in release"]
fn event_rates_per_movement() {
    let cams = common::dhp19_cameras();
    // SIM_MOVEMENTS=a,b,… limits the survey.
    let only = std::env::var("SIM_MOVEMENTS").unwrap_or_default();
    let specs: Vec<RecordingSpec> = Movement::ALL
        .iter()
        .filter(|m| only.is_empty() || only.split(',').any(|o| o == m.name()))
        .enumerate()
        .map(|(i, &movement)| RecordingSpec {
            seed: 7,
            subject: i as u32,
            movement,
            seconds: 3.0,
            pixel: PixelModel::V2,
        })
        .collect();
    let lines = std::sync::Mutex::new(Vec::new());
    let start = std::time::Instant::now();
    let events = std::sync::atomic::AtomicUsize::new(0);
    simulate_many(&specs, &cams, |i, r| {
        events.fetch_add(r.events.len(), std::sync::atomic::Ordering::Relaxed);
        let per_cam: Vec<String> = (0..4)
            .map(|c| format!("{:>4}k", r.channel(c).count() / 3 / 1000))
            .collect();
        let visible = r
            .gt_mm
            .iter()
            .flat_map(|g| g.iter())
            .filter(|j| {
                let p = j.map(f64::from);
                [2, 3]
                    .iter()
                    .all(|&c| cams[c].project(p).is_some_and(|uv| cams[c].is_visible(uv)))
            })
            .count();
        let total = r.gt_mm.len() * 13;
        lines.lock().unwrap().push((i, format!(
            "{:<22} events/s per camera {} | joints visible in both front cameras {visible}/{total} | {} steps",
            specs[i].movement.name(),
            per_cam.join(" "),
            r.steps
        )));
    });
    let mut lines = lines.into_inner().unwrap();
    lines.sort();
    for (_, l) in lines {
        println!("{l}");
    }
    let s = start.elapsed().as_secs_f64();
    let n = events.into_inner() as f64;
    let rate = n / s / rayon::current_num_threads() as f64;
    println!("{n} events in {s:.1} s: {rate:.0} events/s per thread");
}

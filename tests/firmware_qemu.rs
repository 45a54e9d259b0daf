//! The firmware (`firmware/`) under QEMU against the core on the host, window for window.
//!
//! `firmware_matches_the_host_core_under_qemu` builds the `thumbv7em-none-eabihf` image, runs it
//! on QEMU's `mps2-an500` (Cortex-M7) with semihosting and `-icount shift=0` (and
//! `cortex_m4_build_matches_the_host_core_under_qemu` the same firmware built for a Cortex-M4F,
//! on QEMU's `mps2-an386`), decodes its defmt
//! frames with `defmt-decoder` and the ELF's defmt table (what `defmt-print` does), runs the same
//! event stream through `evpose-core` on the host with the same storage, seed and model blob,
//! and asserts identical windows, point clouds, network inputs, head accumulators (CRC-32),
//! joints, joint confidences and temporally filtered joints (f32 bits). It fails, never skips,
//! when QEMU or the target is missing: `scripts/test.sh` installs
//! both. Both tests also check that the image has no heap and no panic path beyond those
//! `firmware/panic-paths.txt` lists, and print the firmware's figures
//! (instructions per stage, per point-layer MAC, flash, RAM, stack); run with `--nocapture`.
//! `firmware_reports_a_stack_overflow_under_qemu` runs an image that overflows its stack on
//! purpose and requires the HardFault handler's report and exit code instead of a lockup.
//!
//! This file also holds the reference codec of the firmware's `EVS1` event stream (format in
//! `firmware/src/input.rs`): the encoder that made `firmware/assets/street-00-02.evs` and an
//! independent decoder, checked against the bundled `.npy` windows it was cut from.

use std::io::Read as _;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use evpose_core::kernels::Kernels;
use evpose_core::model::FEATURES;
use evpose_core::pipeline::{PipelineError, I8};
use evpose_core::smooth::{AxisState, FixedLag, Held, LagParams, LagSlot, SmoothParams, Smoother};
use evpose_core::{
    scratch_words, Davis346Storage, Estimator, Event, Joint2d, Model, Plan, RasterConfig,
    Rasterizer, Session, Workspace,
};
use evpose_host::budget::{image_budget, ImageBudget};
use evpose_host::model::AlignedBlob;
use evpose_tests::fixtures;

/// Sampler seed: the firmware's `SEED` (its point count is the model's `input_points`).
const SEED: u64 = 0;

/// The windows in the event asset: the first 22,500 events of the DAVIS346 street recording,
/// which are the bundled windows street-00, -01 and -02.
const WINDOWS: [&str; 3] = ["street-00", "street-01", "street-02"];
/// Longest QEMU may run (it takes a few seconds).
const QEMU_TIMEOUT: Duration = Duration::from_secs(300);

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn firmware_dir() -> PathBuf {
    repo().join("firmware")
}

fn event_asset() -> PathBuf {
    firmware_dir().join("assets/street-00-02.evs")
}

fn model_asset() -> PathBuf {
    firmware_dir().join("../models/mcu.evq")
}

/// The reference codec of the `EVS1` stream (see `firmware/src/input.rs`).
mod evs {
    use evpose_core::Event;

    const MAGIC: &[u8; 4] = b"EVS1";
    const HEADER_LEN: usize = 24;
    const TIME: u32 = 1 << 31;
    /// Largest time step an EVENT word holds, exclusive.
    const DT_LIMIT: i64 = 1 << 9;
    /// Range of a TIME word's signed 31-bit step.
    const STEP_MIN: i64 = -(1 << 30);
    const STEP_MAX: i64 = (1 << 30) - 1;

    /// Header fields.
    #[derive(Debug, PartialEq, Eq)]
    pub struct Header {
        pub width: u16,
        pub height: u16,
        pub t0: i64,
    }

    /// Encodes events; `t0` is the first event's time (0 for an empty stream).
    pub fn encode(events: &[Event], width: u16, height: u16) -> Vec<u8> {
        let t0 = events.first().map_or(0, |e| e.t);
        let mut out = Vec::with_capacity(HEADER_LEN + 4 * events.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&width.to_le_bytes());
        out.extend_from_slice(&height.to_le_bytes());
        out.extend_from_slice(&(events.len() as u32).to_le_bytes());
        out.extend_from_slice(&0u32.to_le_bytes());
        out.extend_from_slice(&t0.to_le_bytes());
        let mut time = t0;
        for e in events {
            assert!(e.x < 2048 && e.y < 1024, "pixel {e:?} outside 2048 x 1024");
            let mut step = e.t - time;
            while !(0..DT_LIMIT).contains(&step) {
                let s = step.clamp(STEP_MIN, STEP_MAX);
                out.extend_from_slice(&(TIME | (s as i32 as u32 & !TIME)).to_le_bytes());
                step -= s;
            }
            let word =
                u32::from(e.x) | u32::from(e.y) << 11 | u32::from(e.on) << 21 | (step as u32) << 22;
            out.extend_from_slice(&word.to_le_bytes());
            time = e.t;
        }
        out
    }

    /// Decodes a whole stream.
    pub fn decode(bytes: &[u8]) -> Result<(Header, Vec<Event>), String> {
        if bytes.len() < HEADER_LEN || &bytes[..4] != MAGIC {
            return Err("not an EVS1 stream".into());
        }
        let u16_at = |o: usize| u16::from_le_bytes(bytes[o..o + 2].try_into().unwrap());
        let count = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
        let header = Header {
            width: u16_at(4),
            height: u16_at(6),
            t0: i64::from_le_bytes(bytes[16..24].try_into().unwrap()),
        };
        let mut time = header.t0;
        let mut events = Vec::with_capacity(count);
        let mut words = bytes[HEADER_LEN..].chunks_exact(4);
        while events.len() < count {
            let w = u32::from_le_bytes(
                words
                    .next()
                    .ok_or_else(|| format!("stream ends after {} events", events.len()))?
                    .try_into()
                    .unwrap(),
            );
            if w & TIME != 0 {
                // Bits 0..=30, sign-extended from bit 30.
                let step = i64::from(w & !TIME) - if w & 1 << 30 != 0 { 1 << 31 } else { 0 };
                time += step;
                continue;
            }
            time += i64::from(w >> 22 & 0x1FF);
            events.push(Event::new(
                (w & 0x7FF) as u16,
                (w >> 11 & 0x3FF) as u16,
                time,
                w >> 21 & 1 == 1,
            ));
        }
        if words.next().is_some() || !words.remainder().is_empty() {
            return Err("bytes after the last event".into());
        }
        Ok((header, events))
    }
}

/// Events of a bundled `.npy` window ((N, 4) float64 `[x, y, t_us, p]`).
fn npy_events(path: &Path) -> Vec<Event> {
    let (shape, v) = evpose_host::array::read_f64(path).unwrap();
    assert_eq!(shape.len(), 2, "{}", path.display());
    assert_eq!(shape[1], 4, "{}", path.display());
    v.chunks_exact(4)
        .map(|r| Event::new(r[0] as u16, r[1] as u16, r[2] as i64, r[3] > 0.5))
        .collect()
}

fn fixture_events() -> Vec<Event> {
    WINDOWS
        .iter()
        .flat_map(|w| npy_events(&fixtures().join(format!("{w}.events.npy"))))
        .collect()
}

#[test]
fn event_asset_is_the_recording_windows() {
    let bytes = std::fs::read(event_asset()).unwrap();
    let (header, decoded) = evs::decode(&bytes).unwrap();
    let want = fixture_events();
    assert_eq!(
        header,
        evs::Header {
            width: 346,
            height: 260,
            t0: want[0].t
        }
    );
    assert_eq!(decoded.len(), want.len());
    for (i, (d, w)) in decoded.iter().zip(&want).enumerate() {
        assert_eq!(d, w, "event {i}");
    }
    // The committed asset is exactly what the encoder makes: 4 bytes per event.
    assert_eq!(evs::encode(&want, 346, 260), bytes);
    assert_eq!(bytes.len(), 24 + 4 * want.len());
}

#[test]
fn event_codec_round_trips_odd_streams() {
    let events = [
        Event::new(0, 0, -5, false),
        Event::new(2047, 1023, -5, true),          // same time
        Event::new(3, 4, 506, true),               // step of 511: still one word
        Event::new(3, 4, 1018, false),             // step of 512: a TIME word
        Event::new(5, 6, 1000, true),              // backwards
        Event::new(7, 8, 1000 + (1 << 31), false), // beyond one TIME word
        Event::new(9, 10, -(1 << 40), true),       // far backwards
        Event::new(345, 259, 1_589_163_147_368_868, true), // an absolute DV timestamp
    ];
    let bytes = evs::encode(&events, 2048, 1024);
    let (header, decoded) = evs::decode(&bytes).unwrap();
    assert_eq!(header.t0, -5);
    assert_eq!(decoded, events);
    assert!(evs::decode(&bytes[..bytes.len() - 1]).is_err());
    assert_eq!(evs::decode(&evs::encode(&[], 1, 1)).unwrap().1, vec![]);
}

/// Rewrites `firmware/assets/street-00-02.evs` from a converted recording:
/// `EVPOSE_EVENTS_NPY=events.npy cargo test --release --test firmware_qemu -- --ignored
/// regenerate_event_asset` (what `scripts/make-firmware-assets.sh` runs).
#[test]
#[ignore = "regenerates a committed asset; run by scripts/make-firmware-assets.sh"]
fn regenerate_event_asset() {
    let npy = std::env::var_os("EVPOSE_EVENTS_NPY")
        .expect("set EVPOSE_EVENTS_NPY to an (N, 4) .npy of the DAVIS346 street recording");
    let mut events = npy_events(Path::new(&npy));
    events.truncate(WINDOWS.len() * 7_500);
    assert_eq!(events.len(), WINDOWS.len() * 7_500, "recording too short");
    std::fs::write(event_asset(), evs::encode(&events, 346, 260)).unwrap();
}

/// Fails with what to do when the tools are missing (CI installs both with scripts/test.sh).
fn require_tools() {
    let qemu = Command::new("qemu-system-arm").arg("--version").output();
    assert!(
        qemu.as_ref().is_ok_and(|o| o.status.success()),
        "qemu-system-arm is missing ({}); install it: `apt-get install qemu-system-arm` \
         (scripts/test.sh does)",
        qemu.err().map_or("it failed".into(), |e| e.to_string())
    );
    let libdir = Command::new("rustc")
        .args([
            "--print",
            "target-libdir",
            "--target",
            "thumbv7em-none-eabihf",
        ])
        .output()
        .expect("rustc runs");
    let libdir = PathBuf::from(String::from_utf8_lossy(&libdir.stdout).trim());
    let has_core = std::fs::read_dir(&libdir).is_ok_and(|d| {
        d.flatten()
            .any(|f| f.file_name().to_string_lossy().starts_with("libcore-"))
    });
    assert!(
        has_core,
        "the thumbv7em-none-eabihf target is not installed (no libcore in {}); install it: \
         `rustup target add thumbv7em-none-eabihf` (scripts/test.sh does)",
        libdir.display()
    );
}

/// The cores the firmware is built and run for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Cpu {
    /// The firmware as configured (`firmware/.cargo/config.toml`, default features): a
    /// Cortex-M7 with its double-precision FPv5 FPU, on QEMU's `mps2-an500`.
    M7,
    /// The same firmware built as a Cortex-M4F runs it (`-C target-cpu=cortex-m4`, without the
    /// `fpv5` feature: FPv4 requantization, f64 in software) on QEMU's Cortex-M4
    /// (`mps2-an386`), which faults on any instruction the M4 lacks.
    M4,
}

impl Cpu {
    fn machine(self) -> &'static str {
        match self {
            Cpu::M7 => "mps2-an500",
            Cpu::M4 => "mps2-an386",
        }
    }

    fn name(self) -> &'static str {
        match self {
            Cpu::M7 => "cortex-m7",
            Cpu::M4 => "cortex-m4",
        }
    }
}

/// The rustflags of `firmware/.cargo/config.toml` (its one `rustflags = [...]` list of quoted
/// flags without commas or `#`; comments dropped first), with the target CPU replaced by
/// `cpu`'s.
fn firmware_rustflags(cpu: Cpu) -> Vec<String> {
    let config = std::fs::read_to_string(firmware_dir().join(".cargo/config.toml")).unwrap();
    let code: String = config
        .lines()
        .map(|l| l.split('#').next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n");
    let list = code
        .split_once("rustflags = [")
        .and_then(|(_, rest)| rest.split_once(']'))
        .expect("firmware/.cargo/config.toml has a rustflags list")
        .0;
    let flags: Vec<String> = list
        .split(',')
        .map(|f| f.trim().trim_matches('"'))
        .filter(|f| !f.is_empty())
        .map(|f| {
            if f.starts_with("target-cpu=") {
                format!("target-cpu={}", cpu.name())
            } else {
                f.to_string()
            }
        })
        .collect();
    assert!(
        flags.iter().any(|f| f.starts_with("target-cpu=")),
        "no target-cpu in {flags:?}"
    );
    flags
}

/// Builds the release image for `cpu` (its own workspace; the M4's in a target folder of its
/// own); returns the ELF's path.
fn build_firmware(cpu: Cpu) -> PathBuf {
    build_firmware_with(cpu, None)
}

/// [`build_firmware`] with one more cargo feature of the firmware, in a target folder named
/// after it (so that it never replaces the pipeline's image that another test runs).
fn build_firmware_with(cpu: Cpu, feature: Option<&str>) -> PathBuf {
    let dir = firmware_dir();
    let mut target = match cpu {
        Cpu::M7 => dir.join("target"),
        Cpu::M4 => dir.join("target/cortex-m4"),
    };
    if let Some(f) = feature {
        target = target.join(f);
    }
    // The three images build at once (the tests run in parallel) into nested target folders.
    // Cargo creates a missing target folder as a temporary one renamed into place, and the M7
    // build's rename of `firmware/target` could replace the folder in which the other builds
    // had just made theirs ("No such file or directory"); folders that already exist are used
    // as they are.
    std::fs::create_dir_all(&target).expect("the firmware's target folder");
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut cmd = Command::new(cargo);
    // The firmware's .cargo/config.toml (target, linker scripts, CPU) applies from its folder;
    // flags meant for the host build must not leak into it.
    cmd.args(["build", "--release"])
        .current_dir(&dir)
        .env("CARGO_TARGET_DIR", &target);
    for var in [
        "RUSTFLAGS",
        "CARGO_ENCODED_RUSTFLAGS",
        "CARGO_BUILD_RUSTFLAGS",
        "CARGO_BUILD_TARGET",
        "RUSTDOCFLAGS",
    ] {
        cmd.env_remove(var);
    }
    if let Some(f) = feature {
        cmd.args(["--features", f]);
    }
    if cpu == Cpu::M4 {
        // The config's flags with the other CPU (the variable replaces the config's list).
        cmd.arg("--no-default-features").env(
            "CARGO_ENCODED_RUSTFLAGS",
            firmware_rustflags(cpu).join("\x1f"),
        );
    }
    let out = cmd.output().expect("cargo runs");
    assert!(
        out.status.success(),
        "building the firmware for {cpu:?} failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    target.join("thumbv7em-none-eabihf/release/evpose-firmware")
}

/// Runs the image under QEMU; returns what it wrote to semihosting stdout (defmt frames).
/// Panics if it fails or runs longer than [`QEMU_TIMEOUT`].
fn run_qemu(elf: &Path, cpu: Cpu) -> Vec<u8> {
    let (status, bytes, stderr) = qemu(elf, cpu);
    let lines = defmt_lines(elf, &bytes).join("\n");
    match status {
        None => panic!("QEMU ran longer than {QEMU_TIMEOUT:?}; output:\n{lines}\n{stderr}"),
        Some(s) if !s.success() => panic!("the firmware failed ({s}):\n{lines}\n{stderr}"),
        Some(_) => bytes,
    }
}

/// Runs the image under QEMU: its exit status (`None` if it ran longer than [`QEMU_TIMEOUT`]
/// and was killed), what it wrote to semihosting stdout (defmt frames) and QEMU's stderr.
fn qemu(elf: &Path, cpu: Cpu) -> (Option<ExitStatus>, Vec<u8>, String) {
    let mut child = Command::new("qemu-system-arm")
        .args([
            "-machine",
            cpu.machine(),
            "-cpu",
            cpu.name(),
            "-nographic",
            "-monitor",
            "none",
            "-serial",
            "none",
            "-semihosting-config",
            "enable=on,target=native",
            "-icount",
            "shift=0",
            "-kernel",
        ])
        .arg(elf)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("qemu-system-arm starts");
    let mut stdout = child.stdout.take().expect("piped");
    let reader = std::thread::spawn(move || {
        let mut buf = Vec::new();
        stdout.read_to_end(&mut buf).map(|_| buf)
    });
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().expect("waits on QEMU") {
            break Some(s);
        }
        if start.elapsed() > QEMU_TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let bytes = reader.join().expect("reader").expect("QEMU's stdout");
    let mut stderr = String::new();
    if let Some(mut e) = child.stderr.take() {
        let _ = e.read_to_string(&mut stderr);
    }
    (status, bytes, stderr)
}

/// Decodes defmt frames with the ELF's table into text lines (levels as `ERROR `… prefixes).
fn defmt_lines(elf: &Path, bytes: &[u8]) -> Vec<String> {
    let elf = std::fs::read(elf).unwrap();
    let table = defmt_decoder::Table::parse(&elf)
        .expect("the ELF's defmt table parses")
        .expect("the ELF has a defmt table");
    let mut stream = table.new_stream_decoder();
    stream.received(bytes);
    let mut lines = Vec::new();
    loop {
        match stream.decode() {
            Ok(f) => {
                let level = f.level().map(|l| format!("{l:?} ").to_uppercase());
                lines.push(format!(
                    "{}{}",
                    level.unwrap_or_default(),
                    f.display_message()
                ));
            }
            Err(defmt_decoder::DecodeError::UnexpectedEof) => break,
            Err(e) => {
                lines.push(format!("(undecodable defmt data: {e:?})"));
                break;
            }
        }
    }
    lines
}

/// `key=value` fields of a line, after the first word when it has no `=`.
fn fields(line: &str) -> Vec<(&str, &str)> {
    let line = line.split_once(" joints=").map_or(line, |(a, _)| a);
    line.split_whitespace()
        .filter_map(|t| t.split_once('='))
        .collect()
}

fn field<T: std::str::FromStr>(line: &str, key: &str) -> T {
    let v = fields(line)
        .into_iter()
        .find(|(k, _)| *k == key)
        .unwrap_or_else(|| panic!("no {key}= in {line:?}"))
        .1;
    let v = v.strip_prefix("0x").map_or_else(
        || v.to_string(),
        |hex| u64::from_str_radix(hex, 16).unwrap().to_string(),
    );
    v.parse()
        .unwrap_or_else(|_| panic!("bad {key}= in {line:?}"))
}

/// What the firmware or the host computed for one window.
#[derive(Debug, PartialEq, Eq)]
struct WindowResult {
    events: u32,
    points: usize,
    t_min: i64,
    t_max: i64,
    crc_points: u32,
    crc_input: u32,
    crc_heads: u32,
    joints: Vec<u16>,
    /// Joint confidences, as f32 bits (compared exactly).
    confidence_bits: Vec<u32>,
    /// The temporally filtered joints (`core::smooth`), `[x, y]` per joint, as f32 bits.
    filtered_bits: Vec<u32>,
}

/// The firmware's per-window lines: results and instructions.
fn firmware_windows(lines: &[String]) -> Vec<(WindowResult, String)> {
    let mut out = Vec::new();
    for i in 0.. {
        let tag = format!("window={i} ");
        let of_window: Vec<&String> = lines.iter().filter(|l| l.starts_with(&tag)).collect();
        if of_window.is_empty() {
            break;
        }
        let find = |key: &str| {
            *of_window
                .iter()
                .find(|l| l.contains(key))
                .unwrap_or_else(|| panic!("window {i}: no line with {key}"))
        };
        let res = find("crc_heads=");
        let list = |key: &str| -> Vec<u64> {
            find(key)
                .split_once(key)
                .and_then(|(_, j)| j.strip_suffix(']'))
                .expect("a list")
                .split(',')
                .map(|v| v.trim().parse().expect("a number"))
                .collect()
        };
        let joints = list(" joints=[").into_iter().map(|v| v as u16).collect();
        let confidence_bits = list(" confidence_bits=[")
            .into_iter()
            .map(|v| v as u32)
            .collect();
        let filtered_bits = list(" filtered_bits=[")
            .into_iter()
            .map(|v| v as u32)
            .collect();
        out.push((
            WindowResult {
                events: field(res, "events"),
                points: field(res, "points"),
                t_min: field(res, "t_min"),
                t_max: field(res, "t_max"),
                crc_points: field(res, "crc_points"),
                crc_input: field(res, "crc_input"),
                crc_heads: field(res, "crc_heads"),
                joints,
                confidence_bits,
                filtered_bits,
            },
            find(" instructions ").clone(),
        ));
    }
    out
}

/// The fixed-lag filter's outputs in the order they came: (window, `[x, y]` per joint as f32
/// bits).
type Lagged = Vec<(u64, Vec<u32>)>;

/// The firmware's `lagged:` lines.
fn firmware_lagged(lines: &[String]) -> Lagged {
    lines
        .iter()
        .filter_map(|l| l.strip_prefix("lagged: "))
        .map(|l| {
            let bits = l
                .split_once("bits=[")
                .and_then(|(_, b)| b.strip_suffix(']'))
                .expect("a list")
                .split(',')
                .map(|v| v.trim().parse().expect("a number"))
                .collect();
            (field(l, "window"), bits)
        })
        .collect()
}

/// The fixed-lag filter's parameters, from the firmware's `fixed_lag:` line.
fn firmware_lag(lines: &[String]) -> LagParams {
    let line = lines
        .iter()
        .find_map(|l| l.strip_prefix("fixed_lag: "))
        .expect("a fixed_lag: line");
    LagParams {
        lag: field(line, "lag"),
        reset_after_us: field(line, "reset_after_us"),
    }
}

/// The firmware's pipeline, on the host: the same core session over the same stream, storage,
/// seed and model blob, with the same digests; and the fixed-lag filter's outputs with the
/// firmware's parameters `lag`.
fn host_windows(events: &[Event], blob: &[u8], lag: LagParams) -> (Vec<WindowResult>, Lagged) {
    let model = Model::parse(blob).unwrap();
    let (j, w, h) = (model.joints(), model.width(), model.height());
    // The firmware's storage type, on the heap (122 KiB) and borrowed, as the firmware
    // borrows its `static`.
    let mut storage = Box::new(Davis346Storage::new());
    let raster = Rasterizer::new(RasterConfig::DAVIS346, &mut *storage).unwrap();
    let plan = Plan::new(&model, Kernels::best(), scratch_words(&model)).unwrap();
    let n = model.input_points(); // the firmware's POINTS (build.rs)
    let mut session = Session::new(raster, Estimator::new(plan, n, SEED));
    let mut indices = vec![0u32; n];
    let mut rows = vec![[0f32; FEATURES]; n];
    let mut scratch = vec![0i32; plan.scratch_words()];
    let (mut out_x, mut out_y) = (vec![0i32; j * w], vec![0i32; j * h]);
    let mut joints = vec![Joint2d::default(); j];
    let mut ws = Workspace::<I8> {
        indices: &mut indices,
        rows: &mut rows,
        scratch: &mut scratch,
        x: &mut out_x,
        y: &mut out_y,
        joints: &mut joints,
    };
    let scales = model.head_scales().expect("a version 3 blob");
    let mut smooth_state = vec![AxisState::default(); 2 * j];
    let mut smoother = Smoother::new(SmoothParams::DEFAULT, &mut smooth_state).unwrap();
    let mut lag_slots = vec![LagSlot::default(); FixedLag::slots_for(lag.lag)];
    let mut lag_held = vec![Held::default(); lag_slots.len() * j];
    let mut lagged = FixedLag::with_params(lag, j, &mut lag_slots, &mut lag_held).unwrap();
    let mut lagged_out = Vec::new();
    let pop = |f: &mut FixedLag<'_>, to: &mut Lagged| {
        let mut buf = vec![[0f32; 2]; j];
        while let Some(k) = f.pop(&mut buf) {
            to.push((k, buf.iter().flatten().map(|v| v.to_bits()).collect()));
        }
    };
    let mut out = Vec::new();
    // Event by event, unlike the firmware's batches: windows do not depend on batching.
    for e in events {
        session
            .feed(std::slice::from_ref(e), &mut ws, &mut (), |e| {
                let s = e.window.summary();
                let d = e.digest();
                let mut confidence = vec![0f32; e.joints.len()];
                e.confidence(scales, &mut confidence).unwrap();
                let mut filtered = vec![[0f32; 2]; e.joints.len()];
                smoother
                    .update(s.t_max, e.joints, &confidence, &mut filtered)
                    .unwrap();
                lagged.push(s.t_max, e.joints, &confidence).unwrap();
                pop(&mut lagged, &mut lagged_out);
                out.push(WindowResult {
                    events: s.events,
                    points: e.window.len(),
                    t_min: s.t_min,
                    t_max: s.t_max,
                    crc_points: d.points,
                    crc_input: d.input,
                    crc_heads: d.heads,
                    joints: e.joints.iter().flat_map(|p| [p.x, p.y]).collect(),
                    confidence_bits: confidence.iter().map(|c| c.to_bits()).collect(),
                    filtered_bits: filtered.iter().flatten().map(|v| v.to_bits()).collect(),
                });
                Ok::<(), PipelineError>(())
            })
            .unwrap();
    }
    lagged.finish();
    pop(&mut lagged, &mut lagged_out);
    (out, lagged_out)
}

/// An image's output, checked against the host core, and its sections and symbols.
struct Checked {
    elf: PathBuf,
    image: ImageBudget,
    text: String,
    firmware: Vec<(WindowResult, String)>,
    blob: AlignedBlob,
}

/// Builds the image for `cpu`, runs it under QEMU and asserts that it matches the host core:
/// the kernels' boot self-test, every window (points, network input, heads, joints,
/// confidences, filtered joints), the row-major plan, the fixed-lag filter, the event counts.
fn run_and_compare(cpu: Cpu) -> Checked {
    require_tools();
    let elf = build_firmware(cpu);
    let lines = defmt_lines(&elf, &run_qemu(&elf, cpu));
    let text = lines.join("\n");
    assert!(
        !lines.iter().any(|l| l.starts_with("ERROR")),
        "the firmware reported an error:\n{text}"
    );

    // The DSP kernels and the requantization (FPv5 on the M7, FPv4 on the M4), on the real
    // instructions, against the reference (boot self-test): i8 matvec, every int8 product, blocked matmat, pooling, i16 matvec and
    // requantization (five slopes each).
    let selftest = lines
        .iter()
        .find(|l| l.starts_with("selftest:"))
        .unwrap_or_else(|| panic!("no selftest line:\n{text}"));
    assert_eq!(field::<String>(selftest, "kernels"), "armdsp", "{selftest}");
    assert!(
        field::<u32>(selftest, "cases")
            >= 71 * 9 + 256 + 9 * 9 * 3 * 2 + 11 + 70 * 9 + 3 * 4 + (8 * 256 + 5 * 8) * 5,
        "{selftest}"
    );
    assert_eq!(field::<u32>(selftest, "mismatches"), 0, "{selftest}");
    // The batch event decoder against the per-event one (TIME words, straddled reads, an
    // overflow; `input::check_decoder`).
    assert_eq!(field::<u32>(selftest, "decoder_cases"), 24, "{selftest}");
    assert_eq!(
        field::<u32>(selftest, "decoder_mismatches"),
        0,
        "{selftest}"
    );
    // The core's EVT decoder on the real instructions: the first window's events as faery's
    // EVT 3.0 words and as evutils's EVT 2.1 words in a GenX320's byte order give its 7,500
    // events (`input::check_evt`, against the EVS1 stream).
    for (tag, name) in [("evt3:", "EVT 3.0"), ("evt21:", "EVT 2.1")] {
        let line = lines
            .iter()
            .find(|l| l.starts_with(tag))
            .unwrap_or_else(|| panic!("no {tag} line:\n{text}"));
        assert_eq!(field::<u32>(line, "events"), 7_500, "{line}");
        assert_eq!(field::<u32>(line, "mismatches"), 0, "{line}");
        println!(
            "{name} decoding: {:.1} instructions per event",
            field::<u64>(line, "instructions") as f64 / 7_500.0
        );
    }

    let (_, events) = evs::decode(&std::fs::read(event_asset()).unwrap()).unwrap();
    let blob = AlignedBlob::new(&std::fs::read(model_asset()).unwrap());
    // Lag 0 would pass every window through unchanged: a weaker comparison.
    let lag = firmware_lag(&lines);
    assert!(
        lag.lag >= 1,
        "the firmware's fixed-lag filter averages nothing: {lag:?}"
    );
    let (host, host_lagged) = host_windows(&events, blob.bytes(), lag);
    let firmware = firmware_windows(&lines);
    assert_eq!(host.len(), WINDOWS.len());
    assert_eq!(
        firmware.len(),
        host.len(),
        "the firmware reported {} windows:\n{text}",
        firmware.len()
    );
    for (i, ((fw, _), h)) in firmware.iter().zip(&host).enumerate() {
        assert_eq!(fw, h, "window {i}: firmware (left) and host (right) differ");
    }
    // The row-major plan the firmware times on the last window's input gives that window's
    // heads: the row-major block kernel, end to end, on the real instructions.
    let row_major = lines
        .iter()
        .find_map(|l| l.strip_prefix("row_major: "))
        .expect("a row_major: line");
    let last = host.last().expect("windows");
    assert_eq!(
        field::<u32>(row_major, "crc_heads"),
        last.crc_heads,
        "row-major plan on the last window: firmware and host heads differ"
    );
    // The fixed-lag filter: every window once, in order, the same bits; the windows differ.
    assert_eq!(
        host_lagged.iter().map(|l| l.0).collect::<Vec<_>>(),
        (0..host.len() as u64).collect::<Vec<_>>()
    );
    assert!(host_lagged.windows(2).all(|p| p[0].1 != p[1].1));
    assert_eq!(
        firmware_lagged(&lines),
        host_lagged,
        "fixed-lag filter: firmware (left) and host (right) differ"
    );
    let done = lines
        .iter()
        .find(|l| l.starts_with("done:"))
        .unwrap_or_else(|| panic!("no done line:\n{text}"));
    assert_eq!(field::<u64>(done, "accepted"), events.len() as u64);
    assert_eq!(field::<u64>(done, "dropped"), 0);
    Checked {
        image: image_budget(&elf).unwrap(),
        elf,
        text,
        firmware,
        blob,
    }
}

#[test]
fn firmware_matches_the_host_core_under_qemu() {
    let checked = run_and_compare(Cpu::M7);
    check_image(Cpu::M7, &checked);
    print_figures(Cpu::M7, &checked);
}

/// The image has no heap (no heap section or allocator symbol, nothing heap-like in the map),
/// and every function that calls into the panic machinery is one that
/// `firmware/panic-paths.txt` lists (and firmware/README.md explains): a new one fails here.
/// Both builds (M7 and M4) share the list.
fn check_image(cpu: Cpu, checked: &Checked) {
    let (elf, image) = (&checked.elf, &checked.image);
    assert!(
        image.heap.is_empty(),
        "{cpu:?}: heap in the image: {:?}",
        image.heap
    );
    let map = std::fs::read_to_string(elf.with_file_name("evpose-firmware.map")).unwrap();
    for needle in [".heap", "__rust_alloc", "__rg_alloc"] {
        assert!(
            !map.contains(needle),
            "{cpu:?}: the linker map mentions {needle}"
        );
    }

    let listed = std::fs::read_to_string(firmware_dir().join("panic-paths.txt")).unwrap();
    let listed: std::collections::BTreeSet<&str> = listed
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .collect();
    let found: Vec<String> = image
        .panic_paths
        .iter()
        .map(|p| format!("{} -> {}", p.caller, p.panics))
        .collect();
    let new: Vec<&String> = found
        .iter()
        .filter(|p| !listed.contains(p.as_str()))
        .collect();
    assert!(
        new.is_empty(),
        "{cpu:?}: panic paths not in firmware/panic-paths.txt (remove them, or list and explain them):\n{}",
        new.iter()
            .map(|p| p.as_str())
            .collect::<Vec<_>>()
            .join("\n")
    );
    let gone: Vec<&&str> = listed
        .iter()
        .filter(|l| !found.iter().any(|f| f == *l))
        .collect();
    eprintln!(
        "{cpu:?} panic paths: {} ({} listed paths not in this image: {gone:?})",
        found.len(),
        gone.len()
    );
}

/// The figures (goals, not asserts): see the README's "Firmware (Cortex-M7)" section.
fn print_figures(cpu: Cpu, c: &Checked) {
    eprintln!("firmware output ({cpu:?}):\n{}", c.text);
    let image = &c.image;
    let model = Model::parse(c.blob.bytes()).unwrap();
    for (i, (_, instr)) in c.firmware.iter().enumerate() {
        let infer: u64 = field(instr, "infer");
        let macs =
            model.macs_per_point() * model.input_points() as u64 + model.macs_after_pooling();
        eprintln!(
            "{cpu:?} window {i}: rasterize {:.1} instructions/event, infer {:.3} \
             instructions/MAC overall, {} per point-layer MAC",
            field::<f64>(instr, "rasterize") / 7_500.0,
            infer as f64 / macs as f64,
            field::<String>(instr, "per_point_layer_mac")
        );
    }
    eprintln!(
        "{cpu:?} image: flash {} bytes, RAM {} bytes ({} static + {:?} stack)",
        image.flash_bytes, image.ram_bytes, image.static_ram_bytes, image.stack_bytes
    );
}

/// A stack overflow is reported, not a lockup: the image built with the `overflow-test` feature
/// recurses without bound at boot, runs off the bottom of RAM (memory.x puts the stack there)
/// and faults; the HardFault handler (`firmware/src/fault.rs`) moves to a valid stack before
/// running any Rust, prints where the stack pointer went and exits with code 3. A handler on the
/// overflowed stack faults again inside HardFault: QEMU then aborts ("Lockup: can't escalate")
/// and a board hangs.
#[test]
fn firmware_reports_a_stack_overflow_under_qemu() {
    require_tools();
    let elf = build_firmware_with(Cpu::M7, Some("overflow-test"));
    let (status, bytes, stderr) = qemu(&elf, Cpu::M7);
    let text = defmt_lines(&elf, &bytes).join("\n");
    assert_eq!(
        status.and_then(|s| s.code()),
        Some(3),
        "the overflow did not end in the HardFault handler's exit; output:\n{text}\n{stderr}"
    );
    let line = text
        .lines()
        .find(|l| l.contains("hard fault: stack overflow"))
        .unwrap_or_else(|| panic!("no stack overflow report:\n{text}"));
    // The stack pointer it reports is below the stack region's bottom.
    let field = |key: &str| {
        let hex = line
            .split_once(&format!(" {key}=0x"))
            .map(|(_, rest)| &rest[..8])
            .unwrap_or_else(|| panic!("no {key} in {line}"));
        u32::from_str_radix(hex, 16).unwrap()
    };
    let (sp, bottom) = (field("sp"), field("bottom"));
    assert!(sp < bottom, "{line}");
    assert!(!text.contains("overflow-test: returned"), "{text}");
}

/// The firmware as a Cortex-M4F runs it, on QEMU's Cortex-M4: the same results, bit for bit,
/// from the FPv4 requantization and the rasterizer's integer slice fractions (f64 in
/// software), with the M7 image's checks of heap and panic paths. Its figures are what `evpose budget` takes for cores without FPv5
/// (`firmware/measured.json`'s `*_without_arm_fpv5`).
#[test]
fn cortex_m4_build_matches_the_host_core_under_qemu() {
    let checked = run_and_compare(Cpu::M4);
    check_image(Cpu::M4, &checked);
    print_figures(Cpu::M4, &checked);
}

//! Host wall time of the flight visual odometry on real 640x480 stereo pairs (the VO work items of
//! `docs/results/timing.md`), the
//! Rust half of `tools/vo_speed.py` (which exports the pairs and runs the OpenCV peer).
//!
//! Loads the rectified pairs listed in `DIR/pairs.txt` (one name per line; `NAME_left.pgm`,
//! `NAME_right.pgm`, binary P5 640x480) and their calibration `DIR/calibration.txt`
//! (`fx_px`, `fy_px`, `cx_px`, `cy_px`, `baseline_m` of the rectified left camera), then runs
//! `fsw::vo::VisualOdometry<150>` exactly as the flight software does: the flight `VoConfig` of
//! `NavConfig::rocky8` (through `FswConfig::rocky8`), `start` then `step` with the flight's
//! background quantum (`ExecConfig::background_quantum`, 60 cost units) until finished, one
//! update per consecutive pair, no motion prior (`None`: "no motion", as the flight passes when
//! it has none). The camera frame is taken as the rover frame (identity mounting): the pairs
//! come from a fixed camera, and the mounting only rotates the output.
//!
//! Each pass starts a fresh pipeline on the first pair (the keyframe, timed apart) and updates
//! on each following pair; the wall time of an update is `std::time::Instant` around `start`
//! and all its `step` calls. Run single-threaded and pinned to one core:
//!
//! ```sh
//! python3 tools/vo_speed.py /tmp/vo_speed --export-only
//! cargo build --release -p sim-host --example vo_speed
//! taskset -c 0 target/release/examples/vo_speed /tmp/vo_speed --passes 5
//! ```
//!
//! Options: `--passes P` timed passes (default 5), `--warmup W` untimed passes first
//! (default 1), `--json` one JSON object per update on stdout (for `tools/vo_speed.py`),
//! `--profile` one more pass run one work item per `step` with the host time summed per
//! `WorkKind` (the updates' items, not the first frame's), printed last (a `{"profile": ...}`
//! line with `--json`).

use anyhow::{bail, Context, Result};
use fsw::flight::FswConfig;
use fsw::vo::{Progress, VisualOdometry, VoConfig, VoOutput, WorkKind};
use rover_hal::{StereoCalibration, StereoFrame, IMAGE_HEIGHT_PX, IMAGE_PIXELS, IMAGE_WIDTH_PX};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Features of the flight pipeline (`fsw::flight::nav::VO_FEATURES`).
const FEATURES: usize = fsw::flight::nav::VO_FEATURES;

/// Reads a binary (P5) 640x480 8-bit PGM written by `tools/vo_speed.py`.
fn read_pgm(path: &Path) -> Result<Vec<u8>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let head = String::from_utf8_lossy(bytes.get(..32).unwrap_or(&bytes)).into_owned();
    let mut fields = head.split_ascii_whitespace();
    if fields.next() != Some("P5") {
        bail!("{}: not a binary PGM", path.display());
    }
    let w: usize = fields.next().context("width")?.parse()?;
    let h: usize = fields.next().context("height")?.parse()?;
    if (w, h) != (IMAGE_WIDTH_PX, IMAGE_HEIGHT_PX) || bytes.len() < IMAGE_PIXELS {
        bail!("{}: {w}x{h}, expected 640x480", path.display());
    }
    Ok(bytes[bytes.len() - IMAGE_PIXELS..].to_vec())
}

/// Reads `key = value` lines.
fn read_calibration(path: &Path) -> Result<StereoCalibration> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let values: BTreeMap<String, f64> = text
        .lines()
        .filter_map(|l| {
            let (k, v) = l.split_once('=')?;
            Some((k.trim().to_string(), v.trim().parse().ok()?))
        })
        .collect();
    let get = |k: &str| {
        values
            .get(k)
            .copied()
            .with_context(|| format!("{}: no {k}", path.display()))
    };
    Ok(StereoCalibration {
        fx_px: get("fx_px")?,
        fy_px: get("fy_px")?,
        cx_px: get("cx_px")?,
        cy_px: get("cy_px")?,
        baseline_m: get("baseline_m")?,
        rot_rover_from_camera: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        pos_camera_in_rover_m: [0.0; 3],
    })
}

/// One timed update.
struct Update {
    pass: usize,
    pair: String,
    ms: f64,
    result: Result<VoOutput, fsw::vo::VoError>,
}

/// Runs one frame as the flight does: `start`, then `step` with the flight quantum until done.
fn run_frame(
    vo: &mut VisualOdometry<FEATURES>,
    frame: &StereoFrame,
    quantum: u32,
) -> (f64, Result<VoOutput, fsw::vo::VoError>) {
    let t = Instant::now();
    let result = match vo.start(frame, None) {
        Err(e) => Err(e),
        Ok(()) => loop {
            if let Progress::Finished(r) = vo.step(frame, quantum) {
                break r;
            }
        },
    };
    (t.elapsed().as_secs_f64() * 1e3, result)
}

/// One more pass, one work item per `step`: host time (ms) and item count per [`WorkKind`],
/// summed over the updates (the first frame of the pass excluded).
fn profile_pass(
    vo: &mut VisualOdometry<FEATURES>,
    pairs: &[(Vec<u8>, Vec<u8>)],
    t_us: &mut u64,
    sequence: &mut u32,
) -> [(f64, u64); WorkKind::COUNT] {
    let mut sums = [(0.0, 0u64); WorkKind::COUNT];
    vo.reset();
    for (k, (left, right)) in pairs.iter().enumerate() {
        *t_us += 1_000_000;
        *sequence = sequence.wrapping_add(1);
        let frame = StereoFrame {
            left,
            right,
            capture_t_us: *t_us,
            sequence: *sequence,
        };
        if vo.start(&frame, None).is_err() {
            continue;
        }
        while let Some(kind) = vo.next_work() {
            let t = Instant::now();
            // Quantum 1: exactly one item per call.
            let done = matches!(vo.step(&frame, 1), Progress::Finished(_));
            let ms = t.elapsed().as_secs_f64() * 1e3;
            if k > 0 {
                if let Some(slot) = sums.get_mut(kind as usize) {
                    slot.0 += ms;
                    slot.1 += 1;
                }
            }
            if done {
                break;
            }
        }
    }
    sums
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    // Nearest rank.
    let rank = ((p / 100.0) * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

/// The command line: the folder of the pairs and the options.
struct Args {
    dir: PathBuf,
    passes: usize,
    warmup: usize,
    json: bool,
    profile: bool,
}

fn parse_args() -> Result<Args> {
    let mut args = std::env::args().skip(1);
    let mut dir: Option<PathBuf> = None;
    let (mut passes, mut warmup, mut json, mut profile) = (5usize, 1usize, false, false);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--passes" => passes = args.next().context("--passes N")?.parse()?,
            "--warmup" => warmup = args.next().context("--warmup N")?.parse()?,
            "--json" => json = true,
            "--profile" => profile = true,
            _ if dir.is_none() => dir = Some(PathBuf::from(a)),
            _ => bail!("unexpected argument {a}"),
        }
    }
    let dir = dir.context("usage: vo_speed DIR [--passes P] [--warmup W] [--json]")?;
    Ok(Args {
        dir,
        passes,
        warmup,
        json,
        profile,
    })
}

/// A stereo pair: the left and the right image.
type Pair = (Vec<u8>, Vec<u8>);

/// The pair names of `DIR/pairs.txt` and their images.
fn load_pairs(dir: &Path) -> Result<(Vec<String>, Vec<Pair>)> {
    let names: Vec<String> = std::fs::read_to_string(dir.join("pairs.txt"))
        .context("reading pairs.txt (export with tools/vo_speed.py)")?
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .map(String::from)
        .collect();
    if names.len() < 2 {
        bail!("need at least two pairs");
    }
    let mut pairs = Vec::new();
    for n in &names {
        let left = read_pgm(&dir.join(format!("{n}_left.pgm")))?;
        let right = read_pgm(&dir.join(format!("{n}_right.pgm")))?;
        pairs.push((left, right));
    }
    Ok((names, pairs))
}

/// The timed passes (after the warm-up passes): every update, and the first frames' times.
#[allow(clippy::too_many_arguments)]
fn timed_passes(
    vo: &mut VisualOdometry<FEATURES>,
    names: &[String],
    pairs: &[(Vec<u8>, Vec<u8>)],
    quantum: u32,
    (warmup, passes): (usize, usize),
    t_us: &mut u64,
    sequence: &mut u32,
) -> (Vec<Update>, Vec<f64>) {
    let mut updates = Vec::new();
    let mut keyframe_ms = Vec::new();
    for pass in 0..warmup + passes {
        vo.reset();
        for (k, (left, right)) in pairs.iter().enumerate() {
            *t_us += 1_000_000;
            *sequence = sequence.wrapping_add(1);
            let frame = StereoFrame {
                left,
                right,
                capture_t_us: *t_us,
                sequence: *sequence,
            };
            let (ms, result) = run_frame(vo, &frame, quantum);
            if pass < warmup {
                continue;
            }
            if k == 0 {
                keyframe_ms.push(ms);
            } else {
                updates.push(Update {
                    pass: pass - warmup,
                    pair: names[k].clone(),
                    ms,
                    result,
                });
            }
        }
    }

    (updates, keyframe_ms)
}

/// One line per update (a JSON object with `json`).
fn print_updates(updates: &[Update], json: bool) {
    for u in updates {
        let q = u.result.map(|o| o.quality).unwrap_or_default();
        let (ok, error) = match &u.result {
            Ok(o) if o.pose.is_some() => (true, String::new()),
            Ok(_) => (false, "NoPose".to_string()),
            Err(e) => (false, format!("{e:?}")),
        };
        let turned_deg = u
            .result
            .ok()
            .and_then(|o| o.pose)
            .map(|p| p.rot_0_1.angle().to_degrees())
            .unwrap_or(f64::NAN);
        let moved_mm = u
            .result
            .ok()
            .and_then(|o| o.pose)
            .map(|p| p.trans_0_1_m.norm() * 1e3)
            .unwrap_or(f64::NAN);
        if json {
            println!(
                "{}",
                serde_json::json!({
                    "pass": u.pass, "pair": u.pair, "ms": u.ms, "ok": ok, "error": error,
                    "features": q.features, "stereo_matches": q.stereo_matches,
                    "tracked": q.tracked, "inliers": q.inliers, "work_items": q.work_items,
                    "translation_mm": if moved_mm.is_finite() { moved_mm } else { -1.0 },
                    "rotation_deg": if turned_deg.is_finite() { turned_deg } else { -1.0 },
                })
            );
        } else {
            println!(
                "pass {} pair {:>4}: {:7.2} ms  features {:3} stereo {:3} tracked {:3} inliers {:3} \
                 items {:4}  {}",
                u.pass,
                u.pair,
                u.ms,
                q.features,
                q.stereo_matches,
                q.tracked,
                q.inliers,
                q.work_items,
                if ok {
                    format!("ok, |t| {moved_mm:.1} mm, angle {turned_deg:.3} deg")
                } else {
                    error
                }
            );
        }
    }
}

/// The summary of the timed updates (on stderr with `json`).
fn print_summary(
    updates: &[Update],
    keyframe_ms: &mut [f64],
    pairs: usize,
    quantum: u32,
    passes: usize,
    json: bool,
) {
    let mut ms: Vec<f64> = updates.iter().map(|u| u.ms).collect();
    ms.sort_by(f64::total_cmp);
    keyframe_ms.sort_by(f64::total_cmp);
    let successes = updates
        .iter()
        .filter(|u| matches!(u.result, Ok(o) if o.pose.is_some()))
        .count();
    let summary = format!(
        "flight VO ({FEATURES} features, quantum {quantum}): {} updates over {passes} passes of {} pairs: \
         median {:.2} ms, p90 {:.2} ms, min {:.2} ms, max {:.2} ms; first frame (keyframe) median {:.2} ms; \
         {successes} with a motion",
        ms.len(),
        pairs,
        percentile(&ms, 50.0),
        percentile(&ms, 90.0),
        ms.first().copied().unwrap_or(f64::NAN),
        ms.last().copied().unwrap_or(f64::NAN),
        percentile(keyframe_ms, 50.0),
    );
    if json {
        eprintln!("{summary}");
    } else {
        println!("{summary}");
    }
}

/// The profile pass's host time per work kind.
fn print_profile(sums: &[(f64, u64)], pairs: usize, json: bool) {
    let updates = (pairs - 1) as f64;
    if json {
        let kinds: serde_json::Map<String, serde_json::Value> = WorkKind::ALL
            .iter()
            .zip(sums.iter())
            .map(|(k, (ms, n))| {
                (
                    format!("{k:?}"),
                    serde_json::json!({"ms_per_update": ms / updates, "items_per_update": *n as f64 / updates}),
                )
            })
            .collect();
        println!("{}", serde_json::json!({ "profile": kinds }));
    } else {
        println!("host time per update by work kind (one item per step):");
        for (k, (ms, n)) in WorkKind::ALL.iter().zip(sums.iter()) {
            println!(
                "  {:10} {:7.3} ms  {:6.1} items",
                format!("{k:?}"),
                ms / updates,
                *n as f64 / updates
            );
        }
    }
}

fn main() -> Result<()> {
    let Args {
        dir,
        passes,
        warmup,
        json,
        profile,
    } = parse_args()?;
    let (names, pairs) = load_pairs(&dir)?;
    let calibration = read_calibration(&dir.join("calibration.txt"))?;
    let flight = FswConfig::rocky8([0.0; 3], 0.0);
    let config: VoConfig = flight.nav.vo.pipeline;
    let quantum = flight.exec.background_quantum;
    // On the heap like the flight's static slot (no 90 KB temporary on the stack).
    let mut vo = Box::new(VisualOdometry::<FEATURES>::EMPTY);
    vo.init(config, &calibration)
        .map_err(|e| anyhow::anyhow!("VO refused the configuration or calibration: {e:?}"))?;

    let mut t_us = 0u64;
    let mut sequence = 0u32;
    let (updates, mut keyframe_ms) = timed_passes(
        &mut vo,
        &names,
        &pairs,
        quantum,
        (warmup, passes),
        &mut t_us,
        &mut sequence,
    );
    print_updates(&updates, json);
    print_summary(
        &updates,
        &mut keyframe_ms,
        pairs.len(),
        quantum,
        passes,
        json,
    );
    if profile {
        let sums = profile_pass(&mut vo, &pairs, &mut t_us, &mut sequence);
        print_profile(&sums, pairs.len(), json);
    }
    Ok(())
}

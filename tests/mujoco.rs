//! Recordings pegs did not make: MuJoCo simulates and renders a scene (the Panda from the bundled
//! URDF as MuJoCo reads it, driven by MuJoCo's own inverse kinematics; free bodies; its own
//! rasteriser), `rosbags` writes the rosbag2 bag, and pegs replays it from a configuration that
//! names only the objects, the table friction and the robot (`tests/mujoco/generate.py`).
//!
//! The recorder runs in the venv that `tests/run_all.sh` makes (`tests/mujoco/setup_venv.sh`),
//! named by `PEGS_MUJOCO_PYTHON`. Seeds here were never used for tuning (tuning used 0 to 4).

use std::path::{Path, PathBuf};
use std::process::Command;

fn python() -> PathBuf {
    match std::env::var_os("PEGS_MUJOCO_PYTHON") {
        Some(p) => PathBuf::from(p),
        None => panic!(
            "PEGS_MUJOCO_PYTHON is not set: run tests/run_all.sh, or make the venv with \
             `bash tests/mujoco/setup_venv.sh VENV` and set PEGS_MUJOCO_PYTHON=VENV/bin/python"
        ),
    }
}

fn run(command: &mut Command) -> String {
    let o = command.output().unwrap();
    assert!(
        o.status.success(),
        "{command:?} failed: {}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// Record scene `kind` of `seed` with MuJoCo at 320x180, in the recording shape drawn for the
/// seed or `shape`, with extra generator arguments; its folder.
fn record(kind: &str, seed: u32, shape: Option<&str>, extra: &[&str]) -> PathBuf {
    record_as("pegs", kind, seed, shape, extra)
}

/// As `record`, into a folder of its own for the variant `tag`.
fn record_as(tag: &str, kind: &str, seed: u32, shape: Option<&str>, extra: &[&str]) -> PathBuf {
    let out = std::env::temp_dir().join(format!("pegs-mujoco-{}/{tag}", std::process::id()));
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/mujoco/generate.py");
    let seed = seed.to_string();
    let mut args = vec![script.to_str().unwrap(), "--kind", kind, "--seed", &seed];
    args.extend(["--out", out.to_str().unwrap()]);
    if let Some(shape) = shape {
        args.extend(["--shape", shape]);
    }
    args.extend_from_slice(extra);
    run(Command::new(python()).args(&args));
    out.join(format!("{kind}_{seed}"))
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// `pegs replay` of a recorded folder with its configuration; metrics.json.
fn replay(folder: &Path, extra: &[&str]) -> serde_json::Value {
    let out = folder.join("out");
    let bag = folder.join("bag");
    let config = folder.join("config.yaml");
    let mut args = vec![
        "replay",
        bag.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    run(Command::new(env!("CARGO_BIN_EXE_pegs")).args(&args));
    json(&out.join("metrics.json"))
}

/// The object's true centre at each recorded frame, m.
fn truth_centres(folder: &Path, object: &str) -> Vec<[f64; 3]> {
    let text = std::fs::read_to_string(folder.join("ground_truth.csv")).unwrap();
    text.lines()
        .skip(1)
        .filter(|l| l.split(',').nth(1) == Some(object))
        .map(|l| {
            let f: Vec<f64> = l
                .split(',')
                .skip(2)
                .take(3)
                .map(|x| x.parse().unwrap())
                .collect();
            [f[0], f[1], f[2]]
        })
        .collect()
}

/// How far the object's true centre moved over the recording, m.
fn truth_travel(folder: &Path, object: &str) -> f64 {
    let points = truth_centres(folder, object);
    let (a, b) = (points[0], points[points.len() - 1]);
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn error_mm(metrics: &serde_json::Value, object: &str, stat: &str) -> f64 {
    metrics["tracking_error"][object][stat]
        .as_f64()
        .unwrap_or_else(|| panic!("no {stat} tracking error of {object}: {metrics}"))
}

/// An object at rest in another engine's recording: the world built from its first RGB-D frames
/// (16UC1 millimetres, as a RealSense records depth) and masks stays on it (no drift from shading
/// pegs's renderer does not model).
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn an_object_at_rest_in_another_engines_recording_stays_tracked() {
    let folder = record("control_still", 11, None, &["--depth", "16UC1"]);
    let m = replay(&folder, &[]);
    let (mean, last) = (
        error_mm(&m, "obj1", "mean_mm"),
        error_mm(&m, "obj1", "final_mm"),
    );
    println!("still: mean {mean:.2} mm, final {last:.2} mm");
    assert!(truth_travel(&folder, "obj1") < 0.002, "the object rests");
    let sunk = &json(&folder.join("truth.json"))["robot_sunk"];
    assert_eq!(sunk, &serde_json::json!({}), "the robot touches nothing");
    let warnings = m["warnings"].as_array().unwrap();
    assert!(
        warnings.is_empty(),
        "every camera's depth used: {warnings:?}"
    );
    assert!(mean < 2.0 && last < 3.0, "mean {mean} mm, final {last} mm");
}

/// An object dropped onto the table (MuJoCo holds it 5-13 cm up at the first frame and lets
/// go, the robot parked): built where the cameras see it, not put down on the table, it falls
/// with pegs's gravity and is followed down and at rest. When initialisation put every object on
/// the table, the drops of seeds 3700-3703 were tracked 95-132 mm off on average, off by the
/// drop's height from the first tick to the last.
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_dropped_object_is_built_in_the_air_where_it_is_seen_and_followed_down() {
    let folder = record_as("drop", "restitution", 41, None, &[]);
    let m = replay(&folder, &[]);
    let heights: Vec<f64> = truth_centres(&folder, "obj1")
        .iter()
        .map(|p| p[2])
        .collect();
    let fall = heights[0] - heights[heights.len() - 1];
    let above = m["init"]["objects"]["obj1"]["in_the_air_m"]
        .as_f64()
        .unwrap_or_else(|| panic!("not built in the air: {}", m["init"]));
    let (mean, p95) = (
        error_mm(&m, "obj1", "mean_mm"),
        error_mm(&m, "obj1", "p95_mm"),
    );
    println!(
        "dropped {:.1} cm, built {:.1} cm above the table; mean {mean:.2} mm, p95 {p95:.2} mm, \
         events {}",
        fall * 100.0,
        above * 100.0,
        m["track_events"]
    );
    assert!(fall > 0.05, "the object fell {fall} m");
    // Its bottom from the lowest of its mask's edge: within a pixel (here 2-3 mm) of the truth.
    // From the lowest interior depth point it was built 3 mm high.
    assert!(
        (above - fall).abs() < 0.0025,
        "built {above} m up, fell {fall} m"
    );
    assert!(mean < 5.0 && p95 < 10.0, "mean {mean} mm, p95 {p95} mm");
}

/// The generator's truth is physics: MuJoCo 4.0 lost every contact of restitution_3904's
/// cylinder after 1.5 s at rest (found only once it touches the plane), and it fell 11 mm into the
/// table and was thrown 7 cm up. Its contacts found a tenth of a millimetre early
/// (`simulate.CYLINDER_WATCH`), it stays where it landed, within that tenth.
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_cylinder_at_rest_in_the_generators_recording_stays_on_the_table() {
    let folder = record_as("cylinder", "restitution", 3904, None, &[]);
    let truth = json(&folder.join("truth.json"));
    assert_eq!(truth["objects"][0]["shape"], "cylinder", "{truth}");
    // 30 frames a second: from 0.5 s, after the bounces.
    let heights: Vec<f64> = (truth_centres(&folder, "obj1").iter().skip(15))
        .map(|p| p[2])
        .collect();
    let rest = heights[heights.len() - 1];
    let (low, high) =
        (heights.iter()).fold((f64::MAX, f64::MIN), |(lo, hi), z| (lo.min(*z), hi.max(*z)));
    assert!(
        rest - low < 2e-4 && high - rest < 2e-4,
        "rests at {rest} m, between {low} and {high} after 0.5 s"
    );
}

/// An object the robot pushes in another engine's recording: the robot moved by the recorded
/// joint states, the object by pegs's physics and the visual forces, compared with where MuJoCo
/// put it. Visual forces make the tracking better than the physics alone.
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn an_object_pushed_in_another_engines_recording_is_tracked_through_the_push() {
    let folder = record("control_pushed", 12, None, &[]);
    let travel = truth_travel(&folder, "obj1");
    let m = replay(&folder, &["--compare"]);
    let mean = error_mm(&m, "obj1", "mean_mm");
    let physics = m["comparison"]["obj1"]["physics_only_mean_mm"]
        .as_f64()
        .unwrap();
    println!(
        "pushed {:.0} mm: mean {mean:.2} mm, physics only {physics:.2} mm",
        travel * 1e3
    );
    assert!(travel > 0.03, "the robot pushes the object: {travel} m");
    // MuJoCo's soft contacts let the rod into what it pushes: a steady push, a millimetre or two.
    let sunk = &json(&folder.join("truth.json"))["robot_sunk"]["obj1"];
    let deepest = sunk["deepest_mm"].as_f64().unwrap_or(f64::NAN);
    assert!(
        deepest > 0.0 && deepest < 5.0,
        "the rod sinks {deepest} mm into the pushed object"
    );
    // Today's bar (the README's third-party table has every case); issue 25 asks for 5 mm.
    assert!(mean < 15.0, "mean {mean} mm");
    assert!(mean < physics, "visual forces help: {mean} vs {physics} mm");
}

/// MuJoCo's contacts are soft: a push needs the rod inside its object to move it. Recorded with
/// stiff contacts (`generate.py --stiff-contacts`), the same push keeps the rod within a
/// millimetre of the object's surface, less than half as deep, and still moves it.
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn stiff_contacts_keep_the_rod_out_of_the_object_it_pushes() {
    let deepest = |folder: &Path| {
        let truth = json(&folder.join("truth.json"));
        truth["robot_sunk"]["obj1"]["deepest_mm"]
            .as_f64()
            .unwrap_or_else(|| panic!("the robot never touched obj1: {truth}"))
    };
    let soft = record_as("soft", "control_pushed", 12, None, &[]);
    let stiff = record_as("stiff", "control_pushed", 12, None, &["--stiff-contacts"]);
    let (soft_mm, stiff_mm) = (deepest(&soft), deepest(&stiff));
    println!("rod inside the pushed box: soft {soft_mm:.2} mm, stiff {stiff_mm:.2} mm");
    assert!(stiff_mm < 1.0, "stiff: {stiff_mm} mm");
    assert!(
        stiff_mm < 0.5 * soft_mm,
        "stiff {stiff_mm} mm, soft {soft_mm} mm"
    );
    let travel = truth_travel(&stiff, "obj1");
    assert!(travel > 0.03, "the stiff push moves the box: {travel} m");
}

/// The bag a RealSense + Franka rig records, written by rosbags in both storages: realsense2_camera's
/// topics with JPEG colour on `.../image_raw/compressed`, 16UC1 millimetre aligned depth, no
/// masks, wall-clock epoch stamps and the drivers' tf chain (world -> link -> colour frame ->
/// optical). With a configuration that names only the cameras, the objects and the robot, pegs
/// finds the cameras, resolves the chain, initialises without masks and tracks the pushed object
/// as well as from the same scene in pegs's own layout; `pegs diagnose` runs on it and, on this
/// control, names nothing.
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_realsense_rig_bag_is_tracked_as_well_as_pegs_own_layout() {
    let (kind, seed) = ("control_pushed", 12);
    let own = error_mm(
        &replay(&record(kind, seed, None, &[]), &[]),
        "obj1",
        "mean_mm",
    );
    let epoch = "1763900000.25";
    for storage in ["mcap", "sqlite3"] {
        let args = [
            "--layout",
            "realsense",
            "--storage",
            storage,
            "--stamp0",
            epoch,
        ];
        let folder = record_as(storage, kind, seed, None, &args);
        let bag = folder.join("bag");
        let has = |ext: &str| {
            std::fs::read_dir(&bag)
                .unwrap()
                .any(|f| f.unwrap().path().extension().is_some_and(|e| e == ext))
        };
        assert!(has(if storage == "mcap" { "mcap" } else { "db3" }));
        let config = folder.join("config.yaml");
        let info = run(Command::new(env!("CARGO_BIN_EXE_pegs")).args([
            "bag",
            "info",
            bag.to_str().unwrap(),
            "--config",
            config.to_str().unwrap(),
            "--json",
        ]));
        let info: serde_json::Value = serde_json::from_str(&info).unwrap();
        assert_eq!(info["storage"], storage);
        assert_eq!(info["usable_cameras"].as_array().unwrap().len(), 3);
        assert_eq!(info["cameras"][0]["tf_chain"].as_array().unwrap().len(), 4);
        assert_eq!(info["cameras"][0]["depth"], "16UC1");
        assert_eq!(info["urdf_joints_matched"].as_array().unwrap().len(), 7);
        let m = replay(&folder, &[]);
        let mean = error_mm(&m, "obj1", "mean_mm");
        println!("{storage}: mean {mean:.2} mm (pegs's layout {own:.2} mm)");
        assert_eq!(m["cameras"].as_array().unwrap().len(), 3, "{m}");
        assert_eq!(m["rejected_images"], 0, "{m}");
        assert_eq!(
            m["init"]["labels_from_clusters"], true,
            "no masks: clusters"
        );
        assert!(
            mean < (own * 1.25).max(own + 2.0),
            "{storage}: {mean:.2} mm against {own:.2} mm from pegs's layout"
        );
        let out = folder.join("diagnosis");
        let args = [
            "diagnose",
            bag.to_str().unwrap(),
            "--config",
            config.to_str().unwrap(),
        ];
        run(Command::new(env!("CARGO_BIN_EXE_pegs"))
            .args(args)
            .args(["--out", out.to_str().unwrap()]));
        let report = json(&out.join("report.json"));
        assert_eq!(report["object"], "obj1");
        assert_eq!(
            report["effect"], "none",
            "a control names nothing: {report}"
        );
    }
}

/// The push's time span in a recording's hidden truth (the first push's start, the last's end).
fn push_span(folder: &Path) -> (f64, f64) {
    let truth = json(&folder.join("truth.json"));
    let pushes = truth["pushes"].as_array().unwrap();
    let t0 = pushes[0]["t0"].as_f64().unwrap();
    let t1 = pushes[pushes.len() - 1]["t1"].as_f64().unwrap();
    (t0, t1)
}

/// Open-loop predictions from tracked states move the robot as it was recorded, so a push
/// continues in them: on a control (nothing concealed) the object predicted 0.2 s and 1 s ahead
/// from a state in the middle of the push lands within a few mm of where tracking found it.
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn predictions_during_a_push_follow_the_recorded_robot() {
    let folder = record("control_pushed", 13, Some("long_push"), &[]);
    let config = pegs::config::Config::load(&folder.join("config.yaml")).unwrap();
    let opts = pegs::replay::ReplayOptions {
        progress: false,
        capture: true,
        ..Default::default()
    };
    let bag = folder.join("bag");
    let metrics = pegs::replay::run(&bag, &config, &folder.join("traced"), opts).unwrap();
    let trace = metrics.trace.unwrap();
    let object = trace.base.shape_id("obj1").unwrap();
    let (t0, t1) = push_span(&folder);
    let dt = trace.dt();
    // States from 0.3 s into the push until 1 s before it ends, every 0.1 s.
    let starts: Vec<usize> = (0..trace.states.len())
        .filter(|&k| {
            let t = trace.states[k].time;
            t > t0 + 0.3 && t < t1 - 1.0 && k % 3 == 0
        })
        .collect();
    assert!(starts.len() >= 5, "{} states during the push", starts.len());
    let median_mm = |trace: &pegs::trace::Trace, horizon_s: f64| {
        let horizon = (horizon_s / dt).round() as usize;
        let p = trace
            .predict(&trace.physics, object, &starts, horizon)
            .unwrap();
        let mut e: Vec<f32> = p.iter().map(|p| p.error * 1e3).collect();
        e.sort_by(f32::total_cmp);
        e[e.len() / 2]
    };
    let (short, long) = (median_mm(&trace, 0.2), median_mm(&trace, 1.0));
    // The same predictions with the robot frozen where each state found it.
    let frozen = pegs::trace::Trace {
        robot: None,
        ..trace.clone()
    };
    let (short_frozen, long_frozen) = (median_mm(&frozen, 0.2), median_mm(&frozen, 1.0));
    println!(
        "push {t0:.1}-{t1:.1} s: median prediction error 0.2 s {short:.2} mm, 1 s {long:.2} mm; \
         robot frozen {short_frozen:.2} / {long_frozen:.2} mm"
    );
    // With the robot driven as recorded the push goes on in the prediction; frozen, the object
    // stops where the state found it. (A few mm at 1 s is the goal: how an off-centre push turns
    // the object differs between the engines' contact and friction models.)
    assert!(short < 3.0, "0.2 s predictions miss by {short} mm");
    assert!(long < 15.0, "1 s predictions miss by {long} mm");
    assert!(
        short < 0.75 * short_frozen && long < 0.67 * long_frozen,
        "a frozen robot misses the push: {short_frozen} / {long_frozen} vs {short} / {long} mm"
    );
}

/// Issue 25's model errors, recorded by MuJoCo: a hand the model does not have pushes the object;
/// the table is several times more slippery than configured, so the struck object slides on; an
/// unmodelled cord pulls the object back when the robot lets go. After each, the tracked object
/// is where MuJoCo put it, within 10 mm half a second after the last push and from then on
/// (before the pose pull and re-localisation: 47, 71 and 10 mm). Seed 40 was never used for
/// tuning.
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn objects_moved_by_what_the_model_lacks_are_tracked_within_10_mm_half_a_second_later() {
    for kind in ["hand", "slippery", "tether"] {
        let folder = record(kind, 40, Some("push_then_rest"), &[]);
        let truth = json(&folder.join("truth.json"));
        let pushes = match truth["pushes"].as_array().unwrap() {
            p if p.is_empty() => truth["hand"].as_array().unwrap().clone(),
            p => p.clone(),
        };
        let end = pushes.last().unwrap()["t1"].as_f64().unwrap();
        let m = replay(&folder, &[]);
        let text = std::fs::read_to_string(folder.join("out/tracking_error.csv")).unwrap();
        let after: Vec<f64> = text
            .lines()
            .skip(1)
            .filter_map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                let t: f64 = f[0].parse().ok()?;
                (t >= end + 0.5).then(|| f[2].parse().ok())?
            })
            .collect();
        let worst = after.iter().copied().fold(0.0, f64::max);
        let mean = error_mm(&m, "obj1", "mean_mm");
        let travel = truth_travel(&folder, "obj1");
        println!(
            "{kind}: moved {:.0} mm; mean {mean:.1} mm, at most {worst:.1} mm from 0.5 s after \
             the push; events {}",
            travel * 1e3,
            m["track_events"]
        );
        assert!(travel > 0.03, "{kind}: the object moved {travel} m");
        assert!(after.len() > 30, "{kind}: {} ticks after", after.len());
        assert!(worst < 10.0, "{kind}: {worst} mm after the push");
        assert!(mean < 8.0, "{kind}: mean {mean} mm");
    }
}

/// `folder`'s configuration with `correct` settings added (YAML flow mapping body), written
/// beside it as `config_TAG.yaml`; its path.
fn config_with(folder: &Path, tag: &str, correct: &str) -> PathBuf {
    let text = std::fs::read_to_string(folder.join("config.yaml")).unwrap();
    let head = "  ros__parameters:\n";
    assert!(text.contains(head) && !text.contains("\n    correct:"));
    let path = folder.join(format!("config_{tag}.yaml"));
    let added = format!("{head}    correct: {{{correct}}}\n");
    std::fs::write(&path, text.replacen(head, &added, 1)).unwrap();
    path
}

/// `folder` replayed with `correct` settings added (`config_with`) into `out_TAG`: its metrics
/// and the folder written.
fn replay_with(folder: &Path, tag: &str, correct: &str) -> (serde_json::Value, PathBuf) {
    let config = config_with(folder, tag, correct);
    let out = folder.join(format!("out_{tag}"));
    run(Command::new(env!("CARGO_BIN_EXE_pegs")).args([
        "replay",
        folder.join("bag").to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]));
    (json(&out.join("metrics.json")), out)
}

/// `replay_with`: `object`'s mean and p95 tracking error (mm).
fn replayed_with(folder: &Path, tag: &str, correct: &str, object: &str) -> (f64, f64) {
    let (m, _) = replay_with(folder, tag, correct);
    (
        error_mm(&m, object, "mean_mm"),
        error_mm(&m, object, "p95_mm"),
    )
}

#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_nudge_follows_an_unmodelled_hand_closer_than_the_pull_alone() {
    // The hand is a body the model lacks: the pull's force must first outgrow the model's
    // friction, so the tracked object lags each push and then overshoots. A nudge moves the
    // tracked state towards where the search finds it. Three seeds none of the tuning sets used,
    // recorded as they were when the nudge was tuned (`--plan-from-start`): the nudge cuts the
    // p95 summed over them from 40.8 to 29.3 mm (the mean 15.8 to 11.9). As the generator lays
    // pushes out now, 44.7 to 38.6 (20.2 to 14.1); with the pull's damping at 25, 36.9 to 34.9.
    // Both sides without the follow damping, as tuned: with it (the default) the pull alone
    // lags less and the nudge cuts the p95 only from 37.7 to 33.1 mm, its mean up from 12.8 to
    // 14.6. The nudge is on by default; the pull's side turns it off.
    let (mut p95_pull, mut p95_nudge, mut mean_pull, mut mean_nudge) = (0.0, 0.0, 0.0, 0.0);
    for seed in [41, 42, 43] {
        let folder = record_as("nudge", "hand", seed, None, &["--plan-from-start"]);
        let mut errors = Vec::new();
        for (tag, correct) in [
            ("pull", "pose_nudge: 0.0, pose_follow_damping: 0.0"),
            (
                "nudge",
                "pose_nudge: 0.5, pose_nudge_velocity: 0.5, pose_nudge_beyond: 0.006, \
                 pose_follow_damping: 0.0",
            ),
        ] {
            errors.push(replayed_with(&folder, tag, correct, "obj1"));
        }
        println!(
            "hand_{seed}: pull alone mean {:.1} p95 {:.1} mm; nudged mean {:.1} p95 {:.1} mm",
            errors[0].0, errors[0].1, errors[1].0, errors[1].1
        );
        mean_pull += errors[0].0;
        p95_pull += errors[0].1;
        mean_nudge += errors[1].0;
        p95_nudge += errors[1].1;
    }
    assert!(
        p95_nudge < 0.85 * p95_pull,
        "p95 summed over the seeds: nudged {p95_nudge:.1} against {p95_pull:.1} mm"
    );
    assert!(
        mean_nudge < mean_pull + 1.0,
        "mean summed over the seeds: nudged {mean_nudge:.1} against {mean_pull:.1} mm"
    );
}

/// After a collision the model plays out wrong, the model holds the struck box against the box
/// that struck it, turned a quarter turn from where the images have it: MuJoCo's heavy5_3000 (the
/// struck box five times lighter than configured, 60 x 54 mm, so its colours hardly tell the
/// turn). Colour alone agreed with it 0.67 and up and it was never searched for: 19 mm mean, no
/// event. Its depth tells: the agreement that tells a lost track reads it too
/// (`correct::agreement`), falls under 0.6 a few ticks after the strike, and the box is found in
/// the images and moved there, with an event that says so (a 67 deg turn at 0.97 s: 2.1 mm mean,
/// 1.2 final). That is replayed with no nudge in contact (`pose_nudge_contact_beyond: 0`), the
/// default until the nudge in contact was switched on; with it (the default, 10 mm) the box is
/// nudged there before it is lost (1.8 mm mean, 1.4 final, no event).
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn an_object_turned_where_only_the_depth_tells_is_found_where_the_images_have_it() {
    let folder = record_as("contact", "heavy5", 3000, None, &[]);
    let (m, _) = replay_with(
        &folder,
        "no_contact_nudge",
        "pose_nudge_contact_beyond: 0.0",
    );
    let (mean, final_mm) = (
        error_mm(&m, "obj2", "mean_mm"),
        error_mm(&m, "obj2", "final_mm"),
    );
    let events = m["track_events"].as_array().cloned().unwrap_or_default();
    println!(
        "struck box, no nudge in contact: {mean:.1} mm mean, {final_mm:.1} final; events {events:?}"
    );
    let turned = events.iter().any(|e| {
        e["object"] == "obj2"
            && e["event"] == "relocated"
            && e["turn_deg"].as_f64().is_some_and(|t| t.abs() > 30.0)
    });
    assert!(turned, "the box was not found turned: {events:?}");
    assert!(
        mean < 5.0 && final_mm < 5.0,
        "{mean:.1} mm mean, {final_mm:.1} final"
    );
    let m = replay(&folder, &[]);
    let (mean, p95) = (
        error_mm(&m, "obj2", "mean_mm"),
        error_mm(&m, "obj2", "p95_mm"),
    );
    println!("as configured (nudged in contact): {mean:.1} mm mean (p95 {p95:.1})");
    assert!(
        mean < 5.0 && p95 < 10.0,
        "nudged in contact: {mean:.1} mm mean, p95 {p95:.1}"
    );
}

/// The tilt (rad) of the last pose of `object` in a pose table (t, object, x, y, z, qx, qy, qz,
/// qw): the angle between its body's z axis and the world's.
fn final_tilt(path: &Path, object: &str) -> f64 {
    let text = std::fs::read_to_string(path).unwrap();
    let last = text
        .lines()
        .rfind(|l| l.split(',').nth(1) == Some(object))
        .unwrap_or_else(|| panic!("no {object} in {}", path.display()));
    let q: Vec<f64> = last
        .split(',')
        .skip(5)
        .map(|x| x.parse().unwrap())
        .collect();
    (1.0 - 2.0 * (q[0] * q[0] + q[1] * q[1]))
        .clamp(-1.0, 1.0)
        .acos()
}

/// A T-block on a cord the model lacks, pushed twice, each push planned from where it stood at
/// the start (`--plan-from-start`): the second brings the rod down onto it at 1.96 s, as an arm
/// model that is off would. MuJoCo's kinematic rod passes into it and the images show it flat.
/// With no nudge in contact (`pose_nudge_contact_beyond: 0`, the default until the nudge in
/// contact was switched on) the model throws it about and by 2.17 s has it on its side (93 deg).
/// The search for it used to turn it only about the vertical from where it was, so it was found
/// on its side and lost: it left the modelled table (366 mm mean). Found standing as it started,
/// it is tracked to the end (3.9 mm mean, 8.1 p95, 0 deg final tilt, when the nudge in contact
/// came). As configured, nudged towards where the images have it while the rod is in it, the
/// model never tips it (3.8 mm mean, 9.0 p95). Seed 1400 was recorded after this was built. (The guard was tether 1301, the seed
/// this was found on; built without phantom cells (`rgbd::without_phantoms`), the model no
/// longer tips that one over.)
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn an_object_the_model_tips_over_is_found_standing_where_the_cameras_see_it_stand() {
    let folder = record_as("tipped", "tether", 1400, None, &["--plan-from-start"]);
    let second = &json(&folder.join("truth.json"))["pushes"][1];
    assert!(
        second["inside"].as_array().is_some_and(|o| !o.is_empty()),
        "the second push no longer comes down into the T-block: {second}"
    );
    let truth_tilt = final_tilt(&folder.join("ground_truth.csv"), "obj1").to_degrees();
    assert!(
        truth_tilt < 5.0,
        "MuJoCo's T-block ends tilted {truth_tilt} deg"
    );
    let (m, out) = replay_with(
        &folder,
        "no_contact_nudge",
        "pose_nudge_contact_beyond: 0.0",
    );
    let (mean, p95) = (
        error_mm(&m, "obj1", "mean_mm"),
        error_mm(&m, "obj1", "p95_mm"),
    );
    let tilt = final_tilt(&out.join("objects.csv"), "obj1").to_degrees();
    let events = m["track_events"].as_array().cloned().unwrap_or_default();
    let stood_up = events.iter().any(|e| {
        e["event"] == "relocated" && e["turn_deg"].as_f64().is_some_and(|turn| turn > 45.0)
    });
    println!(
        "tether_1400, no nudge in contact: mean {mean:.1} p95 {p95:.1} mm; final tilt {tilt:.1} \
         deg (truth {truth_tilt:.1}); events {events:?}"
    );
    assert!(stood_up, "no relocation turned it back: {events:?}");
    assert!(tilt < 10.0, "tracked on its side at the end: {tilt} deg");
    assert!(mean < 8.0 && p95 < 15.0, "mean {mean} p95 {p95} mm");
    let m = replay(&folder, &[]);
    let (mean, p95) = (
        error_mm(&m, "obj1", "mean_mm"),
        error_mm(&m, "obj1", "p95_mm"),
    );
    let tilt = final_tilt(&folder.join("out/objects.csv"), "obj1").to_degrees();
    println!("tether_1400 as configured: mean {mean:.1} p95 {p95:.1} mm; final tilt {tilt:.1} deg");
    assert!(tilt < 10.0, "tracked on its side at the end: {tilt} deg");
    assert!(mean < 8.0 && p95 < 15.0, "mean {mean} p95 {p95} mm");
}

/// The generator lays each push out against the object where the pushes before it leave it, and
/// moves a later push with its object until it starts: its rod comes down 3 cm short of where its
/// line meets the object, never onto it. Laid out against where the objects stood at the start
/// (`--plan-from-start`, as the README's tables were recorded), tether 1400's second push and
/// sticky 1400's came down 17 and 19 mm inside their objects, and sticky 1400's first 112 mm
/// short of its bar, never reaching it (the rod placed behind the bar's furthest extent, not where
/// its slanting line meets the bar's side). The engine's own poses judge it: MuJoCo's, when each
/// push starts (`truth.json`).
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_later_push_comes_down_clear_of_the_object_an_earlier_one_moved() {
    for kind in ["tether", "sticky"] {
        let folder = record_as("clear", kind, 1400, None, &[]);
        let truth = json(&folder.join("truth.json"));
        let pushes = truth["pushes"].as_array().cloned().unwrap_or_default();
        println!("{kind}_1400: {pushes:?}");
        assert!(
            pushes.len() >= 2,
            "{kind}_1400 is no longer pushed several times"
        );
        for (k, push) in pushes.iter().enumerate() {
            let inside = push["inside"].as_array().map_or(0, |o| o.len());
            assert_eq!(inside, 0, "push {k} of {kind}_1400 comes down into {push}");
            let gap = push["gap_m"].as_f64().unwrap_or(f64::NAN);
            assert!(
                (0.025..0.035).contains(&gap),
                "push {k} of {kind}_1400 comes down {gap} m from the object along its line"
            );
        }
    }
}

/// The two objects of a collision scene are drawn clear of each other, so nothing moves before
/// the rod does. Placed a fixed distance along the push from the first object's centre, the
/// second started inside the first in 6 of the 72 heavy and heavy5 scenes of the seeds used until
/// then, and MuJoCo threw the two apart at its first step: heavy5_4500's box 10.5 mm, most of it
/// in 0.1 s, before the arm moved, and the tracker, whose model had the two in contact, never
/// caught up with it (6.0 mm mean).
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn objects_drawn_for_a_collision_rest_until_the_push_begins() {
    let folder = record_as("apart", "heavy5", 4500, None, &[]);
    let truth = json(&folder.join("truth.json"));
    let start = truth["pushes"][0]["t0"].as_f64().unwrap_or(f64::NAN);
    let text = std::fs::read_to_string(folder.join("ground_truth.csv")).unwrap();
    for object in ["obj1", "obj2"] {
        let before: Vec<[f64; 2]> = (text.lines().skip(1))
            .map(|l| l.split(',').collect::<Vec<_>>())
            .filter(|f| f[1] == object && f[0].parse::<f64>().unwrap() < start)
            .map(|f| [f[2].parse().unwrap(), f[3].parse().unwrap()])
            .collect();
        let moved = (before.iter())
            .map(|p| (p[0] - before[0][0]).hypot(p[1] - before[0][1]))
            .fold(0.0, f64::max);
        println!(
            "{object}: {:.2} mm before the push at {start:.2} s",
            moved * 1e3
        );
        assert!(
            before.len() > 10,
            "{object}: {} frames before the push",
            before.len()
        );
        assert!(
            moved < 5e-4,
            "{object} moved {moved} m before the push began"
        );
    }
}

/// What a recording can show of its concealed effect (`counterfactual.py`, `shown` in
/// truth.json): MuJoCo replays each 1 s window from its state at the window's start without the
/// effect. Replayed without an effect it does not have, a control's every window ends where the
/// recording's does (the replay is the engine's own, to the step), while a drag of 0.6-1.6 N s/m
/// on a struck object moves the end of every window it slides in. On drag_3100 (three strikes)
/// it shows in 7 of the 8 windows the robot does not touch (up to 97 mm), and on drag_3101 (one
/// strike) in 1 of 2: there a diagnosis that fits free motion has nothing to name it from.
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_concealed_effect_shows_in_windows_that_end_elsewhere_without_it_and_a_control_in_none() {
    let shown = |kind: &str, seed: u32| {
        let folder = record_as("shown", kind, seed, None, &[]);
        json(&folder.join("truth.json"))["shown"]["obj1"].clone()
    };
    let control = shown("control_pushed", 3100);
    println!("control_pushed_3100: {control}");
    let windows = control["pushed_windows"].as_u64().unwrap_or(0);
    assert!(
        windows > 30,
        "the control's push moves it in {windows} windows"
    );
    for key in ["free_max_mm", "pushed_max_mm"] {
        let most = control[key].as_f64().unwrap_or(f64::NAN);
        assert!(
            most < 0.5,
            "replayed as recorded, a window ends {most} mm off"
        );
    }
    let drag = shown("drag", 3100);
    println!("drag_3100: {drag}");
    let (free, windows) = (drag["free_shown"].as_u64(), drag["free_windows"].as_u64());
    assert!(
        free.zip(windows).is_some_and(|(s, w)| s >= 6 && s <= w),
        "the drag shows in {free:?} of {windows:?} free windows"
    );
    assert!(drag["free_max_mm"].as_f64().is_some_and(|m| m > 20.0));
    let once = shown("drag", 3101);
    println!("drag_3101: {once}");
    assert!(once["free_shown"].as_u64().is_some_and(|s| s < 6));
}

/// A cord (MuJoCo's tether_3200: 40 N/m, three pushes) snaps the box back 10-25 cm each time
/// the rod lets go, faster than the tracker follows: it is relocated three times. With windows
/// across a relocation left out, 3 windows were left and the verdict was "not enough evidence";
/// judged from where the images had the box at each window's start and end, the cord is named a
/// spring within 25 % of its stiffness (34.4 N/m when written).
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_cord_that_snaps_an_object_back_faster_than_the_tracker_follows_is_named() {
    let folder = record_as("snap", "tether", 3200, None, &[]);
    let truth = json(&folder.join("truth.json"));
    let out = folder.join("diagnosis");
    run(Command::new(env!("CARGO_BIN_EXE_pegs")).args([
        "diagnose",
        folder.join("bag").to_str().unwrap(),
        "--config",
        folder.join("config.yaml").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]));
    let report = json(&out.join("report.json"));
    let obj = &report["objects"][0];
    println!(
        "{}",
        serde_json::to_string_pretty(&obj["parameters"]).unwrap_or_default()
    );
    let jumps = obj["relocated"].as_array().map_or(0, |r| r.len());
    assert!(
        jumps >= 1,
        "no relocation: this no longer tests windows across one"
    );
    assert_eq!(obj["effect"], "spring", "{}", obj["verdict"]);
    let stiffness = obj["parameters"][0]["value"].as_f64().unwrap_or(f64::NAN);
    let k = truth["parameter"].as_f64().unwrap_or(f64::NAN);
    assert!(
        (stiffness - k).abs() <= 0.25 * k,
        "{stiffness:.1} N/m against {k:.1}"
    );
}

/// The world built from the first RGB-D frames holds only what the cameras saw. At MuJoCo's
/// first frame of control_pushed 1300 the robot hovers beside a T-block, so no camera sees the
/// table along one side of its stem; carving keeps what no camera sees past, and the stem was
/// built 15 mm too wide there (41 mm from its centre line against 26.7). The rod then grazes that
/// side by 6 mm: MuJoCo moves the T-block 4 mm, pegs's physics alone moved it 22 mm (14.5 mm mean
/// error, 18.2 final). Without the phantom cells (`rgbd::without_phantoms`) it follows MuJoCo's
/// push within 3 mm (2.3 mean, 2.7 final) with no visual forces. The seed is the one this was
/// found on, kept as a regression guard, recorded as it was then (`--plan-from-start`).
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn a_rod_grazing_an_object_moves_it_as_far_as_another_engine_does() {
    let folder = record_as(
        "grazed",
        "control_pushed",
        1300,
        None,
        &["--plan-from-start"],
    );
    let m = replay(&folder, &["--no-visual-forces"]);
    let (mean, last) = (
        error_mm(&m, "obj1", "mean_mm"),
        error_mm(&m, "obj1", "final_mm"),
    );
    let built = &m["init"]["rgbd_objects"]["obj1"];
    println!("control_pushed_1300, physics only: mean {mean:.1} final {last:.1} mm; {built}");
    let removed = built["phantom_cells"].as_u64().unwrap();
    assert!(removed > 0, "no phantom cell was removed: {built}");
    let travel = truth_travel(&folder, "obj1");
    assert!(
        (0.002..0.01).contains(&travel),
        "the rod grazes it: it moves {travel} m"
    );
    assert!(mean < 5.0 && last < 5.0, "mean {mean} final {last} mm");
}

/// Per tick of `folder`'s replay of `object`: the tracking error (mm) and whether the tracker had
/// it lost (`out/tracking_error.csv`, `out/health.csv`, one row per tick each).
fn error_and_lost(folder: &Path, object: &str) -> Vec<(f64, bool)> {
    let rows = |file: &str, column: usize| -> Vec<String> {
        let text = std::fs::read_to_string(folder.join("out").join(file)).unwrap();
        text.lines()
            .skip(1)
            .filter(|l| l.split(',').nth(1) == Some(object))
            .map(|l| l.split(',').nth(column).unwrap_or_default().to_string())
            .collect()
    };
    let (error, lost) = (rows("tracking_error.csv", 2), rows("health.csv", 3));
    assert_eq!(error.len(), lost.len(), "one row per tick in both");
    error
        .iter()
        .zip(&lost)
        .map(|(e, l)| (e.parse().unwrap(), l == "1"))
        .collect()
}

/// An object the model holds back while it slides on, out of the cameras' views (slippery_1902:
/// one camera still half sees where the model has it at the edge of its view, each camera
/// measuring one tick in three) or beyond the modelled table (slippery_1602: the floor there,
/// compared with the black of an empty render, looked like the orange bar) is never off
/// silently: within every half second the tracker spends 30 mm or more off, it says the object
/// is lost. Both were held 90-96 mm off for over 2 s, saying nothing, before. Since the backdrop
/// (`correct::backdrop`, the next test) slippery_1602 is followed past the edge and never 30 mm
/// off; slippery_1902 still is, and is reported.
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn an_object_that_slides_where_the_model_cannot_follow_is_reported_lost() {
    let mut lost_runs = 0;
    for seed in [1602, 1902] {
        let folder = record_as("slid", "slippery", seed, None, &[]);
        let travel = truth_travel(&folder, "obj1");
        let m = replay(&folder, &[]);
        let ticks = error_and_lost(&folder, "obj1");
        let events = &m["track_events"];
        println!(
            "slippery_{seed}: slid {:.0} mm; events {events}",
            travel * 1e3
        );
        assert!(travel > 0.25, "slippery_{seed} slid only {travel} m");
        let mut off = 0;
        for (k, (error, _)) in ticks.iter().enumerate() {
            off = if *error >= 30.0 { off + 1 } else { 0 };
            if off == 15 {
                let run = &ticks[k + 1 - off..=k];
                assert!(
                    run.iter().any(|(_, lost)| *lost),
                    "slippery_{seed}: 30 mm or more off for 0.5 s from tick {}, not lost: {run:?}",
                    k + 1 - off
                );
                lost_runs += 1;
            }
        }
        let said = events
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e["event"] == "lost");
        assert_eq!(said, ticks.iter().any(|(_, l)| *l), "{events}");
    }
    println!("{lost_runs} half-seconds 30 mm or more off, each reported lost");
}

/// An object that slides past the modelled table's edge stays tracked where the cameras saw the
/// floor at the start: slippery_1602's bar slid 54 cm, ending 15 cm past the edge in dimmer
/// light. Compared with its own colour alone there (before `correct::backdrop`) it was left 102
/// mm behind, 47 mm mean; compared with the floor each camera saw there first, 12 mm mean and 23
/// mm at the end.
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn an_object_that_slides_past_the_modelled_table_is_followed_against_the_floor_first_seen() {
    let folder = record_as("slid_past", "slippery", 1602, None, &[]);
    let m = replay(&folder, &[]);
    let error = &m["tracking_error"]["obj1"];
    let (mean, last) = (
        error["mean_mm"].as_f64().unwrap(),
        error["final_mm"].as_f64().unwrap(),
    );
    println!(
        "slippery_1602: mean {mean:.1} mm, final {last:.1} mm; {}",
        m["track_events"]
    );
    assert!(mean < 25.0, "mean {mean} mm");
    assert!(last < 50.0, "final {last} mm");
}

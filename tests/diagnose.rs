//! The diagnosis end to end on concealed physics: each scenario's true world has one effect the
//! images do not show (the control none); `pegs scenario concealed` generates, diagnoses and
//! judges each against its hidden truth, failing unless the right effect is named (nothing for
//! the control), its parameter is within 25 %, it is located, and the held-out 1 s open-loop
//! prediction error at least halves. The reports, plots and model files are checked here too.
//!
//! A diagnosis takes minutes on two cores: the full tier runs the control (nothing may be named)
//! and, through the demo, the drag; `PEGS_CONCEALED=all` (`tests/run_all.sh --all-concealed`)
//! runs every concealed scenario but the drag, as `pegs scenario concealed` does for the README's
//! table (the heavy box alone takes 7 minutes: a mass ratio that shows only in the boxes it
//! strikes), and `PEGS_CONCEALED=concealed_heavy` any list of them.

use std::process::Command;

/// The scenarios of the full tier.
const FULL_TIER: &str = "concealed_control";
/// Every concealed scenario but the drag, which is the demo's story (below).
const ALL: &str = "concealed_control,concealed_tilt,concealed_tether,concealed_patch,concealed_weight,concealed_heavy";

fn scenarios() -> String {
    match std::env::var("PEGS_CONCEALED").as_deref() {
        Ok("all") => ALL.to_string(),
        Ok(list) if !list.is_empty() => list.to_string(),
        _ => FULL_TIER.to_string(),
    }
}

#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn concealed_physics_is_located_named_modelled_and_the_fit_improves() {
    let scenarios = scenarios();
    let out = std::env::temp_dir().join(format!("pegs-diagnose-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let o = Command::new(env!("CARGO_BIN_EXE_pegs"))
        .args([
            "scenario",
            "concealed",
            "--out",
            out.to_str().unwrap(),
            "--width",
            "160",
            "--height",
            "90",
            "--scenarios",
            &scenarios,
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    println!("{stdout}");
    assert!(
        o.status.success(),
        "{}\n{}",
        stdout,
        String::from_utf8_lossy(&o.stderr)
    );
    let verdicts: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("verdicts.json")).unwrap()).unwrap();
    assert_eq!(
        verdicts.as_array().unwrap().len(),
        scenarios.split(',').count()
    );
    for v in verdicts.as_array().unwrap() {
        let name = v["scenario"].as_str().unwrap();
        assert_eq!(v["named"], v["truth"], "{name}");
        let dir = out.join(name).join("diagnosis");
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap())
                .unwrap();
        for field in [
            "mismatch",
            "effect",
            "parameters",
            "explained_fraction",
            "before",
            "after",
        ] {
            assert!(
                report.get(field).is_some(),
                "{name}: report.json lacks {field}"
            );
        }
        for plot in ["box_residual.png", "box_feature.png", "box_paths.png"] {
            let img = image::open(dir.join(plot)).unwrap();
            assert!(img.width() > 300, "{name}: {plot}");
        }
        let model = pegs::config::ModelFile::load(&dir.join("model.yaml")).unwrap();
        if name == "concealed_control" {
            assert!(
                model.effects.is_empty() && report["mismatch"].as_array().unwrap().is_empty(),
                "{name}: {report}"
            );
        } else {
            assert_eq!(model.effects.len(), 1, "{name}");
            // The augmented model corrects less on the held-out part than the current one.
            let (b, a) = (
                report["before"]["open_loop_error_mm"].as_f64().unwrap(),
                report["after"]["open_loop_error_mm"].as_f64().unwrap(),
            );
            assert!(a <= 0.5 * b, "{name}: {b} -> {a}");
        }
        if name == "concealed_heavy" {
            // The struck boxes have no effect of their own; their mismatches are the heavy box's.
            let others: Vec<&serde_json::Value> = report["objects"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|o| o["object"] != "box")
                .collect();
            assert_eq!(others.len(), 2, "{name}");
            assert!(
                others.iter().all(|o| o["effect"] == "none"),
                "{name}: {report}"
            );
            assert!(
                others.iter().any(|o| o["explained_by"]
                    .as_str()
                    .is_some_and(|e| e.contains("mass_error of box"))
                    && !o["mismatch"].as_array().unwrap().is_empty()),
                "{name}: {report}"
            );
        }
    }
}

/// `pegs demo` tells the whole story on the drag scenario: generate, track, diagnose, refit,
/// report, judged against the hidden truth.
#[test]
#[ignore = "slow: full tier (tests/run_all.sh)"]
fn the_demo_finds_the_concealed_drag() {
    let out = std::env::temp_dir().join(format!("pegs-demo-story-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let config = concat!(env!("CARGO_MANIFEST_DIR"), "/config/pegs.yaml");
    let o = Command::new(env!("CARGO_BIN_EXE_pegs"))
        .args([
            "demo",
            "--seconds",
            "0.5",
            "--config",
            config,
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{}\n{}",
        stdout,
        String::from_utf8_lossy(&o.stderr)
    );
    let verdicts: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(out.join("story").join("verdicts.json")).unwrap(),
    )
    .unwrap();
    let v = &verdicts[0];
    assert_eq!(
        (v["scenario"].as_str(), v["named"].as_str()),
        (Some("concealed_drag"), Some("viscous_drag")),
        "{v}"
    );
    assert!(
        v["relative_error"].as_f64().unwrap() <= 0.25
            && v["halved"] == true
            && v["located"] == true,
        "{v}"
    );
    let story = std::fs::read_to_string(out.join("story.md")).unwrap();
    assert!(
        story.contains("viscous_drag") && story.contains("passed"),
        "{story}"
    );
    assert!(
        out.join("story/concealed_drag/diagnosis/model.yaml")
            .exists()
            && out.join("trajectory.csv").exists()
    );
}

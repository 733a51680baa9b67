//! `pegs ablate`: the supplementary's ablations on synthetic scenarios. Each scenario is generated
//! once per image resolution, then replayed with one setting changed at a time (physical priors,
//! number of cameras, resolution, visual-force gain, Gaussian position learning rate, Adam
//! iterations). Writes per group a PNG of tracking error over time and a summary table.
//!
//! Owns only the sweep's bookkeeping; the tracking itself is `replay::run`, unchanged.

use crate::config::Config;
use crate::plot;
use crate::replay::{self, ReplayOptions};
use crate::scenario::generate::{self, GenerateOptions};
use anyhow::{Context, Result, bail};
use glam::Vec3;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Tracking error over time: `(t s, error mm)`.
type Series = Vec<(f64, f32)>;

pub const START: &str = "<!-- ablation-table:start -->";
pub const END: &str = "<!-- ablation-table:end -->";

/// What the sweep varies; the defaults are the supplementary's axes around pegs' defaults.
#[derive(Clone, Debug)]
pub struct SweepOptions {
    pub scenarios: Vec<String>,
    /// Resolution of every run except the resolution group.
    pub base: (u32, u32),
    pub seconds: f64,
    pub resolutions: Vec<(u32, u32)>,
    pub cameras: Vec<usize>,
    pub gains: Vec<f32>,
    pub learning_rates: Vec<f32>,
    pub iterations: Vec<u32>,
}

impl Default for SweepOptions {
    fn default() -> Self {
        Self {
            scenarios: vec!["two_boxes".into(), "pushed_tblock".into()],
            base: (320, 180),
            seconds: 4.5,
            resolutions: vec![(1280, 720), (640, 360), (320, 180), (160, 90)],
            cameras: vec![1, 2, 3],
            gains: vec![500.0, 1000.0, 1500.0, 3000.0, 6000.0],
            learning_rates: vec![0.0005, 0.0015, 0.005, 0.015],
            iterations: vec![1, 2, 5, 10],
        }
    }
}

/// One replay of the sweep: a group (what is varied) and the setting in it.
struct Variant {
    group: &'static str,
    label: String,
    resolution: (u32, u32),
    cameras: Option<usize>,
    config: Config,
}

/// The physical-prior settings the supplementary compares, applied to `base`.
fn prior_variants(base: &Config) -> Vec<(String, Config)> {
    let mut out = vec![("all priors".to_string(), base.clone())];
    let mut c = base.clone();
    c.physics.collisions.enabled = false;
    out.push(("no particle collisions".into(), c));
    let mut c = base.clone();
    c.physics.ground.enabled = false;
    c.physics.gravity = Vec3::ZERO;
    out.push(("no ground, no gravity".into(), c));
    let mut c = base.clone();
    c.physics.gravity = Vec3::ZERO;
    out.push(("no gravity".into(), c));
    out
}

fn variants(opts: &SweepOptions, base: &Config) -> Vec<Variant> {
    let mut v = Vec::new();
    let at_base = |group, label: String, config: Config| Variant {
        group,
        label,
        resolution: opts.base,
        cameras: None,
        config,
    };
    for (label, config) in prior_variants(base) {
        v.push(at_base("priors", label, config));
    }
    for &n in &opts.cameras {
        v.push(Variant {
            group: "cameras",
            label: format!("{n} camera{}", if n == 1 { "" } else { "s" }),
            resolution: opts.base,
            cameras: Some(n),
            config: base.clone(),
        });
    }
    for &(w, h) in &opts.resolutions {
        v.push(Variant {
            group: "resolution",
            label: format!("{w}x{h}"),
            resolution: (w, h),
            cameras: None,
            config: base.clone(),
        });
    }
    for &g in &opts.gains {
        let mut c = base.clone();
        c.correct.gain = g;
        v.push(at_base("gain", format!("gain {g}"), c));
    }
    for &lr in &opts.learning_rates {
        let mut c = base.clone();
        c.correct.lr_mean = lr;
        v.push(at_base("learning_rate", format!("lr {lr}"), c));
    }
    for &n in &opts.iterations {
        let mut c = base.clone();
        c.correct.iterations = n;
        v.push(at_base(
            "adam_iterations",
            format!("{n} iteration{}", if n == 1 { "" } else { "s" }),
            c,
        ));
    }
    v
}

/// One row of the summary.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub scenario: String,
    pub group: String,
    pub variant: String,
    /// Tracking error averaged over the scenario's objects, mm.
    pub mean_mm: f32,
    pub p95_mm: f32,
    pub final_mm: f32,
    pub wall_ms_per_tick: f64,
}

/// Per-tick error averaged over objects: `(t, mm)`.
fn mean_series(m: &replay::Metrics) -> Vec<(f64, f32)> {
    let n = m.error_series.len().max(1) as f32;
    let Some(first) = m.error_series.values().next() else {
        return Vec::new();
    };
    (0..first.len())
        .map(|k| {
            (
                first[k].0,
                m.error_series
                    .values()
                    .map(|s| s.get(k).map_or(0.0, |e| e.1))
                    .sum::<f32>()
                    / n
                    * 1e3,
            )
        })
        .collect()
}

/// Run the sweep into `out`; returns the summary rows (also in `out/summary.md` and `.json`).
pub fn run(opts: &SweepOptions, out: &Path) -> Result<Vec<Row>> {
    if opts.scenarios.is_empty() {
        bail!("no scenario to sweep");
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut rows = Vec::new();
    for name in &opts.scenarios {
        rows.extend(sweep_scenario(opts, name, &out.join(name))?);
    }
    std::fs::write(
        out.join("summary.json"),
        serde_json::to_string_pretty(&rows)?,
    )?;
    std::fs::write(out.join("summary.md"), summary_table(&rows))?;
    Ok(rows)
}

/// Every variant of the sweep on scenario `name` (recordings, runs and plots in `dir`).
fn sweep_scenario(opts: &SweepOptions, name: &str, dir: &Path) -> Result<Vec<Row>> {
    let all = variants(opts, &Config::default());
    let recordings = recordings(opts, name, dir, &all)?;
    let mut rows = Vec::new();
    let mut groups: BTreeMap<&str, Vec<(String, Series)>> = BTreeMap::new();
    // Replay is deterministic: a setting that equals one already run (the defaults appear in
    // every group) reuses its result.
    let mut done: BTreeMap<String, (Series, f64)> = BTreeMap::new();
    for v in &all {
        let (recording, scene_config) = &recordings[&v.resolution];
        let config = Config {
            scene: scene_config.scene.clone(),
            ..v.config.clone()
        };
        let cameras = v
            .cameras
            .filter(|&n| n < crate::scenario::cameras(name, 1, 1).len());
        let key = format!("{:?} {:?} {}", v.resolution, cameras, config.to_yaml()?);
        let (series, wall_ms_per_tick) = match done.get(&key) {
            Some(r) => r.clone(),
            None => {
                let run_dir = dir.join(v.group).join(v.label.replace(' ', "_"));
                eprintln!("{name}: {} / {}", v.group, v.label);
                let options = ReplayOptions {
                    progress: true,
                    max_cameras: cameras,
                    ..Default::default()
                };
                let m = replay::run(recording, &config, &run_dir, options)?;
                let r = (mean_series(&m), m.wall_ms_per_tick);
                done.insert(key, r.clone());
                r
            }
        };
        // Back to metres for the same statistics as replay's metrics.
        let errors: Vec<f32> = series.iter().map(|e| e.1 * 1e-3).collect();
        if errors.is_empty() {
            bail!(
                "{}: no ground truth to measure against",
                recording.display()
            );
        }
        let stats = replay::stats(&errors);
        rows.push(Row {
            scenario: name.to_string(),
            group: v.group.into(),
            variant: v.label.clone(),
            mean_mm: stats.mean_mm,
            p95_mm: stats.p95_mm,
            final_mm: stats.final_mm,
            wall_ms_per_tick,
        });
        groups
            .entry(v.group)
            .or_default()
            .push((v.label.clone(), series));
    }
    for (group, lines) in &groups {
        let title = format!("{name}: {}", group.replace('_', " "));
        plot::error_over_time(&dir.join(format!("{group}.png")), &title, lines)?;
    }
    Ok(rows)
}

/// One recording of scenario `name` per resolution the variants use, with its replay config.
fn recordings(
    opts: &SweepOptions,
    name: &str,
    dir: &Path,
    all: &[Variant],
) -> Result<BTreeMap<(u32, u32), (PathBuf, Config)>> {
    let mut recordings = BTreeMap::new();
    for v in all {
        if recordings.contains_key(&v.resolution) {
            continue;
        }
        let (w, h) = v.resolution;
        let rec_dir = dir.join(format!("recording_{w}x{h}"));
        eprintln!("{name}: generating {w}x{h}");
        let options = GenerateOptions {
            width: w,
            height: h,
            seconds: opts.seconds,
            ..Default::default()
        };
        generate::generate(name, &rec_dir, &options)?;
        let scene = Config::load(&rec_dir.join("config.yaml"))?.scene;
        let config = Config {
            scene,
            ..Config::default()
        };
        recordings.insert(v.resolution, (rec_dir.join("recording"), config));
    }
    Ok(recordings)
}

/// The caption of the summary table in the README.
pub fn caption(opts: &SweepOptions) -> String {
    format!(
        "Tracking error averaged over the objects, {} s per run, the tracker started 1 cm / 5 deg off. Milliseconds per tick are wall time on the machine that ran the sweep, and noisy.",
        opts.seconds
    )
}

/// Markdown: one row per group and setting, one error column per scenario.
pub fn summary_table(rows: &[Row]) -> String {
    let mut scenarios: Vec<&str> = Vec::new();
    let mut settings: Vec<(&str, &str)> = Vec::new();
    for r in rows {
        if !scenarios.contains(&r.scenario.as_str()) {
            scenarios.push(&r.scenario);
        }
        if !settings.contains(&(r.group.as_str(), r.variant.as_str())) {
            settings.push((&r.group, &r.variant));
        }
    }
    let mut out = String::from("| ablation | setting |");
    for s in &scenarios {
        out += &format!(" {s} mean / p95 (mm) | {s} ms per tick |");
    }
    out += "\n| --- | --- |";
    out += &" ---: | ---: |".repeat(scenarios.len());
    out += "\n";
    for (group, variant) in settings {
        out += &format!("| {} | {variant} |", group.replace('_', " "));
        for s in &scenarios {
            match rows
                .iter()
                .find(|r| r.scenario == *s && r.group == group && r.variant == variant)
            {
                Some(r) => {
                    out += &format!(
                        " {:.2} / {:.2} | {:.0} |",
                        r.mean_mm, r.p95_mm, r.wall_ms_per_tick
                    )
                }
                None => out += " - | - |",
            }
        }
        out += "\n";
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sweep_changes_one_setting_at_a_time() {
        let opts = SweepOptions::default();
        let base = Config::default();
        let v = variants(&opts, &base);
        assert_eq!(v.len(), 4 + 3 + 4 + 5 + 4 + 4);
        let priors: Vec<&Variant> = v.iter().filter(|v| v.group == "priors").collect();
        assert!(priors[0].config == base);
        assert!(
            !priors[1].config.physics.collisions.enabled
                && priors[1].config.physics.gravity == base.physics.gravity
        );
        assert!(
            !priors[2].config.physics.ground.enabled
                && priors[2].config.physics.gravity == Vec3::ZERO
        );
        assert!(
            priors[3].config.physics.ground.enabled
                && priors[3].config.physics.gravity == Vec3::ZERO
        );
        let gains: Vec<f32> = v
            .iter()
            .filter(|v| v.group == "gain")
            .map(|v| v.config.correct.gain)
            .collect();
        assert_eq!(gains, opts.gains);
        // Everything outside the resolution group runs at the base resolution, and only the
        // camera group drops cameras.
        assert!(
            v.iter()
                .filter(|v| v.group != "resolution")
                .all(|v| v.resolution == opts.base)
        );
        assert!(
            v.iter()
                .filter(|v| v.cameras.is_some())
                .all(|v| v.group == "cameras")
        );
    }

    #[test]
    fn the_summary_has_a_column_pair_per_scenario_and_a_row_per_setting() {
        let row = |s: &str, g: &str, v: &str, m: f32| Row {
            scenario: s.into(),
            group: g.into(),
            variant: v.into(),
            mean_mm: m,
            p95_mm: 2.0 * m,
            final_mm: m,
            wall_ms_per_tick: 10.0,
        };
        let rows = vec![
            row("a", "gain", "gain 1", 1.0),
            row("b", "gain", "gain 1", 3.0),
            row("a", "gain", "gain 2", 5.0),
        ];
        let t = summary_table(&rows);
        let lines: Vec<&str> = t.lines().collect();
        assert_eq!(lines.len(), 4);
        assert!(lines[2].contains("1.00 / 2.00") && lines[2].contains("3.00 / 6.00"));
        assert!(lines[3].contains("5.00 / 10.00") && lines[3].contains(" - |"));
    }
}

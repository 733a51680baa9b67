//! `pegs replay`: a driver of `Tracker::tick` fed by a recording instead of live topics. Ticks run
//! on the recording's own clock; each tick uses the newest image of every camera stamped no later
//! than the tick, and the robot follows the recorded joint states interpolated in time. What the
//! ticks did is written by observers: `objects.csv`, tracking error against ground truth
//! (`truth`), silhouette IoU and the contact sheet (`silhouette`), `residuals.csv` and, for the
//! diagnosis, the trace. Deterministic: the same recording and configuration give the same
//! outputs.
//!
//! - `recording`: the recording surveyed (cameras by the `node` templates, tf, joint states) and
//!   its first frames read.
//! - `start`: the world at the start (a scenario, or initialised from the first frames).
//! - `info`: `pegs bag info`, what a replay would use from a bag.
//! - `feed`: streams the colour images to `inputs::Inputs` as the clock passes their stamps.

mod feed;
mod info;
mod recording;
pub mod silhouette;
mod start;
mod truth;

pub use info::{BagInfo, info};
pub use truth::stats;

use crate::config::Config;
use crate::init;
use crate::trace::residuals::ResidualLog;
use crate::trace::{self, Trace};
use crate::tracker::{Observer, Tick, Tracker};
use crate::trajectory::TrajectoryWriter;
use anyhow::{Context, Result};
use feed::Feed;
use glam::Vec3;
use recording::Streams;
use serde::Serialize;
use silhouette::Silhouettes;
use std::collections::BTreeMap;
use std::path::Path;
use truth::TruthError;

#[derive(Clone, Copy, Debug)]
pub struct ReplayOptions {
    pub visual_forces: bool,
    /// False: visual forces only (no gravity, ground or collisions), as in the paper's ablation.
    pub physics: bool,
    pub progress: bool,
    /// Use only the first N cameras (sorted by name); all when None.
    pub max_cameras: Option<usize>,
    /// Keep every tracked state in `Metrics::trace` (for open-loop predictions).
    pub capture: bool,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        Self {
            visual_forces: true,
            physics: true,
            progress: true,
            max_cameras: None,
            capture: false,
        }
    }
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct ErrorStats {
    pub mean_mm: f32,
    pub p95_mm: f32,
    pub final_mm: f32,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct Metrics {
    pub recording: String,
    pub mode: String,
    pub ticks: usize,
    pub seconds: f64,
    pub cameras: Vec<String>,
    pub wall_ms_per_tick: f64,
    pub mean_loss: f32,
    pub rejected_images: usize,
    /// Ticks at which a camera's newest image was too old to use, per camera.
    pub stale_camera_ticks: BTreeMap<String, usize>,
    pub rejected_joint_states: usize,
    pub warnings: Vec<String>,
    /// 3-D tracking error per object against `ground_truth.csv` beside the recording, if any.
    pub tracking_error: BTreeMap<String, ErrorStats>,
    /// Per-tick tracking error per object: `(t, metres)`; also written to `tracking_error.csv`.
    #[serde(skip)]
    pub error_series: BTreeMap<String, Vec<(f64, f32)>>,
    /// How the world was initialised from the first frames (when no scenario is configured).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub init: Option<init::InitReport>,
    /// Per object and camera: IoU of the tracked object's rendered silhouette with its colour mask.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub silhouette_iou: BTreeMap<String, BTreeMap<String, silhouette::IouStats>>,
    /// With `--compare`: the same recording replayed physics-only and visual-forces-only.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub comparison: BTreeMap<String, Comparison>,
    /// With `ReplayOptions::capture`: the tracked states, the robot's recorded trajectory and
    /// the residuals, for the diagnosis.
    #[serde(skip)]
    pub trace: Option<Trace>,
    /// Objects lost (their silhouettes stopped agreeing with the images), found again and
    /// relocated (moved to where the images show them), in order (`tracker::health`); also said
    /// in `warnings`.
    pub track_events: Vec<ObjectEvent>,
}

/// A tracked object lost, found again or relocated.
#[derive(Clone, Debug, Serialize)]
pub struct ObjectEvent {
    pub object: String,
    /// Seconds after the replay's start.
    pub at_s: f64,
    #[serde(flatten)]
    pub change: crate::tracker::Change,
    /// The silhouette agreement that decided it.
    pub agreement: f32,
}

/// Mean tracking errors of the ablated runs and this run's error as a fraction of theirs.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Comparison {
    pub physics_only_mean_mm: f32,
    pub visual_forces_only_mean_mm: f32,
    pub ratio_to_physics_only: f32,
    pub ratio_to_visual_forces_only: f32,
}

/// Replay with both priors and visual forces, then physics-only and visual-forces-only (into
/// `out/physics_only` and `out/visual_forces_only`), and record the comparison in `out/metrics.json`.
pub fn run_compare(
    recording: &Path,
    config: &Config,
    out: &Path,
    progress: bool,
) -> Result<Metrics> {
    let mut main = run(
        recording,
        config,
        out,
        ReplayOptions {
            progress,
            ..Default::default()
        },
    )?;
    let physics = run(
        recording,
        config,
        &out.join("physics_only"),
        ReplayOptions {
            visual_forces: false,
            progress,
            ..Default::default()
        },
    )?;
    let visual = run(
        recording,
        config,
        &out.join("visual_forces_only"),
        ReplayOptions {
            physics: false,
            progress,
            ..Default::default()
        },
    )?;
    for (object, e) in &main.tracking_error {
        let p = physics
            .tracking_error
            .get(object)
            .map_or(f32::NAN, |e| e.mean_mm);
        let v = visual
            .tracking_error
            .get(object)
            .map_or(f32::NAN, |e| e.mean_mm);
        main.comparison.insert(
            object.clone(),
            Comparison {
                physics_only_mean_mm: p,
                visual_forces_only_mean_mm: v,
                ratio_to_physics_only: e.mean_mm / p,
                ratio_to_visual_forces_only: e.mean_mm / v,
            },
        );
    }
    std::fs::write(
        out.join("metrics.json"),
        serde_json::to_string_pretty(&main)?,
    )?;
    Ok(main)
}

impl Metrics {
    fn mode(opts: &ReplayOptions) -> &'static str {
        match (opts.physics, opts.visual_forces) {
            (true, true) => "physics + visual forces",
            (true, false) => "physics only",
            (false, true) => "visual forces only",
            (false, false) => "neither (open loop, no physics)",
        }
    }
}

/// Replay `recording` with `config` into `out` (`objects.csv`, `metrics.json`, `residuals.csv`,
/// and with ground truth or colour masks their error tables).
pub fn run(recording: &Path, config: &Config, out: &Path, opts: ReplayOptions) -> Result<Metrics> {
    config.check_files()?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut metrics = Metrics {
        recording: recording.display().to_string(),
        mode: Metrics::mode(&opts).into(),
        ..Default::default()
    };
    let fit = config.scene.table.as_ref().map_or((1, 0.0), |t| {
        (t.fit_frames.max(1) as usize, t.fit_span as f64)
    });
    let streams = Streams::read(
        recording,
        &config.node,
        fit,
        opts.max_cameras,
        &mut metrics.warnings,
    )?;
    metrics.cameras = streams.cameras.iter().map(|c| c.name.clone()).collect();
    let (mut scene, ground) = start::scene(&streams, config, opts.progress, &mut metrics)?;
    if scene.robot.is_some() && streams.joint_states.is_empty() {
        metrics
            .warnings
            .push("no joint states: the robot holds its scenario motion".into());
    }
    let config = replay_config(config, ground, &opts);
    let (t0, t_end) = streams.span;
    let dt = config.physics.dt as f64;
    let ticks = ((t_end - t0) / dt + 1e-6).floor().max(0.0) as usize;
    scene.world.time = t0;
    let mut tracker = Tracker::new(scene, &config, opts.visual_forces)?;
    let mut observers = Observers::new(recording, out, &config, &tracker, &metrics, ticks, opts)?;
    observers.start(&tracker)?;
    let mut feed = Feed::new(&streams, &tracker, &config)?;
    let progress = if opts.progress {
        let style = indicatif::ProgressStyle::with_template(
            "{wide_bar} {pos}/{len} ticks ({per_sec}), {elapsed} elapsed, {eta} left",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
        indicatif::ProgressBar::new(ticks as u64).with_style(style)
    } else {
        indicatif::ProgressBar::hidden()
    };
    let clock = std::time::Instant::now();
    // Each tick's silhouette agreement per object, and whether it is lost (`health.csv`).
    let mut health = String::from("t,object,agreement,lost,found_offset_mm\n");
    for index in 1..=ticks {
        let inputs = feed.tick(t0 + index as f64 * dt, &config, &mut metrics);
        let report = tracker.tick(&inputs)?;
        for e in &report.track_events {
            let object = tracker.world().shapes.name[e.shape as usize].clone();
            let at_s = e.time - t0;
            let line = e.describe(&object, at_s);
            eprintln!("warning: {line}");
            metrics.warnings.push(line);
            metrics.track_events.push(ObjectEvent {
                object,
                at_s,
                change: e.change,
                agreement: e.agreement,
            });
        }
        let world = tracker.world();
        for shape in world.shapes.dynamic_ids() {
            let h = tracker.health();
            let a = report
                .correction
                .as_ref()
                .and_then(|c| c.agreement.get(shape as usize));
            let a = a
                .copied()
                .flatten()
                .map_or(String::new(), |a| format!("{a:.3}"));
            let found = (report.correction.as_ref())
                .and_then(|c| c.found_offset.get(shape as usize).copied().flatten())
                .map_or(String::new(), |d| format!("{:.2}", d * 1e3));
            let name = &world.shapes.name[shape as usize];
            let lost = h.is_lost(shape) as u8;
            health.push_str(&format!(
                "{:.6},{name},{a},{lost},{found}\n",
                report.time - t0
            ));
        }
        let tick = Tick {
            index,
            tracker: &tracker,
            inputs: &inputs,
            report: &report,
        };
        observers.tick(&tick)?;
        progress.inc(1);
    }
    progress.finish_and_clear();
    metrics.wall_ms_per_tick = clock.elapsed().as_secs_f64() * 1e3 / ticks.max(1) as f64;
    metrics.ticks = ticks;
    metrics.seconds = ticks as f64 * dt;
    feed.finish(&mut metrics);
    std::fs::write(out.join("health.csv"), health)?;
    observers.finish(out, &mut metrics)?;
    std::fs::write(
        out.join("metrics.json"),
        serde_json::to_string_pretty(&metrics)?,
    )?;
    metrics.trace = observers
        .trace
        .map(|r| r.finish(observers.residuals.samples));
    Ok(metrics)
}

/// The configuration a replay tracks with: the ground fitted at initialisation, and without
/// physics (`opts.physics` false) no gravity, ground or collisions.
fn replay_config(config: &Config, ground: Option<(Vec3, f32)>, opts: &ReplayOptions) -> Config {
    let mut config = config.clone();
    if let Some((normal, height)) = ground {
        config.physics.ground.normal = normal;
        config.physics.ground.height = height;
    }
    if !opts.physics {
        config.physics.gravity = Vec3::ZERO;
        config.physics.ground.enabled = false;
        config.physics.collisions.enabled = false;
    }
    config
}

/// What watches a replay's ticks.
struct Observers {
    objects: TrajectoryWriter,
    truth: Option<TruthError>,
    silhouettes: Silhouettes,
    residuals: ResidualLog,
    summary: Summary,
    trace: Option<trace::Recorder>,
}

impl Observers {
    #[allow(clippy::too_many_arguments)]
    fn new(
        recording: &Path,
        out: &Path,
        config: &Config,
        tracker: &Tracker,
        metrics: &Metrics,
        ticks: usize,
        opts: ReplayOptions,
    ) -> Result<Self> {
        let registered = metrics
            .init
            .as_ref()
            .map_or(Vec::new(), |i| i.rgbd_objects.keys().cloned().collect());
        let objects_with_masks = match config.scene.scenario {
            None => config.scene.objects.as_slice(),
            Some(_) => &[],
        };
        Ok(Self {
            objects: TrajectoryWriter::create(&out.join("objects.csv"))?,
            truth: TruthError::beside(recording, registered)?,
            silhouettes: Silhouettes::new(
                tracker.world(),
                objects_with_masks,
                metrics.cameras.clone(),
                ticks,
                &config.render,
                config.correct.occluder_threshold,
            ),
            residuals: ResidualLog::default(),
            summary: Summary::default(),
            trace: opts.capture.then(trace::Recorder::default),
        })
    }

    fn all(&mut self) -> Vec<&mut dyn Observer> {
        let mut all: Vec<&mut dyn Observer> = vec![
            &mut self.objects,
            &mut self.silhouettes,
            &mut self.residuals,
            &mut self.summary,
        ];
        all.extend(self.truth.as_mut().map(|o| o as &mut dyn Observer));
        all.extend(self.trace.as_mut().map(|o| o as &mut dyn Observer));
        all
    }

    fn start(&mut self, tracker: &Tracker) -> Result<()> {
        self.all().into_iter().try_for_each(|o| o.start(tracker))
    }

    fn tick(&mut self, tick: &Tick) -> Result<()> {
        self.all().into_iter().try_for_each(|o| o.tick(tick))
    }

    /// Close the files and put what the observers measured into `metrics`.
    fn finish(&mut self, out: &Path, metrics: &mut Metrics) -> Result<()> {
        self.objects.finish()?;
        metrics.mean_loss = self.summary.loss / metrics.ticks.max(1) as f32;
        if let Some(truth) = &self.truth {
            metrics.tracking_error = truth.finish(out)?;
            metrics.error_series = truth.series.clone();
        }
        self.residuals.write_csv(&out.join("residuals.csv"))?;
        metrics.silhouette_iou = self.silhouettes.finish(out)?;
        Ok(())
    }
}

/// The photometric loss summed over the ticks.
#[derive(Default)]
struct Summary {
    loss: f32,
}

impl Observer for Summary {
    fn tick(&mut self, tick: &Tick) -> Result<()> {
        if let Some(c) = &tick.report.correction {
            self.loss += c.loss_before;
        }
        Ok(())
    }
}

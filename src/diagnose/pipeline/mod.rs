//! `pegs diagnose`: locate, name, model, show (see the module docs). One pass per file:
//!
//! - `study`: per object, the windows its open-loop predictions are judged on, every family
//!   fitted on them and cross-validated over folds of them, and the one named;
//! - `refine`: the named effects fitted again on a replay tracked with them, and objects whose
//!   mismatches another object's effect explains;
//! - `show`: the replay with the augmented model, before / after outcomes, plots and the report.

mod refine;
mod show;
mod study;

use super::report::{Report, Verdict};
use crate::config::{Config, ModelFile};
use crate::physics::effects::Effect;
use crate::replay::{self, Metrics, ReplayOptions};
use crate::trace::Trace;
use anyhow::{Context, Result};
use std::path::Path;

#[derive(Clone, Copy, Debug)]
pub struct DiagnoseOptions {
    /// Open-loop prediction horizon, s.
    pub horizon: f64,
    /// The residual regression (`select`) fits on this fraction of the recording (in time) and is
    /// judged on the rest. The families are judged by cross-validation (`study`).
    pub train_fraction: f64,
    /// A family is named only if it removes at least this fraction of the squared open-loop
    /// error on the windows it was fitted on and, cross-validated, on windows it was not.
    pub min_gain: f64,
    /// Seconds at the start while tracking converges onto the start pose; not used.
    pub settle: f64,
    /// Windows where the robot touches the object are fitted and judged too (the predictions move
    /// the robot as recorded). Off by default: on MuJoCo's pushed controls the difference
    /// between two engines' contacts was named as missing physics (a constant force).
    pub robot_contact: bool,
    pub progress: bool,
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self {
            horizon: 1.0,
            train_fraction: 0.7,
            min_gain: 0.3,
            settle: 0.5,
            robot_contact: false,
            progress: true,
        }
    }
}

/// What every object's study shares: the horizon of the open-loop predictions (ticks), the
/// recording's first time, the options and the spans over which the first replay's tracks give
/// the predictions' start velocities (`Trace::velocity_spans`), kept for every later replay.
struct Plan {
    horizon: usize,
    t_first: f64,
    opts: DiagnoseOptions,
    velocity_spans: Option<Vec<usize>>,
}

impl Plan {
    fn new(trace: &Trace, opts: DiagnoseOptions) -> Self {
        Self {
            horizon: (opts.horizon / trace.dt()).round().max(1.0) as usize,
            t_first: trace.states.first().map_or(0.0, |s| s.time),
            opts,
            velocity_spans: Some(trace.velocity_spans()),
        }
    }

    fn say(&self, line: String) {
        if self.opts.progress {
            eprintln!("{line}");
        }
    }
}

/// Replay `recording` with `config` into `out`, keeping the trace.
fn traced_replay(recording: &Path, config: &Config, out: &Path, plan: &Plan) -> Result<Metrics> {
    let opts = ReplayOptions {
        progress: plan.opts.progress,
        capture: true,
        ..Default::default()
    };
    let mut run = replay::run(recording, config, out, opts)?;
    if let (Some(trace), Some(spans)) = (run.trace.as_mut(), &plan.velocity_spans) {
        trace.keep_velocity_spans(spans.clone());
    }
    Ok(run)
}

/// Replay `recording` with `config`, find what physics the model misses and write `out/report.md`,
/// `out/report.json`, `out/model.yaml`, plots and the replays (`out/before`, `out/named`,
/// `out/after`).
pub fn diagnose(
    recording: &Path,
    config: &Config,
    out: &Path,
    opts: DiagnoseOptions,
) -> Result<Report> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    if opts.progress {
        eprintln!("replaying with the current model");
    }
    let quiet = Plan {
        horizon: 1,
        t_first: 0.0,
        opts,
        velocity_spans: None,
    };
    let before = traced_replay(recording, config, &out.join("before"), &quiet)?;
    let trace = before.trace.as_ref().context("replay kept no trace")?;
    let plan = Plan::new(trace, opts);
    // Every object is located first: an effect of one may show in another's motion (a box
    // struck by one heavier than modelled slides further than predicted).
    let objects = study::locate_all(trace, &plan)?;
    let mut studies = Vec::new();
    for object in &objects {
        studies.push(study::study(trace, &plan, object, &objects)?);
    }
    study::one_mass_change(trace, &plan, &mut studies)?;
    let effects = refine::refine_named(recording, config, out, &plan, &mut studies)?;
    let model = ModelFile {
        source: format!("pegs diagnose {}", recording.display()),
        effects,
    };
    let model_path = out.join("model.yaml");
    refine::explain_by_others(trace, &model, &mut studies)?;
    let after = show::replay_after(recording, config, out, &plan, &model)?;
    let terms: Vec<Option<Effect>> = studies
        .iter()
        .map(|s| s.chosen.as_ref().and_then(|f| f.effect_term.clone()))
        .collect();
    let report = show::report(
        out,
        recording,
        &model_path,
        trace,
        &plan,
        &before,
        after.as_ref(),
        studies,
    )?;
    // The model file keeps only the effects the replay with them confirmed.
    let confirmed: Vec<Effect> = report
        .objects
        .iter()
        .zip(terms)
        .filter(|(o, _)| o.verdict == Verdict::Named)
        .filter_map(|(_, term)| term)
        .collect();
    if confirmed.len() < model.effects.len() {
        plan.say(format!(
            "{} named effect(s) not confirmed by the replay with them: left out of {}",
            model.effects.len() - confirmed.len(),
            model_path.display()
        ));
    }
    ModelFile {
        effects: confirmed,
        ..model
    }
    .save(&model_path)?;
    Ok(report)
}

//! Show: replay with the augmented model (`out/after`), the outcomes over every judged window
//! before and after,
//! each object's short-horizon errors (CSV) and plots, and the report (`report.json`,
//! `report.md`).

use super::study::Study;
use super::{Plan, traced_replay};
use crate::config::{Config, ModelFile};
use crate::diagnose::candidates;
use crate::diagnose::plots;
use crate::diagnose::report::{ObjectReport, Outcome, Parameter, Report, Verdict, confirmed};
use crate::diagnose::select::{self, SelectOptions};
use crate::replay::Metrics;
use crate::trace::{Prediction, Sample, Trace};
use anyhow::{Context, Result};
use std::path::Path;

/// The replay with the augmented model, if the model adds anything.
pub fn replay_after(
    recording: &Path,
    config: &Config,
    out: &Path,
    plan: &Plan,
    model: &ModelFile,
) -> Result<Option<Metrics>> {
    if model.effects.is_empty() {
        return Ok(None);
    }
    plan.say(format!(
        "replaying with the augmented model ({} effect(s))",
        model.effects.len()
    ));
    traced_replay(recording, &model.apply(config), &out.join("after"), plan).map(Some)
}

/// Outcomes, plots and the report of every study.
#[allow(clippy::too_many_arguments)]
pub fn report(
    out: &Path,
    recording: &Path,
    model_path: &Path,
    trace: &Trace,
    plan: &Plan,
    before: &Metrics,
    after: Option<&Metrics>,
    studies: Vec<Study>,
) -> Result<Report> {
    let mut objects = Vec::new();
    for study in studies {
        let outcome_before = outcome(&study.base, &study.samples, before, &study.name);
        let (outcome_after, after_windows) = match after {
            Some(run) => {
                let t = run.trace.as_ref().context("replay kept no trace")?;
                let p = t.predict(&t.physics, study.shape, &study.windows, plan.horizon)?;
                let mine: Vec<Sample> = t
                    .samples
                    .iter()
                    .filter(|s| s.object == study.name)
                    .cloned()
                    .collect();
                (outcome(&p, &mine, run, &study.name), p)
            }
            None => (outcome_before.clone(), study.base.clone()),
        };
        let folds = fold_spans(trace, &study, plan.horizon);
        write_object(out, trace, &study, &folds, &after_windows)?;
        let relocated = trace
            .jumps
            .iter()
            .filter(|j| j.shape == study.shape)
            .cloned()
            .collect();
        let velocity = (
            trace.velocity_spans()[study.shape as usize],
            trace.roughness(study.shape).map(|r| (r * 1e3) as f32),
        );
        objects.push(object_report(
            study,
            relocated,
            velocity,
            outcome_before,
            outcome_after,
            folds,
            plan.opts.train_fraction,
        ));
    }
    let report = Report::new(
        recording.display().to_string(),
        model_path.display().to_string(),
        objects,
    );
    let json = serde_json::to_string_pretty(&report)?;
    std::fs::write(out.join("report.json"), json)?;
    std::fs::write(out.join("report.md"), report.markdown())?;
    Ok(report)
}

/// The time span (s) of each fold's windows, from the first window's start to the last one's end.
fn fold_spans(trace: &Trace, study: &Study, horizon: usize) -> Vec<[f64; 2]> {
    let time = |k: usize| trace.states[k.min(trace.states.len() - 1)].time;
    study
        .folds
        .iter()
        .filter(|f| !f.is_empty())
        .map(|f| {
            let (first, last) = (study.windows[f.start], study.windows[f.end - 1]);
            [time(first), time(last + horizon)]
        })
        .collect()
}

/// The object's short-horizon errors (`<object>_short_horizon_errors.csv`) and its plots of the
/// residual over time, the residual against the named effect's feature, and the open-loop paths.
fn write_object(
    out: &Path,
    trace: &Trace,
    study: &Study,
    folds: &[[f64; 2]],
    after_windows: &[Prediction],
) -> Result<()> {
    let mut csv = String::from("t,error_mm\n");
    for (t, e) in &study.located.errors {
        csv += &format!("{t:.4},{:.3}\n", e * 1e3);
    }
    std::fs::write(
        out.join(format!("{}_short_horizon_errors.csv", study.name)),
        csv,
    )?;
    let plot = |kind: &str| out.join(format!("{}_{kind}.png", study.name));
    let fold_starts: Vec<f64> = folds.iter().map(|f| f[0]).collect();
    plots::residual_over_time(
        &plot("residual"),
        &study.samples,
        &study.located,
        &fold_starts,
    )?;
    let family = study.chosen.as_ref().and_then(|f| f.family);
    plots::residual_vs_feature(&plot("feature"), &study.samples, family, &study.setting)?;
    plots::paths(
        &plot("paths"),
        trace,
        study.shape,
        folds.first().map_or(0.0, |f| f[0]),
        &study.base,
        after_windows,
    )
}

/// Metrics of one replay: open-loop error of `predictions`, mean corrective force of the
/// object's samples, tracking error if there is ground truth.
fn outcome(predictions: &[Prediction], samples: &[Sample], run: &Metrics, object: &str) -> Outcome {
    let tracking: Option<&Vec<(f64, f32)>> = run.error_series.get(object);
    Outcome {
        open_loop_error_mm: predictions.iter().map(|p| p.error).sum::<f32>()
            / predictions.len().max(1) as f32
            * 1e3,
        open_loop_windows: predictions.len(),
        corrective_effort_n: samples.iter().map(|s| s.force.length()).sum::<f32>()
            / samples.len().max(1) as f32,
        tracking_error_mm: tracking
            .filter(|e| !e.is_empty())
            .map(|e| e.iter().map(|x| x.1).sum::<f32>() / e.len() as f32 * 1e3),
    }
}

fn object_report(
    mut study: Study,
    relocated: Vec<crate::trace::Jump>,
    (velocity_span, track_roughness_mm): (usize, Option<f32>),
    before: Outcome,
    after: Outcome,
    folds: Vec<[f64; 2]>,
    train_fraction: f64,
) -> ObjectReport {
    // A named effect that the replay with it does not bear out is reported as such, not named.
    let not_confirmed = if study.chosen.is_some() && !confirmed(&before, &after) {
        study.explained.clear();
        study.chosen.take()
    } else {
        None
    };
    let mut parameters = Vec::new();
    let mut residual_explained_fraction = None;
    if let Some(f) = &study.chosen {
        parameters.push(Parameter {
            name: f.parameter.clone(),
            value: f.value,
            low: Some(f.low),
            high: Some(f.high),
            unit: f.unit.clone(),
        });
        if let Some(family) = f.family {
            let extras = family.report(&study.setting, f.value, f.effect_term.as_ref());
            parameters.extend(extras.into_iter().map(|(name, value, unit)| Parameter {
                name: name.into(),
                value,
                low: None,
                high: None,
                unit: unit.into(),
            }));
        }
        if let Some(c) = f
            .family
            .and_then(|family| family.regression())
            .and_then(candidates::Candidate::from_name)
        {
            let single = select::select(
                &study.samples,
                &[c],
                SelectOptions {
                    train_fraction,
                    min_gain: f64::NEG_INFINITY,
                    min_t: 0.0,
                },
            );
            residual_explained_fraction = single.found.first().map(|x| x.explained_fraction);
        }
    }
    let verdict = if not_confirmed.is_some() {
        Verdict::NotConfirmed
    } else {
        Verdict::of(
            study.chosen.is_some(),
            study.explained_by.is_some(),
            super::study::judgeable(&study.folds, &study.pushed),
            study.unlocated.is_some(),
        )
    };
    let named_on = study.refined_from.as_ref().or(study.chosen.as_ref());
    let free_explained_fraction = named_on
        .filter(|_| study.pushed.contains(&true))
        .and_then(|f| super::study::free_gain(f, &study.base, &study.pushed));
    ObjectReport {
        object: study.name,
        verdict,
        locate_threshold_mm: study.located.threshold * 1e3,
        velocity_span,
        track_roughness_mm,
        // Deviations no effect explains are listed apart: they are not missing physics.
        unexplained: study
            .located
            .windows
            .iter()
            .filter(|w| {
                !study
                    .explained
                    .iter()
                    .any(|e| e.t_start < w.t_end && w.t_start < e.t_end)
            })
            .cloned()
            .collect(),
        relocated,
        mismatch: study.explained,
        explained_by: study.explained_by,
        effect: study
            .chosen
            .as_ref()
            .map_or("none".into(), |f| f.effect.clone()),
        parameters,
        // How much the effect explains is judged where it was named, cross-validated.
        explained_fraction: study
            .refined_from
            .as_ref()
            .or(study.chosen.as_ref())
            .filter(|_| study.chosen.is_some())
            .map_or(0.0, |f| f.heldout_gain()),
        named_fit: study.refined_from,
        residual_explained_fraction,
        windows: study.windows.len(),
        pushed_windows: study.pushed.iter().filter(|p| **p).count(),
        free_explained_fraction,
        folds,
        candidates: study.fits,
        regression: study.regression,
        not_confirmed,
        unlocated: study.unlocated,
        before,
        after,
    }
}

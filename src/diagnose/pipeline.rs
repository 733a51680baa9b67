//! `pegs diagnose`: locate, name, model, show (see the module docs).

use super::locate::{self, Located};
use super::refit::{self, Family, Fit, Setting};
use super::report::{ObjectReport, Outcome, Parameter, Report};
use super::select::{self, SelectOptions};
use super::trace::Prediction;
use super::{Sample, candidates, plots, read_residuals};
use crate::config::{Config, ModelFile};
use crate::replay::{self, Metrics, ReplayOptions};
use crate::world::ShapeId;
use anyhow::{Context, Result};
use std::path::Path;

#[derive(Clone, Copy, Debug)]
pub struct DiagnoseOptions {
    /// Open-loop prediction horizon, s.
    pub horizon: f64,
    /// Fraction of the recording (in time) used for fitting; the rest is held out.
    pub train_fraction: f64,
    /// A family is named only if it removes at least this fraction of the squared open-loop
    /// error on both the fitting and the held-out windows.
    pub min_gain: f64,
    /// Seconds at the start while tracking converges onto the start pose; not used.
    pub settle: f64,
    pub progress: bool,
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        Self {
            horizon: 1.0,
            train_fraction: 0.7,
            min_gain: 0.3,
            settle: 0.5,
            progress: true,
        }
    }
}

/// Windows start every this many ticks.
const WINDOW_STRIDE: usize = 4;
/// A window counts only if the object moves (tracked or predicted) at least this far in it, m.
const ACTIVE_MOTION: f32 = 0.005;

/// Replay `recording` with `config`, find what physics the model misses and write `out/report.md`,
/// `out/report.json`, `out/model.yaml`, plots and the replays (`out/before`, `out/after`).
pub fn diagnose(
    recording: &Path,
    config: &Config,
    out: &Path,
    opts: DiagnoseOptions,
) -> Result<Report> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let say = |s: String| {
        if opts.progress {
            eprintln!("{s}");
        }
    };
    say("replaying with the current model".into());
    let before = replay::run(
        recording,
        config,
        &out.join("before"),
        ReplayOptions {
            progress: opts.progress,
            capture: true,
            ..Default::default()
        },
    )?;
    let trace = before.trace.as_ref().context("replay kept no trace")?;
    let samples = read_residuals(&out.join("before").join("residuals.csv"))?;
    let horizon = (opts.horizon / trace.dt()).round().max(1.0) as usize;
    let t_first = trace.states.first().map_or(0.0, |s| s.time);
    let t_last = trace.states.last().map_or(0.0, |s| s.time);
    let cut = t_first + opts.train_fraction * (t_last - t_first);
    let shapes: Vec<ShapeId> = trace.base.shapes.dynamic_ids().collect();
    // Every object is located first: an effect of one may show in another's motion (a box
    // struck by one heavier than modelled slides further than predicted).
    let mut objects: Vec<(ShapeId, String, Vec<Sample>, Located)> = Vec::new();
    for &shape in &shapes {
        let name = trace.base.shapes.name[shape as usize].clone();
        let mine: Vec<Sample> = samples
            .iter()
            .filter(|s| s.object == name)
            .cloned()
            .collect();
        say(format!("{name}: locating mismatches"));
        let located = locate::locate(trace, &trace.physics, shape, &mine, opts.settle)?;
        objects.push((shape, name, mine, located));
    }
    let mut studies: Vec<Study> = Vec::new();
    for (shape, name, mine, located) in objects.iter().cloned() {
        // Fitting windows end before the cut; held-out ones start after it; both only where the
        // object moves.
        let last = trace.states.len().saturating_sub(horizon + 1);
        let all: Vec<usize> = (0..=last)
            .step_by(WINDOW_STRIDE)
            .filter(|&k| trace.states[k].time >= t_first + opts.settle)
            .collect();
        let base = trace.predict(&trace.physics, shape, &all, horizon)?;
        let time = |k: usize| trace.states[k].time;
        // Windows where the robot touches the object are left out: how a push plays out open
        // loop hangs on the recorded robot motion's timing to a few milliseconds, a mismatch of
        // its own that no effect of the object explains (the control scenario's pushes miss by
        // tens of mm with the true physics).
        let pushed: Vec<f64> = mine
            .iter()
            .filter(|s| s.touching_robot)
            .map(|s| s.t)
            .collect();
        let active = |p: &Prediction| {
            let c0 = trace.centroid(shape, p.start);
            let tracked = (p.start..=p.start + horizon)
                .map(|k| trace.centroid(shape, k).distance(c0))
                .fold(0.0, f32::max);
            let predicted = p.path.iter().map(|q| q.distance(c0)).fold(0.0, f32::max);
            let (t0, t1) = (time(p.start), time(p.start + horizon));
            tracked.max(predicted) > ACTIVE_MOTION
                && !pushed.iter().any(|t| *t >= t0 - 1e-9 && *t <= t1 + 1e-9)
        };
        let base_train: Vec<Prediction> = base
            .iter()
            .filter(|p| time(p.start + horizon) <= cut + 1e-9 && active(p))
            .cloned()
            .collect();
        let base_heldout: Vec<Prediction> = base
            .iter()
            .filter(|p| time(p.start) >= cut - 1e-9 && active(p))
            .cloned()
            .collect();
        let train: Vec<usize> = base_train.iter().map(|p| p.start).collect();
        let heldout: Vec<usize> = base_heldout.iter().map(|p| p.start).collect();
        let (force_direction, anchor) = refit::directions(trace, shape, &base_train);
        // A friction patch can only be found where the object slid in the fitting windows.
        let region = refit::footprint(trace, shape, &train, horizon);
        let setting = Setting {
            object: name.clone(),
            shape,
            mass: trace.base.shapes.mass[shape as usize],
            base: trace.physics.clone(),
            force_direction,
            anchor,
            region,
            com_limit: refit::com_limits(trace, shape),
        };
        let mut fits: Vec<Fit> = Vec::new();
        if !train.is_empty() && !heldout.is_empty() {
            for family in refit::ALL {
                say(format!("{name}: fitting {} open loop", family.name()));
                if let Some(f) = refit::fit(
                    trace,
                    &setting,
                    family,
                    &train,
                    &heldout,
                    horizon,
                    &base_train,
                    &base_heldout,
                )? {
                    fits.push(f);
                }
            }
        }
        fits.sort_by(|a, b| b.heldout_gain().total_cmp(&a.heldout_gain()));
        // Named: of the families that pass on both parts, the simplest that the windows cannot
        // tell from the best (one standard error), provided it explains located mismatches, the
        // object's own or another's.
        let mut chosen = None;
        let mut explained = Vec::new();
        for f in parsimonious(
            fits.iter()
                .filter(|f| f.train_gain() >= opts.min_gain && f.heldout_gain() >= opts.min_gain)
                .collect(),
        ) {
            let Some(effect) = f.effect_term.clone() else {
                continue;
            };
            let mut physics = trace.physics.clone();
            physics.effects.push(effect);
            explained = locate::explained(trace, &located, &physics, shape, &mine)?;
            let explains_another = || -> Result<bool> {
                for (other, _, theirs, their_located) in objects
                    .iter()
                    .filter(|o| o.0 != shape && !o.3.windows.is_empty())
                {
                    if !locate::explained(trace, their_located, &physics, *other, theirs)?
                        .is_empty()
                    {
                        return Ok(true);
                    }
                }
                Ok(false)
            };
            if !explained.is_empty() || explains_another()? {
                chosen = Some(f.clone());
                break;
            }
        }
        let regression = select::select(
            &mine,
            &candidates::ALL,
            SelectOptions {
                train_fraction: opts.train_fraction,
                ..Default::default()
            },
        );
        studies.push(Study {
            shape,
            name,
            samples: mine,
            located,
            explained,
            explained_by: None,
            train,
            heldout,
            setting,
            fits,
            chosen,
            refined_from: None,
            regression,
            base_heldout,
        });
    }
    one_mass_change(&mut studies);
    let mut effects: Vec<_> = studies
        .iter()
        .filter_map(|s| s.chosen.as_ref().and_then(|f| f.effect_term.clone()))
        .collect();
    // Model: the named terms' parameters refined on a replay tracked with them. Tracking with a
    // model that lacks the effect lags what the effect does (the visual forces pull the object
    // after it), and a parameter fitted to that lag inherits it; with the effect in the model the
    // tracked motion is closer to the truth.
    if !effects.is_empty() {
        say(format!(
            "replaying with the named effect(s) to refine their parameters ({})",
            effects.len()
        ));
        let named = ModelFile {
            source: String::new(),
            effects: effects.clone(),
        };
        let run = replay::run(
            recording,
            &named.apply(config),
            &out.join("named"),
            ReplayOptions {
                progress: opts.progress,
                capture: true,
                ..Default::default()
            },
        )?;
        let retraced = run.trace.as_ref().context("replay kept no trace")?;
        effects.clear();
        for study in studies.iter_mut() {
            let Some(named) = study.chosen.clone() else {
                continue;
            };
            let Some(family) = named.family else { continue };
            say(format!("{}: refining {}", study.name, family.name()));
            let base_train =
                retraced.predict(&study.setting.base, study.shape, &study.train, horizon)?;
            let base_heldout =
                retraced.predict(&study.setting.base, study.shape, &study.heldout, horizon)?;
            let (direction, anchor) = refit::directions(retraced, study.shape, &base_train);
            let setting = Setting {
                force_direction: direction.or(study.setting.force_direction),
                anchor: anchor.or(study.setting.anchor),
                region: refit::footprint(retraced, study.shape, &study.train, horizon)
                    .or(study.setting.region),
                ..study.setting.clone()
            };
            let refined = refit::fit(
                retraced,
                &setting,
                family,
                &study.train,
                &study.heldout,
                horizon,
                &base_train,
                &base_heldout,
            )?;
            let kept = match refined {
                Some(f) if f.effect_term.is_some() => {
                    study.refined_from = Some(named);
                    f
                }
                _ => named,
            };
            effects.extend(kept.effect_term.clone());
            study.chosen = Some(kept);
        }
    }
    let model = ModelFile {
        source: format!("pegs diagnose {}", recording.display()),
        effects,
    };
    let model_path = out.join("model.yaml");
    model.save(&model_path)?;
    // An object with no effect of its own may still have missed because of another's: a box
    // struck by one heavier than modelled slides further than predicted.
    let named: Vec<String> = studies
        .iter()
        .filter_map(|s| {
            s.chosen
                .as_ref()
                .map(|f| format!("{} of {}", f.effect, s.name))
        })
        .collect();
    for study in studies
        .iter_mut()
        .filter(|s| s.chosen.is_none() && !s.located.windows.is_empty())
    {
        let mut physics = trace.physics.clone();
        physics.effects.extend(
            model
                .effects
                .iter()
                .filter(|e| e.object() != Some(study.name.as_str()))
                .cloned(),
        );
        if physics.effects.is_empty() {
            continue;
        }
        study.explained =
            locate::explained(trace, &study.located, &physics, study.shape, &study.samples)?;
        if !study.explained.is_empty() {
            study.explained_by = Some(named.join(", "));
        }
    }
    // Show: replay again with the augmented model.
    let after = if model.effects.is_empty() {
        None
    } else {
        say(format!(
            "replaying with the augmented model ({} effect(s))",
            model.effects.len()
        ));
        Some(replay::run(
            recording,
            &model.apply(config),
            &out.join("after"),
            ReplayOptions {
                progress: opts.progress,
                capture: true,
                ..Default::default()
            },
        )?)
    };
    let after_samples = match &after {
        Some(_) => read_residuals(&out.join("after").join("residuals.csv"))?,
        None => samples.clone(),
    };
    let mut objects = Vec::new();
    for study in studies {
        let outcome_before = outcome(
            &study.base_heldout,
            &study.samples,
            &before,
            &study.name,
            cut,
        );
        let (outcome_after, after_heldout) = match &after {
            Some(run) => {
                let t = run.trace.as_ref().context("replay kept no trace")?;
                let p = t.predict(&t.physics, study.shape, &study.heldout, horizon)?;
                let mine: Vec<Sample> = after_samples
                    .iter()
                    .filter(|s| s.object == study.name)
                    .cloned()
                    .collect();
                (outcome(&p, &mine, run, &study.name, cut), p)
            }
            None => (outcome_before.clone(), study.base_heldout.clone()),
        };
        let mut csv = String::from("t,error_mm\n");
        for (t, e) in &study.located.errors {
            csv += &format!("{t:.4},{:.3}\n", e * 1e3);
        }
        std::fs::write(
            out.join(format!("{}_short_horizon_errors.csv", study.name)),
            csv,
        )?;
        let plot = |kind: &str| out.join(format!("{}_{kind}.png", study.name));
        plots::residual_over_time(&plot("residual"), &study.samples, &study.located, cut)?;
        plots::residual_vs_feature(
            &plot("feature"),
            &study.samples,
            study.chosen.as_ref().and_then(|f| f.family),
            &study.setting,
        )?;
        plots::paths(
            &plot("paths"),
            trace,
            study.shape,
            cut,
            &study.base_heldout,
            &after_heldout,
        )?;
        objects.push(object_report(
            study,
            outcome_before,
            outcome_after,
            cut,
            opts.train_fraction,
        ));
    }
    let report = Report::new(
        recording.display().to_string(),
        model_path.display().to_string(),
        objects,
    );
    std::fs::write(
        out.join("report.json"),
        serde_json::to_string_pretty(&report)?,
    )?;
    std::fs::write(out.join("report.md"), report.markdown())?;
    Ok(report)
}

/// Masses show only as ratios between objects that collide: a box struck by one heavier than
/// modelled fits a lighter mass of its own as well. Of several objects named a mass change,
/// only the one whose change cuts the held-out error most keeps it.
fn one_mass_change(studies: &mut [Study]) {
    let chosen: Vec<Option<&Fit>> = studies.iter().map(|s| s.chosen.as_ref()).collect();
    let dropped = mass_changes_to_drop(&chosen);
    for i in dropped {
        studies[i].chosen = None;
        studies[i].explained.clear();
    }
}

/// Of the named fits (one per object), the indices of the mass changes to drop: all but the one
/// with the best held-out gain.
fn mass_changes_to_drop(chosen: &[Option<&Fit>]) -> Vec<usize> {
    let mass: Vec<(usize, f64)> = chosen
        .iter()
        .enumerate()
        .filter_map(|(i, f)| {
            f.filter(|f| f.family == Some(Family::MassScale))
                .map(|f| (i, f.heldout_gain()))
        })
        .collect();
    let best = mass.iter().max_by(|a, b| a.1.total_cmp(&b.1)).map(|b| b.0);
    mass.iter()
        .map(|m| m.0)
        .filter(|&i| Some(i) != best)
        .collect()
}

/// `passing` reordered by the one-standard-error rule over all windows (fitting and held-out; a
/// family that fits the first part far worse is no twin of one that fits both): the best fit
/// (lowest mean squared error) and the fits within one standard error of it (paired over
/// windows) come first, simplest first; then the rest, best first.
fn parsimonious(passing: Vec<&Fit>) -> Vec<&Fit> {
    let windows = |f: &Fit| {
        f.train_errors
            .iter()
            .chain(&f.heldout_errors)
            .copied()
            .collect::<Vec<f64>>()
    };
    let total = |f: &Fit| windows(f).iter().sum::<f64>();
    let mut passing = passing;
    passing.sort_by(|a, b| total(a).total_cmp(&total(b)));
    let Some(best) = passing.first().copied() else {
        return passing;
    };
    let close = |f: &Fit| {
        let d: Vec<f64> = windows(f)
            .iter()
            .zip(&windows(best))
            .map(|(a, b)| a - b)
            .collect();
        let n = d.len().max(1) as f64;
        let mean = d.iter().sum::<f64>() / n;
        let se = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt()
            / n.sqrt();
        mean <= se
    };
    let mut order: Vec<(usize, usize, &Fit)> = passing
        .iter()
        .enumerate()
        .map(|(i, f)| {
            (
                if close(f) {
                    f.family.map_or(usize::MAX, |x| x.complexity())
                } else {
                    usize::MAX
                },
                i,
                *f,
            )
        })
        .collect();
    order.sort_by_key(|(complexity, i, _)| (*complexity, *i));
    order.into_iter().map(|(_, _, f)| f).collect()
}

struct Study {
    shape: ShapeId,
    name: String,
    samples: Vec<Sample>,
    located: Located,
    /// The located mismatches the named effect explains (or, for an object with none of its
    /// own, the effects named on other objects).
    explained: Vec<locate::Mismatch>,
    /// For an object with no effect of its own: the other objects' effects that explain its
    /// mismatches.
    explained_by: Option<String>,
    train: Vec<usize>,
    heldout: Vec<usize>,
    setting: Setting,
    fits: Vec<Fit>,
    /// The named family's fit: refined on the replay with the named effects when that worked.
    chosen: Option<Fit>,
    /// The fit that named it, on the first replay (when `chosen` was refined).
    refined_from: Option<Fit>,
    regression: select::Selection,
    base_heldout: Vec<Prediction>,
}

/// Held-out metrics of one replay: open-loop error of `predictions`, mean corrective force of the
/// object's samples after `cut`, tracking error after `cut` if there is ground truth.
fn outcome(
    predictions: &[Prediction],
    samples: &[Sample],
    run: &Metrics,
    object: &str,
    cut: f64,
) -> Outcome {
    let held: Vec<&Sample> = samples.iter().filter(|s| s.t >= cut).collect();
    let tracking: Option<Vec<f32>> = run
        .error_series
        .get(object)
        .map(|s| s.iter().filter(|e| e.0 >= cut).map(|e| e.1).collect());
    Outcome {
        open_loop_error_mm: predictions.iter().map(|p| p.error).sum::<f32>()
            / predictions.len().max(1) as f32
            * 1e3,
        open_loop_windows: predictions.len(),
        corrective_effort_n: held.iter().map(|s| s.force.length()).sum::<f32>()
            / held.len().max(1) as f32,
        tracking_error_mm: tracking
            .filter(|e| !e.is_empty())
            .map(|e| e.iter().sum::<f32>() / e.len() as f32 * 1e3),
    }
}

/// The regression candidate that matches a simulation family, if any.
fn regression_counterpart(family: Family) -> Option<candidates::Candidate> {
    use candidates::Candidate as C;
    match family {
        Family::ViscousDrag => Some(C::ViscousDrag),
        Family::GroundFriction | Family::FrictionPatch => Some(C::GroundFriction),
        Family::ConstantForce => Some(C::ConstantForce),
        Family::Spring => Some(C::Spring),
        Family::MassScale => Some(C::MassError),
        Family::AngularDamping => Some(C::AngularDamping),
        // Impacts are too short for the per-tick force regression.
        Family::Restitution => None,
        Family::CenterOfMass(_) => None,
    }
}

fn object_report(
    study: Study,
    before: Outcome,
    after: Outcome,
    cut: f64,
    train_fraction: f64,
) -> ObjectReport {
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
        let s = &study.setting;
        let fixed = |name: &str, value: f32, unit: &str| Parameter {
            name: name.into(),
            value,
            low: None,
            high: None,
            unit: unit.into(),
        };
        match f.family {
            Some(Family::ConstantForce) => {
                // The fitted direction (refined from the setting's).
                let fitted = match &f.effect_term {
                    Some(crate::physics::Effect::ConstantForce { force, .. }) => {
                        Some(force.normalize_or_zero())
                    }
                    _ => s.force_direction,
                };
                if let Some(d) = fitted {
                    parameters.push(fixed("direction_x", d.x, ""));
                    parameters.push(fixed("direction_y", d.y, ""));
                }
                // The same force from a tilted table: m g sin(angle).
                let ratio = (f.value / (s.mass * 9.81)).clamp(-1.0, 1.0);
                parameters.push(fixed("equivalent_tilt", ratio.asin().to_degrees(), "deg"));
            }
            Some(Family::Spring) => {
                if let Some(a) = s.anchor {
                    parameters.push(fixed("anchor_x", a.x, "m"));
                    parameters.push(fixed("anchor_y", a.y, "m"));
                }
            }
            Some(Family::FrictionPatch) => {
                // The placed patch (see `refit::place_patch`).
                if let Some(crate::physics::Effect::FrictionPatch {
                    center: c,
                    half_size: h,
                    ..
                }) = &f.effect_term
                {
                    for (n, v) in [
                        ("center_x", c.x),
                        ("center_y", c.y),
                        ("half_size_x", h.x),
                        ("half_size_y", h.y),
                    ] {
                        parameters.push(fixed(n, v, "m"));
                    }
                }
            }
            Some(Family::CenterOfMass(axis)) => {
                parameters.push(fixed("body_axis", axis as f32, "0 = x, 1 = y"))
            }
            _ => {}
        }
        if let Some(c) = f.family.and_then(regression_counterpart) {
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
    ObjectReport {
        object: study.name,
        locate_threshold_mm: study.located.threshold * 1e3,
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
        mismatch: study.explained,
        explained_by: study.explained_by,
        effect: study
            .chosen
            .as_ref()
            .map_or("none".into(), |f| f.effect.clone()),
        parameters,
        // How much the effect explains is judged where it was named.
        explained_fraction: study
            .refined_from
            .as_ref()
            .or(study.chosen.as_ref())
            .map_or(0.0, |f| f.heldout_gain()),
        named_fit: study.refined_from,
        residual_explained_fraction,
        heldout_from: cut,
        train_windows: study.train.len(),
        heldout_windows: study.heldout.len(),
        candidates: study.fits,
        regression: study.regression,
        before,
        after,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fit(family: Family, errors: &[f64]) -> Fit {
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        Fit {
            effect: family.name().into(),
            parameter: String::new(),
            unit: String::new(),
            value: 1.0,
            low: 1.0,
            high: 1.0,
            train_before: 1.0,
            train_after: 0.1,
            heldout_before: 1.0,
            heldout_after: mean,
            heldout_errors: errors.to_vec(),
            train_errors: Vec::new(),
            family: Some(family),
            effect_term: None,
        }
    }

    #[test]
    fn of_two_objects_named_a_mass_change_only_the_one_that_explains_more_keeps_it() {
        let heavy = fit(Family::MassScale, &[0.1]);
        let light = fit(Family::MassScale, &[0.5]);
        let drag = fit(Family::ViscousDrag, &[0.05]);
        // Held-out gains 0.9 and 0.5: the lighter-box reading is dropped; other effects stay.
        assert_eq!(
            mass_changes_to_drop(&[Some(&light), None, Some(&heavy), Some(&drag)]),
            vec![0]
        );
        assert!(mass_changes_to_drop(&[Some(&heavy), Some(&drag)]).is_empty());
    }

    #[test]
    fn the_simpler_of_two_indistinguishable_fits_comes_first_and_a_clearly_better_one_stays_first()
    {
        // The spring is slightly better on average but not window by window: the constant force
        // (fewer quantities from the data) is named.
        let spring = fit(Family::Spring, &[0.10, 0.30, 0.20, 0.05, 0.40]);
        let force = fit(Family::ConstantForce, &[0.12, 0.25, 0.24, 0.06, 0.42]);
        let order = parsimonious(vec![&spring, &force]);
        assert_eq!(order[0].family, Some(Family::ConstantForce));
        // Better in every window by a margin: the spring stays.
        let force = fit(Family::ConstantForce, &[0.30, 0.50, 0.40, 0.25, 0.60]);
        let order = parsimonious(vec![&spring, &force]);
        assert_eq!(order[0].family, Some(Family::Spring));
    }
}

//! Per object: where its open-loop predictions fail (`locate`), the windows they are judged on
//! (fitting before the cut, held out after it, only where the object moves and the robot does
//! not touch it), every family fitted on them, and the one named: of the families that pass on
//! both parts, the simplest that the windows cannot tell from the best, provided it explains
//! located mismatches (the object's own or another's).

use super::Plan;
use crate::diagnose::candidates;
use crate::diagnose::locate::{self, Located, Mismatch};
use crate::diagnose::refit::{self, Fit};
use crate::diagnose::select::{self, SelectOptions};
use crate::physics::effects::{FAMILIES, FitSetting};
use crate::trace::{Prediction, Sample, Trace};
use crate::world::ShapeId;
use anyhow::Result;

/// Windows start every this many ticks.
const WINDOW_STRIDE: usize = 4;
/// A window counts only if the object moves (tracked or predicted) at least this far in it, m.
const ACTIVE_MOTION: f32 = 0.005;

/// An object of the trace with its residuals and located mismatches.
#[derive(Clone)]
pub struct Object {
    pub shape: ShapeId,
    pub name: String,
    pub samples: Vec<Sample>,
    pub located: Located,
}

pub struct Study {
    pub shape: ShapeId,
    pub name: String,
    pub samples: Vec<Sample>,
    pub located: Located,
    /// The located mismatches the named effect explains (or, for an object with none of its
    /// own, the effects named on other objects).
    pub explained: Vec<Mismatch>,
    /// For an object with no effect of its own: the other objects' effects that explain its
    /// mismatches.
    pub explained_by: Option<String>,
    pub train: Vec<usize>,
    pub heldout: Vec<usize>,
    pub setting: FitSetting,
    pub fits: Vec<Fit>,
    /// The named family's fit: refined on the replay with the named effects when that worked.
    pub chosen: Option<Fit>,
    /// The fit that named it, on the first replay (when `chosen` was refined).
    pub refined_from: Option<Fit>,
    pub regression: select::Selection,
    pub base_heldout: Vec<Prediction>,
}

/// Every dynamic object of the trace, located.
pub fn locate_all(trace: &Trace, plan: &Plan) -> Result<Vec<Object>> {
    let mut objects = Vec::new();
    for shape in trace.base.shapes.dynamic_ids() {
        let name = trace.base.shapes.name[shape as usize].clone();
        let samples: Vec<Sample> = trace
            .samples
            .iter()
            .filter(|s| s.object == name)
            .cloned()
            .collect();
        plan.say(format!("{name}: locating mismatches"));
        let located = locate::locate(trace, &trace.physics, shape, &samples, plan.opts.settle)?;
        objects.push(Object {
            shape,
            name,
            samples,
            located,
        });
    }
    Ok(objects)
}

/// The base model's predictions of `object` in the fitting and held-out windows.
fn windows(
    trace: &Trace,
    plan: &Plan,
    object: &Object,
) -> Result<(Vec<Prediction>, Vec<Prediction>)> {
    let (shape, horizon) = (object.shape, plan.horizon);
    let last = trace.states.len().saturating_sub(horizon + 1);
    let all: Vec<usize> = (0..=last)
        .step_by(WINDOW_STRIDE)
        .filter(|&k| trace.states[k].time >= plan.t_first + plan.opts.settle)
        // A relocation is something outside the model moving the object: never fitted.
        .filter(|&k| !trace.jumps_between(shape, k, k + horizon))
        .collect();
    let base = trace.predict(&trace.physics, shape, &all, horizon)?;
    let time = |k: usize| trace.states[k].time;
    // Windows where the robot touches the object are left out: how a push plays out open loop
    // hangs on the recorded robot motion's timing to a few milliseconds, a mismatch of its own
    // that no effect of the object explains (the control scenario's pushes miss by tens of mm
    // with the true physics).
    let pushed: Vec<f64> = object
        .samples
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
    let cut = plan.cut;
    let (train, heldout) = base.iter().filter(|p| active(p)).fold(
        (Vec::new(), Vec::new()),
        |(mut train, mut heldout), p| {
            if time(p.start + horizon) <= cut + 1e-9 {
                train.push(p.clone());
            }
            if time(p.start) >= cut - 1e-9 {
                heldout.push(p.clone());
            }
            (train, heldout)
        },
    );
    Ok((train, heldout))
}

/// Fit every family to `object` and name one.
pub fn study(trace: &Trace, plan: &Plan, object: &Object, objects: &[Object]) -> Result<Study> {
    let (shape, name) = (object.shape, &object.name);
    let (base_train, base_heldout) = windows(trace, plan, object)?;
    let train: Vec<usize> = base_train.iter().map(|p| p.start).collect();
    let heldout: Vec<usize> = base_heldout.iter().map(|p| p.start).collect();
    let (force_direction, anchor) = refit::directions(trace, shape, &base_train);
    let setting = FitSetting {
        object: name.clone(),
        shape,
        mass: trace.base.shapes.mass[shape as usize],
        base: trace.physics.clone(),
        force_direction,
        anchor,
        // A friction patch can only be found where the object slid in the fitting windows.
        region: refit::footprint(trace, shape, &train, plan.horizon),
        com_limit: refit::com_limits(trace, shape),
    };
    let mut fits: Vec<Fit> = Vec::new();
    if !train.is_empty() && !heldout.is_empty() {
        for &family in &FAMILIES {
            plan.say(format!("{name}: fitting {} open loop", family.name()));
            let fit = refit::fit(
                trace,
                &setting,
                family,
                &train,
                &heldout,
                plan.horizon,
                &base_train,
                &base_heldout,
            )?;
            fits.extend(fit);
        }
    }
    fits.sort_by(|a, b| b.heldout_gain().total_cmp(&a.heldout_gain()));
    let (chosen, explained) = choose(trace, plan, object, objects, &fits)?;
    let options = SelectOptions {
        train_fraction: plan.opts.train_fraction,
        ..Default::default()
    };
    let regression = select::select(&object.samples, &candidates::ALL, options);
    Ok(Study {
        shape,
        name: name.clone(),
        samples: object.samples.clone(),
        located: object.located.clone(),
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
    })
}

/// The named fit and the mismatches it explains: of the fits that pass on both parts (in
/// `parsimonious` order), the first whose effect explains located mismatches of this object or
/// of another.
fn choose(
    trace: &Trace,
    plan: &Plan,
    object: &Object,
    objects: &[Object],
    fits: &[Fit],
) -> Result<(Option<Fit>, Vec<Mismatch>)> {
    let min_gain = plan.opts.min_gain;
    let passing = fits
        .iter()
        .filter(|f| f.train_gain() >= min_gain && f.heldout_gain() >= min_gain)
        .collect();
    let mut explained = Vec::new();
    for f in parsimonious(passing) {
        let Some(effect) = f.effect_term.clone() else {
            continue;
        };
        let mut physics = trace.physics.clone();
        physics.effects.push(effect);
        explained = locate::explained(
            trace,
            &object.located,
            &physics,
            object.shape,
            &object.samples,
        )?;
        let explains_another = || -> Result<bool> {
            let others = objects
                .iter()
                .filter(|o| o.shape != object.shape && !o.located.windows.is_empty());
            for other in others {
                if !locate::explained(trace, &other.located, &physics, other.shape, &other.samples)?
                    .is_empty()
                {
                    return Ok(true);
                }
            }
            Ok(false)
        };
        if !explained.is_empty() || explains_another()? {
            return Ok((Some(f.clone()), explained));
        }
    }
    Ok((None, explained))
}

/// Masses show only as ratios between objects that collide: a box struck by one heavier than
/// modelled fits a lighter mass of its own as well. Of several objects named a mass change,
/// only the one whose change cuts the held-out error most keeps it.
pub fn one_mass_change(studies: &mut [Study]) {
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
            f.filter(|f| f.family.is_some_and(|x| x.ratio_between_objects()))
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::effects::{Family, family};

    fn fit(id: &str, errors: &[f64]) -> Fit {
        let family: &'static dyn Family = family(id).unwrap();
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
        let heavy = fit("mass_error", &[0.1]);
        let light = fit("mass_error", &[0.5]);
        let drag = fit("viscous_drag", &[0.05]);
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
        let spring = fit("spring", &[0.10, 0.30, 0.20, 0.05, 0.40]);
        let force = fit("constant_force", &[0.12, 0.25, 0.24, 0.06, 0.42]);
        let order = parsimonious(vec![&spring, &force]);
        assert_eq!(order[0].family.map(|f| f.id()), Some("constant_force"));
        // Better in every window by a margin: the spring stays.
        let force = fit("constant_force", &[0.30, 0.50, 0.40, 0.25, 0.60]);
        let order = parsimonious(vec![&spring, &force]);
        assert_eq!(order[0].family.map(|f| f.id()), Some("spring"));
    }
}

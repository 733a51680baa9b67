//! Locate: where the model's predictions fail. From every tracked state the physics alone
//! predicts a short horizon ahead; a start whose prediction misses the tracked state by clearly
//! more than the tracking noise is a mismatch. Runs of such starts are the mismatch windows,
//! each with its time span, the table region the object crossed and its contact phase.
//! Once an effect is named, `explained` keeps the mismatches that effect removes: where the
//! missing physics acts, apart from misses no effect explains (such as robot contacts).

use crate::physics::PhysicsConfig;
use crate::trace::Sample;
use crate::trace::{Prediction, Trace};
use crate::world::ShapeId;
use anyhow::Result;
use glam::Vec2;
use serde::Serialize;

/// Short prediction horizon of the locator, s: long enough for a missing effect to show,
/// short enough to pin down when and where it acts.
pub const HORIZON: f64 = 0.2;
/// A mismatch counts as explained where the named effect cuts its miss to this fraction or less.
const EXPLAINED: f32 = 2.0 / 3.0;
/// Errors below this (m) are tracking noise whatever the statistics say.
pub const MIN_ERROR: f32 = 0.003;
/// A window in which the tracked speed rises by more than this (m/s) is one where the object was
/// driven.
pub const SPEED_UP: f32 = 0.03;

#[derive(Clone, Debug, Serialize)]
pub struct Mismatch {
    pub object: String,
    pub t_start: f64,
    pub t_end: f64,
    /// The box of table positions (world x, y; m) the object's centre crossed.
    pub region_min: [f32; 2],
    pub region_max: [f32; 2],
    /// The box of table positions the object's particles covered meanwhile (its footprint).
    pub footprint_min: [f32; 2],
    pub footprint_max: [f32; 2],
    /// Contact phase: "sliding", "pushed by the robot", "touching another object" or "at rest".
    pub phase: String,
    /// Largest short-horizon prediction error in the window, mm.
    pub peak_error_mm: f32,
    /// The tracked object gained speed (by more than `SPEED_UP`) while no modelled body pushed
    /// it: something drove it. Passive effects (friction, drag, damping, mass) only slow an
    /// object down; unexplained, this is an agent the model lacks (an unmodelled push).
    pub sped_up: bool,
}

impl Mismatch {
    pub fn region(&self) -> (Vec2, Vec2) {
        (Vec2::from(self.region_min), Vec2::from(self.region_max))
    }
}

/// The locator's findings for one object.
#[derive(Clone, Debug, Serialize)]
pub struct Located {
    pub windows: Vec<Mismatch>,
    /// Error a start must exceed to count (m), and the per-start errors `(t, m)`.
    pub threshold: f32,
    #[serde(skip)]
    pub errors: Vec<(f64, f32)>,
    /// The predictions behind `errors` (start index and error; no paths).
    #[serde(skip)]
    pub predictions: Vec<Prediction>,
}

/// A start counts as quiet when the tracked object moves less than this over the horizon, m.
const QUIET_MOTION: f32 = 0.002;

/// Tracking noise of short-horizon predictions: the median error from starts where the tracked
/// object stays put (no effect on a moving object shows there), or, if it hardly rests, the lower
/// quartile of all errors. The median of all errors would be the effect itself when it acts for
/// most of the recording (a tilted table keeps the box sliding).
fn noise(errors: &[f32], quiet: &[bool]) -> f32 {
    let quantile = |mut v: Vec<f32>, q: f32| {
        v.sort_by(f32::total_cmp);
        v.get(((v.len() as f32 * q) as usize).min(v.len().saturating_sub(1)))
            .copied()
            .unwrap_or(0.0)
    };
    let resting: Vec<f32> = errors
        .iter()
        .zip(quiet)
        .filter(|(_, q)| **q)
        .map(|(e, _)| *e)
        .collect();
    if resting.len() >= 5 {
        quantile(resting, 0.5)
    } else {
        quantile(errors.to_vec(), 0.25)
    }
}

/// Short-horizon predictions from every other tracked state of `object` with `physics`, and the
/// windows where they fail. `samples` are the object's residual samples (for contact phases);
/// starts in the first `settle` seconds are skipped.
pub fn locate(
    trace: &Trace,
    physics: &PhysicsConfig,
    object: ShapeId,
    samples: &[Sample],
    settle: f64,
) -> Result<Located> {
    let horizon = (HORIZON / trace.dt()).round().max(1.0) as usize;
    let last = trace.states.len().saturating_sub(horizon + 1);
    // Skip the first `settle` seconds: tracking is still pulling the model onto its start pose.
    let t0 = trace.states.first().map_or(0.0, |s| s.time);
    let starts: Vec<usize> = (0..=last)
        .step_by(2)
        .filter(|&k| trace.states[k].time >= t0 + settle)
        // Across a relocation the track jumped where no physics goes (reported apart).
        .filter(|&k| !trace.jumps_between(object, k, k + horizon))
        .collect();
    let mut predictions = trace.predict(physics, object, &starts, horizon)?;
    predictions.iter_mut().for_each(|p| p.path = Vec::new());
    let errors: Vec<(f64, f32)> = predictions
        .iter()
        .map(|p| (trace.states[p.start].time, p.error))
        .collect();
    let quiet: Vec<bool> = predictions
        .iter()
        .map(|p| {
            trace
                .centroid(object, (p.start + horizon).min(trace.states.len() - 1))
                .distance(trace.centroid(object, p.start))
                < QUIET_MOTION
        })
        .collect();
    let values: Vec<f32> = errors.iter().map(|e| e.1).collect();
    // A robust 3 sigma above the noise.
    let threshold = (4.0 * noise(&values, &quiet)).max(MIN_ERROR);
    let windows = runs(
        trace,
        object,
        &predictions,
        |p| p.error > threshold,
        samples,
    );
    Ok(Located {
        windows,
        threshold,
        errors,
        predictions,
    })
}

/// Of the mismatches in `located`, the windows that `physics` (the model with a named effect)
/// explains: starts where the located model missed by more than the threshold and `physics`
/// misses by at most two thirds as much (an effect such as a shifted centre of mass builds up
/// over the horizon, so its short-horizon gain is modest).
pub fn explained(
    trace: &Trace,
    located: &Located,
    physics: &PhysicsConfig,
    object: ShapeId,
    samples: &[Sample],
) -> Result<Vec<Mismatch>> {
    let horizon = (HORIZON / trace.dt()).round().max(1.0) as usize;
    let flagged: Vec<usize> = located
        .predictions
        .iter()
        .filter(|p| p.error > located.threshold)
        .map(|p| p.start)
        .collect();
    let after = trace.predict(physics, object, &flagged, horizon)?;
    let fixed: std::collections::HashMap<usize, f32> =
        after.iter().map(|p| (p.start, p.error)).collect();
    Ok(runs(
        trace,
        object,
        &located.predictions,
        |p| {
            fixed
                .get(&p.start)
                .is_some_and(|e| *e <= EXPLAINED * p.error)
        },
        samples,
    ))
}

/// Windows of at least two consecutive predictions that `flagged` marks.
fn runs(
    trace: &Trace,
    object: ShapeId,
    predictions: &[Prediction],
    flagged: impl Fn(&Prediction) -> bool,
    samples: &[Sample],
) -> Vec<Mismatch> {
    let horizon = (HORIZON / trace.dt()).round().max(1.0) as usize;
    let name = trace.base.shapes.name[object as usize].clone();
    let mut windows = Vec::new();
    let mut run: Vec<&Prediction> = Vec::new();
    for p in predictions.iter().map(Some).chain([None]) {
        match p {
            Some(p) if flagged(p) => run.push(p),
            _ => {
                if run.len() >= 2 {
                    windows.push(window(trace, object, &name, &run, horizon, samples));
                }
                run.clear();
            }
        }
    }
    windows
}

fn window(
    trace: &Trace,
    object: ShapeId,
    name: &str,
    run: &[&Prediction],
    horizon: usize,
    samples: &[Sample],
) -> Mismatch {
    let (first, last) = (run[0].start, run[run.len() - 1].start + horizon);
    let (t_start, t_end) = (
        trace.states[first].time,
        trace.states[last.min(trace.states.len() - 1)].time,
    );
    let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
    let (mut foot_lo, mut foot_hi) = (lo, hi);
    // Where the object was when its prediction started to fail: the first half of each horizon.
    for p in run {
        for k in p.start..=(p.start + horizon / 2).min(trace.states.len() - 1) {
            let c = trace.centroid(object, k).truncate();
            lo = lo.min(c);
            hi = hi.max(c);
            for q in &trace.states[k].position[trace.base.shapes.range(object)] {
                foot_lo = foot_lo.min(q.truncate());
                foot_hi = foot_hi.max(q.truncate());
            }
        }
    }
    let inside: Vec<&Sample> = samples
        .iter()
        .filter(|s| s.t >= t_start - 1e-9 && s.t <= t_end + 1e-9)
        .collect();
    let count = |f: &dyn Fn(&Sample) -> bool| inside.iter().filter(|s| f(s)).count();
    let phases = [
        ("pushed by the robot", count(&|s| s.touching_robot)),
        (
            "touching another object",
            count(&|s| s.touching_object && !s.touching_robot),
        ),
        (
            "sliding",
            count(&|s| {
                !s.touching_robot && !s.touching_object && s.velocity.truncate().length() > 0.01
            }),
        ),
        (
            "at rest",
            count(&|s| {
                !s.touching_robot && !s.touching_object && s.velocity.truncate().length() <= 0.01
            }),
        ),
    ];
    let phase = phases
        .iter()
        .max_by_key(|p| p.1)
        .map_or("at rest", |p| p.0)
        .to_string();
    // Tracked speed (central differences of the centre) from the window's start.
    let n = trace.states.len();
    let speed = |k: usize| {
        let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
        let dt = (trace.states[b].time - trace.states[a].time) as f32;
        if dt > 0.0 {
            (trace.centroid(object, b) - trace.centroid(object, a))
                .truncate()
                .length()
                / dt
        } else {
            0.0
        }
    };
    let gain = (first..=last.min(n - 1)).map(speed).fold(0.0, f32::max) - speed(first);
    // Another object striking it is modelled too: a box set moving by a heavier striker is a
    // collision, not an unmodelled push.
    let sped_up = gain > SPEED_UP && count(&|s| s.touching_robot || s.touching_object) == 0;
    Mismatch {
        object: name.to_string(),
        t_start,
        t_end,
        region_min: lo.to_array(),
        region_max: hi.to_array(),
        footprint_min: foot_lo.to_array(),
        footprint_max: foot_hi.to_array(),
        phase,
        peak_error_mm: run.iter().map(|p| p.error).fold(0.0, f32::max) * 1e3,
        sped_up,
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::math::Pose;
    use crate::world::{WorldBuilder, box_lattice};
    use glam::Vec3;

    /// A 6 x 4 x 2 cm box resting on the ground.
    pub(crate) fn resting_box() -> (crate::world::World, crate::world::ShapeId) {
        let mut b = WorldBuilder::new();
        let shape = b.add_rigid(
            "box",
            &box_lattice(Vec3::new(0.03, 0.02, 0.01), 0.01),
            0.005,
            0.005,
            Pose::from_translation(Vec3::new(0.0, 0.0, 0.0151)),
            Vec3::ONE,
        );
        (b.build(), shape)
    }

    /// A box at rest is set sliding at tick 40 by something the physics does not know (its
    /// velocity is set): the window around the kick is one where it sped up; a window while it
    /// slows down on its own is not.
    #[test]
    fn a_window_where_something_unmodelled_sets_the_object_moving_is_flagged_as_sped_up() {
        let (world, shape) = resting_box();
        // A slippery table: it is still sliding, slowing, a second after the kick.
        let mut physics = PhysicsConfig::default();
        physics.ground.static_friction = 0.04;
        physics.ground.kinetic_friction = 0.03;
        let kick = |k| (k == 40).then_some(Vec3::new(0.3, 0.0, 0.0));
        let trace = Trace::simulated(world, physics.clone(), physics.clone(), 70, shape, kick);
        let horizon = (HORIZON / trace.dt()).round() as usize;
        let flag = |starts: Vec<usize>, samples: &[Sample]| {
            let p = trace.predict(&physics, shape, &starts, horizon).unwrap();
            window(
                &trace,
                shape,
                "box",
                &p.iter().collect::<Vec<_>>(),
                horizon,
                samples,
            )
            .sped_up
        };
        assert!(flag((34..=40).step_by(2).collect(), &[]));
        let sliding = trace.centroid(shape, 62).x - trace.centroid(shape, 56).x;
        assert!(sliding > 0.01, "still sliding: {sliding}");
        assert!(!flag((48..=56).step_by(2).collect(), &[]));
        // The same kick where the tracked world has another object touching it at the kick: a
        // collision the model has, not something outside it.
        let struck = Sample {
            t: trace.states[40].time,
            object: "box".into(),
            touching_object: true,
            ..Default::default()
        };
        assert!(!flag((34..=40).step_by(2).collect(), &[struck]));
    }

    /// A box at rest that the tracker relocated 5 cm (the track jumps, as when something outside
    /// the model moved it unseen): without the jump on record the windows across it are a
    /// mismatch; with it they are left out, since no physics makes such a jump.
    #[test]
    fn a_relocation_is_no_mismatch_of_the_physics() {
        let (world, shape) = resting_box();
        let physics = PhysicsConfig::default();
        let mut trace =
            Trace::simulated(world, physics.clone(), physics.clone(), 70, shape, |_| None);
        let range = trace.base.shapes.range(shape);
        for state in &mut trace.states[40..] {
            state.position[range.clone()]
                .iter_mut()
                .for_each(|p| *p += Vec3::new(0.05, 0.0, 0.0));
        }
        let unsaid = locate(&trace, &physics, shape, &[], 0.0).unwrap();
        assert!(!unsaid.windows.is_empty(), "the jump reads as a mismatch");
        trace.jumps.push(crate::trace::Jump {
            object: "box".into(),
            shape,
            state: 40,
            time: trace.states[40].time,
            jump_m: 0.05,
        });
        let said = locate(&trace, &physics, shape, &[], 0.0).unwrap();
        assert!(said.windows.is_empty(), "{:?}", said.windows);
    }

    #[test]
    fn noise_comes_from_resting_starts_so_an_effect_acting_most_of_the_time_is_not_noise() {
        // Twenty moving starts miss by 3-4 mm (the effect), eight resting ones by 0.1 mm.
        let mut errors: Vec<f32> = (0..20).map(|i| 0.003 + 0.00005 * i as f32).collect();
        errors.extend([0.0001; 8]);
        let quiet: Vec<bool> = (0..28).map(|i| i >= 20).collect();
        assert!((noise(&errors, &quiet) - 0.0001).abs() < 1e-9);
        // Without resting starts, the lower quartile.
        let moving = vec![false; 28];
        let q = noise(&errors, &moving);
        assert!(q < 0.0031 && q > 0.0, "{q}");
    }
}

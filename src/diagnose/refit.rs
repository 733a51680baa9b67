//! Model and name by simulation: each candidate effect is a family of physics terms with one
//! physical parameter; the parameter is fitted by running the physics open loop (no visual
//! forces) from tracked states and matching where tracking found the object one horizon later.
//! Families are fitted on the first part of the recording and judged on the held-out rest; one
//! is named only when it clearly cuts the held-out prediction error. Intervals come from a
//! bootstrap over the fitting windows.

use super::trace::{Prediction, Trace};
use crate::config::PhysicsConfig;
use crate::physics::Effect;
use crate::world::ShapeId;
use anyhow::Result;
use glam::{Vec2, Vec3};
use serde::Serialize;

/// One candidate family: the effect it adds and the parameter it fits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    ViscousDrag,
    GroundFriction,
    ConstantForce,
    Spring,
    MassScale,
    AngularDamping,
    FrictionPatch,
    /// Centre of mass moved along the body's x or y axis.
    CenterOfMass(usize),
}

pub const ALL: [Family; 9] = [
    Family::ViscousDrag,
    Family::GroundFriction,
    Family::ConstantForce,
    Family::Spring,
    Family::MassScale,
    Family::AngularDamping,
    Family::FrictionPatch,
    Family::CenterOfMass(0),
    Family::CenterOfMass(1),
];

impl Family {
    /// The effect's name in reports (both centre-of-mass axes are one effect).
    pub fn name(self) -> &'static str {
        match self {
            Family::ViscousDrag => "viscous_drag",
            Family::GroundFriction => "ground_friction",
            Family::ConstantForce => "constant_force",
            Family::Spring => "spring",
            Family::MassScale => "mass_error",
            Family::AngularDamping => "angular_damping",
            Family::FrictionPatch => "friction_patch",
            Family::CenterOfMass(_) => "center_of_mass_offset",
        }
    }

    /// The fitted parameter's name and unit.
    pub fn parameter(self) -> (&'static str, &'static str) {
        match self {
            Family::ViscousDrag => ("coefficient", "N s/m"),
            Family::GroundFriction | Family::FrictionPatch => ("friction", ""),
            Family::ConstantForce => ("magnitude", "N"),
            Family::Spring => ("stiffness", "N/m"),
            Family::MassScale => ("factor", ""),
            Family::AngularDamping => ("coefficient", "1/s"),
            Family::CenterOfMass(_) => ("offset", "m"),
        }
    }
}

/// What a family needs to know beyond its parameter: the object, the base physics, directions
/// and places found from the base model's prediction errors.
pub struct Setting {
    pub object: String,
    pub shape: ShapeId,
    pub mass: f32,
    pub base: PhysicsConfig,
    /// Direction of the missing force in the plane (mean displacement error), if any.
    pub force_direction: Option<Vec3>,
    /// Anchor of a spring that would explain the displacement errors, if one would.
    pub anchor: Option<Vec3>,
    /// Table region of the located mismatches.
    pub region: Option<(Vec2, Vec2)>,
    /// Largest centre-of-mass offset along body x and y that keeps every particle's mass positive.
    pub com_limit: [f32; 2],
}

impl Setting {
    /// The search range of `family`'s parameter (low, high, logarithmic), or None when the family
    /// does not apply (no direction, no anchor, no region).
    fn range(&self, family: Family) -> Option<(f32, f32, bool)> {
        let m = self.mass;
        let g = 9.81;
        match family {
            Family::ViscousDrag => Some((0.03 * m, 30.0 * m, true)),
            Family::GroundFriction => Some((0.0, 0.6, false)),
            Family::ConstantForce => self.force_direction.map(|_| (0.002 * m * g, 0.3 * m * g, true)),
            Family::Spring => self.anchor.map(|_| (0.1 * m, 100.0 * m, true)),
            Family::MassScale => Some((0.25, 4.0, true)),
            Family::AngularDamping => Some((0.03, 30.0, true)),
            Family::FrictionPatch => self.region.map(|_| (0.0, 1.0, false)),
            Family::CenterOfMass(axis) => (self.com_limit[axis] > 1e-3).then(|| (-self.com_limit[axis], self.com_limit[axis], false)),
        }
    }

    /// The effect of `family` with parameter `value`.
    pub fn effect(&self, family: Family, value: f32) -> Option<Effect> {
        let object = self.object.clone();
        let friction_gap = self.base.ground.static_friction - self.base.ground.kinetic_friction;
        Some(match family {
            Family::ViscousDrag => Effect::ViscousDrag { object: Some(object), coefficient: value },
            Family::GroundFriction => Effect::FrictionPatch {
                center: Vec2::ZERO,
                half_size: Vec2::splat(1e3),
                static_friction: value + friction_gap,
                kinetic_friction: value,
            },
            Family::ConstantForce => Effect::ConstantForce { object: Some(object), force: self.force_direction? * value },
            Family::Spring => Effect::Spring { object, point: Vec3::ZERO, anchor: self.anchor?, stiffness: value, rest_length: 0.0, damping: 0.0, tether: false },
            Family::MassScale => Effect::MassScale { object, factor: value },
            Family::AngularDamping => Effect::AngularDamping { object: Some(object), coefficient: value },
            Family::FrictionPatch => {
                let (lo, hi) = self.region?;
                Effect::FrictionPatch { center: (lo + hi) * 0.5, half_size: (hi - lo) * 0.5, static_friction: value + friction_gap, kinetic_friction: value }
            }
            Family::CenterOfMass(axis) => Effect::CenterOfMassOffset { object, offset: if axis == 0 { Vec3::X } else { Vec3::Y } * value },
        })
    }

    fn physics(&self, family: Family, value: f32) -> Option<PhysicsConfig> {
        let mut p = self.base.clone();
        p.effects.push(self.effect(family, value)?);
        Some(p)
    }
}

/// A family fitted to the training windows and judged on the held-out ones.
#[derive(Clone, Debug, Serialize)]
pub struct Fit {
    pub effect: String,
    pub parameter: String,
    pub unit: String,
    pub value: f32,
    /// 95 % bootstrap interval over the training windows.
    pub low: f32,
    pub high: f32,
    /// Mean squared open-loop error (m^2) before and after, on training and held-out windows.
    pub train_before: f64,
    pub train_after: f64,
    pub heldout_before: f64,
    pub heldout_after: f64,
    #[serde(skip)]
    pub family: Option<Family>,
    #[serde(skip)]
    pub effect_term: Option<Effect>,
}

impl Fit {
    /// Fraction of the held-out squared prediction error this effect removes.
    pub fn heldout_gain(&self) -> f64 {
        1.0 - self.heldout_after / self.heldout_before.max(1e-12)
    }
    pub fn train_gain(&self) -> f64 {
        1.0 - self.train_after / self.train_before.max(1e-12)
    }
}

fn mean_square(p: &[Prediction]) -> f64 {
    p.iter().map(|p| (p.error as f64).powi(2)).sum::<f64>() / p.len().max(1) as f64
}

/// Fit `family` on `train` starts and judge it on `heldout` starts (each predicted `horizon`
/// ticks). `base_train` / `base_heldout` are the base model's predictions from the same starts.
#[allow(clippy::too_many_arguments)]
pub fn fit(trace: &Trace, setting: &Setting, family: Family, train: &[usize], heldout: &[usize], horizon: usize, base_train: &[Prediction], base_heldout: &[Prediction]) -> Result<Option<Fit>> {
    let Some((lo, hi, log)) = setting.range(family) else { return Ok(None) };
    let to_x = |v: f32| if log { v.ln() } else { v };
    let from_x = |x: f32| if log { x.exp() } else { x };
    // Every evaluated parameter with its per-window squared errors (None: physics refused it).
    let mut evaluated: Vec<(f32, Vec<f64>)> = Vec::new();
    let loss = |v: f32, evaluated: &mut Vec<(f32, Vec<f64>)>| -> Result<f64> {
        let Some(physics) = setting.physics(family, v) else { return Ok(f64::INFINITY) };
        match trace.predict(&physics, setting.shape, train, horizon) {
            Ok(p) => {
                let e: Vec<f64> = p.iter().map(|p| (p.error as f64).powi(2)).collect();
                let l = e.iter().sum::<f64>() / e.len().max(1) as f64;
                evaluated.push((v, e));
                Ok(l)
            }
            // Parameters the physics rejects (a centre of mass outside the body) fit nothing.
            Err(_) => Ok(f64::INFINITY),
        }
    };
    const GRID: usize = 7;
    let xs: Vec<f32> = (0..GRID).map(|i| to_x(lo) + (to_x(hi) - to_x(lo)) * i as f32 / (GRID - 1) as f32).collect();
    let mut losses = Vec::with_capacity(GRID);
    for &x in &xs {
        losses.push(loss(from_x(x), &mut evaluated)?);
    }
    let best = (0..GRID).min_by(|&a, &b| losses[a].total_cmp(&losses[b])).unwrap_or(0);
    if !losses[best].is_finite() {
        return Ok(None);
    }
    // Golden-section search in the grid cells around the best grid point.
    let (mut a, mut b) = (xs[best.saturating_sub(1)], xs[(best + 1).min(GRID - 1)]);
    let r = 0.618_034f32;
    let (mut c, mut d) = (b - r * (b - a), a + r * (b - a));
    let (mut fc, mut fd) = (loss(from_x(c), &mut evaluated)?, loss(from_x(d), &mut evaluated)?);
    for _ in 0..3 {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - r * (b - a);
            fc = loss(from_x(c), &mut evaluated)?;
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + r * (b - a);
            fd = loss(from_x(d), &mut evaluated)?;
        }
    }
    let (value, train_after) = evaluated
        .iter()
        .map(|(v, e)| (*v, e.iter().sum::<f64>() / e.len().max(1) as f64))
        .min_by(|x, y| x.1.total_cmp(&y.1))
        .unwrap_or((from_x(xs[best]), losses[best]));
    let (low, high) = bootstrap_interval(&evaluated, 200, to_x, from_x);
    let physics = setting.physics(family, value).ok_or_else(|| anyhow::anyhow!("family {family:?} lost its setting"))?;
    let held = trace.predict(&physics, setting.shape, heldout, horizon)?;
    let (name, unit) = family.parameter();
    Ok(Some(Fit {
        effect: family.name().to_string(),
        parameter: name.to_string(),
        unit: unit.to_string(),
        value,
        low,
        high,
        train_before: mean_square(base_train),
        train_after,
        heldout_before: mean_square(base_heldout),
        heldout_after: mean_square(&held),
        family: Some(family),
        effect_term: setting.effect(family, value),
    }))
}

/// Percentile interval of the best parameter over bootstrap resamples of the windows: per
/// resample, the vertex of the parabola through the best evaluated parameter and its neighbours
/// (in the search coordinate `to_x`), so the interval is not limited to the evaluated points.
fn bootstrap_interval(evaluated: &[(f32, Vec<f64>)], resamples: usize, to_x: impl Fn(f32) -> f32, from_x: impl Fn(f32) -> f32) -> (f32, f32) {
    let n = evaluated.first().map_or(0, |e| e.1.len());
    if n == 0 {
        return (f32::NAN, f32::NAN);
    }
    let mut points: Vec<(f32, &Vec<f64>)> = evaluated.iter().map(|(v, e)| (to_x(*v), e)).collect();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    points.dedup_by(|a, b| (a.0 - b.0).abs() < 1e-9);
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut picks = Vec::with_capacity(resamples);
    for _ in 0..resamples {
        let mut weight = vec![0u32; n];
        for _ in 0..n {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            weight[(state % n as u64) as usize] += 1;
        }
        let loss: Vec<f64> = points.iter().map(|(_, e)| e.iter().zip(&weight).map(|(x, w)| x * *w as f64).sum()).collect();
        let Some(i) = (0..loss.len()).min_by(|&a, &b| loss[a].total_cmp(&loss[b])) else { continue };
        let x = if i > 0 && i + 1 < points.len() {
            let (x0, x1, x2) = (points[i - 1].0 as f64, points[i].0 as f64, points[i + 1].0 as f64);
            let (y0, y1, y2) = (loss[i - 1], loss[i], loss[i + 1]);
            let den = (x1 - x0) * (y1 - y2) - (x1 - x2) * (y1 - y0);
            let num = (x1 - x0).powi(2) * (y1 - y2) - (x1 - x2).powi(2) * (y1 - y0);
            if den.abs() > 1e-18 { (x1 - 0.5 * num / den).clamp(x0, x2) as f32 } else { x1 as f32 }
        } else {
            points[i].0
        };
        picks.push(from_x(x));
    }
    if picks.is_empty() {
        return (f32::NAN, f32::NAN);
    }
    picks.sort_by(f32::total_cmp);
    let k = picks.len();
    (picks[(k as f32 * 0.025) as usize], picks[((k as f32 * 0.975) as usize).min(k - 1)])
}

/// Largest centre-of-mass offsets along body x and y that keep every particle's mass positive
/// (a linear reweighting of the particles; see `physics::effects`), with a margin.
pub fn com_limits(trace: &Trace, shape: ShapeId) -> [f32; 2] {
    let w = &trace.base;
    let rest: Vec<Vec3> = w.shapes.range(shape).map(|i| w.particles.rest[i]).collect();
    let n = rest.len().max(1) as f32;
    let mean = rest.iter().copied().sum::<Vec3>() / n;
    [0, 1].map(|axis| {
        let coord: Vec<f32> = rest.iter().map(|r| (*r - mean)[axis]).collect();
        let var = coord.iter().map(|c| c * c).sum::<f32>() / n;
        let reach = coord.iter().fold(0.0f32, |m, c| m.max(c.abs()));
        if reach > 0.0 { 0.8 * var / reach } else { 0.0 }
    })
}

/// Directions for the force-like families from the base model's displacement errors: the mean
/// error's direction (a constant force) and the anchor of the spring `e = a (anchor - x)` that
/// fits them best, if it pulls (`a > 0`).
pub fn directions(trace: &Trace, shape: ShapeId, base: &[Prediction]) -> (Option<Vec3>, Option<Vec3>) {
    // Per window: the mean predicted position and the miss (tracked - predicted) at its end.
    let rows: Vec<(Vec2, Vec2)> = base
        .iter()
        .map(|p| {
            let end = p.start + p.path.len() - 1;
            let predicted = p.path.last().copied().unwrap_or_default().truncate();
            let mean_x = p.path.iter().map(|q| q.truncate()).sum::<Vec2>() / p.path.len().max(1) as f32;
            (mean_x, trace.centroid(shape, end).truncate() - predicted)
        })
        .collect();
    let total: Vec2 = rows.iter().map(|r| r.1).sum();
    let force = (total.length() > 1e-6).then(|| total.normalize().extend(0.0));
    let anchor = spring_anchor(&rows).map(|a| a.extend(trace.centroid(shape, 0).z));
    (force, anchor)
}

/// Least squares of `miss = b - a x` (unknowns b_x, b_y, a) over `(x, miss)` rows; the anchor
/// `b / a` if the fitted spring pulls.
fn spring_anchor(rows: &[(Vec2, Vec2)]) -> Option<Vec2> {
    let n = rows.len();
    if n < 3 {
        return None;
    }
    let x = nalgebra::DMatrix::from_fn(2 * n, 3, |i, j| {
        let c = i % 2;
        match j {
            2 => -(rows[i / 2].0[c] as f64),
            _ => (j == c) as u8 as f64,
        }
    });
    let y = nalgebra::DVector::from_fn(2 * n, |i, _| rows[i / 2].1[i % 2] as f64);
    let beta = x.svd(true, true).solve(&y, 1e-12).ok()?;
    let a = beta[2];
    (a > 1e-6).then(|| Vec2::new((beta[0] / a) as f32, (beta[1] / a) as f32))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spring_anchor_is_recovered_from_misses_and_a_push_has_none() {
        let anchor = Vec2::new(0.45, -0.2);
        let pulls: Vec<(Vec2, Vec2)> = (0..8).map(|k| Vec2::new(0.5 + 0.01 * k as f32, -0.1 + 0.03 * k as f32)).map(|x| (x, 0.3 * (anchor - x))).collect();
        let found = spring_anchor(&pulls).unwrap();
        assert!(found.distance(anchor) < 1e-4, "{found}");
        let pushes: Vec<(Vec2, Vec2)> = pulls.iter().map(|&(x, e)| (x, -e)).collect();
        assert_eq!(spring_anchor(&pushes), None);
    }

    #[test]
    fn the_bootstrap_interval_brackets_a_well_determined_minimum() {
        // Per-window losses (v - 1)^2 + window noise: every resample's best is near 1.
        let evaluated: Vec<(f32, Vec<f64>)> = (0..21)
            .map(|i| {
                let v = 0.5 + i as f32 * 0.05;
                (v, (0..12).map(|w| ((v - 1.0) as f64).powi(2) + 0.001 * ((w * 7 % 5) as f64)).collect())
            })
            .collect();
        let (lo, hi) = bootstrap_interval(&evaluated, 100, |v| v, |x| x);
        assert!(lo <= 1.0 && hi >= 1.0 && hi - lo < 0.11, "{lo} {hi}");
    }
}

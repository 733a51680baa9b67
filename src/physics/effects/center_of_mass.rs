//! A moved centre of mass: the object's centre of mass is shifted by `offset` (body frame, m),
//! its total mass unchanged (a hidden weight). The particles' masses are re-weighted
//! exponentially over their rest positions, which reaches about half way to a bar's end (a linear
//! re-weighting runs out of positive mass at a third).

use super::{Family, Feature, FitSetting, ReportValue, Term, vec3_parameters, vec3_slot};
use crate::physics::Effect;
use crate::world::{ShapeId, World};
use anyhow::{Context, Result, bail};
use glam::{DMat3, DVec3, Vec3};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CenterOfMassOffset {
    pub object: String,
    pub offset: Vec3,
}

impl Term for CenterOfMassOffset {
    fn object(&self) -> Option<&str> {
        Some(&self.object)
    }

    fn parameters(&self) -> Vec<(&'static str, f32)> {
        vec3_parameters(&["offset_x", "offset_y", "offset_z"], self.offset).to_vec()
    }

    fn parameter_mut(&mut self, name: &str) -> Option<&mut f32> {
        vec3_slot(&mut self.offset, name, "offset")
    }

    fn scale_inv_mass(
        &self,
        world: &World,
        shapes: &[ShapeId],
        inv_mass: &mut [f32],
    ) -> Result<()> {
        let s = shapes[0];
        shift_center_of_mass(world, s, self.offset, inv_mass).with_context(|| {
            let along = self.offset.normalize_or_zero();
            format!(
                "object '{}' can hold its centre of mass at most {:.3} m from its own along \
                 {along:.2}: set center_of_mass_offset's offset (body frame, m) within that, or \
                 check its frame and units",
                world.shapes.name[s as usize],
                center_of_mass_reach(world, s, along)
            )
        })
    }
}

/// Re-weight the masses of one shape so that the total mass stays the same and the centre of
/// mass moves by `offset` (body frame): `m_i' = m_i exp(a . u_i) / Z`, `u_i` a particle's rest
/// position from the centre of mass, `a` solved for by Newton's method. Of all re-weightings with
/// that centre of mass this one departs least from the particles' own masses (least relative
/// entropy) and every mass stays positive; a small offset re-weights almost linearly,
/// `1 + a . u_i`. Every offset strictly inside the hull of the particles has one; those whose
/// masses would differ more than `MAX_WEIGHT_RATIO` times are refused.
fn shift_center_of_mass(
    world: &World,
    s: ShapeId,
    offset: Vec3,
    inv_mass: &mut [f32],
) -> Result<()> {
    let name = &world.shapes.name[s as usize];
    let range = world.shapes.range(s);
    let masses: Vec<f64> = inv_mass[range.clone()]
        .iter()
        .map(|w| 1.0 / *w as f64)
        .collect();
    let rest: Vec<DVec3> = world.particles.rest[range.clone()]
        .iter()
        .map(|r| r.as_dvec3())
        .collect();
    let total: f64 = masses.iter().sum();
    let com = rest
        .iter()
        .zip(&masses)
        .map(|(r, m)| *r * *m)
        .sum::<DVec3>()
        / total;
    let u: Vec<DVec3> = rest.iter().map(|r| *r - com).collect();
    let target = offset.as_dvec3();
    if moments(&masses, &u, DVec3::ZERO).2.determinant().abs() < 1e-24 {
        bail!(
            "center_of_mass_offset: object '{name}' is flat or a line; its centre of mass cannot move off that set"
        );
    }
    // Newton on the convex dual `log sum m_i exp(a . u_i) - a . offset`: its gradient is the
    // re-weighted centre of mass less the offset, its Hessian the re-weighted covariance.
    let mut a = DVec3::ZERO;
    for _ in 0..MAX_NEWTON {
        let (share, mean, cov) = moments(&masses, &u, a);
        let miss = mean - target;
        if miss.length() < COM_TOLERANCE {
            // Heaviest particle over the lightest: exp of the spread of `a . u`.
            let spread = u
                .iter()
                .map(|x| a.dot(*x))
                .fold((f64::MAX, f64::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)));
            let ratio = (spread.1 - spread.0).exp();
            if ratio > MAX_WEIGHT_RATIO {
                bail!(
                    "center_of_mass_offset: offset {offset} is too far for object '{name}': its particles' masses would differ {ratio:.0} times (at most {MAX_WEIGHT_RATIO:.0})"
                );
            }
            for (k, i) in range.enumerate() {
                inv_mass[i] = (1.0 / (share[k] * total)) as f32;
            }
            return Ok(());
        }
        let step = cov.inverse() * miss;
        if !step.is_finite() {
            break;
        }
        // Halve the step until the dual falls (an offset near the hull's edge needs large `a`).
        let dual = |a: DVec3| log_partition(&masses, &u, a) - a.dot(target);
        let (now, mut t) = (dual(a), 1.0);
        while t > 1e-6 && dual(a - step * t) > now {
            t *= 0.5;
        }
        a -= step * t;
    }
    bail!(
        "center_of_mass_offset: offset {offset} is outside object '{name}' (no positive masses put its centre of mass there)"
    )
}

/// Newton iterations and the centre-of-mass tolerance (m) of `shift_center_of_mass`.
const MAX_NEWTON: usize = 200;
const COM_TOLERANCE: f64 = 1e-7;

/// The most one particle of an object may weigh against another after the re-weighting. The
/// solver's contacts move a light particle of a rigid body that its heavy ones then hold back:
/// a 0.3 m plank dropped on a ridge tipped as it should at a ratio of 105 and was thrown over at
/// 2.7 million. At 100 the centre of mass reaches about 0.58 of the way to the end of a uniform
/// bar (a linear re-weighting: 0.33).
pub const MAX_WEIGHT_RATIO: f64 = 100.0;

/// The largest centre-of-mass offset along `axis` (body frame, unit), either way, that the
/// re-weighting represents for shape `s` within `MAX_WEIGHT_RATIO` (0 for a flat object or a
/// line along it), to a millimetre.
pub fn center_of_mass_reach(world: &World, s: ShapeId, axis: Vec3) -> f32 {
    let range = world.shapes.range(s);
    let inv_mass = &world.particles.inv_mass;
    let reaches = |offset: f32| {
        let mut scratch = inv_mass.clone();
        shift_center_of_mass(world, s, axis * offset, &mut scratch).is_ok()
    };
    // Beyond the outermost particle seen from any of them, nothing is reached.
    let along: Vec<f32> = world.particles.rest[range]
        .iter()
        .map(|r| r.dot(axis))
        .collect();
    let (low, high) = along
        .iter()
        .fold((f32::MAX, f32::MIN), |(lo, hi), v| (lo.min(*v), hi.max(*v)));
    let extent = (high - low).max(0.0);
    [1.0f32, -1.0]
        .map(|side| {
            let (mut lo, mut hi) = (0.0f32, extent);
            while hi - lo > 1e-3 {
                let mid = 0.5 * (lo + hi);
                match reaches(side * mid) {
                    true => lo = mid,
                    false => hi = mid,
                }
            }
            lo
        })
        .into_iter()
        .fold(f32::MAX, f32::min)
}

/// Under the weights `m_i exp(a . u_i)`: each particle's share of the total, and the weighted
/// mean and covariance of `u`.
fn moments(masses: &[f64], u: &[DVec3], a: DVec3) -> (Vec<f64>, DVec3, DMat3) {
    let top = u.iter().map(|x| a.dot(*x)).fold(f64::MIN, f64::max);
    let raw: Vec<f64> = masses
        .iter()
        .zip(u)
        .map(|(m, x)| m * (a.dot(*x) - top).exp())
        .collect();
    let sum: f64 = raw.iter().sum();
    let share: Vec<f64> = raw.iter().map(|w| w / sum).collect();
    let mean = share.iter().zip(u).map(|(w, x)| *x * *w).sum::<DVec3>();
    let mut cov = DMat3::ZERO;
    for (w, x) in share.iter().zip(u) {
        let d = *x - mean;
        cov += DMat3::from_cols(d * d.x, d * d.y, d * d.z) * *w;
    }
    (share, mean, cov)
}

/// `log sum m_i exp(a . u_i)`, computed without overflow.
fn log_partition(masses: &[f64], u: &[DVec3], a: DVec3) -> f64 {
    let top = u.iter().map(|x| a.dot(*x)).fold(f64::MIN, f64::max);
    top + masses
        .iter()
        .zip(u)
        .map(|(m, x)| m * (a.dot(*x) - top).exp())
        .sum::<f64>()
        .ln()
}

/// The offset along body x (`ComFamily(0)`) or y (`ComFamily(1)`), within the object
/// (`FitSetting::com_limit`).
#[derive(Debug)]
pub struct ComFamily(pub usize);

impl Family for ComFamily {
    fn id(&self) -> &'static str {
        ["center_of_mass_offset_x", "center_of_mass_offset_y"][self.0]
    }

    fn name(&self) -> &'static str {
        "center_of_mass_offset"
    }

    fn parameter(&self) -> (&'static str, &'static str) {
        ("offset", "m")
    }

    fn complexity(&self) -> usize {
        2
    }

    fn range(&self, s: &FitSetting) -> Option<(f32, f32, bool)> {
        let limit = s.com_limit[self.0];
        (limit > 1e-3).then(|| (-limit, limit, false))
    }

    fn effect(&self, s: &FitSetting, value: f32) -> Option<Effect> {
        let axis = if self.0 == 0 { Vec3::X } else { Vec3::Y };
        Some(
            CenterOfMassOffset {
                object: s.object.clone(),
                offset: axis * value,
            }
            .into(),
        )
    }

    fn report(&self, _: &FitSetting, _: f32, _: Option<&Effect>) -> Vec<ReportValue> {
        vec![("body_axis", self.0 as f32, "0 = x, 1 = y")]
    }

    fn feature(&self) -> Feature {
        Feature::AngularVelocity
    }
}

#[cfg(test)]
mod tests {
    use super::super::EffectModel;
    use super::super::tests::one_box;
    use super::*;

    #[test]
    fn center_of_mass_offset_moves_the_com_and_keeps_the_mass() {
        let w = one_box();
        let offset = Vec3::new(0.008, -0.004, 0.001);
        let moved = CenterOfMassOffset {
            object: "box".into(),
            offset,
        };
        let model = EffectModel::bind(&[moved.into()], &w).unwrap();
        let inv = model.effective_inv_mass(&w).unwrap();
        let (com, total) = com_and_mass(&w, &inv);
        let nominal = com_and_mass(&w, &w.particles.inv_mass).1;
        assert!((total - nominal).abs() / nominal < 1e-5);
        assert!((com - offset).length() < 1e-5, "com {com} want {offset}");
        // Too far: outside the body no positive masses put the centre of mass, which is refused.
        let far = CenterOfMassOffset {
            object: "box".into(),
            offset: Vec3::new(0.2, 0.0, 0.0),
        };
        let far = EffectModel::bind(&[far.into()], &w).unwrap();
        assert!(far.effective_inv_mass(&w).is_err());
    }

    /// The centre of mass and total mass of `w`'s particles under `inv_mass`.
    fn com_and_mass(w: &World, inv_mass: &[f32]) -> (Vec3, f32) {
        let m: Vec<f32> = inv_mass.iter().map(|x| 1.0 / x).collect();
        let total: f32 = m.iter().sum();
        let com = w
            .particles
            .rest
            .iter()
            .zip(&m)
            .map(|(r, m)| *r * *m)
            .sum::<Vec3>()
            / total;
        (com, total)
    }

    #[test]
    fn a_hidden_weight_reaches_past_a_linear_re_weighting_with_every_mass_positive() {
        let w = one_box();
        let end = w.particles.rest.iter().fold(0.0f32, |m, r| m.max(r.x));
        let nominal = com_and_mass(&w, &w.particles.inv_mass).1;
        // A linear re-weighting `1 + a x` reaches at most var / end = end / 3 for particles
        // spread evenly over +-end; the exponential one over half the way within the ratio.
        let reach = center_of_mass_reach(&w, 0, Vec3::X);
        assert!(reach > 0.5 * end && reach < end, "reach {reach}, end {end}");
        for offset in [
            Vec3::new(0.98 * reach, 0.0, 0.0),
            Vec3::new(-0.6 * reach, 0.005, -0.002),
        ] {
            let moved = CenterOfMassOffset {
                object: "box".into(),
                offset,
            };
            let model = EffectModel::bind(&[moved.into()], &w).unwrap();
            let inv = model.effective_inv_mass(&w).unwrap();
            assert!(inv.iter().all(|x| x.is_finite() && *x > 0.0));
            let heaviest = inv.iter().fold(f32::MAX, |m, x| m.min(*x));
            let lightest = inv.iter().fold(0.0f32, |m, x| m.max(*x));
            assert!(lightest / heaviest <= MAX_WEIGHT_RATIO as f32 * 1.001);
            let (com, total) = com_and_mass(&w, &inv);
            assert!((total - nominal).abs() / nominal < 1e-4);
            assert!((com - offset).length() < 1e-5, "com {com} want {offset}");
        }
        // Past the reach the particles' masses would differ too much: refused, as is a point
        // outside the object.
        for x in [1.05 * reach, 1.05 * end] {
            let far = CenterOfMassOffset {
                object: "box".into(),
                offset: Vec3::new(x, 0.0, 0.0),
            };
            let far = EffectModel::bind(&[far.into()], &w).unwrap();
            let Err(e) = far.effective_inv_mass(&w) else {
                panic!("offset {x} accepted");
            };
            // The refusal says how far the weight can go.
            let said = format!("{e:#}");
            assert!(said.contains(&format!("{reach:.3} m")), "{said}");
        }
    }

    #[test]
    fn a_small_hidden_weight_re_weights_the_masses_almost_linearly() {
        // To first order `exp(a . u) = 1 + a . u`: the re-weighting a linear model of the weight
        // would give, so small offsets keep their meaning.
        let w = one_box();
        let offset = Vec3::new(0.002, 0.0, 0.0);
        let moved = CenterOfMassOffset {
            object: "box".into(),
            offset,
        };
        let model = EffectModel::bind(&[moved.into()], &w).unwrap();
        let inv = model.effective_inv_mass(&w).unwrap();
        let n = w.particles.len() as f32;
        let var = w.particles.rest.iter().map(|r| r.x * r.x).sum::<f32>() / n;
        for (r, (new, old)) in w
            .particles
            .rest
            .iter()
            .zip(inv.iter().zip(&w.particles.inv_mass))
        {
            let linear = 1.0 + offset.x / var * r.x;
            let ratio = old / new;
            assert!(
                (ratio - linear).abs() < 0.01,
                "weight {ratio} linear {linear}"
            );
        }
    }
}

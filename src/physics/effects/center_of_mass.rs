//! A moved centre of mass: the object's centre of mass is shifted by `offset` (body frame, m),
//! its total mass unchanged (a hidden weight). The particles' masses are re-weighted linearly over
//! their rest positions.

use super::{Family, Feature, FitSetting, ReportValue, Term, vec3_parameters, vec3_slot};
use crate::physics::Effect;
use crate::world::{ShapeId, World};
use anyhow::{Result, bail};
use glam::{Mat3, Vec3};
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
        shift_center_of_mass(world, shapes[0], self.offset, inv_mass)
    }
}

/// Re-weight the masses of one shape linearly over its rest positions, `m_i' = m_i (1 + a . u_i)`,
/// so that the total mass stays the same and the centre of mass moves by `offset` (body frame).
fn shift_center_of_mass(
    world: &World,
    s: ShapeId,
    offset: Vec3,
    inv_mass: &mut [f32],
) -> Result<()> {
    let range = world.shapes.range(s);
    let rest = &world.particles.rest[range.clone()];
    let masses: Vec<f32> = inv_mass[range.clone()].iter().map(|w| 1.0 / w).collect();
    let total: f32 = masses.iter().sum();
    let com = rest.iter().zip(&masses).map(|(r, m)| *r * *m).sum::<Vec3>() / total;
    let mut cov = Mat3::ZERO;
    for (r, m) in rest.iter().zip(&masses) {
        let u = *r - com;
        cov += Mat3::from_cols(u * u.x, u * u.y, u * u.z) * *m;
    }
    if cov.determinant().abs() < 1e-18 {
        bail!(
            "center_of_mass_offset: object '{}' is flat or a line; its centre of mass cannot move off that set",
            world.shapes.name[s as usize]
        );
    }
    let a = cov.inverse() * (offset * total);
    for (k, i) in range.enumerate() {
        let weight = 1.0 + a.dot(rest[k] - com);
        if weight < 0.05 {
            bail!(
                "center_of_mass_offset: offset {offset} is too large for object '{}' (it would need negative mass)",
                world.shapes.name[s as usize]
            );
        }
        inv_mass[i] = 1.0 / (masses[k] * weight);
    }
    Ok(())
}

/// The offset along body x (`ComFamily(0)`) or y (`ComFamily(1)`), within the largest offset that
/// keeps every particle's mass positive.
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
        let m: Vec<f32> = inv.iter().map(|x| 1.0 / x).collect();
        let total: f32 = m.iter().sum();
        let nominal: f32 = w.particles.inv_mass.iter().map(|x| 1.0 / x).sum();
        assert!((total - nominal).abs() / nominal < 1e-5);
        let com = w
            .particles
            .rest
            .iter()
            .zip(&m)
            .map(|(r, m)| *r * *m)
            .sum::<Vec3>()
            / total;
        assert!((com - offset).length() < 1e-5, "com {com} want {offset}");
        // Too far: outside the body needs negative masses, which is refused.
        let far = CenterOfMassOffset {
            object: "box".into(),
            offset: Vec3::new(0.2, 0.0, 0.0),
        };
        let far = EffectModel::bind(&[far.into()], &w).unwrap();
        assert!(far.effective_inv_mass(&w).is_err());
    }
}

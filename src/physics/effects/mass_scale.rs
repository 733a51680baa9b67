//! A mass error: the object's true mass is `factor` times its modelled mass (same distribution).
//! Masses show only when objects collide, and then only as a ratio between them.

use super::{Family, Feature, FitSetting, Term};
use crate::physics::Effect;
use crate::world::{ShapeId, World};
use anyhow::Result;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MassScale {
    pub object: String,
    pub factor: f32,
}

impl Term for MassScale {
    fn object(&self) -> Option<&str> {
        Some(&self.object)
    }

    fn parameters(&self) -> Vec<(&'static str, f32)> {
        vec![("factor", self.factor)]
    }

    fn parameter_mut(&mut self, name: &str) -> Option<&mut f32> {
        (name == "factor").then_some(&mut self.factor)
    }

    fn check(&self) -> Option<&'static str> {
        (self.factor <= 0.0).then_some("factor must be > 0")
    }

    fn scale_inv_mass(
        &self,
        world: &World,
        shapes: &[ShapeId],
        inv_mass: &mut [f32],
    ) -> Result<()> {
        for i in world.shapes.range(shapes[0]) {
            inv_mass[i] /= self.factor;
        }
        Ok(())
    }
}

/// The factor between one object's true and modelled mass, 0.25 to 4.
#[derive(Debug)]
pub struct MassFamily;

impl Family for MassFamily {
    fn id(&self) -> &'static str {
        "mass_error"
    }

    fn parameter(&self) -> (&'static str, &'static str) {
        ("factor", "")
    }

    fn complexity(&self) -> usize {
        1
    }

    fn range(&self, _: &FitSetting) -> Option<(f32, f32, bool)> {
        Some((0.25, 4.0, true))
    }

    fn effect(&self, s: &FitSetting, value: f32) -> Option<Effect> {
        Some(
            MassScale {
                object: s.object.clone(),
                factor: value,
            }
            .into(),
        )
    }

    fn feature(&self) -> Feature {
        Feature::Acceleration
    }

    fn regression(&self) -> Option<&'static str> {
        Some("mass_error")
    }

    fn ratio_between_objects(&self) -> bool {
        true
    }
}

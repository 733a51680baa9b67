//! Angular damping: damps motion relative to the centre of mass (rotation). Acceleration
//! `-coefficient * (v_i - v_com)` on every particle, i.e. torque `-coefficient * I * omega` (1/s).

use super::{Bound, Family, Feature, FitSetting, Forces, Term};
use crate::physics::Effect;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AngularDamping {
    /// None: every dynamic object.
    #[serde(default)]
    pub object: Option<String>,
    pub coefficient: f32,
}

impl Term for AngularDamping {
    fn object(&self) -> Option<&str> {
        self.object.as_deref()
    }

    fn parameters(&self) -> Vec<(&'static str, f32)> {
        vec![("coefficient", self.coefficient)]
    }

    fn parameter_mut(&mut self, name: &str) -> Option<&mut f32> {
        (name == "coefficient").then_some(&mut self.coefficient)
    }

    fn check(&self) -> Option<&'static str> {
        (self.coefficient < 0.0).then_some("coefficient must be >= 0")
    }

    fn accelerate(&self, at: &Forces, bound: &Bound, accel: &mut [glam::Vec3]) {
        let velocity = &at.world.particles.velocity;
        for &s in &bound.shapes {
            let v_com = at.shape.velocity[s as usize];
            at.world
                .shapes
                .range(s)
                .for_each(|i| accel[i] -= self.coefficient * (velocity[i] - v_com));
        }
    }
}

/// The angular damping of one object, 0.03 to 30 per second.
#[derive(Debug)]
pub struct AngularDampingFamily;

impl Family for AngularDampingFamily {
    fn id(&self) -> &'static str {
        "angular_damping"
    }

    fn parameter(&self) -> (&'static str, &'static str) {
        ("coefficient", "1/s")
    }

    fn complexity(&self) -> usize {
        1
    }

    fn range(&self, _: &FitSetting) -> Option<(f32, f32, bool)> {
        Some((0.03, 30.0, true))
    }

    fn effect(&self, s: &FitSetting, value: f32) -> Option<Effect> {
        Some(
            AngularDamping {
                object: Some(s.object.clone()),
                coefficient: value,
            }
            .into(),
        )
    }

    fn feature(&self) -> Feature {
        Feature::AngularVelocity
    }

    fn regression(&self) -> Option<&'static str> {
        Some("angular_damping")
    }
}

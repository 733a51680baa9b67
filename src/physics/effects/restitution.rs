//! Restitution: ground contacts give back `coefficient` of the normal speed an object strikes the
//! ground with (0, the base model: contacts absorb it; 1: a perfect bounce). The solver applies it
//! at shape level after each substep's contacts.

use super::{Family, FitSetting, Term};
use crate::physics::Effect;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Restitution {
    /// None: every dynamic object.
    #[serde(default)]
    pub object: Option<String>,
    pub coefficient: f32,
}

impl Term for Restitution {
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
        (!(0.0..=1.0).contains(&self.coefficient)).then_some("coefficient must be within 0 ..= 1")
    }

    fn restitution(&self) -> Option<f32> {
        Some(self.coefficient)
    }
}

/// The restitution of one object's ground impacts, 0 to 0.95. Impacts are too short for the
/// per-tick force regression.
#[derive(Debug)]
pub struct RestitutionFamily;

impl Family for RestitutionFamily {
    fn id(&self) -> &'static str {
        "restitution"
    }

    fn parameter(&self) -> (&'static str, &'static str) {
        ("coefficient", "")
    }

    fn complexity(&self) -> usize {
        1
    }

    fn range(&self, _: &FitSetting) -> Option<(f32, f32, bool)> {
        Some((0.0, 0.95, false))
    }

    fn effect(&self, s: &FitSetting, value: f32) -> Option<Effect> {
        Some(
            Restitution {
                object: Some(s.object.clone()),
                coefficient: value,
            }
            .into(),
        )
    }
}

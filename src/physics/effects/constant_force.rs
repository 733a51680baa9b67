//! A constant force on the object (N): airflow, a hidden push, or a tilted table seen from one
//! object (`m g sin(angle)` downhill).

use super::{
    Bound, Family, Feature, FitSetting, Forces, Refinement, ReportValue, Term, vec3_parameters,
    vec3_slot,
};
use crate::physics::Effect;
use glam::Vec3;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConstantForce {
    /// None: every dynamic object.
    #[serde(default)]
    pub object: Option<String>,
    pub force: Vec3,
}

impl Term for ConstantForce {
    fn object(&self) -> Option<&str> {
        self.object.as_deref()
    }

    fn parameters(&self) -> Vec<(&'static str, f32)> {
        vec3_parameters(&["force_x", "force_y", "force_z"], self.force).to_vec()
    }

    fn parameter_mut(&mut self, name: &str) -> Option<&mut f32> {
        vec3_slot(&mut self.force, name, "force")
    }

    fn accelerate(&self, at: &Forces, bound: &Bound, accel: &mut [Vec3]) {
        for &s in &bound.shapes {
            let a = self.force / at.shape.mass[s as usize];
            at.world.shapes.range(s).for_each(|i| accel[i] += a);
        }
    }
}

const G: f32 = 9.81;

/// The magnitude of a horizontal force along the direction the base model's misses point in,
/// 0.002 to 0.3 times the object's weight; the direction is refined with it.
#[derive(Debug)]
pub struct ForceFamily;

impl Family for ForceFamily {
    fn id(&self) -> &'static str {
        "constant_force"
    }

    fn parameter(&self) -> (&'static str, &'static str) {
        ("magnitude", "N")
    }

    fn complexity(&self) -> usize {
        2
    }

    fn range(&self, s: &FitSetting) -> Option<(f32, f32, bool)> {
        let m = s.mass;
        s.force_direction
            .map(|_| (0.002 * m * G, 0.3 * m * G, true))
    }

    fn effect(&self, s: &FitSetting, value: f32) -> Option<Effect> {
        Some(
            ConstantForce {
                object: Some(s.object.clone()),
                force: s.force_direction? * value,
            }
            .into(),
        )
    }

    /// Both horizontal components of the force.
    fn refinement(&self, s: &FitSetting, value: f32) -> Option<Refinement> {
        let d = s.force_direction?;
        Some(Refinement {
            start: vec![(d.x * value) as f64, (d.y * value) as f64],
            steps: vec![0.1 * value.max(1e-3) as f64; 2],
        })
    }

    fn refined(&self, s: &FitSetting, p: &[f64]) -> Option<(FitSetting, f32)> {
        let f = Vec3::new(p[0] as f32, p[1] as f32, 0.0);
        let mut s = s.clone();
        s.force_direction = Some(f.try_normalize()?);
        Some((s, f.length()))
    }

    /// The fitted direction, and the table tilt that would give the same force.
    fn report(&self, s: &FitSetting, value: f32, fitted: Option<&Effect>) -> Vec<ReportValue> {
        let direction = match fitted {
            Some(Effect::ConstantForce(c)) => Some(c.force.normalize_or_zero()),
            _ => s.force_direction,
        };
        let mut out = Vec::new();
        if let Some(d) = direction {
            out.push(("direction_x", d.x, ""));
            out.push(("direction_y", d.y, ""));
        }
        let ratio = (value / (s.mass * G)).clamp(-1.0, 1.0);
        out.push(("equivalent_tilt", ratio.asin().to_degrees(), "deg"));
        out
    }

    fn feature(&self) -> Feature {
        Feature::SpeedAlongDirection
    }

    fn regression(&self) -> Option<&'static str> {
        Some("constant_force")
    }
}

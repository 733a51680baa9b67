//! A spring from a point of the object (body frame) to a world anchor, acting on the particle
//! nearest that point. With `tether: true` it only pulls when stretched beyond `rest_length` (a
//! string). `damping` acts along the spring.

use super::{
    Bound, Family, Feature, FitSetting, Forces, Refinement, ReportValue, Term, vec3_parameters,
    vec3_slot,
};
use crate::physics::Effect;
use crate::world::{ShapeId, World};
use glam::Vec3;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Spring {
    pub object: String,
    pub point: Vec3,
    pub anchor: Vec3,
    pub stiffness: f32,
    #[serde(default)]
    pub rest_length: f32,
    #[serde(default)]
    pub damping: f32,
    #[serde(default)]
    pub tether: bool,
}

impl Term for Spring {
    fn object(&self) -> Option<&str> {
        Some(&self.object)
    }

    fn parameters(&self) -> Vec<(&'static str, f32)> {
        let mut p = vec3_parameters(&["point_x", "point_y", "point_z"], self.point).to_vec();
        p.extend(vec3_parameters(
            &["anchor_x", "anchor_y", "anchor_z"],
            self.anchor,
        ));
        p.extend([
            ("stiffness", self.stiffness),
            ("rest_length", self.rest_length),
            ("damping", self.damping),
        ]);
        p
    }

    fn parameter_mut(&mut self, name: &str) -> Option<&mut f32> {
        match name {
            "stiffness" => Some(&mut self.stiffness),
            "rest_length" => Some(&mut self.rest_length),
            "damping" => Some(&mut self.damping),
            _ if name.starts_with("point_") => vec3_slot(&mut self.point, name, "point"),
            _ => vec3_slot(&mut self.anchor, name, "anchor"),
        }
    }

    fn check(&self) -> Option<&'static str> {
        (self.stiffness < 0.0 || self.rest_length < 0.0 || self.damping < 0.0)
            .then_some("stiffness, rest_length and damping must be >= 0")
    }

    /// The particle whose rest position is nearest the attachment point.
    fn attachment(&self, world: &World, shapes: &[ShapeId]) -> Option<usize> {
        let range = world.shapes.range(*shapes.first()?);
        let rest = &world.particles.rest[range.clone()];
        let nearest = (0..rest.len()).min_by(|&a, &b| {
            rest[a]
                .distance_squared(self.point)
                .total_cmp(&rest[b].distance_squared(self.point))
        });
        nearest.map(|k| range.start + k)
    }

    fn accelerate(&self, at: &Forces, bound: &Bound, accel: &mut [Vec3]) {
        let Some(i) = bound.particle else { return };
        let p = &at.world.particles;
        let d = p.position[i] - self.anchor;
        let len = d.length();
        if len < 1e-9 {
            return;
        }
        let dir = d / len;
        let stretch = len - self.rest_length;
        if self.tether && stretch <= 0.0 {
            return;
        }
        let force = -(self.stiffness * stretch + self.damping * p.velocity[i].dot(dir)) * dir;
        accel[i] += force * at.inv_mass[i];
    }
}

/// A spring from the object's centre to the anchor the base model's misses point at, 0.1 to 100
/// times the object's mass per second squared; the anchor is refined with the stiffness.
#[derive(Debug)]
pub struct SpringFamily;

impl Family for SpringFamily {
    fn id(&self) -> &'static str {
        "spring"
    }

    fn parameter(&self) -> (&'static str, &'static str) {
        ("stiffness", "N/m")
    }

    fn complexity(&self) -> usize {
        3
    }

    fn range(&self, s: &FitSetting) -> Option<(f32, f32, bool)> {
        let m = s.mass;
        s.anchor.map(|_| (0.1 * m, 100.0 * m, true))
    }

    fn effect(&self, s: &FitSetting, value: f32) -> Option<Effect> {
        Some(
            Spring {
                object: s.object.clone(),
                point: Vec3::ZERO,
                anchor: s.anchor?,
                stiffness: value,
                rest_length: 0.0,
                damping: 0.0,
                tether: false,
            }
            .into(),
        )
    }

    /// The stiffness and the anchor's horizontal position.
    fn refinement(&self, s: &FitSetting, value: f32) -> Option<Refinement> {
        let a = s.anchor?;
        Some(Refinement {
            start: vec![value as f64, a.x as f64, a.y as f64],
            steps: vec![0.1 * value.max(1e-3) as f64, 0.01, 0.01],
        })
    }

    fn refined(&self, s: &FitSetting, p: &[f64]) -> Option<(FitSetting, f32)> {
        let mut s = s.clone();
        let a = s.anchor?;
        s.anchor = Some(Vec3::new(p[1] as f32, p[2] as f32, a.z));
        (p[0] > 0.0).then_some((s, p[0] as f32))
    }

    fn report(&self, s: &FitSetting, _: f32, _: Option<&Effect>) -> Vec<ReportValue> {
        s.anchor.map_or(Vec::new(), |a| {
            vec![("anchor_x", a.x, "m"), ("anchor_y", a.y, "m")]
        })
    }

    fn feature(&self) -> Feature {
        Feature::DistanceFromAnchor
    }

    fn regression(&self) -> Option<&'static str> {
        Some("spring")
    }
}

//! A friction patch: the ground friction differs inside an axis-aligned rectangle of the table
//! (world x, y); the last patch containing a contact wins. A table-wide patch is a friction change.

use super::{Family, Feature, FitSetting, ReportValue, Term};
use crate::physics::Effect;
use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrictionPatch {
    pub center: Vec2,
    pub half_size: Vec2,
    pub static_friction: f32,
    pub kinetic_friction: f32,
}

impl Term for FrictionPatch {
    fn parameters(&self) -> Vec<(&'static str, f32)> {
        vec![
            ("center_x", self.center.x),
            ("center_y", self.center.y),
            ("half_size_x", self.half_size.x),
            ("half_size_y", self.half_size.y),
            ("static_friction", self.static_friction),
            ("kinetic_friction", self.kinetic_friction),
        ]
    }

    fn parameter_mut(&mut self, name: &str) -> Option<&mut f32> {
        match name {
            "center_x" => Some(&mut self.center.x),
            "center_y" => Some(&mut self.center.y),
            "half_size_x" => Some(&mut self.half_size.x),
            "half_size_y" => Some(&mut self.half_size.y),
            "static_friction" => Some(&mut self.static_friction),
            "kinetic_friction" => Some(&mut self.kinetic_friction),
            _ => None,
        }
    }

    fn check(&self) -> Option<&'static str> {
        (self.half_size.min_element() < 0.0
            || self.static_friction < 0.0
            || self.kinetic_friction < 0.0)
            .then_some("sizes and friction coefficients must be >= 0")
    }

    fn varies_ground_friction(&self) -> bool {
        true
    }

    fn ground_friction(&self, p: Vec3) -> Option<(f32, f32)> {
        let d = (Vec2::new(p.x, p.y) - self.center).abs();
        (d.x <= self.half_size.x && d.y <= self.half_size.y)
            .then_some((self.static_friction, self.kinetic_friction))
    }
}

/// A patch of kinetic friction `value` (static friction `value` plus the base model's gap).
fn patch(s: &FitSetting, (lo, hi): (Vec2, Vec2), value: f32) -> Effect {
    FrictionPatch {
        center: (lo + hi) * 0.5,
        half_size: (hi - lo) * 0.5,
        static_friction: value + s.friction_gap(),
        kinetic_friction: value,
    }
    .into()
}

/// The ground's kinetic friction everywhere, 0 to 0.6 (a table-wide patch).
#[derive(Debug)]
pub struct GroundFrictionFamily;

impl Family for GroundFrictionFamily {
    fn id(&self) -> &'static str {
        "ground_friction"
    }

    fn parameter(&self) -> (&'static str, &'static str) {
        ("friction", "")
    }

    fn complexity(&self) -> usize {
        1
    }

    fn range(&self, _: &FitSetting) -> Option<(f32, f32, bool)> {
        Some((0.0, 0.6, false))
    }

    fn effect(&self, s: &FitSetting, value: f32) -> Option<Effect> {
        Some(
            FrictionPatch {
                center: Vec2::ZERO,
                half_size: Vec2::splat(1e3),
                static_friction: value + s.friction_gap(),
                kinetic_friction: value,
            }
            .into(),
        )
    }

    fn regression(&self) -> Option<&'static str> {
        Some("ground_friction")
    }
}

/// The kinetic friction, 0 to 1, of a patch the diagnosis places inside the area the object slid
/// over (`FitSetting::region`): its edge and friction are fitted, its extent across the motion is
/// the slid-over area's.
#[derive(Debug)]
pub struct PatchFamily;

impl Family for PatchFamily {
    fn id(&self) -> &'static str {
        "friction_patch"
    }

    fn parameter(&self) -> (&'static str, &'static str) {
        ("friction", "")
    }

    fn complexity(&self) -> usize {
        5
    }

    fn range(&self, s: &FitSetting) -> Option<(f32, f32, bool)> {
        s.region.map(|_| (0.0, 1.0, false))
    }

    fn effect(&self, s: &FitSetting, value: f32) -> Option<Effect> {
        Some(patch(s, s.region?, value))
    }

    fn placed_in_slid_area(&self) -> bool {
        true
    }

    /// The placed patch.
    fn report(&self, _: &FitSetting, _: f32, fitted: Option<&Effect>) -> Vec<ReportValue> {
        let Some(Effect::FrictionPatch(p)) = fitted else {
            return Vec::new();
        };
        vec![
            ("center_x", p.center.x, "m"),
            ("center_y", p.center.y, "m"),
            ("half_size_x", p.half_size.x, "m"),
            ("half_size_y", p.half_size.y, "m"),
        ]
    }

    fn feature(&self) -> Feature {
        Feature::PositionAlongSlide
    }

    fn regression(&self) -> Option<&'static str> {
        Some("ground_friction")
    }
}

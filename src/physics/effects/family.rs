//! Diagnosis families: an effect with one physical parameter that `pegs diagnose` fits to a
//! recording by simulating open loop. Each effect's file says how its family is searched (the
//! parameter's range, the effect for a value, what else is refined with it, what the report adds,
//! which feature the corrective force depends on); the fitting itself (grid, golden section,
//! Gauss-Newton, bootstrap, judging on held-out windows) is `diagnose::refit`.

use super::{
    Effect, angular_damping, center_of_mass, constant_force, friction_patch, mass_scale,
    restitution, spring, viscous_drag,
};
use crate::physics::PhysicsConfig;
use crate::world::ShapeId;
use glam::{Vec2, Vec3};

/// What a family needs to know beyond its parameter: the object, the base physics, and the
/// directions and places the diagnosis found from the base model's prediction errors.
#[derive(Clone, Debug)]
pub struct FitSetting {
    pub object: String,
    pub shape: ShapeId,
    pub mass: f32,
    pub base: PhysicsConfig,
    /// Direction of the missing force in the plane (mean displacement error), if any.
    pub force_direction: Option<Vec3>,
    /// Anchor of a spring that would explain the displacement errors, if one would.
    pub anchor: Option<Vec3>,
    /// The table area (x, y box) the object's particles covered in the fitting windows; a
    /// friction patch is placed inside it.
    pub region: Option<(Vec2, Vec2)>,
    /// Largest centre-of-mass offset along body x and y that keeps every particle's mass positive.
    pub com_limit: [f32; 2],
}

impl FitSetting {
    /// The base physics with `family`'s effect at `value` added, if the family applies.
    pub fn physics(&self, family: &dyn Family, value: f32) -> Option<PhysicsConfig> {
        let mut p = self.base.clone();
        p.effects.push(family.effect(self, value)?);
        Some(p)
    }

    /// Ground static minus kinetic friction of the base model (a friction change keeps it).
    pub fn friction_gap(&self) -> f32 {
        self.base.ground.static_friction - self.base.ground.kinetic_friction
    }
}

/// The quantities a family refines together with its parameter (Gauss-Newton on the windows'
/// misses): their start values and finite-difference steps.
pub struct Refinement {
    pub start: Vec<f64>,
    pub steps: Vec<f64>,
}

/// A fixed quantity the report shows beside the fitted parameter: name, value, unit.
pub type ReportValue = (&'static str, f32, &'static str);

/// What the corrective force of a family depends on, for the report's scatter plot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Feature {
    /// Speed; force against the motion.
    Speed,
    /// Speed; force along the fitted direction.
    SpeedAlongDirection,
    /// Distance from the fitted anchor; force towards it.
    DistanceFromAnchor,
    /// Acceleration; force against it.
    Acceleration,
    /// Angular velocity about the vertical; torque about it.
    AngularVelocity,
    /// Position along the slide (the slid-over area's longer side); force against the motion.
    PositionAlongSlide,
}

/// One diagnosis family. Unit structs in the effects' files implement it; `FAMILIES` lists them.
pub trait Family: Sync + std::fmt::Debug {
    /// Unique among families (the centre of mass is two families, along body x and y).
    fn id(&self) -> &'static str;
    /// The effect's name in reports.
    fn name(&self) -> &'static str {
        self.id()
    }
    /// The fitted parameter's name and unit.
    fn parameter(&self) -> (&'static str, &'static str);
    /// How many quantities the family takes from the data: its parameter plus what its setting
    /// estimates (a direction, an anchor, a region, an axis). Between fits the held-out windows
    /// cannot tell apart, the simpler is named.
    fn complexity(&self) -> usize;
    /// The search range of the parameter (low, high, logarithmic), or None when the family does
    /// not apply (no direction, no anchor, no region).
    fn range(&self, s: &FitSetting) -> Option<(f32, f32, bool)>;
    /// The effect with parameter `value`.
    fn effect(&self, s: &FitSetting, value: f32) -> Option<Effect>;
    /// What is refined with the parameter, starting from the one-parameter fit `value`.
    fn refinement(&self, _s: &FitSetting, _value: f32) -> Option<Refinement> {
        None
    }
    /// The setting and parameter that refined quantities `p` stand for.
    fn refined(&self, _s: &FitSetting, _p: &[f64]) -> Option<(FitSetting, f32)> {
        None
    }
    /// Whether the diagnosis places the family's region inside the slid-over area before fitting.
    fn placed_in_slid_area(&self) -> bool {
        false
    }
    /// Fixed quantities the report shows with the fitted `value` (`fitted`: the effect as fitted).
    fn report(&self, _s: &FitSetting, _value: f32, _fitted: Option<&Effect>) -> Vec<ReportValue> {
        Vec::new()
    }
    fn feature(&self) -> Feature {
        Feature::Speed
    }
    /// The per-tick force regression's candidate of the same physics (`diagnose::candidates`).
    fn regression(&self) -> Option<&'static str> {
        None
    }
    /// Whether the parameter shows only as a ratio between colliding objects (a mass), so that of
    /// several objects only one may be named it.
    fn ratio_between_objects(&self) -> bool {
        false
    }
}

/// Every family, in the order the diagnosis fits them.
pub static FAMILIES: [&dyn Family; 10] = [
    &viscous_drag::DragFamily,
    &friction_patch::GroundFrictionFamily,
    &constant_force::ForceFamily,
    &spring::SpringFamily,
    &mass_scale::MassFamily,
    &angular_damping::AngularDampingFamily,
    &restitution::RestitutionFamily,
    &friction_patch::PatchFamily,
    &center_of_mass::ComFamily(0),
    &center_of_mass::ComFamily(1),
];

/// The family with id `id`.
pub fn family(id: &str) -> Option<&'static dyn Family> {
    FAMILIES.iter().copied().find(|f| f.id() == id)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn family_ids_are_unique_and_each_family_builds_an_effect_of_its_name() {
        let setting = FitSetting {
            object: "box".into(),
            shape: 0,
            mass: 0.3,
            base: PhysicsConfig::default(),
            force_direction: Some(Vec3::X),
            anchor: Some(Vec3::new(0.1, 0.2, 0.0)),
            region: Some((Vec2::ZERO, Vec2::ONE)),
            com_limit: [0.02, 0.01],
        };
        for (k, f) in FAMILIES.iter().enumerate() {
            assert!(FAMILIES[..k].iter().all(|g| g.id() != f.id()), "{}", f.id());
            let (lo, hi, _) = f.range(&setting).expect("every family applies here");
            assert!(lo < hi, "{}", f.id());
            let effect = f.effect(&setting, 0.5 * (lo + hi)).unwrap();
            effect.validate().unwrap();
            // Reports name effects by family; the physics by effect (a friction change is a
            // table-wide patch, a mass error a mass scale).
            let expected = match f.id() {
                "ground_friction" => "friction_patch",
                "mass_error" => "mass_scale",
                _ => f.name(),
            };
            assert_eq!(effect.name(), expected, "{}", f.id());
        }
        assert!(family("spring").is_some() && family("gravity").is_none());
    }
}

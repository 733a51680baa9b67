//! Extra physical effects: named terms with parameters that a scene may or may not have (forces,
//! mass distribution, local ground friction, ground impacts). The base model (gravity, ground,
//! contacts, shape matching) is in the solver.
//!
//! Each effect is defined in one file: its parameters (a serde struct, tagged by its `effect:`
//! name in configuration and model files), its physics (a `Term`: force, mass change, friction or
//! restitution) and its diagnosis families (`Family`: how `pegs diagnose` searches its
//! parameter). A new effect is one new file plus a line in `effects!` (and in `FAMILIES` if the
//! diagnosis should try it).
//!
//! This module binds effects to a world and evaluates them for the solver; it never steps.

mod angular_damping;
mod center_of_mass;
mod constant_force;
mod family;
mod friction_patch;
mod mass_scale;
mod restitution;
mod spring;
mod table_tilt;
mod viscous_drag;

pub use angular_damping::AngularDamping;
pub use center_of_mass::{CenterOfMassOffset, MAX_WEIGHT_RATIO, center_of_mass_reach};
pub use constant_force::ConstantForce;
pub use family::{FAMILIES, Family, Feature, FitSetting, Refinement, ReportValue, family};
pub use friction_patch::FrictionPatch;
pub use mass_scale::MassScale;
pub use restitution::Restitution;
pub use spring::Spring;
pub use table_tilt::{TableTilt, tangent_basis};
pub use viscous_drag::ViscousDrag;

use crate::world::{ShapeId, ShapeKind, World};
use anyhow::{Result, anyhow, bail};
use glam::Vec3;
use serde::{Deserialize, Serialize};

/// What an effect does to the physics. Every method but the parameter access has a default that
/// does nothing, so an effect implements only what it changes.
pub trait Term {
    /// The object it acts on; None for every dynamic object (or the table).
    fn object(&self) -> Option<&str> {
        None
    }
    /// The scalar parameters, by name, in a fixed order (vectors expand to `_x`, `_y`, `_z`).
    fn parameters(&self) -> Vec<(&'static str, f32)>;
    /// One scalar parameter by the name `parameters` reports.
    fn parameter_mut(&mut self, name: &str) -> Option<&mut f32>;
    /// Why the parameters make no physical sense (they are finite here), if they do not.
    fn check(&self) -> Option<&'static str> {
        None
    }
    /// A particle of `shapes` the effect acts through, chosen when it is bound to a world.
    fn attachment(&self, _world: &World, _shapes: &[ShapeId]) -> Option<usize> {
        None
    }
    /// Change the inverse masses of `shapes` (the world's nominal ones, or those of earlier
    /// effects).
    fn scale_inv_mass(
        &self,
        _world: &World,
        _shapes: &[ShapeId],
        _inv_mass: &mut [f32],
    ) -> Result<()> {
        Ok(())
    }
    /// Add this effect's accelerations (m/s^2) of the particles of `shapes` to `accel`.
    fn accelerate(&self, _at: &Forces, _bound: &Bound, _accel: &mut [Vec3]) {}
    /// Ground restitution of `shapes`, if the effect sets one.
    fn restitution(&self) -> Option<f32> {
        None
    }
    /// Whether the ground friction depends on where a particle touches it.
    fn varies_ground_friction(&self) -> bool {
        false
    }
    /// Ground friction (static, kinetic) at `p`, if the effect sets it there.
    fn ground_friction(&self, _p: Vec3) -> Option<(f32, f32)> {
        None
    }
}

/// The registry: each effect's configuration name and its parameter struct.
macro_rules! effects {
    ($($name:literal => $variant:ident),* $(,)?) => {
        /// One extra physical effect, tagged by its name (`effect: viscous_drag`).
        #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
        #[serde(tag = "effect")]
        pub enum Effect {
            $(#[serde(rename = $name)] $variant($variant),)*
        }

        impl Effect {
            /// The name configuration and model files use.
            pub fn name(&self) -> &'static str {
                match self { $(Effect::$variant(_) => $name,)* }
            }

            fn term(&self) -> &dyn Term {
                match self { $(Effect::$variant(e) => e,)* }
            }

            fn term_mut(&mut self) -> &mut dyn Term {
                match self { $(Effect::$variant(e) => e,)* }
            }
        }

        $(impl From<$variant> for Effect {
            fn from(e: $variant) -> Self {
                Effect::$variant(e)
            }
        })*
    };
}

effects! {
    "viscous_drag" => ViscousDrag,
    "angular_damping" => AngularDamping,
    "constant_force" => ConstantForce,
    "restitution" => Restitution,
    "table_tilt" => TableTilt,
    "mass_scale" => MassScale,
    "center_of_mass_offset" => CenterOfMassOffset,
    "friction_patch" => FrictionPatch,
    "spring" => Spring,
}

impl Effect {
    /// The object this effect acts on, if it names one.
    pub fn object(&self) -> Option<&str> {
        self.term().object()
    }

    /// The scalar parameters, by name, in a fixed order (vectors expand to `_x`, `_y`, `_z`).
    pub fn parameters(&self) -> Vec<(&'static str, f32)> {
        self.term().parameters()
    }

    /// Set one scalar parameter by the name `parameters()` reports.
    pub fn set_parameter(&mut self, name: &str, value: f32) -> Result<()> {
        let effect_name = self.name();
        let slot = self
            .term_mut()
            .parameter_mut(name)
            .ok_or_else(|| anyhow!("effect {effect_name} has no parameter {name}"))?;
        *slot = value;
        self.validate()
    }

    pub fn validate(&self) -> Result<()> {
        let bad = self.parameters().into_iter().find(|(_, v)| !v.is_finite());
        if let Some((p, v)) = bad {
            bail!(
                "effect {}: parameter {p} must be finite, got {v}",
                self.name()
            );
        }
        match self.term().check() {
            Some(why) => bail!("effect {}: {why}", self.name()),
            None => Ok(()),
        }
    }
}

/// A `Vec3` parameter's component named `{prefix}_x`, `_y` or `_z`.
fn vec3_slot<'a>(v: &'a mut Vec3, name: &str, prefix: &str) -> Option<&'a mut f32> {
    match name.strip_prefix(prefix)? {
        "_x" => Some(&mut v.x),
        "_y" => Some(&mut v.y),
        "_z" => Some(&mut v.z),
        _ => None,
    }
}

/// The names and values of a `Vec3` parameter's components.
fn vec3_parameters(prefix: &'static [&'static str; 3], v: Vec3) -> [(&'static str, f32); 3] {
    [(prefix[0], v.x), (prefix[1], v.y), (prefix[2], v.z)]
}

/// Effects bound to a particular world: object names resolved to shapes, attachments to
/// particles. Built by the solver whenever the world's layout or the effects change.
pub struct EffectModel {
    terms: Vec<Bound>,
}

/// One effect bound to a world.
pub struct Bound {
    effect: Effect,
    /// The shapes it acts on.
    pub shapes: Vec<ShapeId>,
    /// The particle it acts through (a spring's attachment), if any.
    pub particle: Option<usize>,
}

/// Per-shape quantities the force terms need, computed once per substep.
pub struct ShapeState<'a> {
    pub mass: &'a [f32],
    pub velocity: &'a [Vec3],
}

/// What a force term may read: the world, effective inverse masses, per-shape mass and velocity,
/// gravity and the ground normal.
pub struct Forces<'a> {
    pub world: &'a World,
    pub inv_mass: &'a [f32],
    pub shape: &'a ShapeState<'a>,
    pub gravity: Vec3,
    pub ground_normal: Vec3,
}

impl EffectModel {
    pub fn bind(effects: &[Effect], world: &World) -> Result<Self> {
        let mut terms = Vec::with_capacity(effects.len());
        for effect in effects {
            effect.validate()?;
            let shapes: Vec<ShapeId> = match effect.object() {
                Some(name) => {
                    let s = world.shape_id(name).ok_or_else(|| {
                        anyhow!(
                            "effect {}: no object named '{name}' in the scene",
                            effect.name()
                        )
                    })?;
                    if !matches!(
                        world.shapes.kind[s as usize],
                        ShapeKind::Rigid | ShapeKind::Rope
                    ) {
                        bail!("effect {}: object '{name}' is not dynamic", effect.name());
                    }
                    vec![s]
                }
                None => world.shapes.dynamic_ids().collect(),
            };
            let particle = effect.term().attachment(world, &shapes);
            terms.push(Bound {
                effect: effect.clone(),
                shapes,
                particle,
            });
        }
        Ok(Self { terms })
    }

    pub fn is_empty(&self) -> bool {
        self.terms.is_empty()
    }

    /// Inverse masses with mass effects applied to the world's nominal ones.
    pub fn effective_inv_mass(&self, world: &World) -> Result<Vec<f32>> {
        let mut inv_mass = world.particles.inv_mass.clone();
        for t in &self.terms {
            t.effect
                .term()
                .scale_inv_mass(world, &t.shapes, &mut inv_mass)?;
        }
        Ok(inv_mass)
    }

    /// Add the effects' accelerations (m/s^2) of every particle to `accel`.
    pub fn add_accelerations(
        &self,
        world: &World,
        inv_mass: &[f32],
        shape: &ShapeState,
        gravity: Vec3,
        ground_normal: Vec3,
        accel: &mut [Vec3],
    ) {
        let at = Forces {
            world,
            inv_mass,
            shape,
            gravity,
            ground_normal,
        };
        for t in &self.terms {
            t.effect.term().accelerate(&at, t, accel);
        }
    }

    /// Each of `shapes` shapes' ground restitution (0 where no effect gives one; the last wins).
    pub fn restitution(&self, shapes: usize) -> Vec<f32> {
        let mut e = vec![0.0; shapes];
        for t in &self.terms {
            if let Some(coefficient) = t.effect.term().restitution() {
                t.shapes.iter().for_each(|&s| e[s as usize] = coefficient);
            }
        }
        e
    }

    pub fn has_friction_patches(&self) -> bool {
        self.terms
            .iter()
            .any(|t| t.effect.term().varies_ground_friction())
    }

    /// Ground friction coefficients at `p`: the last effect that sets them there, else `base`.
    pub fn ground_friction(&self, p: Vec3, base: (f32, f32)) -> (f32, f32) {
        self.terms
            .iter()
            .rev()
            .find_map(|t| t.effect.term().ground_friction(p))
            .unwrap_or(base)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Pose;
    use crate::world::{WorldBuilder, box_lattice};

    pub(super) fn one_box() -> World {
        let mut b = WorldBuilder::new();
        b.add_rigid(
            "box",
            &box_lattice(Vec3::new(0.05, 0.04, 0.02), 0.01),
            0.005,
            0.002,
            Pose::IDENTITY,
            Vec3::ONE,
        );
        b.build()
    }

    #[test]
    fn parameters_round_trip_by_name_and_unknown_names_fail() {
        let mut e: Effect = Spring {
            object: "box".into(),
            point: Vec3::ZERO,
            anchor: Vec3::ONE,
            stiffness: 3.0,
            rest_length: 0.1,
            damping: 0.0,
            tether: true,
        }
        .into();
        for (name, _) in e.parameters() {
            let mut f = e.clone();
            f.set_parameter(name, 0.25).unwrap();
            assert_eq!(
                f.parameters().iter().find(|(n, _)| *n == name).unwrap().1,
                0.25,
                "{name}"
            );
        }
        assert!(e.set_parameter("mass", 1.0).is_err());
        assert!(
            e.set_parameter("stiffness", -1.0).is_err(),
            "validation runs after setting"
        );
    }

    #[test]
    fn binding_reports_unknown_objects() {
        let w = one_box();
        let mass = MassScale {
            object: "mug".into(),
            factor: 2.0,
        };
        let err = EffectModel::bind(&[mass.into()], &w).err().unwrap();
        assert!(err.to_string().contains("mug"));
    }

    #[test]
    fn every_effect_is_read_and_written_by_its_name_and_unknown_fields_are_refused() {
        let effects: Vec<Effect> = serde_yaml_ng::from_str(
            "- {effect: viscous_drag, object: box, coefficient: 0.5}\n\
             - {effect: angular_damping, coefficient: 0.2}\n\
             - {effect: constant_force, force: [0.1, 0, 0]}\n\
             - {effect: restitution, coefficient: 0.4}\n\
             - {effect: table_tilt, angle: 0.01, azimuth: 0}\n\
             - {effect: mass_scale, object: box, factor: 2}\n\
             - {effect: center_of_mass_offset, object: box, offset: [0.01, 0, 0]}\n\
             - {effect: friction_patch, center: [0, 0], half_size: [1, 1], static_friction: 0.2, kinetic_friction: 0.1}\n\
             - {effect: spring, object: box, point: [0, 0, 0], anchor: [1, 0, 0], stiffness: 2}\n",
        )
        .unwrap();
        let names: Vec<&str> = effects.iter().map(|e| e.name()).collect();
        assert_eq!(
            names,
            [
                "viscous_drag",
                "angular_damping",
                "constant_force",
                "restitution",
                "table_tilt",
                "mass_scale",
                "center_of_mass_offset",
                "friction_patch",
                "spring"
            ]
        );
        for e in &effects {
            let text = serde_yaml_ng::to_string(e).unwrap();
            assert!(
                text.starts_with(&format!("effect: {}\n", e.name())),
                "{text}"
            );
            assert_eq!(&serde_yaml_ng::from_str::<Effect>(&text).unwrap(), e);
        }
        let unknown = "{effect: viscous_drag, coefficient: 0.5, mass: 1}";
        assert!(serde_yaml_ng::from_str::<Effect>(unknown).is_err());
        assert!(serde_yaml_ng::from_str::<Effect>("{effect: levitation}").is_err());
    }
}

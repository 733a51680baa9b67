//! The `physics` section of the configuration: the solver's numbers (tick, substeps, iterations,
//! damping, relaxation), the ground plane and particle contacts, and the named extra effects.
//! Validated here, beside the solver it configures.

use super::Effect;
use anyhow::{Result, bail};
use glam::Vec3;
use serde::{Deserialize, Serialize};

/// Position-based dynamics (spec section 2, "Predict").
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PhysicsConfig {
    /// Length of one tick in seconds.
    pub dt: f32,
    pub substeps: u32,
    /// Jacobi iterations per substep.
    pub iterations: u32,
    /// Gravity in m/s^2 (world z up). Zero it to ablate the gravity prior.
    pub gravity: Vec3,
    /// Velocities are multiplied by this after every tick (empirical, < 1; 1 disables it).
    pub damping: f32,
    /// Over-relaxation of averaged Jacobi corrections (1 = plain averaging).
    pub relaxation: f32,
    /// Fraction of the shape-matching correction applied per iteration (1 = rigid).
    pub shape_stiffness: f32,
    /// Weight (times its mass) in shape matching of a particle pinned by something immovable in
    /// the current sweep: touching a kinematic or static body, or held by static friction on the
    /// ground. The rigid body then moves with its contact points, as a rigid body does, instead of
    /// the averaging over all its particles diluting the contact (1 disables it).
    pub pin_weight: f32,
    /// Which ground contacts held by static friction are pinned in shape matching.
    pub ground_pins: GroundPins,
    /// Gauss-Seidel sweeps over distance constraints (ropes) per Jacobi iteration, alternating
    /// direction. A 50-link rope swinging from one end stretched by 2.0 % with 1 sweep, 0.5 % with 4.
    pub distance_sweeps: u32,
    pub ground: GroundConfig,
    pub collisions: CollisionConfig,
    /// Extra physical effects, named and parameterised (see `physics::effects`).
    pub effects: Vec<Effect>,
}

impl Default for PhysicsConfig {
    fn default() -> Self {
        Self {
            dt: 1.0 / 30.0,
            substeps: 20,
            iterations: 4,
            gravity: Vec3::new(0.0, 0.0, -9.81),
            damping: 0.99,
            relaxation: 1.0,
            shape_stiffness: 1.0,
            pin_weight: 100.0,
            ground_pins: GroundPins::EveryStickingContact,
            distance_sweeps: 4,
            ground: GroundConfig::default(),
            collisions: CollisionConfig::default(),
            effects: Vec::new(),
        }
    }
}

/// Which of a rigid shape's ground contacts held by static friction weigh `pin_weight` in shape
/// matching.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GroundPins {
    /// Every sticking contact, whatever the shape's other contacts do (the default, which the
    /// tracker is tuned with). A sticking contact near the pivot of a spinning or pushed-and-
    /// turning shape then outweighs the sliding contacts' friction: a spin stops after twice the
    /// angle Coulomb friction allows.
    EveryStickingContact,
    /// Only when static friction holds every ground contact of the shape (it sticks as a whole);
    /// where some slide, none is pinned, and a spin stops where Coulomb friction stops it.
    WholeShape,
}

/// The ground plane `normal . x = height` with Coulomb friction.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GroundConfig {
    pub enabled: bool,
    /// Unit normal pointing out of the table (normalised on load).
    pub normal: Vec3,
    /// Signed distance of the plane from the origin along `normal`, metres.
    pub height: f32,
    pub static_friction: f32,
    pub kinetic_friction: f32,
    /// Where a rigid object bears on the plane, hence how much friction resists its turning.
    pub support: GroundSupport,
}

impl Default for GroundConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            normal: Vec3::Z,
            height: 0.0,
            static_friction: 0.5,
            kinetic_friction: 0.4,
            support: GroundSupport::Face,
        }
    }
}

/// Where a rigid object resting on the ground bears its weight. A rigid solid on a rigid plane is
/// statically indeterminate, so this is a modelling choice; it leaves sliding friction as it is
/// and sets the friction torque against turning (for a long bar, corners give about twice the
/// face's).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GroundSupport {
    /// Every particle of the lowest layer bears alike: the weight spread over the face (the
    /// default, which the tracker is tuned with).
    Face,
    /// Only the vertices of the footprint's support polygon bear (a box's four corners), as a
    /// rigid box on a rigid plane does in MuJoCo; the rest of the face stands `SUPPORT_RELIEF`
    /// clear (`ground::bearing_loads`).
    Corners,
}

/// Particle-particle contacts between different shapes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CollisionConfig {
    pub enabled: bool,
    pub static_friction: f32,
    pub kinetic_friction: f32,
    /// Extra search distance for contact candidates, as a fraction of the largest particle radius.
    pub margin: f32,
}

impl Default for CollisionConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            static_friction: 0.3,
            kinetic_friction: 0.25,
            margin: 0.5,
        }
    }
}

impl PhysicsConfig {
    /// Reject values that would make the solver meaningless instead of silently misbehaving.
    pub fn validate(&self) -> Result<()> {
        if !(self.dt.is_finite() && self.dt > 0.0) {
            bail!(
                "physics.dt must be a positive number of seconds, got {}",
                self.dt
            );
        }
        if self.substeps == 0 || self.iterations == 0 || self.distance_sweeps == 0 {
            bail!(
                "physics.substeps, physics.iterations and physics.distance_sweeps must be at least 1"
            );
        }
        if !self.gravity.is_finite() {
            bail!("physics.gravity must be finite");
        }
        if !(0.0..=1.0).contains(&self.damping) {
            bail!("physics.damping must be in [0, 1], got {}", self.damping);
        }
        if !(self.relaxation > 0.0 && self.relaxation < 2.0) {
            bail!(
                "physics.relaxation must be in (0, 2), got {}",
                self.relaxation
            );
        }
        if !(self.shape_stiffness > 0.0 && self.shape_stiffness <= 1.0) {
            bail!(
                "physics.shape_stiffness must be in (0, 1], got {}",
                self.shape_stiffness
            );
        }
        if !(self.pin_weight.is_finite() && self.pin_weight >= 1.0) {
            bail!("physics.pin_weight must be >= 1, got {}", self.pin_weight);
        }
        if self.ground.normal.length() < 1e-6 || !self.ground.normal.is_finite() {
            bail!("physics.ground.normal must be a non-zero vector");
        }
        for (name, mu) in [
            ("ground.static_friction", self.ground.static_friction),
            ("ground.kinetic_friction", self.ground.kinetic_friction),
            (
                "collisions.static_friction",
                self.collisions.static_friction,
            ),
            (
                "collisions.kinetic_friction",
                self.collisions.kinetic_friction,
            ),
        ] {
            if !(mu.is_finite() && mu >= 0.0) {
                bail!("physics.{name} must be >= 0, got {mu}");
            }
        }
        for e in &self.effects {
            e.validate()?;
        }
        Ok(())
    }
}

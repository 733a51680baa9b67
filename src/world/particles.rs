//! Particle state: geometry and physics of the world, one entry per particle.

use super::ShapeId;
use glam::Vec3;
use serde::{Deserialize, Serialize};

/// How a particle moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Phase {
    /// Moved by the physics (objects, ropes).
    Dynamic,
    /// Follows a prescribed pose (robot links); pushes others, is never pushed.
    Kinematic,
    /// Never moves (fixtures).
    Static,
}

/// Structure of arrays over all particles. All vectors have the same length.
#[derive(Clone, Debug, Default)]
pub struct Particles {
    pub position: Vec<Vec3>,
    pub velocity: Vec<Vec3>,
    /// 1 / mass in 1/kg; zero for kinematic and static particles. Mass is also the visual inertia.
    pub inv_mass: Vec<f32>,
    pub radius: Vec<f32>,
    pub shape: Vec<ShapeId>,
    pub phase: Vec<Phase>,
    /// Rest position in the owning shape's body frame (rigid, kinematic and static shapes).
    pub rest: Vec<Vec3>,
    /// External force (N) acting during the coming tick, e.g. visual forces; cleared after each tick.
    pub external_force: Vec<Vec3>,
}

impl Particles {
    pub fn len(&self) -> usize {
        self.position.len()
    }

    pub fn is_empty(&self) -> bool {
        self.position.is_empty()
    }

    #[allow(clippy::too_many_arguments)]
    pub fn push(
        &mut self,
        position: Vec3,
        inv_mass: f32,
        radius: f32,
        shape: ShapeId,
        phase: Phase,
        rest: Vec3,
    ) -> usize {
        self.position.push(position);
        self.velocity.push(Vec3::ZERO);
        self.inv_mass.push(if phase == Phase::Dynamic {
            inv_mass
        } else {
            0.0
        });
        self.radius.push(radius);
        self.shape.push(shape);
        self.phase.push(phase);
        self.rest.push(rest);
        self.external_force.push(Vec3::ZERO);
        self.position.len() - 1
    }

    /// The mass (kg) a force on particle `i` acts through: 0 for a fixed particle (no force
    /// moves it), where `mass` is infinite.
    pub fn movable_mass(&self, i: usize) -> f32 {
        if self.inv_mass[i] > 0.0 {
            1.0 / self.inv_mass[i]
        } else {
            0.0
        }
    }

    pub fn mass(&self, i: usize) -> f32 {
        if self.inv_mass[i] > 0.0 {
            1.0 / self.inv_mass[i]
        } else {
            f32::INFINITY
        }
    }
}

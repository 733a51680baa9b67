//! 3-D Gaussians: the appearance of the world. Each object Gaussian is bonded to a parent particle
//! and stored in that particle's frame; static-scene Gaussians have no parent and live in the world.

use glam::{Quat, Vec3};

/// Parent index of a Gaussian that is not bonded to any particle.
pub const NO_PARENT: u32 = u32::MAX;

/// Structure of arrays over Gaussians.
#[derive(Clone, Debug, Default)]
pub struct Gaussians {
    /// Parent particle, or `NO_PARENT`.
    pub parent: Vec<u32>,
    /// Mean in the parent particle's frame (world frame without parent), metres.
    pub local_mean: Vec<Vec3>,
    /// Rotation in the parent particle's frame.
    pub local_rotation: Vec<Quat>,
    /// Standard deviations along the Gaussian's own axes, metres.
    pub scale: Vec<Vec3>,
    /// Opacity in (0, 1).
    pub opacity: Vec<f32>,
    /// Linear RGB in [0, 1].
    pub colour: Vec<Vec3>,
}

impl Gaussians {
    pub fn len(&self) -> usize {
        self.parent.len()
    }

    pub fn is_empty(&self) -> bool {
        self.parent.is_empty()
    }

    pub fn push(
        &mut self,
        parent: u32,
        local_mean: Vec3,
        local_rotation: Quat,
        scale: Vec3,
        opacity: f32,
        colour: Vec3,
    ) -> usize {
        self.parent.push(parent);
        self.local_mean.push(local_mean);
        self.local_rotation.push(local_rotation);
        self.scale.push(scale);
        self.opacity.push(opacity);
        self.colour.push(colour);
        self.parent.len() - 1
    }
}

//! The world model as plain data: particles, shapes, Gaussians and rope constraints, stored as
//! structures of arrays (f32). This module owns the layout and simple queries; it never steps
//! physics (see `physics`) nor renders (see `render`).

mod builder;
mod constraints;
mod gaussians;
mod lattice;
mod particles;
mod shapes;

pub use builder::{BodyGaussian, ObjectModel, WorldBuilder};
pub use constraints::DistanceConstraints;
pub use gaussians::{Gaussians, NO_PARENT};
pub use lattice::{box_lattice, cylinder_lattice, t_block_lattice};
pub use particles::{Particles, Phase};
pub use shapes::{Primitive, ShapeId, ShapeKind, Shapes, Solid};

use crate::math::Pose;
use glam::{Quat, Vec3};

/// Everything the simulation knows about the scene at one instant.
#[derive(Clone, Debug, Default)]
pub struct World {
    pub particles: Particles,
    pub shapes: Shapes,
    pub gaussians: Gaussians,
    /// Distance constraints (rope segments, rope bending, attachments).
    pub distance: DistanceConstraints,
    /// Simulation time in seconds.
    pub time: f64,
}

impl World {
    pub fn shape_id(&self, name: &str) -> Option<ShapeId> {
        self.shapes
            .name
            .iter()
            .position(|n| n == name)
            .map(|i| i as ShapeId)
    }

    /// Orientation of a particle's frame: its shape's rotation for rigid and kinematic shapes,
    /// the world frame otherwise. Gaussians bonded to the particle rotate with it.
    pub fn particle_frame_rotation(&self, particle: usize) -> Quat {
        let s = self.particles.shape[particle] as usize;
        match self.shapes.kind[s] {
            ShapeKind::Rigid | ShapeKind::Kinematic | ShapeKind::Static => {
                self.shapes.pose[s].rotation
            }
            ShapeKind::Rope => Quat::IDENTITY,
        }
    }

    /// Pose of a particle's frame in the world.
    pub fn particle_frame(&self, particle: usize) -> Pose {
        Pose::new(
            self.particles.position[particle],
            self.particle_frame_rotation(particle),
        )
    }

    /// World-space means and rotations of all Gaussians (bonded ones follow their parent's frame).
    pub fn gaussian_world_means(&self) -> (Vec<Vec3>, Vec<Quat>) {
        (0..self.gaussians.len())
            .map(|i| self.gaussian_world_pose(i))
            .unzip()
    }

    /// World-space mean and rotation of Gaussian `i` (a bonded one follows its parent's frame).
    pub fn gaussian_world_pose(&self, i: usize) -> (Vec3, Quat) {
        let g = &self.gaussians;
        match g.parent[i] {
            NO_PARENT => (g.local_mean[i], g.local_rotation[i]),
            parent => {
                let frame = self.particle_frame(parent as usize);
                (
                    frame.transform_point(g.local_mean[i]),
                    (frame.rotation * g.local_rotation[i]).normalize(),
                )
            }
        }
    }

    /// Bond world-space Gaussians to the closest particle among `candidates`, storing their mean
    /// and rotation in that particle's frame (the paper's last initialisation step).
    pub fn bond_gaussians_to_closest(
        &mut self,
        gaussian_ids: std::ops::Range<usize>,
        candidates: &[u32],
    ) {
        if candidates.is_empty() {
            return;
        }
        for gi in gaussian_ids {
            let world_mean = self.gaussians.local_mean[gi];
            let world_rot = self.gaussians.local_rotation[gi];
            let mut best = candidates[0];
            let mut best_d = f32::INFINITY;
            for &p in candidates {
                let d = self.particles.position[p as usize].distance_squared(world_mean);
                if d < best_d {
                    best_d = d;
                    best = p;
                }
            }
            let inv = self.particle_frame(best as usize).inverse();
            self.gaussians.parent[gi] = best;
            self.gaussians.local_mean[gi] = inv.transform_point(world_mean);
            self.gaussians.local_rotation[gi] = (inv.rotation * world_rot).normalize();
        }
    }

    /// Total linear momentum of the dynamic particles, using the world's nominal masses.
    pub fn linear_momentum(&self) -> Vec3 {
        let p = &self.particles;
        (0..p.len())
            .filter(|&i| p.phase[i] == Phase::Dynamic && p.inv_mass[i] > 0.0)
            .map(|i| p.velocity[i] / p.inv_mass[i])
            .sum()
    }

    /// Mass-weighted centroid of a shape's particles.
    pub fn shape_centroid(&self, shape: ShapeId) -> Vec3 {
        mass_weighted_mean(
            self.shapes.range(shape),
            &self.particles.position,
            &self.particles.inv_mass,
        )
    }

    /// Mass-weighted mean velocity of a shape's particles.
    pub fn shape_velocity(&self, shape: ShapeId) -> Vec3 {
        mass_weighted_mean(
            self.shapes.range(shape),
            &self.particles.velocity,
            &self.particles.inv_mass,
        )
    }

    /// Move a shape rigidly by `motion` (applied in the world frame) and bring it to rest.
    pub fn move_shape(&mut self, shape: ShapeId, motion: Pose) {
        for i in self.shapes.range(shape) {
            self.particles.position[i] = motion.transform_point(self.particles.position[i]);
            self.particles.velocity[i] = Vec3::ZERO;
        }
        let s = shape as usize;
        self.shapes.pose[s] = motion.mul(&self.shapes.pose[s]);
        self.shapes.target[s] = motion.mul(&self.shapes.target[s]);
    }

    /// Indices of the Gaussians bonded to `shape`'s particles.
    pub fn gaussians_of(&self, shape: ShapeId) -> Vec<usize> {
        let range = self.shapes.range(shape);
        (0..self.gaussians.len())
            .filter(|&i| {
                self.gaussians.parent[i] != NO_PARENT
                    && range.contains(&(self.gaussians.parent[i] as usize))
            })
            .collect()
    }

    /// Largest distance of a rigid shape's particles from where its current pose puts their rest
    /// positions: zero for a perfectly rigid body.
    pub fn rigid_deviation(&self, shape: ShapeId) -> f32 {
        let pose = self.shapes.pose[shape as usize];
        self.shapes
            .range(shape)
            .map(|i| {
                (pose.transform_point(self.particles.rest[i]) - self.particles.position[i]).length()
            })
            .fold(0.0, f32::max)
    }
}

/// Mean of `values` over `range` weighted by mass (1 / `inv_mass`); particles without mass
/// (kinematic, static) count with weight 1 so immovable shapes still have a centroid.
pub fn mass_weighted_mean(
    range: std::ops::Range<usize>,
    values: &[Vec3],
    inv_mass: &[f32],
) -> Vec3 {
    let mut sum = Vec3::ZERO;
    let mut weight = 0.0;
    for i in range {
        let m = if inv_mass[i] > 0.0 {
            1.0 / inv_mass[i]
        } else {
            1.0
        };
        sum += m * values[i];
        weight += m;
    }
    if weight > 0.0 {
        sum / weight
    } else {
        Vec3::ZERO
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{WorldBuilder, box_lattice};

    #[test]
    fn bonded_gaussians_follow_their_shape_rigidly() {
        let mut b = WorldBuilder::new();
        let pose = Pose::new(Vec3::new(0.0, 0.0, 0.1), Quat::from_rotation_z(0.3));
        let s = b.add_rigid(
            "box",
            &box_lattice(Vec3::splat(0.02), 0.01),
            0.005,
            0.001,
            pose,
            Vec3::ONE,
        );
        let mut w = b.build();
        // A free Gaussian placed off any particle, then bonded to the box.
        let gi = w.gaussians.push(
            NO_PARENT,
            Vec3::new(0.013, -0.004, 0.11),
            Quat::from_rotation_x(0.2),
            Vec3::splat(0.003),
            0.9,
            Vec3::X,
        );
        let candidates: Vec<u32> = w.shapes.range(s).map(|i| i as u32).collect();
        w.bond_gaussians_to_closest(gi..gi + 1, &candidates);
        let (m0, r0) = w.gaussian_world_means();
        assert!(
            (m0[gi] - Vec3::new(0.013, -0.004, 0.11)).length() < 1e-6,
            "bonding must not move the Gaussian"
        );
        assert!(crate::math::rotation_angle_between(r0[gi], Quat::from_rotation_x(0.2)) < 1e-3);

        // Move the shape rigidly: the Gaussian must move with the same transform.
        let motion = Pose::new(Vec3::new(0.2, -0.1, 0.05), Quat::from_rotation_y(0.7));
        for i in w.shapes.range(s) {
            w.particles.position[i] = motion.transform_point(w.particles.position[i]);
        }
        w.shapes.pose[s as usize] = motion.mul(&w.shapes.pose[s as usize]);
        let (m1, r1) = w.gaussian_world_means();
        assert!((m1[gi] - motion.transform_point(m0[gi])).length() < 1e-5);
        assert!(crate::math::rotation_angle_between(r1[gi], motion.rotation * r0[gi]) < 1e-3);
    }
}

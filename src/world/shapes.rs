//! Shapes group particles into objects: rigid shape-matching groups, rope chains, kinematic robot
//! links and static fixtures. A shape's particles are one contiguous index range.

use super::Particles;
use crate::math::Pose;
use glam::{Mat3, Vec3};
use serde::{Deserialize, Serialize};
use std::ops::Range;

pub type ShapeId = u32;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ShapeKind {
    /// Shape matching keeps the particles at their rest configuration (one rigid object).
    Rigid,
    /// A chain held by distance and bending constraints.
    Rope,
    /// Follows a prescribed pose (robot link, pusher).
    Kinematic,
    /// Never moves.
    Static,
}

/// Structure of arrays over shapes.
#[derive(Clone, Debug, Default)]
pub struct Shapes {
    pub name: Vec<String>,
    pub kind: Vec<ShapeKind>,
    pub first_particle: Vec<u32>,
    pub particle_count: Vec<u32>,
    /// Body frame to world. Rigid: from shape matching; kinematic: the prescribed pose;
    /// rope: centroid with identity rotation.
    pub pose: Vec<Pose>,
    /// Kinematic shapes: the pose to reach at the end of the coming tick.
    pub target: Vec<Pose>,
    /// Nominal mass, kg (zero for kinematic and static shapes).
    pub mass: Vec<f32>,
    /// Centre of mass in the body frame (rest positions), m.
    pub center_of_mass: Vec<Vec3>,
    /// Inertia tensor about the centre of mass in the body frame, kg m^2 (particles as solid spheres).
    pub inertia: Vec<Mat3>,
    /// Kinematic shapes: the exact geometry their particles sample, in the body frame, where it
    /// is known (a URDF's primitives); contacts then meet it instead of the particles. Empty: the
    /// particles.
    pub primitives: Vec<Vec<Primitive>>,
    /// Kinematic shapes: how far the shape gives way per newton it pushes objects with, m/N (a
    /// robot under impedance control; `physics::yielding`). Zero: rigid.
    pub compliance: Vec<f32>,
}

/// A solid of known geometry at `origin` in its shape's body frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Primitive {
    pub origin: Pose,
    pub solid: Solid,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Solid {
    Box {
        half: Vec3,
    },
    /// Along the local z axis.
    Cylinder {
        radius: f32,
        half_length: f32,
    },
    Capsule {
        radius: f32,
        half_length: f32,
    },
    Sphere {
        radius: f32,
    },
}

impl Shapes {
    pub fn len(&self) -> usize {
        self.name.len()
    }

    pub fn is_empty(&self) -> bool {
        self.name.is_empty()
    }

    pub fn range(&self, s: ShapeId) -> Range<usize> {
        let first = self.first_particle[s as usize] as usize;
        first..first + self.particle_count[s as usize] as usize
    }

    pub fn push(
        &mut self,
        name: &str,
        kind: ShapeKind,
        particles: Range<usize>,
        pose: Pose,
    ) -> ShapeId {
        self.name.push(name.to_string());
        self.kind.push(kind);
        self.first_particle.push(particles.start as u32);
        self.particle_count
            .push((particles.end - particles.start) as u32);
        self.pose.push(pose);
        self.target.push(pose);
        self.mass.push(0.0);
        self.center_of_mass.push(Vec3::ZERO);
        self.inertia.push(Mat3::ZERO);
        self.primitives.push(Vec::new());
        self.compliance.push(0.0);
        (self.name.len() - 1) as ShapeId
    }

    /// Recompute mass, centre of mass and inertia of shape `s` from its particles' nominal masses
    /// and rest positions (ropes: from current positions, as they have no rest frame).
    pub fn update_mass_properties(&mut self, s: ShapeId, particles: &Particles) {
        let range = self.range(s);
        let point = |i: usize| {
            if self.kind[s as usize] == ShapeKind::Rope {
                particles.position[i]
            } else {
                particles.rest[i]
            }
        };
        let masses: Vec<f32> = range
            .clone()
            .map(|i| {
                if particles.inv_mass[i] > 0.0 {
                    1.0 / particles.inv_mass[i]
                } else {
                    0.0
                }
            })
            .collect();
        let mass: f32 = masses.iter().sum();
        let com = if mass > 0.0 {
            range
                .clone()
                .zip(&masses)
                .map(|(i, m)| *m * point(i))
                .sum::<Vec3>()
                / mass
        } else {
            Vec3::ZERO
        };
        let mut inertia = Mat3::ZERO;
        for (i, m) in range.zip(&masses) {
            let r = point(i) - com;
            let sphere = 0.4 * m * particles.radius[i] * particles.radius[i];
            // m (|r|^2 I - r r^T) for the point, plus the sphere's own inertia.
            inertia += Mat3::from_diagonal(Vec3::splat(m * r.length_squared() + sphere))
                - Mat3::from_cols(r * r.x, r * r.y, r * r.z) * *m;
        }
        self.mass[s as usize] = mass;
        self.center_of_mass[s as usize] = com;
        self.inertia[s as usize] = inertia;
    }

    /// Ids of the shapes that physics moves (rigid objects and ropes).
    pub fn dynamic_ids(&self) -> impl Iterator<Item = ShapeId> + '_ {
        (0..self.len() as ShapeId)
            .filter(|&s| matches!(self.kind[s as usize], ShapeKind::Rigid | ShapeKind::Rope))
    }
}

#[cfg(test)]
mod tests {
    use crate::math::Pose;
    use crate::world::{WorldBuilder, box_lattice};
    use glam::Vec3;

    #[test]
    fn box_mass_properties_match_the_discrete_lattice_formula() {
        let (r, m) = (0.005, 0.002);
        let mut b = WorldBuilder::new();
        let s = b.add_rigid(
            "box",
            &box_lattice(Vec3::new(0.04, 0.02, 0.01), 2.0 * r),
            r,
            m,
            Pose::from_translation(Vec3::new(1.0, 2.0, 3.0)),
            Vec3::ONE,
        );
        let w = b.build();
        let (nx, ny, nz) = (8.0f32, 4.0f32, 2.0f32);
        let n = nx * ny * nz;
        assert!((w.shapes.mass[s as usize] - n * m).abs() < 1e-6);
        assert!(
            w.shapes.center_of_mass[s as usize].length() < 1e-6,
            "body frame is centred"
        );
        // Sum of squared lattice coordinates along an axis with k points at spacing d: d^2 k (k^2 - 1) / 12, per line.
        let sq = |k: f32, others: f32| (2.0 * r).powi(2) * k * (k * k - 1.0) / 12.0 * others;
        let (sx, sy, sz) = (sq(nx, ny * nz), sq(ny, nx * nz), sq(nz, nx * ny));
        let sphere = 0.4 * m * r * r * n;
        let i = w.shapes.inertia[s as usize];
        let want = Vec3::new(
            m * (sy + sz) + sphere,
            m * (sx + sz) + sphere,
            m * (sx + sy) + sphere,
        );
        assert!(
            (i.diagonal() - want).abs().max_element() < 1e-9,
            "{:?} vs {want:?}",
            i.diagonal()
        );
        assert!(
            i.x_axis.y.abs() < 1e-10 && i.x_axis.z.abs() < 1e-10 && i.y_axis.z.abs() < 1e-10,
            "symmetric box: no products of inertia"
        );
    }
}

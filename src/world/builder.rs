//! `WorldBuilder`: adds shapes with contiguous particles and one bonded Gaussian per particle,
//! or an `ObjectModel` (an object's particles and Gaussians in its body frame, from a file or
//! from RGB-D) with its own Gaussians bonded to the nearest particle. It builds; it never steps.

use crate::math::Pose;
use crate::world::{Phase, ShapeId, ShapeKind, World};
use glam::{Quat, Vec3};

/// A Gaussian in an object's body frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyGaussian {
    pub mean: Vec3,
    pub rotation: Quat,
    /// Standard deviations, m.
    pub scale: Vec3,
    pub opacity: f32,
    /// RGB in [0, 1].
    pub colour: Vec3,
}

/// An object as particles and Gaussians in its body frame, with its body-to-world pose.
#[derive(Clone, Debug)]
pub struct ObjectModel {
    pub name: String,
    pub pose: Pose,
    /// Body-frame position and radius of each particle.
    pub particles: Vec<(Vec3, f32)>,
    pub gaussians: Vec<BodyGaussian>,
}

/// Gaussian standard deviation relative to the particle radius for builder-made Gaussians.
const GAUSSIAN_SCALE_PER_RADIUS: f32 = 0.6;

#[derive(Default)]
pub struct WorldBuilder {
    world: World,
}

impl WorldBuilder {
    pub fn new() -> Self {
        Self::default()
    }

    #[allow(clippy::too_many_arguments)]
    fn add_solid(
        &mut self,
        name: &str,
        kind: ShapeKind,
        phase: Phase,
        body_points: &[Vec3],
        radius: f32,
        inv_mass: f32,
        pose: Pose,
        colour: Vec3,
    ) -> ShapeId {
        let shape = self.world.shapes.len() as ShapeId;
        let first = self.world.particles.len();
        for &r in body_points {
            let i = self.world.particles.push(
                pose.transform_point(r),
                inv_mass,
                radius,
                shape,
                phase,
                r,
            );
            self.push_gaussian(i, radius, colour);
        }
        let s = self
            .world
            .shapes
            .push(name, kind, first..self.world.particles.len(), pose);
        self.world
            .shapes
            .update_mass_properties(s, &self.world.particles);
        s
    }

    /// The exact geometry kinematic `shape`'s particles sample (`Shapes::primitives`).
    pub fn set_primitives(&mut self, shape: ShapeId, primitives: Vec<super::Primitive>) {
        self.world.shapes.primitives[shape as usize] = primitives;
    }

    /// How far kinematic `shape` yields per newton it pushes with (`Shapes::compliance`, m/N).
    pub fn set_compliance(&mut self, shape: ShapeId, compliance: f32) {
        self.world.shapes.compliance[shape as usize] = compliance;
    }

    fn push_gaussian(&mut self, particle: usize, radius: f32, colour: Vec3) {
        self.world.gaussians.push(
            particle as u32,
            Vec3::ZERO,
            Quat::IDENTITY,
            Vec3::splat(GAUSSIAN_SCALE_PER_RADIUS * radius),
            0.95,
            colour,
        );
    }

    /// A rigid object made of particles at `body_points` (body frame), placed at `pose`.
    pub fn add_rigid(
        &mut self,
        name: &str,
        body_points: &[Vec3],
        radius: f32,
        particle_mass: f32,
        pose: Pose,
        colour: Vec3,
    ) -> ShapeId {
        self.add_solid(
            name,
            ShapeKind::Rigid,
            Phase::Dynamic,
            body_points,
            radius,
            1.0 / particle_mass,
            pose,
            colour,
        )
    }

    /// A rigid object from a model with its own particles (body frame, per-particle radii) and
    /// Gaussians (body frame), placed at the model's pose; each Gaussian is bonded to its closest
    /// particle.
    pub fn add_rigid_model(
        &mut self,
        name: &str,
        model: &ObjectModel,
        particle_mass: f32,
    ) -> ShapeId {
        let shape = self.world.shapes.len() as ShapeId;
        let first = self.world.particles.len();
        for &(r, radius) in &model.particles {
            self.world.particles.push(
                model.pose.transform_point(r),
                1.0 / particle_mass,
                radius,
                shape,
                Phase::Dynamic,
                r,
            );
        }
        for g in &model.gaussians {
            // The particle's frame has the body's rotation, so the offset in it is the body-frame one.
            let closest = (0..model.particles.len())
                .min_by(|&a, &b| {
                    g.mean
                        .distance_squared(model.particles[a].0)
                        .total_cmp(&g.mean.distance_squared(model.particles[b].0))
                })
                .unwrap_or(0);
            self.world.gaussians.push(
                (first + closest) as u32,
                g.mean - model.particles[closest].0,
                g.rotation,
                g.scale,
                g.opacity,
                g.colour,
            );
        }
        let s = self.world.shapes.push(
            name,
            ShapeKind::Rigid,
            first..self.world.particles.len(),
            model.pose,
        );
        self.world
            .shapes
            .update_mass_properties(s, &self.world.particles);
        s
    }

    /// A kinematic body (robot link, pusher) that follows its `Shapes::target` pose.
    pub fn add_kinematic(
        &mut self,
        name: &str,
        body_points: &[Vec3],
        radius: f32,
        pose: Pose,
        colour: Vec3,
    ) -> ShapeId {
        self.add_solid(
            name,
            ShapeKind::Kinematic,
            Phase::Kinematic,
            body_points,
            radius,
            0.0,
            pose,
            colour,
        )
    }

    /// A body that never moves.
    pub fn add_static(
        &mut self,
        name: &str,
        body_points: &[Vec3],
        radius: f32,
        pose: Pose,
        colour: Vec3,
    ) -> ShapeId {
        self.add_solid(
            name,
            ShapeKind::Static,
            Phase::Static,
            body_points,
            radius,
            0.0,
            pose,
            colour,
        )
    }

    /// A rope through `points` (world frame): segment constraints between neighbours (rigid) and
    /// bending constraints between particles two apart with `bending_stiffness` in (0, 1].
    pub fn add_rope(
        &mut self,
        name: &str,
        points: &[Vec3],
        radius: f32,
        particle_mass: f32,
        bending_stiffness: f32,
        colour: Vec3,
    ) -> ShapeId {
        let shape = self.world.shapes.len() as ShapeId;
        let first = self.world.particles.len();
        for &p in points {
            let i = self.world.particles.push(
                p,
                1.0 / particle_mass,
                radius,
                shape,
                Phase::Dynamic,
                Vec3::ZERO,
            );
            self.push_gaussian(i, radius, colour);
        }
        // Bending first, segments last: constraints are projected in order, so each sweep ends with
        // the stiff segment lengths satisfied.
        if bending_stiffness > 0.0 {
            for k in 0..points.len().saturating_sub(2) {
                let (a, b) = (first + k, first + k + 2);
                self.world.distance.push(
                    a as u32,
                    b as u32,
                    points[k].distance(points[k + 2]),
                    bending_stiffness,
                );
            }
        }
        for k in 0..points.len().saturating_sub(1) {
            let (a, b) = (first + k, first + k + 1);
            self.world
                .distance
                .push(a as u32, b as u32, points[k].distance(points[k + 1]), 1.0);
        }
        let centroid = points.iter().copied().sum::<Vec3>() / points.len().max(1) as f32;
        let s = self.world.shapes.push(
            name,
            ShapeKind::Rope,
            first..self.world.particles.len(),
            Pose::from_translation(centroid),
        );
        self.world
            .shapes
            .update_mass_properties(s, &self.world.particles);
        s
    }

    /// Tie two particles together at their current distance (e.g. a rope end to a gripper).
    pub fn attach(&mut self, a: usize, b: usize) {
        let d = self.world.particles.position[a].distance(self.world.particles.position[b]);
        self.world.distance.push(a as u32, b as u32, d, 1.0);
    }

    /// Set the standard deviation and opacity of the Gaussians bonded to `shape`'s particles.
    pub fn set_gaussian_look(&mut self, shape: ShapeId, scale: f32, opacity: f32) {
        let range = self.world.shapes.range(shape);
        let g = &mut self.world.gaussians;
        for i in 0..g.len() {
            if range.contains(&(g.parent[i] as usize)) {
                g.scale[i] = Vec3::splat(scale);
                g.opacity[i] = opacity;
            }
        }
    }

    /// A Gaussian of the static scene (table, walls): world frame, no parent particle; scale as
    /// standard deviations (m), opacity in (0, 1).
    pub fn add_scene_gaussian(
        &mut self,
        mean: Vec3,
        rotation: Quat,
        scale: Vec3,
        opacity: f32,
        colour: Vec3,
    ) {
        self.world
            .gaussians
            .push(super::NO_PARENT, mean, rotation, scale, opacity, colour);
    }

    /// Recolour the Gaussians of `shape` whose parent's rest position `paint` maps to a colour.
    pub fn paint(&mut self, shape: ShapeId, paint: impl Fn(Vec3) -> Option<Vec3>) {
        let range = self.world.shapes.range(shape);
        for i in 0..self.world.gaussians.len() {
            let p = self.world.gaussians.parent[i] as usize;
            if range.contains(&p)
                && let Some(c) = paint(self.world.particles.rest[p])
            {
                self.world.gaussians.colour[i] = c;
            }
        }
    }

    /// Give every particle of `shape` the same initial velocity.
    pub fn set_velocity(&mut self, shape: ShapeId, velocity: Vec3) {
        for i in self.world.shapes.range(shape) {
            self.world.particles.velocity[i] = velocity;
        }
    }

    pub fn world(&self) -> &World {
        &self.world
    }

    pub fn build(self) -> World {
        self.world
    }
}

//! Built-in scenes: the demo's tabletop and the benchmark scenes. A `Scene` is a world plus
//! scripted motions for its kinematic shapes (pose as a function of time).

use super::{WorldBuilder, box_lattice, cylinder_lattice, t_block_lattice};
use crate::math::Pose;
use crate::physics::Solver;
use crate::world::{ShapeId, World};
use anyhow::Result;
use glam::{Quat, Vec3};

/// Pose of a kinematic shape at a time (seconds).
pub type Script = Box<dyn Fn(f64) -> Pose + Send + Sync>;

pub struct Scene {
    pub world: World,
    pub scripts: Vec<(ShapeId, Script)>,
}

impl Scene {
    /// Set every scripted shape's target to its pose one tick ahead, then step.
    pub fn advance(&mut self, solver: &mut Solver) -> Result<()> {
        let t_next = self.world.time + solver.config().dt as f64;
        for (s, script) in &self.scripts {
            self.world.shapes.target[*s as usize] = script(t_next);
        }
        solver.step(&mut self.world)
    }
}

/// Piecewise-linear motion through `(time, position)` waypoints with a fixed rotation; holds the
/// first/last waypoint outside their time span.
pub fn waypoints(points: Vec<(f64, Vec3)>, rotation: Quat) -> Script {
    Box::new(move |t| {
        let pos = match points.iter().position(|(tk, _)| *tk > t) {
            None => points.last().map(|p| p.1).unwrap_or(Vec3::ZERO),
            Some(0) => points[0].1,
            Some(k) => {
                let (t0, p0) = points[k - 1];
                let (t1, p1) = points[k];
                p0.lerp(p1, ((t - t0) / (t1 - t0)) as f32)
            }
        };
        Pose::new(pos, rotation)
    })
}

pub const ORANGE: Vec3 = Vec3::new(1.0, 0.45, 0.1);
pub const BLUE: Vec3 = Vec3::new(0.2, 0.4, 0.9);
pub const WHITE: Vec3 = Vec3::new(0.9, 0.9, 0.9);
pub const GREEN: Vec3 = Vec3::new(0.2, 0.8, 0.3);

/// Particle radius of the built-in objects (the real T-block data uses 6 mm).
pub const RADIUS: f32 = 0.005;
/// Mass of one object particle, kg (the T-block of ~500 particles weighs ~0.5 kg).
pub const PARTICLE_MASS: f32 = 0.001;

/// The demo's tabletop: a pusher drives a T-block into a box that was dropped beside it while a
/// gripper drags a rope across the table. Exercises ground, friction, contacts, shape matching,
/// rope constraints and kinematic motion in one run.
pub fn tabletop() -> Scene {
    let spacing = 2.0 * RADIUS;
    let mut b = WorldBuilder::new();
    let t_points = t_block_lattice(0.2, 0.05, 0.03, spacing);
    let t_rest_z = RADIUS + spacing; // three layers: centre layer one spacing above the lowest
    b.add_rigid("tblock", &t_points, RADIUS, PARTICLE_MASS, Pose::new(Vec3::new(0.0, 0.0, t_rest_z), Quat::from_rotation_z(0.35)), ORANGE);
    let box_half = Vec3::splat(0.03);
    b.add_rigid("box", &box_lattice(box_half, spacing), RADIUS, PARTICLE_MASS, Pose::new(Vec3::new(0.03, 0.2, 0.25), Quat::from_rotation_x(0.3)), BLUE);
    let rope_points: Vec<Vec3> = (0..40).map(|k| Vec3::new(-0.45 + k as f32 * spacing, 0.3, RADIUS)).collect();
    let rope = b.add_rope("rope", &rope_points, RADIUS, PARTICLE_MASS, 0.2, GREEN);
    let pusher_points = cylinder_lattice(0.01, 0.06, spacing);
    let pusher_start = Vec3::new(0.0, -0.3, 0.035);
    let pusher = b.add_kinematic("pusher", &pusher_points, RADIUS, Pose::from_translation(pusher_start), WHITE);
    let rope_end = b.world().shapes.range(rope).start;
    let grip_start = rope_points[0] - Vec3::new(spacing, 0.0, 0.0);
    let gripper = b.add_kinematic("gripper", &[Vec3::ZERO], RADIUS, Pose::from_translation(grip_start), WHITE);
    let grip_particle = b.world().shapes.range(gripper).start;
    b.attach(grip_particle, rope_end);
    let world = b.build();
    let scripts: Vec<(ShapeId, Script)> = vec![
        (
            pusher,
            waypoints(
                vec![(0.5, pusher_start), (3.5, pusher_start + Vec3::new(0.0, 0.4, 0.0)), (4.5, pusher_start + Vec3::new(0.0, 0.4, 0.15))],
                Quat::IDENTITY,
            ),
        ),
        (
            gripper,
            waypoints(vec![(0.3, grip_start), (1.0, grip_start + Vec3::new(0.0, 0.0, 0.1)), (3.0, grip_start + Vec3::new(-0.2, -0.1, 0.1))], Quat::IDENTITY),
        ),
    ];
    Scene { world, scripts }
}

/// `n` dynamic particles as a field of 3x3x3 cubes standing in a tight grid on the ground (two
/// layers), so every particle has ground and neighbour contacts.
pub fn cube_field(n: usize) -> Scene {
    let spacing = 2.0 * RADIUS;
    let cube = box_lattice(Vec3::splat(1.5 * spacing), spacing);
    let cubes = n.div_ceil(cube.len());
    let per_layer = cubes.div_ceil(2);
    let side = (per_layer as f32).sqrt().ceil() as usize;
    // Slight overlap between neighbouring cubes so contacts are active from the first tick.
    let pitch = 3.0 * spacing - 0.2 * RADIUS;
    let mut b = WorldBuilder::new();
    for c in 0..cubes {
        let layer = c / per_layer;
        let k = c % per_layer;
        let (ix, iy) = (k % side, k / side);
        let centre = Vec3::new(ix as f32 * pitch, iy as f32 * pitch, RADIUS + spacing + layer as f32 * 3.0 * spacing);
        b.add_rigid(&format!("cube{c}"), &cube, RADIUS, PARTICLE_MASS, Pose::from_translation(centre), BLUE);
    }
    Scene { world: b.build(), scripts: Vec::new() }
}

/// The paper's pushing setup in particles: a T-block on the table and a robot arm approximated by
/// kinematic capsules (thousands of particles) whose last link, the pusher, drives the block.
pub fn tblock_and_robot() -> Scene {
    let spacing = 2.0 * RADIUS;
    let mut b = WorldBuilder::new();
    b.add_rigid("tblock", &t_block_lattice(0.2, 0.05, 0.03, spacing), RADIUS, PARTICLE_MASS, Pose::from_translation(Vec3::new(0.45, 0.0, RADIUS + spacing)), ORANGE);
    let link_radius = 0.04;
    let link_len = 0.3;
    let link = cylinder_lattice(link_radius, link_len, 1.2 * spacing);
    // A fixed arm silhouette: base column, shoulder, forearm reaching over the table, and the pusher.
    let links = [
        (Vec3::new(0.0, 0.0, 0.16), Quat::IDENTITY),
        (Vec3::new(0.0, 0.0, 0.46), Quat::IDENTITY),
        (Vec3::new(0.1, 0.0, 0.7), Quat::from_rotation_y(1.2)),
        (Vec3::new(0.36, 0.0, 0.72), Quat::from_rotation_y(1.7)),
        (Vec3::new(0.5, 0.0, 0.55), Quat::from_rotation_y(0.3)),
        (Vec3::new(0.52, 0.0, 0.33), Quat::IDENTITY),
    ];
    let mut scripts: Vec<(ShapeId, Script)> = Vec::new();
    let arm_speed = 0.05; // m/s: the whole arm translates along y, pushing the block sideways
    for (k, (pos, rot)) in links.iter().enumerate() {
        let id = b.add_kinematic(&format!("link{k}"), &link, RADIUS, Pose::new(*pos, *rot), WHITE);
        let (pos, rot) = (*pos, *rot);
        scripts.push((id, Box::new(move |t| Pose::new(pos + Vec3::new(0.0, arm_speed * t as f32, 0.0), rot))));
    }
    let pusher_start = Vec3::new(0.45, -0.13, 0.035);
    let pusher = b.add_kinematic("pusher", &cylinder_lattice(0.01, 0.06, spacing), RADIUS, Pose::from_translation(pusher_start), WHITE);
    scripts.push((pusher, Box::new(move |t| Pose::from_translation(pusher_start + Vec3::new(0.0, arm_speed * t as f32, 0.0)))));
    Scene { world: b.build(), scripts }
}

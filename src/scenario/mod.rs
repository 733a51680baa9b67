//! Synthetic scenarios with ground truth: a "true world" simulated by pegs' own physics (possibly
//! with extra effects the tracker's model lacks) and rendered into three cameras with sensor noise
//! and exposure drift, and a "model world" the tracker starts from (possibly off the true pose).
//! Both are built by the same function, so particle i of an object is the same material point in
//! both and the 3-D tracking error is a per-particle distance.

use crate::math::Pose;
use crate::render::{Camera, GaussianCloud, GaussianParams, RenderSettings, Roi, cpu::CpuRenderer, logit};
use crate::robot::{RobotConfig, RobotInWorld};
use crate::scene::builtin::{self, Scene, pusher_trajectory};
use crate::scene::{WorldBuilder, box_lattice};
use crate::world::World;
use anyhow::{Context, Result, bail};

pub mod generate;
pub mod table;
use glam::{DVec3, Quat, Vec3, Vec4};

pub const NAMES: [&str; 4] = ["resting_box", "pushed_box", "pushed_tblock", "two_boxes"];

/// The tracked objects of scenario `name`.
pub fn object_names(name: &str) -> &'static [&'static str] {
    match name {
        n if n.contains("tblock") => &["tblock"],
        "two_boxes" => &["box", "box2"],
        _ => &["box"],
    }
}

/// Particle radius and mass of scenario objects.
const R: f32 = 0.005;
const MASS: f32 = 0.001;

/// A flat textured table of static Gaussians (no particles: the ground plane is the physics).
fn add_table(b: &mut WorldBuilder) {
    for iy in 0..60 {
        for ix in 0..60 {
            let shade = if (ix / 6 + iy / 6) % 2 == 0 { 0.12 } else { 0.2 };
            b.add_scene_gaussian(GaussianParams {
                mean: Vec3::new(0.2 + ix as f32 * 0.01, -0.3 + iy as f32 * 0.01, -0.001),
                rotation: Vec4::new(0.0, 0.0, 0.0, 1.0),
                log_scale: Vec3::new(0.006f32.ln(), 0.006f32.ln(), 0.0008f32.ln()),
                opacity_logit: logit(0.97),
                colour: Vec3::splat(shade),
            });
        }
    }
}

/// The three cameras of a scenario, looking at the workspace around (0.5, 0, 0).
pub fn cameras(width: u32, height: u32) -> Vec<Camera> {
    let fx = 0.9 * width as f32;
    let target = Vec3::new(0.5, 0.0, 0.02);
    vec![
        Camera::look_at(width, height, fx, Vec3::new(1.0, -0.45, 0.55), target),
        Camera::look_at(width, height, fx, Vec3::new(0.95, 0.5, 0.6), target),
        Camera::look_at(width, height, fx, Vec3::new(0.25, -0.55, 0.65), target),
    ]
}

/// Build scenario `name`'s world with the object placed `offset` away from its true start.
pub fn build(name: &str, offset: Pose) -> Result<Scene> {
    let mut b = WorldBuilder::new();
    add_table(&mut b);
    if object_names(name) == ["tblock"] {
        // The push-T block of the paper's real scenes: 20 x 20 cm, 3 cm thick, orange.
        let rest = Pose::new(Vec3::new(0.5, 0.0, R + 2.0 * R), Quat::from_rotation_z(0.35));
        let start = Pose::new(rest.translation + offset.translation, offset.rotation * rest.rotation);
        let t = b.add_rigid("tblock", &crate::scene::t_block_lattice(0.2, 0.05, 0.03, 2.0 * R), R, MASS, start, Vec3::new(1.0, 0.45, 0.1));
        b.set_gaussian_look(t, R, 0.97);
    } else {
        // A 12 x 6 x 5 cm box, blue with a yellow end, so no rotation of it looks the same.
        let half = Vec3::new(0.06, 0.03, 0.025);
        let rest = Pose::new(Vec3::new(0.5, 0.0, R + 2.0 * 2.0 * R), Quat::from_rotation_z(0.2));
        let start = Pose::new(rest.translation + offset.translation, offset.rotation * rest.rotation);
        let bx = b.add_rigid("box", &box_lattice(half, 2.0 * R), R, MASS, start, Vec3::new(0.15, 0.35, 0.9));
        b.set_gaussian_look(bx, R, 0.97);
        b.paint(bx, |p| if p.x > 0.02 { Some(Vec3::new(0.95, 0.8, 0.1)) } else { None });
        if name == "two_boxes" {
            // A second, 8 x 8 x 5 cm red box with a white end, in the first one's path.
            let rest = Pose::new(Vec3::new(0.51, 0.13, R + 2.0 * 2.0 * R), Quat::from_rotation_z(-0.3));
            let start = Pose::new(rest.translation + offset.translation, offset.rotation * rest.rotation);
            let b2 = b.add_rigid("box2", &box_lattice(Vec3::new(0.04, 0.04, 0.025), 2.0 * R), R, MASS, start, Vec3::new(0.85, 0.15, 0.15));
            b.set_gaussian_look(b2, R, 0.97);
            b.paint(b2, |p| if p.y > 0.02 { Some(Vec3::splat(0.9)) } else { None });
        }
    }
    let model = builtin::panda_pusher()?;
    let waypoints: Vec<(f64, DVec3)> = match name {
        // The robot parks away from the box.
        "resting_box" => vec![(0.0, DVec3::new(0.3, -0.3, 0.2))],
        // The rod comes down behind the box and pushes it 15 cm along +y.
        "pushed_box" | "two_boxes" => vec![(0.0, DVec3::new(0.5, -0.16, 0.12)), (0.5, DVec3::new(0.5, -0.16, 0.02)), (3.5, DVec3::new(0.5, 0.1, 0.02)), (4.0, DVec3::new(0.5, 0.1, 0.12))],
        // The rod comes down behind the stem and pushes the T 15 cm along +y, turning it.
        "pushed_tblock" => vec![(0.0, DVec3::new(0.5, -0.22, 0.12)), (0.5, DVec3::new(0.5, -0.22, 0.015)), (3.5, DVec3::new(0.5, 0.04, 0.015)), (4.0, DVec3::new(0.5, 0.04, 0.12))],
        other => bail!("unknown scenario '{other}' (known: {})", NAMES.join(", ")),
    };
    let mut waypoints = waypoints;
    if waypoints.len() == 1 {
        waypoints.push((10.0, waypoints[0].1));
    }
    let trajectory = pusher_trajectory(&model, &waypoints, 30.0)?;
    let q0 = trajectory.at(0.0).context("empty trajectory")?;
    let robot = RobotInWorld::add(&mut b, model, &q0, &RobotConfig::default())?;
    Ok(Scene { world: b.build(), scripts: Vec::new(), robot: Some((robot, trajectory)) })
}

/// Render what the cameras see of `world`, with sensor noise (std-dev `noise`) and an exposure
/// factor; deterministic for a given `seed`.
pub fn observe(world: &World, cameras: &[Camera], noise: f32, exposure: f32, seed: u64) -> Vec<Vec<Vec3>> {
    let cloud = GaussianCloud::from_world(world);
    let mut renderer = CpuRenderer::new(RenderSettings::default());
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut gauss = move || {
        // Sum of uniforms: cheap, deterministic, close enough to normal for sensor noise.
        let mut s = 0.0f32;
        for _ in 0..4 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            s += (state >> 40) as f32 / (1u64 << 24) as f32;
        }
        (s - 2.0) * 1.732
    };
    cameras
        .iter()
        .map(|c| {
            let out = renderer.forward(&cloud, c, Roi::full(c));
            out.colour.into_iter().map(|px| (px * exposure + Vec3::new(gauss(), gauss(), gauss()) * noise).clamp(Vec3::ZERO, Vec3::ONE)).collect()
        })
        .collect()
}

/// Mean distance (m) between the particles of `object` in the two worlds.
pub fn tracking_error(truth: &World, model: &World, object: &str) -> Option<f32> {
    let (a, b) = (truth.shape_id(object)?, model.shape_id(object)?);
    let (ra, rb) = (truth.shapes.range(a), model.shapes.range(b));
    if ra.len() != rb.len() || ra.is_empty() {
        return None;
    }
    let sum: f32 = ra.clone().zip(rb).map(|(i, j)| truth.particles.position[i].distance(model.particles.position[j])).sum();
    Some(sum / ra.len() as f32)
}

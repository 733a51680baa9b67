//! Built-in scenes: the demo's tabletop and the benchmark scenes. A `Scene` is a world plus
//! scripted motions for its kinematic shapes (pose as a function of time).

use crate::math::Pose;
use crate::physics::Solver;
use crate::robot::ik::{self, IkGoal};
use crate::robot::{
    GeometrySource, JointTrajectory, PackagePaths, RobotConfig, RobotInWorld, RobotModel,
};
use crate::world::{ShapeId, World, WorldBuilder, box_lattice, t_block_lattice};
use anyhow::{Context, Result};
use glam::{DVec3, Quat, Vec3};

/// Pose of a kinematic shape at a time (seconds).
pub type Script = Box<dyn Fn(f64) -> Pose + Send + Sync>;

pub struct Scene {
    pub world: World,
    pub scripts: Vec<(ShapeId, Script)>,
    /// A robot replaying joint-state samples (forward kinematics every substep).
    pub robot: Option<(RobotInWorld, JointTrajectory)>,
}

impl Scene {
    /// Set every scripted shape's target to its pose one tick ahead, then step.
    pub fn advance(&mut self, solver: &mut Solver) -> Result<()> {
        let dt = solver.config().dt as f64;
        let t_next = self.world.time + dt;
        for (s, script) in &self.scripts {
            self.world.shapes.target[*s as usize] = script(t_next);
        }
        match &self.robot {
            Some((robot, trajectory)) => {
                let mut driver = robot.driver(trajectory, self.world.time, dt);
                solver.step_driven(&mut self.world, &mut driver)
            }
            None => solver.step(&mut self.world),
        }
    }
}

/// The bundled Panda with its rod pusher (primitive geometry, so it needs no mesh files).
pub fn panda_pusher() -> Result<RobotModel> {
    RobotModel::parse(
        include_str!("../urdf/panda_pusher.urdf"),
        std::path::Path::new("."),
        &PackagePaths::default(),
        GeometrySource::Collision,
    )
    .context("bundled urdf/panda_pusher.urdf")
}

/// The pusher rod's tip in the `panda_pusher` link frame.
pub const PUSHER_TIP: DVec3 = DVec3::new(0.0, 0.0, -0.14);

/// Joint-state samples at `rate` Hz that move the pusher tip through `(time, point)` waypoints
/// (linear between them) with the rod pointing down, by inverse kinematics warm-started from the
/// previous sample.
pub fn pusher_trajectory(
    model: &RobotModel,
    waypoints: &[(f64, DVec3)],
    rate: f64,
) -> Result<JointTrajectory> {
    let link = model
        .link_index("panda_pusher")
        .context("the robot has no panda_pusher link")?;
    let mut q = vec![0.0; model.joints.len()];
    for (name, v) in [
        ("panda_joint2", -0.3),
        ("panda_joint4", -2.2),
        ("panda_joint6", 1.9),
        ("panda_joint7", 0.785),
    ] {
        if let Some(k) = model.joint_index(name) {
            q[k] = v;
        }
    }
    let (t0, t1) = (
        waypoints.first().map_or(0.0, |w| w.0),
        waypoints.last().map_or(0.0, |w| w.0),
    );
    let mut trajectory = JointTrajectory::default();
    let samples = ((t1 - t0) * rate).ceil() as usize;
    for k in 0..=samples {
        let t = t0 + k as f64 / rate;
        let target = match waypoints.iter().position(|w| w.0 > t) {
            None => waypoints.last().map_or(DVec3::ZERO, |w| w.1),
            Some(0) => waypoints[0].1,
            Some(i) => waypoints[i - 1].1.lerp(
                waypoints[i].1,
                (t - waypoints[i - 1].0) / (waypoints[i].0 - waypoints[i - 1].0),
            ),
        };
        let goal = IkGoal {
            link,
            point: PUSHER_TIP,
            target,
            axis: DVec3::NEG_Z,
            direction: Some(DVec3::NEG_Z),
        };
        let (solution, error) = ik::solve(model, &q, &goal, 100);
        anyhow::ensure!(
            error < 1e-3,
            "pusher cannot reach {target} (IK error {error} m)"
        );
        q = solution;
        trajectory.push(t, q.clone());
    }
    Ok(trajectory)
}

/// Piecewise-linear motion through `(time, position)` waypoints with a fixed rotation; holds the
/// first/last waypoint outside their time span.
pub fn waypoints_script(points: Vec<(f64, Vec3)>, rotation: Quat) -> Script {
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

/// The demo's tabletop: the Panda's rod pusher, replayed from joint-state samples, drives a
/// T-block into a box that was dropped beside it, while a gripper drags a rope across the table.
/// Exercises the robot, ground, friction, contacts, shape matching, rope constraints and kinematic
/// motion in one run.
pub fn tabletop() -> Result<Scene> {
    let spacing = 2.0 * RADIUS;
    let mut b = WorldBuilder::new();
    let t_points = t_block_lattice(0.2, 0.05, 0.03, spacing);
    let t_rest_z = RADIUS + spacing; // three layers: centre layer one spacing above the lowest
    b.add_rigid(
        "tblock",
        &t_points,
        RADIUS,
        PARTICLE_MASS,
        Pose::new(Vec3::new(0.5, 0.0, t_rest_z), Quat::from_rotation_z(0.35)),
        ORANGE,
    );
    let box_half = Vec3::splat(0.03);
    b.add_rigid(
        "box",
        &box_lattice(box_half, spacing),
        RADIUS,
        PARTICLE_MASS,
        Pose::new(Vec3::new(0.53, 0.2, 0.25), Quat::from_rotation_x(0.3)),
        BLUE,
    );
    let rope_points: Vec<Vec3> = (0..40)
        .map(|k| Vec3::new(0.25 + k as f32 * spacing, -0.4, RADIUS))
        .collect();
    let rope = b.add_rope("rope", &rope_points, RADIUS, PARTICLE_MASS, 0.2, GREEN);
    let rope_end = b.world().shapes.range(rope).start;
    let grip_start = rope_points[0] - Vec3::new(spacing, 0.0, 0.0);
    let gripper = b.add_kinematic(
        "gripper",
        &[Vec3::ZERO],
        RADIUS,
        Pose::from_translation(grip_start),
        WHITE,
    );
    let grip_particle = b.world().shapes.range(gripper).start;
    b.attach(grip_particle, rope_end);

    // The robot: tip lowered behind the T-block's stem, pushed along +y, lifted.
    let model = panda_pusher()?;
    let waypoints = [
        (0.0, DVec3::new(0.5, -0.26, 0.15)),
        (0.6, DVec3::new(0.5, -0.26, 0.02)),
        (3.6, DVec3::new(0.5, 0.12, 0.02)),
        (4.2, DVec3::new(0.5, 0.12, 0.15)),
    ];
    let trajectory = pusher_trajectory(&model, &waypoints, 30.0)?;
    let q0 = trajectory.at(0.0).context("empty trajectory")?;
    let robot = RobotInWorld::add(
        &mut b,
        model,
        &q0,
        &RobotConfig {
            particle_radius: RADIUS,
            ..RobotConfig::default()
        },
    )?;
    let world = b.build();
    let scripts: Vec<(ShapeId, Script)> = vec![(
        gripper,
        waypoints_script(
            vec![
                (0.3, grip_start),
                (1.0, grip_start + Vec3::new(0.0, 0.0, 0.1)),
                (3.0, grip_start + Vec3::new(0.2, -0.1, 0.1)),
            ],
            Quat::IDENTITY,
        ),
    )];
    Ok(Scene {
        world,
        scripts,
        robot: Some((robot, trajectory)),
    })
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
        let centre = Vec3::new(
            ix as f32 * pitch,
            iy as f32 * pitch,
            RADIUS + spacing + layer as f32 * 3.0 * spacing,
        );
        b.add_rigid(
            &format!("cube{c}"),
            &cube,
            RADIUS,
            PARTICLE_MASS,
            Pose::from_translation(centre),
            BLUE,
        );
    }
    Scene {
        world: b.build(),
        scripts: Vec::new(),
        robot: None,
    }
}

/// The paper's pushing setup in particles: a T-block (525 particles, one rigid shape) and the
/// Panda with its rod pusher (a few thousand kinematic particles at 6 mm radius) replaying
/// joint-state samples that push the block, forward kinematics every substep.
pub fn tblock_and_robot() -> Result<Scene> {
    let spacing = 2.0 * RADIUS;
    let mut b = WorldBuilder::new();
    b.add_rigid(
        "tblock",
        &t_block_lattice(0.2, 0.05, 0.03, spacing),
        RADIUS,
        PARTICLE_MASS,
        Pose::from_translation(Vec3::new(0.5, 0.0, RADIUS + spacing)),
        ORANGE,
    );
    let model = panda_pusher()?;
    let waypoints = [
        (0.0, DVec3::new(0.5, -0.2, 0.02)),
        (4.0, DVec3::new(0.5, 0.1, 0.02)),
    ];
    let trajectory = pusher_trajectory(&model, &waypoints, 30.0)?;
    let q0 = trajectory.at(0.0).context("empty trajectory")?;
    let robot = RobotInWorld::add(&mut b, model, &q0, &RobotConfig::default())?;
    Ok(Scene {
        world: b.build(),
        scripts: Vec::new(),
        robot: Some((robot, trajectory)),
    })
}

//! The robot in the world model: a URDF model (`model`), joint states and their interpolation in
//! time (`joint_state`), particles sampled over link geometry (`sampling`), and the binding that
//! adds each link to the world as a kinematic shape with bonded Gaussians and moves it by forward
//! kinematics every physics substep. Nothing here is fitted by hand.

pub mod ik;
pub mod joint_state;
pub mod model;
pub mod sampling;

pub use joint_state::{JointStateTracker, JointTrajectory, UpdateReport};
pub use model::{GeometrySource, PackagePaths, RobotModel, root_link_name};
pub use sampling::Sampling;

use crate::math::Pose;
use crate::physics::KinematicDriver;
use crate::world::WorldBuilder;
use crate::world::{ShapeId, World};
use anyhow::{Result, bail};
use glam::{DAffine3, DQuat, Quat, Vec3};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// How a robot enters the world.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobotConfig {
    /// URDF file; none means no robot in the scene.
    pub urdf: Option<PathBuf>,
    /// Directories searched for `package://` URIs.
    pub package_paths: Vec<PathBuf>,
    /// Pose of the URDF root link in the world: position (m) and quaternion x, y, z, w.
    pub base_position: Vec3,
    pub base_orientation: [f32; 4],
    pub geometry: GeometrySource,
    pub sampling: Sampling,
    pub particle_radius: f32,
    /// Particle spacing as a multiple of the radius (2 = touching particles).
    pub spacing_per_radius: f32,
    /// How objects meet the links: as their particles (the default, which the tracker is tuned
    /// with), or as the URDF's exact solids where a link's geometry is all boxes, cylinders,
    /// capsules and spheres (meshes stay particles).
    pub contact: RobotContact,
    /// How stiffly the links hold their place where they push objects, N/m: each link gives way
    /// by the force it pushes with over this, as an arm under Cartesian
    /// impedance control does (frankx's Cartesian impedance motion holds 2000 N/m by default;
    /// `physics::yielding`). None: rigid, where the joint angles put it.
    pub stiffness: Option<f32>,
    /// Colour for every link; overrides URDF materials.
    pub colour: Option<Vec3>,
    /// Colour of links without a URDF material.
    pub default_colour: Vec3,
    /// Joint names as the driver publishes them start with `joint_prefix_received` (e.g. `fr3_`
    /// from franka_ros2 on Jazzy), which is replaced by `joint_prefix_urdf` (e.g. `panda_`) to
    /// match the URDF. Both empty: names are used as they come.
    pub joint_prefix_received: String,
    pub joint_prefix_urdf: String,
    /// Topic of the URDF text (`std_msgs/String`, transient local, as robot_state_publisher
    /// publishes `/robot_description`): `pegs node` waits for it and builds the robot from it
    /// instead of `urdf`. Empty: `urdf`.
    pub description_topic: String,
    /// The URDF text received on `description_topic` (run-time data, never in a file).
    #[serde(skip)]
    pub description: Option<String>,
    /// The tf frame of the URDF's root link: where the tf tree reaches it from the world frame
    /// (`/tf_static`) when tracking starts, the robot stands there instead of at `base_position` /
    /// `base_orientation`. Empty: the root link's name, used if the tf is there; named: `pegs node`
    /// waits for it as long as for the cameras (`node.camera_wait`).
    pub base_frame: String,
}

impl Default for RobotConfig {
    fn default() -> Self {
        Self {
            urdf: None,
            package_paths: Vec::new(),
            base_position: Vec3::ZERO,
            base_orientation: [0.0, 0.0, 0.0, 1.0],
            geometry: GeometrySource::Collision,
            sampling: Sampling::Surface,
            particle_radius: 0.006,
            spacing_per_radius: 2.0,
            contact: RobotContact::Particles,
            stiffness: None,
            colour: None,
            default_colour: Vec3::splat(0.9),
            joint_prefix_received: String::new(),
            joint_prefix_urdf: String::new(),
            description_topic: String::new(),
            description: None,
            base_frame: String::new(),
        }
    }
}

/// A driver's joint name as the URDF has it: `received` replaced by `urdf` at its start (`fr3_`
/// for `panda_`); unchanged when `received` is empty or not its prefix.
pub fn joint_name_for_urdf(name: &str, received: &str, urdf: &str) -> String {
    match name.strip_prefix(received) {
        Some(rest) if !received.is_empty() => format!("{urdf}{rest}"),
        _ => name.to_string(),
    }
}

impl RobotConfig {
    /// Relative paths (the URDF, package directories) made relative to `dir`, the
    /// configuration's folder.
    pub fn resolve_paths(&mut self, dir: &std::path::Path) {
        if let Some(urdf) = &mut self.urdf
            && urdf.is_relative()
        {
            *urdf = dir.join(&*urdf);
        }
        for p in &mut self.package_paths {
            if p.is_relative() {
                *p = dir.join(&*p);
            }
        }
    }

    pub fn base_pose(&self) -> DAffine3 {
        let [x, y, z, w] = self.base_orientation.map(|v| v as f64);
        DAffine3::from_rotation_translation(
            DQuat::from_xyzw(x, y, z, w).normalize(),
            self.base_position.as_dvec3(),
        )
    }

    pub fn validate(&self) -> Result<()> {
        if !(self.particle_radius.is_finite() && self.particle_radius > 0.0) {
            bail!(
                "robot.particle_radius must be positive, got {}",
                self.particle_radius
            );
        }
        if !(self.spacing_per_radius.is_finite() && self.spacing_per_radius > 0.0) {
            bail!(
                "robot.spacing_per_radius must be positive, got {}",
                self.spacing_per_radius
            );
        }
        if let Some(k) = self.stiffness
            && !(k.is_finite() && k > 0.0)
        {
            bail!("robot.stiffness must be positive (N/m) or left out (rigid), got {k}");
        }
        if !self.base_position.is_finite()
            || self.base_orientation.iter().any(|v| !v.is_finite())
            || Quat::from_array(self.base_orientation).length() < 1e-6
        {
            bail!(
                "robot.base_position / base_orientation must be finite and the quaternion non-zero"
            );
        }
        Ok(())
    }
}

fn to_pose(a: &DAffine3) -> Pose {
    let (_, rot, t) = a.to_scale_rotation_translation();
    Pose::new(t.as_vec3(), rot.as_quat().normalize())
}

/// A robot placed in a world: which shape each link became.
/// How objects meet the robot's links (`RobotConfig::contact`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RobotContact {
    /// Sphere against sphere with the links' particles: a pushed face sits in the grooves
    /// between them and cannot slide along the pusher.
    #[default]
    Particles,
    /// Against the URDF's solids (`world::Primitive`), edges rounded by 6 mm. On the 16 pushed
    /// controls of MuJoCo seeds 3000-3003, 3400-3403, 3500-3503, 3600-3603, physics only, the
    /// mean error summed over recordings 162.6 -> 133.1 mm (README, "The robot").
    Exact,
}

#[derive(Clone, Debug)]
pub struct RobotInWorld {
    pub model: RobotModel,
    pub base: DAffine3,
    /// `(link index, shape)` for every link that has geometry.
    pub link_shapes: Vec<(usize, ShapeId)>,
}

impl RobotInWorld {
    /// Sample every link's geometry into a kinematic shape (body frame = link frame) with one
    /// Gaussian per particle, placed at joint positions `q`.
    pub fn add(
        builder: &mut WorldBuilder,
        model: RobotModel,
        q: &[f64],
        config: &RobotConfig,
    ) -> Result<Self> {
        config.validate()?;
        let base = config.base_pose();
        let poses = model.forward_kinematics(q);
        let radius = config.particle_radius;
        let spacing = (radius * config.spacing_per_radius) as f64;
        let mut link_shapes = Vec::new();
        for (li, link) in model.links.iter().enumerate() {
            if link.geometry.is_empty() {
                continue;
            }
            let mut points = Vec::new();
            for g in &link.geometry {
                // Particles of `radius` on the shape shrunk by it: the robot collides where its
                // URDF surface is, not a particle radius outside it.
                let shape = sampling::inset(&g.shape, radius as f64);
                points.extend(
                    sampling::sample(&shape, spacing, config.sampling)
                        .into_iter()
                        .map(|p| g.origin.transform_point3(p)),
                );
            }
            let points: Vec<Vec3> = sampling::thin(points, spacing)
                .into_iter()
                .map(|p| p.as_vec3())
                .collect();
            let colour = config
                .colour
                .or(link.colour)
                .unwrap_or(config.default_colour);
            let shape = builder.add_kinematic(
                &format!("robot/{}", link.name),
                &points,
                radius,
                to_pose(&(base * poses[li])),
                colour,
            );
            if config.contact == RobotContact::Exact {
                let exact: Option<Vec<_>> = link.geometry.iter().map(primitive_of).collect();
                if let Some(exact) = exact {
                    builder.set_primitives(shape, exact);
                }
            }
            if let Some(k) = config.stiffness {
                builder.set_compliance(shape, 1.0 / k);
            }
            // Surface samples are `spacing` apart: Gaussians of half that spread close the gaps, so
            // the robot renders solid and occludes what is behind it.
            builder.set_gaussian_look(shape, 0.5 * spacing as f32, 0.98);
            link_shapes.push((li, shape));
        }
        Ok(Self {
            model,
            base,
            link_shapes,
        })
    }

    /// World poses of the linked shapes for joint positions `q`.
    pub fn link_poses(&self, q: &[f64]) -> Vec<(ShapeId, Pose)> {
        let fk = self.model.forward_kinematics(q);
        self.link_shapes
            .iter()
            .map(|&(li, s)| (s, to_pose(&(self.base * fk[li]))))
            .collect()
    }

    /// Set every link's target for the end of the coming tick (used when no per-substep driver is).
    pub fn set_targets(&self, world: &mut World, q: &[f64]) {
        for (s, pose) in self.link_poses(q) {
            world.shapes.target[s as usize] = pose;
        }
    }

    /// A driver that moves the links by forward kinematics of `trajectory` interpolated at every
    /// substep of the tick that starts at `tick_start` and lasts `dt`.
    pub fn driver<'a>(
        &'a self,
        trajectory: &'a JointTrajectory,
        tick_start: f64,
        dt: f64,
    ) -> RobotDriver<'a> {
        RobotDriver {
            robot: self,
            trajectory,
            tick_start,
            dt,
            cache: None,
        }
    }
}

/// The exact solid of a link's geometry (None for a mesh).
fn primitive_of(g: &model::LinkGeometry) -> Option<crate::world::Primitive> {
    use crate::world::Solid;
    let solid = match g.shape {
        model::Shape::Box { size } => Solid::Box {
            half: (size * 0.5).as_vec3(),
        },
        model::Shape::Cylinder { radius, length } => Solid::Cylinder {
            radius: radius as f32,
            half_length: 0.5 * length as f32,
        },
        model::Shape::Capsule { radius, length } => Solid::Capsule {
            radius: radius as f32,
            half_length: 0.5 * length as f32,
        },
        model::Shape::Sphere { radius } => Solid::Sphere {
            radius: radius as f32,
        },
        model::Shape::Mesh { .. } => return None,
    };
    Some(crate::world::Primitive {
        origin: to_pose(&g.origin),
        solid,
    })
}

/// Forward kinematics per substep (computed once per substep for all links).
pub struct RobotDriver<'a> {
    robot: &'a RobotInWorld,
    trajectory: &'a JointTrajectory,
    tick_start: f64,
    dt: f64,
    cache: Option<(f32, Vec<(ShapeId, Pose)>)>,
}

impl KinematicDriver for RobotDriver<'_> {
    fn pose_at(&mut self, shape: ShapeId, tick_fraction: f32) -> Option<Pose> {
        if self.cache.as_ref().is_none_or(|(f, _)| *f != tick_fraction) {
            let q = self
                .trajectory
                .at(self.tick_start + self.dt * tick_fraction as f64)?;
            self.cache = Some((tick_fraction, self.robot.link_poses(&q)));
        }
        self.cache
            .as_ref()?
            .1
            .iter()
            .find(|(s, _)| *s == shape)
            .map(|(_, p)| *p)
    }
}

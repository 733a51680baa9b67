//! Configuration: every number of the model lives here, with the paper's values as defaults.
//! Files are YAML in the ROS 2 parameter-file layout (`<node>: ros__parameters: {...}`) so the same
//! file serves `pegs node --params-file`; a plain mapping without that wrapper is accepted too.

use crate::physics::Effect;
use anyhow::{Context, Result, bail};
use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The whole configuration file. Sections grow with the system (render, correct, ros, ...).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    pub physics: PhysicsConfig,
    pub robot: crate::robot::RobotConfig,
    pub render: crate::render::RenderSettings,
    pub correct: crate::correct::CorrectConfig,
    pub scene: SceneConfig,
    pub node: crate::ros::NodeConfig,
}

/// Where the tracker's world comes from: a built-in scenario's world (with its tracked object
/// moved by an initial pose error), or objects loaded from files plus a table fitted to the first
/// frames (`init`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SceneConfig {
    /// A name from `pegs scenario list`; when set, `objects` and `table` are not used.
    pub scenario: Option<String>,
    /// Initial pose error of the scenario's tracked object: translation (m) and rotation about z (rad).
    pub offset_position: Vec3,
    pub offset_yaw: f32,
    /// Objects loaded from files.
    pub objects: Vec<ObjectConfig>,
    /// Objects built from the first frames' depth and instance masks (`/<camera>/depth/image_raw`,
    /// `/<camera>/mask/image_raw`).
    pub rgbd_objects: Vec<RgbdObjectConfig>,
    /// Fit the ground plane to the first depth frames (RANSAC) instead of `physics.ground`.
    pub ground_from_depth: bool,
    /// The table as thin-disk Gaussians on the ground plane, fitted to the first frames.
    pub table: Option<TableConfig>,
}

/// An object found in the first RGB-D frames by its instance-mask label.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RgbdObjectConfig {
    pub name: String,
    /// Its value in the mask images (1..=255).
    pub label: u8,
    /// Total mass, kg.
    pub mass: f32,
    pub particle_radius: f32,
    /// A rope (a chain of particles along its centre line) instead of a rigid object.
    pub rope: bool,
    /// Rope only: stiffness of the bending constraints in (0, 1].
    pub bending_stiffness: f32,
}

impl Default for RgbdObjectConfig {
    fn default() -> Self {
        Self {
            name: String::new(),
            label: 1,
            mass: 0.2,
            particle_radius: 0.005,
            rope: false,
            bending_stiffness: 0.3,
        }
    }
}

/// One tracked object loaded from a file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObjectConfig {
    pub name: String,
    /// Object file in the embodied-gaussians JSON format (pose, Gaussians, particles).
    pub embodied_gaussians: PathBuf,
    /// Total mass, kg, shared equally by the particles.
    pub mass: f32,
    /// Colour band that picks this object out of the images: aligns it at the start and measures
    /// the silhouette overlap of the tracking in `pegs replay`.
    pub mask: Option<ColourMask>,
    /// Before tracking, move the object on the table to best match `mask` in the first frames.
    pub align_at_start: bool,
    /// Adam steps fitting the object's colours to the inside of `mask` in the first frame, after
    /// the alignment (the file's colours were captured under other lighting); 0 keeps them.
    pub colour_fit_steps: u32,
    /// Adam steps fitting the Gaussians' opacities and sizes to `mask` in the first frames, after
    /// the table is fitted; 0 keeps them.
    pub silhouette_fit_steps: u32,
}

impl Default for ObjectConfig {
    fn default() -> Self {
        Self {
            name: String::new(),
            embodied_gaussians: PathBuf::new(),
            mass: 0.2,
            mask: None,
            align_at_start: true,
            colour_fit_steps: 100,
            silhouette_fit_steps: 100,
        }
    }
}

/// The table: a grid of flat Gaussians on the ground plane over a rectangle of world x, y.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TableConfig {
    pub min: Vec2,
    pub max: Vec2,
    /// Grid spacing, m.
    pub spacing: f32,
    /// Adam steps on the disks' colours, and frames used per camera: the first one and others
    /// spread over the first `fit_span` seconds (0: the first frames).
    pub fit_steps: u32,
    pub fit_frames: u32,
    pub fit_span: f32,
    pub lr: f32,
    /// The fit renders at this fraction of the camera resolution (the disks are coarser than pixels).
    pub fit_resolution: f32,
    /// The disks lie this far (m) below the ground plane: object Gaussians that reach into the
    /// table (the soft bottom of a reconstruction) would otherwise be hidden by it, and the
    /// photometric loss would lift the object to show them.
    pub drop: f32,
}

impl Default for TableConfig {
    fn default() -> Self {
        Self {
            min: Vec2::splat(-0.5),
            max: Vec2::splat(0.5),
            spacing: 0.01,
            fit_steps: 500,
            fit_frames: 3,
            fit_span: 0.0,
            lr: 0.02,
            fit_resolution: 0.5,
            drop: 0.01,
        }
    }
}

pub use crate::init::ColourMask;

impl SceneConfig {
    pub fn validate(&self) -> Result<()> {
        for o in &self.objects {
            if o.name.is_empty() || !(o.mass.is_finite() && o.mass > 0.0) {
                bail!(
                    "scene.objects: every object needs a name and a positive mass ('{}', {})",
                    o.name,
                    o.mass
                );
            }
        }
        for o in &self.rgbd_objects {
            if o.name.is_empty()
                || o.label == 0
                || !(o.mass.is_finite() && o.mass > 0.0)
                || !(o.particle_radius.is_finite() && o.particle_radius > 0.0)
            {
                bail!(
                    "scene.rgbd_objects: '{}' needs a name, a label of 1 to 255, a positive mass and particle radius",
                    o.name
                );
            }
            if o.rope && !(o.bending_stiffness > 0.0 && o.bending_stiffness <= 1.0) {
                bail!(
                    "scene.rgbd_objects: rope '{}' needs bending_stiffness in (0, 1]",
                    o.name
                );
            }
        }
        if let Some(t) = &self.table {
            let cells = ((t.max - t.min) / t.spacing).max_element();
            if !(t.spacing.is_finite() && t.spacing > 0.0)
                || !(t.min.cmplt(t.max).all())
                || !(cells <= 2000.0)
            {
                bail!(
                    "scene.table: spacing must be positive, min below max, at most 2000 disks a side"
                );
            }
            if !(t.fit_resolution > 0.0 && t.fit_resolution <= 1.0)
                || !(t.lr.is_finite() && t.lr >= 0.0)
                || !(t.fit_span.is_finite() && t.fit_span >= 0.0)
                || !t.drop.is_finite()
            {
                bail!("scene.table: fit_resolution in (0, 1], lr and fit_span >= 0, drop finite");
            }
        }
        Ok(())
    }
}

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
            distance_sweeps: 4,
            ground: GroundConfig::default(),
            collisions: CollisionConfig::default(),
            effects: Vec::new(),
        }
    }
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
}

impl Default for GroundConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            normal: Vec3::Z,
            height: 0.0,
            static_friction: 0.5,
            kinetic_friction: 0.4,
        }
    }
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

impl Config {
    /// Parse YAML text, with or without the ROS `<node>: ros__parameters:` wrapper.
    pub fn from_yaml(text: &str) -> Result<Self> {
        let value: serde_yaml_ng::Value =
            serde_yaml_ng::from_str(text).context("configuration is not valid YAML")?;
        let params = ros_parameters(&value).unwrap_or(&value);
        let config: Config = if params.is_null() {
            Config::default()
        } else {
            serde_yaml_ng::from_value(params.clone())
                .context("configuration does not match the expected fields")?
        };
        config.validated()
    }

    /// This configuration checked field by field (the ground normal normalised).
    pub fn validated(mut self) -> Result<Self> {
        self.physics.ground.normal = self.physics.ground.normal.normalize_or(Vec3::Z);
        self.physics.validate()?;
        self.robot.validate()?;
        self.correct.validate()?;
        self.scene.validate()?;
        self.node.validate()?;
        Ok(self)
    }

    /// YAML in the ROS 2 parameter-file layout under the node name `pegs`.
    pub fn to_yaml(&self) -> Result<String> {
        let mut params = serde_yaml_ng::Mapping::new();
        params.insert("ros__parameters".into(), serde_yaml_ng::to_value(self)?);
        let mut root = serde_yaml_ng::Mapping::new();
        root.insert("pegs".into(), params.into());
        Ok(serde_yaml_ng::to_string(&root)?)
    }

    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read configuration {}", path.display()))?;
        Self::from_yaml(&text).with_context(|| format!("in configuration {}", path.display()))
    }
}

/// The `ros__parameters` mapping of the first node in a ROS 2 parameter file, if it is one.
pub(crate) fn ros_parameters(value: &serde_yaml_ng::Value) -> Option<&serde_yaml_ng::Value> {
    let map = value.as_mapping()?;
    map.values()
        .find_map(|node| node.as_mapping()?.get("ros__parameters"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_config_parses_and_matches_defaults() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/pegs.yaml");
        let c = Config::load(&path).expect("config/pegs.yaml must load");
        assert_eq!(
            c,
            Config::default(),
            "config/pegs.yaml documents the defaults; keep them equal"
        );
    }

    #[test]
    fn shipped_node_config_for_the_franka_rig_parses() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/franka_3xd455.yaml");
        let c = Config::load(&path).expect("config/franka_3xd455.yaml must load");
        assert_eq!(c.node.cameras.len(), 3);
        assert!(c.robot.urdf.is_some());
    }

    #[test]
    fn written_configuration_reads_back_equal() {
        let mut c = Config::default();
        c.physics.substeps = 11;
        c.scene.scenario = Some("pushed_box".into());
        assert_eq!(Config::from_yaml(&c.to_yaml().unwrap()).unwrap(), c);
    }

    #[test]
    fn plain_mapping_and_ros_wrapper_are_both_accepted() {
        let plain = Config::from_yaml("physics:\n  substeps: 7\n").unwrap();
        let ros = Config::from_yaml("pegs:\n  ros__parameters:\n    physics:\n      substeps: 7\n")
            .unwrap();
        assert_eq!(plain.physics.substeps, 7);
        assert_eq!(plain, ros);
        assert_eq!(Config::from_yaml("").unwrap(), Config::default());
    }

    #[test]
    fn bad_values_are_rejected_with_the_field_name() {
        let e = Config::from_yaml("physics:\n  dt: -1\n").unwrap_err();
        assert!(format!("{e:#}").contains("physics.dt"), "{e:#}");
        let e = Config::from_yaml("physics:\n  damping: 1.5\n").unwrap_err();
        assert!(format!("{e:#}").contains("damping"), "{e:#}");
        let e = Config::from_yaml("physics:\n  substepz: 3\n").unwrap_err();
        assert!(format!("{e:#}").contains("substepz"), "{e:#}");
    }

    #[test]
    fn bad_scene_values_are_rejected() {
        let e = Config::from_yaml("scene:\n  rgbd_objects:\n    - {name: box, label: 0}\n")
            .unwrap_err();
        assert!(format!("{e:#}").contains("rgbd_objects"), "{e:#}");
        let e = Config::from_yaml("scene:\n  table: {min: [0, 0], max: [1, 1], spacing: 0}\n")
            .unwrap_err();
        assert!(format!("{e:#}").contains("scene.table"), "{e:#}");
        let e = Config::from_yaml(
            "scene:\n  objects:\n    - {name: t, embodied_gaussians: t.json, mass: -1}\n",
        )
        .unwrap_err();
        assert!(format!("{e:#}").contains("scene.objects"), "{e:#}");
        assert!(Config::from_yaml("scene:\n  table: {min: [0, 0], max: [1, 1]}\n").is_ok());
    }

    #[test]
    fn effects_are_read_by_name() {
        let c = Config::from_yaml(
            "physics:\n  effects:\n    - effect: viscous_drag\n      object: box\n      coefficient: 0.5\n    - effect: table_tilt\n      angle: 0.01\n      azimuth: 0.0\n",
        )
        .unwrap();
        assert_eq!(c.physics.effects.len(), 2);
        assert_eq!(c.physics.effects[0].name(), "viscous_drag");
        assert_eq!(c.physics.effects[1].parameters()[0], ("angle", 0.01));
    }
}

/// A model file: physical effects a diagnosis added to the base model (`pegs diagnose` writes
/// it; `pegs replay --model` and the node load it on top of their configuration).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ModelFile {
    /// What produced the file (free text).
    pub source: String,
    pub effects: Vec<Effect>,
}

impl ModelFile {
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read model file {}", path.display()))?;
        let model: ModelFile = serde_yaml_ng::from_str(&text)
            .with_context(|| format!("in model file {}", path.display()))?;
        for e in &model.effects {
            e.validate()
                .with_context(|| format!("in model file {}", path.display()))?;
        }
        Ok(model)
    }

    pub fn save(&self, path: &Path) -> Result<()> {
        std::fs::write(path, serde_yaml_ng::to_string(self)?)
            .with_context(|| format!("cannot write {}", path.display()))
    }

    /// `config` with this file's effects added to its physics.
    pub fn apply(&self, config: &Config) -> Config {
        let mut c = config.clone();
        c.physics.effects.extend(self.effects.iter().cloned());
        c
    }
}

#[cfg(test)]
mod model_file_tests {
    use super::*;

    #[test]
    fn a_model_file_round_trips_and_adds_its_effects() {
        let dir = std::env::temp_dir().join(format!("pegs-model-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("model.yaml");
        let model = ModelFile {
            source: "test".into(),
            effects: vec![Effect::ViscousDrag {
                object: Some("box".into()),
                coefficient: 0.9,
            }],
        };
        model.save(&path).unwrap();
        assert_eq!(ModelFile::load(&path).unwrap(), model);
        let config = model.apply(&Config::default());
        assert_eq!(config.physics.effects, model.effects);
        std::fs::write(
            &path,
            "effects:\n  - effect: viscous_drag\n    coefficient: -1.0\n",
        )
        .unwrap();
        assert!(
            format!("{:#}", ModelFile::load(&path).unwrap_err())
                .contains("coefficient must be >= 0")
        );
    }
}

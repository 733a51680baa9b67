//! Configuration: assembles the sections, each defined and validated beside what it configures
//! (`physics::PhysicsConfig`, `robot::RobotConfig`, `render::RenderSettings`,
//! `correct::CorrectConfig`, `init::SceneConfig`, `topics::NodeConfig`), loads them and saves
//! them. Files are YAML in the ROS 2 parameter-file layout (`<node>: ros__parameters: {...}`) so
//! the same file serves `pegs node --params-file`; a plain mapping without that wrapper is
//! accepted too. A model file (`ModelFile`) adds a diagnosis's effects to a configuration.

use crate::correct::CorrectConfig;
use crate::init::SceneConfig;
use crate::physics::{Effect, PhysicsConfig};
use crate::render::RenderSettings;
use crate::robot::RobotConfig;
use crate::topics::NodeConfig;
use anyhow::{Context, Result};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The whole configuration file: one field per section.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    pub physics: PhysicsConfig,
    pub robot: RobotConfig,
    pub render: RenderSettings,
    pub correct: CorrectConfig,
    pub scene: SceneConfig,
    pub node: NodeConfig,
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

    /// Every file the configuration names exists (the URDF, object files): checked before a
    /// replay or the node starts, so a typo is an error at once and not after the cameras come.
    pub fn check_files(&self) -> Result<()> {
        let named = self.robot.urdf.iter().map(|p| ("robot.urdf", p)).chain(
            self.scene
                .objects
                .iter()
                .map(|o| ("scene.objects[].embodied_gaussians", &o.embodied_gaussians)),
        );
        for (setting, path) in named {
            if !path.is_file() {
                anyhow::bail!("{setting}: {} does not exist", path.display());
            }
        }
        Ok(())
    }

    /// What initialisation reads: the scene section, the robot, the ground and the renderer.
    pub fn init(&self) -> crate::init::Settings<'_> {
        crate::init::Settings {
            scene: &self.scene,
            robot: &self.robot,
            ground: &self.physics.ground,
            render: &self.render,
        }
    }

    /// YAML in the ROS 2 parameter-file layout under the node name `pegs`.
    pub fn to_yaml(&self) -> Result<String> {
        let mut params = serde_yaml_ng::Mapping::new();
        params.insert("ros__parameters".into(), serde_yaml_ng::to_value(self)?);
        let mut root = serde_yaml_ng::Mapping::new();
        root.insert("pegs".into(), params.into());
        Ok(serde_yaml_ng::to_string(&root)?)
    }

    /// Load a configuration file; relative paths in it (URDF, package paths, object files) are
    /// relative to the file's folder, wherever pegs is started from.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read configuration {}", path.display()))?;
        let mut config = Self::from_yaml(&text)
            .with_context(|| format!("in configuration {}", path.display()))?;
        let dir = path.parent().unwrap_or(Path::new("."));
        config.robot.resolve_paths(dir);
        config.scene.resolve_paths(dir);
        Ok(config)
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
        c.scene.check_tracks_something().unwrap();
        // Relative paths are relative to the file, not to where pegs runs.
        let urdf = c.robot.urdf.expect("a robot");
        assert!(urdf.is_file(), "{} resolves to a file", urdf.display());
        let mut empty = c.scene.clone();
        empty.rgbd_objects.clear();
        let e = format!("{:#}", empty.check_tracks_something().unwrap_err());
        assert!(e.contains("scene.rgbd_objects"), "{e}");
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
    use crate::physics::effects::ViscousDrag;

    #[test]
    fn a_model_file_round_trips_and_adds_its_effects() {
        let dir = std::env::temp_dir().join(format!("pegs-model-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("model.yaml");
        let model = ModelFile {
            source: "test".into(),
            effects: vec![Effect::ViscousDrag(ViscousDrag {
                object: Some("box".into()),
                coefficient: 0.9,
            })],
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

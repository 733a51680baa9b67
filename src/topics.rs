//! The `node` section of the configuration: how pegs meets the ROS graph. Camera names, the topic
//! and frame templates of each camera (`{camera}` stands for its name), the joint-states topic,
//! the world frame, and the names and rates of what the node publishes. Shared by `pegs node` and
//! the tools that read recordings, so live and offline use the same names.

use anyhow::{Result, bail};
use serde::{Deserialize, Serialize};

/// Topics, frames and output rates of the node. Camera topics are templates in which
/// `{camera}` stands for each name in `cameras`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NodeConfig {
    pub cameras: Vec<String>,
    pub image_topic: String,
    pub camera_info_topic: String,
    /// Depth (32FC1 in metres, or 16UC1 in `depth_unit`s) and instance masks (mono8): read once,
    /// to initialise a scene from RGB-D.
    pub depth_topic: String,
    pub mask_topic: String,
    /// Metres per unit of 16UC1 depth (realsense2_camera publishes millimetres: 0.001).
    pub depth_unit: f32,
    /// Each camera's optical frame (z forward, y down), looked up on /tf_static.
    pub optical_frame: String,
    pub joint_states_topic: String,
    pub world_frame: String,
    /// Prefix of every output topic: `{prefix}/objects`, `{prefix}/poses`, `{prefix}/particles`,
    /// `{prefix}/debug/{camera}/image` (and `/compressed`).
    pub output_prefix: String,
    /// Render and publish debug images every N ticks (0: never).
    pub debug_images_every: u32,
    /// Seconds between diagnostics messages.
    pub diagnostics_period: f32,
}

impl Default for NodeConfig {
    fn default() -> Self {
        Self {
            cameras: vec!["cam0".into(), "cam1".into(), "cam2".into()],
            image_topic: "/{camera}/color/image_raw".into(),
            camera_info_topic: "/{camera}/color/camera_info".into(),
            depth_topic: "/{camera}/depth/image_raw".into(),
            mask_topic: "/{camera}/mask/image_raw".into(),
            depth_unit: 0.001,
            optical_frame: "{camera}_color_optical_frame".into(),
            joint_states_topic: "/joint_states".into(),
            world_frame: "world".into(),
            output_prefix: "/pegs".into(),
            debug_images_every: 10,
            diagnostics_period: 1.0,
        }
    }
}

impl NodeConfig {
    pub fn validate(&self) -> Result<()> {
        if self.cameras.is_empty() {
            bail!("node.cameras must name at least one camera");
        }
        for (name, t) in [
            ("image_topic", &self.image_topic),
            ("camera_info_topic", &self.camera_info_topic),
            ("optical_frame", &self.optical_frame),
        ] {
            if !t.contains("{camera}") {
                bail!("node.{name} must contain {{camera}}, got '{t}'");
            }
        }
        if !(self.depth_unit.is_finite() && self.depth_unit > 0.0) {
            bail!("node.depth_unit must be > 0 m, got {}", self.depth_unit);
        }
        if !(self.diagnostics_period.is_finite() && self.diagnostics_period > 0.0) {
            bail!(
                "node.diagnostics_period must be > 0, got {}",
                self.diagnostics_period
            );
        }
        Ok(())
    }

    /// `template` with `{camera}` replaced.
    pub fn for_camera(template: &str, camera: &str) -> String {
        template.replace("{camera}", camera)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn camera_templates_expand_and_templates_without_a_camera_are_refused() {
        let c = NodeConfig::default();
        assert_eq!(
            NodeConfig::for_camera(&c.image_topic, "cam1"),
            "/cam1/color/image_raw"
        );
        assert_eq!(
            NodeConfig::for_camera(&c.optical_frame, "cam1"),
            "cam1_color_optical_frame"
        );
        c.validate().unwrap();
        let fixed = NodeConfig {
            image_topic: "/color/image_raw".into(),
            ..c.clone()
        };
        assert!(format!("{:#}", fixed.validate().unwrap_err()).contains("image_topic"));
        let none = NodeConfig {
            cameras: vec![],
            ..c
        };
        assert!(none.validate().is_err());
    }
}

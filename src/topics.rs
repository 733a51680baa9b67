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
    /// Camera names. Empty: `pegs replay` uses every camera whose topics match the templates;
    /// `pegs node` needs them named.
    pub cameras: Vec<String>,
    pub image_topic: String,
    pub camera_info_topic: String,
    /// Depth (32FC1 in metres, or 16UC1 in `depth_unit`s) and instance masks (mono8): read to
    /// initialise a scene from RGB-D, and depth on for the pose search where
    /// `correct.pose_search_depth` is set.
    pub depth_topic: String,
    pub mask_topic: String,
    /// Metres per unit of 16UC1 depth (realsense2_camera publishes millimetres: 0.001).
    pub depth_unit: f32,
    /// Each camera's optical frame (z forward, y down), found in the tf tree from `world_frame`.
    /// Empty: the `frame_id` of the camera's images and CameraInfo.
    pub optical_frame: String,
    pub joint_states_topic: String,
    pub world_frame: String,
    /// Seconds the node waits for every camera's CameraInfo and pose before it starts with those
    /// it has; a camera ready later joins at the next tick.
    pub camera_wait: f32,
    /// Prefix of every output topic: `{prefix}/objects`, `{prefix}/poses`, `{prefix}/particles`,
    /// `{prefix}/debug/{camera}/image` (and `/compressed`). Topic names resolve as in rcl: `/x`
    /// absolute, `~` the node's own name (`/pegs` by default, `/ns/pegs` in a namespace), any other
    /// name under the node's namespace (`joint_states` is `/joint_states`, or `/ns/joint_states`).
    /// A recording has no namespace: there both are taken from the root.
    pub output_prefix: String,
    /// Render and publish debug images every N ticks (0: never).
    pub debug_images_every: u32,
    /// Seconds between diagnostics messages.
    pub diagnostics_period: f32,
    /// The node's clock is `/clock` (`ros2 bag play --clock`, a simulator) instead of the wall
    /// clock: ticks wait for it, and images and outputs are judged and stamped on it. The ROS
    /// parameter is `use_sim_time`, as for every node.
    pub use_sim_time: bool,
}

impl Default for NodeConfig {
    fn default() -> Self {
        Self {
            cameras: Vec::new(),
            image_topic: "/camera/{camera}/color/image_raw".into(),
            camera_info_topic: "/camera/{camera}/color/camera_info".into(),
            depth_topic: "/camera/{camera}/aligned_depth_to_color/image_raw".into(),
            mask_topic: "/camera/{camera}/mask/image_raw".into(),
            depth_unit: 0.001,
            optical_frame: String::new(),
            joint_states_topic: "joint_states".into(),
            world_frame: "world".into(),
            camera_wait: 5.0,
            output_prefix: "~".into(),
            debug_images_every: 10,
            diagnostics_period: 1.0,
            use_sim_time: false,
        }
    }
}

impl NodeConfig {
    pub fn validate(&self) -> Result<()> {
        for (name, t) in [
            ("image_topic", &self.image_topic),
            ("camera_info_topic", &self.camera_info_topic),
            ("depth_topic", &self.depth_topic),
            ("mask_topic", &self.mask_topic),
        ] {
            if !t.contains("{camera}") {
                bail!("node.{name} must contain {{camera}}, got '{t}'");
            }
        }
        if !self.optical_frame.is_empty() && !self.optical_frame.contains("{camera}") {
            bail!(
                "node.optical_frame must be empty (the images' frame_id) or contain {{camera}}, \
                 got '{}'",
                self.optical_frame
            );
        }
        if !(self.depth_unit.is_finite() && self.depth_unit > 0.0) {
            bail!("node.depth_unit must be > 0 m, got {}", self.depth_unit);
        }
        if !(self.camera_wait.is_finite() && self.camera_wait >= 0.0) {
            bail!("node.camera_wait must be >= 0 s, got {}", self.camera_wait);
        }
        if !(self.diagnostics_period.is_finite() && self.diagnostics_period > 0.0) {
            bail!(
                "node.diagnostics_period must be > 0, got {}",
                self.diagnostics_period
            );
        }
        Ok(())
    }

    /// What `pegs node` needs beyond `validate`: the cameras named.
    pub fn validate_live(&self) -> Result<()> {
        if self.cameras.is_empty() {
            bail!(
                "node.cameras must name at least one camera (e.g. node.cameras: [cam_left, \
                 cam_right, cam_top], the camera_name each realsense2_camera driver was given)"
            );
        }
        Ok(())
    }

    /// `name` as an absolute topic name in a recording (no namespace: relative names from the
    /// root).
    pub fn in_recording(name: &str) -> String {
        format!(
            "/{}",
            name.trim_start_matches(['/', '~']).trim_start_matches('/')
        )
    }

    /// `template` with `{camera}` replaced.
    pub fn for_camera(template: &str, camera: &str) -> String {
        template.replace("{camera}", camera)
    }

    /// The camera whose name fills `{camera}` in `template` to give `topic`, if any (a name is
    /// one path segment: no '/').
    pub fn camera_in(template: &str, topic: &str) -> Option<String> {
        let (before, after) = template.split_once("{camera}")?;
        let name = topic.strip_prefix(before)?.strip_suffix(after)?;
        (!name.is_empty() && !name.contains('/')).then(|| name.to_string())
    }

    /// Camera `camera`'s optical frame: the template's, or `header_frame` when the template is
    /// empty (then the images' own frame_id).
    pub fn optical_frame_of(&self, camera: &str, header_frame: &str) -> String {
        if self.optical_frame.is_empty() {
            header_frame.trim_start_matches('/').to_string()
        } else {
            Self::for_camera(&self.optical_frame, camera)
        }
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
            "/camera/cam1/color/image_raw"
        );
        c.validate().unwrap();
        let fixed = NodeConfig {
            image_topic: "/color/image_raw".into(),
            ..c.clone()
        };
        assert!(format!("{:#}", fixed.validate().unwrap_err()).contains("image_topic"));
        assert!(c.validate_live().is_err(), "the node needs cameras named");
        assert_eq!(
            NodeConfig::camera_in(&c.image_topic, "/camera/left/color/image_raw"),
            Some("left".into())
        );
        for other in [
            "/camera/left/depth/image_raw",
            "/camera//color/image_raw",
            "/camera/a/b/color/image_raw",
            "/left/color/image_raw",
        ] {
            assert_eq!(
                NodeConfig::camera_in(&c.image_topic, other),
                None,
                "{other}"
            );
        }
        assert_eq!(
            c.optical_frame_of("left", "left_color_optical_frame"),
            "left_color_optical_frame"
        );
        let named = NodeConfig {
            optical_frame: "{camera}_optical".into(),
            ..c
        };
        assert_eq!(named.optical_frame_of("left", "whatever"), "left_optical");
    }
}

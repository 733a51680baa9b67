//! `pegs bag info`: what pegs will use from a bag with a configuration, from one streaming pass
//! (`recording::Survey`): the cameras its `node` templates find (topic, encoding, image count and
//! rate, CameraInfo, the tf chain to the optical frame or why there is none, depth and masks),
//! the joint states and their names matched against the configured URDF, and every warning the
//! replay would give. Reads only; prints nothing itself.

use super::recording::Survey;
use crate::config::Config;
use anyhow::{Context, Result};
use serde::Serialize;
use std::fmt;
use std::path::Path;

#[derive(Serialize)]
pub struct BagInfo {
    #[serde(flatten)]
    pub survey: Survey,
    /// Cameras the replay would use.
    pub usable_cameras: Vec<String>,
    /// The URDF's movable joints found in the joint states, and those not found.
    pub urdf_joints_matched: Vec<String>,
    pub urdf_joints_missing: Vec<String>,
    /// Joint-state names the URDF does not have (ignored by the replay).
    pub unknown_joints: Vec<String>,
    pub warnings: Vec<String>,
}

/// Survey `bag` with `config`'s templates and robot.
pub fn info(bag: &Path, config: &Config) -> Result<BagInfo> {
    let mut warnings = Vec::new();
    let survey = Survey::of(bag, &config.node, &mut warnings)?;
    let usable_cameras = survey
        .cameras
        .iter()
        .filter(|c| c.unusable.is_none())
        .map(|c| c.name.clone())
        .collect();
    let movable = match &config.robot.urdf {
        Some(path) => urdf_rs::read_file(path)
            .with_context(|| format!("cannot read URDF {}", path.display()))?
            .joints
            .into_iter()
            .filter(|j| !matches!(j.joint_type, urdf_rs::JointType::Fixed))
            .map(|j| j.name)
            .collect(),
        None => Vec::new(),
    };
    // The names as the replay will see them, after robot.joint_prefix_* (fr3_ -> panda_).
    let robot = &config.robot;
    let renamed: Vec<String> = survey
        .joint_names
        .iter()
        .map(|j| {
            let (received, urdf) = (&robot.joint_prefix_received, &robot.joint_prefix_urdf);
            crate::robot::joint_name_for_urdf(j, received, urdf)
        })
        .collect();
    let (matched, missing) = movable.iter().cloned().partition(|j| renamed.contains(j));
    let unknown_joints = survey
        .joint_names
        .iter()
        .zip(&renamed)
        .filter(|(_, r)| config.robot.urdf.is_some() && !movable.contains(r))
        .map(|(j, _)| j.clone())
        .collect();
    Ok(BagInfo {
        survey,
        usable_cameras,
        urdf_joints_matched: matched,
        urdf_joints_missing: missing,
        unknown_joints,
        warnings,
    })
}

impl fmt::Display for BagInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = &self.survey;
        writeln!(
            f,
            "{}: {} storage, {} messages over {:.1} s, {} topics",
            s.path,
            s.storage,
            s.messages,
            s.duration_s,
            s.topics.len()
        )?;
        writeln!(f, "cameras ({} usable):", self.usable_cameras.len())?;
        for c in &s.cameras {
            let status = c.unusable.as_deref().unwrap_or("used");
            writeln!(f, "  {}: {status}", c.name)?;
            writeln!(
                f,
                "    colour {} [{}], {} images at {:.1} Hz",
                c.topic, c.encoding, c.images, c.rate_hz
            )?;
            let chain = if c.tf_chain.is_empty() {
                "none".to_string()
            } else {
                c.tf_chain.join(" -> ")
            };
            let moving = if c.moving { " (moving: /tf)" } else { "" };
            writeln!(f, "    frame {}, tf {chain}{moving}", c.frame)?;
            writeln!(
                f,
                "    CameraInfo {}, depth {}, masks {}",
                if c.has_camera_info { "yes" } else { "no" },
                c.depth.as_deref().unwrap_or("none"),
                c.masks
                    .as_deref()
                    .unwrap_or("none (clusters of depth points)")
            )?;
        }
        writeln!(
            f,
            "joint states: {} messages, {} names",
            s.joint_states,
            s.joint_names.len()
        )?;
        if !self.urdf_joints_matched.is_empty() || !self.urdf_joints_missing.is_empty() {
            writeln!(
                f,
                "  URDF joints matched {}/{}{}",
                self.urdf_joints_matched.len(),
                self.urdf_joints_matched.len() + self.urdf_joints_missing.len(),
                if self.urdf_joints_missing.is_empty() {
                    String::new()
                } else {
                    format!("; missing: {}", self.urdf_joints_missing.join(", "))
                }
            )?;
        }
        if !self.unknown_joints.is_empty() {
            writeln!(f, "  not in the URDF: {}", self.unknown_joints.join(", "))?;
        }
        for w in &self.warnings {
            writeln!(f, "warning: {w}")?;
        }
        Ok(())
    }
}

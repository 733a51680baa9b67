//! The robot as a rig has it: its URDF as robot_state_publisher offers it (`robot.description_topic`,
//! received live or found in a recording) and its base where the rig's tf tree puts it. Shared by
//! `pegs node` and `pegs replay`, so live and offline place the robot alike.
//!
//! Owns only where the robot's description and base come from; building it is `init`'s.

use crate::record::TfTree;
use crate::robot::{RobotConfig, root_link_name};
use anyhow::{Context, Result};

/// `robot` with the URDF text received on its `description_topic` (`description`; required when
/// that topic is set), standing where `tf` puts its base frame (the URDF's root link unless
/// `robot.base_frame` names another) from `world`, if the tree reaches it; else at the configured
/// `base_position` / `base_orientation`. With it, a line saying where the base came from (None
/// without a robot).
pub fn rig_robot(
    robot: &RobotConfig,
    description: Option<&str>,
    tf: &TfTree,
    world: &str,
) -> Result<(RobotConfig, Option<String>)> {
    let mut robot = robot.clone();
    let topic = &robot.description_topic;
    if !topic.is_empty() {
        let text = description.with_context(|| format!("no URDF received on {topic}"))?;
        robot.description = Some(text.to_string());
    }
    let text = match (&robot.description, &robot.urdf) {
        (Some(text), _) => text.clone(),
        (None, Some(path)) => std::fs::read_to_string(path)
            .with_context(|| format!("cannot read URDF {}", path.display()))?,
        (None, None) => return Ok((robot, None)),
    };
    let frame = match robot.base_frame.is_empty() {
        true => root_link_name(&text)?,
        false => robot.base_frame.clone(),
    };
    let line = match tf.lookup_nearest(world, &frame, 0.0) {
        Ok(world_from_base) => {
            robot.base_position = world_from_base.translation;
            robot.base_orientation = world_from_base.rotation.to_array();
            format!(
                "robot base from tf {world} -> {frame}: position {:?}, orientation (x, y, z, w) {:?}",
                robot.base_position.to_array(),
                robot.base_orientation
            )
        }
        Err(why) => format!(
            "robot base: no tf {world} -> {frame} ({why}); robot.base_position {:?} used",
            robot.base_position.to_array()
        ),
    };
    Ok((robot, Some(line)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Header, Quaternion, TfMessage, Transform, TransformStamped, Vector3};

    /// The base follows the tf tree where it reaches the root link, the configuration where it
    /// does not; a description topic without a description is an error naming it.
    #[test]
    fn the_robot_stands_where_tf_puts_its_root_link_else_where_configured() {
        let urdf = include_str!("../../urdf/panda_pusher.urdf");
        let mut robot = RobotConfig {
            description_topic: "/robot_description".into(),
            base_position: glam::Vec3::new(0.0, 0.0, 0.5),
            ..Default::default()
        };
        let mut tf = TfTree::default();
        let (placed, line) = rig_robot(&robot, Some(urdf), &tf, "world").unwrap();
        assert_eq!(placed.base_position, robot.base_position);
        assert!(line.unwrap().contains("no tf world -> panda_link0"));
        let edge = TransformStamped {
            header: Header {
                frame_id: "world".into(),
                ..Default::default()
            },
            child_frame_id: "panda_link0".into(),
            transform: Transform {
                translation: Vector3 {
                    x: 0.3,
                    y: -0.1,
                    z: 0.0,
                },
                rotation: Quaternion {
                    w: 1.0,
                    ..Default::default()
                },
            },
        };
        let refused = tf.add(
            &TfMessage {
                transforms: vec![edge],
            },
            true,
        );
        assert!(refused.is_empty(), "{refused:?}");
        let (placed, line) = rig_robot(&robot, Some(urdf), &tf, "world").unwrap();
        assert!((placed.base_position - glam::Vec3::new(0.3, -0.1, 0.0)).length() < 1e-6);
        assert!(placed.description.is_some() && line.unwrap().contains("from tf"));
        let e = rig_robot(&robot, None, &tf, "world").unwrap_err();
        assert!(format!("{e:#}").contains("/robot_description"));
        robot.description_topic.clear();
        assert!(
            rig_robot(&robot, None, &tf, "world").unwrap().1.is_none(),
            "no robot"
        );
    }
}

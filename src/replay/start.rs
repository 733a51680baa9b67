//! The world a replay starts from: a built-in scenario's (with its configured start error), or one
//! initialised from the recording's first frames (`init`): the first image of every camera and
//! images spread over the table's fit span (picked by `recording`), the first depth and mask
//! images, the first joint states.

use super::Metrics;
use super::recording::Streams;
use crate::config::Config;
use crate::init::{self, FirstFrames};
use crate::inputs::{decode_depth, decode_image, decode_labels};
use crate::math::Pose;
use crate::scenario;
use crate::scene::Scene;
use anyhow::Result;
use glam::{Quat, Vec3};

/// The start scene and, when initialisation fitted one, the ground plane (normal, height).
pub fn scene(
    streams: &Streams,
    config: &Config,
    progress: bool,
    metrics: &mut Metrics,
) -> Result<(Scene, Option<(Vec3, f32)>)> {
    let scene_config = &config.scene;
    if let Some(name) = scene_config.scenario.as_deref() {
        let offset = Pose::new(
            scene_config.offset_position,
            Quat::from_rotation_z(scene_config.offset_yaw),
        );
        return Ok((scenario::build(name, offset)?, None));
    }
    let mut depths = Vec::new();
    let mut labels = Vec::new();
    let mut colour = Vec::new();
    for stream in &streams.cameras {
        let (name, cam) = (&stream.name, &stream.camera);
        let mut unused = |what: &str, why: String| {
            metrics
                .warnings
                .push(format!("camera {name}: {what} not used: {why}"))
        };
        colour.push(
            stream
                .first_images
                .iter()
                .filter_map(|(_, i)| {
                    decode_image(i, cam)
                        .map_err(|why| unused("a first image", why))
                        .ok()
                })
                .collect::<Vec<_>>(),
        );
        let unit = config.node.depth_unit;
        let depth = stream.depth.as_ref().map(|i| decode_depth(i, cam, unit));
        depths.push(depth.and_then(|d| d.map_err(|why| unused("depth", why)).ok()));
        let mask = stream.mask.as_ref().map(|i| decode_labels(i, cam));
        labels.push(mask.and_then(|m| m.map_err(|why| unused("masks", why)).ok()));
    }
    let frames: Vec<FirstFrames> = streams
        .cameras
        .iter()
        .zip(&colour)
        .zip(depths.iter().zip(&labels))
        .map(|((stream, images), (d, l))| FirstFrames {
            name: stream.name.clone(),
            camera: stream.camera,
            images: images.iter().map(|i| i.as_slice()).collect(),
            depth: d.as_deref(),
            labels: l.as_deref(),
        })
        .collect();
    let first_joints: Vec<(String, f64)> = streams
        .joint_states
        .first()
        .map(|(_, js)| {
            js.name
                .iter()
                .cloned()
                .zip(js.position.iter().copied())
                .collect()
        })
        .unwrap_or_default();
    if progress {
        eprintln!(
            "initialising the scene from the first frames of {} cameras",
            frames.len()
        );
    }
    // The robot as the rig had it: the URDF recorded on `robot.description_topic`, the base where
    // the recording's tf puts it.
    let topic = crate::topics::NodeConfig::in_recording(&config.robot.description_topic);
    let description = streams.robot_descriptions.get(&topic).map(String::as_str);
    if description.is_none() && !config.robot.description_topic.is_empty() {
        anyhow::bail!(
            "robot.description_topic: no URDF on {topic} in the recording (robot descriptions \
             found: {:?}); set robot.urdf instead",
            streams.robot_descriptions.keys().collect::<Vec<_>>()
        );
    }
    let world = &config.node.world_frame;
    let (robot, line) = init::rig::rig_robot(&config.robot, description, &streams.tf, world)?;
    if let Some(line) = line {
        eprintln!("{line}");
    }
    let settings = init::Settings {
        robot: &robot,
        ..config.init()
    };
    let (scene, report) = init::build_scene(&settings, &frames, &first_joints, progress)?;
    for line in report.lines() {
        eprintln!("{line}");
    }
    let ground = report.ground;
    metrics.init = Some(report);
    Ok((scene, ground))
}

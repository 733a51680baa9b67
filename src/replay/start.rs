//! The world a replay starts from: a built-in scenario's (with its configured start error), or one
//! initialised from the recording's first frames (`init`): the first image of every camera and
//! images spread over the table's fit span, the first depth and mask images, the first joint
//! states.

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
    let (count, span) = scene_config.table.as_ref().map_or((1, 0.0), |t| {
        (t.fit_frames.max(1) as usize, t.fit_span as f64)
    });
    let colour: Vec<Vec<Vec<Vec3>>> = streams
        .cameras
        .iter()
        .zip(&streams.images)
        .map(|((_, camera), images)| spread_frames(images, camera, count, span))
        .collect();
    let mut depths = Vec::new();
    let mut labels = Vec::new();
    for (c, (name, cam)) in streams.cameras.iter().enumerate() {
        let mut unused = |what: &str, why: String| {
            metrics
                .warnings
                .push(format!("camera {name}: {what} not used: {why}"))
        };
        let unit = config.node.depth_unit;
        let depth = streams.depth[c]
            .as_ref()
            .map(|i| decode_depth(i, cam, unit));
        depths.push(depth.and_then(|d| d.map_err(|why| unused("depth", why)).ok()));
        let mask = streams.masks[c].as_ref().map(|i| decode_labels(i, cam));
        labels.push(mask.and_then(|m| m.map_err(|why| unused("masks", why)).ok()));
    }
    let frames: Vec<FirstFrames> = streams
        .cameras
        .iter()
        .zip(&colour)
        .zip(depths.iter().zip(&labels))
        .map(|(((name, cam), images), (d, l))| FirstFrames {
            name: name.clone(),
            camera: *cam,
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
    let (scene, report) = init::build_scene(&config.init(), &frames, &first_joints, progress)?;
    for (name, o) in &report.objects {
        if let Some(a) = &o.alignment {
            eprintln!(
                "{name}: aligned to its masks, moved {:.1} mm, turned {:.1} deg, silhouette IoU {:.2} -> {:.2} ({:.1} s)",
                a.moved_mm, a.turned_deg, a.iou_before, a.iou_after, a.seconds
            );
        }
    }
    let ground = report.ground;
    metrics.init = Some(report);
    Ok((scene, ground))
}

/// The first decodable image of a camera, then images spread over `span` seconds after it
/// (`count` in all, fewer if they coincide).
fn spread_frames(
    images: &[(f64, crate::msgs::Image)],
    camera: &crate::render::Camera,
    count: usize,
    span: f64,
) -> Vec<Vec<Vec3>> {
    let Some(first) = images.first() else {
        return Vec::new();
    };
    let usable: Vec<(f64, Vec<Vec3>)> = images
        .iter()
        .filter(|(t, _)| *t <= first.0 + span + 1e-9)
        .filter_map(|(t, img)| decode_image(img, camera).ok().map(|d| (*t, d)))
        .collect();
    let mut picked: Vec<usize> = (0..count)
        .filter_map(|k| {
            let target = usable.first()?.0 + span * k as f64 / (count.max(2) - 1) as f64;
            (0..usable.len()).min_by(|&a, &b| {
                (usable[a].0 - target)
                    .abs()
                    .total_cmp(&(usable[b].0 - target).abs())
            })
        })
        .collect();
    picked.dedup();
    picked.into_iter().map(|i| usable[i].1.clone()).collect()
}

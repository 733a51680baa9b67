//! `pegs scenario generate`: simulate a scenario's true world, render it into its three cameras
//! with sensor noise and exposure drift, and write a recording (MCAP: images, camera info,
//! /tf_static, joint states), the ground truth (CSV of object poses) and a replay config.

use super::{build, cameras, model_config, observe, observe_depth_and_labels, truth_config};
use crate::config::Config;
use crate::init::SceneConfig;
use crate::math::Pose;
use crate::msgs::{self, JointState, Time};
use crate::record::{self, RecordingWriter};
use crate::render::Camera;
use crate::tracker::Tracker;
use crate::trajectory::{ParticleWriter, TrajectoryWriter};
use anyhow::{Context, Result};
use glam::Vec3;
use std::path::Path;

pub struct GenerateOptions {
    pub width: u32,
    pub height: u32,
    pub seconds: f64,
    /// Initial pose error written into the replay config (the tracker starts there).
    pub offset_position: Vec3,
    pub offset_yaw: f32,
    pub noise: f32,
}

impl Default for GenerateOptions {
    fn default() -> Self {
        Self {
            width: 640,
            height: 360,
            seconds: 4.5,
            offset_position: Vec3::new(0.01, 0.0, 0.0),
            offset_yaw: 5f32.to_radians(),
            noise: 0.01,
        }
    }
}

pub fn camera_name(k: usize) -> String {
    format!("cam{k}")
}

pub fn generate(name: &str, out: &Path, opts: &GenerateOptions) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let config = model_config(name);
    let mut truth = Tracker::new(build(name, Pose::IDENTITY)?, &truth_config(name), false)?;
    let cams = cameras(name, opts.width, opts.height);
    let mut rec = RecordingWriter::create(&out.join("recording"))?;
    let mut gt = TrajectoryWriter::create(&out.join("ground_truth.csv"))?;
    let mut gt_particles = ParticleWriter::create(&out.join("ground_truth_particles.csv"))?;
    // Static extrinsics: each optical frame's pose in the world.
    let named: Vec<(String, Camera)> = cams
        .iter()
        .enumerate()
        .map(|(k, c)| (camera_name(k), *c))
        .collect();
    let tf = record::optical_frames_tf(&named);
    rec.write(
        record::TF_STATIC,
        msgs::schema::tf_message(),
        Time::from_seconds(0.0),
        &tf,
    )?;
    let dt = config.physics.dt as f64;
    let ticks = (opts.seconds / dt).round() as usize;
    let (robot, trajectory) = truth
        .robot()
        .map(|(r, t)| (r.clone(), t.clone()))
        .context("scenarios have a robot")?;
    let progress = indicatif::ProgressBar::new(ticks as u64 + 1);
    for k in 0..=ticks {
        if k > 0 {
            truth.predict()?;
        }
        let t = k as f64 * dt;
        if k == 0 {
            // What initialisation from RGB-D starts from: depth and instance masks of the first frame.
            write_depth_and_masks(&mut rec, truth.world(), &cams, super::object_names(name), t)?;
        }
        let exposure = 1.0 + 0.03 * (t as f32 * 1.7).sin();
        let images = observe(truth.world(), &cams, opts.noise, exposure, k as u64);
        write_images(&mut rec, &cams, &images, t)?;
        let q = trajectory.at(t).context("empty joint trajectory")?;
        write_joint_state(&mut rec, &robot.model, &q, t)?;
        gt.record(truth.world())?;
        gt_particles.record(truth.world())?;
        progress.inc(1);
    }
    progress.finish_and_clear();
    rec.finish()?;
    gt.finish()?;
    gt_particles.finish()?;
    let mut replay_config = Config {
        scene: SceneConfig {
            scenario: Some(name.to_string()),
            offset_position: opts.offset_position,
            offset_yaw: opts.offset_yaw,
            ..Default::default()
        },
        ..config
    };
    replay_config.node.cameras = named.iter().map(|(n, _)| n.clone()).collect();
    std::fs::write(out.join("config.yaml"), replay_config.to_yaml()?)?;
    Ok(())
}

/// Depth (32FC1) and instance masks (mono8, label k + 1 for `objects[k]`) of every camera at `t`.
fn write_depth_and_masks(
    rec: &mut RecordingWriter,
    world: &crate::world::World,
    cams: &[Camera],
    objects: &[&str],
    t: f64,
) -> Result<()> {
    let observed = observe_depth_and_labels(world, cams, objects);
    for (i, (c, (depth, labels))) in cams.iter().zip(observed).enumerate() {
        let name = camera_name(i);
        let frame = record::optical_frame(&name);
        let depth = record::depth32(c.width, c.height, &depth, t, &frame);
        rec.image(&record::depth_topic(&name), &depth)?;
        let mask = record::mono8(c.width, c.height, labels, t, &frame);
        rec.image(&record::mask_topic(&name), &mask)?;
    }
    Ok(())
}

/// Every camera's CameraInfo and rgb8 image at `t`.
fn write_images(
    rec: &mut RecordingWriter,
    cams: &[Camera],
    images: &[Vec<Vec3>],
    t: f64,
) -> Result<()> {
    for (i, (c, img)) in cams.iter().zip(images).enumerate() {
        let name = camera_name(i);
        let frame = record::optical_frame(&name);
        let data = img
            .iter()
            .flat_map(|p| {
                let p = (p.clamp(Vec3::ZERO, Vec3::ONE) * 255.0).round();
                p.to_array().map(|v| v as u8)
            })
            .collect();
        let info = record::camera_info(c, t, &frame);
        rec.camera_info(&record::info_topic(&name), &info)?;
        let image = record::rgb8(c.width, c.height, data, t, &frame);
        rec.image(&record::image_topic(&name), &image)?;
    }
    Ok(())
}

/// The robot's actuated joints at positions `q` (all joints), stamped `t`.
fn write_joint_state(
    rec: &mut RecordingWriter,
    model: &crate::robot::RobotModel,
    q: &[f64],
    t: f64,
) -> Result<()> {
    let joints: Vec<usize> = model.actuated_joints().collect();
    let js = JointState {
        header: record::header(t, ""),
        name: joints
            .iter()
            .map(|&j| model.joints[j].name.clone())
            .collect(),
        position: joints.iter().map(|&j| q[j]).collect(),
        ..Default::default()
    };
    rec.write(
        record::JOINT_STATES,
        msgs::schema::joint_state(),
        Time::from_seconds(t),
        &js,
    )
}

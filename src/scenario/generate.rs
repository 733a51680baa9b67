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
    let mut rec = RecordingWriter::create(&out.join("recording.mcap"))?;
    let mut gt = TrajectoryWriter::create(&out.join("ground_truth.csv"))?;
    let mut gt_particles = ParticleWriter::create(&out.join("ground_truth_particles.csv"))?;
    // Static extrinsics: each optical frame's pose in the world.
    let named: Vec<(String, Camera)> = cams
        .iter()
        .enumerate()
        .map(|(k, c)| (camera_name(k), *c))
        .collect();
    rec.write(
        record::TF_STATIC,
        msgs::schema::tf_message(),
        Time::from_seconds(0.0),
        &record::optical_frames_tf(&named),
    )?;
    let dt = config.physics.dt as f64;
    let ticks = (opts.seconds / dt).round() as usize;
    let (robot, trajectory) = truth
        .robot()
        .map(|(r, t)| (r.clone(), t.clone()))
        .context("scenarios have a robot")?;
    let joint_names: Vec<usize> = robot.model.actuated_joints().collect();
    let progress = indicatif::ProgressBar::new(ticks as u64 + 1);
    for k in 0..=ticks {
        if k > 0 {
            truth.predict()?;
        }
        let t = k as f64 * dt;
        let exposure = 1.0 + 0.03 * (t as f32 * 1.7).sin();
        let images = observe(truth.world(), &cams, opts.noise, exposure, k as u64);
        if k == 0 {
            // What initialisation from RGB-D starts from: depth and instance masks of the first frame.
            for (i, (c, (depth, labels))) in cams
                .iter()
                .zip(observe_depth_and_labels(
                    truth.world(),
                    &cams,
                    super::object_names(name),
                ))
                .enumerate()
            {
                let frame = record::optical_frame(&camera_name(i));
                rec.write(
                    &record::depth_topic(&camera_name(i)),
                    msgs::schema::image(),
                    Time::from_seconds(t),
                    &record::depth32(c.width, c.height, &depth, t, &frame),
                )?;
                rec.write(
                    &record::mask_topic(&camera_name(i)),
                    msgs::schema::image(),
                    Time::from_seconds(t),
                    &record::mono8(c.width, c.height, labels, t, &frame),
                )?;
            }
        }
        for (i, (c, img)) in cams.iter().zip(&images).enumerate() {
            let frame = record::optical_frame(&camera_name(i));
            let data = img
                .iter()
                .flat_map(|p| {
                    (p.clamp(Vec3::ZERO, Vec3::ONE) * 255.0)
                        .round()
                        .to_array()
                        .map(|v| v as u8)
                })
                .collect();
            rec.write(
                &record::info_topic(&camera_name(i)),
                msgs::schema::camera_info(),
                Time::from_seconds(t),
                &record::camera_info(c, t, &frame),
            )?;
            rec.write(
                &record::image_topic(&camera_name(i)),
                msgs::schema::image(),
                Time::from_seconds(t),
                &record::rgb8(c.width, c.height, data, t, &frame),
            )?;
        }
        let q = trajectory.at(t).context("empty joint trajectory")?;
        let js = JointState {
            header: record::header(t, ""),
            name: joint_names
                .iter()
                .map(|&j| robot.model.joints[j].name.clone())
                .collect(),
            position: joint_names.iter().map(|&j| q[j]).collect(),
            ..Default::default()
        };
        rec.write(
            record::JOINT_STATES,
            msgs::schema::joint_state(),
            Time::from_seconds(t),
            &js,
        )?;
        gt.record(truth.world())?;
        gt_particles.record(truth.world())?;
        progress.inc(1);
    }
    progress.finish_and_clear();
    rec.finish()?;
    gt.finish()?;
    gt_particles.finish()?;
    let replay_config = Config {
        scene: SceneConfig {
            scenario: Some(name.to_string()),
            offset_position: opts.offset_position,
            offset_yaw: opts.offset_yaw,
            ..Default::default()
        },
        ..config
    };
    std::fs::write(out.join("config.yaml"), replay_config.to_yaml()?)?;
    Ok(())
}

//! `pegs scenario generate`: simulate a scenario's true world, render it into its three cameras
//! with sensor noise and exposure drift, and write a recording (MCAP: images, camera info,
//! /tf_static, joint states), the ground truth (CSV of object poses) and a replay config.

use super::{build, cameras, observe, truth_config};
use crate::config::{Config, SceneConfig};
use crate::math::Pose;
use crate::msgs::{self, CameraInfo, Header, Image, JointState, Quaternion, TfMessage, Time, Transform, TransformStamped, Vector3};
use crate::record::{self, RecordingWriter};
use crate::render::Camera;
use crate::trajectory::{ParticleWriter, TrajectoryWriter};
use crate::tracker::Tracker;
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
        Self { width: 640, height: 360, seconds: 4.5, offset_position: Vec3::new(0.01, 0.0, 0.0), offset_yaw: 5f32.to_radians(), noise: 0.01 }
    }
}

pub fn camera_name(k: usize) -> String {
    format!("cam{k}")
}

fn header(t: f64, frame: &str) -> Header {
    Header { stamp: Time::from_seconds(t), frame_id: frame.to_string() }
}

fn camera_info(c: &Camera, t: f64, frame: &str) -> CameraInfo {
    // Back to the OpenCV convention of CameraInfo (pixel centres at integers).
    let (fx, fy, cx, cy) = (c.fx as f64, c.fy as f64, c.cx as f64 - 0.5, c.cy as f64 - 0.5);
    CameraInfo {
        header: header(t, frame),
        height: c.height,
        width: c.width,
        distortion_model: "plumb_bob".into(),
        d: vec![0.0; 5],
        k: [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        ..Default::default()
    }
}

fn rgb8(c: &Camera, pixels: &[Vec3], t: f64, frame: &str) -> Image {
    let data = pixels.iter().flat_map(|p| (p.clamp(Vec3::ZERO, Vec3::ONE) * 255.0).round().to_array().map(|v| v as u8)).collect();
    Image { header: header(t, frame), height: c.height, width: c.width, encoding: "rgb8".into(), is_bigendian: 0, step: 3 * c.width, data }
}

pub fn generate(name: &str, out: &Path, opts: &GenerateOptions) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let config = Config::default();
    let mut truth = Tracker::new(build(name, Pose::IDENTITY)?, &truth_config(name), false)?;
    let cams = cameras(name, opts.width, opts.height);
    let mut rec = RecordingWriter::create(&out.join("recording.mcap"))?;
    let mut gt = TrajectoryWriter::create(&out.join("ground_truth.csv"))?;
    let mut gt_particles = ParticleWriter::create(&out.join("ground_truth_particles.csv"))?;
    // Static extrinsics: each optical frame's pose in the world.
    let transforms = cams
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let cam_to_world = c.world_to_camera.inverse();
            let (t, q) = (cam_to_world.translation, cam_to_world.rotation);
            TransformStamped {
                header: header(0.0, record::WORLD_FRAME),
                child_frame_id: record::optical_frame(&camera_name(k)),
                transform: Transform { translation: Vector3 { x: t.x as f64, y: t.y as f64, z: t.z as f64 }, rotation: Quaternion { x: q.x as f64, y: q.y as f64, z: q.z as f64, w: q.w as f64 } },
            }
        })
        .collect();
    rec.write(record::TF_STATIC, msgs::schema::tf_message(), Time::from_seconds(0.0), &TfMessage { transforms })?;
    let dt = config.physics.dt as f64;
    let ticks = (opts.seconds / dt).round() as usize;
    let (robot, trajectory) = truth.scene.robot.as_ref().map(|(r, t)| (r.clone(), t.clone())).context("scenarios have a robot")?;
    let joint_names: Vec<usize> = robot.model.actuated_joints().collect();
    let progress = indicatif::ProgressBar::new(ticks as u64 + 1);
    for k in 0..=ticks {
        if k > 0 {
            truth.tick(&[])?;
        }
        let t = k as f64 * dt;
        let exposure = 1.0 + 0.03 * (t as f32 * 1.7).sin();
        let images = observe(&truth.scene.world, &cams, opts.noise, exposure, k as u64);
        for (i, (c, img)) in cams.iter().zip(&images).enumerate() {
            let frame = record::optical_frame(&camera_name(i));
            rec.write(&record::info_topic(&camera_name(i)), msgs::schema::camera_info(), Time::from_seconds(t), &camera_info(c, t, &frame))?;
            rec.write(&record::image_topic(&camera_name(i)), msgs::schema::image(), Time::from_seconds(t), &rgb8(c, img, t, &frame))?;
        }
        let q = trajectory.at(t).context("empty joint trajectory")?;
        let js = JointState {
            header: header(t, ""),
            name: joint_names.iter().map(|&j| robot.model.joints[j].name.clone()).collect(),
            position: joint_names.iter().map(|&j| q[j]).collect(),
            ..Default::default()
        };
        rec.write(record::JOINT_STATES, msgs::schema::joint_state(), Time::from_seconds(t), &js)?;
        gt.record(&truth.scene.world)?;
        gt_particles.record(&truth.scene.world)?;
        progress.inc(1);
    }
    progress.finish_and_clear();
    rec.finish()?;
    gt.finish()?;
    gt_particles.finish()?;
    let replay_config = Config { scene: SceneConfig { scenario: Some(name.to_string()), offset_position: opts.offset_position, offset_yaw: opts.offset_yaw }, ..Config::default() };
    std::fs::write(out.join("config.yaml"), replay_config.to_yaml()?)?;
    Ok(())
}

//! `pegs replay`: the predict / correct loop driven by a recording instead of live topics. Ticks
//! run on the recording's own clock; each tick uses the newest image of every camera stamped no
//! later than the tick, and the robot follows the recorded joint states interpolated in time.
//! Deterministic: the same recording and configuration give the same outputs.

pub mod silhouette;

use crate::config::Config;
use crate::init::{self, FirstFrames};
use crate::inputs::{Inputs, decode_image};
use crate::math::Pose;
use crate::msgs::{self, CameraInfo, Image, JointState, TfMessage};
use crate::record::{self, RawMessage};
use crate::render::Camera;
use crate::scenario;
use crate::tracker::Tracker;
use crate::trajectory::TrajectoryWriter;
use anyhow::{Context, Result, bail};
use glam::{Quat, Vec3};
use serde::Serialize;
use silhouette::SilhouetteMeter;
use std::collections::BTreeMap;
use std::path::Path;

#[derive(Clone, Copy, Debug)]
pub struct ReplayOptions {
    pub visual_forces: bool,
    /// False: visual forces only (no gravity, ground or collisions), as in the paper's ablation.
    pub physics: bool,
    pub progress: bool,
    /// Use only the first N cameras (sorted by name); all when None.
    pub max_cameras: Option<usize>,
    /// Keep every tracked state in `Metrics::trace` (for open-loop predictions).
    pub capture: bool,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        Self {
            visual_forces: true,
            physics: true,
            progress: true,
            max_cameras: None,
            capture: false,
        }
    }
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct ErrorStats {
    pub mean_mm: f32,
    pub p95_mm: f32,
    pub final_mm: f32,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct Metrics {
    pub recording: String,
    pub mode: String,
    pub ticks: usize,
    pub seconds: f64,
    pub cameras: Vec<String>,
    pub wall_ms_per_tick: f64,
    pub mean_loss: f32,
    pub rejected_images: usize,
    /// Ticks at which a camera's newest image was too old to use, per camera.
    pub stale_camera_ticks: BTreeMap<String, usize>,
    pub rejected_joint_states: usize,
    pub warnings: Vec<String>,
    /// 3-D tracking error per object against `ground_truth.csv` beside the recording, if any.
    pub tracking_error: BTreeMap<String, ErrorStats>,
    /// Per-tick tracking error per object: `(t, metres)`; also written to `tracking_error.csv`.
    #[serde(skip)]
    pub error_series: BTreeMap<String, Vec<(f64, f32)>>,
    /// How the world was initialised from the first frames (when no scenario is configured).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub init: Option<init::InitReport>,
    /// Per object and camera: IoU of the tracked object's rendered silhouette with its colour mask.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub silhouette_iou: BTreeMap<String, BTreeMap<String, silhouette::IouStats>>,
    /// With `--compare`: the same recording replayed physics-only and visual-forces-only.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub comparison: BTreeMap<String, Comparison>,
    /// With `ReplayOptions::capture`: the tracked states, for open-loop predictions.
    #[serde(skip)]
    pub trace: Option<crate::diagnose::trace::Trace>,
}

/// Mean tracking errors of the ablated runs and this run's error as a fraction of theirs.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Comparison {
    pub physics_only_mean_mm: f32,
    pub visual_forces_only_mean_mm: f32,
    pub ratio_to_physics_only: f32,
    pub ratio_to_visual_forces_only: f32,
}

/// Replay with both priors and visual forces, then physics-only and visual-forces-only (into
/// `out/physics_only` and `out/visual_forces_only`), and record the comparison in `out/metrics.json`.
pub fn run_compare(
    recording: &Path,
    config: &Config,
    out: &Path,
    progress: bool,
) -> Result<Metrics> {
    let mut main = run(
        recording,
        config,
        out,
        ReplayOptions {
            progress,
            ..Default::default()
        },
    )?;
    let physics = run(
        recording,
        config,
        &out.join("physics_only"),
        ReplayOptions {
            visual_forces: false,
            progress,
            ..Default::default()
        },
    )?;
    let visual = run(
        recording,
        config,
        &out.join("visual_forces_only"),
        ReplayOptions {
            physics: false,
            progress,
            ..Default::default()
        },
    )?;
    for (object, e) in &main.tracking_error {
        let p = physics
            .tracking_error
            .get(object)
            .map_or(f32::NAN, |e| e.mean_mm);
        let v = visual
            .tracking_error
            .get(object)
            .map_or(f32::NAN, |e| e.mean_mm);
        main.comparison.insert(
            object.clone(),
            Comparison {
                physics_only_mean_mm: p,
                visual_forces_only_mean_mm: v,
                ratio_to_physics_only: e.mean_mm / p,
                ratio_to_visual_forces_only: e.mean_mm / v,
            },
        );
    }
    std::fs::write(
        out.join("metrics.json"),
        serde_json::to_string_pretty(&main)?,
    )?;
    Ok(main)
}

/// A recording's content sorted for replay.
struct Streams {
    cameras: Vec<(String, Camera)>,
    /// Per camera: (stamp, image) in time order.
    images: Vec<Vec<(f64, Image)>>,
    /// Per camera: the first depth and instance-mask images, if recorded.
    depth: Vec<Option<Image>>,
    masks: Vec<Option<Image>>,
    joint_states: Vec<(f64, JointState)>,
}

fn camera_of(topic: &str, suffix: &str) -> Option<String> {
    topic
        .strip_suffix(suffix)
        .map(|p| p.trim_start_matches('/').to_string())
}

fn parse(messages: Vec<RawMessage>, warnings: &mut Vec<String>) -> Result<Streams> {
    let mut infos: BTreeMap<String, CameraInfo> = BTreeMap::new();
    let mut poses: BTreeMap<String, Pose> = BTreeMap::new();
    let mut images: BTreeMap<String, Vec<(f64, Image)>> = BTreeMap::new();
    let mut depth: BTreeMap<String, Image> = BTreeMap::new();
    let mut masks: BTreeMap<String, Image> = BTreeMap::new();
    let mut joint_states = Vec::new();
    for m in messages {
        let decoded: Result<()> = (|| {
            if let Some(cam) = camera_of(&m.topic, "/color/camera_info") {
                let info: CameraInfo = msgs::from_cdr(&m.data)?;
                infos.entry(cam).or_insert(info);
            } else if let Some(cam) = camera_of(&m.topic, "/color/image_raw") {
                let img: Image = msgs::from_cdr(&m.data)?;
                images
                    .entry(cam)
                    .or_default()
                    .push((img.header.stamp.seconds(), img));
            } else if let Some(cam) = camera_of(&m.topic, "/depth/image_raw") {
                depth.entry(cam).or_insert(msgs::from_cdr(&m.data)?);
            } else if let Some(cam) = camera_of(&m.topic, "/mask/image_raw") {
                masks.entry(cam).or_insert(msgs::from_cdr(&m.data)?);
            } else if m.topic == record::JOINT_STATES {
                let js: JointState = msgs::from_cdr(&m.data)?;
                joint_states.push((js.header.stamp.seconds(), js));
            } else if m.topic == record::TF_STATIC {
                let tf: TfMessage = msgs::from_cdr(&m.data)?;
                for t in tf.transforms {
                    let (p, q) = (t.transform.translation, t.transform.rotation);
                    let cam_to_world = Pose::new(
                        Vec3::new(p.x as f32, p.y as f32, p.z as f32),
                        Quat::from_xyzw(q.x as f32, q.y as f32, q.z as f32, q.w as f32).normalize(),
                    );
                    if t.header.frame_id != record::WORLD_FRAME {
                        warnings.push(format!(
                            "/tf_static {} -> {}: only transforms from '{}' are used",
                            t.header.frame_id,
                            t.child_frame_id,
                            record::WORLD_FRAME
                        ));
                        continue;
                    }
                    poses.insert(t.child_frame_id, cam_to_world.inverse());
                }
            }
            Ok(())
        })();
        if let Err(e) = decoded {
            warnings.push(format!("skipped a message on {}: {e:#}", m.topic));
        }
    }
    let mut cameras = Vec::new();
    let mut streams = Vec::new();
    let (mut depth_streams, mut mask_streams) = (Vec::new(), Vec::new());
    for (name, mut imgs) in images {
        let Some(info) = infos.get(&name) else {
            warnings.push(format!(
                "camera {name}: images but no CameraInfo; camera ignored"
            ));
            continue;
        };
        let Some(pose) = poses.get(&record::optical_frame(&name)) else {
            warnings.push(format!(
                "camera {name}: no /tf_static transform to {}; camera ignored",
                record::optical_frame(&name)
            ));
            continue;
        };
        let k = info.k;
        if !(k[0] > 0.0 && k[4] > 0.0) || info.width == 0 || info.height == 0 {
            warnings.push(format!("camera {name}: invalid CameraInfo; camera ignored"));
            continue;
        }
        imgs.sort_by(|a, b| a.0.total_cmp(&b.0));
        depth_streams.push(depth.remove(&name));
        mask_streams.push(masks.remove(&name));
        cameras.push((
            name,
            Camera::from_opencv(
                info.width,
                info.height,
                k[0] as f32,
                k[4] as f32,
                k[2] as f32,
                k[5] as f32,
                *pose,
            ),
        ));
        streams.push(imgs);
    }
    joint_states.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(Streams {
        cameras,
        images: streams,
        depth: depth_streams,
        masks: mask_streams,
        joint_states,
    })
}

/// Metres from a 32FC1 depth image of the camera's size (non-finite or negative values become 0,
/// unknown).
pub fn decode_depth(img: &Image, camera: &Camera) -> std::result::Result<Vec<f32>, String> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    if img.width != camera.width
        || img.height != camera.height
        || img.encoding != "32FC1"
        || img.is_bigendian != 0
        || (img.step as usize) < 4 * w
        || img.data.len() < img.step as usize * h
    {
        return Err(format!(
            "depth must be little-endian 32FC1 of {w}x{h}, got {} {}x{}",
            img.encoding, img.width, img.height
        ));
    }
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let at = y * img.step as usize + 4 * x;
            let d = f32::from_le_bytes([
                img.data[at],
                img.data[at + 1],
                img.data[at + 2],
                img.data[at + 3],
            ]);
            out.push(if d.is_finite() && d > 0.0 { d } else { 0.0 });
        }
    }
    Ok(out)
}

/// Labels from a mono8 instance-mask image of the camera's size.
pub fn decode_labels(img: &Image, camera: &Camera) -> std::result::Result<Vec<u8>, String> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    if img.width != camera.width
        || img.height != camera.height
        || img.encoding != "mono8"
        || (img.step as usize) < w
        || img.data.len() < img.step as usize * h
    {
        return Err(format!(
            "instance masks must be mono8 of {w}x{h}, got {} {}x{}",
            img.encoding, img.width, img.height
        ));
    }
    Ok((0..h)
        .flat_map(|y| {
            img.data[y * img.step as usize..y * img.step as usize + w]
                .iter()
                .copied()
        })
        .collect())
}

/// Ground-truth poses per object: time-ordered `(t, pose)`.
fn read_ground_truth(path: &Path) -> Result<BTreeMap<String, Vec<(f64, Pose)>>> {
    let text = std::fs::read_to_string(path)?;
    let mut out: BTreeMap<String, Vec<(f64, Pose)>> = BTreeMap::new();
    for (n, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 9 {
            bail!("{}:{}: expected 9 fields", path.display(), n + 1);
        }
        let v: Vec<f32> = f[2..]
            .iter()
            .map(|x| x.parse::<f32>())
            .collect::<std::result::Result<_, _>>()
            .with_context(|| format!("{}:{}", path.display(), n + 1))?;
        let t: f64 = f[0]
            .parse()
            .with_context(|| format!("{}:{}", path.display(), n + 1))?;
        out.entry(f[1].to_string()).or_default().push((
            t,
            Pose::new(
                Vec3::new(v[0], v[1], v[2]),
                Quat::from_xyzw(v[3], v[4], v[5], v[6]).normalize(),
            ),
        ));
    }
    Ok(out)
}

/// Ground-truth particle positions of deformable objects: object -> time-ordered `(t, positions)`.
type ParticleTruth = BTreeMap<String, Vec<(f64, Vec<Vec3>)>>;

fn read_ground_truth_particles(path: &Path) -> Result<ParticleTruth> {
    let text = std::fs::read_to_string(path)?;
    let mut out: ParticleTruth = BTreeMap::new();
    for (n, line) in text.lines().enumerate().skip(1) {
        let at = || format!("{}:{}", path.display(), n + 1);
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 6 {
            bail!("{}: expected 6 fields", at());
        }
        let t: f64 = f[0].parse().with_context(at)?;
        let k: usize = f[2].parse().with_context(at)?;
        let v: Vec<f32> = f[3..]
            .iter()
            .map(|x| x.parse::<f32>())
            .collect::<std::result::Result<_, _>>()
            .with_context(at)?;
        let track = out.entry(f[1].to_string()).or_default();
        if track.last().is_none_or(|(tl, _)| *tl != t) {
            track.push((t, Vec::new()));
        }
        let Some((_, points)) = track.last_mut() else {
            continue;
        };
        if k != points.len() {
            bail!("{}: particle {k} out of order", at());
        }
        points.push(Vec3::new(v[0], v[1], v[2]));
    }
    Ok(out)
}

/// Mean, 95th percentile and last of per-tick errors in metres, reported in mm.
pub fn stats(errors: &[f32]) -> ErrorStats {
    if errors.is_empty() {
        return ErrorStats::default();
    }
    let mut sorted = errors.to_vec();
    sorted.sort_by(f32::total_cmp);
    let p95 = sorted[((sorted.len() as f32 * 0.95).ceil() as usize).clamp(1, sorted.len()) - 1];
    ErrorStats {
        mean_mm: errors.iter().sum::<f32>() / errors.len() as f32 * 1e3,
        p95_mm: p95 * 1e3,
        final_mm: errors[errors.len() - 1] * 1e3,
    }
}

pub fn run(recording: &Path, config: &Config, out: &Path, opts: ReplayOptions) -> Result<Metrics> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut metrics = Metrics {
        recording: recording.display().to_string(),
        ..Default::default()
    };
    let (messages, problem) = record::read_messages(recording)?;
    if let Some(p) = problem {
        eprintln!("warning: {p}; replaying what was read");
        metrics.warnings.push(p);
    }
    let mut streams = parse(messages, &mut metrics.warnings)?;
    if let Some(n) = opts.max_cameras {
        streams.cameras.truncate(n);
        streams.images.truncate(n);
    }
    if streams.cameras.is_empty() {
        bail!(
            "{} has no usable camera (needs images, CameraInfo and /tf_static)",
            recording.display()
        );
    }
    metrics.cameras = streams.cameras.iter().map(|c| c.0.clone()).collect();
    let scene_config = &config.scene;
    let mut ground_from_depth = None;
    let mut scene = match scene_config.scenario.as_deref() {
        Some(name) => scenario::build(
            name,
            Pose::new(
                scene_config.offset_position,
                Quat::from_rotation_z(scene_config.offset_yaw),
            ),
        )?,
        None => {
            // Initialise from the first frames of every camera.
            // The first image of each camera, then images spread over the table's fit span.
            let (count, span) = scene_config.table.as_ref().map_or((1, 0.0), |t| {
                (t.fit_frames.max(1) as usize, t.fit_span as f64)
            });
            let decoded: Vec<Vec<Vec<Vec3>>> = streams
                .cameras
                .iter()
                .zip(&streams.images)
                .map(|((_, cam), imgs)| {
                    let usable: Vec<(f64, Vec<Vec3>)> = imgs
                        .iter()
                        .filter(|(t, _)| *t <= imgs[0].0 + span + 1e-9)
                        .filter_map(|(t, img)| decode_image(img, cam).ok().map(|d| (*t, d)))
                        .collect();
                    let mut picked: Vec<usize> = (0..count)
                        .filter_map(|k| {
                            let target =
                                usable.first()?.0 + span * k as f64 / (count.max(2) - 1) as f64;
                            (0..usable.len()).min_by(|&a, &b| {
                                (usable[a].0 - target)
                                    .abs()
                                    .total_cmp(&(usable[b].0 - target).abs())
                            })
                        })
                        .collect();
                    picked.dedup();
                    picked.into_iter().map(|i| usable[i].1.clone()).collect()
                })
                .collect();
            let mut depths = Vec::new();
            let mut labels = Vec::new();
            for (c, (name, cam)) in streams.cameras.iter().enumerate() {
                depths.push(streams.depth[c].as_ref().and_then(|i| {
                    decode_depth(i, cam)
                        .map_err(|why| {
                            metrics
                                .warnings
                                .push(format!("camera {name}: depth not used: {why}"))
                        })
                        .ok()
                }));
                labels.push(streams.masks[c].as_ref().and_then(|i| {
                    decode_labels(i, cam)
                        .map_err(|why| {
                            metrics
                                .warnings
                                .push(format!("camera {name}: masks not used: {why}"))
                        })
                        .ok()
                }));
            }
            let frames: Vec<FirstFrames> = streams
                .cameras
                .iter()
                .zip(&decoded)
                .zip(depths.iter().zip(&labels))
                .map(|(((name, cam), imgs), (d, l))| FirstFrames {
                    name: name.clone(),
                    camera: *cam,
                    images: imgs.iter().map(|i| i.as_slice()).collect(),
                    depth: d.as_deref(),
                    labels: l.as_deref(),
                })
                .collect();
            let initial_joints: Vec<(String, f64)> = streams
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
            if opts.progress {
                eprintln!(
                    "initialising the scene from the first frames of {} cameras",
                    frames.len()
                );
            }
            let (scene, report) =
                init::build_scene(config, &frames, &initial_joints, opts.progress)?;
            if let Some((normal, height)) = report.ground {
                ground_from_depth = Some((normal, height));
            }
            for (name, o) in &report.objects {
                if let Some(a) = &o.alignment {
                    eprintln!(
                        "{name}: aligned to its masks, moved {:.1} mm, turned {:.1} deg, silhouette IoU {:.2} -> {:.2} ({:.1} s)",
                        a.moved_mm, a.turned_deg, a.iou_before, a.iou_after, a.seconds
                    );
                }
            }
            metrics.init = Some(report);
            scene
        }
    };
    if scene.robot.is_some() && streams.joint_states.is_empty() {
        metrics
            .warnings
            .push("no joint states: the robot holds its scenario motion".into());
    }
    let mut config = config.clone();
    if let Some((normal, height)) = ground_from_depth {
        config.physics.ground.normal = normal;
        config.physics.ground.height = height;
    }
    metrics.mode = match (opts.physics, opts.visual_forces) {
        (true, true) => "physics + visual forces",
        (true, false) => "physics only",
        (false, true) => "visual forces only",
        (false, false) => "neither (open loop, no physics)",
    }
    .into();
    if !opts.physics {
        config.physics.gravity = Vec3::ZERO;
        config.physics.ground.enabled = false;
        config.physics.collisions.enabled = false;
    }
    let t0 = streams
        .images
        .iter()
        .filter_map(|s| s.first().map(|f| f.0))
        .fold(f64::INFINITY, f64::min);
    let t_end = streams
        .images
        .iter()
        .filter_map(|s| s.last().map(|f| f.0))
        .fold(f64::NEG_INFINITY, f64::max);
    scene.world.time = t0;
    let mut tracker = Tracker::new(scene, &config, opts.visual_forces)?;
    use crate::diagnose::trace::{State, Trace};
    let mut trace = opts.capture.then(|| Trace {
        base: tracker.scene.world.clone(),
        physics: config.physics.clone(),
        robot: tracker.scene.robot.clone(),
        states: vec![State::of(&tracker.scene.world)],
    });
    let mut meters: Vec<SilhouetteMeter> = if config.scene.scenario.is_none() {
        config
            .scene
            .objects
            .iter()
            .filter_map(|o| {
                // The occluder test of the correction; its usual value where the correction does not use it.
                let threshold = if config.correct.occluder_threshold > 0.0 {
                    config.correct.occluder_threshold
                } else {
                    0.35
                };
                Some(SilhouetteMeter::new(
                    tracker.scene.world.shape_id(&o.name)?,
                    &o.name,
                    o.mask?,
                    streams.cameras.len(),
                    &config.render,
                    threshold,
                ))
            })
            .collect()
    } else {
        Vec::new()
    };
    let dt = config.physics.dt as f64;
    let ticks = ((t_end - t0) / dt + 1e-6).floor().max(0.0) as usize;
    let truth = {
        let path = recording.with_file_name("ground_truth.csv");
        if path.is_file() {
            Some(read_ground_truth(&path)?)
        } else {
            None
        }
    };
    let particle_truth = {
        let path = recording.with_file_name("ground_truth_particles.csv");
        if path.is_file() {
            read_ground_truth_particles(&path)?
        } else {
            ParticleTruth::new()
        }
    };
    // Objects built from RGB-D have a body frame of their own: their error is measured after
    // registering it to the true body frame at the start (so it is the drift of the tracking).
    let mut registration: BTreeMap<String, Pose> = BTreeMap::new();
    if let (Some(truth), Some(report)) = (&truth, &metrics.init) {
        for name in report.rgbd_objects.keys() {
            if let (Some(track), Some(s)) = (truth.get(name), tracker.scene.world.shape_id(name))
                && let Some((_, first)) = track.first()
            {
                registration.insert(
                    name.clone(),
                    first
                        .inverse()
                        .mul(&tracker.scene.world.shapes.pose[s as usize]),
                );
            }
        }
    }
    let mut writer = TrajectoryWriter::create(&out.join("objects.csv"))?;
    writer.record(&tracker.scene.world)?;
    let mut errors: BTreeMap<String, Vec<(f64, f32)>> = BTreeMap::new();
    // Observations reach the tick through `Inputs` exactly as they do in the live node: each
    // message is offered when the clock passes its stamp.
    let robot_start = tracker.scene.robot.as_ref().map(|(r, traj)| {
        (
            r.model.clone(),
            traj.at(t0)
                .unwrap_or_else(|| vec![0.0; r.model.joints.len()]),
        )
    });
    let mut inputs = Inputs::new(
        streams.cameras.clone(),
        robot_start.as_ref().map(|(m, q)| (m, q.as_slice())),
    );
    let mut cursor = vec![0usize; streams.cameras.len()];
    let mut joint_cursor = 0;
    let max_age = config.correct.max_image_age as f64;
    let progress = if opts.progress {
        indicatif::ProgressBar::new(ticks as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    let mut loss_sum = 0.0f32;
    // State, contacts and corrective wrench of every object per tick (what `diagnose` explains).
    let mut residuals = crate::diagnose::log::ResidualLog::default();
    let ground = config.physics.ground.enabled.then_some((
        config.physics.ground.normal.normalize_or(Vec3::Z),
        config.physics.ground.height,
    ));
    // Contact sheet: six moments spread over the recording.
    let sheet_ticks: Vec<usize> = (0..6)
        .map(|i| 1 + i * ticks.saturating_sub(1) / 5)
        .collect();
    let mut sheet = Vec::new();
    let clock = std::time::Instant::now();
    for k in 1..=ticks {
        let t = t0 + k as f64 * dt;
        for (c, stream) in streams.images.iter().enumerate() {
            while cursor[c] < stream.len() && stream[cursor[c]].0 <= t + 1e-6 {
                // Refusals are counted and explained by `inputs`.
                let _ = inputs.offer_image(c, &stream[cursor[c]].1, t);
                cursor[c] += 1;
            }
        }
        while joint_cursor < streams.joint_states.len()
            && streams.joint_states[joint_cursor].0 <= t + 1e-6
        {
            let _ = inputs.offer_joint_state(&streams.joint_states[joint_cursor].1, t);
            joint_cursor += 1;
        }
        if let (Some(trajectory), Some((_, scene_trajectory))) =
            (inputs.trajectory_for(t), &mut tracker.scene.robot)
        {
            *scene_trajectory = trajectory;
        }
        for line in inputs.log.take_lines() {
            if metrics.warnings.len() < 50 {
                metrics.warnings.push(line);
            }
        }
        let tick_inputs = inputs.tick_inputs(t, max_age);
        for name in &tick_inputs.stale {
            let n = metrics.stale_camera_ticks.entry(name.clone()).or_insert(0);
            if *n == 0 {
                let stamp = inputs
                    .cameras
                    .iter()
                    .find(|f| &f.name == name)
                    .and_then(|f| f.latest.as_ref())
                    .map_or(f64::NAN, |l| l.0);
                let line = format!(
                    "camera {name}: no image since {stamp:.3} s (at {t:.3} s); continuing with the other cameras"
                );
                eprintln!("warning: {line}");
                metrics.warnings.push(line);
            }
            *n += 1;
        }
        let views = tick_inputs.views();
        let stats = tracker.tick(&views)?;
        if let Some(s) = &stats {
            loss_sum += s.loss_before;
        }
        residuals.record(
            &tracker.scene.world,
            stats.as_ref(),
            ground,
            t,
            config.physics.dt,
        );
        if let Some(trace) = &mut trace {
            trace.states.push(State::of(&tracker.scene.world));
        }
        // Silhouettes of the corrected state against the images it was corrected with.
        let sheet_row = sheet_ticks.contains(&k);
        let mut row = Vec::new();
        for meter in &mut meters {
            for (c, feed) in inputs.cameras.iter().enumerate() {
                let Some((stamp, pixels)) = &feed.latest else {
                    continue;
                };
                if t - stamp > max_age {
                    continue;
                }
                let cam = &feed.camera;
                if let Some(overlay) =
                    meter.measure(&tracker.scene.world, c, cam, pixels, t, sheet_row)
                {
                    row.push((cam.width, cam.height, overlay));
                }
            }
        }
        if !row.is_empty() {
            sheet.push(row);
        }
        writer.record(&tracker.scene.world)?;
        if let Some(truth) = &truth {
            let w = &tracker.scene.world;
            for s in w.shapes.dynamic_ids() {
                let name = &w.shapes.name[s as usize];
                let range = w.shapes.range(s);
                if let Some(track) = particle_truth.get(name) {
                    // Deformable: particle k against the true particle k.
                    let i = track
                        .partition_point(|(ts, _)| *ts < t - 1e-6)
                        .min(track.len() - 1);
                    let points = &track[i].1;
                    if points.len() == range.len() {
                        let e = range
                            .zip(points)
                            .map(|(p, q)| w.particles.position[p].distance(*q))
                            .sum::<f32>()
                            / points.len() as f32;
                        errors.entry(name.clone()).or_default().push((t, e));
                    }
                    continue;
                }
                let Some(track) = truth.get(name) else {
                    continue;
                };
                let i = track
                    .partition_point(|(ts, _)| *ts < t - 1e-6)
                    .min(track.len() - 1);
                let pose = match registration.get(name) {
                    Some(x) => track[i].1.mul(x),
                    None => track[i].1,
                };
                let n = range.len() as f32;
                let e = range
                    .map(|p| {
                        pose.transform_point(w.particles.rest[p])
                            .distance(w.particles.position[p])
                    })
                    .sum::<f32>()
                    / n;
                errors.entry(name.clone()).or_default().push((t, e));
            }
        }
        progress.inc(1);
    }
    progress.finish_and_clear();
    metrics.rejected_images = inputs.log.images_rejected;
    metrics.rejected_joint_states = inputs.log.joint_states_rejected;
    writer.finish()?;
    metrics.ticks = ticks;
    metrics.seconds = ticks as f64 * dt;
    metrics.wall_ms_per_tick = clock.elapsed().as_secs_f64() * 1e3 / ticks.max(1) as f64;
    metrics.mean_loss = loss_sum / ticks.max(1) as f32;
    metrics.tracking_error = errors
        .iter()
        .map(|(k, v)| (k.clone(), stats(&v.iter().map(|e| e.1).collect::<Vec<_>>())))
        .collect();
    if !errors.is_empty() {
        let mut csv = String::from("t,object,error_mm\n");
        for (object, series) in &errors {
            for (t, e) in series {
                csv += &format!("{t:.6},{object},{:.4}\n", e * 1e3);
            }
        }
        std::fs::write(out.join("tracking_error.csv"), csv)?;
    }
    metrics.error_series = errors;
    let mut csv = String::from(crate::diagnose::CSV_HEADER);
    csv.push('\n');
    for sample in &residuals.samples {
        csv += &sample.csv_row();
        csv.push('\n');
    }
    std::fs::write(out.join("residuals.csv"), csv)?;
    if !meters.is_empty() {
        let mut csv = String::from("t,object,camera,iou,visible_iou\n");
        for meter in &meters {
            let per_camera = metrics
                .silhouette_iou
                .entry(meter.object.clone())
                .or_default();
            for (c, series) in meter.series.iter().enumerate() {
                let camera = &streams.cameras[c].0;
                per_camera.insert(
                    camera.clone(),
                    silhouette::iou_stats(
                        &series.iter().map(|s| s.1).collect::<Vec<_>>(),
                        &series.iter().map(|s| s.2).collect::<Vec<_>>(),
                    ),
                );
                for (t, v, visible) in series {
                    csv += &format!("{t:.6},{},{camera},{v:.4},{visible:.4}\n", meter.object);
                }
            }
        }
        std::fs::write(out.join("silhouette_iou.csv"), csv)?;
        silhouette::write_contact_sheet(&out.join("contact_sheet.png"), &sheet)?;
    }
    std::fs::write(
        out.join("metrics.json"),
        serde_json::to_string_pretty(&metrics)?,
    )?;
    metrics.trace = trace;
    Ok(metrics)
}

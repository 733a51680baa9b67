//! `pegs bench`: speed measurements printed as JSON (targets live here, not in tests).

use crate::physics::PhysicsConfig;
use crate::physics::Solver;
use crate::scene::{self, Scene};
use crate::world::Phase;
use anyhow::Result;
use serde::Serialize;
use std::time::Instant;

#[derive(Debug, Serialize)]
pub struct SceneTiming {
    pub scene: String,
    pub dynamic_particles: usize,
    pub kinematic_particles: usize,
    pub shapes: usize,
    pub ticks: usize,
    pub contact_candidates: usize,
    pub ms_per_tick_median: f64,
    pub ms_per_tick_mean: f64,
    pub ms_per_tick_min: f64,
    pub ms_per_tick_max: f64,
}

#[derive(Debug, Serialize)]
pub struct PhysicsBench {
    pub benchmark: &'static str,
    pub threads: usize,
    pub dt: f32,
    pub substeps: u32,
    pub iterations: u32,
    pub scenes: Vec<SceneTiming>,
}

/// A named scene constructor.
pub type SceneMaker = (&'static str, fn() -> Result<Scene>);

/// The scenes `pegs bench physics` measures, by name.
pub fn physics_scenes() -> Vec<SceneMaker> {
    vec![
        ("cube_field_1k", || Ok(scene::cube_field(1_000))),
        ("cube_field_10k", || Ok(scene::cube_field(10_000))),
        ("cube_field_50k", || Ok(scene::cube_field(50_000))),
        ("tblock_robot", scene::tblock_and_robot),
    ]
}

pub fn physics(
    config: &PhysicsConfig,
    ticks: usize,
    warmup: usize,
    only: &[String],
) -> Result<PhysicsBench> {
    let mut scenes = Vec::new();
    for (name, make) in physics_scenes() {
        if !only.is_empty() && !only.iter().any(|o| o == name) {
            continue;
        }
        let mut scene = make()?;
        let mut solver = Solver::new(config.clone(), &scene.world)?;
        for _ in 0..warmup {
            scene.advance(&mut solver)?;
        }
        let mut times = Vec::with_capacity(ticks);
        for _ in 0..ticks {
            let t = Instant::now();
            scene.advance(&mut solver)?;
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let mut sorted = times.clone();
        sorted.sort_by(f64::total_cmp);
        let p = &scene.world.particles;
        scenes.push(SceneTiming {
            scene: name.to_string(),
            dynamic_particles: p.phase.iter().filter(|&&ph| ph == Phase::Dynamic).count(),
            kinematic_particles: p.phase.iter().filter(|&&ph| ph == Phase::Kinematic).count(),
            shapes: scene.world.shapes.len(),
            ticks,
            contact_candidates: solver.stats.contact_candidates,
            ms_per_tick_median: sorted[sorted.len() / 2],
            ms_per_tick_mean: times.iter().sum::<f64>() / times.len() as f64,
            ms_per_tick_min: sorted[0],
            ms_per_tick_max: sorted[sorted.len() - 1],
        });
    }
    Ok(PhysicsBench {
        benchmark: "physics",
        threads: rayon::current_num_threads(),
        dt: config.dt,
        substeps: config.substeps,
        iterations: config.iterations,
        scenes,
    })
}

// ---- rendering ----

use crate::render::cpu::CpuRenderer;
use crate::render::{
    Backend, Camera, GaussianCloud, GaussianParams, PixelGrads, RenderSettings, Roi, logit,
};
use glam::{Vec3, Vec4};

/// The benchmark's tabletop in Gaussians: a T-block (~500), a robot arm (~10k) and the table
/// (~10k thin disks), seen by three cameras. Returns the cloud, the cameras at `width` x `height`,
/// and the index range of the T-block's Gaussians.
pub fn tblock_render_scene(
    width: u32,
    height: u32,
) -> (GaussianCloud, Vec<Camera>, std::ops::Range<usize>) {
    let mut cloud = GaussianCloud::default();
    let unit = Vec4::new(0.0, 0.0, 0.0, 1.0);
    // Table: 100 x 100 disks over 1 m^2, a faint checker so it has texture.
    for iy in 0..100 {
        for ix in 0..100 {
            let shade = if (ix / 10 + iy / 10) % 2 == 0 {
                0.15
            } else {
                0.22
            };
            cloud.push(GaussianParams {
                mean: Vec3::new(-0.2 + ix as f32 * 0.01, -0.5 + iy as f32 * 0.01, 0.0),
                rotation: unit,
                log_scale: Vec3::new(0.006f32.ln(), 0.006f32.ln(), 0.0008f32.ln()),
                opacity_logit: logit(0.95),
                colour: Vec3::splat(shade),
            });
        }
    }
    // Robot: six links, each a cylinder of radius 4 cm sampled on its surface.
    let links = [
        (Vec3::new(0.0, 0.0, 0.16), Vec3::Z),
        (Vec3::new(0.0, 0.0, 0.46), Vec3::Z),
        (Vec3::new(0.1, 0.0, 0.7), Vec3::new(0.93, 0.0, 0.36)),
        (Vec3::new(0.36, 0.0, 0.72), Vec3::new(0.99, 0.0, -0.13)),
        (Vec3::new(0.5, 0.0, 0.55), Vec3::new(0.3, 0.0, -0.95)),
        (Vec3::new(0.52, 0.0, 0.33), Vec3::NEG_Z),
    ];
    for (centre, axis) in links {
        let axis = axis.normalize();
        let side = axis.any_orthonormal_vector();
        let other = axis.cross(side);
        for k in 0..1667 {
            let along = (k / 40) as f32 / 41.0 - 0.5;
            let angle = (k % 40) as f32 / 40.0 * std::f32::consts::TAU;
            let p =
                centre + axis * (0.3 * along) + 0.04 * (side * angle.cos() + other * angle.sin());
            cloud.push(GaussianParams {
                mean: p,
                rotation: unit,
                log_scale: Vec3::splat(0.007f32.ln()),
                opacity_logit: logit(0.9),
                colour: Vec3::splat(0.9),
            });
        }
    }
    // T-block: a 4-layer lattice at 11.2 mm, one Gaussian per point (480).
    let start = cloud.len();
    for p in crate::world::t_block_lattice(0.2, 0.05, 0.045, 0.0112) {
        cloud.push(GaussianParams {
            mean: p + Vec3::new(0.45, 0.0, 0.02),
            rotation: unit,
            log_scale: Vec3::splat(0.0065f32.ln()),
            opacity_logit: logit(0.95),
            colour: Vec3::new(1.0, 0.45, 0.1),
        });
    }
    let end = cloud.len();
    let fx = 0.6 * width as f32;
    let target = Vec3::new(0.45, 0.0, 0.0);
    let cameras = vec![
        Camera::look_at(width, height, fx, Vec3::new(1.2, -0.5, 0.7), target),
        Camera::look_at(width, height, fx, Vec3::new(1.1, 0.6, 0.8), target),
        Camera::look_at(width, height, fx, Vec3::new(0.3, -0.9, 0.9), target),
    ];
    (cloud, cameras, start..end)
}

#[derive(Debug, Serialize)]
pub struct RenderTiming {
    pub backend: String,
    pub resolution: [u32; 2],
    pub window: &'static str,
    /// Pixels rendered per camera (mean over the cameras).
    pub pixels_per_camera: usize,
    pub gaussians: usize,
    pub cameras: usize,
    /// All cameras, median over repetitions.
    pub forward_ms: f64,
    pub forward_backward_ms: f64,
    pub forward_backward_ms_per_camera: f64,
}

#[derive(Debug, Serialize)]
pub struct RenderBench {
    pub benchmark: &'static str,
    pub threads: usize,
    pub runs: Vec<RenderTiming>,
    /// Backends that could not be opened, with the reason.
    pub skipped: Vec<String>,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Time every case on every backend that opens (the wgpu one is skipped with a note when no
/// adapter exists); with `save`, also write each camera's full-frame render there as PNG.
pub fn render(repetitions: usize, save: Option<&std::path::Path>) -> Result<RenderBench> {
    let mut runs = Vec::new();
    let mut skipped = Vec::new();
    let mut renderers = Vec::new();
    for backend in [Backend::Cpu, Backend::Wgpu] {
        match crate::render::open(backend, RenderSettings::default()) {
            Ok(r) => renderers.push(r),
            Err(e) => skipped.push(format!("{backend:?}: {e:#}")),
        }
    }
    for (w, h) in [(640u32, 360u32), (320, 180)] {
        let (cloud, cameras, block) = tblock_render_scene(w, h);
        if let Some(dir) = save {
            std::fs::create_dir_all(dir)?;
            let mut r = CpuRenderer::new(RenderSettings::default());
            for (k, c) in cameras.iter().enumerate() {
                r.forward(&cloud, c, Roi::full(c))
                    .save_png(&dir.join(format!("tblock_{w}x{h}_cam{k}.png")))?;
            }
        }
        for window in ["full", "roi"] {
            let rois: Vec<Roi> = cameras
                .iter()
                .map(|c| {
                    if window == "full" {
                        Roi::full(c)
                    } else {
                        crate::render::footprint_roi(
                            &cloud,
                            &block.clone().collect::<Vec<_>>(),
                            c,
                            8.0,
                        )
                    }
                })
                .collect();
            for renderer in renderers.iter_mut() {
                let (mut fwd, mut both) = (Vec::new(), Vec::new());
                // One untimed pass: pipelines compile and buffers grow on first use.
                for (c, roi) in cameras.iter().zip(&rois) {
                    renderer.forward(&cloud, c, *roi)?;
                }
                for _ in 0..repetitions.max(1) {
                    let t = Instant::now();
                    for (c, roi) in cameras.iter().zip(&rois) {
                        renderer.forward(&cloud, c, *roi)?;
                    }
                    fwd.push(t.elapsed().as_secs_f64() * 1e3);
                    let t = Instant::now();
                    for (c, roi) in cameras.iter().zip(&rois) {
                        let out = renderer.forward(&cloud, c, *roi)?;
                        let grads = PixelGrads {
                            colour: out.colour.iter().map(|c| *c - Vec3::splat(0.5)).collect(),
                            ..Default::default()
                        };
                        renderer.backward(&cloud, &grads)?;
                    }
                    both.push(t.elapsed().as_secs_f64() * 1e3);
                }
                let forward_backward_ms = median(both);
                runs.push(RenderTiming {
                    backend: renderer.name(),
                    resolution: [w, h],
                    window,
                    pixels_per_camera: rois.iter().map(|r| r.pixels()).sum::<usize>() / rois.len(),
                    gaussians: cloud.len(),
                    cameras: cameras.len(),
                    forward_ms: median(fwd),
                    forward_backward_ms,
                    forward_backward_ms_per_camera: forward_backward_ms / cameras.len() as f64,
                });
            }
        }
    }
    Ok(RenderBench {
        benchmark: "render",
        threads: rayon::current_num_threads(),
        runs,
        skipped,
    })
}

// ---- whole ticks ----

#[derive(Debug, Serialize)]
pub struct TickTiming {
    pub backend: String,
    pub resolution: [u32; 2],
    pub cameras: usize,
    pub ticks: usize,
    pub predict_ms: f64,
    pub correct_ms: f64,
    pub tick_ms: f64,
    pub ticks_per_second: f64,
    /// Median milliseconds per tick of each correction stage (see `CorrectStats::stage_ms`).
    pub correct_stages_ms: std::collections::BTreeMap<String, f64>,
    /// The tick that relocates the T-block when tracking starts `LOST_BY` off it; None if no
    /// tick within `MAX_TICKS_LOST` did.
    pub relocation: Option<RelocationTiming>,
}

/// How long finding a lost object took: the tick that moved it, and the search in that tick.
#[derive(Debug, Serialize)]
pub struct RelocationTiming {
    /// Ticks run before it (the object is searched for once its agreement has stayed low).
    pub after_ticks: usize,
    pub tick_ms: f64,
    pub search_ms: f64,
    /// How far it was moved (m) and turned (degrees).
    pub jump_m: f32,
    pub turn_deg: f32,
}

/// The tracker's start off the T-block for `RelocationTiming`: beyond the pose pull's 4 cm, so the
/// object is lost and searched for over the whole relocation radius (25 cm and a full turn).
const LOST_BY: (f32, f32, f32) = (0.06, 0.05, 0.5);
const MAX_TICKS_LOST: usize = 30;

/// Track the T-block from `LOST_BY` off it until it is relocated.
fn relocation(
    scenario_name: &str,
    config: &crate::config::Config,
    cameras: &[crate::render::Camera],
) -> Result<Option<RelocationTiming>> {
    use crate::math::Pose;
    use crate::scenario;
    use crate::tracker::{Change, Tracker};
    // Without the nudge: it moves an object towards the local search's poses before it is ever
    // lost (started `LOST_BY` off, the T-block was not relocated within `MAX_TICKS_LOST`), and
    // this times the relocation search.
    let mut config = config.clone();
    config.correct.pose_nudge = 0.0;
    let config = &config;
    let (x, y, yaw) = LOST_BY;
    let off = Pose::new(glam::Vec3::new(x, y, 0.0), glam::Quat::from_rotation_z(yaw));
    let mut truth = Tracker::new(
        scenario::build(scenario_name, Pose::IDENTITY)?,
        config,
        false,
    )?;
    let mut model = Tracker::new(scenario::build(scenario_name, off)?, config, true)?;
    let dt = config.physics.dt as f64;
    for k in 0..MAX_TICKS_LOST {
        let report = scenario::tick_on_truth((&mut truth, &mut model), cameras, k, dt)?;
        let moved = report.track_events.iter().find_map(|e| match e.change {
            Change::Relocated {
                jump_m, turn_deg, ..
            } => Some((jump_m, turn_deg)),
            _ => None,
        });
        if let Some((jump_m, turn_deg)) = moved {
            let stages = report.correction.as_ref().map(|c| &c.stage_ms);
            return Ok(Some(RelocationTiming {
                after_ticks: k,
                tick_ms: report.predict_ms + report.correct_ms,
                search_ms: stages
                    .and_then(|s| s.get("relocate"))
                    .copied()
                    .unwrap_or(0.0),
                jump_m,
                turn_deg,
            }));
        }
    }
    Ok(None)
}

#[derive(Debug, Serialize)]
pub struct TickBench {
    pub benchmark: &'static str,
    pub scenario: &'static str,
    pub threads: usize,
    pub adam_iterations: u32,
    pub runs: Vec<TickTiming>,
    pub skipped: Vec<String>,
}

/// Time full predict + correct ticks of the pushed T-block scenario (observations rendered
/// beforehand, outside the timing) for each resolution and backend.
pub fn tick(ticks: usize, backends: &[Backend], resolutions: &[(u32, u32)]) -> Result<TickBench> {
    use crate::config::Config;
    use crate::scenario;
    use crate::tracker::Tracker;
    let mut runs = Vec::new();
    let mut skipped = Vec::new();
    let scenario_name = "pushed_tblock";
    for &backend in backends {
        let mut config = Config::default();
        config.correct.backend = backend;
        for &(w, h) in resolutions {
            let cameras = scenario::cameras(scenario_name, w, h);
            let mut truth = Tracker::new(
                scenario::build(scenario_name, crate::math::Pose::IDENTITY)?,
                &config,
                false,
            )?;
            let mut model = match Tracker::new(
                scenario::build(scenario_name, crate::math::Pose::IDENTITY)?,
                &config,
                true,
            ) {
                Ok(m) => m,
                Err(e) => {
                    skipped.push(format!("{backend:?}: {e:#}"));
                    break;
                }
            };
            let (mut predict, mut correct) = (Vec::new(), Vec::new());
            let mut stages: std::collections::BTreeMap<String, Vec<f64>> = Default::default();
            let dt = config.physics.dt as f64;
            for k in 0..ticks + 2 {
                let report = scenario::tick_on_truth((&mut truth, &mut model), &cameras, k, dt)?;
                if k >= 2 {
                    predict.push(report.predict_ms);
                    correct.push(report.correct_ms);
                    for (stage, ms) in report.correction.iter().flat_map(|c| &c.stage_ms) {
                        stages.entry(stage.clone()).or_default().push(*ms);
                    }
                }
            }
            let (p, c) = (median(predict), median(correct));
            runs.push(TickTiming {
                backend: format!("{backend:?}").to_lowercase(),
                resolution: [w, h],
                cameras: cameras.len(),
                ticks,
                predict_ms: p,
                correct_ms: c,
                tick_ms: p + c,
                ticks_per_second: 1e3 / (p + c),
                correct_stages_ms: stages.into_iter().map(|(k, v)| (k, median(v))).collect(),
                relocation: relocation(scenario_name, &config, &cameras)?,
            });
        }
    }
    Ok(TickBench {
        benchmark: "tick",
        scenario: scenario_name,
        threads: rayon::current_num_threads(),
        adam_iterations: crate::correct::CorrectConfig::default().iterations,
        runs,
        skipped,
    })
}

/// Memory and speed of replaying a long bag (`pegs bench bag`).
#[derive(Debug, Serialize)]
pub struct BagBench {
    pub benchmark: &'static str,
    pub scenario: &'static str,
    pub width: u32,
    pub height: u32,
    pub seconds: f64,
    pub bag_bytes: u64,
    pub messages: usize,
    pub write_s: f64,
    pub replay_s: f64,
    pub ticks: usize,
    pub ms_per_tick: f64,
    /// Peak resident memory of this process during the replay alone (VmHWM after resetting
    /// it), MB; and before the replay began.
    pub peak_rss_mb: f64,
    pub rss_before_mb: f64,
    pub tracking_mean_mm: f32,
}

/// Write an uncompressed rosbag2 bag of `seconds` of the resting box (a 1 s recording of it,
/// looped with its stamps shifted: the box stays at rest, so tracking stays meaningful), then
/// replay it and measure the replay's peak resident memory. The bag is left in `dir`.
pub fn bag(seconds: f64, (width, height): (u32, u32), dir: &std::path::Path) -> Result<BagBench> {
    use crate::config::Config;
    use crate::msgs::{self, CameraInfo, Image, JointState};
    use crate::record::{self, RecordingWriter};
    use crate::scenario::generate::{GenerateOptions, generate};
    let scenario = "resting_box";
    let short = dir.join("short");
    let opts = GenerateOptions {
        width,
        height,
        seconds: 1.0,
        ..Default::default()
    };
    generate(scenario, &short, &opts)?;
    let clock = Instant::now();
    let (messages, problem) = record::read_messages(&short.join("recording"))?;
    if let Some(p) = problem {
        anyhow::bail!("the 1 s recording is damaged: {p}");
    }
    let period = messages.iter().map(|m| m.time).fold(0.0, f64::max) + 1.0 / 30.0;
    let long = dir.join("long");
    let mut w = RecordingWriter::create_with(&long, false)?;
    let mut written = 0;
    let loops = (seconds / period).ceil().max(1.0) as usize;
    for k in 0..loops {
        let shift = k as f64 * period;
        for m in &messages {
            let t = m.time + shift;
            let cdr = match m.schema.as_str() {
                "sensor_msgs/msg/Image" => shifted::<Image>(&m.data, shift, |i| &mut i.header)?,
                "sensor_msgs/msg/CameraInfo" => {
                    shifted::<CameraInfo>(&m.data, shift, |i| &mut i.header)?
                }
                "sensor_msgs/msg/JointState" => {
                    shifted::<JointState>(&m.data, shift, |j| &mut j.header)?
                }
                "tf2_msgs/msg/TFMessage" if k == 0 => m.data.clone(),
                _ => continue,
            };
            let schema = msgs::schema::of_type(&m.schema).unwrap_or_default();
            w.write_raw(&m.topic, (schema.0, schema.1), t, &cdr)?;
            written += 1;
        }
    }
    w.finish()?;
    drop(messages);
    // The ground truth looped the same way, beside the long bag.
    let truth = std::fs::read_to_string(short.join("ground_truth.csv"))?;
    let mut lines = truth.lines();
    let mut looped = lines.next().unwrap_or_default().to_string() + "\n";
    let rows: Vec<&str> = lines.collect();
    for k in 0..loops {
        for row in &rows {
            if let Some((t, rest)) = row.split_once(',')
                && let Ok(t) = t.parse::<f64>()
            {
                looped += &format!("{:.6},{rest}\n", t + k as f64 * period);
            }
        }
    }
    std::fs::write(dir.join("ground_truth.csv"), looped)?;
    let write_s = clock.elapsed().as_secs_f64();
    let bag_bytes = std::fs::read_dir(&long)?
        .filter_map(|f| f.ok()?.metadata().ok())
        .map(|m| m.len())
        .sum();
    let config = Config::load(&short.join("config.yaml"))?;
    let rss_before_mb = memory_mb("VmRSS");
    // Writing 5 to clear_refs resets the peak (VmHWM) to the current resident size.
    let _ = std::fs::write("/proc/self/clear_refs", "5");
    let clock = Instant::now();
    let opts = crate::replay::ReplayOptions {
        progress: false,
        ..Default::default()
    };
    let metrics = crate::replay::run(&long, &config, &dir.join("out"), opts)?;
    let replay_s = clock.elapsed().as_secs_f64();
    Ok(BagBench {
        benchmark: "bag",
        scenario,
        width,
        height,
        seconds: loops as f64 * period,
        bag_bytes,
        messages: written,
        write_s,
        replay_s,
        ticks: metrics.ticks,
        ms_per_tick: metrics.wall_ms_per_tick,
        peak_rss_mb: memory_mb("VmHWM"),
        rss_before_mb,
        tracking_mean_mm: metrics
            .tracking_error
            .values()
            .map(|e| e.mean_mm)
            .fold(0.0, f32::max),
    })
}

/// A CDR message with its header's stamp moved by `shift` seconds.
fn shifted<T: Serialize + serde::de::DeserializeOwned>(
    cdr: &[u8],
    shift: f64,
    header: impl Fn(&mut T) -> &mut crate::msgs::Header,
) -> Result<Vec<u8>> {
    let mut msg: T = crate::msgs::from_cdr(cdr)?;
    let h = header(&mut msg);
    h.stamp = crate::msgs::Time::from_seconds(h.stamp.seconds() + shift);
    crate::msgs::to_cdr(&msg)
}

/// A `/proc/self/status` memory figure in MB (NaN where there is none).
fn memory_mb(field: &str) -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| {
            l.strip_prefix(field)?
                .trim_start_matches(':')
                .split_whitespace()
                .next()?
                .parse::<f64>()
                .ok()
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

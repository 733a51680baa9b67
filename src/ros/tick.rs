//! The tick thread. It waits until the configured cameras are known (CameraInfo and pose) and,
//! for a scene initialised from cameras, have sent a first image; builds the world as replay does
//! (a scenario, or `init` from the first frames); then drives `Tracker::tick` at the physics rate
//! on the node's clock (wall or `/clock`), on whatever is newest, skipping ticks whose deadline
//! passed instead of queueing them (the first tick predicts across the whole set-up, from the
//! first frames on); a clock that goes back (a bag played again) restarts the world's clock there.
//! What each tick produced goes to the publishing thread (`Outputs`).

use super::diagnostics::{ObjectHealth, Window, diagnostics, waiting_diagnostics};
use super::node::RunStats;
use super::publish::{Output, TickOutput};
use super::subscribe::Shared;
use super::{RosClock, log, outputs, rss_mb};
use crate::config::Config;
use crate::init::FirstFrames;
use crate::inputs::{TickInputs, decode_depth, decode_image, decode_labels};
use crate::math::Pose;
use crate::msgs::{Header, Time};
use crate::render::{Camera, GaussianCloud};
use crate::robot::RobotConfig;
use crate::scene::Scene;
use crate::topics::NodeConfig;
use crate::tracker::{Observer, Tick, Tracker};
use anyhow::{Context as _, Result, anyhow, bail};
use glam::Quat;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Start the tracker, then tick until `stop`.
pub fn tick_loop(
    config: Config,
    shared: Arc<Mutex<Shared>>,
    live: Arc<Mutex<Config>>,
    tx: SyncSender<Output>,
    stop: Arc<AtomicBool>,
) -> Result<RunStats> {
    let rss_mb_start = rss_mb();
    let Some(mut tracker) = start_tracker(&config, &shared, &stop, &tx)? else {
        return Ok(RunStats {
            rss_mb_start,
            ..Default::default()
        });
    };
    let dt = config.physics.dt as f64;
    let clock = shared
        .lock()
        .map_err(|_| anyhow!("state lock poisoned"))?
        .clock
        .clone();
    // Simulated time may run at any rate: look at it often rather than sleep until a deadline.
    let poll = if clock.is_simulated() { 0.002 } else { 0.1 };
    let mut outputs = Outputs::new(&config, shared.clone(), tx);
    outputs.stats.rss_mb_start = rss_mb_start;
    let mut applied = config;
    // The world's clock is the node's clock: tick k ends at start + k dt, whatever happened before.
    let mut next = tracker.time() + dt;
    let started = RosClock::wall();
    let mut index = 0;
    while !stop.load(Ordering::SeqCst) {
        let Some(now) = clock.now() else {
            std::thread::sleep(Duration::from_secs_f64(poll));
            continue;
        };
        if now < next - dt - CLOCK_BACK_S {
            log(&format!(
                "the clock went back from {:.3} s to {now:.3} s (a recording played again?): the \
                 world's clock restarts there",
                next - dt
            ));
            tracker.restart_clock(now);
            next = now + dt;
            continue;
        }
        let wait = next - now;
        if wait > 0.0 {
            std::thread::sleep(Duration::from_secs_f64(wait.min(poll)));
            continue;
        }
        // A tick whose deadline passed more than a period ago is not run late: it is skipped, and
        // the world is predicted across it without correction (its images are gone).
        while now - next > dt {
            next += dt;
            outputs.stats.skipped_ticks += 1;
        }
        outputs.clock = Instant::now();
        // Newest configuration from the parameter services.
        if let Ok(c) = live.lock()
            && *c != applied
        {
            applied = c.clone();
            tracker.set_correct(applied.correct.clone());
            outputs.debug_every = applied.node.debug_images_every as usize;
        }
        join_late_cameras(&shared, &applied.node, next)?;
        let max_age = applied.correct.max_image_age as f64;
        let inputs = take_inputs(&shared, tracker.time(), next, max_age)?;
        let report = if index == 0 {
            let report = tracker.first_tick(&inputs)?;
            log(&format!(
                "first tick at {next:.3} s: the {:.2} s since the first frames predicted ({} ticks)",
                report.caught_up as f64 * dt,
                report.caught_up
            ));
            report
        } else {
            tracker.tick(&inputs)?
        };
        if report.jumped_s > 0.0 {
            log(&format!(
                "tick at {next:.3} s ran {:.2} s late: the world's clock jumped {:.2} s unpredicted \
                 (the robot stands at once where its joint states took it)",
                (report.caught_up + 1) as f64 * dt + report.jumped_s,
                report.jumped_s
            ));
            outputs.stats.jumped_s += report.jumped_s;
        }
        index += 1;
        outputs.gain = tracker.visual_gain().unwrap_or(applied.correct.gain);
        outputs.max_age = applied.correct.max_image_age as f64;
        outputs.tick(&Tick {
            index,
            tracker: &tracker,
            inputs: &inputs,
            report: &report,
        })?;
        next += dt;
    }
    Ok(outputs.finish(RosClock::wall() - started))
}

/// A clock this far behind the world's (s) went back: the world's clock restarts from it.
pub const CLOCK_BACK_S: f64 = 1.0;

/// What the tick from the world's clock `from` to `t` consumes, and the input explanations
/// logged.
fn take_inputs(shared: &Mutex<Shared>, from: f64, t: f64, max_age: f64) -> Result<TickInputs> {
    let Ok(mut s) = shared.lock() else {
        bail!("state lock poisoned")
    };
    let Some(inputs) = s.inputs.as_mut() else {
        bail!("inputs missing")
    };
    let tick = inputs.tick_inputs_from(from, t, max_age);
    for line in inputs.log.take_lines() {
        log(&line);
    }
    Ok(tick)
}

/// The cameras that are ready (CameraInfo and pose), in configuration order.
fn ready_cameras(s: &Shared, nc: &NodeConfig) -> Vec<(String, Camera)> {
    nc.cameras
        .iter()
        .filter_map(|name| {
            let info = s.infos.get(name)?;
            let pose = s.camera_poses.get(name)?;
            let k = info.k;
            let (fx, fy, cx, cy) = (k[0] as f32, k[4] as f32, k[2] as f32, k[5] as f32);
            let camera = Camera::from_opencv(info.width, info.height, fx, fy, cx, cy, *pose);
            Some((name.clone(), camera))
        })
        .collect()
}

/// Wait for the cameras, then build the scene and its tracker; None if stopped first. While
/// waiting, `/diagnostics` says what for, every `node.diagnostics_period`.
fn start_tracker(
    config: &Config,
    shared: &Mutex<Shared>,
    stop: &AtomicBool,
    tx: &SyncSender<Output>,
) -> Result<Option<Tracker>> {
    let nc = &config.node;
    let started = RosClock::wall();
    let mut told = false;
    let mut said_at = f64::NEG_INFINITY;
    loop {
        if RosClock::wall() - said_at >= nc.diagnostics_period as f64 {
            said_at = RosClock::wall();
            let s = shared.lock().map_err(|_| anyhow!("state lock poisoned"))?;
            let header = Header {
                stamp: Time::from_seconds(s.clock.now().unwrap_or(0.0)),
                frame_id: String::new(),
            };
            let from_frames = config.scene.scenario.is_none();
            let (description, base) = robot_missing(config, &s);
            let robot: Vec<String> = description.into_iter().chain(base).collect();
            let waiting =
                waiting_diagnostics(&header, &s, nc, from_frames, &robot, said_at - started);
            // A full channel only means the publisher is busy; the next period says it again.
            let _ = tx.try_send(Output::Waiting(waiting));
        }
        if stop.load(Ordering::SeqCst) {
            return Ok(None);
        }
        let (cameras, needs_images, clock_runs, (description, base)) = {
            let s = shared.lock().map_err(|_| anyhow!("state lock poisoned"))?;
            let cameras = ready_cameras(&s, nc);
            let from_frames = config.scene.scenario.is_none();
            let needs_images =
                from_frames && cameras.iter().any(|(c, _)| !s.first_images.contains_key(c));
            let clock_runs = s.clock.now().is_some();
            (cameras, needs_images, clock_runs, robot_missing(config, &s))
        };
        let waited = RosClock::wall() - started;
        // The robot's description is waited for; a named base frame's tf as long as cameras are.
        let all = cameras.len() == nc.cameras.len() && base.is_none();
        let ready = !cameras.is_empty() && !needs_images && clock_runs && description.is_none();
        if ready && (all || waited > nc.camera_wait as f64) {
            return start(config, cameras, shared, waited).map(Some);
        }
        if !told && waited > 1.0 {
            log(&format!(
                "waiting for CameraInfo and /tf_static of {:?}{}",
                nc.cameras,
                if clock_runs {
                    ""
                } else {
                    ", and /clock (use_sim_time)"
                }
            ));
            told = true;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Cameras left out at start that are ready now (CameraInfo and pose) join the tracking from
/// their next image; said in the log, and their diagnostics clear.
fn join_late_cameras(shared: &Mutex<Shared>, nc: &NodeConfig, t: f64) -> Result<()> {
    let mut s = shared.lock().map_err(|_| anyhow!("state lock poisoned"))?;
    if s.unused_cameras.is_empty() {
        return Ok(());
    }
    for (name, camera) in ready_cameras(&s, nc) {
        if s.unused_cameras.remove(&name).is_none() {
            continue;
        }
        if let Some(inputs) = s.inputs.as_mut() {
            inputs.add_camera(name.clone(), camera);
        }
        log(&format!(
            "camera {name}: ready at {t:.3} s; joins the tracking"
        ));
    }
    Ok(())
}

/// Log and remember the configured cameras that are not ready.
fn report_unused_cameras(s: &mut Shared, nc: &NodeConfig, ready: &[(String, Camera)], waited: f64) {
    for name in &nc.cameras {
        if ready.iter().any(|(c, _)| c == name) {
            continue;
        }
        let why = match (
            s.infos.contains_key(name),
            s.camera_poses.contains_key(name),
        ) {
            (false, _) => "no CameraInfo",
            (true, false) => "no /tf_static transform to its optical frame",
            _ => "not ready",
        };
        log(&format!(
            "camera {name}: {why} after {waited:.1} s; continuing without it"
        ));
        s.unused_cameras.insert(name.clone(), why.to_string());
    }
}

/// Build the world from what has arrived and its tracker. The world begins when its first frames
/// and joint state were the newest; the subscriptions run on while it is built (no lock held), and
/// the joint states that came meanwhile go to the tracker's inputs, so the first tick predicts the
/// robot along them across however long building took (`Tracker::first_tick`).
fn start(
    config: &Config,
    cameras: Vec<(String, Camera)>,
    shared: &Mutex<Shared>,
    waited: f64,
) -> Result<Tracker> {
    let lock = || shared.lock().map_err(|_| anyhow!("state lock poisoned"));
    let (first, t) = {
        let mut s = lock()?;
        report_unused_cameras(&mut s, &config.node, &cameras, waited);
        let t = s.clock.now().context("no time yet")?;
        (s.first_arrivals(), t)
    };
    let mut scene = build_scene(config, &cameras, &first)?;
    scene.world.time = t;
    let tracker = Tracker::new(scene, config, true)?;
    let mut inputs = tracker.inputs(cameras);
    let robot = &config.robot;
    inputs.rename_joints(&robot.joint_prefix_received, &robot.joint_prefix_urdf);
    let mut s = lock()?;
    let now = s.clock.now().unwrap_or(t);
    let since = first
        .joint_history
        .back()
        .map(|js| js.header.stamp.seconds());
    for js in std::mem::take(&mut s.joint_history) {
        if since.is_none_or(|t0| js.header.stamp.seconds() >= t0) {
            let _ = inputs.offer_joint_state(&js, now);
        }
    }
    for (c, img) in std::mem::take(&mut s.first_images) {
        if let Some(k) = inputs.camera_index(&c) {
            let _ = inputs.offer_image(k, &img, now);
        }
    }
    log(&format!(
        "tracking {} object(s) with {} camera(s)",
        tracker.world().shapes.dynamic_ids().count(),
        inputs.cameras.len()
    ));
    s.inputs = Some(inputs);
    Ok(tracker)
}

/// A built-in scenario's world, or one initialised from the first frames (as `pegs replay` does).
fn build_scene(config: &Config, cameras: &[(String, Camera)], s: &Shared) -> Result<Scene> {
    if let Some(name) = &config.scene.scenario {
        let offset = Pose::new(
            config.scene.offset_position,
            Quat::from_rotation_z(config.scene.offset_yaw),
        );
        return crate::scenario::build(name, offset);
    }
    let mut images = Vec::new();
    for (name, cam) in cameras {
        let img = s
            .first_images
            .get(name)
            .with_context(|| format!("camera {name}: no first image"))?;
        let decoded = decode_image(img, cam)
            .map_err(|why| anyhow!("camera {name}: first image unusable: {why}"))?;
        images.push(decoded);
    }
    let unit = config.node.depth_unit;
    let depth: Vec<Option<Vec<f32>>> = cameras
        .iter()
        .map(|(n, c)| {
            let image = s.first_depth.get(n)?;
            usable(n, "depth image", decode_depth(image, c, unit))
        })
        .collect();
    let labels: Vec<Option<Vec<u8>>> = cameras
        .iter()
        .map(|(n, c)| {
            let image = s.first_masks.get(n)?;
            usable(n, "mask image", decode_labels(image, c))
        })
        .collect();
    let frames: Vec<FirstFrames> = cameras
        .iter()
        .enumerate()
        .map(|(k, (name, cam))| FirstFrames {
            name: name.clone(),
            camera: *cam,
            images: vec![images[k].as_slice()],
            depth: depth[k].as_deref(),
            labels: labels[k].as_deref(),
        })
        .collect();
    let joints: Vec<(String, f64)> = s
        .joint_history
        .back()
        .map(|js| {
            let named = js.name.iter().cloned().zip(js.position.iter().copied());
            named.filter(|(_, v)| v.is_finite()).collect()
        })
        .unwrap_or_default();
    let robot = robot_config(config, s)?;
    let settings = crate::init::Settings {
        robot: &robot,
        ..config.init()
    };
    let (scene, report) = crate::init::build_scene(&settings, &frames, &joints, false)?;
    for line in report.lines() {
        log(&line);
    }
    Ok(scene)
}

/// What the robot still lacks before a scene is built from the first frames: the URDF on
/// `robot.description_topic`, and the tf to `robot.base_frame` when one is named.
fn robot_missing(config: &Config, s: &Shared) -> (Option<String>, Option<String>) {
    let robot = &config.robot;
    if config.scene.scenario.is_some() {
        return (None, None);
    }
    let topic = &robot.description_topic;
    let description = (!topic.is_empty() && s.robot_description.is_none())
        .then(|| format!("robot_description on {topic}"));
    let world = &config.node.world_frame;
    let frame = &robot.base_frame;
    let base = (!frame.is_empty() && s.tf.lookup_nearest(world, frame, 0.0).is_err())
        .then(|| format!("tf {world} -> {frame} (robot base)"));
    (description, base)
}

/// The robot as the node builds it: from the URDF received on `robot.description_topic` when
/// one is set, standing where `/tf_static` puts its base (said in the log).
fn robot_config(config: &Config, s: &Shared) -> Result<RobotConfig> {
    let description = s.robot_description.as_deref();
    let world = &config.node.world_frame;
    let (robot, line) = crate::init::rig::rig_robot(&config.robot, description, &s.tf, world)?;
    if let Some(line) = line {
        log(&line);
    }
    Ok(robot)
}

/// A decoded first depth or mask image, or None with the reason logged: initialisation goes on
/// without it (and says so itself if an object then cannot be built).
fn usable<T>(camera: &str, what: &str, decoded: Result<T, String>) -> Option<T> {
    decoded
        .map_err(|why| log(&format!("camera {camera}: first {what} not used: {why}")))
        .ok()
}

/// The node's observer of ticks: builds each tick's messages for the publishing thread, keeps the
/// run's statistics and the window of numbers `/diagnostics` reports.
struct Outputs {
    shared: Arc<Mutex<Shared>>,
    tx: SyncSender<Output>,
    node: NodeConfig,
    world_frame: String,
    dt: f64,
    diagnostics_period: f64,
    debug_every: usize,
    /// When the current tick started (for its duration).
    clock: Instant,
    /// The gain and image age limit the tick corrected with (for diagnostics).
    gain: f32,
    max_age: f64,
    window: Window,
    last_diagnostics: f64,
    tick_ms: Vec<f64>,
    stats: RunStats,
}

impl Outputs {
    fn new(config: &Config, shared: Arc<Mutex<Shared>>, tx: SyncSender<Output>) -> Self {
        Self {
            shared,
            tx,
            node: config.node.clone(),
            world_frame: config.node.world_frame.clone(),
            dt: config.physics.dt as f64,
            diagnostics_period: config.node.diagnostics_period as f64,
            debug_every: config.node.debug_images_every as usize,
            clock: Instant::now(),
            gain: config.correct.gain,
            max_age: config.correct.max_image_age as f64,
            window: Window::default(),
            last_diagnostics: RosClock::wall(),
            tick_ms: Vec::new(),
            stats: RunStats::default(),
        }
    }

    /// Camera `name`'s optical frame: the template's, or its CameraInfo's frame_id.
    fn optical_frame(&self, name: &str) -> String {
        let header = self
            .shared
            .lock()
            .ok()
            .and_then(|s| Some(s.infos.get(name)?.header.frame_id.clone()))
            .unwrap_or_default();
        self.node.optical_frame_of(name, &header)
    }

    /// The run's statistics after `elapsed` seconds of ticking.
    fn finish(mut self, elapsed: f64) -> RunStats {
        let stats = &mut self.stats;
        stats.achieved_rate_hz = stats.ticks as f64 / elapsed.max(1e-9);
        let ms = &mut self.tick_ms;
        ms.sort_by(f64::total_cmp);
        stats.tick_ms_mean = ms.iter().sum::<f64>() / ms.len().max(1) as f64;
        let p95 = ((ms.len() as f64 * 0.95) as usize).min(ms.len().saturating_sub(1));
        stats.tick_ms_p95 = ms.get(p95).copied().unwrap_or(f64::NAN);
        stats.rss_mb_end = rss_mb();
        if let Ok(s) = self.shared.lock()
            && let Some(inputs) = &s.inputs
        {
            stats.images_rejected = inputs.log.images_rejected;
            stats.joint_states_rejected = inputs.log.joint_states_rejected;
            let rejections = inputs.rejections.iter();
            stats.rejections = rejections.map(|(k, v)| (k.to_string(), *v)).collect();
            let cameras = inputs.cameras.iter();
            stats.images_accepted = cameras.map(|f| (f.name.clone(), f.accepted)).collect();
        }
        log(&format!(
            "stopped after {} ticks ({:.1} Hz, {} overruns, {} skipped, {:.2} s jumped)",
            stats.ticks,
            stats.achieved_rate_hz,
            stats.overruns,
            stats.skipped_ticks,
            stats.jumped_s
        ));
        self.stats
    }

    /// Count the tick into the statistics and the diagnostics window.
    fn count(&mut self, tick: &Tick) {
        let tick_ms = self.clock.elapsed().as_secs_f64() * 1e3;
        self.stats.ticks += 1;
        if tick_ms > self.dt * 1e3 {
            self.stats.overruns += 1;
        }
        let w = &mut self.window;
        w.ticks += 1;
        w.tick_ms.push(tick_ms);
        w.no_views += tick.inputs.images.is_empty() as usize;
        w.gain = self.gain;
        w.max_age = self.max_age;
        w.count_images(tick.inputs);
        if let Some(c) = &tick.report.correction {
            w.loss += c.loss_before as f64;
            w.force += c.force.iter().map(|f| f.length() as f64).sum::<f64>();
        }
        self.tick_ms.push(tick_ms);
    }

    /// Diagnostics when the period has passed.
    fn diagnostics(
        &mut self,
        header: &Header,
        tick: &Tick,
    ) -> Option<crate::msgs::DiagnosticArray> {
        if RosClock::wall() - self.last_diagnostics < self.diagnostics_period {
            return None;
        }
        self.last_diagnostics = RosClock::wall();
        let world = tick.tracker.world();
        let health = tick.tracker.health();
        let objects: Vec<ObjectHealth> = world
            .shapes
            .dynamic_ids()
            .map(|shape| ObjectHealth {
                name: world.shapes.name[shape as usize].clone(),
                lost: health.is_lost(shape),
                agreement: health.agreement(shape),
                relocations: health.relocations(shape),
                off_table: tick.tracker.table_edge().is_off(shape),
            })
            .collect();
        let s = self.shared.lock().ok()?;
        let (window, stats) = (&self.window, &self.stats);
        let d = diagnostics(header, &s, tick.inputs, window, stats, self.dt, &objects);
        self.window = Window::default();
        d
    }
}

impl Observer for Outputs {
    fn tick(&mut self, tick: &Tick) -> Result<()> {
        let world = tick.tracker.world();
        for e in &tick.report.track_events {
            let name = &world.shapes.name[e.shape as usize];
            log(&e.describe(name, e.time));
        }
        let header = Header {
            stamp: Time::from_seconds(tick.inputs.time),
            frame_id: self.world_frame.clone(),
        };
        let objects = outputs::tracked_objects(world, tick.report.correction.as_ref(), &header);
        self.count(tick);
        let images = &tick.inputs.images;
        let newest_image = images.iter().map(|i| i.stamp).reduce(f64::max);
        let debug = (self.debug_every > 0 && self.stats.ticks.is_multiple_of(self.debug_every))
            .then(|| {
                let cameras = images
                    .iter()
                    .map(|i| (i.name.clone(), i.camera, self.optical_frame(&i.name)))
                    .collect();
                (GaussianCloud::from_world(world), cameras)
            });
        let diagnostics = self.diagnostics(&header, tick);
        let cloud = outputs::particle_cloud(world, &header);
        let output = TickOutput {
            header,
            objects,
            cloud,
            newest_image,
            debug,
            diagnostics,
        };
        match self.tx.try_send(Output::Tick(Box::new(output))) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => self.stats.dropped_outputs += 1,
            Err(TrySendError::Disconnected(_)) => bail!("the publishing thread stopped"),
        }
        Ok(())
    }
}

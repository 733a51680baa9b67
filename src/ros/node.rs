//! The running node. Three kinds of threads, none of which waits on another for long:
//! - tokio tasks (two workers) receive messages, check them and hand them to `Inputs`;
//! - the tick thread starts the tracker once cameras are known, then runs predict / correct at
//!   the physics rate on whatever is newest, counting overruns instead of queueing ticks;
//! - the publishing thread renders debug images and publishes, dropping a tick's output if the
//!   previous one is still being sent.

use super::NodeConfig;
use super::outputs;
use super::params::{self, LaunchArgs};
use crate::config::Config;
use crate::inputs::Inputs;
use crate::math::Pose;
use crate::msgs::{
    CameraInfo, CompressedImage, DiagnosticArray, DiagnosticStatus, Header, Image, JointState,
    KeyValue, PointCloud2, PoseArray, TfMessage, Time, TrackedObjectArray,
};
use crate::render::{Camera, GaussianCloud, Roi};
use crate::scene::builtin::Scene;
use crate::tracker::Tracker;
use anyhow::{Context as _, Result, anyhow, bail};
use futures::StreamExt;
use glam::{Quat, Vec3};
use ros2_client::dds::rustdds::{self, TopicKind, policy::ResourceLimits};
use ros2_client::qos::{Durability, History, Reliability, WhenFull};
use ros2_client::{
    Context, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher, QosProfile,
};
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{SyncSender, TrySendError, sync_channel};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// How long the node waits for every camera's CameraInfo and /tf_static transform before it
/// starts with the cameras it has.
const CAMERA_WAIT_S: f64 = 5.0;
/// At most this many missed ticks are caught up by prediction alone; beyond it the world jumps.
const MAX_CATCH_UP_TICKS: usize = 10;

/// Seconds since the Unix epoch: the node's clock (ROS time without simulated time).
pub fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

fn log(line: &str) {
    eprintln!("[pegs {:.3}] {line}", now());
}

/// Options of `pegs node` beyond the configuration.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// Stop after this many seconds (None: until SIGINT / SIGTERM).
    pub duration: Option<f64>,
    /// Write run statistics (JSON) here on exit.
    pub stats: Option<std::path::PathBuf>,
}

/// What the node measured over its run (also the content of `--stats`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct RunStats {
    pub ticks: usize,
    pub overruns: usize,
    pub skipped_ticks: usize,
    pub dropped_outputs: usize,
    pub achieved_rate_hz: f64,
    pub tick_ms_mean: f64,
    pub tick_ms_p95: f64,
    /// Newest image stamp used by a tick to the publication of that tick's poses.
    pub latency_ms_p50: f64,
    pub latency_ms_p95: f64,
    pub images_rejected: usize,
    pub joint_states_rejected: usize,
    pub malformed_messages: usize,
    pub rss_mb_start: f64,
    pub rss_mb_end: f64,
    pub rejections: BTreeMap<String, usize>,
    /// Images accepted per camera over the tracking run (a rate far below the camera's says the
    /// network lost them: large best-effort samples arrive only if every fragment does).
    pub images_accepted: BTreeMap<String, usize>,
}

/// Resident memory of this process in MB (Linux; 0 elsewhere).
pub fn rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<f64>().ok())
        .map_or(0.0, |pages| pages * 4096.0 / 1e6)
}

/// Everything the subscriptions have delivered, shared with the tick thread (held briefly).
#[derive(Default)]
struct Shared {
    infos: BTreeMap<String, CameraInfo>,
    /// Camera name -> world-to-camera pose, from /tf_static.
    camera_poses: BTreeMap<String, Pose>,
    /// Before the tracker starts: the newest image, depth and mask of each camera (for init).
    first_images: BTreeMap<String, Image>,
    first_depth: BTreeMap<String, Image>,
    first_masks: BTreeMap<String, Image>,
    last_joint_state: Option<JointState>,
    inputs: Option<Inputs>,
    malformed: BTreeMap<String, usize>,
    bad_camera_info: BTreeMap<String, String>,
    /// Configured cameras left out at start, with the reason.
    unused_cameras: BTreeMap<String, String>,
}

/// One tick's results for the publishing thread.
struct TickOutput {
    header: Header,
    objects: TrackedObjectArray,
    cloud: PointCloud2,
    /// Newest image stamp used (for the end-to-end latency).
    newest_image: Option<f64>,
    debug: Option<(GaussianCloud, Vec<(String, Camera)>)>,
    diagnostics: Option<DiagnosticArray>,
}

struct Publishers {
    objects: Publisher<TrackedObjectArray>,
    poses: Publisher<PoseArray>,
    cloud: Publisher<PointCloud2>,
    tf: Publisher<TfMessage>,
    diagnostics: Publisher<DiagnosticArray>,
    debug: BTreeMap<String, (Publisher<Image>, Publisher<CompressedImage>)>,
}

fn topic_name(full: &str) -> Result<Name> {
    Name::parse(full).map_err(|e| anyhow!("bad topic name '{full}': {e:?}"))
}

fn sensor_qos() -> QosProfile {
    QosProfile::subscription_default()
        .reliability(Reliability::BestEffort)
        .history(History::KeepLast { depth: 2 })
}

fn state_qos(depth: usize) -> QosProfile {
    QosProfile::publisher_default()
        .reliability(Reliability::Reliable {
            when_full: WhenFull::Wait(Duration::from_millis(5)),
        })
        .history(History::KeepLast { depth })
}

fn latched_qos() -> QosProfile {
    state_qos(100).durability(Durability::TransientLocal)
}

fn ros_context() -> Result<Context> {
    let domain = match std::env::var("ROS_DOMAIN_ID") {
        Ok(s) if !s.trim().is_empty() => s
            .trim()
            .parse::<u16>()
            .with_context(|| format!("ROS_DOMAIN_ID='{s}' is not a domain id"))?,
        _ => 0,
    };
    // As with rmw implementations: LOCALHOST keeps discovery and traffic on the loopback interface.
    let localhost = std::env::var("ROS_AUTOMATIC_DISCOVERY_RANGE")
        .is_ok_and(|v| v.eq_ignore_ascii_case("LOCALHOST"));
    let participant = ros2_client::dds::rustdds::DomainParticipantBuilder::new(domain);
    let participant = if localhost {
        participant.with_only_networks([std::net::Ipv4Addr::LOCALHOST])
    } else {
        participant
    };
    let participant = participant
        .build()
        .map_err(|e| anyhow!("cannot start DDS on domain {domain}: {e:?}"))?;
    log(&format!(
        "DDS domain {domain}{}",
        if localhost { ", loopback only" } else { "" }
    ));
    Context::from_domain_participant(participant)
        .map_err(|e| anyhow!("cannot create the ROS context: {e:?}"))
}

/// Run the node until SIGINT / SIGTERM or `options.duration`.
pub fn run(config: Config, launch: &LaunchArgs, options: RunOptions) -> Result<RunStats> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    runtime.block_on(run_async(config, launch, options))
}

async fn run_async(config: Config, launch: &LaunchArgs, options: RunOptions) -> Result<RunStats> {
    let context = ros_context()?;
    let live_config = Arc::new(Mutex::new(config.clone()));
    let mut node_options = NodeOptions::new()
        .enable_rosout(true)
        .start_parameter_services(true);
    for (name, value) in params::flatten(&config)? {
        node_options = node_options.declare_parameter(&name, value);
    }
    let check = live_config.clone();
    let apply = live_config.clone();
    node_options = node_options
        .parameter_validator(Box::new(move |name, value| {
            let current = check
                .lock()
                .map_err(|_| "configuration lock poisoned".to_string())?
                .clone();
            let json = params::from_parameter(value)
                .ok_or_else(|| format!("{name}: unsupported value type"))?;
            let next =
                params::with_parameter(&current, name, json).map_err(|e| format!("{e:#}"))?;
            if next != current && !params::is_live(name) {
                return Err(format!(
                    "{name} is fixed once the node runs; restart with -p {name}:=VALUE"
                ));
            }
            Ok(())
        }))
        .parameter_set_action(Box::new(move |name, value| {
            let mut current = apply
                .lock()
                .map_err(|_| "configuration lock poisoned".to_string())?;
            let json = params::from_parameter(value)
                .ok_or_else(|| format!("{name}: unsupported value type"))?;
            let next =
                params::with_parameter(&current, name, json).map_err(|e| format!("{e:#}"))?;
            if next != *current {
                log(&format!(
                    "parameter {name} set to {value:?}; applied from the next tick"
                ));
                *current = next;
            }
            Ok(())
        }));
    let node_name = launch.node_name.clone().unwrap_or_else(|| "pegs".into());
    let namespace = launch.namespace.clone().unwrap_or_else(|| "/".into());
    let mut node = context
        .new_node(
            NodeName::new(&namespace, &node_name).map_err(|e| anyhow!("bad node name: {e:?}"))?,
            node_options,
        )
        .map_err(|e| anyhow!("cannot create node: {e:?}"))?;
    tokio::spawn(node.spinner().map_err(|e| anyhow!("{e:?}"))?.spin());

    let nc = config.node.clone();
    let shared = Arc::new(Mutex::new(Shared::default()));
    let publishers = create_publishers(&mut node, &nc)?;
    let node_name =
        NodeName::new(&namespace, &node_name).map_err(|e| anyhow!("bad node name: {e:?}"))?;
    subscribe(&context, &node_name, &mut node, &nc, shared.clone())?;
    log(&format!(
        "node {} up: cameras {:?}, rate {:.1} Hz",
        node.fully_qualified_name(),
        nc.cameras,
        1.0 / config.physics.dt
    ));

    let stop = Arc::new(AtomicBool::new(false));
    let (tx, rx) = sync_channel::<TickOutput>(1);
    let latencies = Arc::new(Mutex::new(Vec::<f64>::new()));
    let publisher_thread = {
        let latencies = latencies.clone();
        let (render, optical_frame) = (config.render.clone(), nc.optical_frame.clone());
        std::thread::Builder::new()
            .name("pegs-publish".into())
            .spawn(move || publish_loop(rx, publishers, render, &optical_frame, latencies))?
    };
    let tick_thread = {
        let (shared, stop, live) = (shared.clone(), stop.clone(), live_config.clone());
        std::thread::Builder::new()
            .name("pegs-tick".into())
            .spawn(move || tick_loop(config, shared, live, tx, stop))?
    };
    let deadline = options
        .duration
        .map(|d| tokio::time::Instant::now() + Duration::from_secs_f64(d));
    let mut terminate = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    tokio::select! {
        _ = tokio::signal::ctrl_c() => log("SIGINT: stopping"),
        _ = terminate.recv() => log("SIGTERM: stopping"),
        _ = async { match deadline { Some(d) => tokio::time::sleep_until(d).await, None => std::future::pending().await } } => log("duration reached: stopping"),
    }
    stop.store(true, Ordering::SeqCst);
    let mut stats = tick_thread
        .join()
        .map_err(|_| anyhow!("the tick thread panicked"))??;
    publisher_thread
        .join()
        .map_err(|_| anyhow!("the publishing thread panicked"))?;
    let mut l = latencies
        .lock()
        .map_err(|_| anyhow!("latency lock poisoned"))?
        .clone();
    l.sort_by(f64::total_cmp);
    let pick = |q: f64| {
        if l.is_empty() {
            f64::NAN
        } else {
            l[((l.len() as f64 * q) as usize).min(l.len() - 1)] * 1e3
        }
    };
    stats.latency_ms_p50 = pick(0.5);
    stats.latency_ms_p95 = pick(0.95);
    if let Ok(s) = shared.lock() {
        stats.malformed_messages = s.malformed.values().sum();
    }
    node.stop_spinner();
    if let Some(path) = &options.stats {
        std::fs::write(path, serde_json::to_string_pretty(&stats)?)
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(stats)
}

fn create_publishers(node: &mut Node, nc: &NodeConfig) -> Result<Publishers> {
    fn make<T: serde::Serialize>(
        node: &mut Node,
        name: &str,
        package: &str,
        ty: &str,
        qos: QosProfile,
    ) -> Result<Publisher<T>> {
        let topic = node
            .create_topic(&topic_name(name)?, MessageTypeName::new(package, ty), &qos)
            .map_err(|e| anyhow!("topic {name}: {e:?}"))?;
        node.create_publisher(&topic, None)
            .map_err(|e| anyhow!("publisher {name}: {e:?}"))
    }
    let p = &nc.output_prefix;
    let mut debug = BTreeMap::new();
    for cam in &nc.cameras {
        let raw = make(
            node,
            &format!("{p}/debug/{cam}/image"),
            "sensor_msgs",
            "Image",
            sensor_qos(),
        )?;
        let compressed = make(
            node,
            &format!("{p}/debug/{cam}/image/compressed"),
            "sensor_msgs",
            "CompressedImage",
            sensor_qos(),
        )?;
        debug.insert(cam.clone(), (raw, compressed));
    }
    Ok(Publishers {
        objects: make(
            node,
            &format!("{p}/objects"),
            "pegs",
            "TrackedObjectArray",
            state_qos(10),
        )?,
        poses: make(
            node,
            &format!("{p}/poses"),
            "geometry_msgs",
            "PoseArray",
            state_qos(10),
        )?,
        cloud: make(
            node,
            &format!("{p}/particles"),
            "sensor_msgs",
            "PointCloud2",
            sensor_qos(),
        )?,
        tf: make(node, "/tf", "tf2_msgs", "TFMessage", state_qos(100))?,
        diagnostics: make(
            node,
            "/diagnostics",
            "diagnostic_msgs",
            "DiagnosticArray",
            state_qos(10),
        )?,
        debug,
    })
}

/// Creates subscription topics whose receive cache holds no more samples than the history depth.
/// ros2-client's QoS profiles carry no resource limits, and without them RustDDS keeps up to 64
/// samples per topic whatever the depth: 64 images per camera, and for topics that publish
/// rarely (depth and masks, once per recording loop) a cache that fills for minutes, which is
/// the memory growth a long run showed.
struct BoundedTopics<'a> {
    context: &'a Context,
    node_name: &'a NodeName,
}

impl BoundedTopics<'_> {
    fn create(
        &self,
        name: &str,
        type_name: MessageTypeName,
        qos: &QosProfile,
    ) -> Result<rustdds::Topic> {
        let mut policies = rustdds::QosPolicies::from(qos);
        if let History::KeepLast { depth } = qos.history {
            let depth = depth as i32;
            let limits = rustdds::QosPolicyBuilder::new()
                .resource_limits(ResourceLimits {
                    max_samples: depth,
                    max_instances: 1,
                    max_samples_per_instance: depth,
                })
                .build();
            policies = policies.modify_by(&limits);
        }
        let dds_name = topic_name(name)?.to_dds_name("rt", self.node_name, "");
        self.context
            .domain_participant()
            .create_topic(
                dds_name,
                type_name.dds_msg_type(),
                &policies,
                TopicKind::NoKey,
            )
            .map_err(|e| anyhow!("topic {name}: {e:?}"))
    }
}

/// Spawn one task per subscription. A message that cannot be decoded is counted and logged;
/// nothing a publisher sends stops a task.
fn subscribe(
    context: &Context,
    node_name: &NodeName,
    node: &mut Node,
    nc: &NodeConfig,
    shared: Arc<Mutex<Shared>>,
) -> Result<()> {
    let bounded = BoundedTopics { context, node_name };
    #[allow(clippy::too_many_arguments)]
    fn sub<T: 'static + serde::de::DeserializeOwned + Send + Sync>(
        topics: &BoundedTopics,
        node: &mut Node,
        name: &str,
        package: &str,
        ty: &str,
        qos: QosProfile,
        shared: Arc<Mutex<Shared>>,
        handle: impl Fn(&mut Shared, T) + Send + 'static,
    ) -> Result<()> {
        let topic = topics.create(name, MessageTypeName::new(package, ty), &qos)?;
        let subscription = node
            .create_subscription::<T>(&topic, None)
            .map_err(|e| anyhow!("subscription {name}: {e:?}"))?;
        let name = name.to_string();
        tokio::spawn(async move {
            let stream = subscription.async_stream();
            tokio::pin!(stream);
            while let Some(item) = stream.next().await {
                let Ok(mut s) = shared.lock() else { return };
                match item {
                    Ok((msg, _info)) => handle(&mut s, msg),
                    Err(e) => {
                        let n = s.malformed.entry(name.clone()).or_insert(0);
                        *n += 1;
                        if *n <= 5 {
                            log(&format!("{name}: malformed message ({e:?}); ignored"));
                        }
                    }
                }
            }
        });
        Ok(())
    }
    for cam in nc.cameras.clone() {
        let c = cam.clone();
        sub::<Image>(
            &bounded,
            node,
            &NodeConfig::for_camera(&nc.image_topic, &cam),
            "sensor_msgs",
            "Image",
            sensor_qos(),
            shared.clone(),
            move |s, img| match &mut s.inputs {
                Some(inputs) => {
                    if let Some(k) = inputs.camera_index(&c) {
                        let _ = inputs.offer_image(k, &img, now());
                    }
                }
                None => {
                    s.first_images.insert(c.clone(), img);
                }
            },
        )?;
        let c = cam.clone();
        sub::<CameraInfo>(
            &bounded,
            node,
            &NodeConfig::for_camera(&nc.camera_info_topic, &cam),
            "sensor_msgs",
            "CameraInfo",
            state_qos(5).reliability(Reliability::BestEffort),
            shared.clone(),
            move |s, info| {
                let k = info.k;
                if !(k[0] > 0.0 && k[4] > 0.0 && k.iter().all(|v| v.is_finite()))
                    || info.width == 0
                    || info.height == 0
                {
                    if s.bad_camera_info
                        .insert(
                            c.clone(),
                            format!(
                                "fx {} fy {} size {}x{}",
                                k[0], k[4], info.width, info.height
                            ),
                        )
                        .is_none()
                    {
                        log(&format!(
                            "camera {c}: invalid CameraInfo (fx {}, fy {}, {}x{}); ignored",
                            k[0], k[4], info.width, info.height
                        ));
                    }
                    return;
                }
                match s.infos.get(&c) {
                    None => {
                        s.infos.insert(c.clone(), info);
                    }
                    Some(old)
                        if (old.width, old.height, old.k) != (info.width, info.height, info.k)
                            && s.inputs.is_some() =>
                    {
                        if s.bad_camera_info
                            .insert(c.clone(), "changed while running".into())
                            .is_none()
                        {
                            log(&format!(
                                "camera {c}: CameraInfo changed while running; keeping the first (restart the node to use the new one)"
                            ));
                        }
                    }
                    Some(_) => {
                        if s.inputs.is_none() {
                            s.infos.insert(c.clone(), info);
                        }
                    }
                }
            },
        )?;
        let c = cam.clone();
        sub::<Image>(
            &bounded,
            node,
            &NodeConfig::for_camera(&nc.depth_topic, &cam),
            "sensor_msgs",
            "Image",
            sensor_qos(),
            shared.clone(),
            move |s, img| {
                if s.inputs.is_none() {
                    s.first_depth.insert(c.clone(), img);
                }
            },
        )?;
        let c = cam.clone();
        sub::<Image>(
            &bounded,
            node,
            &NodeConfig::for_camera(&nc.mask_topic, &cam),
            "sensor_msgs",
            "Image",
            sensor_qos(),
            shared.clone(),
            move |s, img| {
                if s.inputs.is_none() {
                    s.first_masks.insert(c.clone(), img);
                }
            },
        )?;
    }
    sub::<JointState>(
        &bounded,
        node,
        &nc.joint_states_topic,
        "sensor_msgs",
        "JointState",
        state_qos(100),
        shared.clone(),
        move |s, js| match &mut s.inputs {
            Some(inputs) => {
                let _ = inputs.offer_joint_state(&js, now());
            }
            None => s.last_joint_state = Some(js),
        },
    )?;
    let frames: BTreeMap<String, String> = nc
        .cameras
        .iter()
        .map(|c| (NodeConfig::for_camera(&nc.optical_frame, c), c.clone()))
        .collect();
    let world = nc.world_frame.clone();
    sub::<TfMessage>(
        &bounded,
        node,
        "/tf_static",
        "tf2_msgs",
        "TFMessage",
        latched_qos(),
        shared,
        move |s, tf| {
            for t in tf.transforms {
                let Some(cam) = frames.get(&t.child_frame_id) else {
                    continue;
                };
                if t.header.frame_id != world {
                    log(&format!(
                        "/tf_static {} -> {}: only transforms from '{world}' are used",
                        t.header.frame_id, t.child_frame_id
                    ));
                    continue;
                }
                let (p, q) = (t.transform.translation, t.transform.rotation);
                let values = [p.x, p.y, p.z, q.x, q.y, q.z, q.w];
                let norm = (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w).sqrt();
                if values.iter().any(|v| !v.is_finite()) || !(0.5..2.0).contains(&norm) {
                    log(&format!(
                        "/tf_static {}: not a valid transform; ignored",
                        t.child_frame_id
                    ));
                    continue;
                }
                let camera_to_world = Pose::new(
                    Vec3::new(p.x as f32, p.y as f32, p.z as f32),
                    Quat::from_xyzw(q.x as f32, q.y as f32, q.z as f32, q.w as f32).normalize(),
                );
                s.camera_poses
                    .insert(cam.clone(), camera_to_world.inverse());
            }
        },
    )?;
    Ok(())
}

/// The cameras that are ready (CameraInfo and pose), in configuration order.
fn ready_cameras(s: &Shared, nc: &NodeConfig) -> Vec<(String, Camera)> {
    nc.cameras
        .iter()
        .filter_map(|name| {
            let info = s.infos.get(name)?;
            let pose = s.camera_poses.get(name)?;
            let k = info.k;
            Some((
                name.clone(),
                Camera::from_opencv(
                    info.width,
                    info.height,
                    k[0] as f32,
                    k[4] as f32,
                    k[2] as f32,
                    k[5] as f32,
                    *pose,
                ),
            ))
        })
        .collect()
}

/// Wait for the cameras, then build the scene: a built-in scenario's world, or one initialised
/// from the first frames (as `pegs replay` does).
fn start_tracker(
    config: &Config,
    shared: &Mutex<Shared>,
    stop: &AtomicBool,
) -> Result<Option<Tracker>> {
    let nc = &config.node;
    let started = now();
    let mut told = false;
    loop {
        if stop.load(Ordering::SeqCst) {
            return Ok(None);
        }
        let (cameras, needs_images) = {
            let s = shared.lock().map_err(|_| anyhow!("state lock poisoned"))?;
            let cameras = ready_cameras(&s, nc);
            let needs_images = config.scene.scenario.is_none()
                && cameras.iter().any(|(c, _)| !s.first_images.contains_key(c));
            (cameras, needs_images)
        };
        let waited = now() - started;
        let all = cameras.len() == nc.cameras.len();
        if !cameras.is_empty() && !needs_images && (all || waited > CAMERA_WAIT_S) {
            let mut s = shared.lock().map_err(|_| anyhow!("state lock poisoned"))?;
            for name in &nc.cameras {
                if !cameras.iter().any(|(c, _)| c == name) {
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
            let scene = build_scene(config, &cameras, &s)?;
            let robot = scene.robot.as_ref().map(|(r, traj)| {
                (
                    r.model.clone(),
                    traj.at(scene.world.time)
                        .unwrap_or_else(|| vec![0.0; r.model.joints.len()]),
                )
            });
            let mut inputs = Inputs::new(cameras, robot.as_ref().map(|(m, q)| (m, q.as_slice())));
            let t = now();
            if let Some(js) = s.last_joint_state.take() {
                let _ = inputs.offer_joint_state(&js, t);
            }
            for (c, img) in std::mem::take(&mut s.first_images) {
                if let Some(k) = inputs.camera_index(&c) {
                    let _ = inputs.offer_image(k, &img, t);
                }
            }
            let mut scene = scene;
            scene.world.time = t;
            let tracker = Tracker::new(scene, config, true)?;
            log(&format!(
                "tracking {} object(s) with {} camera(s)",
                tracker.scene.world.shapes.dynamic_ids().count(),
                inputs.cameras.len()
            ));
            s.inputs = Some(inputs);
            return Ok(Some(tracker));
        }
        if !told && waited > 1.0 {
            log(&format!(
                "waiting for CameraInfo and /tf_static of {:?}",
                nc.cameras
            ));
            told = true;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn build_scene(config: &Config, cameras: &[(String, Camera)], s: &Shared) -> Result<Scene> {
    if let Some(name) = &config.scene.scenario {
        return crate::scenario::build(
            name,
            Pose::new(
                config.scene.offset_position,
                Quat::from_rotation_z(config.scene.offset_yaw),
            ),
        );
    }
    let mut images = Vec::new();
    for (name, cam) in cameras {
        let img = s
            .first_images
            .get(name)
            .with_context(|| format!("camera {name}: no first image"))?;
        images.push(
            crate::inputs::decode_image(img, cam)
                .map_err(|why| anyhow!("camera {name}: first image unusable: {why}"))?,
        );
    }
    let depth: Vec<Option<Vec<f32>>> = cameras
        .iter()
        .map(|(n, c)| {
            s.first_depth
                .get(n)
                .and_then(|i| crate::replay::decode_depth(i, c).ok())
        })
        .collect();
    let labels: Vec<Option<Vec<u8>>> = cameras
        .iter()
        .map(|(n, c)| {
            s.first_masks
                .get(n)
                .and_then(|i| crate::replay::decode_labels(i, c).ok())
        })
        .collect();
    let frames: Vec<crate::init::FirstFrames> = cameras
        .iter()
        .enumerate()
        .map(|(k, (name, cam))| crate::init::FirstFrames {
            name: name.clone(),
            camera: *cam,
            images: vec![images[k].as_slice()],
            depth: depth[k].as_deref(),
            labels: labels[k].as_deref(),
        })
        .collect();
    let joints: Vec<(String, f64)> = s
        .last_joint_state
        .as_ref()
        .map(|js| {
            js.name
                .iter()
                .cloned()
                .zip(js.position.iter().copied())
                .filter(|(_, v)| v.is_finite())
                .collect()
        })
        .unwrap_or_default();
    let (scene, _report) = crate::init::build_scene(config, &frames, &joints, false)?;
    Ok(scene)
}

/// Per-camera numbers for diagnostics.
#[derive(Default)]
struct Window {
    ticks: usize,
    tick_ms: Vec<f64>,
    loss: f64,
    force: f64,
    no_views: usize,
}

fn tick_loop(
    config: Config,
    shared: Arc<Mutex<Shared>>,
    live: Arc<Mutex<Config>>,
    tx: SyncSender<TickOutput>,
    stop: Arc<AtomicBool>,
) -> Result<RunStats> {
    let mut stats = RunStats {
        rss_mb_start: rss_mb(),
        ..Default::default()
    };
    let Some(mut tracker) = start_tracker(&config, &shared, &stop)? else {
        return Ok(stats);
    };
    let nc = config.node.clone();
    let dt = config.physics.dt as f64;
    let mut applied = config.clone();
    // The world's clock is the node's clock: tick k ends at start + k dt, whatever happened before.
    tracker.scene.world.time = now();
    let mut next = tracker.scene.world.time + dt;
    let mut window = Window::default();
    let mut last_diagnostics = now();
    let mut all_tick_ms = Vec::new();
    let started = now();
    let frame = nc.world_frame.clone();
    while !stop.load(Ordering::SeqCst) {
        let wait = next - now();
        if wait > 0.0 {
            std::thread::sleep(Duration::from_secs_f64(wait.min(0.1)));
            continue;
        }
        // A tick whose deadline passed more than a period ago is not run late: it is skipped, and
        // the world is predicted across it without correction (its images are gone).
        while now() - next > dt {
            next += dt;
            stats.skipped_ticks += 1;
        }
        let clock = Instant::now();
        let t = next;
        // Newest configuration from the parameter services.
        if let Ok(c) = live.lock()
            && *c != applied
        {
            applied = c.clone();
            if let Some(corrector) = &mut tracker.corrector {
                corrector.config = applied.correct.clone();
            }
        }
        let (tick_inputs, trajectory, lines) = {
            let Ok(mut s) = shared.lock() else {
                bail!("state lock poisoned")
            };
            let Some(inputs) = s.inputs.as_mut() else {
                bail!("inputs missing")
            };
            let tick_inputs = inputs.tick_inputs(t, applied.correct.max_image_age as f64);
            let trajectory = inputs.trajectory_for(t);
            (tick_inputs, trajectory, inputs.log.take_lines())
        };
        for line in &lines {
            log(line);
        }
        // The robot follows the newest joint states, also across skipped ticks.
        if let (Some(trajectory), Some((_, scene_trajectory))) =
            (trajectory, &mut tracker.scene.robot)
        {
            *scene_trajectory = trajectory;
        }
        let behind = ((t - dt - tracker.scene.world.time) / dt).round().max(0.0) as usize;
        if behind > MAX_CATCH_UP_TICKS {
            tracker.scene.world.time += (behind - MAX_CATCH_UP_TICKS) as f64 * dt;
        }
        for _ in 0..behind.min(MAX_CATCH_UP_TICKS) {
            tracker.scene.advance(&mut tracker.solver)?;
        }
        let views = tick_inputs.views();
        if views.is_empty() {
            window.no_views += 1;
        }
        let correction = if applied.correct.enabled {
            tracker.tick(&views)?
        } else {
            tracker.scene.advance(&mut tracker.solver)?;
            None
        };
        let header = Header {
            stamp: Time::from_seconds(t),
            frame_id: frame.clone(),
        };
        let objects = outputs::tracked_objects(&tracker.scene.world, correction.as_ref(), &header);
        let newest_image = tick_inputs.images.iter().map(|i| i.stamp).reduce(f64::max);
        let tick_ms = clock.elapsed().as_secs_f64() * 1e3;
        stats.ticks += 1;
        if tick_ms > dt * 1e3 {
            stats.overruns += 1;
        }
        window.ticks += 1;
        window.tick_ms.push(tick_ms);
        all_tick_ms.push(tick_ms);
        if let Some(c) = &correction {
            window.loss += c.loss_before as f64;
            window.force += c.force.iter().map(|f| f.length() as f64).sum::<f64>();
        }
        let debug_every = applied.node.debug_images_every as usize;
        let debug = (debug_every > 0 && stats.ticks % debug_every == 0).then(|| {
            (
                GaussianCloud::from_world(&tracker.scene.world),
                tick_inputs
                    .images
                    .iter()
                    .map(|i| (i.name.clone(), i.camera))
                    .collect(),
            )
        });
        let diagnostics = if now() - last_diagnostics >= nc.diagnostics_period as f64 {
            last_diagnostics = now();
            let d = diagnostics(&header, &shared, &tick_inputs, &window, &stats, dt);
            window = Window::default();
            d
        } else {
            None
        };
        let cloud = outputs::particle_cloud(&tracker.scene.world, &header);
        match tx.try_send(TickOutput {
            header,
            objects,
            cloud,
            newest_image,
            debug,
            diagnostics,
        }) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => stats.dropped_outputs += 1,
            Err(TrySendError::Disconnected(_)) => bail!("the publishing thread stopped"),
        }
        next += dt;
    }
    let elapsed = now() - started;
    stats.achieved_rate_hz = stats.ticks as f64 / elapsed.max(1e-9);
    all_tick_ms.sort_by(f64::total_cmp);
    stats.tick_ms_mean = all_tick_ms.iter().sum::<f64>() / all_tick_ms.len().max(1) as f64;
    stats.tick_ms_p95 = all_tick_ms
        .get(((all_tick_ms.len() as f64 * 0.95) as usize).min(all_tick_ms.len().saturating_sub(1)))
        .copied()
        .unwrap_or(f64::NAN);
    stats.rss_mb_end = rss_mb();
    if let Ok(s) = shared.lock()
        && let Some(inputs) = &s.inputs
    {
        stats.images_rejected = inputs.log.images_rejected;
        stats.joint_states_rejected = inputs.log.joint_states_rejected;
        stats.rejections = inputs
            .rejections
            .iter()
            .map(|(k, v)| (k.to_string(), *v))
            .collect();
        stats.images_accepted = inputs
            .cameras
            .iter()
            .map(|f| (f.name.clone(), f.accepted))
            .collect();
    }
    log(&format!(
        "stopped after {} ticks ({:.1} Hz, {} overruns, {} skipped)",
        stats.ticks, stats.achieved_rate_hz, stats.overruns, stats.skipped_ticks
    ));
    Ok(stats)
}

fn kv(key: &str, value: impl ToString) -> KeyValue {
    KeyValue {
        key: key.into(),
        value: value.to_string(),
    }
}

fn diagnostics(
    header: &Header,
    shared: &Mutex<Shared>,
    tick: &crate::inputs::TickInputs,
    window: &Window,
    stats: &RunStats,
    dt: f64,
) -> Option<DiagnosticArray> {
    let s = shared.lock().ok()?;
    let inputs = s.inputs.as_ref()?;
    let n = window.ticks.max(1) as f64;
    let mean_ms = window.tick_ms.iter().sum::<f64>() / n;
    let mut status = Vec::new();
    let tick_level = if mean_ms > dt * 1e3 {
        DiagnosticStatus::WARN
    } else {
        DiagnosticStatus::OK
    };
    status.push(DiagnosticStatus {
        level: tick_level,
        name: "pegs: tick".into(),
        message: if tick_level == DiagnosticStatus::OK {
            "on time".into()
        } else {
            format!("ticks take {mean_ms:.1} ms of {:.1} ms", dt * 1e3)
        },
        hardware_id: "pegs".into(),
        values: vec![
            kv("tick_ms_mean", format!("{mean_ms:.2}")),
            kv("ticks", stats.ticks),
            kv("overruns", stats.overruns),
            kv("skipped_ticks", stats.skipped_ticks),
            kv("dropped_outputs", stats.dropped_outputs),
            kv("rss_mb", format!("{:.1}", rss_mb())),
        ],
    });
    for feed in &inputs.cameras {
        let age = tick
            .ages
            .iter()
            .find(|(n, _)| *n == feed.name)
            .and_then(|(_, a)| *a);
        let stale = tick.stale.contains(&feed.name);
        let (level, message) = match age {
            None => (DiagnosticStatus::ERROR, "no image received".to_string()),
            Some(a) if stale => (
                DiagnosticStatus::ERROR,
                format!(
                    "stopped publishing: newest image is {a:.2} s old; tracking with the other cameras"
                ),
            ),
            Some(_) if feed.rejected > 0 => (
                DiagnosticStatus::WARN,
                format!("{} image(s) rejected", feed.rejected),
            ),
            Some(_) => (DiagnosticStatus::OK, "ok".into()),
        };
        status.push(DiagnosticStatus {
            level,
            name: format!("pegs: camera {}", feed.name),
            message,
            hardware_id: feed.name.clone(),
            values: vec![
                kv("age_s", age.map_or("none".into(), |a| format!("{a:.3}"))),
                kv("accepted", feed.accepted),
                kv("rejected", feed.rejected),
            ],
        });
    }
    for (name, why) in &s.unused_cameras {
        status.push(DiagnosticStatus {
            level: DiagnosticStatus::ERROR,
            name: format!("pegs: camera {name}"),
            message: format!("not used: {why} when tracking started"),
            hardware_id: name.clone(),
            values: vec![],
        });
    }
    for (name, why) in &s.bad_camera_info {
        if !inputs.cameras.iter().any(|f| &f.name == name) || why.contains("changed") {
            status.push(DiagnosticStatus {
                level: DiagnosticStatus::ERROR,
                name: format!("pegs: camera {name}"),
                message: format!("CameraInfo problem: {why}"),
                hardware_id: name.clone(),
                values: vec![],
            });
        }
    }
    let rejected: usize =
        inputs.rejections.values().sum::<usize>() + s.malformed.values().sum::<usize>();
    let mut values: Vec<KeyValue> = inputs.rejections.iter().map(|(k, v)| kv(k, v)).collect();
    values.extend(
        s.malformed
            .iter()
            .map(|(topic, v)| kv(&format!("malformed {topic}"), v)),
    );
    values.push(kv(
        "joint_states_rejected",
        inputs.log.joint_states_rejected,
    ));
    values.push(kv(
        "unknown_joints",
        inputs
            .log
            .unknown_joints
            .iter()
            .cloned()
            .collect::<Vec<_>>()
            .join(","),
    ));
    status.push(DiagnosticStatus {
        level: if rejected > 0 || !inputs.log.unknown_joints.is_empty() {
            DiagnosticStatus::WARN
        } else {
            DiagnosticStatus::OK
        },
        name: "pegs: inputs".into(),
        message: if rejected > 0 {
            format!("{rejected} message(s) rejected so far")
        } else {
            "all messages accepted".into()
        },
        hardware_id: "pegs".into(),
        values,
    });
    let health = if window.no_views as f64 >= n {
        (
            DiagnosticStatus::ERROR,
            "no usable camera: prediction only".to_string(),
        )
    } else {
        (DiagnosticStatus::OK, "tracking".to_string())
    };
    status.push(DiagnosticStatus {
        level: health.0,
        name: "pegs: tracking".into(),
        message: health.1,
        hardware_id: "pegs".into(),
        values: vec![
            kv("cameras_used", tick.images.len()),
            kv("photometric_loss", format!("{:.6}", window.loss / n)),
            kv("visual_force_n", format!("{:.4}", window.force / n)),
        ],
    });
    Some(DiagnosticArray {
        header: header.clone(),
        status,
    })
}

fn publish_loop(
    rx: std::sync::mpsc::Receiver<TickOutput>,
    publishers: Publishers,
    render: crate::render::RenderSettings,
    optical_frame: &str,
    latencies: Arc<Mutex<Vec<f64>>>,
) {
    let mut renderer = crate::render::cpu::CpuRenderer::new(render);
    let mut failures = 0usize;
    let mut fail = |what: &str, e: String| {
        failures += 1;
        if failures <= 5 {
            log(&format!("publishing {what} failed: {e}"));
        }
    };
    while let Ok(out) = rx.recv() {
        let tf = outputs::object_frames(&out.objects);
        let poses = outputs::pose_array(&out.objects);
        if let Err(e) = publishers.objects.publish(out.objects) {
            fail("objects", format!("{e:?}"));
        }
        if let Some(stamp) = out.newest_image
            && let Ok(mut l) = latencies.lock()
            && l.len() < 1_000_000
        {
            l.push(now() - stamp);
        }
        if let Err(e) = publishers.poses.publish(poses) {
            fail("poses", format!("{e:?}"));
        }
        if let Err(e) = publishers.tf.publish(tf) {
            fail("tf", format!("{e:?}"));
        }
        if let Err(e) = publishers.cloud.publish(out.cloud) {
            fail("particles", format!("{e:?}"));
        }
        if let Some(d) = out.diagnostics
            && let Err(e) = publishers.diagnostics.publish(d)
        {
            fail("diagnostics", format!("{e:?}"));
        }
        if let Some((cloud, cameras)) = out.debug {
            for (name, camera) in cameras {
                let Some((raw_pub, compressed_pub)) = publishers.debug.get(&name) else {
                    continue;
                };
                let rendered = crate::render::Renderer::forward(
                    &mut renderer,
                    &cloud,
                    &camera,
                    Roi::full(&camera),
                );
                match rendered.and_then(|r| {
                    outputs::debug_images(
                        &r.colour,
                        camera.width,
                        camera.height,
                        &Header {
                            frame_id: NodeConfig::for_camera(optical_frame, &name),
                            ..out.header.clone()
                        },
                    )
                }) {
                    Ok((raw, compressed)) => {
                        if let Err(e) = raw_pub.publish(raw) {
                            fail("debug image", format!("{e:?}"));
                        }
                        if let Err(e) = compressed_pub.publish(compressed) {
                            fail("debug image", format!("{e:?}"));
                        }
                    }
                    Err(e) => fail("debug image", format!("{e:#}")),
                }
            }
        }
    }
}

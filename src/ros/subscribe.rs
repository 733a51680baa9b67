//! Topics in: one task per subscription hands each message to the state it shares with the tick
//! thread. Before tracking starts, the newest image, depth and mask of each camera are kept for
//! initialisation, and the last seconds of joint states for it and the start-up's first tick;
//! afterwards images and joint states go to `Inputs`, which checks them. A message that cannot be decoded is counted and logged; nothing a publisher sends stops
//! a task.

use super::params::Remaps;
use super::{RosClock, log};
use crate::inputs::Inputs;
use crate::math::Pose;
use crate::msgs::{CameraInfo, Clock, Image, JointState, StringMsg, TfMessage};
use crate::record::TfTree;
use crate::topics::NodeConfig;
use anyhow::{Result, anyhow};
use futures::StreamExt;
use ros2_client::dds::rustdds::{self, TopicKind, policy::ResourceLimits};
use ros2_client::qos::{Durability, History, Reliability, WhenFull};
use ros2_client::{Context, MessageTypeName, Name, Node, NodeName, QosProfile};
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Everything the subscriptions have delivered, shared with the tick thread (held briefly).
#[derive(Default)]
pub struct Shared {
    pub infos: BTreeMap<String, CameraInfo>,
    /// Camera name -> world-to-camera pose, from the tf tree.
    pub camera_poses: BTreeMap<String, Pose>,
    /// `/tf_static` as received.
    pub tf: TfTree,
    /// Before the tracker starts: the newest image, depth and mask of each camera (for init).
    pub first_images: BTreeMap<String, Image>,
    pub first_depth: BTreeMap<String, Image>,
    pub first_masks: BTreeMap<String, Image>,
    /// Before the tracker starts: the newest joint states in order (at most
    /// `JOINT_HISTORY_LEN`); the last one stands the robot for initialisation, and those after it
    /// drive the robot across the ticks the start-up took.
    pub joint_history: std::collections::VecDeque<JointState>,
    pub inputs: Option<Inputs>,
    pub malformed: BTreeMap<String, usize>,
    pub bad_camera_info: BTreeMap<String, String>,
    /// Configured cameras left out at start, with the reason.
    pub unused_cameras: BTreeMap<String, String>,
    /// The node's clock (set by `/clock` with `use_sim_time`).
    pub clock: RosClock,
    /// The URDF received on `robot.description_topic` (the newest).
    pub robot_description: Option<String>,
    /// Where the pose search scores depth (`correct.pose_search_depth`): the depth images'
    /// unit for 16UC1 (`node.depth_unit`), and depth goes on to `Inputs` once tracking runs.
    /// None: depth is read for initialisation only.
    pub tracking_depth_unit: Option<f32>,
}

/// Joint states kept before tracking starts: 4 s of a 1 kHz driver.
pub const JOINT_HISTORY_LEN: usize = 4096;

pub fn topic_name(full: &str) -> Result<Name> {
    Name::parse(full).map_err(|e| anyhow!("bad topic name '{full}': {e:?}"))
}

pub fn sensor_qos() -> QosProfile {
    QosProfile::subscription_default()
        .reliability(Reliability::BestEffort)
        .history(History::KeepLast { depth: 2 })
}

pub fn state_qos(depth: usize) -> QosProfile {
    QosProfile::publisher_default()
        .reliability(Reliability::Reliable {
            when_full: WhenFull::Wait(Duration::from_millis(5)),
        })
        .history(History::KeepLast { depth })
}

fn latched_qos() -> QosProfile {
    state_qos(100).durability(Durability::TransientLocal)
}

impl Shared {
    /// A depth image: kept for initialisation before tracking, offered to `Inputs` after where
    /// tracking scores depth.
    fn on_depth(&mut self, camera: &str, img: Image) {
        match (&mut self.inputs, self.tracking_depth_unit) {
            (Some(inputs), Some(unit)) => {
                if let Some(k) = inputs.camera_index(camera) {
                    let now = self.clock.now().unwrap_or(f64::NAN);
                    let _ = inputs.offer_depth(k, &img, unit, now);
                }
            }
            (Some(_), None) => {}
            (None, _) => {
                self.first_depth.insert(camera.to_string(), img);
            }
        }
    }

    fn on_image(&mut self, camera: &str, img: Image) {
        match &mut self.inputs {
            Some(inputs) => {
                if let Some(k) = inputs.camera_index(camera) {
                    let now = self.clock.now().unwrap_or(f64::NAN);
                    let _ = inputs.offer_image(k, &img, now);
                }
            }
            None => {
                self.first_images.insert(camera.to_string(), img);
            }
        }
    }

    /// The first valid CameraInfo of each camera; a change once tracking runs is reported and
    /// ignored.
    fn on_camera_info(&mut self, c: &str, info: CameraInfo) {
        let k = info.k;
        if !(k[0] > 0.0 && k[4] > 0.0 && k.iter().all(|v| v.is_finite()))
            || info.width == 0
            || info.height == 0
        {
            let why = format!(
                "fx {} fy {} size {}x{}",
                k[0], k[4], info.width, info.height
            );
            if self.bad_camera_info.insert(c.to_string(), why).is_none() {
                log(&format!(
                    "camera {c}: invalid CameraInfo (fx {}, fy {}, {}x{}); ignored",
                    k[0], k[4], info.width, info.height
                ));
            }
            return;
        }
        let running = self.inputs.is_some();
        match self.infos.get(c) {
            Some(old)
                if (old.width, old.height, old.k) != (info.width, info.height, info.k)
                    && running =>
            {
                let changed = "changed while running".to_string();
                if self
                    .bad_camera_info
                    .insert(c.to_string(), changed)
                    .is_none()
                {
                    log(&format!(
                        "camera {c}: CameraInfo changed while running; keeping the first (restart the node to use the new one)"
                    ));
                }
            }
            Some(_) if running => {}
            _ => {
                self.infos.insert(c.to_string(), info);
            }
        }
    }

    fn on_joint_state(&mut self, js: JointState) {
        match &mut self.inputs {
            Some(inputs) => {
                let now = self.clock.now().unwrap_or(f64::NAN);
                let _ = inputs.offer_joint_state(&js, now);
            }
            None => {
                if self.joint_history.len() == JOINT_HISTORY_LEN {
                    self.joint_history.pop_front();
                }
                self.joint_history.push_back(js);
            }
        }
    }

    /// What initialisation reads, copied out so the world can be built while the subscriptions
    /// go on: the first frames, the newest joint state, the robot's description and the tf tree.
    pub fn first_arrivals(&self) -> Shared {
        Shared {
            first_images: self.first_images.clone(),
            first_depth: self.first_depth.clone(),
            first_masks: self.first_masks.clone(),
            joint_history: self.joint_history.back().cloned().into_iter().collect(),
            robot_description: self.robot_description.clone(),
            tf: self.tf.clone(),
            clock: self.clock.clone(),
            ..Default::default()
        }
    }

    /// `/tf_static` into the tf tree, then the camera poses it now resolves.
    fn on_tf_static(&mut self, nc: &NodeConfig, tf: TfMessage) {
        for why in self.tf.add(&tf, true) {
            log(&why);
        }
        self.resolve_camera_poses(nc);
    }

    /// Each camera's pose from the tf tree: world -> ... -> its optical frame (the template's,
    /// or its CameraInfo's frame_id when the template is empty), once both are known.
    fn resolve_camera_poses(&mut self, nc: &NodeConfig) {
        for camera in &nc.cameras {
            let header = self
                .infos
                .get(camera)
                .map_or("", |i| i.header.frame_id.as_str());
            let frame = nc.optical_frame_of(camera, header);
            if frame.is_empty() {
                continue;
            }
            if let Ok(world_from_optical) = self.tf.lookup_nearest(&nc.world_frame, &frame, 0.0) {
                self.camera_poses
                    .insert(camera.clone(), world_from_optical.inverse());
            }
        }
    }
}

/// Creates subscription topics whose receive cache holds no more samples than the history depth.
/// ros2-client's QoS profiles carry no resource limits, and without them RustDDS keeps up to 64
/// samples per topic whatever the depth: 64 images per camera, and for topics that publish
/// rarely (depth and masks, once per recording loop) a cache that fills for minutes, which is
/// the memory growth a long run showed.
struct Subscriber<'a> {
    context: &'a Context,
    node_name: &'a NodeName,
    node: &'a mut Node,
    shared: Arc<Mutex<Shared>>,
    remaps: &'a Remaps,
}

impl Subscriber<'_> {
    fn create_topic(
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

    /// Subscribe to `name` (`package/ty`) and hand every message to `handle` on the shared state.
    fn subscribe<T: 'static + serde::de::DeserializeOwned + Send + Sync>(
        &mut self,
        name: &str,
        package_ty: (&str, &str),
        qos: QosProfile,
        handle: impl Fn(&mut Shared, T) + Send + 'static,
    ) -> Result<()> {
        self.subscribe_until(name, package_ty, qos, handle, |_| false)
    }

    /// As `subscribe`, but the subscription is dropped (its DDS reader deleted, so nothing more
    /// is received or deserialised) once `done` holds on the shared state, checked every 0.5 s.
    fn subscribe_until<T: 'static + serde::de::DeserializeOwned + Send + Sync>(
        &mut self,
        name: &str,
        (package, ty): (&str, &str),
        qos: QosProfile,
        handle: impl Fn(&mut Shared, T) + Send + 'static,
        done: fn(&Shared) -> bool,
    ) -> Result<()> {
        let name = &self.remaps.apply(name);
        let topic = self.create_topic(name, MessageTypeName::new(package, ty), &qos)?;
        let subscription = self
            .node
            .create_subscription::<T>(&topic, None)
            .map_err(|e| anyhow!("subscription {name}: {e:?}"))?;
        let (name, shared) = (name.to_string(), self.shared.clone());
        tokio::spawn(async move {
            let stream = subscription.async_stream();
            tokio::pin!(stream);
            let mut check = tokio::time::interval(Duration::from_millis(500));
            loop {
                let item = tokio::select! {
                    item = stream.next() => item,
                    _ = check.tick() => {
                        if shared.lock().is_ok_and(|s| done(&s)) {
                            log(&format!("{name}: no longer needed; unsubscribed"));
                            break;
                        }
                        continue;
                    }
                };
                let Some(item) = item else { break };
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
}

const IMAGE: (&str, &str) = ("sensor_msgs", "Image");

/// One task per subscription: every camera's image, CameraInfo, depth and mask, the joint states,
/// /tf_static, /clock with `use_sim_time`, and the URDF on `robot.description_topic` until
/// tracking starts.
pub fn subscribe(
    context: &Context,
    node_name: &NodeName,
    node: &mut Node,
    nc: &NodeConfig,
    robot: &crate::robot::RobotConfig,
    shared: Arc<Mutex<Shared>>,
    remaps: &Remaps,
) -> Result<()> {
    let mut s = Subscriber {
        context,
        node_name,
        node,
        shared,
        remaps,
    };
    for cam in nc.cameras.clone() {
        let topic = |template: &str| NodeConfig::for_camera(template, &cam);
        let c = cam.clone();
        s.subscribe(
            &topic(&nc.image_topic),
            IMAGE,
            sensor_qos(),
            move |s, img| s.on_image(&c, img),
        )?;
        let c = cam.clone();
        let info_qos = state_qos(5).reliability(Reliability::BestEffort);
        let frames = nc.clone();
        s.subscribe(
            &topic(&nc.camera_info_topic),
            ("sensor_msgs", "CameraInfo"),
            info_qos,
            move |s, info| {
                s.on_camera_info(&c, info);
                s.resolve_camera_poses(&frames);
            },
        )?;
        // Masks: only the first frames, for initialisation; dropped once tracking runs. Depth
        // alike, unless tracking scores it (`Shared::on_depth`).
        let c = cam.clone();
        s.subscribe_until(
            &topic(&nc.depth_topic),
            IMAGE,
            sensor_qos(),
            move |s: &mut Shared, img| s.on_depth(&c, img),
            |s| s.inputs.is_some() && s.tracking_depth_unit.is_none(),
        )?;
        let c = cam.clone();
        s.subscribe_until(
            &topic(&nc.mask_topic),
            IMAGE,
            sensor_qos(),
            move |s: &mut Shared, img| {
                if s.inputs.is_none() {
                    s.first_masks.insert(c.clone(), img);
                }
            },
            |s| s.inputs.is_some(),
        )?;
    }
    let joint_states = ("sensor_msgs", "JointState");
    s.subscribe(
        &nc.joint_states_topic,
        joint_states,
        state_qos(100),
        Shared::on_joint_state,
    )?;
    if !robot.description_topic.is_empty() {
        // As robot_state_publisher offers it: reliable, transient local (late joiners get it).
        let qos = state_qos(1).durability(Durability::TransientLocal);
        s.subscribe_until(
            &robot.description_topic,
            ("std_msgs", "String"),
            qos,
            |s: &mut Shared, urdf: StringMsg| {
                if s.inputs.is_none() {
                    s.robot_description = Some(urdf.data);
                }
            },
            |s| s.inputs.is_some(),
        )?;
    }
    if nc.use_sim_time {
        // As rclcpp's clock subscription: best effort, the newest message only.
        let qos = sensor_qos().history(History::KeepLast { depth: 1 });
        s.subscribe("/clock", ("rosgraph_msgs", "Clock"), qos, |s, c: Clock| {
            s.clock.set(c.clock.seconds())
        })?;
    }
    let frames = nc.clone();
    s.subscribe(
        "/tf_static",
        ("tf2_msgs", "TFMessage"),
        latched_qos(),
        move |s, tf| s.on_tf_static(&frames, tf),
    )
}

//! `/diagnostics` from the tick thread, once per `node.diagnostics_period`: the tick's timing,
//! every camera's state (ERROR when it never sent an image, stopped, or was left out at start),
//! the inputs refused so far, and whether tracking sees anything.

use super::node::RunStats;
use super::rss_mb;
use super::subscribe::Shared;
use crate::inputs::TickInputs;
use crate::msgs::{DiagnosticArray, DiagnosticStatus, Header, KeyValue};
use crate::topics::NodeConfig;
use std::collections::BTreeMap;

/// A camera whose newest image is this much older than `correct.max_image_age` has stopped
/// (ERROR); below it, its images only arrive too late to be used (WARN).
pub const STOPPED_AFTER_S: f64 = 0.5;

/// What the ticks since the last diagnostics measured.
#[derive(Default)]
pub struct Window {
    pub ticks: usize,
    pub tick_ms: Vec<f64>,
    pub loss: f64,
    pub force: f64,
    pub no_views: usize,
    /// The visual-force gain the last tick corrected with.
    pub gain: f32,
    /// `correct.max_image_age` at the last tick, s.
    pub max_age: f64,
    /// Per camera: the ages (s) of the images the ticks used, and the ticks whose newest image
    /// was too old to use.
    pub ages_used: BTreeMap<String, Vec<f64>>,
    pub late: BTreeMap<String, usize>,
}

impl Window {
    /// Count one tick's images: the age of each one used, and the cameras skipped as too old.
    pub fn count_images(&mut self, tick: &TickInputs) {
        for image in &tick.images {
            let age = tick.time - image.stamp;
            self.ages_used
                .entry(image.name.clone())
                .or_default()
                .push(age);
        }
        for name in &tick.stale {
            *self.late.entry(name.clone()).or_insert(0) += 1;
        }
    }
}

fn kv(key: &str, value: impl ToString) -> KeyValue {
    KeyValue {
        key: key.into(),
        value: value.to_string(),
    }
}

fn status(
    level: u8,
    name: String,
    message: String,
    hardware_id: &str,
    values: Vec<KeyValue>,
) -> DiagnosticStatus {
    DiagnosticStatus {
        level,
        name,
        message,
        hardware_id: hardware_id.into(),
        values,
    }
}

/// The diagnostics after the tick whose inputs were `tick` (None before tracking starts).
pub fn diagnostics(
    header: &Header,
    s: &Shared,
    tick: &TickInputs,
    window: &Window,
    stats: &RunStats,
    dt: f64,
    objects: &[ObjectHealth],
) -> Option<DiagnosticArray> {
    s.inputs.as_ref()?;
    let mut all = vec![tick_status(window, stats, dt)];
    all.extend(camera_statuses(s, tick, window));
    all.push(inputs_status(s));
    // Skipped ticks are tracked time too: a node slower than its rate still reaches the deadline.
    let tracked_s = (stats.ticks + stats.skipped_ticks) as f64 * dt;
    all.extend(robot_status(s, tracked_s));
    all.push(tracking_status(tick, window));
    all.extend(objects.iter().map(object_status));
    Some(DiagnosticArray {
        header: header.clone(),
        status: all,
    })
}

/// Before tracking starts: what each configured camera still lacks (CameraInfo, the tf chain to
/// its optical frame, a first image when the scene is built from them), as a WARN status.
pub fn waiting_diagnostics(
    header: &Header,
    s: &Shared,
    nc: &NodeConfig,
    needs_images: bool,
    robot: &[String],
    waited: f64,
) -> DiagnosticArray {
    let mut missing = Vec::new();
    for camera in &nc.cameras {
        let info = s.infos.get(camera);
        if info.is_none() {
            missing.push(format!("{camera} CameraInfo"));
        } else if !s.camera_poses.contains_key(camera) {
            let header_frame = info.map_or("", |i| i.header.frame_id.as_str());
            let frame = nc.optical_frame_of(camera, header_frame);
            missing.push(format!("{camera} tf {} -> {frame}", nc.world_frame));
        }
        if needs_images && !s.first_images.contains_key(camera) {
            missing.push(format!("{camera} first image"));
        }
    }
    missing.extend(robot.iter().cloned());
    if s.clock.now().is_none() {
        missing.push("/clock (use_sim_time)".into());
    }
    let message = if missing.is_empty() {
        "starting".to_string()
    } else {
        format!("waiting for: {}", missing.join(", "))
    };
    let values = vec![
        kv("waited_s", format!("{waited:.1}")),
        kv("camera_wait_s", nc.camera_wait),
    ];
    DiagnosticArray {
        header: header.clone(),
        status: vec![status(
            DiagnosticStatus::WARN,
            "pegs: start-up".into(),
            message,
            "pegs",
            values,
        )],
    }
}

fn tick_status(window: &Window, stats: &RunStats, dt: f64) -> DiagnosticStatus {
    let mean_ms = window.tick_ms.iter().sum::<f64>() / window.ticks.max(1) as f64;
    let on_time = mean_ms <= dt * 1e3;
    let (level, message) = match on_time {
        true => (DiagnosticStatus::OK, "on time".into()),
        false => (
            DiagnosticStatus::WARN,
            format!("ticks take {mean_ms:.1} ms of {:.1} ms", dt * 1e3),
        ),
    };
    let values = vec![
        kv("tick_ms_mean", format!("{mean_ms:.2}")),
        kv("ticks", stats.ticks),
        kv("overruns", stats.overruns),
        kv("skipped_ticks", stats.skipped_ticks),
        kv("jumped_s", format!("{:.2}", stats.jumped_s)),
        kv("dropped_outputs", stats.dropped_outputs),
        kv("rss_mb", format!("{:.1}", rss_mb())),
    ];
    status(level, "pegs: tick".into(), message, "pegs", values)
}

fn camera_statuses(s: &Shared, tick: &TickInputs, window: &Window) -> Vec<DiagnosticStatus> {
    let Some(inputs) = &s.inputs else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for feed in &inputs.cameras {
        let age = tick
            .ages
            .iter()
            .find(|(n, _)| *n == feed.name)
            .and_then(|(_, a)| *a);
        let stale = tick.stale.contains(&feed.name);
        let used = window
            .ages_used
            .get(&feed.name)
            .map_or(&[][..], Vec::as_slice);
        let late = window.late.get(&feed.name).copied().unwrap_or(0);
        let (level, message) = match age {
            None => (DiagnosticStatus::ERROR, "no image received".to_string()),
            Some(a) if stale && a > window.max_age + STOPPED_AFTER_S => (
                DiagnosticStatus::ERROR,
                format!(
                    "stopped publishing: newest image is {a:.2} s old; tracking with the other cameras"
                ),
            ),
            Some(a) if stale || late * 2 > window.ticks => (
                DiagnosticStatus::WARN,
                format!(
                    "images too late: {late} of {} ticks had none newer than \
                     correct.max_image_age ({:.0} ms; newest now {:.0} ms old); those ticks skip it",
                    window.ticks,
                    window.max_age * 1e3,
                    a * 1e3
                ),
            ),
            Some(_) if feed.rejected > 0 => (
                DiagnosticStatus::WARN,
                format!("{} image(s) rejected", feed.rejected),
            ),
            Some(_) => (DiagnosticStatus::OK, "ok".into()),
        };
        let mean_used = used.iter().sum::<f64>() / used.len().max(1) as f64;
        // Ages below zero are images stamped ahead of the tick (within `max_image_age`, used too).
        let max_used = used.iter().copied().reduce(f64::max).unwrap_or(0.0);
        let values = vec![
            kv("age_s", age.map_or("none".into(), |a| format!("{a:.3}"))),
            kv("age_used_ms_mean", format!("{:.1}", mean_used * 1e3)),
            kv("age_used_ms_max", format!("{:.1}", max_used * 1e3)),
            kv("ticks_used", used.len()),
            kv("ticks_too_late", late),
            kv("accepted", feed.accepted),
            kv("rejected", feed.rejected),
        ];
        out.push(status(
            level,
            format!("pegs: camera {}", feed.name),
            message,
            &feed.name,
            values,
        ));
    }
    let error = |name: &String, message: String| {
        status(
            DiagnosticStatus::ERROR,
            format!("pegs: camera {name}"),
            message,
            name,
            vec![],
        )
    };
    for (name, why) in &s.unused_cameras {
        out.push(error(
            name,
            format!("not used: {why} when tracking started"),
        ));
    }
    for (name, why) in &s.bad_camera_info {
        if !inputs.cameras.iter().any(|f| &f.name == name) || why.contains("changed") {
            out.push(error(name, format!("CameraInfo problem: {why}")));
        }
    }
    out
}

fn inputs_status(s: &Shared) -> DiagnosticStatus {
    let Some(inputs) = &s.inputs else {
        return status(
            DiagnosticStatus::OK,
            "pegs: inputs".into(),
            String::new(),
            "pegs",
            vec![],
        );
    };
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
    let unknown: Vec<String> = inputs.log.unknown_joints.iter().cloned().collect();
    values.push(kv("unknown_joints", unknown.join(",")));
    // The cameras whose depth reaches tracking (`correct.pose_search_depth`).
    let depth: Vec<&str> = (inputs.cameras.iter())
        .filter(|c| c.depth.is_some())
        .map(|c| c.name.as_str())
        .collect();
    values.push(kv("depth_cameras", depth.join(",")));
    let level = match rejected > 0 || !unknown.is_empty() {
        true => DiagnosticStatus::WARN,
        false => DiagnosticStatus::OK,
    };
    let message = match rejected {
        0 => "all messages accepted".into(),
        n => format!("{n} message(s) rejected so far"),
    };
    status(level, "pegs: inputs".into(), message, "pegs", values)
}

/// A tracked object's state for `/diagnostics`: its name, whether it is lost, its newest
/// silhouette agreement and how many times it was relocated (`tracker::health`), and whether it
/// stands off the modelled table (`tracker::TableEdge`).
pub struct ObjectHealth {
    pub name: String,
    pub lost: bool,
    pub agreement: Option<f32>,
    pub relocations: usize,
    pub off_table: bool,
}

fn object_status(o: &ObjectHealth) -> DiagnosticStatus {
    let agreement = o.agreement.map_or("none".into(), |a| format!("{a:.2}"));
    let (level, message) = match o.lost {
        true => (
            DiagnosticStatus::ERROR,
            format!(
                "lost: its silhouette no longer agrees with the images (agreement {agreement}); \
                 the model holds it where the images do not show it"
            ),
        ),
        false if o.off_table => (
            DiagnosticStatus::WARN,
            format!(
                "off the modelled table: {}",
                crate::tracker::OFF_TABLE_ADVICE
            ),
        ),
        false => (DiagnosticStatus::OK, "tracked".to_string()),
    };
    let values = vec![
        kv("silhouette_agreement", agreement),
        kv("relocations", o.relocations.to_string()),
        kv("off_table", o.off_table),
    ];
    status(
        level,
        format!("pegs: object {}", o.name),
        message,
        &o.name,
        values,
    )
}

/// Seconds of tracking after which a robot none of whose joints was named is an ERROR.
pub const JOINTS_DEADLINE_S: f64 = 2.0;

/// The robot's joint states: matched, or an ERROR once `JOINTS_DEADLINE_S` of tracking passed
/// without a single joint of the URDF named (the arm would stay where it started, colliding).
fn robot_status(s: &Shared, tracked_s: f64) -> Option<DiagnosticStatus> {
    let inputs = s.inputs.as_ref()?;
    if !inputs.has_robot() {
        return None;
    }
    let unknown: Vec<&str> = inputs
        .log
        .unknown_joints
        .iter()
        .map(String::as_str)
        .collect();
    let (level, message) = if inputs.joints_matched {
        (
            DiagnosticStatus::OK,
            "joint states drive the robot".to_string(),
        )
    } else if tracked_s > JOINTS_DEADLINE_S {
        let seen = if unknown.is_empty() {
            "no joint states received".to_string()
        } else {
            format!("received only {}", unknown.join(", "))
        };
        (
            DiagnosticStatus::ERROR,
            format!(
                "no joint of the URDF named after {tracked_s:.0} s ({seen}); the arm stays where it \
                 started. Set robot.joint_prefix_received and robot.joint_prefix_urdf (e.g. fr3_ \
                 and panda_) or node.joint_states_topic"
            ),
        )
    } else {
        (DiagnosticStatus::OK, "waiting for joint states".to_string())
    };
    Some(status(level, "pegs: robot".into(), message, "pegs", vec![]))
}

fn tracking_status(tick: &TickInputs, window: &Window) -> DiagnosticStatus {
    let n = window.ticks.max(1) as f64;
    let (level, message) = if window.no_views as f64 >= n {
        (
            DiagnosticStatus::ERROR,
            "no usable camera: prediction only".to_string(),
        )
    } else {
        (DiagnosticStatus::OK, "tracking".to_string())
    };
    let values = vec![
        kv("cameras_used", tick.images.len()),
        kv("photometric_loss", format!("{:.6}", window.loss / n)),
        kv("visual_force_n", format!("{:.4}", window.force / n)),
        kv("gain", window.gain),
    ];
    status(level, "pegs: tracking".into(), message, "pegs", values)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn object(lost: bool, off_table: bool) -> DiagnosticStatus {
        object_status(&ObjectHealth {
            name: "box".into(),
            lost,
            agreement: Some(0.9),
            relocations: 0,
            off_table,
        })
    }

    fn value(s: &DiagnosticStatus, key: &str) -> String {
        let kv = s.values.iter().find(|kv| kv.key == key);
        kv.map(|kv| kv.value.clone()).unwrap_or_default()
    }

    #[test]
    fn an_object_off_the_modelled_table_is_a_warning_and_a_lost_one_an_error() {
        let tracked = object(false, false);
        assert_eq!(tracked.level, DiagnosticStatus::OK);
        assert_eq!(value(&tracked, "off_table"), "false");
        let off = object(false, true);
        assert_eq!(off.level, DiagnosticStatus::WARN);
        assert!(off.message.contains("widen scene.table"), "{}", off.message);
        assert_eq!(value(&off, "off_table"), "true");
        assert_eq!(object(true, true).level, DiagnosticStatus::ERROR);
    }
}

//! What a tick consumes, gathered from the outside world: the newest usable image of every camera
//! (with its aligned depth where one of the same stamp came), and the robot's joint trajectory.
//! Both `pegs replay` and `pegs node` feed observations through here, so the checks on everything
//! that comes from outside (encodings, sizes, stamps, non-finite joints, unknown joints) and the
//! choice of data for a tick are one code path.
//!
//! This module owns validation and buffering only; it never touches the world or the tracker.

use crate::correct::View;
use crate::msgs::{CompressedImage, Image, JointState};
use crate::render::Camera;
use crate::robot::{JointStateTracker, JointTrajectory, RobotModel};
use glam::Vec3;
use std::collections::BTreeSet;
use std::fmt;
use std::sync::Arc;

/// Stamps this far ahead of the clock are refused (clock skew or a corrupt header).
pub const MAX_FUTURE_S: f64 = 1.0;
/// Stamps this far behind a stream's newest one are a jump back (a looped recording, a restarted
/// driver) rather than reordering...
pub const JUMP_BACK_S: f64 = 1.0;
/// ...and after this many consecutive jumped-back messages the stream restarts from them.
pub const RESTART_AFTER: usize = 3;
/// How far past its last sample the joint trajectory is extended (linearly) to cover a tick.
pub const MAX_JOINT_EXTRAPOLATION_S: f64 = 0.05;
/// A depth image goes with a colour image stamped within this (s) of it: a camera whose colour
/// and aligned depth are one frame carries one stamp on both (realsense2_camera with
/// `enable_sync`); unsynchronised, they are up to half a frame apart at 30 Hz. At a push's 0.2
/// m/s, 20 ms is 4 mm.
pub const DEPTH_SKEW_S: f64 = 0.02;
/// After this many ticks in a row with depth received but none within `DEPTH_SKEW_S` of the
/// colour, that is said once per camera.
const DEPTH_UNPAIRED_SAY: usize = 30;

/// Why an observation was refused. Every refusal is counted and explained; none changes state.
#[derive(Clone, Debug, PartialEq)]
pub enum Rejection {
    /// Encoding, size or data length disagree with the camera (the text says which).
    BadImage(String),
    /// Not later than the newest message of its stream (duplicate or reordered).
    OutOfOrder { stamp: f64, newest: f64 },
    /// More than `JUMP_BACK_S` behind the newest message of its stream (a looped recording, a
    /// restarted driver); the stream restarts if the next messages jump back too.
    JumpedBack { stamp: f64, newest: f64 },
    /// Stamped ahead of the clock.
    Future { stamp: f64, now: f64 },
    /// Names and positions of a joint state differ in length, or a stamp is not finite.
    Malformed(String),
    /// Every named joint value was NaN or infinite (the finite ones of a message are still used).
    NonFinite(Vec<String>),
}

impl fmt::Display for Rejection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::BadImage(why) => write!(f, "{why}"),
            Self::OutOfOrder { stamp, newest } => write!(
                f,
                "stamp {stamp:.3} s is not after the newest {newest:.3} s (duplicate or out of order)"
            ),
            Self::JumpedBack { stamp, newest } => write!(
                f,
                "stamp {stamp:.3} s is {:.3} s behind the newest {newest:.3} s (jumped back; the stream restarts if the next ones do too)",
                newest - stamp
            ),
            Self::Future { stamp, now } => write!(
                f,
                "stamp {stamp:.3} s is {:.3} s in the future",
                stamp - now
            ),
            Self::Malformed(why) => write!(f, "malformed: {why}"),
            Self::NonFinite(names) => write!(f, "non-finite values for {}", names.join(", ")),
        }
    }
}

impl Rejection {
    /// A short key for counting rejections by kind in diagnostics.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::BadImage(_) => "bad_image",
            Self::OutOfOrder { .. } => "out_of_order",
            Self::JumpedBack { .. } => "jumped_back",
            Self::Future { .. } => "future_stamp",
            Self::Malformed(_) => "malformed",
            Self::NonFinite(_) => "non_finite",
        }
    }
}

/// Stamp ordering of one stream: accepts increasing stamps, refuses reordering, and restarts when
/// the stamps have jumped back for good.
#[derive(Clone, Debug, Default)]
struct StampOrder {
    newest: Option<f64>,
    jumped_back: usize,
}

/// What the stamp of a new message means for its stream.
#[derive(Debug, PartialEq)]
enum Order {
    Next,
    /// Stamps jumped back for good: forget the stream's history and start again from this one.
    Restart {
        back_s: f64,
    },
}

impl StampOrder {
    fn check(&mut self, stamp: f64, now: f64) -> Result<Order, Rejection> {
        if !stamp.is_finite() {
            return Err(Rejection::Malformed(format!("stamp {stamp}")));
        }
        if stamp > now + MAX_FUTURE_S {
            return Err(Rejection::Future { stamp, now });
        }
        match self.newest {
            Some(newest) if stamp <= newest => {
                if newest - stamp > JUMP_BACK_S {
                    self.jumped_back += 1;
                    if self.jumped_back >= RESTART_AFTER {
                        self.jumped_back = 0;
                        self.newest = Some(stamp);
                        return Ok(Order::Restart {
                            back_s: newest - stamp,
                        });
                    }
                    return Err(Rejection::JumpedBack { stamp, newest });
                }
                Err(Rejection::OutOfOrder { stamp, newest })
            }
            _ => {
                self.jumped_back = 0;
                self.newest = Some(stamp);
                Ok(Order::Next)
            }
        }
    }
}

/// One camera's stream: its model and its newest decoded image.
#[derive(Clone, Debug)]
pub struct CameraFeed {
    pub name: String,
    pub camera: Camera,
    /// Stamp and linear-RGB pixels of the newest accepted image.
    pub latest: Option<(f64, Arc<Vec<Vec3>>)>,
    order: StampOrder,
    pub accepted: usize,
    pub rejected: usize,
    /// Stamp and metres (0: unknown) of the newest accepted depth image aligned to the colour.
    pub depth: Option<(f64, Arc<Vec<f32>>)>,
    depth_order: StampOrder,
    /// Ticks in a row whose colour image had no depth within `DEPTH_SKEW_S` though depth came.
    depth_unpaired: usize,
}

impl CameraFeed {
    fn new(name: String, camera: Camera) -> Self {
        Self {
            name,
            camera,
            latest: None,
            order: StampOrder::default(),
            accepted: 0,
            rejected: 0,
            depth: None,
            depth_order: StampOrder::default(),
            depth_unpaired: 0,
        }
    }
}

/// Counts of everything refused, by source and kind, plus lines worth logging once.
#[derive(Clone, Debug, Default)]
pub struct InputLog {
    pub images_rejected: usize,
    pub joint_states_rejected: usize,
    pub unknown_joints: BTreeSet<String>,
    /// Explanations not yet handed to a logger (drained by `take_lines`).
    lines: Vec<String>,
}

impl InputLog {
    /// Refuse an image for a reason found outside `Inputs` (undecodable compression, no pose
    /// for a moving camera): counted and explained like the others.
    pub fn refuse_image(&mut self, why: String) {
        self.images_rejected += 1;
        self.lines.push(why);
    }

    /// An explanation that refuses nothing.
    pub fn say(&mut self, line: String) {
        self.lines.push(line);
    }
}

impl InputLog {
    pub fn take_lines(&mut self) -> Vec<String> {
        std::mem::take(&mut self.lines)
    }
}

/// The data a tick uses from one camera.
#[derive(Clone, Debug)]
pub struct TickImage {
    /// The camera's index in `Inputs::cameras`.
    pub index: usize,
    pub name: String,
    pub stamp: f64,
    pub camera: Camera,
    pub pixels: Arc<Vec<Vec3>>,
    /// The camera's depth aligned to `pixels` (m, 0 unknown), where one is stamped within
    /// `DEPTH_SKEW_S` of them.
    pub depth: Option<Arc<Vec<f32>>>,
}

/// What one tick consumes: the time it ends at, the usable images, every camera's image age
/// (None: never received an image), and the robot's joint trajectory.
#[derive(Clone, Debug, Default)]
pub struct TickInputs {
    /// When the tick ends, s.
    pub time: f64,
    pub images: Vec<TickImage>,
    pub ages: Vec<(String, Option<f64>)>,
    /// Cameras whose newest image is older than the limit.
    pub stale: Vec<String>,
    /// The joint trajectory that drives the robot through the tick (recent samples, extended a
    /// little past the last one); None without a robot or before the first joint state.
    pub trajectory: Option<JointTrajectory>,
    /// Joint-state samples accepted since the previous tick: `(stamp, positions)`, in order.
    pub joint_samples: Vec<(f64, Vec<f64>)>,
}

impl TickInputs {
    /// A tick at `time` with images taken by `cameras` at that time and no joint states
    /// (synthetic scenes, tests, benchmarks).
    pub fn with_images(time: f64, cameras: &[Camera], images: Vec<Vec<Vec3>>) -> Self {
        let images = cameras
            .iter()
            .zip(images)
            .enumerate()
            .map(|(index, (camera, pixels))| TickImage {
                index,
                name: format!("camera{index}"),
                stamp: time,
                camera: *camera,
                pixels: Arc::new(pixels),
                depth: None,
            })
            .collect();
        Self {
            time,
            images,
            ..Default::default()
        }
    }

    pub fn views(&self) -> Vec<View<'_>> {
        self.images
            .iter()
            .map(|i| View {
                camera: i.camera,
                image: &i.pixels,
                depth: i.depth.as_deref().map(|d| &d[..]),
            })
            .collect()
    }
}

/// The robot's joint states: names resolved against the model, kept as a trajectory.
#[derive(Clone, Debug)]
struct Joints {
    tracker: JointStateTracker,
    trajectory: JointTrajectory,
    /// Samples accepted since the last `tick_inputs`.
    fresh: Vec<(f64, Vec<f64>)>,
    order: StampOrder,
}

#[derive(Clone, Debug)]
pub struct Inputs {
    pub cameras: Vec<CameraFeed>,
    joints: Option<Joints>,
    /// Joint-name prefix as received and as the URDF has it (`rename_joints`).
    joint_prefix: Option<(String, String)>,
    /// Whether any joint state has named a joint of the robot.
    pub joints_matched: bool,
    pub log: InputLog,
    /// Rejections so far, by kind (for diagnostics).
    pub rejections: std::collections::BTreeMap<&'static str, usize>,
}

impl Inputs {
    /// `robot`: the model whose joints the joint states name, with the joint positions to start
    /// from; None when the scene has no robot (joint states are then ignored).
    pub fn new(cameras: Vec<(String, Camera)>, robot: Option<(&RobotModel, &[f64])>) -> Self {
        let cameras = cameras
            .into_iter()
            .map(|(name, camera)| CameraFeed::new(name, camera))
            .collect();
        let joints = robot.map(|(model, q)| {
            let mut tracker = JointStateTracker::new(model);
            if q.len() == tracker.positions.len() {
                tracker.positions.copy_from_slice(q);
            }
            Joints {
                tracker,
                trajectory: JointTrajectory::default(),
                fresh: Vec::new(),
                order: StampOrder::default(),
            }
        });
        Self {
            cameras,
            joints,
            joint_prefix: None,
            joints_matched: false,
            log: InputLog::default(),
            rejections: Default::default(),
        }
    }

    /// Whether the scene has a robot whose joints the joint states drive.
    pub fn has_robot(&self) -> bool {
        self.joints.is_some()
    }

    /// Joint names that start with `received` are renamed to start with `urdf` instead (a
    /// driver's naming against the URDF's: `fr3_` against `panda_`). Empty `received`: no change.
    pub fn rename_joints(&mut self, received: &str, urdf: &str) {
        self.joint_prefix =
            (!received.is_empty()).then(|| (received.to_string(), urdf.to_string()));
    }

    /// A camera that became ready after the others (its index), fed from its next image on.
    pub fn add_camera(&mut self, name: String, camera: Camera) -> usize {
        if let Some(k) = self.camera_index(&name) {
            return k;
        }
        self.cameras.push(CameraFeed::new(name, camera));
        self.cameras.len() - 1
    }

    pub fn camera_index(&self, name: &str) -> Option<usize> {
        self.cameras.iter().position(|c| c.name == name)
    }

    fn refuse(&mut self, what: String, why: Rejection) -> Rejection {
        *self.rejections.entry(why.kind()).or_insert(0) += 1;
        // The first few of each kind are explained; the counts carry the rest.
        if self.rejections[why.kind()] <= 5 {
            self.log.lines.push(format!("{what}: {why}; ignored"));
        }
        why
    }

    /// Offer camera `c`'s image, received when the clock read `now` (s). Decoded and kept as the
    /// camera's newest image, or refused with the reason.
    pub fn offer_image(&mut self, c: usize, image: &Image, now: f64) -> Result<(), Rejection> {
        let stamp = image.header.stamp.seconds();
        let feed = &mut self.cameras[c];
        let name = feed.name.clone();
        let checked = decode_image(image, &feed.camera)
            .map_err(Rejection::BadImage)
            .and_then(|pixels| feed.order.check(stamp, now).map(|o| (o, pixels)));
        match checked {
            Ok((order, pixels)) => {
                if let Order::Restart { back_s } = order {
                    self.log.lines.push(format!("camera {name}: stamps jumped back {back_s:.2} s (recording looped or driver restarted); following the new stamps"));
                }
                let feed = &mut self.cameras[c];
                feed.latest = Some((stamp, Arc::new(pixels)));
                feed.accepted += 1;
                Ok(())
            }
            Err(why) => {
                self.cameras[c].rejected += 1;
                self.log.images_rejected += 1;
                Err(self.refuse(format!("camera {name} image at {stamp:.3} s"), why))
            }
        }
    }

    /// Offer camera `c`'s depth image aligned to its colour (32FC1 m, or 16UC1 in `unit` m),
    /// received when the clock read `now`: kept as the camera's newest depth, or refused with the
    /// reason (counted with the images).
    pub fn offer_depth(
        &mut self,
        c: usize,
        image: &Image,
        unit: f32,
        now: f64,
    ) -> Result<(), Rejection> {
        let stamp = image.header.stamp.seconds();
        let feed = &mut self.cameras[c];
        let name = feed.name.clone();
        let checked = decode_depth(image, &feed.camera, unit)
            .map_err(Rejection::BadImage)
            .and_then(|metres| feed.depth_order.check(stamp, now).map(|_| metres));
        match checked {
            Ok(metres) => {
                self.cameras[c].depth = Some((stamp, Arc::new(metres)));
                Ok(())
            }
            Err(why) => {
                self.log.images_rejected += 1;
                Err(self.refuse(format!("camera {name} depth at {stamp:.3} s"), why))
            }
        }
    }

    /// Offer a joint state received when the clock read `now`. Finite values of known joints are
    /// used; unknown joint names are reported once and skipped.
    pub fn offer_joint_state(&mut self, js: &JointState, now: f64) -> Result<(), Rejection> {
        let renamed;
        let js = match &self.joint_prefix {
            Some((received, urdf)) => {
                let mut copy = js.clone();
                for name in &mut copy.name {
                    *name = crate::robot::joint_name_for_urdf(name, received, urdf);
                }
                renamed = copy;
                &renamed
            }
            None => js,
        };
        let stamp = js.header.stamp.seconds();
        let Some(joints) = &mut self.joints else {
            return Ok(());
        };
        let what = format!("joint state at {stamp:.3} s");
        if js.name.len() != js.position.len() {
            self.log.joint_states_rejected += 1;
            return Err(self.refuse(
                what,
                Rejection::Malformed(format!(
                    "{} names but {} positions",
                    js.name.len(),
                    js.position.len()
                )),
            ));
        }
        // Decide on the whole message before changing anything.
        let known_finite = js
            .name
            .iter()
            .zip(&js.position)
            .filter(|(n, v)| v.is_finite() && joints.tracker.knows(n))
            .count();
        let non_finite: Vec<String> = js
            .name
            .iter()
            .zip(&js.position)
            .filter(|(n, v)| !v.is_finite() && joints.tracker.knows(n))
            .map(|(n, _)| n.clone())
            .collect();
        self.joints_matched |= known_finite > 0;
        if known_finite == 0 && !non_finite.is_empty() {
            self.log.joint_states_rejected += 1;
            return Err(self.refuse(what, Rejection::NonFinite(non_finite)));
        }
        let order = match joints.order.check(stamp, now) {
            Ok(o) => o,
            Err(why) => {
                self.log.joint_states_rejected += 1;
                return Err(self.refuse(what, why));
            }
        };
        if let Order::Restart { back_s } = order {
            joints.trajectory = JointTrajectory::default();
            self.log.lines.push(format!("joint states jumped back {back_s:.2} s (recording looped or driver restarted); trajectory restarted"));
        }
        let report = joints.tracker.update(&js.name, &js.position);
        for name in report.new_unknown {
            self.log.lines.push(format!(
                "joint state names unknown joint '{name}'; that value is ignored"
            ));
            self.log.unknown_joints.insert(name);
        }
        if joints
            .trajectory
            .push(stamp, joints.tracker.positions.clone())
        {
            joints.fresh.push((stamp, joints.tracker.positions.clone()));
        }
        if !report.rejected_non_finite.is_empty() {
            let why = Rejection::NonFinite(report.rejected_non_finite);
            self.refuse(format!("{what} (other joints used)"), why);
        }
        Ok(())
    }

    /// The robot trajectory to drive the tick ending at `t`: recent samples, extended linearly a
    /// little past the last one so a tick is not driven by a stale hold. None without a robot or
    /// before the first joint state.
    fn trajectory_for(&mut self, from: f64, t: f64) -> Option<JointTrajectory> {
        let joints = self.joints.as_mut()?;
        if joints.trajectory.is_empty() {
            return None;
        }
        // Two ticks of history are enough to interpolate one tick; a second is kept, and back to
        // `from` where the world's clock stands further behind (a tick that catches up).
        joints.trajectory.forget_before(from.min(t - 1.0));
        Some(joints.trajectory.extended(t, MAX_JOINT_EXTRAPOLATION_S))
    }

    /// What the tick ending at `t` consumes: every camera's newest image no older than `max_age`,
    /// the joint trajectory, and the joint samples accepted since the last call.
    pub fn tick_inputs(&mut self, t: f64, max_age: f64) -> TickInputs {
        self.tick_inputs_from(t - 1.0, t, max_age)
    }

    /// As `tick_inputs`, with the joint trajectory reaching back to `from` (the world's clock
    /// before the tick) however far that is: a tick that predicts across a slow start.
    pub fn tick_inputs_from(&mut self, from: f64, t: f64, max_age: f64) -> TickInputs {
        let mut out = TickInputs {
            time: t,
            trajectory: self.trajectory_for(from, t),
            joint_samples: self
                .joints
                .as_mut()
                .map(|j| std::mem::take(&mut j.fresh))
                .unwrap_or_default(),
            ..Default::default()
        };
        for (index, feed) in self.cameras.iter_mut().enumerate() {
            let age = feed.latest.as_ref().map(|(stamp, _)| t - stamp);
            out.ages.push((feed.name.clone(), age));
            match (&feed.latest, age) {
                // Stamped after the tick (it ran late, or the clock went back): usable within the
                // same margin.
                (Some((stamp, pixels)), Some(a)) if a.abs() <= max_age => {
                    let depth = (feed.depth.as_ref())
                        .filter(|(d, _)| (d - stamp).abs() <= DEPTH_SKEW_S)
                        .map(|(_, metres)| metres.clone());
                    match (&feed.depth, &depth) {
                        (Some((d, _)), None) => {
                            feed.depth_unpaired += 1;
                            if feed.depth_unpaired == DEPTH_UNPAIRED_SAY {
                                self.log.lines.push(format!(
                                    "camera {}: depth stamped {:.3} s from the colour for {} \
                                     ticks (pairs within {DEPTH_SKEW_S} s); the pose search \
                                     uses the colour alone there. Publish aligned depth with \
                                     the colour's stamp (realsense2_camera: enable_sync), or set \
                                     correct.pose_search_depth: 0",
                                    feed.name,
                                    d - stamp,
                                    DEPTH_UNPAIRED_SAY
                                ));
                            }
                        }
                        _ => feed.depth_unpaired = 0,
                    }
                    out.images.push(TickImage {
                        index,
                        name: feed.name.clone(),
                        stamp: *stamp,
                        camera: feed.camera,
                        pixels: pixels.clone(),
                        depth,
                    })
                }
                (Some(_), _) => out.stale.push(feed.name.clone()),
                (None, _) => {}
            }
        }
        out
    }
}

/// An rgb8 image from a `sensor_msgs/CompressedImage` in JPEG or PNG (image_transport's
/// `compressed` format strings: `jpeg`, `png`, `rgb8; jpeg compressed bgr8`, ...); an explanation
/// for anything else (compressedDepth, unknown formats, undecodable data).
pub fn decompress(msg: &CompressedImage) -> Result<Image, String> {
    let format = msg.format.to_ascii_lowercase();
    let kind = if format.contains("compresseddepth") {
        return Err(format!(
            "compressed format '{}' is depth, not colour",
            msg.format
        ));
    } else if format.contains("jpeg") || format.contains("jpg") {
        image::ImageFormat::Jpeg
    } else if format.contains("png") {
        image::ImageFormat::Png
    } else {
        return Err(format!(
            "unsupported compressed format '{}' (jpeg and png are)",
            msg.format
        ));
    };
    let decoded = image::load_from_memory_with_format(&msg.data, kind)
        .map_err(|e| format!("cannot decode the {:?} image: {e}", kind))?
        .to_rgb8();
    let (width, height) = decoded.dimensions();
    Ok(Image {
        header: msg.header.clone(),
        height,
        width,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: 3 * width,
        data: decoded.into_raw(),
    })
}

/// Linear RGB in [0, 1] from an rgb8 or bgr8 image of the camera's size (BGR converted here, at
/// the boundary); an explanation otherwise.
pub fn decode_image(img: &Image, camera: &Camera) -> Result<Vec<Vec3>, String> {
    if img.width != camera.width || img.height != camera.height {
        return Err(format!(
            "image is {}x{}, CameraInfo says {}x{}",
            img.width, img.height, camera.width, camera.height
        ));
    }
    let bgr = match img.encoding.as_str() {
        "rgb8" => false,
        "bgr8" => true,
        other => {
            return Err(format!(
                "unsupported encoding '{other}' (rgb8 and bgr8 are)"
            ));
        }
    };
    let step = img.step as usize;
    let (w, h) = (img.width as usize, img.height as usize);
    if step < 3 * w || img.data.len() < step * h {
        return Err(format!(
            "image data of {} bytes is too short for {w}x{h} with step {step}",
            img.data.len()
        ));
    }
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let p = &img.data[y * step + 3 * x..y * step + 3 * x + 3];
            let (r, g, b) = if bgr {
                (p[2], p[1], p[0])
            } else {
                (p[0], p[1], p[2])
            };
            out.push(Vec3::new(r as f32, g as f32, b as f32) / 255.0);
        }
    }
    Ok(out)
}

/// Metres from a depth image of the camera's size: 32FC1 in metres, or 16UC1 in units of `unit`
/// metres (0 and non-finite or negative values become 0, unknown).
pub fn decode_depth(img: &Image, camera: &Camera, unit: f32) -> Result<Vec<f32>, String> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let bytes = match img.encoding.as_str() {
        "32FC1" => 4,
        "16UC1" => 2,
        _ => 0,
    };
    if img.width != camera.width
        || img.height != camera.height
        || bytes == 0
        || img.is_bigendian != 0
        || (img.step as usize) < bytes * w
        || img.data.len() < img.step as usize * h
    {
        return Err(format!(
            "depth must be little-endian 32FC1 (m) or 16UC1 (units of node.depth_unit) of {w}x{h}, \
             got {} {}x{}",
            img.encoding, img.width, img.height
        ));
    }
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        let row = &img.data[y * img.step as usize..];
        for x in 0..w {
            let at = bytes * x;
            let d = if bytes == 4 {
                f32::from_le_bytes([row[at], row[at + 1], row[at + 2], row[at + 3]])
            } else {
                u16::from_le_bytes([row[at], row[at + 1]]) as f32 * unit
            };
            out.push(if d.is_finite() && d > 0.0 { d } else { 0.0 });
        }
    }
    Ok(out)
}

/// Labels from a mono8 instance-mask image of the camera's size.
pub fn decode_labels(img: &Image, camera: &Camera) -> Result<Vec<u8>, String> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Pose;
    use crate::msgs::{Header, Time};
    use crate::robot::{GeometrySource, PackagePaths};

    fn camera() -> Camera {
        Camera {
            width: 2,
            height: 1,
            fx: 1.0,
            fy: 1.0,
            cx: 1.0,
            cy: 0.5,
            world_to_camera: Pose::IDENTITY,
        }
    }

    fn image(t: f64) -> Image {
        Image {
            header: Header {
                stamp: Time::from_seconds(t),
                frame_id: "cam".into(),
            },
            width: 2,
            height: 1,
            encoding: "rgb8".into(),
            step: 6,
            data: vec![255, 0, 0, 0, 0, 255],
            ..Default::default()
        }
    }

    fn robot() -> RobotModel {
        let urdf = r#"<robot name="t"><link name="a"/><link name="b"/>
          <joint name="j1" type="continuous"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint></robot>"#;
        RobotModel::parse(
            urdf,
            std::path::Path::new("."),
            &PackagePaths::default(),
            GeometrySource::Collision,
        )
        .unwrap()
    }

    fn joint_state(t: f64, names: &[&str], q: &[f64]) -> JointState {
        JointState {
            header: Header {
                stamp: Time::from_seconds(t),
                frame_id: String::new(),
            },
            name: names.iter().map(|s| s.to_string()).collect(),
            position: q.to_vec(),
            ..Default::default()
        }
    }

    #[test]
    fn bgr_and_rgb_decode_to_the_same_colours_and_bad_images_are_explained() {
        let cam = camera();
        let rgb = image(0.0);
        let bgr = Image {
            encoding: "bgr8".into(),
            data: vec![0, 0, 255, 255, 0, 0],
            ..rgb.clone()
        };
        assert_eq!(decode_image(&rgb, &cam).unwrap(), vec![Vec3::X, Vec3::Z]);
        assert_eq!(decode_image(&bgr, &cam).unwrap(), vec![Vec3::X, Vec3::Z]);
        assert!(
            decode_image(
                &Image {
                    encoding: "mono16".into(),
                    ..rgb.clone()
                },
                &cam
            )
            .unwrap_err()
            .contains("mono16")
        );
        assert!(
            decode_image(
                &Image {
                    width: 3,
                    ..rgb.clone()
                },
                &cam
            )
            .unwrap_err()
            .contains("CameraInfo")
        );
        assert!(
            decode_image(
                &Image {
                    data: vec![1, 2],
                    ..rgb
                },
                &cam
            )
            .unwrap_err()
            .contains("too short")
        );
    }

    /// Depth as rigs record it: 32FC1 metres, or 16UC1 in the configured unit (realsense2_camera:
    /// millimetres), rows padded or not; 0 and NaN are unknown; other encodings are refused by
    /// name.
    #[test]
    fn depth_decodes_from_metres_or_millimetres_and_other_encodings_are_named() {
        let cam = camera();
        let metres = Image {
            encoding: "32FC1".into(),
            step: 8,
            data: [0.5f32, f32::NAN]
                .iter()
                .flat_map(|d| d.to_le_bytes())
                .collect(),
            ..image(0.0)
        };
        assert_eq!(decode_depth(&metres, &cam, 0.001).unwrap(), vec![0.5, 0.0]);
        // Millimetres, each row padded to 6 bytes.
        let millimetres = Image {
            encoding: "16UC1".into(),
            step: 6,
            data: [1234u16, 0, 0]
                .iter()
                .flat_map(|d| d.to_le_bytes())
                .collect(),
            ..image(0.0)
        };
        let d = decode_depth(&millimetres, &cam, 0.001).unwrap();
        assert!((d[0] - 1.234).abs() < 1e-6 && d[1] == 0.0, "{d:?}");
        let d = decode_depth(&millimetres, &cam, 0.0001).unwrap();
        assert!((d[0] - 0.1234).abs() < 1e-6, "another unit: {d:?}");
        let mono16 = Image {
            encoding: "mono16".into(),
            ..millimetres
        };
        assert!(
            decode_depth(&mono16, &cam, 0.001)
                .unwrap_err()
                .contains("got mono16")
        );
    }

    #[test]
    fn bad_images_are_refused_without_replacing_the_newest_good_one() {
        let mut inputs = Inputs::new(vec![("a".into(), camera())], None);
        inputs.offer_image(0, &image(1.0), 1.0).unwrap();
        let bad = [
            Image {
                encoding: "mono8".into(),
                ..image(1.1)
            },
            Image {
                width: 4,
                ..image(1.2)
            },
            Image {
                data: vec![0; 3],
                ..image(1.3)
            },
        ];
        for b in &bad {
            assert!(matches!(
                inputs.offer_image(0, b, 1.5),
                Err(Rejection::BadImage(_))
            ));
        }
        assert!(
            matches!(
                inputs.offer_image(0, &image(1.0), 1.5),
                Err(Rejection::OutOfOrder { .. })
            ),
            "duplicate stamp"
        );
        assert!(
            matches!(
                inputs.offer_image(0, &image(0.9), 1.5),
                Err(Rejection::OutOfOrder { .. })
            ),
            "reordered"
        );
        assert!(matches!(
            inputs.offer_image(0, &image(9.0), 1.5),
            Err(Rejection::Future { .. })
        ));
        assert_eq!(
            inputs.cameras[0].latest.as_ref().unwrap().0,
            1.0,
            "the good image stays the newest"
        );
        assert_eq!(inputs.log.images_rejected, 6);
        assert_eq!(inputs.rejections["bad_image"], 3);
        assert!(inputs.log.take_lines().iter().any(|l| l.contains("mono8")));
    }

    #[test]
    fn a_stream_that_jumped_back_for_good_restarts_after_a_few_messages() {
        let mut inputs = Inputs::new(vec![("a".into(), camera())], None);
        inputs.offer_image(0, &image(10.0), 10.0).unwrap();
        for k in 0..RESTART_AFTER - 1 {
            let jumped = inputs.offer_image(0, &image(2.0 + k as f64 * 0.1), 10.5);
            assert!(
                matches!(jumped, Err(Rejection::JumpedBack { .. })),
                "{jumped:?}"
            );
        }
        inputs
            .offer_image(0, &image(2.5), 10.5)
            .expect("the third message after the jump restarts the stream");
        assert_eq!(inputs.cameras[0].latest.as_ref().unwrap().0, 2.5);
        assert!(
            inputs
                .log
                .take_lines()
                .iter()
                .any(|l| l.contains("jumped back"))
        );
        inputs.offer_image(0, &image(2.6), 10.6).unwrap();
    }

    /// A depth image in metres at `t`, 0.5 m and unknown.
    fn depth(t: f64) -> Image {
        Image {
            encoding: "32FC1".into(),
            step: 8,
            data: [0.5f32, 0.0].iter().flat_map(|d| d.to_le_bytes()).collect(),
            ..image(t)
        }
    }

    #[test]
    fn a_depth_image_goes_with_the_colour_image_of_its_stamp_and_not_with_one_a_frame_apart() {
        let mut inputs = Inputs::new(vec![("a".into(), camera())], None);
        inputs.offer_image(0, &image(1.0), 1.0).unwrap();
        inputs.offer_depth(0, &depth(1.0), 0.001, 1.0).unwrap();
        let tick = inputs.tick_inputs(1.0, 0.1);
        let metres = tick.images[0]
            .depth
            .as_deref()
            .expect("depth of the same stamp");
        assert_eq!(metres, &vec![0.5, 0.0]);
        assert_eq!(tick.views()[0].depth, Some(&[0.5, 0.0][..]));
        // The next colour frame, 33 ms on, with the depth not yet there: colour alone.
        inputs.offer_image(0, &image(1.033), 1.033).unwrap();
        let tick = inputs.tick_inputs(1.033, 0.1);
        assert!(tick.images[0].depth.is_none());
        // Depth that never pairs is said once, not every tick.
        for _ in 0..100 {
            inputs.tick_inputs(1.033, 0.1);
        }
        let said = inputs.log.take_lines();
        assert_eq!(said.len(), 1, "{said:?}");
        assert!(said[0].contains("colour alone"), "{}", said[0]);
        // A depth image of another size, or one out of order, is refused with its reason and
        // changes nothing.
        let small = Image {
            width: 1,
            step: 4,
            ..depth(1.033)
        };
        let why = inputs.offer_depth(0, &small, 0.001, 1.04).unwrap_err();
        assert!(why.to_string().contains("2x1"), "{why}");
        let late = inputs.offer_depth(0, &depth(0.9), 0.001, 1.04).unwrap_err();
        assert!(matches!(late, Rejection::OutOfOrder { .. }), "{late:?}");
        assert!(
            inputs
                .log
                .take_lines()
                .iter()
                .any(|l| l.contains("camera a depth"))
        );
        assert!(inputs.tick_inputs(1.033, 0.1).images[0].depth.is_none());
    }

    #[test]
    fn stale_and_missing_cameras_are_left_out_of_the_tick_with_their_ages() {
        let mut inputs = Inputs::new(
            vec![
                ("a".into(), camera()),
                ("b".into(), camera()),
                ("c".into(), camera()),
            ],
            None,
        );
        inputs.offer_image(0, &image(1.0), 1.0).unwrap();
        inputs.offer_image(1, &image(0.2), 1.0).unwrap();
        let tick = inputs.tick_inputs(1.1, 0.5);
        assert_eq!(tick.images.len(), 1);
        assert_eq!(tick.stale, vec!["b".to_string()]);
        assert!((tick.ages[0].1.unwrap() - 0.1).abs() < 1e-9);
        assert!((tick.ages[1].1.unwrap() - 0.9).abs() < 1e-9);
        assert_eq!(tick.ages[2].1, None);
    }

    #[test]
    fn joint_states_skip_bad_values_and_unknown_names_and_extend_to_the_tick() {
        let model = robot();
        let mut inputs = Inputs::new(vec![], Some((&model, &[0.0])));
        inputs
            .offer_joint_state(&joint_state(0.0, &["j1"], &[0.0]), 0.0)
            .unwrap();
        inputs
            .offer_joint_state(&joint_state(0.1, &["j1", "mystery"], &[0.1, 5.0]), 0.1)
            .unwrap();
        assert!(inputs.log.unknown_joints.contains("mystery"));
        assert!(matches!(
            inputs.offer_joint_state(&joint_state(0.15, &["j1"], &[f64::NAN]), 0.15),
            Err(Rejection::NonFinite(_))
        ));
        assert!(matches!(
            inputs.offer_joint_state(&joint_state(0.2, &["j1"], &[]), 0.2),
            Err(Rejection::Malformed(_))
        ));
        assert!(matches!(
            inputs.offer_joint_state(&joint_state(0.05, &["j1"], &[9.0]), 0.2),
            Err(Rejection::OutOfOrder { .. })
        ));
        let tick = inputs.tick_inputs(0.13, 0.5);
        let trajectory = tick.trajectory.unwrap();
        // Linear extension of the last two samples (slope 1 rad/s) for 30 ms.
        assert!((trajectory.at(0.13).unwrap()[0] - 0.13).abs() < 1e-9);
        // The accepted samples reach the tick once, as recorded (not the extension).
        assert_eq!(tick.joint_samples, vec![(0.0, vec![0.0]), (0.1, vec![0.1])]);
        // Beyond the extrapolation limit the extension holds.
        let far = inputs.tick_inputs(1.0, 0.5);
        let held = far.trajectory.unwrap().at(1.0).unwrap()[0];
        assert!((held - (0.1 + MAX_JOINT_EXTRAPOLATION_S)).abs() < 1e-9);
        assert!(far.joint_samples.is_empty(), "each sample reaches one tick");
    }

    /// A tick that predicts from a world's clock 3 s behind (a slow start) gets the joint path
    /// from there, sample by sample: the robot moves along it rather than from where it is now.
    #[test]
    fn a_tick_from_far_behind_gets_the_joint_path_back_to_the_worlds_clock() {
        let model = robot();
        let mut inputs = Inputs::new(vec![], Some((&model, &[0.0])));
        for k in 0..=40 {
            let t = 0.1 * k as f64;
            let js = joint_state(t, &["j1"], &[t * t]);
            inputs.offer_joint_state(&js, 4.0).unwrap();
        }
        let tick = inputs.tick_inputs_from(1.0, 4.0, 0.5);
        let path = tick.trajectory.unwrap();
        for t in [1.0, 1.5, 2.7, 3.9] {
            let q = path.at(t).unwrap()[0];
            assert!((q - t * t).abs() < 1e-9, "{q} at {t} s");
        }
        // Without a world behind, the path starts a second before the tick.
        let recent = inputs.tick_inputs(4.0, 0.5).trajectory.unwrap();
        let held = recent.at(1.0).unwrap()[0];
        assert!(held > 8.0, "held at its first sample, about 3 s: {held}");
    }

    /// PNG decompresses to exactly the pixels it was made from, JPEG to within its quantisation;
    /// depth and unknown formats are refused by name.
    #[test]
    fn compressed_colour_decodes_to_the_pixels_it_encodes() {
        let (w, h) = (16u32, 8u32);
        let pixels: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 251) as u8).collect();
        let picture = image::RgbImage::from_raw(w, h, pixels.clone()).unwrap();
        let encode = |format: image::ImageFormat| {
            let mut bytes = std::io::Cursor::new(Vec::new());
            picture.write_to(&mut bytes, format).unwrap();
            bytes.into_inner()
        };
        let msg = |format: &str, data: Vec<u8>| CompressedImage {
            header: image(1.0).header,
            format: format.into(),
            data,
        };
        let png = decompress(&msg(
            "rgb8; png compressed rgb8",
            encode(image::ImageFormat::Png),
        ))
        .unwrap();
        assert_eq!(
            (png.width, png.height, png.encoding.as_str()),
            (w, h, "rgb8")
        );
        assert_eq!(png.data, pixels);
        assert_eq!(png.header.stamp, Time::from_seconds(1.0));
        let smooth: Vec<u8> = (0..w * h * 3)
            .map(|i| (60 + (i / 3 % w) * 4) as u8)
            .collect();
        let picture = image::RgbImage::from_raw(w, h, smooth.clone()).unwrap();
        let mut bytes = std::io::Cursor::new(Vec::new());
        picture
            .write_to(&mut bytes, image::ImageFormat::Jpeg)
            .unwrap();
        let jpeg = decompress(&msg("jpeg", bytes.into_inner())).unwrap();
        let worst = jpeg
            .data
            .iter()
            .zip(&smooth)
            .map(|(a, b)| (*a as i32 - *b as i32).abs())
            .max()
            .unwrap();
        assert!(worst <= 12, "JPEG off by {worst}");
        let depth = decompress(&msg("16UC1; compressedDepth png", vec![])).unwrap_err();
        assert!(depth.contains("depth"), "{depth}");
        let other = decompress(&msg("theora", vec![1, 2])).unwrap_err();
        assert!(other.contains("'theora'"), "{other}");
        assert!(decompress(&msg("jpeg", vec![1, 2, 3])).is_err());
    }

    /// A driver that prefixes its joints differently from the URDF (`fr3_` for `panda_`): without
    /// the mapping no joint matches and every name is unknown; with it the robot is driven.
    #[test]
    fn a_joint_prefix_mapping_lets_a_drivers_names_drive_the_urdf() {
        let model = crate::robot::RobotModel::parse(
            r#"<robot name="r"><link name="a"/><link name="b"/>
            <joint name="panda_joint1" type="revolute"><parent link="a"/><child link="b"/>
            <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint></robot>"#,
            std::path::Path::new("."),
            &PackagePaths::default(),
            GeometrySource::Collision,
        )
        .unwrap();
        let js = |t: f64| JointState {
            header: Header {
                stamp: Time::from_seconds(t),
                frame_id: String::new(),
            },
            name: vec!["fr3_joint1".into()],
            position: vec![0.5],
            ..Default::default()
        };
        let mut plain = Inputs::new(vec![], Some((&model, &[0.0])));
        plain.offer_joint_state(&js(0.1), 0.1).unwrap();
        assert!(!plain.joints_matched);
        assert!(plain.log.unknown_joints.contains("fr3_joint1"));
        let mut mapped = Inputs::new(vec![], Some((&model, &[0.0])));
        mapped.rename_joints("fr3_", "panda_");
        mapped.offer_joint_state(&js(0.1), 0.1).unwrap();
        assert!(mapped.joints_matched && mapped.log.unknown_joints.is_empty());
        let tick = mapped.tick_inputs(0.1, 1.0);
        let q = tick.trajectory.expect("a trajectory").at(0.1).unwrap();
        assert!((q[0] - 0.5).abs() < 1e-9, "{q:?}");
    }
}

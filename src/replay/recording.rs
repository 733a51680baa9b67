//! A recording surveyed before replay, in two streaming passes that keep only what is small:
//! the survey (every message once: which cameras the `node` templates find, their CameraInfo,
//! image stamps and encodings, the tf tree, the joint states) and the start (the first seconds
//! again: the colour images initialisation fits to and the first depth and mask images). The
//! colour images themselves are streamed later by `feed`. Cameras that cannot be used and
//! messages that cannot be decoded are explained in `warnings`, never dropped silently.

use crate::inputs::decompress;
use crate::math::Pose;
use crate::msgs::{self, CameraInfo, CompressedImage, Header, Image, JointState, TfMessage};
use crate::record::{BagReader, RawMessage, TfTree};
use crate::render::Camera;
use crate::topics::NodeConfig;
use anyhow::Result;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Images stamped further than this from the recording's median image stamp are refused: a zero
/// or garbage stamp in a bag of wall-clock stamps would otherwise stretch the replay over decades.
pub const MAX_STAMP_SPREAD_S: f64 = 24.0 * 3600.0;

/// What a message is to the replay, by its topic and the `node` templates.
#[derive(Clone, Debug, PartialEq)]
pub enum Role {
    Colour { camera: String, compressed: bool },
    Info(String),
    Depth(String),
    Mask(String),
    JointStates,
    TfStatic,
    Tf,
    Other,
}

/// The topic templates a recording is read with.
#[derive(Clone, Debug)]
pub struct Topics {
    pub node: NodeConfig,
}

impl Topics {
    pub fn role(&self, topic: &str) -> Role {
        let n = &self.node;
        let named = |c: String| n.cameras.is_empty() || n.cameras.contains(&c);
        let compressed_template = format!("{}/compressed", n.image_topic);
        if let Some(camera) =
            NodeConfig::camera_in(&n.image_topic, topic).filter(|c| named(c.clone()))
        {
            return Role::Colour {
                camera,
                compressed: false,
            };
        }
        if let Some(camera) =
            NodeConfig::camera_in(&compressed_template, topic).filter(|c| named(c.clone()))
        {
            return Role::Colour {
                camera,
                compressed: true,
            };
        }
        if let Some(c) = NodeConfig::camera_in(&n.camera_info_topic, topic) {
            return Role::Info(c);
        }
        if let Some(c) = NodeConfig::camera_in(&n.depth_topic, topic) {
            return Role::Depth(c);
        }
        if let Some(c) = NodeConfig::camera_in(&n.mask_topic, topic) {
            return Role::Mask(c);
        }
        match topic {
            t if t == NodeConfig::in_recording(&n.joint_states_topic) => Role::JointStates,
            "/tf_static" => Role::TfStatic,
            "/tf" => Role::Tf,
            _ => Role::Other,
        }
    }
}

/// A colour image as recorded: raw, or compressed (decoded when used).
pub enum Colour {
    Raw(Image),
    Compressed(CompressedImage),
}

impl Colour {
    pub fn decode(m: &RawMessage, compressed: bool) -> Result<Self> {
        Ok(if compressed {
            Colour::Compressed(msgs::from_cdr(&m.data)?)
        } else {
            Colour::Raw(msgs::from_cdr(&m.data)?)
        })
    }

    pub fn header(&self) -> &Header {
        match self {
            Colour::Raw(i) => &i.header,
            Colour::Compressed(c) => &c.header,
        }
    }

    pub fn encoding(&self) -> String {
        match self {
            Colour::Raw(i) => i.encoding.clone(),
            Colour::Compressed(c) => format!("compressed ({})", c.format),
        }
    }

    /// The image as `inputs` takes it: raw as is, compressed decoded to rgb8.
    pub fn into_image(self) -> Result<Image, String> {
        match self {
            Colour::Raw(i) => Ok(i),
            Colour::Compressed(c) => decompress(&c),
        }
    }
}

/// One camera as the survey found it.
#[derive(Clone, Debug, Serialize)]
pub struct CameraSurvey {
    pub name: String,
    pub topic: String,
    pub encoding: String,
    /// Image stamps, sorted.
    #[serde(skip)]
    pub stamps: Vec<f64>,
    pub images: usize,
    pub rate_hz: f64,
    pub frame: String,
    /// The frames from the world frame down to the optical frame.
    pub tf_chain: Vec<String>,
    /// The chain has `/tf` links: the camera moves and its pose is looked up at each image.
    pub moving: bool,
    pub has_camera_info: bool,
    pub depth: Option<String>,
    pub masks: Option<String>,
    /// Why the camera cannot be used, if it cannot.
    pub unusable: Option<String>,
    #[serde(skip)]
    pub camera: Option<Camera>,
}

/// A usable camera with the frames initialisation uses.
pub struct CameraStream {
    pub name: String,
    pub camera: Camera,
    pub frame: String,
    pub moving: bool,
    /// `(stamp, image)` spread over the table's fit span, the first one first.
    pub first_images: Vec<(f64, Image)>,
    pub depth: Option<Image>,
    pub mask: Option<Image>,
}

pub struct Streams {
    pub path: PathBuf,
    pub topics: Topics,
    pub cameras: Vec<CameraStream>,
    pub joint_states: Vec<(f64, JointState)>,
    /// `/tf_static`, and the first `/tf` sample of every edge (the feed follows `/tf` in time).
    pub tf: TfTree,
    /// Image stamps outside this window are refused (see `MAX_STAMP_SPREAD_S`).
    pub window: (f64, f64),
    /// First and last accepted image stamp.
    pub span: (f64, f64),
    /// Median of (log time - header stamp) over the images: where in the bag a stamp is found.
    pub log_offset: f64,
    /// The URDF recorded on each `*robot_description` topic.
    pub robot_descriptions: BTreeMap<String, String>,
}

/// Everything one pass over a recording finds, small enough to keep whatever the bag's length.
#[derive(Serialize)]
pub struct Survey {
    pub path: String,
    pub storage: String,
    pub messages: u64,
    /// Log-time span (s).
    pub duration_s: f64,
    /// topic -> (type, count).
    pub topics: BTreeMap<String, (String, u64)>,
    pub cameras: Vec<CameraSurvey>,
    pub joint_states: usize,
    pub joint_names: Vec<String>,
    #[serde(skip)]
    pub joint_samples: Vec<(f64, JointState)>,
    #[serde(skip)]
    pub tf: TfTree,
    #[serde(skip)]
    pub window: (f64, f64),
    #[serde(skip)]
    pub log_offset: f64,
    pub problem: Option<String>,
    /// The first `std_msgs/String` on each topic named `*robot_description`: the URDF as
    /// robot_state_publisher offered it while the bag was recorded.
    #[serde(skip)]
    pub robot_descriptions: BTreeMap<String, String>,
}

/// Per camera while surveying.
#[derive(Default)]
struct Seen {
    topic: String,
    compressed: bool,
    encoding: String,
    frame: String,
    stamps: Vec<f64>,
}

impl Survey {
    /// One streaming pass over `path` with `node`'s templates.
    pub fn of(path: &Path, node: &NodeConfig, warnings: &mut Vec<String>) -> Result<Self> {
        let topics = Topics { node: node.clone() };
        let mut reader = BagReader::open(path)?;
        let storage = reader.storage().to_string();
        let mut seen: BTreeMap<String, Seen> = BTreeMap::new();
        let mut infos: BTreeMap<String, CameraInfo> = BTreeMap::new();
        let mut depth: BTreeMap<String, String> = BTreeMap::new();
        let mut masks: BTreeMap<String, String> = BTreeMap::new();
        let mut survey = Survey {
            path: path.display().to_string(),
            storage,
            messages: 0,
            duration_s: 0.0,
            topics: BTreeMap::new(),
            cameras: Vec::new(),
            joint_states: 0,
            joint_names: Vec::new(),
            joint_samples: Vec::new(),
            tf: TfTree::default(),
            window: (f64::NEG_INFINITY, f64::INFINITY),
            log_offset: 0.0,
            problem: None,
            robot_descriptions: BTreeMap::new(),
        };
        let mut log_span = (f64::INFINITY, f64::NEG_INFINITY);
        let mut offsets = Vec::new();
        let mut joint_names = BTreeSet::new();
        let mut skipped = 0usize;
        for m in reader.by_ref() {
            survey.messages += 1;
            log_span = (log_span.0.min(m.time), log_span.1.max(m.time));
            let entry = survey
                .topics
                .entry(m.topic.clone())
                .or_insert((m.schema.clone(), 0));
            entry.1 += 1;
            let result: Result<()> = (|| {
                match topics.role(&m.topic) {
                    Role::Colour { camera, compressed } => {
                        let s = seen.entry(camera).or_default();
                        if !s.topic.is_empty() && s.compressed != compressed {
                            // Raw and compressed both recorded: raw wins.
                            if compressed {
                                return Ok(());
                            }
                            s.stamps.clear();
                        }
                        let image = Colour::decode(&m, compressed)?;
                        let stamp = image.header().stamp.seconds();
                        if s.stamps.is_empty() {
                            s.topic = m.topic.clone();
                            s.compressed = compressed;
                            s.encoding = image.encoding();
                            s.frame = image.header().frame_id.clone();
                        }
                        s.stamps.push(stamp);
                        offsets.push(m.time - stamp);
                    }
                    Role::Info(camera) => {
                        if let std::collections::btree_map::Entry::Vacant(e) = infos.entry(camera) {
                            e.insert(msgs::from_cdr(&m.data)?);
                        }
                    }
                    Role::Depth(camera) => {
                        if let std::collections::btree_map::Entry::Vacant(e) = depth.entry(camera) {
                            let image: Image = msgs::from_cdr(&m.data)?;
                            e.insert(image.encoding);
                        }
                    }
                    Role::Mask(camera) => {
                        if let std::collections::btree_map::Entry::Vacant(e) = masks.entry(camera) {
                            let image: Image = msgs::from_cdr(&m.data)?;
                            e.insert(image.encoding);
                        }
                    }
                    Role::JointStates => {
                        let js: JointState = msgs::from_cdr(&m.data)?;
                        joint_names.extend(js.name.iter().cloned());
                        survey.joint_samples.push((js.header.stamp.seconds(), js));
                    }
                    Role::TfStatic => {
                        let tf: TfMessage = msgs::from_cdr(&m.data)?;
                        warnings.extend(survey.tf.add(&tf, true));
                    }
                    Role::Tf => {
                        // The first sample of each edge: enough for the chain and a start pose.
                        let mut tf: TfMessage = msgs::from_cdr(&m.data)?;
                        tf.transforms
                            .retain(|t| !survey.tf.has_edge(&t.child_frame_id));
                        if !tf.transforms.is_empty() {
                            warnings.extend(survey.tf.add(&tf, false));
                        }
                    }
                    Role::Other => {
                        let description = m.topic.ends_with("robot_description")
                            && !survey.robot_descriptions.contains_key(&m.topic);
                        if description {
                            let urdf: msgs::StringMsg = msgs::from_cdr(&m.data)?;
                            survey.robot_descriptions.insert(m.topic.clone(), urdf.data);
                        }
                    }
                }
                Ok(())
            })();
            if let Err(e) = result {
                skipped += 1;
                if skipped <= 10 {
                    warnings.push(format!("skipped a message on {}: {e:#}", m.topic));
                }
            }
        }
        if skipped > 10 {
            warnings.push(format!("skipped {skipped} undecodable messages in all"));
        }
        if let Some(p) = reader.problem() {
            eprintln!("warning: {p}; using what was read");
            warnings.push(p.to_string());
            survey.problem = Some(p.to_string());
        }
        survey.duration_s = (log_span.1 - log_span.0).max(0.0);
        survey.log_offset = median(&mut offsets).unwrap_or(0.0);
        survey.joint_names = joint_names.into_iter().collect();
        survey.window = stamp_window(&seen);
        survey.finish_cameras(seen, infos, depth, masks, node, warnings);
        survey.finish_joints(warnings);
        Ok(survey)
    }

    /// Keep the stamps inside the window and decide which cameras can be used.
    fn finish_cameras(
        &mut self,
        seen: BTreeMap<String, Seen>,
        infos: BTreeMap<String, CameraInfo>,
        mut depth: BTreeMap<String, String>,
        mut masks: BTreeMap<String, String>,
        node: &NodeConfig,
        warnings: &mut Vec<String>,
    ) {
        let (lo, hi) = self.window;
        for (name, mut s) in seen {
            let before = s.stamps.len();
            let first_stray = s.stamps.iter().copied().find(|t| !(lo..=hi).contains(t));
            s.stamps.retain(|t| (lo..=hi).contains(t));
            s.stamps.sort_by(f64::total_cmp);
            if let Some(t) = first_stray {
                warnings.push(format!(
                    "camera {name}: {} image(s) refused, stamped far from the recording's other \
                     images (e.g. {t:.3} s against {:.3} s)",
                    before - s.stamps.len(),
                    (lo + hi) / 2.0
                ));
            }
            let info = infos.get(&name);
            let frame = node.optical_frame_of(&name, &s.frame);
            let chain = self.tf.chain(&node.world_frame, &frame);
            let first = s.stamps.first().copied().unwrap_or(0.0);
            let camera = camera_from(info, &self.tf, &node.world_frame, &frame, first);
            let n = s.stamps.len();
            let rate_hz = match (s.stamps.first(), s.stamps.last()) {
                (Some(a), Some(b)) if n > 1 && b > a => (n - 1) as f64 / (b - a),
                _ => 0.0,
            };
            let unusable = match (&camera, n) {
                (_, 0) => Some("no image with a usable stamp".to_string()),
                (Err(why), _) => Some(why.clone()),
                _ => None,
            };
            if let Some(why) = &unusable {
                warnings.push(format!("camera {name}: {why}; camera ignored"));
            }
            self.cameras.push(CameraSurvey {
                name: name.clone(),
                topic: s.topic,
                encoding: s.encoding,
                images: n,
                stamps: s.stamps,
                rate_hz,
                tf_chain: chain.unwrap_or_default(),
                moving: !self.tf.is_fixed(&node.world_frame, &frame),
                frame,
                has_camera_info: info.is_some(),
                depth: depth.remove(&name),
                masks: masks.remove(&name),
                unusable,
                camera: camera.ok(),
            });
        }
    }

    /// Joint states in stamp order, the stray ones refused.
    fn finish_joints(&mut self, warnings: &mut Vec<String>) {
        let (lo, hi) = self.window;
        let before = self.joint_samples.len();
        self.joint_samples.retain(|j| (lo..=hi).contains(&j.0));
        self.joint_samples.sort_by(|a, b| a.0.total_cmp(&b.0));
        self.joint_states = self.joint_samples.len();
        if self.joint_states < before {
            warnings.push(format!(
                "{} joint state(s) refused, stamped far from the recording's images",
                before - self.joint_states
            ));
        }
    }

    /// The error when no camera is usable: what was looked for and what the recording has.
    fn no_camera(&self, node: &NodeConfig) -> anyhow::Error {
        let images: Vec<String> = self
            .topics
            .iter()
            .filter(|(_, (ty, _))| ty.ends_with("/Image") || ty.ends_with("/CompressedImage"))
            .map(|(topic, (ty, _))| format!("{topic} ({ty})"))
            .collect();
        let why: Vec<String> = self
            .cameras
            .iter()
            .filter_map(|c| Some(format!("{}: {}", c.name, c.unusable.as_ref()?)))
            .collect();
        let frame = if node.optical_frame.is_empty() {
            "the images' frame_id".to_string()
        } else {
            format!("'{}'", node.optical_frame)
        };
        anyhow::anyhow!(
            "{} has no usable camera: looked for {{camera}} in {} (or {}/compressed) with {} and a \
             tf chain from '{}' to {frame}{}{}; the recording's image topics: {}",
            self.path,
            node.image_topic,
            node.image_topic,
            node.camera_info_topic,
            node.world_frame,
            if node.cameras.is_empty() {
                String::new()
            } else {
                format!(
                    " for the cameras named in node.cameras ({})",
                    node.cameras.join(", ")
                )
            },
            if why.is_empty() {
                String::new()
            } else {
                format!("; found but unusable: {}", why.join("; "))
            },
            if images.is_empty() {
                "none".to_string()
            } else {
                images.join(", ")
            }
        )
    }
}

impl Streams {
    /// Survey `path` and read its start: the first `max_cameras` usable cameras (by name; all
    /// when None), their first frames for initialisation (`fit_frames` colour images over
    /// `fit_span` s), the joint states.
    pub fn read(
        path: &Path,
        node: &NodeConfig,
        (fit_frames, fit_span): (usize, f64),
        max_cameras: Option<usize>,
        warnings: &mut Vec<String>,
    ) -> Result<Self> {
        let survey = Survey::of(path, node, warnings)?;
        let mut usable: Vec<&CameraSurvey> = survey
            .cameras
            .iter()
            .filter(|c| c.unusable.is_none())
            .collect();
        if let Some(n) = max_cameras {
            usable.truncate(n);
        }
        if usable.is_empty() {
            return Err(survey.no_camera(node));
        }
        let first = usable.iter().filter_map(|c| c.stamps.first()).copied();
        let last = usable.iter().filter_map(|c| c.stamps.last()).copied();
        let span = (
            first.fold(f64::INFINITY, f64::min),
            last.fold(f64::NEG_INFINITY, f64::max),
        );
        let topics = Topics { node: node.clone() };
        let cameras = read_start(
            path,
            &topics,
            &usable,
            (fit_frames, fit_span),
            &survey,
            warnings,
        )?;
        Ok(Streams {
            path: path.to_path_buf(),
            topics,
            cameras,
            joint_states: survey.joint_samples,
            tf: survey.tf,
            window: survey.window,
            span,
            log_offset: survey.log_offset,
            robot_descriptions: survey.robot_descriptions,
        })
    }
}

/// The second pass, over the first seconds only: per camera the colour images nearest the fit
/// times (the first image, then spread over `fit_span`), and the first depth and mask images.
fn read_start(
    path: &Path,
    topics: &Topics,
    usable: &[&CameraSurvey],
    (count, span): (usize, f64),
    survey: &Survey,
    warnings: &mut Vec<String>,
) -> Result<Vec<CameraStream>> {
    let count = count.max(1);
    // Per camera: the fit times, and the nearest image found so far for each.
    let targets: Vec<Vec<f64>> = usable
        .iter()
        .map(|c| {
            let t0 = c.stamps[0];
            let steps = (count.max(2) - 1) as f64;
            (0..count).map(|k| t0 + span * k as f64 / steps).collect()
        })
        .collect();
    let mut best: Vec<Vec<Option<(f64, Image)>>> =
        targets.iter().map(|t| vec![None; t.len()]).collect();
    let mut depth: Vec<Option<Image>> = vec![None; usable.len()];
    let mut mask: Vec<Option<Image>> = vec![None; usable.len()];
    let index = |name: &str| usable.iter().position(|c| c.name == name);
    let (lo, hi) = survey.window;
    let last_target = targets
        .iter()
        .flatten()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    let stop_after = last_target + survey.log_offset + 2.0;
    let mut reader = BagReader::open(path)?;
    for m in reader.by_ref() {
        let done_images = best.iter().flatten().all(Option::is_some);
        let done_first = usable.iter().enumerate().all(|(c, s)| {
            (s.depth.is_none() || depth[c].is_some()) && (s.masks.is_none() || mask[c].is_some())
        });
        if m.time > stop_after && (done_first || m.time > stop_after + 60.0) && done_images {
            break;
        }
        let _ = (|| -> Result<()> {
            match topics.role(&m.topic) {
                Role::Colour { camera, compressed } => {
                    let Some(c) = index(&camera) else {
                        return Ok(());
                    };
                    if m.topic != usable[c].topic {
                        return Ok(());
                    }
                    let colour = Colour::decode(&m, compressed)?;
                    let stamp = colour.header().stamp.seconds();
                    if !(lo..=hi).contains(&stamp) || stamp > last_target + 1.0 {
                        return Ok(());
                    }
                    let closer: Vec<usize> = (0..targets[c].len())
                        .filter(|&k| {
                            best[c][k].as_ref().is_none_or(|b| {
                                (stamp - targets[c][k]).abs() < (b.0 - targets[c][k]).abs()
                            })
                        })
                        .collect();
                    if closer.is_empty() {
                        return Ok(());
                    }
                    match colour.into_image() {
                        Ok(image) => {
                            for k in closer {
                                best[c][k] = Some((stamp, image.clone()));
                            }
                        }
                        Err(why) => {
                            warnings.push(format!("camera {camera}: image at {stamp:.3} s: {why}"))
                        }
                    }
                }
                Role::Depth(camera) => {
                    if let Some(c) = index(&camera).filter(|&c| depth[c].is_none()) {
                        depth[c] = Some(msgs::from_cdr(&m.data)?);
                    }
                }
                Role::Mask(camera) => {
                    if let Some(c) = index(&camera).filter(|&c| mask[c].is_none()) {
                        mask[c] = Some(msgs::from_cdr(&m.data)?);
                    }
                }
                _ => {}
            }
            Ok(())
        })();
    }
    let mut out = Vec::new();
    for (c, s) in usable.iter().enumerate() {
        let mut first_images: Vec<(f64, Image)> = best[c].iter().flatten().cloned().collect();
        first_images.dedup_by(|a, b| a.0 == b.0);
        let Some(camera) = s.camera else { continue };
        out.push(CameraStream {
            name: s.name.clone(),
            camera,
            frame: s.frame.clone(),
            moving: s.moving,
            first_images,
            depth: depth[c].take(),
            mask: mask[c].take(),
        });
    }
    Ok(out)
}

/// The camera model from its CameraInfo and its optical frame's pose at `t`.
fn camera_from(
    info: Option<&CameraInfo>,
    tf: &TfTree,
    world: &str,
    frame: &str,
    t: f64,
) -> Result<Camera, String> {
    let info = info.ok_or("images but no CameraInfo")?;
    let k = info.k;
    if !(k[0] > 0.0 && k[4] > 0.0) || info.width == 0 || info.height == 0 {
        return Err("invalid CameraInfo".into());
    }
    if frame.is_empty() {
        return Err("its images have no frame_id (set node.optical_frame)".into());
    }
    let world_from_optical: Pose = tf.lookup_nearest(world, frame, t)?;
    let (fx, fy, cx, cy) = (k[0] as f32, k[4] as f32, k[2] as f32, k[5] as f32);
    Ok(Camera::from_opencv(
        info.width,
        info.height,
        fx,
        fy,
        cx,
        cy,
        world_from_optical.inverse(),
    ))
}

/// Stamps within `MAX_STAMP_SPREAD_S` of the median image stamp.
fn stamp_window(seen: &BTreeMap<String, Seen>) -> (f64, f64) {
    let mut stamps: Vec<f64> = seen
        .values()
        .flat_map(|s| s.stamps.iter().copied())
        .filter(|t| t.is_finite())
        .collect();
    match median(&mut stamps) {
        Some(m) => (m - MAX_STAMP_SPREAD_S, m + MAX_STAMP_SPREAD_S),
        None => (f64::NEG_INFINITY, f64::INFINITY),
    }
}

fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    Some(values[values.len() / 2])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Time, schema};
    use crate::record;
    use glam::Vec3;

    fn node() -> NodeConfig {
        NodeConfig::default()
    }

    /// A camera that stamped one image 0 in a recording of wall-clock stamps: that image is
    /// refused with a warning, and the recording spans its real 1 s, not 55 years.
    #[test]
    fn a_stray_stamp_is_refused_not_replayed_for_decades() {
        let dir = std::env::temp_dir().join(format!("pegs-stray-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("epoch.mcap");
        let mut w = record::RecordingWriter::create(&path).unwrap();
        let frame = record::optical_frame("cam0");
        let camera = Camera::look_at(2, 1, 2.0, Vec3::new(1.0, 0.0, 1.0), Vec3::ZERO);
        let cameras = [("cam0".to_string(), camera)];
        let epoch = 1.7e9;
        let tf = record::optical_frames_tf(&cameras);
        let at = |t: f64| Time::from_seconds(t);
        w.write(record::TF_STATIC, schema::tf_message(), at(epoch), &tf)
            .unwrap();
        let info = record::camera_info(&camera, epoch, &frame);
        w.camera_info(&record::info_topic("cam0"), &info).unwrap();
        for t in [epoch, epoch + 0.5, 0.0, epoch + 1.0] {
            let image = record::rgb8(2, 1, vec![0; 6], t, &frame);
            w.image(&record::image_topic("cam0"), &image).unwrap();
        }
        w.finish().unwrap();
        let mut warnings = Vec::new();
        let streams = Streams::read(&path, &node(), (1, 0.0), None, &mut warnings).unwrap();
        assert_eq!(streams.span, (epoch, epoch + 1.0));
        assert_eq!(streams.cameras[0].first_images[0].0, epoch);
        assert!(
            warnings.iter().any(|w| w.contains("1 image(s) refused")),
            "{warnings:?}"
        );
    }

    /// A recording whose images are on topics the templates do not match is refused with what
    /// was looked for and what the recording has.
    #[test]
    fn no_usable_camera_names_the_topics_looked_for_and_found() {
        let dir = std::env::temp_dir().join(format!("pegs-streams-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("other.mcap");
        let mut w = record::RecordingWriter::create(&path).unwrap();
        let image = record::rgb8(2, 1, vec![0; 6], 0.0, "cam0_color_optical_frame");
        w.image("/cam0/color/image_raw", &image).unwrap();
        w.finish().unwrap();
        let e = Streams::read(&path, &node(), (1, 0.0), None, &mut Vec::new())
            .err()
            .unwrap();
        let text = format!("{e:#}");
        for part in [
            "no usable camera",
            "/camera/{camera}/color/image_raw",
            "/camera/{camera}/color/camera_info",
            "the images' frame_id",
            "/cam0/color/image_raw (sensor_msgs/msg/Image)",
        ] {
            assert!(text.contains(part), "'{part}' missing from: {text}");
        }
    }

    #[test]
    fn topics_take_their_roles_from_the_templates() {
        let t = Topics { node: node() };
        let colour = |c: &str, compressed| Role::Colour {
            camera: c.into(),
            compressed,
        };
        assert_eq!(t.role("/camera/a/color/image_raw"), colour("a", false));
        assert_eq!(
            t.role("/camera/a/color/image_raw/compressed"),
            colour("a", true)
        );
        assert_eq!(
            t.role("/camera/a/color/camera_info"),
            Role::Info("a".into())
        );
        assert_eq!(
            t.role("/camera/a/aligned_depth_to_color/image_raw"),
            Role::Depth("a".into())
        );
        assert_eq!(t.role("/camera/a/depth/image_rect_raw"), Role::Other);
        assert_eq!(t.role("/joint_states"), Role::JointStates);
        let only_b = Topics {
            node: NodeConfig {
                cameras: vec!["b".into()],
                ..node()
            },
        };
        assert_eq!(only_b.role("/camera/a/color/image_raw"), Role::Other);
        assert_eq!(only_b.role("/camera/b/color/image_raw"), colour("b", false));
    }
}

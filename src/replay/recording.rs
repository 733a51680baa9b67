//! A recording's content sorted for replay: per camera its model (CameraInfo and the optical
//! frame's pose from /tf_static) and its colour images in time order, the first depth and mask
//! images (for initialisation), and the joint states in time order. Messages that cannot be
//! decoded and cameras that cannot be used are explained in `warnings`, never dropped silently.

use crate::math::Pose;
use crate::msgs::{self, CameraInfo, Image, JointState, TfMessage};
use crate::record::{self, RawMessage};
use crate::render::Camera;
use anyhow::{Result, bail};
use glam::{Quat, Vec3};
use std::collections::BTreeMap;
use std::path::Path;

pub struct Streams {
    pub cameras: Vec<(String, Camera)>,
    /// Per camera: (stamp, image) in time order.
    pub images: Vec<Vec<(f64, Image)>>,
    /// Per camera: the first depth and instance-mask images, if recorded.
    pub depth: Vec<Option<Image>>,
    pub masks: Vec<Option<Image>>,
    pub joint_states: Vec<(f64, JointState)>,
}

/// Everything read, by camera name, before the cameras are checked.
#[derive(Default)]
struct Sorted {
    infos: BTreeMap<String, CameraInfo>,
    poses: BTreeMap<String, Pose>,
    images: BTreeMap<String, Vec<(f64, Image)>>,
    depth: BTreeMap<String, Image>,
    masks: BTreeMap<String, Image>,
    joint_states: Vec<(f64, JointState)>,
}

impl Streams {
    /// Read `path`, keeping the first `max_cameras` usable cameras (by name; all when None).
    /// A damaged or truncated file gives what it holds, with a warning.
    pub fn read(
        path: &Path,
        max_cameras: Option<usize>,
        warnings: &mut Vec<String>,
    ) -> Result<Self> {
        let (messages, problem) = record::read_messages(path)?;
        if let Some(p) = problem {
            eprintln!("warning: {p}; replaying what was read");
            warnings.push(p);
        }
        let mut sorted = Sorted::default();
        for m in messages {
            if let Err(e) = sorted.add(&m, warnings) {
                warnings.push(format!("skipped a message on {}: {e:#}", m.topic));
            }
        }
        let mut streams = sorted.into_streams(warnings);
        if let Some(n) = max_cameras {
            streams.cameras.truncate(n);
            streams.images.truncate(n);
        }
        if streams.cameras.is_empty() {
            bail!(
                "{} has no usable camera (needs images, CameraInfo and /tf_static)",
                path.display()
            );
        }
        Ok(streams)
    }

    /// The first and last image stamps over all cameras.
    pub fn span(&self) -> (f64, f64) {
        let first = self.images.iter().filter_map(|s| s.first().map(|f| f.0));
        let last = self.images.iter().filter_map(|s| s.last().map(|f| f.0));
        (
            first.fold(f64::INFINITY, f64::min),
            last.fold(f64::NEG_INFINITY, f64::max),
        )
    }
}

fn camera_of(topic: &str, suffix: &str) -> Option<String> {
    topic
        .strip_suffix(suffix)
        .map(|p| p.trim_start_matches('/').to_string())
}

impl Sorted {
    fn add(&mut self, m: &RawMessage, warnings: &mut Vec<String>) -> Result<()> {
        if let Some(cam) = camera_of(&m.topic, "/color/camera_info") {
            let info: CameraInfo = msgs::from_cdr(&m.data)?;
            self.infos.entry(cam).or_insert(info);
        } else if let Some(cam) = camera_of(&m.topic, "/color/image_raw") {
            let img: Image = msgs::from_cdr(&m.data)?;
            let stamp = img.header.stamp.seconds();
            self.images.entry(cam).or_default().push((stamp, img));
        } else if let Some(cam) = camera_of(&m.topic, "/depth/image_raw") {
            self.depth.entry(cam).or_insert(msgs::from_cdr(&m.data)?);
        } else if let Some(cam) = camera_of(&m.topic, "/mask/image_raw") {
            self.masks.entry(cam).or_insert(msgs::from_cdr(&m.data)?);
        } else if m.topic == record::JOINT_STATES {
            let js: JointState = msgs::from_cdr(&m.data)?;
            self.joint_states.push((js.header.stamp.seconds(), js));
        } else if m.topic == record::TF_STATIC {
            let tf: TfMessage = msgs::from_cdr(&m.data)?;
            for t in tf.transforms {
                if t.header.frame_id != record::WORLD_FRAME {
                    warnings.push(format!(
                        "/tf_static {} -> {}: only transforms from '{}' are used",
                        t.header.frame_id,
                        t.child_frame_id,
                        record::WORLD_FRAME
                    ));
                    continue;
                }
                let (p, q) = (t.transform.translation, t.transform.rotation);
                let cam_to_world = Pose::new(
                    Vec3::new(p.x as f32, p.y as f32, p.z as f32),
                    Quat::from_xyzw(q.x as f32, q.y as f32, q.z as f32, q.w as f32).normalize(),
                );
                self.poses.insert(t.child_frame_id, cam_to_world.inverse());
            }
        }
        Ok(())
    }

    /// The cameras with images, CameraInfo and a pose, in name order; the others explained.
    fn into_streams(mut self, warnings: &mut Vec<String>) -> Streams {
        let mut out = Streams {
            cameras: Vec::new(),
            images: Vec::new(),
            depth: Vec::new(),
            masks: Vec::new(),
            joint_states: std::mem::take(&mut self.joint_states),
        };
        for (name, mut images) in std::mem::take(&mut self.images) {
            let camera = match self.camera(&name) {
                Ok(camera) => camera,
                Err(why) => {
                    warnings.push(format!("camera {name}: {why}; camera ignored"));
                    continue;
                }
            };
            images.sort_by(|a, b| a.0.total_cmp(&b.0));
            out.depth.push(self.depth.remove(&name));
            out.masks.push(self.masks.remove(&name));
            out.cameras.push((name, camera));
            out.images.push(images);
        }
        out.joint_states.sort_by(|a, b| a.0.total_cmp(&b.0));
        out
    }

    fn camera(&self, name: &str) -> Result<Camera, String> {
        let info = self.infos.get(name).ok_or("images but no CameraInfo")?;
        let frame = record::optical_frame(name);
        let pose = self
            .poses
            .get(&frame)
            .ok_or_else(|| format!("no /tf_static transform to {frame}"))?;
        let k = info.k;
        if !(k[0] > 0.0 && k[4] > 0.0) || info.width == 0 || info.height == 0 {
            return Err("invalid CameraInfo".into());
        }
        let (fx, fy, cx, cy) = (k[0] as f32, k[4] as f32, k[2] as f32, k[5] as f32);
        Ok(Camera::from_opencv(
            info.width,
            info.height,
            fx,
            fy,
            cx,
            cy,
            *pose,
        ))
    }
}

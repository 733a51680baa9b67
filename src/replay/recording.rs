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
        // Every image topic the recording has, for the error when no camera is usable.
        let image_topics: std::collections::BTreeSet<String> = messages
            .iter()
            .filter(|m| m.schema.ends_with("/Image") || m.schema.ends_with("/CompressedImage"))
            .map(|m| format!("{} ({})", m.topic, m.schema))
            .collect();
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
            let found: Vec<&str> = image_topics.iter().map(String::as_str).collect();
            bail!(
                "{} has no usable camera: looked for {{camera}} in /{{camera}}/color/image_raw \
                 with /{{camera}}/color/camera_info and a /tf_static transform from '{}' to \
                 {}; the recording's image topics: {}",
                path.display(),
                record::WORLD_FRAME,
                record::optical_frame("{camera}"),
                if found.is_empty() {
                    "none".to_string()
                } else {
                    found.join(", ")
                }
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

/// Images stamped further than this from the recording's median image stamp are refused: a zero
/// or garbage stamp in a bag of wall-clock stamps would otherwise stretch the replay over decades.
pub const MAX_STAMP_SPREAD_S: f64 = 24.0 * 3600.0;

/// Refuse images and joint states whose stamps lie more than `MAX_STAMP_SPREAD_S` from the median
/// image stamp, saying how many and where.
fn drop_stray_stamps(streams: &mut Streams, warnings: &mut Vec<String>) {
    let mut stamps: Vec<f64> = streams.images.iter().flatten().map(|i| i.0).collect();
    if stamps.is_empty() {
        return;
    }
    stamps.sort_by(f64::total_cmp);
    let median = stamps[stamps.len() / 2];
    // NaN stamps count as stray too.
    let stray = |t: f64| {
        (t - median).abs().partial_cmp(&MAX_STAMP_SPREAD_S) != Some(std::cmp::Ordering::Less)
    };
    for ((name, _), images) in streams.cameras.iter().zip(&mut streams.images) {
        let before = images.len();
        let first_stray = images.iter().map(|i| i.0).find(|t| stray(*t));
        images.retain(|i| !stray(i.0));
        if let Some(t) = first_stray {
            warnings.push(format!(
                "camera {name}: {} image(s) refused, stamped far from the recording's other \
                 images (e.g. {t:.3} s against {median:.3} s)",
                before - images.len()
            ));
        }
    }
    let before = streams.joint_states.len();
    streams.joint_states.retain(|j| !stray(j.0));
    if streams.joint_states.len() < before {
        warnings.push(format!(
            "{} joint state(s) refused, stamped far from the recording's images ({median:.3} s)",
            before - streams.joint_states.len()
        ));
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
        drop_stray_stamps(&mut out, warnings);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Time, schema};
    use glam::Vec3;

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
        w.write(
            &record::info_topic("cam0"),
            schema::camera_info(),
            at(epoch),
            &info,
        )
        .unwrap();
        for t in [epoch, epoch + 0.5, 0.0, epoch + 1.0] {
            let image = record::rgb8(2, 1, vec![0; 6], t, &frame);
            w.write(&record::image_topic("cam0"), schema::image(), at(t), &image)
                .unwrap();
        }
        w.finish().unwrap();
        let mut warnings = Vec::new();
        let streams = Streams::read(&path, None, &mut warnings).unwrap();
        assert_eq!(streams.span(), (epoch, epoch + 1.0));
        assert_eq!(streams.images[0].len(), 3);
        assert!(
            warnings.iter().any(|w| w.contains("1 image(s) refused")),
            "{warnings:?}"
        );
    }

    /// A recording whose images are on topics pegs does not look for (realsense2_camera's
    /// default namespace) is refused with what was looked for and what the recording has.
    #[test]
    fn no_usable_camera_names_the_topics_looked_for_and_found() {
        let dir = std::env::temp_dir().join(format!("pegs-streams-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("realsense.mcap");
        let mut w = record::RecordingWriter::create(&path).unwrap();
        let topic = "/camera/cam0/color/image_raw";
        let image = record::rgb8(2, 1, vec![0; 6], 0.0, "cam0_color_optical_frame");
        w.write(topic, schema::image(), Time::from_seconds(0.0), &image)
            .unwrap();
        w.finish().unwrap();
        let e = Streams::read(&path, None, &mut Vec::new()).err().unwrap();
        let text = format!("{e:#}");
        for part in [
            "no usable camera",
            "/{camera}/color/image_raw",
            "/{camera}/color/camera_info",
            "{camera}_color_optical_frame",
            "/camera/cam0/color/image_raw (sensor_msgs/msg/Image)",
        ] {
            assert!(text.contains(part), "'{part}' missing from: {text}");
        }
    }
}

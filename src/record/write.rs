//! Writing recordings: MCAP storage in the rosbag2 profile with CDR-encoded ROS 2 messages, as a
//! rosbag2 directory (`metadata.yaml` beside one MCAP file) or a lone `.mcap` file, on the topics
//! and frames of the default `node` configuration, so a recording pegs writes is read back by the
//! same templates as a rig's bag. Also the message builders the scenario generator and importers
//! use. Never reads.

use super::metadata;
use crate::math::Pose;
use crate::msgs::{
    self, CameraInfo, Header, Image, Quaternion, TfMessage, Time, Transform, TransformStamped,
    Vector3,
};
use crate::render::Camera;
use crate::topics::NodeConfig;
use anyhow::{Context, Result};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// Topic names of one camera in pegs recordings: the default `node` templates.
pub fn image_topic(camera: &str) -> String {
    NodeConfig::for_camera(&NodeConfig::default().image_topic, camera)
}
pub fn info_topic(camera: &str) -> String {
    NodeConfig::for_camera(&NodeConfig::default().camera_info_topic, camera)
}
/// Depth aligned to the colour image (32FC1, metres; 0 where unknown).
pub fn depth_topic(camera: &str) -> String {
    NodeConfig::for_camera(&NodeConfig::default().depth_topic, camera)
}
/// Instance labels aligned to the colour image (mono8; 0 is no object).
pub fn mask_topic(camera: &str) -> String {
    NodeConfig::for_camera(&NodeConfig::default().mask_topic, camera)
}
/// The optical frame pegs stamps a camera's images with (realsense2_camera's name for it).
pub fn optical_frame(camera: &str) -> String {
    format!("{camera}_color_optical_frame")
}
pub const JOINT_STATES: &str = "/joint_states";
pub const TF_STATIC: &str = "/tf_static";
pub const TF: &str = "/tf";
pub const WORLD_FRAME: &str = "world";

pub fn header(t: f64, frame: &str) -> Header {
    Header {
        stamp: Time::from_seconds(t),
        frame_id: frame.to_string(),
    }
}

/// CameraInfo of a pinhole camera without distortion (back to the OpenCV convention: pixel
/// centres at integers).
pub fn camera_info(c: &Camera, t: f64, frame: &str) -> CameraInfo {
    let (fx, fy, cx, cy) = (
        c.fx as f64,
        c.fy as f64,
        c.cx as f64 - 0.5,
        c.cy as f64 - 0.5,
    );
    CameraInfo {
        header: header(t, frame),
        height: c.height,
        width: c.width,
        distortion_model: "plumb_bob".into(),
        d: vec![0.0; 5],
        k: [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        ..Default::default()
    }
}

/// An rgb8 image message from packed RGB bytes.
pub fn rgb8(width: u32, height: u32, data: Vec<u8>, t: f64, frame: &str) -> Image {
    Image {
        header: header(t, frame),
        height,
        width,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: 3 * width,
        data,
    }
}

/// A 32FC1 depth image message (metres, little-endian).
pub fn depth32(width: u32, height: u32, depth: &[f32], t: f64, frame: &str) -> Image {
    Image {
        header: header(t, frame),
        height,
        width,
        encoding: "32FC1".into(),
        is_bigendian: 0,
        step: 4 * width,
        data: depth.iter().flat_map(|d| d.to_le_bytes()).collect(),
    }
}

/// A mono8 image message.
pub fn mono8(width: u32, height: u32, data: Vec<u8>, t: f64, frame: &str) -> Image {
    Image {
        header: header(t, frame),
        height,
        width,
        encoding: "mono8".into(),
        is_bigendian: 0,
        step: width,
        data,
    }
}

/// A transform from `parent` to `child` stamped `t` carrying `parent_from_child`.
pub fn transform(parent: &str, child: &str, t: f64, parent_from_child: Pose) -> TransformStamped {
    let (p, q) = (parent_from_child.translation, parent_from_child.rotation);
    TransformStamped {
        header: header(t, parent),
        child_frame_id: child.to_string(),
        transform: Transform {
            translation: Vector3 {
                x: p.x as f64,
                y: p.y as f64,
                z: p.z as f64,
            },
            rotation: Quaternion {
                x: q.x as f64,
                y: q.y as f64,
                z: q.z as f64,
                w: q.w as f64,
            },
        },
    }
}

/// `/tf_static` content: every named camera's optical frame in the world frame.
pub fn optical_frames_tf(cameras: &[(String, Camera)]) -> TfMessage {
    let transforms = cameras
        .iter()
        .map(|(name, c)| {
            let world_from_optical = c.world_to_camera.inverse();
            transform(WORLD_FRAME, &optical_frame(name), 0.0, world_from_optical)
        })
        .collect();
    TfMessage { transforms }
}

/// Writes one recording: a rosbag2 directory, or a lone MCAP file when the path ends in `.mcap`.
pub struct RecordingWriter {
    writer: mcap::Writer<BufWriter<std::fs::File>>,
    /// The rosbag2 directory, when writing one, and its storage file's name.
    bag: Option<(PathBuf, String)>,
    /// topic -> (channel, type name, message count).
    channels: BTreeMap<String, (u16, String, u64)>,
    sequence: u32,
    span_ns: Option<(u64, u64)>,
}

impl RecordingWriter {
    /// Create `path`: a lone MCAP file if it ends in `.mcap`, otherwise a rosbag2 directory
    /// (replaced if it holds an earlier recording). Chunks are zstd-compressed.
    pub fn create(path: &Path) -> Result<Self> {
        Self::create_with(path, true)
    }

    /// As `create`, with chunk compression or without (as `ros2 bag record` writes by default).
    pub fn create_with(path: &Path, compress: bool) -> Result<Self> {
        let is_file = path.extension().is_some_and(|e| e == "mcap");
        let (file_path, bag) = if is_file {
            (path.to_path_buf(), None)
        } else {
            if path.join("metadata.yaml").is_file() {
                std::fs::remove_dir_all(path)
                    .with_context(|| format!("cannot replace {}", path.display()))?;
            }
            std::fs::create_dir_all(path)
                .with_context(|| format!("cannot create {}", path.display()))?;
            let name = path
                .file_name()
                .map_or("recording".into(), |n| n.to_string_lossy().to_string());
            let file = format!("{name}_0.mcap");
            (path.join(&file), Some((path.to_path_buf(), file)))
        };
        let file = std::fs::File::create(&file_path)
            .with_context(|| format!("cannot create {}", file_path.display()))?;
        let writer = mcap::WriteOptions::new()
            .profile("ros2")
            .compression(compress.then_some(mcap::Compression::Zstd))
            .create(BufWriter::new(file))
            .context("cannot start the MCAP file")?;
        Ok(Self {
            writer,
            bag,
            channels: BTreeMap::new(),
            sequence: 0,
            span_ns: None,
        })
    }

    /// Write `msg` on `topic` (schema `(type name, ros2msg text)`), stamped `stamp`.
    pub fn write<T: Serialize>(
        &mut self,
        topic: &str,
        schema: (&str, String),
        stamp: Time,
        msg: &T,
    ) -> Result<()> {
        self.write_raw(topic, schema, stamp.seconds(), &msgs::to_cdr(msg)?)
    }

    /// Write an image on `topic` at its header's stamp.
    pub fn image(&mut self, topic: &str, image: &Image) -> Result<()> {
        self.write(topic, msgs::schema::image(), image.header.stamp, image)
    }

    /// Write a CameraInfo on `topic` at its header's stamp.
    pub fn camera_info(&mut self, topic: &str, info: &CameraInfo) -> Result<()> {
        self.write(topic, msgs::schema::camera_info(), info.header.stamp, info)
    }

    /// Write an already encoded CDR payload (e.g. copied from another recording) at `time` (s).
    pub fn write_raw(
        &mut self,
        topic: &str,
        schema: (&str, String),
        time: f64,
        cdr: &[u8],
    ) -> Result<()> {
        let channel = match self.channels.get_mut(topic) {
            Some(c) => {
                c.2 += 1;
                c.0
            }
            None => {
                let schema_id = self
                    .writer
                    .add_schema(schema.0, "ros2msg", schema.1.as_bytes())?;
                let c = self
                    .writer
                    .add_channel(schema_id, topic, "cdr", &BTreeMap::new())?;
                self.channels
                    .insert(topic.to_string(), (c, schema.0.to_string(), 1));
                c
            }
        };
        self.sequence += 1;
        let t = Time::from_seconds(time).nanoseconds();
        self.span_ns = Some(self.span_ns.map_or((t, t), |(a, b)| (a.min(t), b.max(t))));
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: self.sequence,
            log_time: t,
            publish_time: t,
        };
        self.writer.write_to_known_channel(&header, cdr)?;
        Ok(())
    }

    /// Close the MCAP file and, for a rosbag2 directory, write its `metadata.yaml`.
    pub fn finish(mut self) -> Result<()> {
        self.writer
            .finish()
            .context("cannot finish the MCAP file")?;
        if let Some((dir, file)) = &self.bag {
            let topics: Vec<_> = self
                .channels
                .iter()
                .map(|(name, (_, type_name, count))| metadata::TopicSummary {
                    name: name.clone(),
                    type_name: type_name.clone(),
                    count: *count,
                })
                .collect();
            let (start, end) = self.span_ns.unwrap_or((0, 0));
            metadata::write(dir, file, &topics, start, end)?;
        }
        Ok(())
    }
}

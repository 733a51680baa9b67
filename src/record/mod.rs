//! Recordings: MCAP files in the rosbag2 profile with CDR-encoded ROS 2 messages, alone or in a
//! rosbag2 directory (`metadata.yaml` and its MCAP storage files). Writing is used by the scenario
//! generator; reading streams messages in file order for replay and tolerates a truncated file
//! (it yields what is intact and says where it stopped).

use crate::msgs::{
    self, CameraInfo, Header, Image, Quaternion, TfMessage, Time, Transform, TransformStamped,
    Vector3,
};
use crate::render::Camera;
use anyhow::{Context, Result};
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};
use std::io::BufWriter;
use std::path::Path;

/// Topic names of one camera in pegs recordings.
pub fn image_topic(camera: &str) -> String {
    format!("/{camera}/color/image_raw")
}
pub fn info_topic(camera: &str) -> String {
    format!("/{camera}/color/camera_info")
}
/// Depth aligned to the colour image (32FC1, metres; 0 where unknown).
pub fn depth_topic(camera: &str) -> String {
    format!("/{camera}/depth/image_raw")
}
/// Instance labels aligned to the colour image (mono8; 0 is no object).
pub fn mask_topic(camera: &str) -> String {
    format!("/{camera}/mask/image_raw")
}
pub fn optical_frame(camera: &str) -> String {
    format!("{camera}_color_optical_frame")
}
pub const JOINT_STATES: &str = "/joint_states";
pub const TF_STATIC: &str = "/tf_static";
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

/// `/tf_static` content: every named camera's optical frame in the world frame.
pub fn optical_frames_tf(cameras: &[(String, Camera)]) -> TfMessage {
    let transforms = cameras
        .iter()
        .map(|(name, c)| {
            let cam_to_world = c.world_to_camera.inverse();
            let (t, q) = (cam_to_world.translation, cam_to_world.rotation);
            TransformStamped {
                header: header(0.0, WORLD_FRAME),
                child_frame_id: optical_frame(name),
                transform: Transform {
                    translation: Vector3 {
                        x: t.x as f64,
                        y: t.y as f64,
                        z: t.z as f64,
                    },
                    rotation: Quaternion {
                        x: q.x as f64,
                        y: q.y as f64,
                        z: q.z as f64,
                        w: q.w as f64,
                    },
                },
            }
        })
        .collect();
    TfMessage { transforms }
}

pub struct RecordingWriter {
    writer: mcap::Writer<BufWriter<std::fs::File>>,
    channels: HashMap<String, u16>,
    sequence: u32,
}

impl RecordingWriter {
    pub fn create(path: &Path) -> Result<Self> {
        let file = std::fs::File::create(path)
            .with_context(|| format!("cannot create {}", path.display()))?;
        let writer = mcap::WriteOptions::new()
            .profile("ros2")
            .compression(Some(mcap::Compression::Zstd))
            .create(BufWriter::new(file))
            .context("cannot start the MCAP file")?;
        Ok(Self {
            writer,
            channels: HashMap::new(),
            sequence: 0,
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
        let channel = match self.channels.get(topic) {
            Some(&c) => c,
            None => {
                let schema_id = self
                    .writer
                    .add_schema(schema.0, "ros2msg", schema.1.as_bytes())?;
                let c = self
                    .writer
                    .add_channel(schema_id, topic, "cdr", &BTreeMap::new())?;
                self.channels.insert(topic.to_string(), c);
                c
            }
        };
        self.sequence += 1;
        let t = Time::from_seconds(time).nanoseconds();
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: self.sequence,
            log_time: t,
            publish_time: t,
        };
        self.writer.write_to_known_channel(&header, cdr)?;
        Ok(())
    }

    pub fn finish(mut self) -> Result<()> {
        self.writer
            .finish()
            .context("cannot finish the MCAP file")?;
        Ok(())
    }
}

/// One recorded message: topic, schema name, log time (s) and CDR payload.
pub struct RawMessage {
    pub topic: String,
    pub schema: String,
    pub time: f64,
    pub data: Vec<u8>,
}

/// Every message of a recording in file order: an MCAP file, or a rosbag2 directory (its
/// `metadata.yaml` and MCAP storage files, in the order it lists them). A damaged or truncated
/// tail ends the list and is reported in the second value instead of failing the whole read.
pub fn read_messages(path: &Path) -> Result<(Vec<RawMessage>, Option<String>)> {
    if !path.is_dir() {
        return read_mcap(path);
    }
    let mut out = Vec::new();
    for file in bag_files(path)? {
        let (messages, problem) = read_mcap(&file)?;
        out.extend(messages);
        if problem.is_some() {
            return Ok((out, problem));
        }
    }
    Ok((out, None))
}

/// The part of a rosbag2 `metadata.yaml` that says where the messages are.
#[derive(serde::Deserialize)]
struct BagMetadata {
    rosbag2_bagfile_information: BagInformation,
}

#[derive(serde::Deserialize)]
struct BagInformation {
    storage_identifier: String,
    relative_file_paths: Vec<String>,
    #[serde(default)]
    compression_format: String,
}

/// The storage files of the rosbag2 directory `dir`, in order; an error names what is missing
/// or not supported.
fn bag_files(dir: &Path) -> Result<Vec<std::path::PathBuf>> {
    let meta_path = dir.join("metadata.yaml");
    let text = std::fs::read_to_string(&meta_path).with_context(|| {
        format!(
            "{} is a directory without metadata.yaml: not a rosbag2 bag (give an .mcap file or a \
             rosbag2 directory)",
            dir.display()
        )
    })?;
    let meta: BagMetadata = serde_yaml_ng::from_str(&text)
        .with_context(|| format!("cannot read {}", meta_path.display()))?;
    let info = meta.rosbag2_bagfile_information;
    if info.storage_identifier != "mcap" {
        anyhow::bail!(
            "{}: storage '{}' is not supported (only mcap; convert it with \
             `ros2 bag convert` to storage_id mcap)",
            dir.display(),
            info.storage_identifier
        );
    }
    if !info.compression_format.is_empty() {
        anyhow::bail!(
            "{}: compressed bags ({}) are not supported (write an uncompressed copy with \
             `ros2 bag convert`)",
            dir.display(),
            info.compression_format
        );
    }
    let files: Vec<_> = info
        .relative_file_paths
        .iter()
        .map(|f| dir.join(f))
        .collect();
    if files.is_empty() {
        anyhow::bail!("{}: metadata.yaml lists no storage files", dir.display());
    }
    if let Some(missing) = files.iter().find(|f| !f.is_file()) {
        anyhow::bail!(
            "{}: metadata.yaml lists {}, which is missing",
            dir.display(),
            missing.display()
        );
    }
    Ok(files)
}

/// Every message of one MCAP file, in file order (see `read_messages`).
fn read_mcap(path: &Path) -> Result<(Vec<RawMessage>, Option<String>)> {
    let bytes =
        std::fs::read(path).with_context(|| format!("cannot read recording {}", path.display()))?;
    let mut out = Vec::new();
    let stream = match mcap::MessageStream::new(&bytes) {
        Ok(s) => s,
        Err(e) => {
            return Ok((
                out,
                Some(format!(
                    "{} is not a readable MCAP file: {e}",
                    path.display()
                )),
            ));
        }
    };
    for m in stream {
        match m {
            Ok(m) => out.push(RawMessage {
                topic: m.channel.topic.clone(),
                schema: m
                    .channel
                    .schema
                    .as_ref()
                    .map(|s| s.name.clone())
                    .unwrap_or_default(),
                time: m.log_time as f64 * 1e-9,
                data: m.data.into_owned(),
            }),
            Err(e) => {
                let report = format!(
                    "{} is damaged after {} messages: {e}",
                    path.display(),
                    out.len()
                );
                return Ok((out, Some(report)));
            }
        }
    }
    Ok((out, None))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{Header, JointState};

    #[test]
    fn writes_and_reads_back_and_survives_truncation() {
        let dir = std::env::temp_dir().join(format!("pegs-rec-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("r.mcap");
        joint_file(&path, 0..200);
        let (msgs_read, problem) = read_messages(&path).unwrap();
        assert!(problem.is_none());
        assert_eq!(msgs_read.len(), 200);
        assert_eq!(msgs_read[0].schema, "sensor_msgs/msg/JointState");
        let js: JointState = msgs::from_cdr(&msgs_read[150].data).unwrap();
        assert_eq!(js.position, vec![150.0]);
        assert!((msgs_read[150].time - 1.5).abs() < 1e-9);
        // Cut the file in the middle: no panic, a clear report, whatever was intact.
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(dir.join("cut.mcap"), &bytes[..bytes.len() / 2]).unwrap();
        let (partial, problem) = read_messages(&dir.join("cut.mcap")).unwrap();
        assert!(problem.is_some(), "truncation must be reported");
        for m in &partial {
            msgs::from_cdr::<JointState>(&m.data).expect("what is returned is intact");
        }
        // Cut inside the first chunk: its messages are lost, and that is reported too.
        std::fs::write(dir.join("cut2.mcap"), &bytes[..100]).unwrap();
        let (partial, problem) = read_messages(&dir.join("cut2.mcap")).unwrap();
        assert!(
            problem.is_some() && partial.len() < 200,
            "{} messages from 100 bytes",
            partial.len()
        );
        std::fs::write(dir.join("junk.mcap"), b"not an mcap").unwrap();
        let (none, problem) = read_messages(&dir.join("junk.mcap")).unwrap();
        assert!(none.is_empty() && problem.is_some());
    }

    /// Joint states k (position k, stamp k / 100 s) for k in `times`, into the MCAP file `path`.
    fn joint_file(path: &Path, times: std::ops::Range<usize>) {
        let mut w = RecordingWriter::create(path).unwrap();
        for k in times {
            let t = Time::from_seconds(k as f64 * 0.01);
            let js = JointState {
                header: Header {
                    stamp: t,
                    frame_id: String::new(),
                },
                name: vec!["j".into()],
                position: vec![k as f64],
                ..Default::default()
            };
            w.write(JOINT_STATES, msgs::schema::joint_state(), t, &js)
                .unwrap();
        }
        w.finish().unwrap();
    }

    /// A rosbag2 directory split into two storage files is read as one recording, in the order
    /// its metadata lists them; other storages, missing files and directories that are not bags
    /// are refused, naming what is wrong.
    #[test]
    fn a_rosbag2_directory_reads_its_storage_files_in_order() {
        let dir = std::env::temp_dir().join(format!("pegs-bag-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        joint_file(&dir.join("bag_0.mcap"), 0..50);
        joint_file(&dir.join("bag_1.mcap"), 50..80);
        let metadata = |storage: &str, files: &[&str]| {
            let list: String = files.iter().map(|f| format!("  - {f}\n")).collect();
            let text = format!(
                "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: {storage}\n  \
                 compression_format: ''\n  relative_file_paths:\n{list}"
            );
            std::fs::write(dir.join("metadata.yaml"), text).unwrap();
        };
        metadata("mcap", &["bag_0.mcap", "bag_1.mcap"]);
        let (read, problem) = read_messages(&dir).unwrap();
        assert!(problem.is_none());
        let positions: Vec<f64> = read
            .iter()
            .map(|m| msgs::from_cdr::<JointState>(&m.data).unwrap().position[0])
            .collect();
        assert_eq!(positions, (0..80).map(|k| k as f64).collect::<Vec<_>>());
        let refused = |why: &str| {
            let e = read_messages(&dir).err().expect("refused");
            let text = format!("{e:#}");
            assert!(text.contains(why), "{text}");
        };
        metadata("sqlite3", &["bag_0.db3"]);
        refused("storage 'sqlite3' is not supported");
        metadata("mcap", &["bag_0.mcap", "bag_2.mcap"]);
        refused("bag_2.mcap, which is missing");
        std::fs::remove_file(dir.join("metadata.yaml")).unwrap();
        refused("without metadata.yaml");
    }
}

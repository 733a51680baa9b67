//! ROS 2 messages pegs reads and writes, as plain serde structs in field order, so the same types
//! serialise to CDR for DDS and for MCAP recordings. `uint8[]` fields use serde_bytes (an order of
//! magnitude faster for images). Each type carries its `ros2msg` schema text for MCAP.

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    pub fn from_seconds(t: f64) -> Self {
        let sec = t.floor();
        Self {
            sec: sec as i32,
            nanosec: ((t - sec) * 1e9).round().min(999_999_999.0) as u32,
        }
    }

    pub fn seconds(&self) -> f64 {
        self.sec as f64 + self.nanosec as f64 * 1e-9
    }

    pub fn nanoseconds(&self) -> u64 {
        (self.sec.max(0) as u64) * 1_000_000_000 + self.nanosec as u64
    }
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Image {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub encoding: String,
    pub is_bigendian: u8,
    pub step: u32,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RegionOfInterest {
    pub x_offset: u32,
    pub y_offset: u32,
    pub height: u32,
    pub width: u32,
    pub do_rectify: bool,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CameraInfo {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub distortion_model: String,
    pub d: Vec<f64>,
    pub k: [f64; 9],
    pub r: [f64; 9],
    pub p: [f64; 12],
    pub binning_x: u32,
    pub binning_y: u32,
    pub roi: RegionOfInterest,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointState {
    pub header: Header,
    pub name: Vec<String>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// x, y, z, w (ROS order).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    pub translation: Vector3,
    pub rotation: Quaternion,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub transform: Transform,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TfMessage {
    pub transforms: Vec<TransformStamped>,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseMsg {
    pub position: Point,
    pub orientation: Quaternion,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PoseArray {
    pub header: Header,
    pub poses: Vec<PoseMsg>,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Twist {
    pub linear: Vector3,
    pub angular: Vector3,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Wrench {
    pub force: Vector3,
    pub torque: Vector3,
}

/// `pegs_msgs/TrackedObject` (msg/TrackedObject.msg).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrackedObject {
    pub name: String,
    pub pose: PoseMsg,
    pub twist: Twist,
    pub visual_wrench: Wrench,
}

/// `pegs_msgs/TrackedObjectArray` (msg/TrackedObjectArray.msg).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrackedObjectArray {
    pub header: Header,
    pub objects: Vec<TrackedObject>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PointField {
    pub name: String,
    pub offset: u32,
    pub datatype: u8,
    pub count: u32,
}

impl PointField {
    pub const UINT32: u8 = 6;
    pub const FLOAT32: u8 = 7;
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PointCloud2 {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub fields: Vec<PointField>,
    pub is_bigendian: bool,
    pub point_step: u32,
    pub row_step: u32,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
    pub is_dense: bool,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CompressedImage {
    pub header: Header,
    pub format: String,
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct KeyValue {
    pub key: String,
    pub value: String,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    pub level: u8,
    pub name: String,
    pub message: String,
    pub hardware_id: String,
    pub values: Vec<KeyValue>,
}

impl DiagnosticStatus {
    pub const OK: u8 = 0;
    pub const WARN: u8 = 1;
    pub const ERROR: u8 = 2;
    pub const STALE: u8 = 3;
}

/// `std_msgs/String`: here the URDF on `/robot_description`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StringMsg {
    pub data: String,
}

/// `rosgraph_msgs/Clock`: simulated time on `/clock` (`ros2 bag play --clock`, simulators).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Clock {
    pub clock: Time,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    pub header: Header,
    pub status: Vec<DiagnosticStatus>,
}

/// Every message type above is a ROS 2 message for ros2-client (DDS).
macro_rules! ros_messages {
    ($($t:ty),*) => { $(impl ros2_client::Message for $t {})* };
}
ros_messages!(
    Image,
    CameraInfo,
    JointState,
    TfMessage,
    PoseArray,
    TrackedObjectArray,
    PointCloud2,
    CompressedImage,
    DiagnosticArray,
    Clock,
    StringMsg
);

/// Encapsulation header of little-endian plain CDR, as ROS 2 writes it.
const CDR_LE: [u8; 4] = [0, 1, 0, 0];

/// Serialise as a ROS 2 CDR payload (encapsulation header + little-endian body).
pub fn to_cdr<T: Serialize>(msg: &T) -> Result<Vec<u8>> {
    let body = cdr_encoding::to_vec::<T, byteorder::LittleEndian>(msg)
        .map_err(|e| anyhow::anyhow!("CDR encoding failed: {e}"))?;
    let mut out = Vec::with_capacity(body.len() + 4);
    out.extend_from_slice(&CDR_LE);
    out.extend_from_slice(&body);
    Ok(out)
}

/// Parse a ROS 2 CDR payload (little- or big-endian encapsulation).
pub fn from_cdr<T: for<'de> Deserialize<'de>>(bytes: &[u8]) -> Result<T> {
    anyhow::ensure!(
        bytes.len() >= 4,
        "CDR payload of {} bytes has no encapsulation header",
        bytes.len()
    );
    let body = &bytes[4..];
    let value = match bytes[1] {
        1 => cdr_encoding::from_bytes::<T, byteorder::LittleEndian>(body),
        0 => cdr_encoding::from_bytes::<T, byteorder::BigEndian>(body),
        other => anyhow::bail!("unsupported CDR encapsulation kind {other}"),
    };
    value
        .map(|(v, _)| v)
        .map_err(|e| anyhow::anyhow!("malformed CDR message: {e}"))
        .context("decoding a recorded message")
}

/// ROS 2 type names and `ros2msg` schema texts (dependencies appended in the rosbag2 layout).
pub mod schema {
    const TIME: &str = "int32 sec\nuint32 nanosec\n";
    const HEADER: &str = "builtin_interfaces/Time stamp\nstring frame_id\n";
    const ROI: &str =
        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n";
    const VECTOR3: &str = "float64 x\nfloat64 y\nfloat64 z\n";
    const QUATERNION: &str = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n";
    const TRANSFORM: &str = "Vector3 translation\nQuaternion rotation\n";
    const TRANSFORM_STAMPED: &str =
        "std_msgs/Header header\nstring child_frame_id\nTransform transform\n";

    fn with_deps(main: &str, deps: &[(&str, &str)]) -> String {
        let mut s = main.to_string();
        for (name, text) in deps {
            s.push_str(&"=".repeat(80));
            s.push_str(&format!("\nMSG: {name}\n{text}"));
        }
        s
    }

    /// The schema of the message type `name` (e.g. `sensor_msgs/msg/Image`), among those pegs
    /// reads and writes.
    pub fn of_type(name: &str) -> Option<(&'static str, String)> {
        [image(), camera_info(), joint_state(), tf_message()]
            .into_iter()
            .find(|s| s.0 == name)
    }

    pub fn image() -> (&'static str, String) {
        let main = "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n";
        (
            "sensor_msgs/msg/Image",
            with_deps(
                main,
                &[
                    ("std_msgs/Header", HEADER),
                    ("builtin_interfaces/Time", TIME),
                ],
            ),
        )
    }

    pub fn camera_info() -> (&'static str, String) {
        let main = "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\nRegionOfInterest roi\n";
        (
            "sensor_msgs/msg/CameraInfo",
            with_deps(
                main,
                &[
                    ("std_msgs/Header", HEADER),
                    ("builtin_interfaces/Time", TIME),
                    ("sensor_msgs/RegionOfInterest", ROI),
                ],
            ),
        )
    }

    pub fn joint_state() -> (&'static str, String) {
        let main = "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n";
        (
            "sensor_msgs/msg/JointState",
            with_deps(
                main,
                &[
                    ("std_msgs/Header", HEADER),
                    ("builtin_interfaces/Time", TIME),
                ],
            ),
        )
    }

    pub fn tf_message() -> (&'static str, String) {
        let main = "geometry_msgs/TransformStamped[] transforms\n";
        (
            "tf2_msgs/msg/TFMessage",
            with_deps(
                main,
                &[
                    ("geometry_msgs/TransformStamped", TRANSFORM_STAMPED),
                    ("std_msgs/Header", HEADER),
                    ("builtin_interfaces/Time", TIME),
                    ("geometry_msgs/Transform", TRANSFORM),
                    ("geometry_msgs/Vector3", VECTOR3),
                    ("geometry_msgs/Quaternion", QUATERNION),
                ],
            ),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_round_trip_through_cdr() {
        let img = Image {
            header: Header {
                stamp: Time::from_seconds(12.25),
                frame_id: "cam0_optical".into(),
            },
            height: 2,
            width: 2,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: 6,
            data: (0..12).collect(),
        };
        let back: Image = from_cdr(&to_cdr(&img).unwrap()).unwrap();
        assert_eq!(back, img);
        let info = CameraInfo {
            k: [1.0, 0.0, 2.0, 0.0, 3.0, 4.0, 0.0, 0.0, 1.0],
            p: [7.0; 12],
            d: vec![0.1, 0.2],
            ..Default::default()
        };
        assert_eq!(
            from_cdr::<CameraInfo>(&to_cdr(&info).unwrap()).unwrap(),
            info
        );
        let js = JointState {
            name: vec!["a".into(), "b".into()],
            position: vec![0.5, f64::NAN],
            ..Default::default()
        };
        let back: JointState = from_cdr(&to_cdr(&js).unwrap()).unwrap();
        assert_eq!(back.name, js.name);
        assert!(back.position[1].is_nan());
        assert!(
            from_cdr::<Image>(&[0, 1, 0, 0, 5]).is_err(),
            "truncated payload is an error"
        );
        assert!(from_cdr::<Image>(&[0, 1]).is_err());
    }

    #[test]
    fn small_image_bytes_match_the_reference_layout() {
        // Stamp 1 s + 2 ns, frame "f", 1x1 rgb8: the fixed part of the CDR layout, byte by byte.
        let img = Image {
            header: Header {
                stamp: Time { sec: 1, nanosec: 2 },
                frame_id: "f".into(),
            },
            height: 1,
            width: 1,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: 3,
            data: vec![9, 8, 7],
        };
        let b = to_cdr(&img).unwrap();
        assert_eq!(&b[..4], &[0, 1, 0, 0]);
        assert_eq!(&b[4..12], &[1, 0, 0, 0, 2, 0, 0, 0], "stamp sec, nanosec");
        assert_eq!(
            &b[12..18],
            &[2, 0, 0, 0, b'f', 0],
            "frame_id with its length and NUL"
        );
        assert_eq!(&b[b.len() - 3..], &[9, 8, 7]);
    }
}

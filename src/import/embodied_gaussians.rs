//! The layout of the PEGS authors' sample data (`embodied_gaussians`): per camera an HEVC video
//! with a JSON of timestamps and intrinsics, `cameras.json` with OpenGL-style camera-to-world
//! matrices, objects as JSON (Gaussians with w,x,y,z quaternions and B,G,R colours) and the ground
//! plane. Every foreign convention of the layout is converted here, at the boundary; the object
//! files themselves are read by `init::object_file`.

use crate::config::Config;
use crate::init::ColourMask;
use crate::init::object_file::{load_object, pose_from_rows, read_json};
use crate::init::{ObjectConfig, TableConfig};
use crate::math::Pose;
use crate::msgs::{self, Time};
use crate::record::{self, RecordingWriter};
use crate::render::Camera;
use anyhow::{Context, Result, bail};
use glam::{DMat4, DVec3, Vec2, Vec3};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};

/// `cameras.json`: serial -> camera-to-world, OpenGL convention (looks along -Z, +Y up).
#[derive(Deserialize)]
struct CameraEntry {
    #[serde(rename = "X_WC")]
    x_wc: [[f64; 4]; 4],
}

/// `videos/<serial>.json`.
#[derive(Deserialize)]
struct VideoMeta {
    #[serde(rename = "K")]
    k: [[f64; 3]; 3],
    resolution: [u32; 2],
    timestamps: Vec<f64>,
}

#[derive(Deserialize)]
struct PlaneFile {
    /// a, b, c, d of `a x + b y + c z + d = 0`.
    plane: [f64; 4],
}

/// Camera-to-world of an OpenGL camera (looks along -Z, +Y up) as the pose of the REP-105 optical
/// frame (z forward, y down): the same origin, y and z axes flipped.
pub fn optical_from_opengl(camera_to_world: &[[f64; 4]; 4]) -> Result<Pose> {
    let gl = DMat4::from_cols_array_2d(camera_to_world).transpose();
    let flipped = gl * DMat4::from_diagonal(glam::DVec4::new(1.0, -1.0, -1.0, 1.0));
    pose_from_rows(&flipped.transpose().to_cols_array_2d())
}

/// The ground plane `a x + b y + c z + d = 0` as (unit normal pointing up, height along it).
pub fn ground_from_plane(p: [f64; 4]) -> Result<(Vec3, f32)> {
    let n = DVec3::new(p[0], p[1], p[2]);
    let len = n.length();
    if !(len > 1e-9 && len.is_finite() && p[3].is_finite()) {
        bail!("ground plane {p:?} has no normal");
    }
    let sign = if n.z >= 0.0 { 1.0 } else { -1.0 };
    Ok(((n * sign / len).as_vec3(), (-p[3] * sign / len) as f32))
}

/// One camera of the layout, with its timestamps.
pub struct SourceCamera {
    pub serial: String,
    pub camera: Camera,
    pub timestamps: Vec<f64>,
    pub video: PathBuf,
}

/// Read the cameras: intrinsics and timestamps from `videos/<serial>.json`, pose from `cameras.json`.
pub fn load_cameras(dir: &Path) -> Result<Vec<SourceCamera>> {
    let entries: BTreeMap<String, CameraEntry> = read_json(&dir.join("cameras.json"))?;
    let mut out = Vec::new();
    for (serial, entry) in entries {
        let meta: VideoMeta = read_json(&dir.join("videos").join(format!("{serial}.json")))?;
        let pose = optical_from_opengl(&entry.x_wc)
            .with_context(|| format!("cameras.json: camera {serial}"))?;
        let [w, h] = meta.resolution;
        let k = meta.k;
        if w == 0 || h == 0 || !(k[0][0] > 0.0 && k[1][1] > 0.0) {
            bail!("videos/{serial}.json: invalid intrinsics or resolution");
        }
        let camera = Camera::from_opencv(
            w,
            h,
            k[0][0] as f32,
            k[1][1] as f32,
            k[0][2] as f32,
            k[1][2] as f32,
            pose.inverse(),
        );
        out.push(SourceCamera {
            serial: serial.clone(),
            camera,
            timestamps: meta.timestamps,
            video: dir.join("videos").join(format!("{serial}.mp4")),
        });
    }
    if out.is_empty() {
        bail!("{}: cameras.json lists no camera", dir.display());
    }
    Ok(out)
}

/// Frames of a video decoded by the `ffmpeg` command-line tool, as packed RGB bytes, in order.
pub struct VideoFrames {
    child: std::process::Child,
    stdout: std::process::ChildStdout,
    frame_bytes: usize,
}

impl VideoFrames {
    pub fn open(path: &Path, width: u32, height: u32) -> Result<Self> {
        if !path.is_file() {
            bail!("video {} does not exist", path.display());
        }
        // Sequential decoding (B-frames, long GOP); BT.601 limited-range YUV becomes full-range RGB.
        let mut child = std::process::Command::new("ffmpeg")
            .args(["-v", "error", "-nostdin", "-i"])
            .arg(path)
            .args([
                "-f",
                "rawvideo",
                "-pix_fmt",
                "rgb24",
                "-s",
                &format!("{width}x{height}"),
                "pipe:1",
            ])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::inherit())
            .spawn()
            .context("cannot run ffmpeg (install it: apt-get install ffmpeg)")?;
        let stdout = child.stdout.take().context("ffmpeg has no stdout")?;
        Ok(Self {
            child,
            stdout,
            frame_bytes: (3 * width * height) as usize,
        })
    }

    /// The next frame, or None at the end of the video.
    pub fn next_frame(&mut self) -> Result<Option<Vec<u8>>> {
        let mut buf = vec![0u8; self.frame_bytes];
        let mut filled = 0;
        while filled < buf.len() {
            let n = self.stdout.read(&mut buf[filled..])?;
            if n == 0 {
                break;
            }
            filled += n;
        }
        match filled {
            0 => Ok(None),
            n if n == buf.len() => Ok(Some(buf)),
            n => bail!("video ended inside a frame ({n} of {} bytes)", buf.len()),
        }
    }
}

impl Drop for VideoFrames {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Name of a camera in pegs recordings (ROS names may not start with a digit).
pub fn camera_name(serial: &str) -> String {
    format!("camera_{serial}")
}

#[derive(Clone, Debug)]
pub struct ImportOptions {
    /// Seconds after the first frame to start at, and how long to import (all when None).
    pub start: f64,
    pub duration: Option<f64>,
    /// Frames closer than `1 / max_rate` to the last kept one are skipped (0 keeps all).
    pub max_rate: f64,
    pub progress: bool,
}

impl Default for ImportOptions {
    fn default() -> Self {
        Self {
            start: 0.0,
            duration: None,
            max_rate: 30.0,
            progress: true,
        }
    }
}

/// What an import wrote.
#[derive(Debug)]
pub struct ImportReport {
    pub frames_per_camera: BTreeMap<String, usize>,
    pub first_stamp: f64,
    pub last_stamp: f64,
    pub warnings: Vec<String>,
}

/// The HSV band of the saturated orange of the sample data's T-block.
pub fn orange_mask() -> ColourMask {
    ColourMask {
        hue_min: 0.0,
        hue_max: 30.0,
        saturation_min: 0.55,
        value_min: 0.35,
    }
}

/// Convert the layout in `dir` into a recording (images, camera info, /tf_static) and a replay
/// configuration: every `*.json` object file in `dir` (except the camera files) becomes an object
/// aligned at the start by `mask`, the ground plane comes from `ground_plane.json`, and a table
/// fitted to the first frames covers the extent of `ground.npy`.
pub fn import(
    dir: &Path,
    recording: &Path,
    config_out: &Path,
    opts: &ImportOptions,
) -> Result<ImportReport> {
    let cameras = load_cameras(dir)?;
    let dir_abs = dir
        .canonicalize()
        .with_context(|| format!("cannot resolve {}", dir.display()))?;
    let mut report = ImportReport {
        frames_per_camera: BTreeMap::new(),
        first_stamp: f64::INFINITY,
        last_stamp: f64::NEG_INFINITY,
        warnings: Vec::new(),
    };
    let t0 = cameras
        .iter()
        .filter_map(|c| c.timestamps.first().copied())
        .fold(f64::INFINITY, f64::min);
    if !t0.is_finite() {
        bail!("no camera has timestamps");
    }
    let (from, to) = (
        t0 + opts.start,
        opts.duration.map_or(f64::INFINITY, |d| t0 + opts.start + d),
    );
    let mut rec = RecordingWriter::create(recording)?;
    let named: Vec<(String, Camera)> = cameras
        .iter()
        .map(|c| (camera_name(&c.serial), c.camera))
        .collect();
    rec.write(
        record::TF_STATIC,
        msgs::schema::tf_message(),
        Time::from_seconds(from),
        &record::optical_frames_tf(&named),
    )?;
    let total: usize = cameras
        .iter()
        .map(|c| {
            c.timestamps
                .iter()
                .filter(|t| (from..=to).contains(*t))
                .count()
        })
        .sum();
    let progress = if opts.progress {
        indicatif::ProgressBar::new(total as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    // The cameras' frames interleaved in stamp order, as a rig's recorder logs them: a replay
    // streams the bag in file order and would otherwise meet one camera's whole recording first.
    let span = (from, to, opts.max_rate);
    let mut imports = cameras
        .iter()
        .map(CameraImport::open)
        .collect::<Result<Vec<_>>>()?;
    while let Some(next) = imports
        .iter_mut()
        .filter_map(|i| i.next_stamp(to).map(|t| (t, i)))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, i)| i)
    {
        next.step(&mut rec, span, &mut report, &progress)?;
    }
    for i in imports {
        i.finish(&mut report)?;
    }
    progress.finish_and_clear();
    rec.finish()?;
    let config = import_config(&dir_abs)?;
    std::fs::write(config_out, config.to_yaml()?)
        .with_context(|| format!("cannot write {}", config_out.display()))?;
    Ok(report)
}

/// One camera's frames on their way into the recording: those stamped within `(from, to)`, at
/// most `max_rate` per second (its CameraInfo once, before its first image).
struct CameraImport<'a> {
    c: &'a SourceCamera,
    name: String,
    frame_id: String,
    video: VideoFrames,
    /// Index of the next timestamp; `None` once the video or the span has ended.
    next: Option<usize>,
    last_kept: f64,
    kept: usize,
    decoded: usize,
}

impl<'a> CameraImport<'a> {
    fn open(c: &'a SourceCamera) -> Result<Self> {
        let name = camera_name(&c.serial);
        Ok(Self {
            c,
            frame_id: record::optical_frame(&name),
            name,
            video: VideoFrames::open(&c.video, c.camera.width, c.camera.height)?,
            next: Some(0),
            last_kept: f64::NEG_INFINITY,
            kept: 0,
            decoded: 0,
        })
    }

    /// The stamp of the next frame, unless the camera is done or past `to`.
    fn next_stamp(&self, to: f64) -> Option<f64> {
        let t = *self.c.timestamps.get(self.next?)?;
        (t <= to).then_some(t)
    }

    /// Decode the next frame and write it if it is kept.
    fn step(
        &mut self,
        rec: &mut RecordingWriter,
        (from, _, max_rate): (f64, f64, f64),
        report: &mut ImportReport,
        progress: &indicatif::ProgressBar,
    ) -> Result<()> {
        let (Some(k), c) = (self.next, self.c) else {
            return Ok(());
        };
        let t = c.timestamps[k];
        let Some(frame) = self
            .video
            .next_frame()
            .with_context(|| format!("decoding {}", c.video.display()))?
        else {
            report.warnings.push(format!(
                "{}: video has {k} frames, its JSON {} timestamps",
                c.serial,
                c.timestamps.len()
            ));
            self.next = None;
            return Ok(());
        };
        self.decoded += 1;
        self.next = Some(k + 1);
        if t < from
            || !t.is_finite()
            || (max_rate > 0.0 && t - self.last_kept < 1.0 / max_rate - 1e-3)
        {
            return Ok(());
        }
        if self.kept == 0 {
            let info = record::camera_info(&c.camera, t, &self.frame_id);
            rec.camera_info(&record::info_topic(&self.name), &info)?;
        }
        let image = record::rgb8(c.camera.width, c.camera.height, frame, t, &self.frame_id);
        rec.image(&record::image_topic(&self.name), &image)?;
        self.last_kept = t;
        self.kept += 1;
        report.first_stamp = report.first_stamp.min(t);
        report.last_stamp = report.last_stamp.max(t);
        progress.inc(1);
        Ok(())
    }

    fn finish(mut self, report: &mut ImportReport) -> Result<()> {
        let c = self.c;
        if self.decoded == c.timestamps.len() && self.video.next_frame()?.is_some() {
            report.warnings.push(format!(
                "{}: the video has more frames than its {} timestamps; the extra ones are dropped",
                c.serial,
                c.timestamps.len()
            ));
        }
        report.frames_per_camera.insert(self.name, self.kept);
        Ok(())
    }
}

/// The replay configuration for the layout in `dir`.
pub fn import_config(dir: &Path) -> Result<Config> {
    let mut config = Config::default();
    let plane: PlaneFile = read_json(&dir.join("ground_plane.json"))?;
    let (normal, height) = ground_from_plane(plane.plane)?;
    config.physics.ground.normal = normal;
    config.physics.ground.height = height;
    let mut objects = Vec::new();
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    for path in files {
        let stem = path
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or_default();
        if matches!(stem, "cameras" | "extrinsics" | "ground_plane") {
            continue;
        }
        let object = load_object(&path)?;
        objects.push(ObjectConfig {
            name: object.name,
            embodied_gaussians: path.clone(),
            mask: Some(orange_mask()),
            mass: 0.5,
            ..Default::default()
        });
    }
    if objects.is_empty() {
        bail!("{}: no object file", dir.display());
    }
    config.scene.objects = objects;
    let ground = dir.join("ground.npy");
    if ground.is_file() {
        let points = read_npy_points(&ground)?;
        let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
        for p in &points {
            lo = lo.min(p.truncate());
            hi = hi.max(p.truncate());
        }
        config.scene.table = Some(TableConfig {
            min: lo,
            max: hi,
            ..Default::default()
        });
    }
    // The arm is not modelled (no joint trajectory in the source): pixels that neither the
    // objects nor the table explain are occluders, left out of the photometric loss. Its pushes
    // reach the block only through visual forces, which real images make noisy: a strongly damped
    // model (half its velocity kept a tick) follows them without being thrown about (with the
    // default damping, noise threw the block 1-3 cm off the table). The visual forces' gain grows
    // by itself for a model that damped (`correct::plant`); the visual-force settings are the
    // defaults. The third camera mostly looks past the arm. The block's mass and friction are not
    // in the source: 0.5 kg (visual inertia and weight against vertical noise) on friction 0.2 /
    // 0.15 (the same visual force still slides it) keep it on the table.
    config.physics.ground.static_friction = 0.2;
    config.physics.ground.kinetic_friction = 0.15;
    config.correct.occluder_threshold = 0.35;
    config.physics.damping = 0.5;
    Ok(config)
}

/// Points from a `.npy` file holding a little-endian float64 array of shape (N, 3), C order.
pub fn read_npy_points(path: &Path) -> Result<Vec<Vec3>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let bad = || format!("{} is not a float64 (N, 3) .npy array", path.display());
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        bail!(bad());
    }
    // Version 1 has a 2-byte header length, versions 2 and 3 a 4-byte one.
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => bail!(bad()),
    };
    let header = std::str::from_utf8(bytes.get(start..start + header_len).with_context(bad)?)
        .with_context(bad)?;
    let compact: String = header.chars().filter(|c| !c.is_whitespace()).collect();
    if !compact.contains("'descr':'<f8'") || !compact.contains("'fortran_order':False") {
        bail!(
            "{}: only little-endian float64 in C order is supported ({header})",
            bad()
        );
    }
    let data = &bytes[start + header_len..];
    if data.len() % 24 != 0 || !compact.contains(&format!("'shape':({},3)", data.len() / 24)) {
        bail!(
            "{}: shape is not ({}, 3) ({header})",
            bad(),
            data.len() / 24
        );
    }
    Ok(data
        .chunks_exact(24)
        .map(|c| {
            Vec3::from_array(std::array::from_fn(|k| {
                f64::from_le_bytes(c[8 * k..8 * k + 8].try_into().unwrap_or_default()) as f32
            }))
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init::object_file::{quat_from_wxyz, rgb_from_bgr};

    #[test]
    fn opengl_camera_becomes_an_optical_frame_looking_along_its_minus_z() {
        // An OpenGL camera at (1, 2, 3) looking down the world -z axis with +y up in the image.
        let gl = [
            [1.0, 0.0, 0.0, 1.0],
            [0.0, 1.0, 0.0, 2.0],
            [0.0, 0.0, 1.0, 3.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let optical = optical_from_opengl(&gl).unwrap();
        assert!((optical.translation - Vec3::new(1.0, 2.0, 3.0)).length() < 1e-6);
        // Optical z (forward) is world -z, optical y (image down) is world -y.
        assert!((optical.rotation * Vec3::Z - Vec3::NEG_Z).length() < 1e-6);
        assert!((optical.rotation * Vec3::Y - Vec3::NEG_Y).length() < 1e-6);
        assert!((optical.rotation * Vec3::X - Vec3::X).length() < 1e-6);
        let cam = Camera::from_opencv(100, 80, 50.0, 50.0, 49.5, 39.5, optical.inverse());
        // A point below the camera lands in the image centre; one further along world +y lands higher.
        let (u, v, z) = cam.project(Vec3::new(1.0, 2.0, 2.0));
        assert!((u - 50.0).abs() < 1e-4 && (v - 40.0).abs() < 1e-4 && (z - 1.0).abs() < 1e-6);
        assert!(cam.project(Vec3::new(1.0, 2.1, 2.0)).1 < 40.0);
    }

    #[test]
    fn quaternions_colours_and_planes_convert_to_ros_conventions() {
        let q = quat_from_wxyz([0.0, 0.0, 0.0, 1.0]);
        assert!(
            (q * Vec3::X - Vec3::NEG_X).length() < 1e-6,
            "w,x,y,z = 0,0,0,1 is a half turn about z"
        );
        assert_eq!(rgb_from_bgr([0.1, 0.2, 0.9]), Vec3::new(0.9, 0.2, 0.1));
        let (n, h) = ground_from_plane([0.0, 0.0, -2.0, 0.02]).unwrap();
        assert!(
            (n - Vec3::Z).length() < 1e-6 && (h - 0.01).abs() < 1e-7,
            "{n} {h}: the plane z = 0.01, normal up"
        );
        assert!(ground_from_plane([0.0, 0.0, 0.0, 1.0]).is_err());
        assert!(
            pose_from_rows(&[
                [2.0, 0.0, 0.0, 0.0],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0]
            ])
            .is_err(),
            "scaled matrices are rejected"
        );
    }

    #[test]
    fn npy_points_are_read_and_other_arrays_rejected() {
        let dir = std::env::temp_dir().join(format!("pegs-npy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let write = |name: &str, descr: &str, rows: usize| {
            let mut header =
                format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': ({rows}, 3), }}");
            while (10 + header.len() + 1) % 64 != 0 {
                header.push(' ');
            }
            header.push('\n');
            let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
            bytes.extend((header.len() as u16).to_le_bytes());
            bytes.extend(header.as_bytes());
            for k in 0..rows * 3 {
                bytes.extend((k as f64 * 0.5).to_le_bytes());
            }
            let p = dir.join(name);
            std::fs::write(&p, bytes).unwrap();
            p
        };
        let points = read_npy_points(&write("ok.npy", "<f8", 2)).unwrap();
        assert_eq!(
            points,
            vec![Vec3::new(0.0, 0.5, 1.0), Vec3::new(1.5, 2.0, 2.5)]
        );
        assert!(read_npy_points(&write("f4.npy", "<f4", 2)).is_err());
        std::fs::write(dir.join("junk.npy"), b"hello").unwrap();
        assert!(read_npy_points(&dir.join("junk.npy")).is_err());
    }
}

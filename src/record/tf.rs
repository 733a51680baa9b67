//! The tf tree: frames linked child -> parent by `/tf_static` (fixed) and `/tf` (stamped) transforms,
//! resolved as chains, so a camera's optical frame is found in the world however many frames lie
//! between (realsense2_camera publishes `cam_link -> cam_color_frame -> cam_color_optical_frame`;
//! the user publishes `world -> cam_link`). Owns no messages and no clock: it keeps transforms and
//! answers lookups. Invalid transforms are refused with the reason, never stored.

use crate::math::Pose;
use crate::msgs::{TfMessage, TransformStamped};
use glam::{Quat, Vec3};
use std::collections::BTreeMap;

/// A stamped transform is used this far (s) beyond the first or last one of its edge; further
/// out the lookup fails instead of extrapolating.
pub const MAX_EXTRAPOLATION_S: f64 = 0.1;

/// How a frame is attached to its parent.
#[derive(Clone, Debug)]
enum Edge {
    Fixed(Pose),
    /// `(stamp, parent_from_child)` sorted by stamp.
    Stamped(Vec<(f64, Pose)>),
}

#[derive(Clone, Debug, Default)]
pub struct TfTree {
    /// child frame -> (parent frame, parent_from_child).
    edges: BTreeMap<String, (String, Edge)>,
}

impl TfTree {
    /// Store every valid transform of `msg` (from `/tf_static` when `fixed`, else `/tf`); the
    /// refused ones come back with the reason.
    pub fn add(&mut self, msg: &TfMessage, fixed: bool) -> Vec<String> {
        let mut refused = Vec::new();
        for t in &msg.transforms {
            match pose_from_transform(t) {
                Ok(pose) => self.add_pose(t, pose, fixed),
                Err(why) => refused.push(format!(
                    "{} {} -> {}: {why}; ignored",
                    if fixed { "/tf_static" } else { "/tf" },
                    t.header.frame_id,
                    t.child_frame_id
                )),
            }
        }
        refused
    }

    fn add_pose(&mut self, t: &TransformStamped, pose: Pose, fixed: bool) {
        let parent = t.header.frame_id.trim_start_matches('/').to_string();
        let child = t.child_frame_id.trim_start_matches('/').to_string();
        if fixed {
            self.edges.insert(child, (parent, Edge::Fixed(pose)));
            return;
        }
        let stamp = t.header.stamp.seconds();
        let entry = self
            .edges
            .entry(child)
            .or_insert_with(|| (parent.clone(), Edge::Stamped(Vec::new())));
        match &mut entry.1 {
            // A frame published on both: /tf_static wins, as in tf2.
            Edge::Fixed(_) => {}
            Edge::Stamped(samples) => {
                entry.0 = parent;
                let at = samples.partition_point(|s| s.0 <= stamp);
                samples.insert(at, (stamp, pose));
            }
        }
    }

    /// The frames from `root` down to `frame` (both included), or why there is no such chain.
    pub fn chain(&self, root: &str, frame: &str) -> Result<Vec<String>, String> {
        let (root, frame) = (root.trim_start_matches('/'), frame.trim_start_matches('/'));
        let mut frames = vec![frame.to_string()];
        let mut at = frame;
        while at != root {
            let Some((parent, _)) = self.edges.get(at) else {
                let known = if frames.len() == 1 {
                    format!("no transform has child frame '{frame}'")
                } else {
                    format!("'{at}' has no parent (reached from '{frame}')")
                };
                return Err(format!("no tf chain from '{root}' to '{frame}': {known}"));
            };
            if frames.len() > self.edges.len() {
                return Err(format!("the tf frames above '{frame}' form a loop"));
            }
            frames.push(parent.clone());
            at = parent;
        }
        frames.reverse();
        Ok(frames)
    }

    /// Whether every link of the chain from `root` to `frame` is fixed (false when there is none).
    pub fn is_fixed(&self, root: &str, frame: &str) -> bool {
        self.chain(root, frame).is_ok_and(|frames| {
            frames[1..]
                .iter()
                .all(|f| matches!(self.edges.get(f), Some((_, Edge::Fixed(_)))))
        })
    }

    /// Whether `child` is attached to a parent.
    pub fn has_edge(&self, child: &str) -> bool {
        self.edges.contains_key(child.trim_start_matches('/'))
    }

    /// Forget stamped samples older than `t` (s), keeping the last one before it, so a tree fed
    /// a long `/tf` stream stays small.
    pub fn forget_before(&mut self, t: f64) {
        for (_, edge) in self.edges.values_mut() {
            if let Edge::Stamped(samples) = edge {
                let keep_from = samples.partition_point(|s| s.0 < t).saturating_sub(1);
                samples.drain(..keep_from);
            }
        }
    }

    /// `root_from_frame` at time `t` (s): the chain's transforms composed, stamped ones
    /// interpolated at `t`.
    pub fn lookup(&self, root: &str, frame: &str, t: f64) -> Result<Pose, String> {
        self.lookup_with(root, frame, t, false)
    }

    /// As `lookup`, but a stamped link far from `t` gives its nearest sample instead of failing
    /// (a start pose from a survey that kept one sample per link).
    pub fn lookup_nearest(&self, root: &str, frame: &str, t: f64) -> Result<Pose, String> {
        self.lookup_with(root, frame, t, true)
    }

    fn lookup_with(&self, root: &str, frame: &str, t: f64, nearest: bool) -> Result<Pose, String> {
        let frames = self.chain(root, frame)?;
        let mut root_from = Pose::IDENTITY;
        for child in &frames[1..] {
            let Some((parent, edge)) = self.edges.get(child) else {
                return Err(format!("tf frame '{child}' vanished"));
            };
            let parent_from_child = match edge {
                Edge::Fixed(p) => *p,
                Edge::Stamped(samples) => sample_at(samples, t)
                    .or_else(|| nearest.then(|| nearest_sample(samples, t)).flatten())
                    .ok_or_else(|| format!("no /tf {parent} -> {child} near {t:.3} s"))?,
            };
            root_from = root_from.mul(&parent_from_child);
        }
        Ok(root_from)
    }
}

/// The stamped pose at `t`, interpolated between its neighbours; the nearest end within
/// `MAX_EXTRAPOLATION_S` outside them.
fn sample_at(samples: &[(f64, Pose)], t: f64) -> Option<Pose> {
    let after = samples.partition_point(|s| s.0 <= t);
    match (after.checked_sub(1).map(|i| samples[i]), samples.get(after)) {
        (Some(a), Some(b)) => {
            let s = ((t - a.0) / (b.0 - a.0).max(1e-12)) as f32;
            Some(a.1.interpolate(&b.1, s))
        }
        (Some(a), None) => (t - a.0 <= MAX_EXTRAPOLATION_S).then_some(a.1),
        (None, Some(b)) => (b.0 - t <= MAX_EXTRAPOLATION_S).then_some(b.1),
        (None, None) => None,
    }
}

fn nearest_sample(samples: &[(f64, Pose)], t: f64) -> Option<Pose> {
    samples
        .iter()
        .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))
        .map(|s| s.1)
}

/// `parent_from_child` of a transform, refused when not finite or the rotation is far from a
/// unit quaternion.
fn pose_from_transform(t: &TransformStamped) -> Result<Pose, String> {
    let (p, q) = (t.transform.translation, t.transform.rotation);
    let values = [p.x, p.y, p.z, q.x, q.y, q.z, q.w];
    if values.iter().any(|v| !v.is_finite()) {
        return Err("not finite".into());
    }
    let norm = (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w).sqrt();
    if !(0.5..2.0).contains(&norm) {
        return Err(format!(
            "rotation is not a unit quaternion (norm {norm:.3})"
        ));
    }
    if t.child_frame_id.is_empty() || t.header.frame_id.is_empty() {
        return Err("a frame name is empty".into());
    }
    Ok(Pose::new(
        Vec3::new(p.x as f32, p.y as f32, p.z as f32),
        Quat::from_xyzw(q.x as f32, q.y as f32, q.z as f32, q.w as f32).normalize(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn edge(parent: &str, child: &str, t: f64, p: Vec3, q: Quat) -> TransformStamped {
        crate::record::transform(parent, child, t, Pose::new(p, q))
    }

    /// A point expressed in the optical frame lands where composing the chain by hand puts it,
    /// for a fixed three-link chain (world -> link -> colour -> optical) and a moving wrist link.
    #[test]
    fn chained_transforms_compose_like_the_frames_they_link() {
        let q1 = Quat::from_rotation_z(0.7);
        let q2 = Quat::from_rotation_x(-0.3);
        let q3 = Quat::from_euler(
            glam::EulerRot::XYZ,
            -std::f32::consts::FRAC_PI_2,
            0.0,
            -std::f32::consts::FRAC_PI_2,
        );
        let mut tf = TfTree::default();
        let links = TfMessage {
            transforms: vec![
                edge(
                    "cam_link",
                    "cam_color_frame",
                    0.0,
                    Vec3::new(0.0, 0.015, 0.0),
                    q2,
                ),
                edge(
                    "cam_color_frame",
                    "cam_color_optical_frame",
                    0.0,
                    Vec3::ZERO,
                    q3,
                ),
            ],
        };
        assert!(tf.add(&links, true).is_empty());
        assert!(tf.lookup("world", "cam_color_optical_frame", 0.0).is_err());
        let user = TfMessage {
            transforms: vec![edge(
                "world",
                "cam_link",
                0.0,
                Vec3::new(0.5, -0.4, 0.6),
                q1,
            )],
        };
        tf.add(&user, true);
        let pose = tf.lookup("world", "cam_color_optical_frame", 3.0).unwrap();
        let p = Vec3::new(0.1, 0.2, 0.9);
        let by_hand = q1 * (q2 * (q3 * p) + Vec3::new(0.0, 0.015, 0.0)) + Vec3::new(0.5, -0.4, 0.6);
        assert!((pose.transform_point(p) - by_hand).length() < 1e-5);
        assert!(tf.is_fixed("world", "cam_color_optical_frame"));
        assert_eq!(
            tf.chain("world", "cam_color_optical_frame").unwrap().len(),
            4
        );
        // A wrist link moving along x at 1 m/s: looked up between two stamps, it interpolates.
        let mut wrist = TfTree::default();
        for k in 0..3 {
            let m = TfMessage {
                transforms: vec![edge(
                    "world",
                    "hand",
                    k as f64,
                    Vec3::new(k as f32, 0.0, 0.0),
                    Quat::IDENTITY,
                )],
            };
            wrist.add(&m, false);
        }
        let at = wrist.lookup("world", "hand", 1.25).unwrap();
        assert!((at.translation.x - 1.25).abs() < 1e-6);
        assert!(!wrist.is_fixed("world", "hand"));
        assert!(wrist.lookup("world", "hand", 2.05).is_ok());
        let late = wrist.lookup("world", "hand", 2.5).unwrap_err();
        assert!(late.contains("near 2.500 s"), "{late}");
    }

    #[test]
    fn broken_chains_and_invalid_transforms_are_named() {
        let mut tf = TfTree::default();
        let bad = TfMessage {
            transforms: vec![
                edge(
                    "world",
                    "a",
                    0.0,
                    Vec3::new(f32::NAN, 0.0, 0.0),
                    Quat::IDENTITY,
                ),
                edge(
                    "b",
                    "c",
                    0.0,
                    Vec3::ZERO,
                    Quat::from_xyzw(0.0, 0.0, 0.0, 0.0),
                ),
            ],
        };
        let refused = tf.add(&bad, true);
        assert_eq!(refused.len(), 2, "{refused:?}");
        assert!(refused[1].contains("unit quaternion"));
        let ok = TfMessage {
            transforms: vec![edge("b", "c", 0.0, Vec3::ZERO, Quat::IDENTITY)],
        };
        tf.add(&ok, true);
        let e = tf.lookup("world", "c", 0.0).unwrap_err();
        assert!(e.contains("'b' has no parent"), "{e}");
        let e = tf.lookup("world", "x", 0.0).unwrap_err();
        assert!(e.contains("no transform has child frame 'x'"), "{e}");
    }
}

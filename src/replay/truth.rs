//! Tracking error against ground truth, as an observer of a replay's ticks: `ground_truth.csv`
//! (object poses) and `ground_truth_particles.csv` (deformable objects' particles) beside a
//! recording (or beside the rosbag2 directory that holds it). A rigid object's error is the mean
//! distance of its particles from where the true pose puts them; a deformable one's, of particle k
//! from true particle k. Objects built from RGB-D have a body frame of their own: their error is
//! measured after registering it to the true body frame at the start (so it is the drift of the
//! tracking), and up to the turns about the vertical that leave its shape as it was (a cylinder's
//! any turn, a box's half turn): such a turn cannot be seen, so the images cannot correct it and
//! it is no tracking error (`symmetric_turns`).

use super::ErrorStats;
use crate::math::Pose;
use crate::tracker::{Observer, Tick, Tracker};
use anyhow::{Context, Result, bail};
use glam::{Quat, Vec3};
use std::collections::BTreeMap;
use std::path::Path;

/// Per-tick tracking error per object: `(t, metres)`.
pub type ErrorSeries = BTreeMap<String, Vec<(f64, f32)>>;

pub struct TruthError {
    poses: BTreeMap<String, Vec<(f64, Pose)>>,
    particles: ParticleTruth,
    /// Objects built from RGB-D: the true body frame's pose in the tracked body frame.
    registered: Vec<String>,
    registration: BTreeMap<String, Pose>,
    /// Registered objects: the body-frame turns that leave their shape as it was (identity first).
    symmetries: BTreeMap<String, Vec<Pose>>,
    pub series: ErrorSeries,
}

impl TruthError {
    /// The ground truth beside `recording`, if there is any; `registered`: objects whose body
    /// frame is their own (built from RGB-D).
    pub fn beside(recording: &Path, registered: Vec<String>) -> Result<Option<Self>> {
        let Some(path) = file_beside(recording, "ground_truth.csv") else {
            return Ok(None);
        };
        Ok(Some(Self {
            poses: read_ground_truth(&path)?,
            particles: match file_beside(recording, "ground_truth_particles.csv") {
                Some(particles) => read_ground_truth_particles(&particles)?,
                None => ParticleTruth::new(),
            },
            registered,
            registration: BTreeMap::new(),
            symmetries: BTreeMap::new(),
            series: ErrorSeries::new(),
        }))
    }

    /// Mean, 95th percentile and last error per object, and `tracking_error.csv`.
    pub fn finish(&self, out: &Path) -> Result<BTreeMap<String, ErrorStats>> {
        if !self.series.is_empty() {
            let mut csv = String::from("t,object,error_mm\n");
            for (object, series) in &self.series {
                for (t, e) in series {
                    csv += &format!("{t:.6},{object},{:.4}\n", e * 1e3);
                }
            }
            let path = out.join("tracking_error.csv");
            std::fs::write(&path, csv)
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
        Ok(self
            .series
            .iter()
            .map(|(k, v)| (k.clone(), stats(&v.iter().map(|e| e.1).collect::<Vec<_>>())))
            .collect())
    }
}

impl Observer for TruthError {
    fn start(&mut self, tracker: &Tracker) -> Result<()> {
        let world = tracker.world();
        for name in &self.registered {
            if let (Some(track), Some(s)) = (self.poses.get(name), world.shape_id(name))
                && let Some((_, first)) = track.first()
            {
                let pose = world.shapes.pose[s as usize];
                let registration = first.inverse().mul(&pose);
                self.registration.insert(name.clone(), registration);
                let rest: Vec<Vec3> = world
                    .shapes
                    .range(s)
                    .map(|i| world.particles.rest[i])
                    .collect();
                let vertical = pose.rotation.inverse() * Vec3::Z;
                self.symmetries
                    .insert(name.clone(), symmetric_turns(&rest, vertical));
            }
        }
        Ok(())
    }

    fn tick(&mut self, tick: &Tick) -> Result<()> {
        let (w, t) = (tick.tracker.world(), tick.inputs.time);
        for s in w.shapes.dynamic_ids() {
            let name = &w.shapes.name[s as usize];
            let range = w.shapes.range(s);
            if let Some(track) = self.particles.get(name) {
                // Deformable: particle k against the true particle k.
                let points = &track[at(track, t)].1;
                if points.len() == range.len() {
                    let e = range
                        .zip(points)
                        .map(|(p, q)| w.particles.position[p].distance(*q))
                        .sum::<f32>()
                        / points.len() as f32;
                    self.series.entry(name.clone()).or_default().push((t, e));
                }
                continue;
            }
            let Some(track) = self.poses.get(name) else {
                continue;
            };
            let truth = track[at(track, t)].1;
            let pose = match self.registration.get(name) {
                Some(x) => truth.mul(x),
                None => truth,
            };
            let n = range.len() as f32;
            let identity = [Pose::default()];
            let turns = self.symmetries.get(name).map_or(&identity[..], |v| &v[..]);
            let e = turns
                .iter()
                .map(|turn| {
                    let pose = pose.mul(turn);
                    range
                        .clone()
                        .map(|p| {
                            pose.transform_point(w.particles.rest[p])
                                .distance(w.particles.position[p])
                        })
                        .sum::<f32>()
                        / n
                })
                .fold(f32::INFINITY, f32::min);
            self.series.entry(name.clone()).or_default().push((t, e));
        }
        Ok(())
    }
}

/// Turns (body frame, about `axis` through the points' centroid, every 5 degrees) under which
/// `points` stay where the shape was: at least `SYMMETRY_SHARE` of them land within the points'
/// spacing of one of the points (the model's resolution), or every turn where every turn keeps
/// `ROUND_SHARE` of them (a round shape with a jagged outline). The identity comes first.
pub fn symmetric_turns(points: &[Vec3], axis: Vec3) -> Vec<Pose> {
    let identity = vec![Pose::default()];
    if points.len() < 2 || axis.length_squared() == 0.0 {
        return identity;
    }
    let axis = axis.normalize();
    let centroid = points.iter().sum::<Vec3>() / points.len() as f32;
    // The points' spacing: the median distance to their nearest neighbour (a sample suffices).
    let mut nearest: Vec<f32> = points
        .iter()
        .step_by(points.len().div_ceil(200))
        .map(|p| {
            points
                .iter()
                .map(|q| p.distance(*q))
                .filter(|d| *d > 1e-6)
                .fold(f32::INFINITY, f32::min)
        })
        .collect();
    nearest.sort_by(f32::total_cmp);
    let spacing = nearest[nearest.len() / 2];
    if !spacing.is_finite() {
        return identity;
    }
    let cell = |p: Vec3| (p / spacing).floor().as_ivec3();
    let mut grid: std::collections::HashMap<glam::IVec3, Vec<Vec3>> = Default::default();
    for p in points {
        grid.entry(cell(*p)).or_default().push(*p);
    }
    let near_shape = |q: Vec3| {
        let c = cell(q);
        (-1..=1).any(|i| {
            (-1..=1).any(|j| {
                (-1..=1).any(|k| {
                    grid.get(&(c + glam::IVec3::new(i, j, k)))
                        .is_some_and(|v| v.iter().any(|p| p.distance(q) <= spacing))
                })
            })
        })
    };
    // The share of the points each turn (every 5 degrees) keeps within the shape.
    let kept: Vec<(Pose, f32)> = (5..360)
        .step_by(5)
        .map(|degrees| {
            let turn = Quat::from_axis_angle(axis, (degrees as f32).to_radians());
            let pose = Pose::new(centroid - turn * centroid, turn);
            let kept = points
                .iter()
                .filter(|p| near_shape(pose.transform_point(**p)))
                .count();
            (pose, kept as f32 / points.len() as f32)
        })
        .collect();
    let round = kept.iter().all(|(_, share)| *share >= ROUND_SHARE);
    let mut turns = identity;
    turns.extend(
        kept.into_iter()
            .filter(|(_, share)| round || *share >= SYMMETRY_SHARE)
            .map(|(pose, _)| pose),
    );
    turns
}

/// Share of an object's points a turn must keep within the shape to leave it as it was.
const SYMMETRY_SHARE: f32 = 0.99;

/// Share of its points an object must keep under every turn to be round, every turn unseen. The
/// outline of an object built from depth and masks is jagged at its particle spacing (the
/// cameras' silhouettes carve a polygon around a cylinder), so a turn of a round one keeps 95 to
/// 99 % of its points and `SYMMETRY_SHARE` missed most of its turns; a box or bar keeps 91 % or
/// less at its worst turn (MuJoCo's cylinders, boxes and bars, built by `init::rgbd`).
const ROUND_SHARE: f32 = 0.93;

/// The index of the first sample at or after `t` (the last one past the end).
fn at<T>(track: &[(f64, T)], t: f64) -> usize {
    track
        .partition_point(|(ts, _)| *ts < t - 1e-6)
        .min(track.len() - 1)
}

/// Mean, 95th percentile and last of per-tick errors in metres, reported in mm.
pub fn stats(errors: &[f32]) -> ErrorStats {
    if errors.is_empty() {
        return ErrorStats::default();
    }
    let mut sorted = errors.to_vec();
    sorted.sort_by(f32::total_cmp);
    let p95 = sorted[((sorted.len() as f32 * 0.95).ceil() as usize).clamp(1, sorted.len()) - 1];
    ErrorStats {
        mean_mm: errors.iter().sum::<f32>() / errors.len() as f32 * 1e3,
        p95_mm: p95 * 1e3,
        final_mm: errors[errors.len() - 1] * 1e3,
    }
}

/// `name` beside the recording file, or beside the rosbag2 directory that holds it.
fn file_beside(recording: &Path, name: &str) -> Option<std::path::PathBuf> {
    let here = recording.with_file_name(name);
    if here.is_file() {
        return Some(here);
    }
    let bag = recording.parent()?;
    let up = bag.with_file_name(name);
    (bag.join("metadata.yaml").is_file() && up.is_file()).then_some(up)
}

/// Ground-truth poses per object: time-ordered `(t, pose)`.
fn read_ground_truth(path: &Path) -> Result<BTreeMap<String, Vec<(f64, Pose)>>> {
    let text = std::fs::read_to_string(path)?;
    let mut out: BTreeMap<String, Vec<(f64, Pose)>> = BTreeMap::new();
    for (n, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 9 {
            bail!("{}:{}: expected 9 fields", path.display(), n + 1);
        }
        let v: Vec<f32> = f[2..]
            .iter()
            .map(|x| x.parse::<f32>())
            .collect::<std::result::Result<_, _>>()
            .with_context(|| format!("{}:{}", path.display(), n + 1))?;
        let t: f64 = f[0]
            .parse()
            .with_context(|| format!("{}:{}", path.display(), n + 1))?;
        out.entry(f[1].to_string()).or_default().push((
            t,
            Pose::new(
                Vec3::new(v[0], v[1], v[2]),
                Quat::from_xyzw(v[3], v[4], v[5], v[6]).normalize(),
            ),
        ));
    }
    Ok(out)
}

/// Ground-truth particle positions of deformable objects: object -> time-ordered `(t, positions)`.
type ParticleTruth = BTreeMap<String, Vec<(f64, Vec<Vec3>)>>;

fn read_ground_truth_particles(path: &Path) -> Result<ParticleTruth> {
    let text = std::fs::read_to_string(path)?;
    let mut out: ParticleTruth = BTreeMap::new();
    for (n, line) in text.lines().enumerate().skip(1) {
        let at = || format!("{}:{}", path.display(), n + 1);
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 6 {
            bail!("{}: expected 6 fields", at());
        }
        let t: f64 = f[0].parse().with_context(at)?;
        let k: usize = f[2].parse().with_context(at)?;
        let v: Vec<f32> = f[3..]
            .iter()
            .map(|x| x.parse::<f32>())
            .collect::<std::result::Result<_, _>>()
            .with_context(at)?;
        let track = out.entry(f[1].to_string()).or_default();
        if track.last().is_none_or(|(tl, _)| *tl != t) {
            track.push((t, Vec::new()));
        }
        let Some((_, points)) = track.last_mut() else {
            continue;
        };
        if k != points.len() {
            bail!("{}: particle {k} out of order", at());
        }
        points.push(Vec3::new(v[0], v[1], v[2]));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on a 5 mm lattice inside `inside` (a 20 cm cube around the origin).
    fn lattice(inside: impl Fn(Vec3) -> bool) -> Vec<Vec3> {
        let mut points = Vec::new();
        for i in -20..=20 {
            for j in -20..=20 {
                for k in -3..=3 {
                    let p = Vec3::new(i as f32, j as f32, k as f32) * 0.005;
                    if inside(p) {
                        points.push(p);
                    }
                }
            }
        }
        points
    }

    fn degrees(turns: &[Pose]) -> Vec<f32> {
        turns
            .iter()
            .map(|t| crate::math::rotation_angle_between(Quat::IDENTITY, t.rotation).to_degrees())
            .collect()
    }

    /// A cylinder looks the same turned any way about its axis, a box only after a half turn, a
    /// T-block never: those turns, and only those, are not tracking errors.
    #[test]
    fn only_turns_that_leave_the_shape_as_it_was_are_unseen() {
        let cylinder = lattice(|p| p.x.hypot(p.y) <= 0.04);
        let turns = degrees(&symmetric_turns(&cylinder, Vec3::Z));
        assert!(turns.len() > 60, "{turns:?}");
        let offset = Vec3::new(0.3, -0.1, 0.0);
        let box_ = lattice(|p| p.x.abs() <= 0.045 && p.y.abs() <= 0.03);
        let moved: Vec<Vec3> = box_.iter().map(|p| *p + offset).collect();
        let turns = degrees(&symmetric_turns(&moved, Vec3::Z));
        assert!(turns.iter().any(|d| (d - 180.0).abs() < 1.0), "{turns:?}");
        assert!(
            turns.iter().all(|d| *d < 6.0 || (d - 180.0).abs() < 6.0),
            "{turns:?}"
        );
        // The half turn is about the box's centre, wherever its body frame is.
        let half = symmetric_turns(&moved, Vec3::Z)
            .into_iter()
            .find(|t| crate::math::rotation_angle_between(Quat::IDENTITY, t.rotation) > 3.0)
            .unwrap();
        assert!(half.transform_point(offset).distance(offset) < 1e-4);
        let tblock = lattice(|p| {
            (p.y > 0.02 && p.y <= 0.045 && p.x.abs() <= 0.09)
                || (p.y <= 0.02 && p.y > -0.1 && p.x.abs() <= 0.0125)
        });
        let turns = degrees(&symmetric_turns(&tblock, Vec3::Z));
        assert!(turns.iter().all(|d| *d < 6.0), "{turns:?}");
    }

    /// A cylinder built from three cameras' silhouettes is the hexagon they carve around it
    /// (three strips as wide as the cylinder, 60 degrees apart) on a lattice: jagged, yet any turn
    /// leaves it as round as it was. A box of about the same size is still seen turned.
    #[test]
    fn a_cylinder_carved_by_three_silhouettes_is_unseen_turned_any_way() {
        let strips = [0.0f32, 60.0, 120.0]
            .map(|a| Vec3::new(a.to_radians().cos(), a.to_radians().sin(), 0.0));
        let carved = lattice(|p| strips.iter().all(|n| p.dot(*n).abs() <= 0.04));
        let turns = degrees(&symmetric_turns(&carved, Vec3::Z));
        assert_eq!(turns.len(), 72, "{turns:?}");
        let box_ = lattice(|p| p.x.abs() <= 0.04 && p.y.abs() <= 0.03);
        let turns = degrees(&symmetric_turns(&box_, Vec3::Z));
        assert!(
            turns.iter().all(|d| *d < 6.0 || (d - 180.0).abs() < 6.0),
            "{turns:?}"
        );
    }
}

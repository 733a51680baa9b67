//! Tracking error against ground truth, as an observer of a replay's ticks: `ground_truth.csv`
//! (object poses) and `ground_truth_particles.csv` (deformable objects' particles) beside a
//! recording (or beside the rosbag2 directory that holds it). A rigid object's error is the mean
//! distance of its particles from where the true pose puts them; a deformable one's, of particle k
//! from true particle k. Objects built from RGB-D have a body frame of their own: their error is
//! measured after registering it to the true body frame at the start (so it is the drift of the
//! tracking).

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
                let registration = first.inverse().mul(&world.shapes.pose[s as usize]);
                self.registration.insert(name.clone(), registration);
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
            let e = range
                .map(|p| {
                    pose.transform_point(w.particles.rest[p])
                        .distance(w.particles.position[p])
                })
                .sum::<f32>()
                / n;
            self.series.entry(name.clone()).or_default().push((t, e));
        }
        Ok(())
    }
}

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

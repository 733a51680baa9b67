//! Joint positions from `sensor_msgs/JointState`-like input: names matched to the model's joints,
//! missing joints keep their last value, unknown names are reported once, non-finite values are
//! rejected. A trajectory of timestamped samples interpolates positions between them.

use super::model::RobotModel;
use std::collections::HashSet;

/// What one update did with its input; callers log and count it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct UpdateReport {
    pub applied: usize,
    /// Names the model does not know, each reported only the first time it is seen.
    pub new_unknown: Vec<String>,
    /// Joints whose value was NaN or infinite (their last value is kept).
    pub rejected_non_finite: Vec<String>,
    /// True when the name and position lists have different lengths (extra entries ignored).
    pub length_mismatch: bool,
}

/// The latest known position of every joint of a model.
#[derive(Clone, Debug)]
pub struct JointStateTracker {
    pub positions: Vec<f64>,
    names: Vec<(String, usize)>,
    reported_unknown: HashSet<String>,
}

impl JointStateTracker {
    /// All joints at zero.
    pub fn new(model: &RobotModel) -> Self {
        let names = model
            .joints
            .iter()
            .enumerate()
            .map(|(k, j)| (j.name.clone(), k))
            .collect();
        Self {
            positions: vec![0.0; model.joints.len()],
            names,
            reported_unknown: HashSet::new(),
        }
    }

    /// Whether `name` is one of the model's joints.
    pub fn knows(&self, name: &str) -> bool {
        self.index(name).is_some()
    }

    fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().find(|(n, _)| n == name).map(|(_, k)| *k)
    }

    pub fn update(&mut self, names: &[String], positions: &[f64]) -> UpdateReport {
        let mut report = UpdateReport {
            length_mismatch: names.len() != positions.len(),
            ..Default::default()
        };
        for (name, &value) in names.iter().zip(positions) {
            match self.index(name) {
                None => {
                    if self.reported_unknown.insert(name.clone()) {
                        report.new_unknown.push(name.clone());
                    }
                }
                Some(_) if !value.is_finite() => report.rejected_non_finite.push(name.clone()),
                Some(k) => {
                    self.positions[k] = value;
                    report.applied += 1;
                }
            }
        }
        report
    }
}

/// Timestamped joint vectors, strictly increasing in time.
#[derive(Clone, Debug, Default)]
pub struct JointTrajectory {
    samples: Vec<(f64, Vec<f64>)>,
}

impl JointTrajectory {
    /// Append a sample; refused (returns false) unless it is later than the last one.
    pub fn push(&mut self, t: f64, positions: Vec<f64>) -> bool {
        if !t.is_finite() || self.samples.last().is_some_and(|(last, _)| t <= *last) {
            return false;
        }
        self.samples.push((t, positions));
        true
    }

    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Drop samples no longer needed to interpolate at or after `t`.
    pub fn forget_before(&mut self, t: f64) {
        let keep_from = self
            .samples
            .iter()
            .rposition(|(ts, _)| *ts <= t)
            .unwrap_or(0);
        self.samples.drain(..keep_from);
    }

    /// This trajectory extended to `t` by continuing its last segment linearly for at most
    /// `max_extrapolation` seconds past the last sample (holding after that).
    pub fn extended(&self, t: f64, max_extrapolation: f64) -> JointTrajectory {
        let mut out = self.clone();
        let n = self.samples.len();
        if n >= 2 && t > self.samples[n - 1].0 {
            let ((t0, a), (t1, b)) = (&self.samples[n - 2], &self.samples[n - 1]);
            let until = t.min(t1 + max_extrapolation);
            let s = (until - t0) / (t1 - t0);
            out.push(
                until,
                a.iter().zip(b).map(|(x, y)| x + s * (y - x)).collect(),
            );
        }
        out
    }

    /// Linear interpolation at `t`, holding the first/last sample outside their span.
    pub fn at(&self, t: f64) -> Option<Vec<f64>> {
        let first = self.samples.first()?;
        if t <= first.0 {
            return Some(first.1.clone());
        }
        let k = self.samples.partition_point(|(ts, _)| *ts <= t);
        if k >= self.samples.len() {
            return self.samples.last().map(|s| s.1.clone());
        }
        let ((t0, a), (t1, b)) = (&self.samples[k - 1], &self.samples[k]);
        let s = (t - t0) / (t1 - t0);
        Some(a.iter().zip(b).map(|(x, y)| x + s * (y - x)).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::model::{GeometrySource, PackagePaths};

    fn model() -> RobotModel {
        let urdf = r#"<robot name="t"><link name="a"/><link name="b"/><link name="c"/>
          <joint name="j1" type="continuous"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint>
          <joint name="j2" type="continuous"><parent link="b"/><child link="c"/><axis xyz="0 0 1"/></joint></robot>"#;
        RobotModel::parse(
            urdf,
            std::path::Path::new("."),
            &PackagePaths::default(),
            GeometrySource::Collision,
        )
        .unwrap()
    }

    #[test]
    fn missing_joints_keep_values_unknown_are_reported_once_nan_is_rejected() {
        let m = model();
        let mut t = JointStateTracker::new(&m);
        let r = t.update(&["j1".into(), "j2".into()], &[0.5, 0.25]);
        assert_eq!(r.applied, 2);
        let r = t.update(&["j2".into(), "elbow".into()], &[0.75, 1.0]);
        assert_eq!(t.positions, vec![0.5, 0.75], "j1 keeps its value");
        assert_eq!(r.new_unknown, vec!["elbow".to_string()]);
        let r = t.update(&["elbow".into()], &[1.0]);
        assert!(r.new_unknown.is_empty(), "reported only once");
        let r = t.update(&["j1".into(), "j2".into()], &[f64::NAN, f64::INFINITY]);
        assert_eq!(r.rejected_non_finite.len(), 2);
        assert_eq!(
            t.positions,
            vec![0.5, 0.75],
            "non-finite values never reach the state"
        );
        let r = t.update(&["j1".into(), "j2".into()], &[0.1]);
        assert!(r.length_mismatch);
        assert_eq!(t.positions, vec![0.1, 0.75]);
    }

    #[test]
    fn trajectory_interpolates_and_refuses_out_of_order_samples() {
        let mut tr = JointTrajectory::default();
        assert!(tr.push(1.0, vec![0.0, 1.0]));
        assert!(tr.push(2.0, vec![1.0, 3.0]));
        assert!(!tr.push(2.0, vec![9.0, 9.0]), "duplicate stamp");
        assert!(!tr.push(1.5, vec![9.0, 9.0]), "stamp going backwards");
        assert_eq!(tr.at(1.25), Some(vec![0.25, 1.5]));
        assert_eq!(tr.at(0.0), Some(vec![0.0, 1.0]));
        assert_eq!(tr.at(5.0), Some(vec![1.0, 3.0]));
        tr.forget_before(1.9);
        assert_eq!(tr.at(1.95), Some(vec![0.95, 2.9]));
    }
}

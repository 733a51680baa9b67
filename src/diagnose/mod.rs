//! Diagnose: what physics the model is missing (spec section 5). The visual force is the force the
//! physics failed to predict; logged per object and tick together with the object's state, it is
//! a residual that candidate physical effects try to explain.
//!
//! The pipeline (`diagnose`): replay with the current model, keeping the tracked states
//! (`trace`) and the residuals (`Sample`, `residuals.csv`); locate where open-loop predictions
//! fail (`locate`); explain the corrective forces by sparse regression over candidate effects
//! with held-out validation (`candidates`, `select`); fit each candidate family's physical
//! parameter by open-loop simulation and name the one that cuts the held-out prediction error
//! (`refit`); fit the named effect again on a replay tracked with it (tracking with a model that
//! lacks an effect lags what it does); rerun with the augmented model and report before / after
//! (`report`, `plots`).
//! Diagnose never changes the tracker; it only replays with different physics.

pub mod candidates;
pub mod locate;
pub mod log;
mod pipeline;
pub mod plots;
pub mod refit;
pub mod report;
pub mod select;
pub mod trace;

use glam::Vec3;
use serde::Serialize;

/// One object at one tick: its state, its contacts and the corrective wrench the visual forces
/// applied (force on the object, torque about its centre of mass).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Sample {
    pub t: f64,
    pub object: String,
    /// Centre of mass, m; velocity, m/s; acceleration (finite difference), m/s^2.
    pub position: Vec3,
    pub velocity: Vec3,
    pub acceleration: Vec3,
    /// Angular velocity about the centre of mass, rad/s.
    pub angular_velocity: Vec3,
    /// Modelled mass, kg, and inertia about the vertical axis through the centre of mass, kg m^2.
    pub mass: f32,
    pub inertia_z: f32,
    /// Contacts: with the ground, with a kinematic body (robot) and with another object.
    pub on_ground: bool,
    pub touching_robot: bool,
    pub touching_object: bool,
    /// The visual forces of this tick, summed: force (N) and torque about the centre of mass (N m).
    pub force: Vec3,
    pub torque: Vec3,
}

/// CSV header of `residuals.csv`.
pub const CSV_HEADER: &str = "t,object,x,y,z,vx,vy,vz,ax,ay,az,wx,wy,wz,mass,inertia_z,on_ground,touching_robot,touching_object,fx,fy,fz,tx,ty,tz";

impl Sample {
    pub fn csv_row(&self) -> String {
        let v = |a: Vec3| format!("{:.6},{:.6},{:.6}", a.x, a.y, a.z);
        format!(
            "{:.6},{},{},{},{},{},{:.6},{:.8},{},{},{},{},{}",
            self.t,
            self.object,
            v(self.position),
            v(self.velocity),
            v(self.acceleration),
            v(self.angular_velocity),
            self.mass,
            self.inertia_z,
            self.on_ground as u8,
            self.touching_robot as u8,
            self.touching_object as u8,
            v(self.force),
            v(self.torque)
        )
    }

    /// Parse a row written by `csv_row`.
    pub fn from_csv_row(line: &str) -> Option<Sample> {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 25 {
            return None;
        }
        let num = |i: usize| f[i].parse::<f32>().ok();
        let v3 = |i: usize| Some(Vec3::new(num(i)?, num(i + 1)?, num(i + 2)?));
        Some(Sample {
            t: f[0].parse().ok()?,
            object: f[1].to_string(),
            position: v3(2)?,
            velocity: v3(5)?,
            acceleration: v3(8)?,
            angular_velocity: v3(11)?,
            mass: num(14)?,
            inertia_z: num(15)?,
            on_ground: f[16] == "1",
            touching_robot: f[17] == "1",
            touching_object: f[18] == "1",
            force: v3(19)?,
            torque: v3(22)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_round_trip_through_csv() {
        let s = Sample {
            t: 1.25,
            object: "box".into(),
            position: Vec3::new(0.5, -0.1, 0.025),
            velocity: Vec3::new(0.01, 0.2, 0.0),
            acceleration: Vec3::new(0.0, -0.5, 0.0),
            angular_velocity: Vec3::new(0.0, 0.0, 0.3),
            mass: 0.36,
            inertia_z: 0.0005,
            on_ground: true,
            touching_robot: false,
            touching_object: true,
            force: Vec3::new(0.1, -0.2, 0.05),
            torque: Vec3::new(0.0, 0.0, -0.001),
        };
        assert_eq!(CSV_HEADER.split(',').count(), 25);
        assert_eq!(Sample::from_csv_row(&s.csv_row()), Some(s));
        assert_eq!(Sample::from_csv_row("1,box,2"), None);
    }
}

/// Read `residuals.csv` (as written by replay).
pub fn read_residuals(path: &std::path::Path) -> anyhow::Result<Vec<Sample>> {
    use anyhow::Context;
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut lines = text.lines();
    if lines.next() != Some(CSV_HEADER) {
        anyhow::bail!(
            "{} is not a residuals file (header differs)",
            path.display()
        );
    }
    lines
        .enumerate()
        .map(|(n, l)| {
            Sample::from_csv_row(l)
                .with_context(|| format!("{}:{}: malformed row", path.display(), n + 2))
        })
        .collect()
}

pub use pipeline::{DiagnoseOptions, diagnose};

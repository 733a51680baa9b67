//! The residual log: per dynamic object and tick, its state, contacts and the corrective wrench
//! the visual forces applied, taken from the world after a predict / correct tick (what the
//! diagnosis explains), and its CSV form (`residuals.csv`).

use crate::correct::CorrectStats;
use crate::math::rotation_angle_between;
use crate::physics::{TOUCH_SLACK, Touched};
use crate::tracker::{Observer, Tick};
use crate::world::{Phase, ShapeId, World};
use anyhow::{Context, Result};
use glam::{Mat3, Vec3};
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
    /// Contacts: with the ground at the tick's end; with a kinematic body (robot) and with
    /// another object at the tick's end or in any substep of it (a strike can be over within a
    /// tick).
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
}

/// Remembers the previous tick to difference velocities and rotations.
#[derive(Default)]
pub struct ResidualLog {
    previous: Vec<Option<(Vec3, glam::Quat)>>,
    pub samples: Vec<Sample>,
}

impl Observer for ResidualLog {
    fn tick(&mut self, tick: &Tick) -> Result<()> {
        let physics = tick.tracker.physics();
        let ground = physics.ground.enabled.then_some((
            physics.ground.normal.normalize_or(Vec3::Z),
            physics.ground.height,
        ));
        let correction = tick.report.correction.as_ref();
        self.record(
            tick.tracker.world(),
            correction,
            &tick.report.touched,
            ground,
            tick.inputs.time,
            physics.dt,
        );
        Ok(())
    }
}

impl ResidualLog {
    /// `residuals.csv`: a header and one row per sample.
    pub fn write_csv(&self, path: &std::path::Path) -> Result<()> {
        let mut csv = String::from(CSV_HEADER);
        csv.push('\n');
        for sample in &self.samples {
            csv += &sample.csv_row();
            csv.push('\n');
        }
        std::fs::write(path, csv).with_context(|| format!("cannot write {}", path.display()))
    }

    /// Log every dynamic shape of `world` after a tick of length `dt` that ended at `t`, in which
    /// the physics saw each shape touch `touched` (per shape; empty when unknown).
    pub fn record(
        &mut self,
        world: &World,
        stats: Option<&CorrectStats>,
        touched: &[Touched],
        ground: Option<(Vec3, f32)>,
        t: f64,
        dt: f32,
    ) {
        if self.previous.len() != world.shapes.len() {
            self.previous = vec![None; world.shapes.len()];
        }
        for s in world.shapes.dynamic_ids() {
            let i = s as usize;
            let velocity = world.shape_velocity(s);
            let rotation = world.shapes.pose[i].rotation;
            let (acceleration, angular_velocity) = match self.previous[i] {
                Some((v0, q0)) => {
                    let dq = (rotation * q0.inverse()).normalize();
                    let (axis, angle) = dq.to_axis_angle();
                    let angle = if angle > std::f32::consts::PI {
                        angle - 2.0 * std::f32::consts::PI
                    } else {
                        angle
                    };
                    let w = if rotation_angle_between(rotation, q0) > 1e-7 {
                        axis * angle / dt
                    } else {
                        Vec3::ZERO
                    };
                    ((velocity - v0) / dt, w)
                }
                None => (Vec3::ZERO, Vec3::ZERO),
            };
            self.previous[i] = Some((velocity, rotation));
            let r = Mat3::from_quat(rotation);
            let inertia_world = r * world.shapes.inertia[i] * r.transpose();
            let (on_ground, robot_now, object_now) = contacts(world, s, ground);
            let during = touched.get(i).copied().unwrap_or_default();
            let (touching_robot, touching_object) =
                (robot_now || during.kinematic, object_now || during.dynamic);
            self.samples.push(Sample {
                t,
                object: world.shapes.name[i].clone(),
                position: world.shape_centroid(s),
                velocity,
                acceleration,
                angular_velocity,
                mass: world.shapes.mass[i],
                inertia_z: inertia_world.z_axis.z,
                on_ground,
                touching_robot,
                touching_object,
                force: stats
                    .and_then(|st| st.force.get(i).copied())
                    .unwrap_or(Vec3::ZERO),
                torque: stats
                    .and_then(|st| st.torque.get(i).copied())
                    .unwrap_or(Vec3::ZERO),
            });
        }
    }
}

/// Whether `shape` touches the ground, a kinematic body or another dynamic shape.
fn contacts(world: &World, shape: ShapeId, ground: Option<(Vec3, f32)>) -> (bool, bool, bool) {
    let p = &world.particles;
    let mine = world.shapes.range(shape);
    let on_ground = ground.is_some_and(|(n, h)| {
        mine.clone()
            .any(|i| n.dot(p.position[i]) - h <= p.radius[i] + TOUCH_SLACK)
    });
    // Bounding sphere of the shape, to skip far particles.
    let centre = world.shape_centroid(shape);
    let reach = mine
        .clone()
        .map(|i| p.position[i].distance(centre) + p.radius[i])
        .fold(0.0, f32::max);
    let (mut robot, mut object) = (false, false);
    for j in 0..p.len() {
        if mine.contains(&j)
            || p.phase[j] == Phase::Static
            || p.position[j].distance(centre) > reach + p.radius[j] + TOUCH_SLACK
        {
            continue;
        }
        let kinematic = p.phase[j] == Phase::Kinematic;
        if (kinematic && robot) || (!kinematic && object) {
            continue;
        }
        if mine.clone().any(|i| {
            p.position[i].distance(p.position[j]) <= p.radius[i] + p.radius[j] + TOUCH_SLACK
        }) {
            if kinematic {
                robot = true;
            } else {
                object = true;
            }
        }
    }
    (on_ground, robot, object)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Pose;
    use crate::world::{WorldBuilder, box_lattice};

    #[test]
    fn state_contacts_and_rates_are_logged() {
        let lattice = box_lattice(Vec3::splat(0.02), 0.01);
        let mut b = WorldBuilder::new();
        let s = b.add_rigid(
            "box",
            &lattice,
            0.005,
            0.001,
            Pose::from_translation(Vec3::new(0.0, 0.0, 0.02)),
            Vec3::ONE,
        );
        b.add_kinematic(
            "rod",
            &[Vec3::ZERO],
            0.005,
            Pose::from_translation(Vec3::new(0.0255, 0.005, 0.025)),
            Vec3::ONE,
        );
        b.add_rigid(
            "far",
            &lattice,
            0.005,
            0.001,
            Pose::from_translation(Vec3::new(1.0, 0.0, 0.02)),
            Vec3::ONE,
        );
        let mut world = b.build();
        let mut log = ResidualLog::default();
        let ground = Some((Vec3::Z, 0.0));
        log.record(&world, None, &[], ground, 0.0, 0.1);
        // Move and turn the box as a rigid body over one 0.1 s tick, with velocity 0.2 m/s along x.
        world.move_shape(
            s,
            Pose::new(Vec3::new(0.02, 0.0, 0.0), glam::Quat::from_rotation_z(0.05)),
        );
        for i in world.shapes.range(s) {
            world.particles.velocity[i] = Vec3::new(0.2, 0.0, 0.0);
        }
        let stats = CorrectStats {
            force: vec![Vec3::new(0.1, 0.0, 0.0), Vec3::ZERO, Vec3::ZERO],
            torque: vec![Vec3::new(0.0, 0.0, 0.01), Vec3::ZERO, Vec3::ZERO],
            ..Default::default()
        };
        // The far box touched the robot during the tick (a strike), though apart at its end.
        let during = [
            Touched::default(),
            Touched::default(),
            Touched {
                kinematic: true,
                dynamic: false,
            },
        ];
        log.record(&world, Some(&stats), &during, ground, 0.1, 0.1);
        let first = &log.samples[0];
        assert!(
            first.on_ground && first.touching_robot && !first.touching_object,
            "{first:?}"
        );
        assert!(
            !log.samples[1].touching_robot,
            "the far box touches nothing but the ground"
        );
        let struck = &log.samples[3];
        assert!(
            struck.touching_robot && !struck.touching_object,
            "a touch the physics saw during the tick counts: {struck:?}"
        );
        let moved = &log.samples[2];
        assert_eq!(moved.object, "box");
        assert!(
            (moved.acceleration - Vec3::new(2.0, 0.0, 0.0)).length() < 1e-3,
            "{}",
            moved.acceleration
        );
        assert!(
            (moved.angular_velocity - Vec3::new(0.0, 0.0, 0.5)).length() < 1e-3,
            "{}",
            moved.angular_velocity
        );
        assert!((moved.mass - 0.064).abs() < 1e-6 && moved.inertia_z > 0.0);
        assert_eq!(
            (moved.force, moved.torque),
            (Vec3::new(0.1, 0.0, 0.0), Vec3::new(0.0, 0.0, 0.01))
        );
    }

    #[test]
    fn a_sample_is_one_csv_row_under_the_header() {
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
        let row = s.csv_row();
        let fields: Vec<&str> = row.split(',').collect();
        assert_eq!(fields.len(), 25, "{row}");
        let at = |name: &str| fields[CSV_HEADER.split(',').position(|h| h == name).unwrap()];
        assert_eq!(
            (at("t"), at("object"), at("vy"), at("touching_object")),
            ("1.250000", "box", "0.200000", "1")
        );
        assert_eq!(
            (at("fy"), at("tz"), at("inertia_z")),
            ("-0.200000", "-0.001000", "0.00050000")
        );
    }
}

//! The residual log: per dynamic object and tick, its state, contacts and corrective wrench,
//! taken from the world after a predict / correct tick.

use super::Sample;
use crate::correct::CorrectStats;
use crate::math::rotation_angle_between;
use crate::world::{Phase, ShapeId, World};
use glam::{Mat3, Vec3};

/// Extra distance (m) within which particles count as touching.
const CONTACT_SLACK: f32 = 0.001;

/// Remembers the previous tick to difference velocities and rotations.
#[derive(Default)]
pub struct ResidualLog {
    previous: Vec<Option<(Vec3, glam::Quat)>>,
    pub samples: Vec<Sample>,
}

impl ResidualLog {
    /// Log every dynamic shape of `world` after a tick of length `dt` that ended at `t`.
    pub fn record(
        &mut self,
        world: &World,
        stats: Option<&CorrectStats>,
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
            let (on_ground, touching_robot, touching_object) = contacts(world, s, ground);
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
            .any(|i| n.dot(p.position[i]) - h <= p.radius[i] + CONTACT_SLACK)
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
            || p.position[j].distance(centre) > reach + p.radius[j] + CONTACT_SLACK
        {
            continue;
        }
        let kinematic = p.phase[j] == Phase::Kinematic;
        if (kinematic && robot) || (!kinematic && object) {
            continue;
        }
        if mine.clone().any(|i| {
            p.position[i].distance(p.position[j]) <= p.radius[i] + p.radius[j] + CONTACT_SLACK
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
    use crate::scene::{WorldBuilder, box_lattice};

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
        log.record(&world, None, ground, 0.0, 0.1);
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
        log.record(&world, Some(&stats), ground, 0.1, 0.1);
        let first = &log.samples[0];
        assert!(
            first.on_ground && first.touching_robot && !first.touching_object,
            "{first:?}"
        );
        assert!(
            !log.samples[1].touching_robot,
            "the far box touches nothing but the ground"
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
}

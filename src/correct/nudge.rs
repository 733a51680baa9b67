//! The pose nudge: where the local search (`relocate`) finds an object convincingly off the
//! model's pose, part of that offset (beyond `pose_nudge_beyond`) is taken into the tracked
//! state at once, the object's particles moved rigidly towards the found pose
//! (`nudge_towards_found`), and part of the move's rate into their velocity. A state update,
//! like a filter's, where the pose pull (`pull`) is a force: a force the model's friction or a
//! missing spring holds back moves the object only once the pull has grown past them, so an
//! object pushed by something the model lacks lagged behind by ticks and then overshot; a nudge
//! is not held back. An object the model has touching the robot or another object is nudged
//! only beyond `pose_nudge_contact_beyond`, only once the search has found it that far off two
//! ticks running (`found_beyond`), and asks the physics to settle it: what the nudge puts into
//! its pusher is to be pushed out in position, not thrown.
//!
//! This module owns moving tracked objects towards found poses and what such a move is worth
//! as a force (for the residuals); it never searches (`relocate`) and never decides whether a
//! found pose is convincing (`pull`).

use super::{CorrectConfig, relocate};
use crate::math::Pose;
use crate::world::{ShapeId, ShapeKind, World};
use glam::Vec3;

/// One object's nudge this tick: the shape, the rigid motion its particles took (world frame),
/// and the force (N, at its centre of mass) that would have moved it as far in one tick from
/// the velocity it kept.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nudge {
    pub shape: ShapeId,
    pub motion: Pose,
    pub force: Vec3,
    /// For an object nudged in contact: the speed (m/s) of its fastest particle after the nudge,
    /// which the physics settles it below for its next tick (`Solver::settle_below`).
    pub settle_below: Option<f32>,
}

/// Move each rigid object the search found convincingly off (`found`, already filtered: `None`
/// for an object not to be nudged; `share` per shape from `pull_share`) by `pose_nudge x share`
/// of the way to the found pose beyond `pose_nudge_beyond` (at its furthest particle, as
/// `pose_pulls` measures its dead zone), and add `pose_nudge_velocity` times the move's rate to
/// its particles' velocities. An object `in_contact` (per shape: the model's last predict step
/// had it touch the robot or another object) is nudged only beyond `pose_nudge_contact_beyond`
/// (never at 0), only where `found_before` (per shape: the search found it beyond that the tick
/// before too, `found_beyond`), and is to be settled. Returns the nudges made.
pub fn nudge_towards_found(
    world: &mut World,
    found: &[Option<relocate::Found>],
    share: &[f32],
    (in_contact, found_before): (&[bool], &[bool]),
    c: &CorrectConfig,
    dt: f32,
) -> Vec<Nudge> {
    let mut nudges = Vec::new();
    if c.pose_nudge <= 0.0 {
        return nudges;
    }
    for (s, found) in found.iter().enumerate() {
        let Some(found) = found else {
            continue;
        };
        if world.shapes.kind[s] != ShapeKind::Rigid {
            continue;
        }
        let here = world.shapes.pose[s];
        let range = world.shapes.range(s as ShapeId);
        let furthest = (super::pull::particle_moves(world, s, &found.pose))
            .map(|d| d.length())
            .fold(0.0, f32::max);
        let touching = in_contact.get(s).copied().unwrap_or(false);
        let confirmed = found_before.get(s).copied().unwrap_or(false);
        let beyond = match touching {
            true if c.pose_nudge_contact_beyond <= 0.0 || !confirmed => continue,
            true => c.pose_nudge_contact_beyond,
            false => c.pose_nudge_beyond,
        };
        if furthest <= beyond {
            continue;
        }
        let keep = 1.0 - beyond / furthest;
        let step = (c.pose_nudge * share.get(s).copied().unwrap_or(0.0) * keep).clamp(0.0, 1.0);
        if step <= 0.0 {
            continue;
        }
        let to = here.interpolate(&found.pose, step);
        let motion = to.mul(&here.inverse());
        let centre = world.shape_centroid(s as ShapeId);
        let moved = motion.transform_point(centre) - centre;
        let mut mass = 0.0;
        for i in range {
            let p = world.particles.position[i];
            let q = motion.transform_point(p);
            world.particles.position[i] = q;
            world.particles.velocity[i] += c.pose_nudge_velocity * (q - p) / dt;
            mass += world.particles.mass(i);
        }
        world.shapes.pose[s] = to;
        let fastest = || {
            (world.shapes.range(s as ShapeId))
                .map(|i| world.particles.velocity[i].length())
                .fold(0.0, f32::max)
        };
        nudges.push(Nudge {
            shape: s as ShapeId,
            motion,
            force: mass * moved / (dt * dt),
            settle_below: touching.then(fastest),
        });
    }
    nudges
}

/// Per shape: whether its found pose (`found`, None: not found) moves some particle of it
/// further than `beyond` from where the model has it (at its furthest particle, as the nudge
/// measures). The correction keeps this tick's for the next: one tick's find on another
/// renderer's images can be far off an object the model has right (MuJoCo's control_pushed_4601,
/// a bar the rod pushes, found 21 mm off for a tick while the model had it within 2 mm), while an
/// object the model holds off is found off tick after tick.
pub fn found_beyond(world: &World, found: &[Option<relocate::Found>], beyond: f32) -> Vec<bool> {
    (found.iter().enumerate())
        .map(|(s, found)| {
            found.is_some_and(|f| {
                (super::pull::particle_moves(world, s, &f.pose)).any(|d| d.length() > beyond)
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{WorldBuilder, box_lattice};
    use glam::Quat;

    /// A 10 x 5 x 4 cm box of 1 g particles resting on z = 0.
    fn one_box() -> World {
        let mut b = WorldBuilder::new();
        b.add_rigid(
            "box",
            &box_lattice(Vec3::new(0.05, 0.025, 0.02), 0.01),
            0.005,
            0.001,
            Pose::from_translation(Vec3::new(0.0, 0.0, 0.025)),
            Vec3::ONE,
        );
        b.build()
    }

    /// `nudge_towards_found` for the one object of `world`, found at `target` (in contact: found
    /// as far off the tick before).
    fn nudge_one(
        world: &mut World,
        target: Pose,
        share: f32,
        touching: bool,
        c: &CorrectConfig,
    ) -> Vec<Nudge> {
        let found = [Some(found_at(target))];
        let contact = (&[touching][..], &[touching][..]);
        nudge_towards_found(world, &found, &[share], contact, c, 1.0 / 30.0)
    }

    fn found_at(pose: Pose) -> relocate::Found {
        relocate::Found {
            pose,
            score: 0.9,
            score_here: 0.5,
        }
    }

    #[test]
    fn a_nudge_moves_a_rigid_object_rigidly_its_share_of_the_way_beyond_what_it_leaves_to_the_pull()
    {
        let mut world = one_box();
        let here = world.shapes.pose[0];
        let target = Pose::new(
            here.translation + Vec3::new(0.02, 0.0, 0.0),
            Quat::from_rotation_z(0.1) * here.rotation,
        );
        let c = CorrectConfig {
            pose_nudge: 0.5,
            pose_nudge_velocity: 0.0,
            ..CorrectConfig::default()
        };
        let before: Vec<Vec3> = world.particles.position.clone();
        let nudges = nudge_one(&mut world, target, 1.0, false, &c);
        assert_eq!(nudges.len(), 1);
        // Rigid: every pair of particles keeps its distance.
        let p = &world.particles.position;
        for (i, j) in [(0, p.len() - 1), (1, p.len() / 2)] {
            let (a, b) = ((before[i] - before[j]).length(), (p[i] - p[j]).length());
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
        // The share of the way beyond `pose_nudge_beyond`: the furthest particle moves
        // 0.5 x (offset - pose_nudge_beyond).
        let furthest_offset = world
            .shapes
            .range(0)
            .map(|i| {
                let r = world.particles.rest[i];
                (target.transform_point(r) - here.transform_point(r)).length()
            })
            .fold(0.0, f32::max);
        let moved = (0..p.len())
            .map(|i| (p[i] - before[i]).length())
            .fold(0.0, f32::max);
        let expected = 0.5 * (furthest_offset - c.pose_nudge_beyond);
        assert!(
            (moved - expected).abs() < 0.1 * expected,
            "{moved} vs {expected}"
        );
        // Velocities untouched without a velocity share; the pose follows the particles.
        assert!(world.particles.velocity.iter().all(|v| *v == Vec3::ZERO));
        assert!(world.rigid_deviation(0) < 1e-5);
        // Within `pose_nudge_beyond`: nothing moves.
        let mut still = one_box();
        let near = Pose::from_translation(Vec3::new(0.002, 0.0, 0.025));
        let none = nudge_one(&mut still, near, 1.0, false, &c);
        assert!(none.is_empty());
    }

    /// An object the model has in contact is nudged only beyond `pose_nudge_contact_beyond`, and
    /// asks to be settled no slower than it moves; never at 0.
    #[test]
    fn an_object_in_contact_is_nudged_only_far_off_and_settled_at_its_own_speed() {
        let c = CorrectConfig {
            pose_nudge: 0.5,
            pose_nudge_velocity: 0.5,
            pose_nudge_beyond: 0.006,
            pose_nudge_contact_beyond: 0.01,
            ..CorrectConfig::default()
        };
        let dt = 1.0 / 30.0;
        let offset = |d: f32| {
            let here = one_box().shapes.pose[0];
            Pose::new(here.translation + Vec3::new(d, 0.0, 0.0), here.rotation)
        };
        // 8 mm off: a free object is nudged, one in contact is not.
        for (touching, nudged) in [(false, true), (true, false)] {
            let n = nudge_one(&mut one_box(), offset(0.008), 1.0, touching, &c);
            assert_eq!(n.len(), nudged as usize, "in contact {touching}");
        }
        // 30 mm off in contact: nudged half the way beyond 10 mm, settled at its new speed.
        let mut world = one_box();
        let centre = world.shape_centroid(0);
        let n = nudge_one(&mut world, offset(0.03), 1.0, true, &c);
        let moved = world.shape_centroid(0) - centre;
        assert!((moved.x - 0.5 * (0.03 - 0.01)).abs() < 1e-4, "{moved}");
        let speed = n[0].settle_below.expect("settled");
        assert!((speed - 0.5 * moved.x / dt).abs() < 1e-3, "{speed} m/s");
        // Free objects are not settled; none in contact is nudged at 0.
        let n = nudge_one(&mut one_box(), offset(0.03), 1.0, false, &c);
        assert_eq!(n[0].settle_below, None);
        let never = CorrectConfig {
            pose_nudge_contact_beyond: 0.0,
            ..c
        };
        let none = nudge_one(&mut one_box(), offset(0.03), 1.0, true, &never);
        assert!(none.is_empty());
        // Found 30 mm off in contact, but not far off the tick before: not nudged. The same find
        // kept for the next tick confirms it there.
        let mut world = one_box();
        let found = [Some(found_at(offset(0.03)))];
        let before = found_beyond(&world, &[None], c.pose_nudge_contact_beyond);
        let first = nudge_towards_found(&mut world, &found, &[1.0], (&[true], &before), &c, dt);
        assert!(first.is_empty());
        let now = found_beyond(&world, &found, c.pose_nudge_contact_beyond);
        assert_eq!((before[0], now[0]), (false, true));
        let second = nudge_towards_found(&mut world, &found, &[1.0], (&[true], &now), &c, dt);
        assert_eq!(second.len(), 1);
        // 8 mm off is not beyond 10 mm: it confirms nothing.
        let near = [Some(found_at(offset(0.008)))];
        assert_eq!(found_beyond(&one_box(), &near, 0.01), [false]);
    }

    #[test]
    fn a_nudge_puts_its_velocity_share_of_the_moves_rate_into_the_object_and_reports_its_force() {
        let mut world = one_box();
        let here = world.shapes.pose[0];
        let target = Pose::new(here.translation + Vec3::new(0.0, 0.03, 0.0), here.rotation);
        let c = CorrectConfig {
            pose_nudge: 1.0,
            pose_nudge_velocity: 0.5,
            ..CorrectConfig::default()
        };
        let dt = 1.0 / 30.0;
        let centre = world.shape_centroid(0);
        let nudges = nudge_one(&mut world, target, 1.0, false, &c);
        let moved = world.shape_centroid(0) - centre;
        // A pure translation: the part within `pose_nudge_beyond` is left to the pull.
        assert!(
            (moved.y - (0.03 - c.pose_nudge_beyond)).abs() < 1e-4,
            "{moved}"
        );
        let v = world.shape_velocity(0);
        assert!((v - 0.5 * moved / dt).length() < 1e-3, "{v}");
        let mass: f32 = (0..world.particles.len())
            .map(|i| world.particles.mass(i))
            .sum();
        let f = nudges[0].force;
        assert!(
            (f - mass * moved / (dt * dt)).length() < 1e-2 * f.length(),
            "{f}"
        );
        // A share over 1 is refused with what to set.
        let over = CorrectConfig {
            pose_nudge: 1.5,
            ..CorrectConfig::default()
        };
        let err = over.validate().unwrap_err().to_string();
        assert!(
            err.contains("correct.pose_nudge") && err.contains("between 0 and 1"),
            "{err}"
        );
        // No share (full agreement): no nudge.
        let mut agreed = one_box();
        let none = nudge_one(&mut agreed, target, 0.0, false, &c);
        assert!(none.is_empty());
    }
}

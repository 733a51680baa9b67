//! The pose pull: where the local search (`relocate`) finds an object's silhouette a few
//! millimetres or degrees from the model's pose, each of its particles is pulled towards that
//! pose (`pose_pulls`, beyond the dead zone), in a share that grows as the silhouette agreement
//! falls (`pull_share`), through a PID across ticks (`PullState`).
//!
//! This module owns turning found poses into per-particle pulls and their state across ticks;
//! it never searches (`relocate`) and never applies forces (the rest of `correct`).

use super::{CorrectConfig, relocate};
use crate::math::Pose;
use crate::world::World;
use glam::Vec3;

/// A pose whose Gaussians look like themselves in fewer than this share of their pixels is not
/// where the images show the object (it is hidden, or not there at all): no pull.
const POSE_MIN_SCORE: f32 = 0.5;

/// Below this gain in score (share of Gaussians that look like themselves) a better pose found
/// nearby is noise.
const POSE_MARGIN: f32 = 0.03;

/// Whether a better pose found nearby is worth pulling towards: it scores at least
/// `POSE_MIN_SCORE`, and `POSE_MARGIN` more than where the model has the object.
pub fn convincing(found: &relocate::Found) -> bool {
    found.score >= POSE_MIN_SCORE && found.score >= found.score_here + POSE_MARGIN
}

/// One particle's pose pull across ticks: its pull at the previous tick and the pull integrated
/// over the ticks it has lasted (s m).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PullState {
    previous: Vec3,
    integral: Vec3,
    /// Ticks in a row the search has had no verdict (`None`) while the pull is held.
    unsure: u32,
    /// The found pose's velocity at the particle (m/s): how far the found point moved since the
    /// last tick, smoothed over ticks (`acceleration_following`).
    found_velocity: Vec3,
    /// Where the found pose put the particle last tick (m): its position plus the pull.
    found_point: Vec3,
}

/// Ticks a pull is held, without force and with its integral kept, through searches that found
/// nothing convincing, before it ends. The best pose's margin over the model's flickers around
/// `POSE_MARGIN` at rest: ending the pull at each flicker threw its integral away every few
/// ticks, and static friction held what the pull alone could not move (MuJoCo's heavy5_502:
/// a T-block 4 deg off in yaw, 10 mm, for its last 1.5 s).
const PULL_HOLD_TICKS: u32 = 1;

impl PullState {
    /// `acceleration`, plus `pose_follow_damping` x `share` x (the found pose's velocity at the
    /// particle, smoothed by `pose_follow_smoothing`, less the particle's `velocity`), while the
    /// pull lasts. The found pose's velocity is how far the found point (the particle's
    /// `position` plus its pull) moved since the last tick. A pull that starts, or resumes after
    /// a tick without a verdict (its last found point two ticks old), has no move of one tick to
    /// go by and takes the particle's own.
    ///
    /// Not the particle's velocity plus the pull's change per second: that velocity is the one
    /// the tick ends with, the pull's change follows the tick's mean, and the two differ by half
    /// the tick's change of velocity. In the visual forces' start-up ring (a 7.5 Hz swing of
    /// 5 mm) that half fed a share of each tick's acceleration back into the next through the
    /// follow damping: pegs's pushed T-block rang until 1.3 s, and now until 0.9 (README, "The
    /// found pose's velocity from its moves").
    pub fn acceleration_following(
        &mut self,
        d: Option<Vec3>,
        position: Vec3,
        velocity: Vec3,
        share: f32,
        c: &CorrectConfig,
        dt: f32,
    ) -> Vec3 {
        let starts = *self == Self::default();
        let resumes = self.unsure > 0;
        let pull = self.acceleration(d, c, dt);
        let Some(d) = d.filter(|_| pull != Vec3::ZERO) else {
            return pull;
        };
        let found_point = position + d;
        self.found_velocity = match starts {
            true => velocity,
            false => {
                let found = match resumes {
                    true => velocity,
                    false => (found_point - self.found_point) / dt,
                };
                self.found_velocity + c.pose_follow_smoothing * (found - self.found_velocity)
            }
        };
        self.found_point = found_point;
        pull + c.pose_follow_damping * share * (self.found_velocity - velocity)
    }

    /// The acceleration (m/s^2) of this tick's pull `d` (m, `pose_pulls`): `pose_gain x d +
    /// pose_damping x its rate + pose_integral x its integral`, the rate and integral since the
    /// pull started. A zero pull (arrived within the dead zone) ends it and clears the state; no
    /// verdict (`None`) holds it, with no force, for up to `PULL_HOLD_TICKS` ticks, then ends it.
    pub fn acceleration(&mut self, d: Option<Vec3>, c: &CorrectConfig, dt: f32) -> Vec3 {
        let d = match d {
            None if *self != Self::default() && self.unsure < PULL_HOLD_TICKS => {
                self.unsure += 1;
                return Vec3::ZERO;
            }
            Some(d) if d != Vec3::ZERO => d,
            _ => {
                *self = Self::default();
                return Vec3::ZERO;
            }
        };
        if self.unsure > 0 {
            self.previous = d;
        }
        self.unsure = 0;
        // A pull that starts has no rate yet. Taking its whole offset as its first change kicked
        // the object (`pose_damping / dt`, three times the gain at 30 Hz) at every start, and a
        // pull starts again each time the offset leaves the dead zone: with every object
        // searched, pegs's pushed T-block rang 10-16 mm either side of the truth.
        if *self == Self::default() {
            self.previous = d;
        }
        let rate = (d - self.previous) / dt;
        self.previous = d;
        if d.dot(self.integral) < 0.0 {
            self.integral = Vec3::ZERO;
        }
        self.integral += d * dt;
        c.pose_gain * d + c.pose_damping * rate + c.pose_integral * self.integral
    }
}

/// The share (0 to 1) of its pose pull an object with silhouette agreement `agreement` gets:
/// none at `pose_search_below`, all at `pose_pull_full_below` and under, linear between.
pub fn pull_share(agreement: f32, c: &CorrectConfig) -> f32 {
    let (top, full) = (c.pose_search_below, c.pose_pull_full_below);
    match top > full {
        true => ((top - agreement) / (top - full)).clamp(0.0, 1.0),
        false => 1.0,
    }
}

/// Per particle: how far the object's best local pose (`Corrector::local_poses`) would move it,
/// less the dead zone (scaled so that the furthest particle's move shrinks by `dead_zone`): zero
/// where that pose is within the dead zone, `None` where the search found no `convincing` pose
/// (or did not run).
pub fn pose_pulls(
    world: &World,
    poses: &[Option<relocate::Found>],
    dead_zone: f32,
) -> Vec<Option<Vec3>> {
    let mut pulls = vec![None; world.particles.len()];
    for (s, found) in poses.iter().enumerate() {
        let Some(found) = found.filter(convincing) else {
            continue;
        };
        let range = world.shapes.range(s as u32);
        let moves: Vec<Vec3> = particle_moves(world, s, &found.pose).collect();
        let furthest = moves.iter().map(|d| d.length()).fold(0.0, f32::max);
        let keep = (1.0 - dead_zone / furthest).max(0.0);
        for (i, d) in range.zip(moves) {
            pulls[i] = Some(if furthest <= dead_zone {
                Vec3::ZERO
            } else {
                keep * d
            });
        }
    }
    pulls
}

/// How far each particle of shape `s` moves (m, world) from where the model has it to where
/// `pose` puts it: the one measure of a found pose's offset that the pull, the nudge and the
/// reports share.
pub fn particle_moves<'a>(
    world: &'a World,
    s: usize,
    pose: &'a Pose,
) -> impl Iterator<Item = Vec3> + 'a {
    let here = world.shapes.pose[s];
    let rest = &world.particles.rest;
    (world.shapes.range(s as u32))
        .map(move |i| pose.transform_point(rest[i]) - here.transform_point(rest[i]))
}

/// Per shape: how far (m) its convincing found pose (`convincing`) is from the model's, as the
/// mean move of its particles (the tracking error's measure); None where the search found none.
pub fn found_offsets(world: &World, poses: &[Option<relocate::Found>]) -> Vec<Option<f32>> {
    (poses.iter().enumerate())
        .map(|(s, found)| {
            let found = found.filter(convincing)?;
            let n = world.shapes.range(s as u32).len().max(1) as f32;
            let moved: f32 = particle_moves(world, s, &found.pose)
                .map(|d| d.length())
                .sum();
            Some(moved / n)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pose_pull_grows_with_its_offset_its_change_and_its_integral_and_ends_at_zero() {
        let c = CorrectConfig::default();
        let dt = 1.0 / 30.0;
        let mut state = PullState::default();
        let d = Vec3::new(0.02, 0.0, 0.0);
        // A pull that starts has no change yet: no kick.
        let first = state.acceleration(Some(d), &c, dt);
        let expected = c.pose_gain * d + c.pose_integral * d * dt;
        assert!(first.distance(expected) < 1e-4, "{first} vs {expected}");
        // Half the offset a tick later: the rate term brakes the approach.
        let second = state.acceleration(Some(0.5 * d), &c, dt);
        let rate = (0.5 * d - d) / dt;
        let expected =
            c.pose_gain * 0.5 * d + c.pose_damping * rate + c.pose_integral * 1.5 * d * dt;
        assert!(second.distance(expected) < 1e-4, "{second} vs {expected}");
        let undamped = c.pose_gain * 0.5 * d + c.pose_integral * 1.5 * d * dt;
        assert!(
            second.x < undamped.x,
            "the rate term brakes: {second} vs {undamped}"
        );
        // A zero pull ends it: the next start has no integral left.
        assert_eq!(state.acceleration(Some(Vec3::ZERO), &c, dt), Vec3::ZERO);
        let again = state.acceleration(Some(d), &c, dt);
        assert!(again.distance(first) < 1e-4, "{again} vs {first}");
    }

    /// Where a free object (on a frictionless table) comes to, from `offset` (m) off a pose the
    /// images keep in one place: each tick's pull held over the tick as the physics applies an
    /// external force (its substeps' semi-implicit Euler, then the velocity the model keeps), no
    /// dead zone. The offset at every tick.
    fn pulled_free(c: &CorrectConfig, offset: f32, seconds: f32) -> Vec<f32> {
        let physics = crate::physics::PhysicsConfig::default();
        let (dt, h) = (physics.dt, physics.dt / physics.substeps as f32);
        let (mut x, mut v, mut state) = (offset, 0.0, PullState::default());
        let mut track = Vec::new();
        for _ in 0..(seconds / dt).round() as usize {
            let d = Some(Vec3::new(-x, 0.0, 0.0));
            let (position, velocity) = (Vec3::new(x, 0.0, 0.0), Vec3::new(v, 0.0, 0.0));
            let a = state
                .acceleration_following(d, position, velocity, 1.0, c, dt)
                .x;
            for _ in 0..physics.substeps {
                v += a * h;
                x += v * h;
            }
            v *= physics.damping;
            track.push(x);
        }
        track
    }

    /// The pull closes a loop through the physics a tick at a time: found at one tick, it acts
    /// over the next as a force the substeps integrate, which moves the object about half as far
    /// in the tick as a change of velocity taken at once. With nothing else to damp it (a
    /// frictionless table, an object the images hold still) the loop's slowest mode grows 1.4 % a
    /// tick on the rate term alone at damping 10 (a 20 mm offset swings out to metres in 10 s; on
    /// MuJoCo's sticky_1601, configured at friction 0.135, a bar at rest rang 20 mm either side
    /// of the truth every 8 ticks for a second). A rate term of 25 settles it but, measured on
    /// the grid-found offset, kicks (README, "The pull's own loop"); the follow damping settles
    /// it on the particles' own velocity.
    #[test]
    fn a_free_object_pulled_through_the_substeps_rings_on_the_rate_term_alone_and_settles_with_the_follow_damping()
     {
        let alone = CorrectConfig {
            pose_damping: 10.0,
            pose_follow_damping: 0.0,
            ..CorrectConfig::default()
        };
        let rang = pulled_free(&alone, 0.02, 10.0);
        let swing = rang[rang.len() - 30..]
            .iter()
            .fold(0.0f32, |m, x| m.max(x.abs()));
        assert!(swing > 0.02, "damping 10 alone settled: {swing} m");
        for damped in [
            CorrectConfig::default(),
            CorrectConfig {
                pose_damping: 25.0,
                ..alone
            },
        ] {
            let track = pulled_free(&damped, 0.02, 10.0);
            let worst = track[track.len() - 30..]
                .iter()
                .fold(0.0f32, |m, x| m.max(x.abs()));
            assert!(worst < 1e-4, "still {worst} m off in the last second");
            // Within a second it is within a millimetre, and never overshoots by more than half.
            let after_one = track[30..].iter().fold(0.0f32, |m, x| m.max(x.abs()));
            assert!(after_one < 1e-3, "{after_one} m off after a second");
            let overshoot = track.iter().fold(0.0f32, |m, x| m.max(-x));
            assert!(overshoot < 0.01, "overshot by {overshoot} m");
        }
    }

    #[test]
    fn a_pulled_particle_moving_with_its_found_pose_is_not_braked_and_one_leaving_it_is() {
        let c = CorrectConfig::default();
        let dt = 1.0 / 30.0;
        let v = Vec3::new(0.2, 0.0, 0.0);
        // The found pose moves with the particle: the offset stays.
        let d = Vec3::new(0.01, 0.0, 0.0);
        let (mut with, mut pid) = (PullState::default(), PullState::default());
        let mut position = Vec3::ZERO;
        for _ in 0..30 {
            position += v * dt;
            let a = with.acceleration_following(Some(d), position, v, 1.0, &c, dt);
            let b = pid.acceleration(Some(d), &c, dt);
            assert!(a.distance(b) < 1e-3, "{a} vs {b}");
        }
        // The found pose stands still while the particle leaves it at v: braked by the follow
        // damping (in share), on top of the rate term.
        let (mut leaving, mut pid) = (PullState::default(), PullState::default());
        let (mut offset, mut position) = (d, Vec3::ZERO);
        let mut braked = Vec3::ZERO;
        for _ in 0..30 {
            (offset, position) = (offset - v * dt, position + v * dt);
            let a = leaving.acceleration_following(Some(offset), position, v, 0.5, &c, dt);
            braked = a - pid.acceleration(Some(offset), &c, dt);
        }
        let expected = -c.pose_follow_damping * 0.5 * v;
        assert!(braked.distance(expected) < 1e-3, "{braked} vs {expected}");
    }

    /// A particle a force accelerates through each tick ends the tick faster than it went on
    /// average. Where its found pose stands still, the follow damping must brake all of the
    /// velocity it ends with: a found velocity taken as the end velocity plus the pull's change
    /// reads half the tick's change of velocity as the found pose moving, and so pushes the
    /// particle on by a share of its last acceleration (the start-up ring's feed).
    #[test]
    fn a_found_pose_standing_still_is_still_while_its_particle_accelerates_through_the_tick() {
        let c = CorrectConfig::default();
        let dt = 1.0 / 30.0;
        let found = Vec3::new(0.02, 0.0, 0.0);
        let (mut state, mut pid) = (PullState::default(), PullState::default());
        let (mut x, mut v) = (Vec3::ZERO, Vec3::ZERO);
        let accel = Vec3::new(6.0, 0.0, 0.0);
        for tick in 0..6 {
            let d = found - x;
            let a = state.acceleration_following(Some(d), x, v, 1.0, &c, dt);
            let follow = a - pid.acceleration(Some(d), &c, dt);
            if tick > 0 {
                let expected = -c.pose_follow_damping * v;
                assert!(
                    follow.distance(expected) < 1e-3,
                    "tick {tick}: follow term {follow} against {expected}"
                );
            }
            // The tick: a steady push over it (the found pose never moves).
            x += v * dt + 0.5 * accel * dt * dt;
            v += accel * dt;
        }
    }

    #[test]
    fn a_pose_pull_that_reverses_drops_the_integral_it_built_the_other_way() {
        let c = CorrectConfig::default();
        let dt = 1.0 / 30.0;
        let d = Vec3::new(0.01, 0.0, 0.0);
        let mut state = PullState::default();
        for _ in 0..20 {
            state.acceleration(Some(d), &c, dt);
        }
        // Overshot: the pose is now the other way. Kept, 20 ticks of integral would keep pushing
        // past it.
        let back = state.acceleration(Some(-d), &c, dt);
        let expected =
            c.pose_gain * -d + c.pose_damping * (-2.0 * d / dt) - c.pose_integral * d * dt;
        assert!(back.distance(expected) < 1e-4, "{back} vs {expected}");
        assert!(back.x < 0.0);
    }

    #[test]
    fn a_pose_pull_keeps_its_integral_through_a_few_searches_without_a_verdict_then_ends() {
        let c = CorrectConfig::default();
        let dt = 1.0 / 30.0;
        let d = Some(Vec3::new(0.01, 0.0, 0.0));
        let mut held = PullState::default();
        let mut steady = PullState::default();
        for _ in 0..10 {
            held.acceleration(d, &c, dt);
            steady.acceleration(d, &c, dt);
        }
        // Searches that find nothing convincing: no force, the integral kept.
        for _ in 0..PULL_HOLD_TICKS {
            assert_eq!(held.acceleration(None, &c, dt), Vec3::ZERO);
        }
        let resumed = held.acceleration(d, &c, dt);
        let continued = steady.acceleration(d, &c, dt);
        assert!(
            resumed.distance(continued) < 1e-4,
            "{resumed} against {continued}"
        );
        // One tick more without a verdict ends it: it starts again from nothing.
        for _ in 0..=PULL_HOLD_TICKS {
            held.acceleration(None, &c, dt);
        }
        assert_eq!(held, PullState::default());
        let fresh = held.acceleration(d, &c, dt);
        assert!(fresh.length() < continued.length() / 2.0, "{fresh}");
    }

    #[test]
    fn a_pose_pull_grows_as_the_agreement_falls_from_where_the_search_starts_to_where_it_pulls_in_full()
     {
        let c = CorrectConfig {
            pose_search_below: 1.0,
            pose_pull_full_below: 0.9,
            ..CorrectConfig::default()
        };
        for (agreement, share) in [(1.0, 0.0), (0.99, 0.1), (0.95, 0.5), (0.9, 1.0), (0.5, 1.0)] {
            let got = pull_share(agreement, &c);
            assert!(
                (got - share).abs() < 1e-5,
                "{agreement}: {got} against {share}"
            );
        }
        // Where the pull is full from the search's start on, it is a step.
        let step = CorrectConfig {
            pose_search_below: 0.9,
            pose_pull_full_below: 0.95,
            ..CorrectConfig::default()
        };
        assert_eq!(pull_share(0.89, &step), 1.0);
    }
}

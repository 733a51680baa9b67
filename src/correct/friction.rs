//! Friction in the correction: the model's table (`Support`) and the share of its kinetic
//! friction made up against the visual forces' averaged push and turn of an object standing on
//! the table (`compensate_friction`), so that one visual-force gain moves objects on rough and
//! slippery tables alike.
//!
//! This module owns that compensation and the test of whether an object stands on a face; it
//! never integrates forces (`physics` does) and never measures pushes (the rest of `correct`).

use super::CorrectConfig;
use crate::world::{ShapeId, ShapeKind, World};
use glam::Vec3;

/// The model's table as the correction needs it: the plane, its kinetic friction and gravity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Support {
    /// Unit normal out of the table and the plane's offset along it (m).
    pub normal: Vec3,
    pub height: f32,
    pub kinetic_friction: f32,
    pub gravity: Vec3,
}

impl Support {
    /// Gravity's pull into the table (m/s^2), which the table's friction scales.
    fn load(&self) -> f32 {
        (-self.normal.dot(self.gravity)).max(0.0)
    }
}

/// How much of the friction compensation an averaged push of `accel` (m/s^2 at the feet) gets:
/// in proportion up to `friction_ramp`, whole beyond it.
fn ramp_in(accel: f32, c: &CorrectConfig) -> f32 {
    match c.friction_ramp > 0.0 {
        true => (accel / c.friction_ramp).min(1.0),
        false => 1.0,
    }
}

/// The share of a table's friction (an acceleration, `friction`) the compensation makes up,
/// where the visual force reaches `held` at a displacement of `friction_hold`: none while the
/// friction is under it (the visual force overcomes it within `friction_hold`, and the friction
/// keeps damping the tracker's small motions at rest), all of it from twice `held`, in
/// proportion between. `held` 0: all of it.
fn beyond_hold(friction: f32, held: f32) -> f32 {
    match held > 0.0 {
        true => ((friction - held) / held).clamp(0.0, 1.0),
        false => 1.0,
    }
}

/// A particle this close (m) to the table beyond its radius rests on it.
const SUPPORT_SLACK: f32 = 0.002;
/// Weight of a tick's push in its running average (about the last three ticks), which sets the
/// friction compensation: image noise pushes a different way every tick and averages out, an
/// offset the model's friction holds keeps pushing the same way.
const PUSH_SMOOTHING: f32 = 0.3;

/// Add to each object pushed along the table it rests on (`Support`) the model's own kinetic
/// friction against that push and turn (averaged over the last few ticks, `PUSH_SMOOTHING`),
/// times `friction_compensation`, ramped in over `friction_ramp` of tangential acceleration
/// (`ramp_in`): the visual force then moves the object as it would move it on a
/// slippery table, so one gain serves rough and slippery tables alike. A rigid object is
/// compensated as a whole while it stands on a face (spread by mass: no torque about its centre
/// of mass), not while it tips over an edge, where the table's friction is the pivot (pegs's
/// T-block pushed over: its edge slid out from under it); a rope particle by particle.
pub fn compensate_friction(
    world: &World,
    forces: &mut [Vec3],
    memory: &mut FrictionMemory,
    s: &Support,
    c: &CorrectConfig,
) {
    memory.push.resize(world.particles.len(), Vec3::ZERO);
    memory.turn.resize(world.particles.len(), 0.0);
    let p = &world.particles;
    let load = s.load();
    let resting = |i: usize| s.normal.dot(p.position[i]) - s.height - p.radius[i] <= SUPPORT_SLACK;
    let mass = |i: usize| p.movable_mass(i);
    // The acceleration along the table that compensates a push `force` on `mass`, whose running
    // average along the table `smoothed` is brought up to date.
    let against = |force: Vec3, mass: f32, smoothed: &mut Vec3| {
        let along = force - s.normal * s.normal.dot(force);
        *smoothed += PUSH_SMOOTHING * (along / mass - *smoothed);
        let accel = smoothed.length();
        if !(accel > 0.0 && accel.is_finite()) {
            *smoothed = Vec3::ZERO;
            return Vec3::ZERO;
        }
        let friction = s.kinetic_friction * load;
        let share = beyond_hold(friction, c.gain * c.friction_hold);
        *smoothed / accel * (c.friction_compensation * friction * share * ramp_in(accel, c))
    };
    for shape in 0..world.shapes.len() {
        let range = world.shapes.range(shape as u32);
        match world.shapes.kind[shape] {
            ShapeKind::Rigid if world.shapes.mass[shape] > 0.0 => {
                let feet: Vec<usize> = range.clone().filter(|&i| resting(i)).collect();
                if !stands_on_a_face(world, &feet, s.normal) {
                    range.for_each(|i| memory.forget(i));
                    continue;
                }
                // The body's average push and turn live in each of its particles alike.
                let total: Vec3 = range.clone().map(|i| forces[i]).sum();
                let mut body = memory.push[range.start];
                let extra = against(total, world.shapes.mass[shape], &mut body);
                let mut turn = memory.turn[range.start];
                let centre = world.shape_centroid(shape as u32);
                let spin = friction_turn(
                    world,
                    forces,
                    (&feet, centre),
                    shape as ShapeId,
                    (s, c),
                    &mut turn,
                );
                for i in range {
                    memory.push[i] = body;
                    memory.turn[i] = turn;
                    let r = p.position[i] - centre;
                    forces[i] += mass(i) * (extra + spin * s.normal.cross(r));
                }
            }
            ShapeKind::Rope => {
                for i in range {
                    match resting(i) && mass(i) > 0.0 {
                        true => {
                            forces[i] += mass(i) * against(forces[i], mass(i), &mut memory.push[i])
                        }
                        false => memory.push[i] = Vec3::ZERO,
                    }
                }
            }
            _ => {}
        }
    }
}

/// The angular acceleration (rad/s^2, about the table's normal) that compensates the turn
/// `forces` give `shape` (centre of mass `centre`) standing on `feet`: its kinetic friction's
/// torque, the load shared evenly among the feet, ramped in as `compensate_friction`'s push
/// (`ramp_in`). `smoothed`, the turn's running average, is brought up to date.
fn friction_turn(
    world: &World,
    forces: &[Vec3],
    (feet, centre): (&[usize], Vec3),
    shape: ShapeId,
    (s, c): (&Support, &CorrectConfig),
    smoothed: &mut f32,
) -> f32 {
    let p = &world.particles;
    let across = |i: usize| {
        let r = p.position[i] - centre;
        r - s.normal * s.normal.dot(r)
    };
    let range = world.shapes.range(shape);
    let inertia: f32 = (range.clone())
        .filter(|&i| p.inv_mass[i] > 0.0)
        .map(|i| across(i).length_squared() / p.inv_mass[i])
        .sum();
    let torque: f32 = range
        .map(|i| s.normal.dot(across(i).cross(forces[i])))
        .sum();
    let reach = feet.iter().map(|&i| across(i).length()).sum::<f32>() / feet.len() as f32;
    if !(inertia > 0.0 && reach > 0.0 && torque.is_finite()) {
        *smoothed = 0.0;
        return 0.0;
    }
    *smoothed += PUSH_SMOOTHING * (torque / inertia - *smoothed);
    let friction =
        s.kinetic_friction * s.load() * world.shapes.mass[shape as usize] * reach / inertia;
    // A turn of `friction_hold` at the feet: the visual force's angular acceleration there.
    let friction = friction * beyond_hold(friction, c.gain * c.friction_hold / reach);
    smoothed.signum() * c.friction_compensation * friction * ramp_in(smoothed.abs() * reach, c)
}

/// Each particle's push along the table and its body's turn about the table's normal (m/s^2,
/// rad/s^2), averaged over the ticks (`compensate_friction`, `PUSH_SMOOTHING`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrictionMemory {
    push: Vec<Vec3>,
    turn: Vec<f32>,
}

impl FrictionMemory {
    /// Forget particle `i`'s pushes (its object was moved, or no longer stands on the table).
    pub fn forget(&mut self, i: usize) {
        if let Some(p) = self.push.get_mut(i) {
            *p = Vec3::ZERO;
        }
        if let Some(t) = self.turn.get_mut(i) {
            *t = 0.0;
        }
    }
}

/// Whether the particles `feet` (those resting on the table) span an area rather than a line:
/// their spread across the line they lie along is at least their radius.
fn stands_on_a_face(world: &World, feet: &[usize], normal: Vec3) -> bool {
    if feet.len() < 3 {
        return false;
    }
    let p = &world.particles;
    let (u, v) = normal.any_orthonormal_pair();
    let n = feet.len() as f32;
    let at = |i: usize| (p.position[i].dot(u), p.position[i].dot(v));
    let (mu, mv) = feet.iter().fold((0.0, 0.0), |(a, b), &i| {
        let (x, y) = at(i);
        (a + x / n, b + y / n)
    });
    let (mut xx, mut xy, mut yy) = (0.0f32, 0.0f32, 0.0f32);
    for &i in feet {
        let (x, y) = at(i);
        let (dx, dy) = (x - mu, y - mv);
        xx += dx * dx / n;
        xy += dx * dy / n;
        yy += dy * dy / n;
    }
    // The smaller eigenvalue of the 2 x 2 covariance: the variance across the line.
    let across = 0.5 * (xx + yy) - (0.25 * (xx - yy) * (xx - yy) + xy * xy).sqrt();
    let radius = feet.iter().map(|&i| p.radius[i]).sum::<f32>() / n;
    across.max(0.0).sqrt() >= 0.5 * radius
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Pose;
    use crate::world::{WorldBuilder, box_lattice};

    /// A 6 x 6 x 4 cm box of 1 g particles on the table (z = 0), turned by `tilt` about x on its
    /// lowest edge, and the table's support (kinetic friction 0.4).
    fn box_on_table(tilt: f32) -> (World, ShapeId, Support) {
        let mut b = WorldBuilder::new();
        let half = Vec3::new(0.03, 0.03, 0.02);
        let turn = glam::Quat::from_rotation_x(tilt);
        // Lowest point of the turned lattice on the table: particle centres one radius up.
        let points = box_lattice(half, 0.01);
        let lowest = points
            .iter()
            .map(|p| (turn * *p).z)
            .fold(f32::MAX, f32::min);
        let s = b.add_rigid(
            "box",
            &points,
            0.005,
            0.001,
            Pose::new(Vec3::new(0.0, 0.0, 0.005 - lowest), turn),
            Vec3::ONE,
        );
        let support = Support {
            normal: Vec3::Z,
            height: 0.0,
            kinetic_friction: 0.4,
            gravity: Vec3::new(0.0, 0.0, -9.81),
        };
        (b.build(), s, support)
    }

    /// The acceleration (m/s^2) friction compensation adds to the box of `box_on_table(tilt)`
    /// after each of `pushes` (m/s^2 along the table, one per tick).
    fn compensation(tilt: f32, pushes: &[Vec3]) -> Vec<Vec3> {
        let c = CorrectConfig {
            friction_compensation: 1.0,
            ..Default::default()
        };
        compensation_on(tilt, 0.4, &c, pushes)
    }

    /// `compensation` on a table of kinetic friction `mu` with the correction `c`.
    fn compensation_on(tilt: f32, mu: f32, c: &CorrectConfig, pushes: &[Vec3]) -> Vec<Vec3> {
        let (w, s, mut support) = box_on_table(tilt);
        support.kinetic_friction = mu;
        let mass = w.shapes.mass[s as usize];
        let mut memory = FrictionMemory::default();
        pushes
            .iter()
            .map(|push| {
                let mut f: Vec<Vec3> = (0..w.particles.len())
                    .map(|i| *push / w.particles.inv_mass[i])
                    .collect();
                compensate_friction(&w, &mut f, &mut memory, &support, c);
                f.iter().sum::<Vec3>() / mass - *push
            })
            .collect()
    }

    #[test]
    fn a_steady_push_on_a_box_standing_on_the_table_gains_its_kinetic_friction() {
        let steady = compensation(0.0, &[Vec3::new(2.0, 0.0, 0.0); 12]);
        let last = *steady.last().unwrap();
        let want = 0.4 * 9.81;
        assert!(
            (last - Vec3::new(want, 0.0, 0.0)).length() < 0.05 * want,
            "{last} vs {want} along x"
        );
        // It builds up over the first ticks (the running average of the push).
        assert!(steady[0].length() < steady[3].length());
    }

    #[test]
    fn a_steady_turn_of_a_box_standing_on_the_table_gains_its_friction_torque() {
        let (w, s, support) = box_on_table(0.0);
        let c = CorrectConfig {
            friction_compensation: 1.0,
            ..Default::default()
        };
        let centre = w.shape_centroid(s);
        let range = w.shapes.range(s);
        let r = |i: usize| (w.particles.position[i] - centre) * Vec3::new(1.0, 1.0, 0.0);
        let spin = |f: &[Vec3]| -> f32 { range.clone().map(|i| r(i).cross(f[i]).z).sum() };
        let inertia: f32 = range.clone().map(|i| 0.001 * r(i).length_squared()).sum();
        // A turn of 100 rad/s^2 about z, tick after tick (past the ramp at the feet's reach).
        let mut memory = FrictionMemory::default();
        let mut added = 0.0;
        for _ in 0..12 {
            let mut f: Vec<Vec3> = (0..w.particles.len())
                .map(|i| 0.001 * Vec3::Z.cross(r(i)) * 100.0)
                .collect();
            let before = spin(&f);
            compensate_friction(&w, &mut f, &mut memory, &support, &c);
            added = (spin(&f) - before) / inertia;
        }
        // Friction of the bottom layer, the weight shared evenly: mu g M x their mean reach.
        let feet: Vec<usize> = range
            .clone()
            .filter(|&i| w.particles.position[i].z < 0.006)
            .collect();
        let reach = feet.iter().map(|&i| r(i).length()).sum::<f32>() / feet.len() as f32;
        let want = 0.4 * 9.81 * w.shapes.mass[s as usize] * reach / inertia;
        assert!(
            (added - want).abs() < 0.05 * want,
            "{added} vs {want} rad/s^2"
        );
    }

    #[test]
    fn friction_the_visual_force_overcomes_within_the_hold_is_kept_and_beyond_twice_it_is_compensated()
     {
        // Gain 600 reaches 0.6 m/s^2 at the 1 mm hold.
        let c = CorrectConfig {
            friction_compensation: 1.0,
            gain: 600.0,
            friction_hold: 0.001,
            ..Default::default()
        };
        let g = 9.81;
        // A slippery table (0.29 m/s^2 of friction), one between (0.9: half of it made up), a
        // rough one (3.9: all of it); the push past the ramp.
        for (mu, share) in [(0.03, 0.0), (0.9 / g, 0.5), (0.4, 1.0)] {
            let steady = compensation_on(0.0, mu, &c, &[Vec3::new(2.0, 0.0, 0.0); 12]);
            let last = steady.last().copied().unwrap_or_default();
            let want = share * mu * g;
            assert!(
                (last - Vec3::new(want, 0.0, 0.0)).length() < 0.05 * mu * g,
                "friction {mu}: {last} vs {want} along x"
            );
        }
    }

    #[test]
    fn a_box_tipping_over_its_edge_keeps_its_friction() {
        let tipping = compensation(0.5, &[Vec3::new(2.0, 0.0, 0.0); 12]);
        assert!(tipping.iter().all(|a| *a == Vec3::ZERO), "{tipping:?}");
    }

    #[test]
    fn noise_that_pushes_a_different_way_every_tick_gains_less_than_a_steady_push() {
        let noise: Vec<Vec3> = (0..12)
            .map(|k| Vec3::new(if k % 2 == 0 { 2.0 } else { -2.0 }, 0.0, 0.0))
            .collect();
        let noisy = compensation(0.0, &noise);
        let steady = compensation(0.0, &[Vec3::new(2.0, 0.0, 0.0); 12]);
        let (n, s) = (noisy[11].length(), steady[11].length());
        assert!(n < 0.5 * s, "noise {n} vs steady {s}");
    }
}

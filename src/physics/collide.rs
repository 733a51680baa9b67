//! Particle-particle contacts between different shapes, as Jacobi corrections gathered per
//! particle from its candidate list (no scatter, so it parallelises without atomics and is
//! deterministic). Friction uses the relative displacement over the substep.
//!
//! A kinematic shape whose exact solids are known (`Shapes::primitives`, a URDF's boxes and
//! cylinders with `robot.contact: exact`) is met as those solids (`sdf`), not particle by
//! particle: its particles only tell which pushable particles are near it. Met particle by
//! particle, a face pressed against a lattice of spheres sits in its grooves, and a pushed box
//! cannot slide along its pusher (see `tests/physics.rs`).

use super::ground::friction;
use super::sdf;
use super::spatial_hash::NeighbourLists;
use super::yielding::Yielding;
use super::{TOUCH_SLACK, Touched};
use crate::math::Pose;
use crate::world::{Particles, Phase, Primitive, ShapeId};
use glam::Vec3;
use rayon::prelude::*;

const CHUNK: usize = 256;

/// The shapes met as their exact solids: per particle its shape, per shape its solids (empty:
/// met particle by particle) and its pose now and at the start of the substep.
#[derive(Clone, Copy)]
pub struct Solids<'a> {
    pub shape: &'a [ShapeId],
    pub primitives: &'a [Vec<Primitive>],
    pub now: &'a [Pose],
    pub before: &'a [Pose],
}

/// Most solid shapes one particle meets at once (further ones are not met).
const SOLIDS_MET: usize = 4;

impl Solids<'_> {
    /// None: nothing is met as a solid.
    pub const NONE: Solids<'static> = Solids {
        shape: &[],
        primitives: &[],
        now: &[],
        before: &[],
    };

    #[inline]
    fn of(&self, j: usize) -> Option<ShapeId> {
        let s = *self.shape.get(j)?;
        self.primitives
            .get(s as usize)
            .is_some_and(|p| !p.is_empty())
            .then_some(s)
    }

    /// The contact of a particle at `x` (radius `r`) with solid shape `s`: its normal, depth, and
    /// how far the solid's surface there moved over the substep.
    fn contact(&self, s: ShapeId, x: Vec3, r: f32) -> Option<(Vec3, f32, Vec3)> {
        let s = s as usize;
        let now = self.now[s];
        let (distance, normal) = sdf::distance_and_normal(&self.primitives[s], &now, x);
        let depth = r - distance;
        if depth <= 0.0 || normal == Vec3::ZERO {
            return None;
        }
        let surface = x - normal * distance;
        let before = self.before.get(s).copied().unwrap_or(now);
        let was = before.transform_point(now.inverse().transform_point(surface));
        Some((normal, depth, surface - was))
    }

    /// The correction of a particle at `x` (at `prev` before the substep, radius `r`) by solid
    /// shape `s`: out of it along its normal, and friction against its surface's motion.
    fn correction(
        &self,
        s: ShapeId,
        x: Vec3,
        prev: Vec3,
        r: f32,
        mu_static: f32,
        mu_kinetic: f32,
    ) -> Option<Vec3> {
        let (normal, depth, moved) = self.contact(s, x, r)?;
        let rel = (x - prev) - moved;
        let tangential = rel - rel.dot(normal) * normal;
        let (slip, _) = friction(tangential, depth, 1.0, mu_static, mu_kinetic);
        Some(depth * normal + slip)
    }
}

/// The contact of particle `i` with particle `j`: the normal from `j` to `i`, how deep they
/// overlap, and `i`'s displacement over the substep relative to `j`'s. None where they do not.
#[inline]
fn pair_contact(
    pos: &[Vec3],
    prev: &[Vec3],
    radius: &[f32],
    (i, j): (usize, usize),
) -> Option<(Vec3, f32, Vec3)> {
    let d = pos[i] - pos[j];
    let dist = d.length();
    let depth = radius[i] + radius[j] - dist;
    if depth <= 0.0 {
        return None;
    }
    let normal = if dist > 1e-9 { d / dist } else { Vec3::Z };
    Some((normal, depth, (pos[i] - prev[i]) - (pos[j] - prev[j])))
}

/// The correction of pushable particle `i` by particle `j` of another shape, in the share of
/// their inverse masses: apart along their centres, and friction against their relative motion.
/// None where they do not overlap.
#[inline]
#[allow(clippy::too_many_arguments)]
fn pair_correction(
    pos: &[Vec3],
    prev: &[Vec3],
    inv_mass: &[f32],
    radius: &[f32],
    (i, j): (usize, usize),
    mu_static: f32,
    mu_kinetic: f32,
) -> Option<Vec3> {
    let (normal, depth, rel) = pair_contact(pos, prev, radius, (i, j))?;
    let wi = inv_mass[i];
    let share = wi / (wi + inv_mass[j]);
    let tangential = rel - rel.dot(normal) * normal;
    let (slip, _) = friction(tangential, depth, 1.0, mu_static, mu_kinetic);
    Some(share * (depth * normal + slip))
}

/// Sum of the contact corrections of each pushable particle into `delta`, and their number into
/// `count`; a contact with a shape that gives way (`yielding`) applies its share and marks the
/// particle in `soft`. Positions are read, never written: apply with `apply_averaged`. A particle touching
/// an immovable partner (kinematic or static) is marked in `pinned`.
#[allow(clippy::too_many_arguments)]
pub fn collision_corrections(
    pos: &[Vec3],
    prev: &[Vec3],
    inv_mass: &[f32],
    radius: &[f32],
    solids: Solids,
    yielding: Yielding,
    lists: &NeighbourLists,
    mu_static: f32,
    mu_kinetic: f32,
    delta: &mut [Vec3],
    count: &mut [u32],
    (pinned, soft): (&mut [bool], &mut [bool]),
) {
    delta
        .par_chunks_mut(CHUNK)
        .zip(count.par_chunks_mut(CHUNK))
        .zip(pinned.par_chunks_mut(CHUNK))
        .zip(soft.par_chunks_mut(CHUNK))
        .enumerate()
        .for_each(|(c, (((dch, cch), sch), softs))| {
            for k in 0..dch.len() {
                let i = c * CHUNK + k;
                let mut sum = Vec3::ZERO;
                let mut n_contacts = 0;
                let wi = inv_mass[i];
                let mut met = [ShapeId::MAX; SOLIDS_MET];
                let mut n_met = 0;
                let mut met_soft = false;
                if wi > 0.0 {
                    for &j in lists.of(i) {
                        let j = j as usize;
                        if let Some(s) = solids.of(j) {
                            if !met[..n_met].contains(&s) && n_met < SOLIDS_MET {
                                met[n_met] = s;
                                n_met += 1;
                            }
                            continue;
                        }
                        let Some(c) = (match yielding.of(j) {
                            Some(s) => pair_contact(pos, prev, radius, (i, j)).map(
                                |(normal, depth, rel)| {
                                    met_soft = true;
                                    yielding.correction(
                                        (i, s, radius[i]),
                                        (normal, depth, rel),
                                        (mu_static, mu_kinetic),
                                    )
                                },
                            ),
                            None => pair_correction(
                                pos,
                                prev,
                                inv_mass,
                                radius,
                                (i, j),
                                mu_static,
                                mu_kinetic,
                            ),
                        }) else {
                            continue;
                        };
                        sum += c;
                        n_contacts += 1;
                        sch[k] |= inv_mass[j] <= 0.0;
                    }
                    for &s in &met[..n_met] {
                        let Some(c) = (match yielding.gives_way(s) {
                            true => solids.contact(s, pos[i], radius[i]).map(
                                |(normal, depth, moved)| {
                                    met_soft = true;
                                    yielding.correction(
                                        (i, s, radius[i]),
                                        (normal, depth, (pos[i] - prev[i]) - moved),
                                        (mu_static, mu_kinetic),
                                    )
                                },
                            ),
                            false => solids
                                .correction(s, pos[i], prev[i], radius[i], mu_static, mu_kinetic),
                        }) else {
                            continue;
                        };
                        sum += c;
                        n_contacts += 1;
                        sch[k] = true;
                    }
                }
                dch[k] = sum;
                cch[k] = n_contacts;
                softs[k] = met_soft;
            }
        });
}

/// `x += relaxation * delta / count` for every particle with at least one correction.
pub fn apply_averaged(pos: &mut [Vec3], delta: &[Vec3], count: &[u32], relaxation: f32) {
    pos.par_iter_mut()
        .with_min_len(8192)
        .enumerate()
        .for_each(|(i, x)| {
            if count[i] > 0 {
                *x += relaxation * delta[i] / count[i] as f32;
            }
        });
}

/// Marks in `touched` (per shape) the kinds of bodies each shape's pushable particles touch at
/// their current positions: a kinematic one, or a particle of another dynamic shape.
pub fn note_touches(p: &Particles, lists: &NeighbourLists, touched: &mut [Touched]) {
    for i in (0..p.len()).filter(|&i| p.phase[i] == Phase::Dynamic) {
        let Some(mine) = touched.get(p.shape[i] as usize).copied() else {
            continue;
        };
        if mine.kinematic && mine.dynamic {
            continue;
        }
        let mut now = mine;
        for &j in lists.of(i) {
            let j = j as usize;
            if p.position[i].distance(p.position[j]) > p.radius[i] + p.radius[j] + TOUCH_SLACK {
                continue;
            }
            match p.phase[j] {
                Phase::Kinematic => now.kinematic = true,
                Phase::Dynamic => now.dynamic = true,
                Phase::Static => {}
            }
        }
        touched[p.shape[i] as usize] = now;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overlapping_pair_is_separated_in_inverse_mass_ratio_conserving_momentum() {
        let pos = vec![Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.015, 0.0, 0.0)];
        let prev = pos.clone();
        let inv_mass = [1.0, 3.0];
        let radius = [0.01, 0.01];
        let lists = NeighbourLists {
            offsets: vec![0, 1, 2],
            neighbours: vec![1, 0],
        };
        let mut delta = vec![Vec3::ZERO; 2];
        let mut count = vec![0; 2];
        collision_corrections(
            &pos,
            &prev,
            &inv_mass,
            &radius,
            Solids::NONE,
            Yielding::NONE,
            &lists,
            0.0,
            0.0,
            &mut delta,
            &mut count,
            (&mut [false; 2], &mut [false; 2]),
        );
        let mut after = pos.clone();
        apply_averaged(&mut after, &delta, &count, 1.0);
        assert!(
            ((after[1] - after[0]).length() - 0.02).abs() < 1e-6,
            "exactly touching afterwards"
        );
        // Momentum-like sum m*dx is zero: 1/w0 * dx0 + 1/w1 * dx1 = 0.
        let p = (after[0] - pos[0]) / inv_mass[0] + (after[1] - pos[1]) / inv_mass[1];
        assert!(p.length() < 1e-7, "{p}");
        // The lighter particle (w = 3) moves three times as far.
        assert!(((after[1] - pos[1]).length() / (after[0] - pos[0]).length() - 3.0).abs() < 1e-3);
    }

    #[test]
    fn kinematic_partner_takes_no_correction() {
        let pos = vec![Vec3::ZERO, Vec3::new(0.0, 0.0, 0.01)];
        let lists = NeighbourLists {
            offsets: vec![0, 1, 1],
            neighbours: vec![1],
        };
        let mut delta = vec![Vec3::ZERO; 2];
        let mut count = vec![0; 2];
        collision_corrections(
            &pos,
            &pos,
            &[1.0, 0.0],
            &[0.01, 0.01],
            Solids::NONE,
            Yielding::NONE,
            &lists,
            0.0,
            0.0,
            &mut delta,
            &mut count,
            (&mut [false; 2], &mut [false; 2]),
        );
        assert!(
            (delta[0] - Vec3::new(0.0, 0.0, -0.01)).length() < 1e-7,
            "dynamic particle takes the whole correction"
        );
        assert_eq!(count[1], 0);
    }
}

//! Yielding kinematic shapes: a robot under impedance control is not a rigid wall. Where it
//! pushes an object it gives way like a spring of stiffness `k` (N/m) with critical damping, so
//! an object it pushes against a resistance `F` (friction, a heavier object in its way, a visual
//! force) rests `F / k` deeper into it than where the joint angles put the link.
//!
//! This module owns the law of that give as the contact's correction (`Yielding::correction`).
//! It never finds contacts (`collide`) and never moves a shape.
//!
//! Why the law gives `F / k`: an object pushed by a link moves with its contact points (they are
//! pinned in shape matching), so each substep of length `h` the contacts move the whole object, of
//! mass `m`, by what the spring and its damper do in that time: `h^2 / m` times `k d + c v`, `d`
//! the depth and `v` the speed into the link. At rest against a steady resistance `F` (taking
//! `a h^2` off the object each substep, `a = F / m`) that is `d = F / k`. The damper is critical,
//! `c = 2 sqrt(k m)`: an undamped give plays stick and slip against the table's static friction
//! (a box pushed at 0.1 m/s by a 1000 N/m wall jerked between 0 and 0.22 m/s five times a
//! second). A sweep runs `iterations` times a substep and applies its share of each. Friction
//! with the link is Coulomb's on the normal correction so made.
//!
//! Where the object does not move with its contacts (held on the table by static friction, whose
//! pins outweigh the contacts' in shape matching) a contact moves it only by its share of the
//! weight there, so its push is scaled up by as much (`contact_share`): the body breaks free where
//! the spring's force passes static friction (without it, at 500 N/m, the rod sank into MuJoCo's
//! pushed controls and passed through them). Deeper than `RIGID_BEYOND` radii a contact is rigid
//! for the rest, so a link never passes through what it pushes.

use super::ground::friction;
use crate::world::ShapeId;
use glam::Vec3;

/// Depth, in the pushed particle's radii, beyond which a yielding contact is rigid: short of
/// where the particle's centre would cross a link's particle (its radius plus theirs) or the
/// middle of a wall two radii thick, where its normal flips (at 2, the soft wall of
/// `tests/physics.rs` was passed through). At 1, a strike's soft give (a rod at speed v sinks
/// about v sqrt(m / k)) went past it and the rigid rest threw MuJoCo's slippery_3000 over.
const RIGID_BEYOND: f32 = 1.5;

/// The kinematic shapes that give way, and what a contact with one needs to know.
#[derive(Clone, Copy)]
pub struct Yielding<'a> {
    /// Per particle, its shape.
    pub shape: &'a [ShapeId],
    /// Per shape, how far it gives way per newton (m/N; `Shapes::compliance`).
    pub compliance: &'a [f32],
    /// Per particle, the mass a contact on it moves: its rigid shape's, or its own.
    pub body_mass: &'a [f32],
    /// Per shape, the share of its weight in shape matching that its contacts with yielding
    /// shapes held at the last sweep (`contact_share`; 1 where it had none).
    pub held_share: &'a [f32],
    /// The substep's length squared, s^2.
    pub h2: f32,
    /// Contact sweeps per substep.
    pub iterations: u32,
}

impl Yielding<'_> {
    /// Nothing gives way.
    pub const NONE: Yielding<'static> = Yielding {
        shape: &[],
        compliance: &[],
        body_mass: &[],
        held_share: &[],
        h2: 0.0,
        iterations: 1,
    };

    /// Whether shape `s` gives way.
    #[inline]
    pub fn gives_way(&self, s: ShapeId) -> bool {
        self.compliance.get(s as usize).is_some_and(|&c| c > 0.0)
    }

    /// The shape of particle `j` if it gives way.
    #[inline]
    pub fn of(&self, j: usize) -> Option<ShapeId> {
        let s = *self.shape.get(j)?;
        self.gives_way(s).then_some(s)
    }

    /// One sweep's correction of pushable particle `i` (radius `r`) in contact with yielding
    /// shape `s`, the contact's normal (out of the link), depth and `i`'s displacement over the
    /// substep relative to the link's surface: the spring-damper's push along the normal (never a
    /// pull) and Coulomb friction on it. Deeper than `RIGID_BEYOND` radii the contact is rigid
    /// for the rest.
    #[inline]
    pub fn correction(
        &self,
        (i, s, r): (usize, ShapeId, f32),
        (normal, depth, rel): (Vec3, f32, Vec3),
        (mu_static, mu_kinetic): (f32, f32),
    ) -> Vec3 {
        let held = self
            .shape
            .get(i)
            .and_then(|&own| self.held_share.get(own as usize));
        let mass = self.body_mass[i] * held.copied().unwrap_or(1.0);
        let (push, slip) = self.push((self.compliance[s as usize], mass), (normal, depth, rel));
        let push = push + (depth - RIGID_BEYOND * r).max(0.0);
        let tangential = slip - slip.dot(normal) * normal;
        let (slip, _) = friction(tangential, push, 1.0, mu_static, mu_kinetic);
        push * normal + slip
    }

    /// The normal push of one sweep for compliance `c` and body mass `m`, and the displacement
    /// friction acts on.
    #[inline]
    fn push(&self, (c, m): (f32, f32), (normal, depth, rel): (Vec3, f32, Vec3)) -> (f32, Vec3) {
        // h^2 k / m, made implicit (h^2 / (h^2 + m / k)) so a stiff link stays stable.
        let spring = self.h2 / (self.h2 + c * m);
        // h c / m with c = 2 sqrt(k m): 2 h sqrt(k / m).
        let damper = (2.0 * (self.h2 / (c * m)).sqrt()).min(1.0);
        let into = (-rel.dot(normal)).max(0.0);
        let push = (spring * depth + damper * into) / self.iterations.max(1) as f32;
        (push, rel)
    }
}

/// Per shape, the share of its weight in shape matching (mass, times `pin_weight` where pinned)
/// that its particles in contact with a yielding shape (`soft`) carry; 1 where none is. A body
/// held on the table by static friction has its ground contacts pinned too, and a contact that
/// carries a tenth of the weight moves it a tenth as far: its push is scaled up by as much
/// (`Yielding::correction` takes the body's mass times this), so the body breaks free where the
/// spring's force, not a tenth of it, passes static friction.
pub fn contact_share(
    ranges: impl Iterator<Item = std::ops::Range<usize>>,
    inv_mass: &[f32],
    pinned: &[bool],
    soft: &[bool],
    pin_weight: f32,
    share: &mut [f32],
) {
    for (s, range) in ranges.enumerate() {
        let (mut held, mut all) = (0.0f32, 0.0f32);
        for i in range {
            if inv_mass[i] <= 0.0 {
                continue;
            }
            let w = if pinned[i] { pin_weight } else { 1.0 } / inv_mass[i];
            all += w;
            if soft[i] {
                held += w;
            }
        }
        share[s] = if held > 0.0 {
            (held / all).clamp(1e-3, 1.0)
        } else {
            1.0
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stiffer_link_pushes_harder_and_only_a_link_that_gives_way_yields() {
        let compliance = [0.0, 1e-3, 1e-4];
        let y = Yielding {
            shape: &[0, 1, 2],
            compliance: &compliance,
            body_mass: &[0.5],
            held_share: &[1.0],
            h2: (1.0f32 / 600.0).powi(2),
            iterations: 4,
        };
        assert!(!y.gives_way(0) && y.gives_way(1) && y.gives_way(2));
        assert_eq!(y.of(0), None);
        assert_eq!(Yielding::NONE.of(1), None);
        let at = |s| y.correction((0, s, 0.005), (Vec3::X, 0.002, Vec3::ZERO), (0.0, 0.0));
        // 0.5 kg on a 1000 N/m link in 1/600 s substeps: h^2 / (h^2 + m / k) ~ 0.0055 of the
        // depth a substep, a quarter of that a sweep.
        let soft = at(1);
        let expected = 0.002 * 2.778e-6 / (2.778e-6 + 5e-4) / 4.0;
        assert!(
            (soft.x - expected).abs() < 1e-3 * expected,
            "{soft} vs {expected}"
        );
        assert!(at(2).x > 5.0 * soft.x);
        // Moving out of the link: no pull back.
        let leaving = y.correction((0, 1, 0.005), (Vec3::X, 0.0, Vec3::X * 0.01), (0.0, 0.0));
        assert_eq!(leaving, Vec3::ZERO);
        // Deeper than 1.5 radii the contact is rigid for the rest.
        let deep = y.correction((0, 1, 0.005), (Vec3::X, 0.0105, Vec3::ZERO), (0.0, 0.0));
        assert!((deep.x - 0.003).abs() < 1e-4, "{deep}");
    }
}

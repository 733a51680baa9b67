//! Ground plane: non-penetration with static and kinetic Coulomb friction, projected per particle
//! (each particle touches the plane through exactly one constraint, so no averaging is needed).

use glam::Vec3;
use rayon::prelude::*;

/// The plane `normal . x = height`.
#[derive(Clone, Copy, Debug)]
pub struct Plane {
    pub normal: Vec3,
    pub height: f32,
}

/// Position-level Coulomb friction (Macklin et al. 2014): cancel the tangential displacement of
/// this substep if it is within the static cone `mu_s * depth`, else shorten it by `mu_k * depth`.
/// `depth` is the normal correction just applied, which stands for the normal impulse.
/// Returns the correction and whether static friction holds (the contact sticks).
#[inline]
pub fn friction(tangential: Vec3, depth: f32, mu_static: f32, mu_kinetic: f32) -> (Vec3, bool) {
    let len = tangential.length();
    if len <= mu_static * depth {
        (-tangential, mu_static > 0.0)
    } else {
        (-tangential * (mu_kinetic * depth / len).min(1.0), false)
    }
}

/// How a particle touches the ground in a sweep.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Grip {
    #[default]
    Free,
    /// Held by static friction.
    Sticks,
    /// Sliding under kinetic friction.
    Slips,
}

/// Push dynamic particles out of the plane and apply friction against their substep-start
/// positions `prev`. `coefficients(p)` gives (static, kinetic) friction at a contact point.
/// Each touching particle's `grip` says whether static friction holds it or it slides.
pub fn project_ground(
    pos: &mut [Vec3],
    prev: &[Vec3],
    radius: &[f32],
    inv_mass: &[f32],
    plane: Plane,
    coefficients: &(dyn Fn(Vec3) -> (f32, f32) + Sync),
    grip: &mut [Grip],
) {
    pos.par_iter_mut()
        .zip(grip.par_iter_mut())
        .with_min_len(8192)
        .enumerate()
        .for_each(|(i, (x, grip))| {
            if inv_mass[i] <= 0.0 {
                return;
            }
            let depth = radius[i] - (plane.normal.dot(*x) - plane.height);
            if depth <= 0.0 {
                return;
            }
            *x += depth * plane.normal;
            let moved = *x - prev[i];
            let tangential = moved - moved.dot(plane.normal) * plane.normal;
            let (mu_s, mu_k) = coefficients(*x);
            let (correction, sticks) = friction(tangential, depth, mu_s, mu_k);
            *x += correction;
            *grip = if sticks { Grip::Sticks } else { Grip::Slips };
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn static_friction_cancels_small_slips_and_kinetic_shortens_large_ones() {
        let t = Vec3::new(1e-4, 0.0, 0.0);
        let friction_correction = |t, d, s, k| friction(t, d, s, k).0;
        assert_eq!(friction_correction(t, 1e-3, 0.5, 0.4), -t);
        let big = Vec3::new(1e-2, 0.0, 0.0);
        let c = friction_correction(big, 1e-3, 0.5, 0.4);
        assert!(
            (c.x + 0.4e-3).abs() < 1e-9,
            "kinetic friction removes mu_k * depth: {c}"
        );
        assert_eq!(friction_correction(Vec3::ZERO, 0.0, 0.5, 0.4), Vec3::ZERO);
        assert!(
            friction(t, 1e-3, 0.5, 0.4).1,
            "a slip inside the static cone sticks"
        );
        assert!(!friction(big, 1e-3, 0.5, 0.4).1);
        assert!(
            !friction(Vec3::ZERO, 1e-3, 0.0, 0.0).1,
            "frictionless contacts never stick"
        );
    }

    #[test]
    fn penetrating_particle_is_lifted_to_its_radius_on_a_tilted_plane() {
        let n = Vec3::new(0.1, 0.0, 1.0).normalize();
        let plane = Plane {
            normal: n,
            height: 0.02,
        };
        let start = Vec3::new(0.3, 0.1, 0.0);
        let mut pos = vec![start];
        let prev = vec![start];
        project_ground(
            &mut pos,
            &prev,
            &[0.01],
            &[1.0],
            plane,
            &|_| (0.0, 0.0),
            &mut [Grip::Free],
        );
        assert!((n.dot(pos[0]) - plane.height - 0.01).abs() < 1e-6);
        // Frictionless: the correction is purely along the normal.
        let d = pos[0] - start;
        assert!(d.cross(n).length() < 1e-6);
        // Kinematic/static particles (inv_mass 0) are never touched.
        let mut pinned = vec![start];
        project_ground(
            &mut pinned,
            &prev,
            &[0.01],
            &[0.0],
            plane,
            &|_| (0.0, 0.0),
            &mut [Grip::Free],
        );
        assert_eq!(pinned[0], start);
    }
}

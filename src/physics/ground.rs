//! Ground plane: non-penetration with static and kinetic Coulomb friction, projected per particle
//! (each particle touches the plane through exactly one constraint, so no averaging is needed),
//! and where a rigid shape bears on it (`Footing`: its whole lowest layer, or its corners).
use glam::Vec3;
use rayon::prelude::*;

/// The plane `normal . x = height`.
#[derive(Clone, Copy, Debug)]
pub struct Plane {
    pub normal: Vec3,
    pub height: f32,
}

/// Position-level Coulomb friction (Macklin et al. 2014): cancel the tangential displacement of
/// this substep if it is within the static cone `mu_s * depth / load`, else shorten it by
/// `mu_k * depth`. `depth` is the normal correction just applied, which stands for the normal
/// impulse; `load` is how many particles' weight the contact carries (1 where the weight is spread
/// evenly). A contact bearing `load` shares sinks `load` times deeper, since shape matching spreads
/// its correction over the shape, so its kinetic friction is `load` times the even share (as it
/// should be) but whether it sticks depends on how fast it slides, not on its load: the cone is
/// judged on its own share. Returns the correction and whether static friction holds.
#[inline]
pub fn friction(
    tangential: Vec3,
    depth: f32,
    load: f32,
    mu_static: f32,
    mu_kinetic: f32,
) -> (Vec3, bool) {
    let len = tangential.length();
    if len <= mu_static * depth / load {
        (-tangential, mu_static > 0.0)
    } else {
        (-tangential * (mu_kinetic * depth / len).min(load), false)
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

/// How each particle meets the ground: how close (m) its centre comes before it touches, and how
/// many particles' weight it bears there (1, more at the corners that bear a shape on `Corners`
/// support; see `friction`).
#[derive(Clone, Debug, Default)]
pub struct Footing {
    pub radius: Vec<f32>,
    pub load: Vec<f32>,
}

/// Push dynamic particles out of the plane and apply friction against their substep-start
/// positions `prev`. `coefficients(p)` gives (static, kinetic) friction at a contact point; a
/// particle touches and bears as its `footing` says.
/// Each touching particle's `grip` says whether static friction holds it or it slides.
pub fn project_ground(
    pos: &mut [Vec3],
    prev: &[Vec3],
    footing: &Footing,
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
            let depth = footing.radius[i] - (plane.normal.dot(*x) - plane.height);
            if depth <= 0.0 {
                return;
            }
            *x += depth * plane.normal;
            let moved = *x - prev[i];
            let tangential = moved - moved.dot(plane.normal) * plane.normal;
            let (mu_s, mu_k) = coefficients(*x);
            let (correction, sticks) = friction(tangential, depth, footing.load[i], mu_s, mu_k);
            *x += correction;
            *grip = if sticks { Grip::Sticks } else { Grip::Slips };
        });
}

/// How far (m) a particle that does not bear may sink into the plane before it touches: the rest
/// of a face resting on its corners stands clear of the table by this much, as a slightly hollow
/// base would. Larger than the few tenths of a millimetre a corner sinks while it carries the
/// shape's weight, small against a particle.
pub const SUPPORT_RELIEF: f32 = 0.002;

/// Directions (in the footprint's plane) whose extreme points bear a shape on `Corners` support.
/// Offset by half a step from the footprint's principal axes, so an edge along one of them (a
/// box's, a bar's) has one extreme point per direction, a corner, not a tie along the edge.
const SUPPORT_DIRECTIONS: usize = 16;

/// How much of a rigid shape's weight each of its particles bears when it rests on its corners,
/// in particles' shares: its lowest layer (within half a particle radius of the lowest along
/// `down`, in the shape's rest frame) bears on the footprint's extreme points in
/// `SUPPORT_DIRECTIONS` directions, the vertices of its support polygon (a box's four corners, a
/// disk's rim, a T's six corners), each carrying `bottom layer / vertices` shares; every other
/// particle bears 0.
pub fn bearing_loads(rest: &[Vec3], radius: &[f32], down: Vec3) -> Vec<f32> {
    let mut bears = vec![false; rest.len()];
    let Some(lowest) = rest.iter().map(|x| x.dot(down)).reduce(f32::max) else {
        return vec![0.0; rest.len()];
    };
    let bottom: Vec<usize> = (0..rest.len())
        .filter(|&i| rest[i].dot(down) >= lowest - 0.5 * radius[i])
        .collect();
    // The footprint's principal axes: the angle of its 2-D second moment's major axis.
    let (u, v) = down.any_orthonormal_pair();
    let flat = |i: usize| glam::Vec2::new(rest[i].dot(u), rest[i].dot(v));
    let mean = bottom.iter().map(|&i| flat(i)).sum::<glam::Vec2>() / bottom.len().max(1) as f32;
    let (mut sxx, mut syy, mut sxy) = (0.0f32, 0.0f32, 0.0f32);
    for &i in &bottom {
        let q = flat(i) - mean;
        (sxx, syy, sxy) = (sxx + q.x * q.x, syy + q.y * q.y, sxy + q.x * q.y);
    }
    let major = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    for k in 0..SUPPORT_DIRECTIONS {
        let angle = major + (k as f32 + 0.5) * std::f32::consts::TAU / SUPPORT_DIRECTIONS as f32;
        let d = angle.cos() * u + angle.sin() * v;
        let extreme = bottom
            .iter()
            .copied()
            .max_by(|&a, &b| rest[a].dot(d).total_cmp(&rest[b].dot(d)));
        if let Some(i) = extreme {
            bears[i] = true;
        }
    }
    let share = bottom.len() as f32 / bears.iter().filter(|&&b| b).count().max(1) as f32;
    bears.iter().map(|&b| if b { share } else { 0.0 }).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn static_friction_cancels_small_slips_and_kinetic_shortens_large_ones() {
        let t = Vec3::new(1e-4, 0.0, 0.0);
        let friction_correction = |t, d, s, k| friction(t, d, 1.0, s, k).0;
        assert_eq!(friction_correction(t, 1e-3, 0.5, 0.4), -t);
        let big = Vec3::new(1e-2, 0.0, 0.0);
        let c = friction_correction(big, 1e-3, 0.5, 0.4);
        assert!(
            (c.x + 0.4e-3).abs() < 1e-9,
            "kinetic friction removes mu_k * depth: {c}"
        );
        assert_eq!(friction_correction(Vec3::ZERO, 0.0, 0.5, 0.4), Vec3::ZERO);
        assert!(
            friction(t, 1e-3, 1.0, 0.5, 0.4).1,
            "a slip inside the static cone sticks"
        );
        assert!(!friction(big, 1e-3, 1.0, 0.5, 0.4).1);
        // A contact carrying four particles' weight sinks four times as deep: it removes four
        // times the kinetic friction but sticks at the same slip as one carrying its own.
        let slip = Vec3::new(0.8e-3, 0.0, 0.0);
        assert!(!friction(slip, 1e-3, 1.0, 0.5, 0.4).1);
        assert!(!friction(slip, 4e-3, 4.0, 0.5, 0.4).1);
        assert!(
            friction(slip, 4e-3, 1.0, 0.5, 0.4).1,
            "unshared, the deep contact sticks"
        );
        let c = friction(big, 4e-3, 4.0, 0.5, 0.4).0;
        assert!(
            (c.x + 1.6e-3).abs() < 1e-9,
            "kinetic friction removes mu_k * depth: {c}"
        );
        assert!(
            !friction(Vec3::ZERO, 1e-3, 1.0, 0.0, 0.0).1,
            "frictionless contacts never stick"
        );
    }

    #[test]
    fn a_footprint_bears_on_its_support_polygons_corners_whatever_its_heading() {
        use crate::world::{box_lattice, cylinder_lattice, t_block_lattice};
        let lowest = |rest: &[Vec3]| rest.iter().map(|x| x.z).fold(f32::MAX, f32::min);
        let bearing = |rest: &[Vec3]| -> Vec<Vec3> {
            let loads = bearing_loads(rest, &vec![0.005; rest.len()], -Vec3::Z);
            // The bearing points carry the whole bottom layer's weight between them.
            let bottom = rest.iter().filter(|x| x.z < lowest(rest) + 0.0025).count() as f32;
            let carried: f32 = loads.iter().sum();
            assert!(
                (carried - bottom).abs() < 1e-3,
                "{carried} of {bottom} shares"
            );
            (0..rest.len())
                .filter(|&i| loads[i] > 0.0)
                .map(|i| rest[i])
                .collect()
        };
        // A bar, turned to any heading in its rest frame: its four bottom corners, nothing else.
        for yaw in [0.0f32, 0.2, std::f32::consts::FRAC_PI_4, 1.3] {
            let turn = glam::Quat::from_rotation_z(yaw);
            let bar: Vec<Vec3> = box_lattice(Vec3::new(0.095, 0.0175, 0.025), 0.01)
                .into_iter()
                .map(|x| turn * x)
                .collect();
            let extent = bar
                .iter()
                .fold(Vec3::ZERO, |m, x| m.max((turn.inverse() * *x).abs()));
            let corners = bearing(&bar);
            assert_eq!(corners.len(), 4, "yaw {yaw}: {corners:?}");
            for c in &corners {
                let local = (turn.inverse() * *c).abs();
                assert!(
                    (local - extent).truncate().abs().max_element() < 1e-5,
                    "yaw {yaw}: {local} is not a corner of {extent}"
                );
                assert!(
                    (c.z - lowest(&bar)).abs() < 1e-6,
                    "yaw {yaw}: {c} is not on the bottom"
                );
            }
        }
        // A T: the bar's four outer corners and the stem's two far ones, not the inner two where
        // the stem meets the bar (they are inside the support polygon).
        let t = t_block_lattice(0.2, 0.05, 0.04, 0.01);
        let corners = bearing(&t);
        assert_eq!(corners.len(), 6, "{corners:?}");
        let far = |x: &Vec3| (x.x.abs() - 0.095).abs() < 1e-5 || (x.y + 0.095).abs() < 1e-5;
        assert!(corners.iter().all(far), "{corners:?}");
        // A disk: points of its rim only.
        let disk = cylinder_lattice(0.04, 0.03, 0.01);
        let rim = disk
            .iter()
            .map(|x| x.truncate().length())
            .fold(0.0f32, f32::max);
        let corners = bearing(&disk);
        assert!(corners.len() >= 4, "{corners:?}");
        assert!(
            corners.iter().all(|x| x.truncate().length() > rim - 0.006),
            "{corners:?}"
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
        let one_particle = Footing {
            radius: vec![0.01],
            load: vec![1.0],
        };
        let mut pos = vec![start];
        let prev = vec![start];
        project_ground(
            &mut pos,
            &prev,
            &one_particle,
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
            &one_particle,
            &[0.0],
            plane,
            &|_| (0.0, 0.0),
            &mut [Grip::Free],
        );
        assert_eq!(pinned[0], start);
    }
}

//! Signed distances to the exact solids of kinematic shapes (`world::Primitive`, a URDF's boxes,
//! cylinders, capsules and spheres), negative inside, and their outward normals: how a particle
//! meets a link with `robot.contact: exact`. Never moves anything.

use crate::math::Pose;
use crate::world::{Primitive, Solid};
use glam::{Vec2, Vec3};

/// Boxes' and cylinders' edges are rounded by this (m, at most half their smallest size): a rod's
/// flat end coming down on an object's edge pushed it straight into the table and jammed it
/// there (MuJoCo's control_pushed_3501, a T-block: thrown 13 cm). About a particle's radius, as
/// rounded as the links' particles were.
const ROUNDING: f32 = 0.006;

/// Step (m) of the central differences the normal is taken from.
const NORMAL_STEP: f32 = 1e-5;

fn solid_distance(solid: &Solid, p: Vec3) -> f32 {
    match *solid {
        Solid::Box { half } => {
            let r = ROUNDING.min(half.min_element());
            let q = p.abs() - (half - Vec3::splat(r));
            q.max(Vec3::ZERO).length() + q.max_element().min(0.0) - r
        }
        Solid::Cylinder {
            radius,
            half_length,
        } => {
            let r = ROUNDING.min(radius).min(half_length);
            let q = Vec2::new(
                p.truncate().length() - (radius - r),
                p.z.abs() - (half_length - r),
            );
            q.max(Vec2::ZERO).length() + q.max_element().min(0.0) - r
        }
        Solid::Capsule {
            radius,
            half_length,
        } => (p - Vec3::new(0.0, 0.0, p.z.clamp(-half_length, half_length))).length() - radius,
        Solid::Sphere { radius } => p.length() - radius,
    }
}

/// Distance from body-frame point `p` to the union of `primitives`.
pub fn distance(primitives: &[Primitive], p: Vec3) -> f32 {
    primitives
        .iter()
        .map(|prim| solid_distance(&prim.solid, prim.origin.inverse().transform_point(p)))
        .fold(f32::INFINITY, f32::min)
}

/// Distance and outward unit normal (world frame) at world point `x` from the solids of a shape
/// standing at `pose`.
pub fn distance_and_normal(primitives: &[Primitive], pose: &Pose, x: Vec3) -> (f32, Vec3) {
    let p = pose.inverse().transform_point(x);
    let along = |axis: Vec3| {
        distance(primitives, p + axis * NORMAL_STEP) - distance(primitives, p - axis * NORMAL_STEP)
    };
    let gradient = Vec3::new(along(Vec3::X), along(Vec3::Y), along(Vec3::Z));
    (
        distance(primitives, p),
        pose.rotation * gradient.normalize_or_zero(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;

    fn at(origin: Pose, solid: Solid) -> Vec<Primitive> {
        vec![Primitive { origin, solid }]
    }

    #[test]
    fn distances_to_a_box_and_a_cylinder_are_their_surfaces_with_rounded_edges() {
        let cube = at(
            Pose::IDENTITY,
            Solid::Box {
                half: Vec3::new(0.05, 0.03, 0.02),
            },
        );
        // Off a face: the distance to its plane; inside: minus the distance to the nearest face.
        assert!((distance(&cube, Vec3::new(0.08, 0.0, 0.0)) - 0.03).abs() < 1e-6);
        assert!((distance(&cube, Vec3::new(0.0, 0.0, 0.015)) + 0.005).abs() < 1e-6);
        // Off an edge, diagonally: the rounding's arc, not the sharp edge.
        let corner = Vec3::new(0.05, 0.03, 0.0) + Vec3::new(1.0, 1.0, 0.0).normalize() * 0.01;
        let rounded = 0.01 + ROUNDING * (2f32.sqrt() - 1.0);
        assert!((distance(&cube, corner) - rounded).abs() < 1e-5);
        // A cylinder along z, turned and moved by its origin.
        let origin = Pose::new(
            Vec3::new(0.1, 0.0, 0.0),
            Quat::from_rotation_x(std::f32::consts::FRAC_PI_2),
        );
        let rod = at(
            origin,
            Solid::Cylinder {
                radius: 0.015,
                half_length: 0.076,
            },
        );
        // Its axis now runs along -y through (0.1, 0, 0): 2 cm off it sideways is 5 mm out.
        assert!((distance(&rod, Vec3::new(0.12, 0.05, 0.0)) - 0.005).abs() < 1e-6);
        assert!((distance(&rod, Vec3::new(0.1, -0.08, 0.0)) - 0.004).abs() < 1e-6);
        let ball = at(Pose::IDENTITY, Solid::Sphere { radius: 0.02 });
        assert!((distance(&ball, Vec3::new(0.0, 0.03, 0.0)) - 0.01).abs() < 1e-6);
        let capsule = at(
            Pose::IDENTITY,
            Solid::Capsule {
                radius: 0.01,
                half_length: 0.05,
            },
        );
        assert!((distance(&capsule, Vec3::new(0.0, 0.0, 0.07)) - 0.01).abs() < 1e-6);
    }

    #[test]
    fn the_normal_is_the_distances_gradient_turned_with_the_shape() {
        let plate = at(
            Pose::IDENTITY,
            Solid::Box {
                half: Vec3::new(0.1, 0.1, 0.01),
            },
        );
        let pose = Pose::new(Vec3::new(0.0, 0.0, 0.5), Quat::from_rotation_y(0.3));
        let x = pose.transform_point(Vec3::new(0.02, -0.03, 0.014));
        let (d, n) = distance_and_normal(&plate, &pose, x);
        assert!((d - 0.004).abs() < 1e-5, "{d}");
        assert!((n - pose.rotation * Vec3::Z).length() < 1e-3, "{n}");
    }
}

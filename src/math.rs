//! Small geometric helpers shared by physics, rendering and I/O: rigid poses and the
//! rotational part of a deformation. Pure functions, unit-tested here.

use glam::{Mat3, Quat, Vec3};
use serde::{Deserialize, Serialize};

/// A rigid transform from a body frame to the world: `world = rotation * body + translation`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub translation: Vec3,
    pub rotation: Quat,
}

impl Default for Pose {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Pose {
    pub const IDENTITY: Pose = Pose {
        translation: Vec3::ZERO,
        rotation: Quat::IDENTITY,
    };

    pub fn new(translation: Vec3, rotation: Quat) -> Self {
        Self {
            translation,
            rotation,
        }
    }

    pub fn from_translation(translation: Vec3) -> Self {
        Self {
            translation,
            rotation: Quat::IDENTITY,
        }
    }

    pub fn transform_point(&self, p: Vec3) -> Vec3 {
        self.rotation * p + self.translation
    }

    pub fn inverse(&self) -> Pose {
        let r = self.rotation.inverse();
        Pose {
            translation: -(r * self.translation),
            rotation: r,
        }
    }

    /// `self * other`: apply `other` first, then `self`.
    pub fn mul(&self, other: &Pose) -> Pose {
        Pose {
            translation: self.transform_point(other.translation),
            rotation: (self.rotation * other.rotation).normalize(),
        }
    }

    /// Interpolate between two poses: linear in translation, spherical in rotation.
    pub fn interpolate(&self, other: &Pose, s: f32) -> Pose {
        Pose {
            translation: self.translation.lerp(other.translation, s),
            rotation: self.rotation.slerp(other.rotation, s).normalize(),
        }
    }
}

/// The rotation closest to `a` in the Frobenius sense, i.e. the rotational factor of its polar
/// decomposition, found by the iterative scheme of Müller et al. (2016, "A robust method to extract
/// the rotational part of deformations"). `guess` warm-starts it (the previous rotation of the same
/// shape), which makes a handful of iterations enough and keeps degenerate cases (flat or collinear
/// point sets) continuous in time.
pub fn extract_rotation(a: &Mat3, guess: Quat, max_iterations: usize) -> Quat {
    // The iteration only depends on the direction of `a`; normalising keeps f32 well scaled for tiny
    // shapes (moment matrices of a few-centimetre object are ~1e-6).
    let norm =
        (a.x_axis.length_squared() + a.y_axis.length_squared() + a.z_axis.length_squared()).sqrt();
    if !norm.is_finite() || norm < 1e-30 {
        return guess;
    }
    let a = *a * (1.0 / norm);
    let mut q = guess.normalize();
    for _ in 0..max_iterations {
        let r = Mat3::from_quat(q);
        let torque = r.x_axis.cross(a.x_axis) + r.y_axis.cross(a.y_axis) + r.z_axis.cross(a.z_axis);
        let alignment = r.x_axis.dot(a.x_axis) + r.y_axis.dot(a.y_axis) + r.z_axis.dot(a.z_axis);
        let omega = torque / (alignment.abs() + 1e-9);
        let angle = omega.length();
        if angle < 1e-7 {
            break;
        }
        q = (Quat::from_axis_angle(omega / angle, angle) * q).normalize();
    }
    q
}

/// Angle in radians between two rotations.
pub fn rotation_angle_between(a: Quat, b: Quat) -> f32 {
    let d = (a.inverse() * b).normalize();
    2.0 * d.w.abs().clamp(0.0, 1.0).acos()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn approx_quat(a: Quat, b: Quat, tol: f32) -> bool {
        rotation_angle_between(a, b) < tol
    }

    #[test]
    fn pose_inverse_and_composition_round_trip() {
        let p = Pose::new(
            Vec3::new(0.3, -0.2, 1.0),
            Quat::from_euler(glam::EulerRot::XYZ, 0.3, -1.1, 2.0),
        );
        let q = p.inverse();
        let x = Vec3::new(0.1, 0.5, -0.7);
        assert!((q.transform_point(p.transform_point(x)) - x).length() < 1e-5);
        let id = p.mul(&q);
        assert!(id.translation.length() < 1e-5);
        assert!(approx_quat(id.rotation, Quat::IDENTITY, 1e-3));
    }

    #[test]
    fn pose_interpolation_hits_both_ends_and_midpoint() {
        let a = Pose::from_translation(Vec3::ZERO);
        let b = Pose::new(Vec3::new(2.0, 0.0, 0.0), Quat::from_rotation_z(1.0));
        let m = a.interpolate(&b, 0.5);
        assert!((m.translation - Vec3::new(1.0, 0.0, 0.0)).length() < 1e-6);
        assert!(approx_quat(m.rotation, Quat::from_rotation_z(0.5), 1e-4));
        assert!(approx_quat(
            a.interpolate(&b, 1.0).rotation,
            b.rotation,
            1e-4
        ));
    }

    #[test]
    fn extracts_rotation_from_rotation_times_symmetric_stretch() {
        // A = R S with S symmetric positive definite: the polar factor is exactly R.
        let r = Quat::from_euler(glam::EulerRot::ZYX, 2.5, -0.7, 0.4);
        let s = Mat3::from_cols(
            Vec3::new(2.0, 0.3, 0.1),
            Vec3::new(0.3, 1.0, -0.2),
            Vec3::new(0.1, -0.2, 0.5),
        );
        let a = Mat3::from_quat(r) * s;
        // Start far away (identity) with enough iterations, then warm-started with few.
        let q = extract_rotation(&a, Quat::IDENTITY, 100);
        assert!(approx_quat(q, r, 1e-3), "got {q:?}, want {r:?}");
        let near = (Quat::from_rotation_x(0.05) * r).normalize();
        let q2 = extract_rotation(&a, near, 8);
        assert!(approx_quat(q2, r, 1e-3));
    }

    #[test]
    fn rotation_extraction_is_scale_invariant_for_tiny_matrices() {
        let r = Quat::from_rotation_y(0.8);
        let a = Mat3::from_quat(r) * 1e-7;
        let q = extract_rotation(&a, Quat::IDENTITY, 50);
        assert!(approx_quat(q, r, 1e-3));
    }

    #[test]
    fn degenerate_matrix_keeps_guess() {
        let g = Quat::from_rotation_z(0.3);
        assert_eq!(extract_rotation(&Mat3::ZERO, g, 10), g);
        let nan = Mat3::from_cols(Vec3::NAN, Vec3::X, Vec3::Y);
        assert_eq!(extract_rotation(&nan, g, 10), g);
    }
}

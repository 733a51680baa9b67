//! Pinhole cameras in the optical frame (REP-105: z forward, x right, y down).
//!
//! Intrinsics use continuous pixel coordinates: pixel `(i, j)` covers `[i, i+1) x [j, j+1)` and
//! is sampled at its centre `(i + 0.5, j + 0.5)`. ROS `CameraInfo` / OpenCV put pixel centres at
//! integers, so their principal point converts with `+0.5` (`Camera::from_opencv`).

use crate::math::Pose;
use glam::{Mat3, Vec3};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    /// World to camera optical frame.
    pub world_to_camera: Pose,
}

impl Camera {
    /// From OpenCV / ROS `CameraInfo` intrinsics (pixel centres at integer coordinates).
    pub fn from_opencv(
        width: u32,
        height: u32,
        fx: f32,
        fy: f32,
        cx: f32,
        cy: f32,
        world_to_camera: Pose,
    ) -> Self {
        Self {
            width,
            height,
            fx,
            fy,
            cx: cx + 0.5,
            cy: cy + 0.5,
            world_to_camera,
        }
    }

    /// A camera at `eye` looking at `target`, image y pointing as close to world -z as possible.
    pub fn look_at(width: u32, height: u32, fx: f32, eye: Vec3, target: Vec3) -> Self {
        let z = (target - eye).normalize();
        let down = Vec3::NEG_Z;
        let x = down.cross(z).try_normalize().unwrap_or(Vec3::X);
        let y = z.cross(x);
        // Rows of the world-to-camera rotation are the camera axes in world coordinates.
        let rot = Mat3::from_cols(x, y, z).transpose();
        let q = glam::Quat::from_mat3(&rot).normalize();
        let world_to_camera = Pose::new(-(q * eye), q);
        Self {
            width,
            height,
            fx,
            fy: fx,
            cx: width as f32 / 2.0,
            cy: height as f32 / 2.0,
            world_to_camera,
        }
    }

    /// Project a world point to continuous pixel coordinates and depth.
    pub fn project(&self, p: Vec3) -> (f32, f32, f32) {
        let c = self.world_to_camera.transform_point(p);
        (
            self.fx * c.x / c.z + self.cx,
            self.fy * c.y / c.z + self.cy,
            c.z,
        )
    }

    /// The row-major index of the pixel a world point projects into; None behind the camera or
    /// outside the image.
    pub fn pixel_of(&self, p: Vec3) -> Option<usize> {
        self.pixel_and_depth_of(p).map(|(k, _)| k)
    }

    /// `pixel_of`, with the point's depth (m, along the optical axis) from the same projection.
    pub fn pixel_and_depth_of(&self, p: Vec3) -> Option<(usize, f32)> {
        let (u, v, depth) = self.project(p);
        let inside = depth > 0.0
            && (0.0..self.width as f32).contains(&u)
            && (0.0..self.height as f32).contains(&v);
        inside.then(|| (v as usize * self.width as usize + u as usize, depth))
    }

    pub fn rotation(&self) -> Mat3 {
        Mat3::from_quat(self.world_to_camera.rotation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_puts_the_target_at_the_principal_point_and_world_up_at_image_up() {
        let cam = Camera::look_at(
            640,
            360,
            400.0,
            Vec3::new(1.0, -0.5, 0.8),
            Vec3::new(0.0, 0.1, 0.0),
        );
        let (u, v, z) = cam.project(Vec3::new(0.0, 0.1, 0.0));
        assert!((u - 320.0).abs() < 1e-3 && (v - 180.0).abs() < 1e-3 && z > 0.0);
        // A point above the target appears higher in the image (smaller v).
        let (_, v_up, _) = cam.project(Vec3::new(0.0, 0.1, 0.1));
        assert!(v_up < v);
    }

    #[test]
    fn opencv_principal_point_moves_half_a_pixel() {
        let c = Camera::from_opencv(10, 10, 5.0, 5.0, 4.5, 4.5, Pose::IDENTITY);
        assert_eq!((c.cx, c.cy), (5.0, 5.0));
        // The optical axis hits the centre of the image: between pixels 4 and 5 for 10 pixels.
        let (u, _, _) = c.project(Vec3::new(0.0, 0.0, 1.0));
        assert_eq!(u, 5.0);
    }
}

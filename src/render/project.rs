//! EWA projection of one 3-D Gaussian into a camera, and its exact backward pass. Pure functions
//! over one Gaussian, shared by the CPU backend and used as the reference for the GPU kernels.
//!
//! Forward: `t = W mu + t_cw`; `Sigma = R(q) diag(exp(2 s)) R(q)^T`; `Sigma2 = J W Sigma W^T J^T +
//! blur I` with the perspective Jacobian `J` at `t` (its x/z, y/z clamped to 1.3 x the field of view
//! as in the reference rasteriser); conic = inverse of `Sigma2`; opacity = sigmoid(logit).

// Comparisons are written `!(x <= limit)` on purpose: NaN must fail them.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::{Camera, RenderSettings};
use glam::{Mat3, Vec2, Vec3, Vec4};

/// One Gaussian in the unconstrained form the optimiser uses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GaussianParams {
    pub mean: Vec3,
    /// Quaternion x, y, z, w, not necessarily unit (normalised inside).
    pub rotation: Vec4,
    /// Natural log of the standard deviations, metres.
    pub log_scale: Vec3,
    pub opacity_logit: f32,
    pub colour: Vec3,
}

/// A Gaussian on the image plane.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Projected {
    /// Mean in continuous pixel coordinates.
    pub mean: Vec2,
    /// Inverse 2-D covariance (a, b, c): the quadratic form is a dx^2 + 2 b dx dy + c dy^2.
    pub conic: Vec3,
    pub depth: f32,
    /// Half size in pixels of the square holding the cut-off ellipse.
    pub radius: f32,
    pub opacity: f32,
    pub colour: Vec3,
}

/// Gradient of the loss with respect to a `Projected`'s fields.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ProjectedGrad {
    pub mean: Vec2,
    pub conic: Vec3,
    pub depth: f32,
    pub opacity: f32,
    pub colour: Vec3,
}

/// Gradient of the loss with respect to `GaussianParams`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ParamGrad {
    pub mean: Vec3,
    pub rotation: Vec4,
    pub log_scale: Vec3,
    pub opacity_logit: f32,
    pub colour: Vec3,
}

pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

pub fn logit(p: f32) -> f32 {
    let p = p.clamp(1e-6, 1.0 - 1e-6);
    (p / (1.0 - p)).ln()
}

/// Rotation matrix of the unit quaternion `q` (x, y, z, w).
fn rotation_matrix(q: Vec4) -> Mat3 {
    let (x, y, z, w) = (q.x, q.y, q.z, q.w);
    // Columns of R.
    Mat3::from_cols(
        Vec3::new(
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y + w * z),
            2.0 * (x * z - w * y),
        ),
        Vec3::new(
            2.0 * (x * y - w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z + w * x),
        ),
        Vec3::new(
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            1.0 - 2.0 * (x * x + y * y),
        ),
    )
}

fn outer(a: Vec3, b: Vec3) -> Mat3 {
    Mat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// `sum_ij a_ij b_ij`
fn frobenius(a: &Mat3, b: &Mat3) -> f32 {
    a.x_axis.dot(b.x_axis) + a.y_axis.dot(b.y_axis) + a.z_axis.dot(b.z_axis)
}

/// Everything the forward pass computes that the backward pass needs again.
struct Intermediate {
    t: Vec3,
    /// Clamped x/z and y/z and whether each was clamped.
    u: Vec2,
    clamped: [bool; 2],
    j0: Vec3,
    j1: Vec3,
    /// Camera-frame 3-D covariance `W Sigma W^T`.
    m: Mat3,
    w: Mat3,
    r: Mat3,
    q: Vec4,
    q_norm: f32,
    d: Vec3,
    /// Unblurred-plus-blur 2-D covariance entries A, B, C.
    abc: Vec3,
}

fn forward_intermediate(
    g: &GaussianParams,
    cam: &Camera,
    s: &RenderSettings,
) -> Option<Intermediate> {
    let w = cam.rotation();
    let t = w * g.mean + cam.world_to_camera.translation;
    if !(t.z >= s.near) || !t.is_finite() {
        return None;
    }
    let lim = Vec2::new(
        1.3 * cam.width as f32 / (2.0 * cam.fx),
        1.3 * cam.height as f32 / (2.0 * cam.fy),
    );
    let raw = Vec2::new(t.x / t.z, t.y / t.z);
    let u = raw.clamp(-lim, lim);
    let clamped = [raw.x != u.x, raw.y != u.y];
    let j0 = Vec3::new(cam.fx / t.z, 0.0, -cam.fx * u.x / t.z);
    let j1 = Vec3::new(0.0, cam.fy / t.z, -cam.fy * u.y / t.z);
    let q_norm = g.rotation.length();
    if !(q_norm > 1e-12) {
        return None;
    }
    let q = g.rotation / q_norm;
    let r = rotation_matrix(q);
    let d = Vec3::new(
        (2.0 * g.log_scale.x).exp(),
        (2.0 * g.log_scale.y).exp(),
        (2.0 * g.log_scale.z).exp(),
    );
    let sigma = r * Mat3::from_diagonal(d) * r.transpose();
    let m = w * sigma * w.transpose();
    let abc = Vec3::new(
        j0.dot(m * j0) + s.blur,
        j0.dot(m * j1),
        j1.dot(m * j1) + s.blur,
    );
    Some(Intermediate {
        t,
        u,
        clamped,
        j0,
        j1,
        m,
        w,
        r,
        q,
        q_norm,
        d,
        abc,
    })
}

/// A cheap conservative bound of `project`'s footprint: image-plane centre and a radius at least
/// as large as `Projected::radius` (from sqrt(lambda_max) <= |J|_F * max scale, blur added), or
/// `None` when the Gaussian is culled anyway. Lets a window skip most of the scene cheaply.
pub fn footprint_bound(
    g: &GaussianParams,
    cam: &Camera,
    s: &RenderSettings,
) -> Option<(Vec2, f32)> {
    let t = cam.world_to_camera.rotation * g.mean + cam.world_to_camera.translation;
    if !(t.z >= s.near) || !t.is_finite() {
        return None;
    }
    let lim = Vec2::new(
        1.3 * cam.width as f32 / (2.0 * cam.fx),
        1.3 * cam.height as f32 / (2.0 * cam.fy),
    );
    let u = Vec2::new(t.x / t.z, t.y / t.z).clamp(-lim, lim);
    let jf2 =
        (cam.fx * cam.fx * (1.0 + u.x * u.x) + cam.fy * cam.fy * (1.0 + u.y * u.y)) / (t.z * t.z);
    let s_max = g.log_scale.max_element().exp();
    let radius = s.cutoff_sigma * (jf2 * s_max * s_max + s.blur).sqrt() * 1.001 + 1e-3;
    let centre = Vec2::new(cam.fx * t.x / t.z + cam.cx, cam.fy * t.y / t.z + cam.cy);
    Some((centre, radius))
}

/// Project one Gaussian; `None` when it is behind the near plane or degenerate.
pub fn project(g: &GaussianParams, cam: &Camera, s: &RenderSettings) -> Option<Projected> {
    let it = forward_intermediate(g, cam, s)?;
    let (a, b, c) = (it.abc.x, it.abc.y, it.abc.z);
    let det = a * c - b * b;
    if !(det > 0.0) {
        return None;
    }
    let conic = Vec3::new(c / det, -b / det, a / det);
    let mid = 0.5 * (a + c);
    let lambda_max = mid + (mid * mid - det).max(0.0).sqrt();
    let radius = s.cutoff_sigma * lambda_max.sqrt();
    let mean = Vec2::new(
        cam.fx * it.t.x / it.t.z + cam.cx,
        cam.fy * it.t.y / it.t.z + cam.cy,
    );
    Some(Projected {
        mean,
        conic,
        depth: it.t.z,
        radius,
        opacity: sigmoid(g.opacity_logit),
        colour: g.colour,
    })
}

/// Chain the image-plane gradient `dp` back to the Gaussian's parameters.
pub fn project_backward(
    g: &GaussianParams,
    cam: &Camera,
    s: &RenderSettings,
    dp: &ProjectedGrad,
) -> ParamGrad {
    let Some(it) = forward_intermediate(g, cam, s) else {
        return ParamGrad::default();
    };
    let (a, b, c) = (it.abc.x, it.abc.y, it.abc.z);
    let det = a * c - b * b;
    if !(det > 0.0) {
        return ParamGrad::default();
    }
    // Conic (C, -B, A) / det with respect to the covariance entries A, B, C.
    let inv2 = 1.0 / (det * det);
    let (ga, gb, gc) = (dp.conic.x, dp.conic.y, dp.conic.z);
    let d_a = inv2 * (-c * c * ga + b * c * gb - b * b * gc);
    let d_b = inv2 * (2.0 * b * c * ga - (a * c + b * b) * gb + 2.0 * a * b * gc);
    let d_c = inv2 * (-b * b * ga + a * b * gb - a * a * gc);

    // Sigma2 = [j0; j1] M [j0; j1]^T: gradients for M (general form) and the Jacobian rows.
    let g_m = outer(it.j0, it.j0) * d_a + outer(it.j0, it.j1) * d_b + outer(it.j1, it.j1) * d_c;
    let g_j0 = (it.m + it.m.transpose()) * it.j0 * d_a + it.m * it.j1 * d_b;
    let g_j1 = it.m.transpose() * it.j0 * d_b + (it.m + it.m.transpose()) * it.j1 * d_c;

    // Jacobian rows j0 = (fx/z, 0, -fx ux/z), j1 = (0, fy/z, -fy uy/z), ux = clamp(x/z).
    let (t, fx, fy) = (it.t, cam.fx, cam.fy);
    let z = t.z;
    let mut g_t = Vec3::ZERO;
    g_t.z += g_j0.x * (-fx / (z * z)) + g_j1.y * (-fy / (z * z));
    // d(-f u / z): with u = x/z unclamped, d/dx = -f/z^2 and d/dz = 2 f x / z^3; clamped, only d/dz = f u / z^2.
    if it.clamped[0] {
        g_t.z += g_j0.z * fx * it.u.x / (z * z);
    } else {
        g_t.x += g_j0.z * (-fx / (z * z));
        g_t.z += g_j0.z * 2.0 * fx * t.x / (z * z * z);
    }
    if it.clamped[1] {
        g_t.z += g_j1.z * fy * it.u.y / (z * z);
    } else {
        g_t.y += g_j1.z * (-fy / (z * z));
        g_t.z += g_j1.z * 2.0 * fy * t.y / (z * z * z);
    }
    // Image-plane mean and depth.
    g_t.x += dp.mean.x * fx / z;
    g_t.y += dp.mean.y * fy / z;
    g_t.z += -dp.mean.x * fx * t.x / (z * z) - dp.mean.y * fy * t.y / (z * z) + dp.depth;
    let mean = it.w.transpose() * g_t;

    // M = W Sigma W^T, Sigma = R D R^T.
    let g_sigma = it.w.transpose() * g_m * it.w;
    let g_sym = g_sigma + g_sigma.transpose();
    let g_r = g_sym * it.r * Mat3::from_diagonal(it.d);
    let rt_g_r = it.r.transpose() * g_sigma * it.r;
    let log_scale = 2.0 * it.d * rt_g_r.diagonal();

    // R(q) for the unit quaternion, then the normalisation.
    let (x, y, zq, w) = (it.q.x, it.q.y, it.q.z, it.q.w);
    // dR/dx etc. as matrices (columns), contracted with g_r.
    let dr_dx = Mat3::from_cols(
        Vec3::new(0.0, 2.0 * y, 2.0 * zq),
        Vec3::new(2.0 * y, -4.0 * x, 2.0 * w),
        Vec3::new(2.0 * zq, -2.0 * w, -4.0 * x),
    );
    let dr_dy = Mat3::from_cols(
        Vec3::new(-4.0 * y, 2.0 * x, -2.0 * w),
        Vec3::new(2.0 * x, 0.0, 2.0 * zq),
        Vec3::new(2.0 * w, 2.0 * zq, -4.0 * y),
    );
    let dr_dz = Mat3::from_cols(
        Vec3::new(-4.0 * zq, 2.0 * w, 2.0 * x),
        Vec3::new(-2.0 * w, -4.0 * zq, 2.0 * y),
        Vec3::new(2.0 * x, 2.0 * y, 0.0),
    );
    let dr_dw = Mat3::from_cols(
        Vec3::new(0.0, 2.0 * zq, -2.0 * y),
        Vec3::new(-2.0 * zq, 0.0, 2.0 * x),
        Vec3::new(2.0 * y, -2.0 * x, 0.0),
    );
    let g_q = Vec4::new(
        frobenius(&g_r, &dr_dx),
        frobenius(&g_r, &dr_dy),
        frobenius(&g_r, &dr_dz),
        frobenius(&g_r, &dr_dw),
    );
    let rotation = (g_q - it.q * it.q.dot(g_q)) / it.q_norm;

    let o = sigmoid(g.opacity_logit);
    ParamGrad {
        mean,
        rotation,
        log_scale,
        opacity_logit: dp.opacity * o * (1.0 - o),
        colour: dp.colour,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Pose;
    use glam::Quat;

    fn camera() -> Camera {
        Camera::look_at(64, 48, 60.0, Vec3::new(0.3, -0.6, 0.5), Vec3::ZERO)
    }

    fn gaussian() -> GaussianParams {
        GaussianParams {
            mean: Vec3::new(0.05, -0.03, 0.04),
            rotation: Vec4::new(0.3, -0.2, 0.5, 0.9),
            log_scale: Vec3::new(-3.0, -2.6, -3.4),
            opacity_logit: 0.7,
            colour: Vec3::new(0.2, 0.5, 0.9),
        }
    }

    /// A scalar of all projected outputs with fixed weights, and its gradient as a ProjectedGrad.
    fn weights() -> ProjectedGrad {
        ProjectedGrad {
            mean: Vec2::new(0.3, -0.7),
            conic: Vec3::new(40.0, -25.0, 30.0),
            depth: 2.0,
            opacity: -1.5,
            colour: Vec3::new(0.4, 0.1, -0.2),
        }
    }

    fn scalar(p: &Projected, w: &ProjectedGrad) -> f64 {
        (p.mean.dot(w.mean)
            + p.conic.dot(w.conic)
            + p.depth * w.depth
            + p.opacity * w.opacity
            + p.colour.dot(w.colour)) as f64
    }

    #[test]
    fn backward_matches_finite_differences_for_every_parameter() {
        let cam = camera();
        let s = RenderSettings::default();
        let g = gaussian();
        let w = weights();
        let grad = project_backward(&g, &cam, &s, &w);
        let mut params: Vec<(String, f32, f32)> = Vec::new();
        let f = |g: &GaussianParams| scalar(&project(g, &cam, &s).unwrap(), &w);
        let mut check = |name: &str,
                         analytic: f32,
                         set: &dyn Fn(&mut GaussianParams, f32),
                         base: f32,
                         h: f32| {
            let mut gp = g;
            set(&mut gp, base + h);
            let up = f(&gp);
            set(&mut gp, base - h);
            let down = f(&gp);
            params.push((
                name.to_string(),
                analytic,
                ((up - down) / (2.0 * h as f64)) as f32,
            ));
        };
        check("mean.x", grad.mean.x, &|g, v| g.mean.x = v, g.mean.x, 1e-3);
        check("mean.y", grad.mean.y, &|g, v| g.mean.y = v, g.mean.y, 1e-3);
        check("mean.z", grad.mean.z, &|g, v| g.mean.z = v, g.mean.z, 1e-3);
        check(
            "rot.x",
            grad.rotation.x,
            &|g, v| g.rotation.x = v,
            g.rotation.x,
            1e-3,
        );
        check(
            "rot.y",
            grad.rotation.y,
            &|g, v| g.rotation.y = v,
            g.rotation.y,
            1e-3,
        );
        check(
            "rot.z",
            grad.rotation.z,
            &|g, v| g.rotation.z = v,
            g.rotation.z,
            1e-3,
        );
        check(
            "rot.w",
            grad.rotation.w,
            &|g, v| g.rotation.w = v,
            g.rotation.w,
            1e-3,
        );
        check(
            "scale.x",
            grad.log_scale.x,
            &|g, v| g.log_scale.x = v,
            g.log_scale.x,
            1e-3,
        );
        check(
            "scale.y",
            grad.log_scale.y,
            &|g, v| g.log_scale.y = v,
            g.log_scale.y,
            1e-3,
        );
        check(
            "scale.z",
            grad.log_scale.z,
            &|g, v| g.log_scale.z = v,
            g.log_scale.z,
            1e-3,
        );
        check(
            "opacity",
            grad.opacity_logit,
            &|g, v| g.opacity_logit = v,
            g.opacity_logit,
            1e-3,
        );
        check(
            "colour.y",
            grad.colour.y,
            &|g, v| g.colour.y = v,
            g.colour.y,
            1e-3,
        );
        for (name, analytic, numeric) in params {
            let tol = 0.01 * numeric.abs().max(analytic.abs()) + 1e-3;
            assert!(
                (analytic - numeric).abs() < tol,
                "{name}: analytic {analytic}, numeric {numeric}"
            );
        }
    }

    #[test]
    fn clamped_jacobian_far_off_axis_still_has_consistent_gradients() {
        // A Gaussian far outside the field of view: x/z is clamped, gradients must follow the clamp.
        let cam = Camera {
            world_to_camera: Pose::IDENTITY,
            ..camera()
        };
        let s = RenderSettings::default();
        let g = GaussianParams {
            mean: Vec3::new(3.0, 0.1, 1.0),
            ..gaussian()
        };
        let w = weights();
        let grad = project_backward(&g, &cam, &s, &w);
        let f = |x: f32| {
            let mut gp = g;
            gp.mean.x = x;
            scalar(&project(&gp, &cam, &s).unwrap(), &w)
        };
        let numeric = ((f(3.0 + 1e-3) - f(3.0 - 1e-3)) / 2e-3) as f32;
        assert!(
            (grad.mean.x - numeric).abs() < 0.01 * numeric.abs() + 1e-3,
            "{} vs {}",
            grad.mean.x,
            numeric
        );
    }

    #[test]
    fn isotropic_gaussian_facing_the_camera_has_the_pinhole_footprint() {
        let cam = Camera {
            width: 100,
            height: 100,
            fx: 200.0,
            fy: 200.0,
            cx: 50.0,
            cy: 50.0,
            world_to_camera: Pose::IDENTITY,
        };
        let s = RenderSettings::default();
        let sigma: f32 = 0.01;
        let g = GaussianParams {
            mean: Vec3::new(0.0, 0.0, 2.0),
            rotation: Vec4::new(0.0, 0.0, 0.0, 1.0),
            log_scale: Vec3::splat(sigma.ln()),
            opacity_logit: 0.0,
            colour: Vec3::ONE,
        };
        let p = project(&g, &cam, &s).unwrap();
        let var = (200.0 * sigma / 2.0) * (200.0 * sigma / 2.0) + s.blur;
        assert!(
            (p.conic.x - 1.0 / var).abs() < 1e-5
                && p.conic.y.abs() < 1e-7
                && (p.conic.z - 1.0 / var).abs() < 1e-5
        );
        assert_eq!(p.mean, Vec2::new(50.0, 50.0));
        assert!((p.radius - 3.0 * var.sqrt()).abs() < 1e-4);
        // Rotating an isotropic Gaussian changes nothing.
        let q = Quat::from_euler(glam::EulerRot::XYZ, 0.4, 1.0, -0.3);
        let g2 = GaussianParams {
            rotation: Vec4::new(q.x, q.y, q.z, q.w),
            ..g
        };
        let p2 = project(&g2, &cam, &s).unwrap();
        assert!((p2.conic - p.conic).abs().max_element() < 1e-5);
    }

    #[test]
    fn footprint_bound_contains_the_exact_footprint() {
        let cam = camera();
        let s = RenderSettings::default();
        for k in 0..200 {
            let f = k as f32;
            let g = GaussianParams {
                mean: Vec3::new(
                    0.1 * (f * 0.37).sin(),
                    0.1 * (f * 0.71).cos(),
                    0.05 * (f * 1.3).sin(),
                ),
                rotation: Vec4::new((f * 0.3).sin(), (f * 0.5).cos(), (f * 0.9).sin(), 1.0),
                log_scale: Vec3::new(
                    -4.0 + (f * 0.2).sin(),
                    -3.5 + (f * 0.4).cos(),
                    -5.0 + (f * 0.8).sin(),
                ),
                ..gaussian()
            };
            let (p, (c, r)) = (
                project(&g, &cam, &s).unwrap(),
                footprint_bound(&g, &cam, &s).unwrap(),
            );
            assert!(
                (p.mean - c).length() < 1e-3 && p.radius <= r,
                "{k}: exact {} bound {r}",
                p.radius
            );
        }
    }

    #[test]
    fn behind_the_camera_is_culled() {
        let cam = Camera {
            world_to_camera: Pose::IDENTITY,
            ..camera()
        };
        let g = GaussianParams {
            mean: Vec3::new(0.0, 0.0, -1.0),
            ..gaussian()
        };
        assert!(project(&g, &cam, &RenderSettings::default()).is_none());
    }
}

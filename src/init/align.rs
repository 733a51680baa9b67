//! Start alignment: before tracking, slide and turn an object on the table until its rendered
//! silhouette best overlaps its mask in every camera (mean intersection over union). Visual forces
//! only pull objects within about their own size; this brings a file pose that is 10 cm and tens of
//! degrees off into that range. A coarse scan over the turn angle, then a pattern search.

use super::mask::{downsample, iou};
use crate::math::Pose;
use crate::render::cpu::CpuRenderer;
use crate::render::{Camera, GaussianCloud, RenderSettings, Roi};
use crate::world::{ShapeId, World};
use glam::{Quat, Vec3, Vec4};
use serde::Serialize;

/// A camera and the object's mask in its first frame (full resolution, row-major).
pub struct MaskView {
    pub camera: Camera,
    pub mask: Vec<bool>,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct Alignment {
    /// Mean silhouette IoU over the cameras at the file pose and after alignment.
    pub iou_before: f32,
    pub iou_after: f32,
    pub moved_mm: f32,
    pub turned_deg: f32,
    pub evaluations: usize,
    pub seconds: f64,
}

struct Search<'a> {
    cloud: GaussianCloud,
    centre: Vec3,
    normal: Vec3,
    axes: (Vec3, Vec3),
    views: Vec<(Camera, Vec<bool>)>,
    renderer: &'a mut CpuRenderer,
    evaluations: usize,
}

impl Search<'_> {
    /// The motion for an offset (along the two in-plane axes, m) and a turn about the normal (rad).
    fn motion(&self, x: [f32; 3]) -> Pose {
        let q = Quat::from_axis_angle(self.normal, x[2]);
        let t = self.axes.0 * x[0] + self.axes.1 * x[1];
        Pose::new(self.centre + t - q * self.centre, q)
    }

    fn score(&mut self, x: [f32; 3]) -> f32 {
        self.evaluations += 1;
        let m = self.motion(x);
        let mut moved = self.cloud.clone();
        for i in 0..moved.len() {
            moved.mean[i] = m.transform_point(self.cloud.mean[i]);
            let r = self.cloud.rotation[i];
            let q = m.rotation * Quat::from_xyzw(r.x, r.y, r.z, r.w).normalize();
            moved.rotation[i] = Vec4::new(q.x, q.y, q.z, q.w);
        }
        let mut total = 0.0;
        for (camera, mask) in &self.views {
            let out = self.renderer.forward(&moved, camera, Roi::full(camera));
            let silhouette: Vec<bool> = out.alpha.iter().map(|a| *a > 0.5).collect();
            total += iou(&silhouette, mask);
        }
        total / self.views.len().max(1) as f32
    }
}

/// Where the cameras' mask centroids point on the plane through `centre` parallel to the ground.
fn mask_centre_on_plane(views: &[MaskView], centre: Vec3, normal: Vec3) -> Option<Vec3> {
    let (mut sum, mut weight) = (Vec3::ZERO, 0.0);
    for v in views {
        let (mut u, mut w, mut n) = (0.0f64, 0.0f64, 0usize);
        for (k, &m) in v.mask.iter().enumerate() {
            if m {
                u += (k as u32 % v.camera.width) as f64 + 0.5;
                w += (k as u32 / v.camera.width) as f64 + 0.5;
                n += 1;
            }
        }
        if n == 0 {
            continue;
        }
        let c = &v.camera;
        let dir_cam = Vec3::new(
            ((u / n as f64) as f32 - c.cx) / c.fx,
            ((w / n as f64) as f32 - c.cy) / c.fy,
            1.0,
        );
        let to_world = c.world_to_camera.inverse();
        let (origin, dir) = (to_world.translation, to_world.rotation * dir_cam);
        let denom = dir.dot(normal);
        if denom.abs() < 1e-6 {
            continue;
        }
        let s = (centre - origin).dot(normal) / denom;
        if s > 0.0 {
            sum += (origin + s * dir) * n as f32;
            weight += n as f32;
        }
    }
    (weight > 0.0).then(|| sum / weight)
}

/// Align `shape` on the ground plane (unit `normal`) to the masks, and move it there.
pub fn align_on_table(
    world: &mut World,
    shape: ShapeId,
    views: &[MaskView],
    normal: Vec3,
    render: &RenderSettings,
) -> Alignment {
    let clock = std::time::Instant::now();
    let ids = world.gaussians_of(shape);
    let cloud = GaussianCloud::from_world_where(world, |i| ids.binary_search(&i).is_ok());
    let normal = normal.normalize_or(Vec3::Z);
    let centre = world.shape_centroid(shape);
    let e1 = normal.any_orthonormal_vector();
    let axes = (e1, normal.cross(e1));
    // Half resolution: the silhouettes are what matter, and four times fewer pixels to render.
    let half: Vec<(Camera, Vec<bool>)> = views
        .iter()
        .map(|v| {
            let c = v.camera;
            let (mask, w, h) = downsample(&v.mask, c.width, c.height);
            (
                Camera {
                    width: w,
                    height: h,
                    fx: c.fx / 2.0,
                    fy: c.fy / 2.0,
                    cx: c.cx / 2.0,
                    cy: c.cy / 2.0,
                    world_to_camera: c.world_to_camera,
                },
                mask,
            )
        })
        .collect();
    let mut renderer = CpuRenderer::new(RenderSettings {
        background: Vec3::ZERO,
        ..render.clone()
    });
    let mut search = Search {
        cloud,
        centre,
        normal,
        axes,
        views: half,
        renderer: &mut renderer,
        evaluations: 0,
    };
    let iou_before = search.score([0.0; 3]);
    let start = mask_centre_on_plane(views, centre, normal).map_or([0.0, 0.0], |p| {
        let d = p - centre;
        [d.dot(axes.0), d.dot(axes.1)]
    });
    // Coarse: every 10 degrees at the masks' centre; keep the four best turns.
    let mut coarse: Vec<(f32, [f32; 3])> = (0..36)
        .map(|k| {
            let x = [start[0], start[1], (k as f32 * 10.0).to_radians()];
            (search.score(x), x)
        })
        .collect();
    coarse.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut best = (iou_before, [0.0f32; 3]);
    for &(s0, x0) in coarse.iter().take(4) {
        let refined = pattern_search(&mut search, x0, s0);
        if refined.0 > best.0 {
            best = refined;
        }
    }
    let motion = search.motion(best.1);
    let evaluations = search.evaluations;
    world.move_shape(shape, motion);
    Alignment {
        iou_before,
        iou_after: best.0,
        moved_mm: (motion.transform_point(centre) - centre).length() * 1e3,
        turned_deg: best.1[2].to_degrees().rem_euclid(360.0),
        evaluations,
        seconds: clock.elapsed().as_secs_f64(),
    }
}

/// What the silhouette fit did: mean IoU over the views before and after.
#[derive(Clone, Debug, Default, Serialize)]
pub struct SilhouetteFit {
    pub steps: u32,
    pub iou_before: f32,
    pub iou_after: f32,
}

/// Fit the opacities and sizes of `shape`'s Gaussians (not their positions) so that its rendered
/// coverage matches the masks (Adam on the squared difference of alpha and mask over a window
/// around the object; `ignore` leaves out pixels where something unmodelled stands in front).
pub fn fit_silhouette(
    world: &mut World,
    shape: ShapeId,
    views: &[MaskView],
    ignore: &[Vec<bool>],
    steps: u32,
    render: &RenderSettings,
) -> anyhow::Result<SilhouetteFit> {
    use crate::correct::adam::Adam;
    use crate::render::footprint_roi;
    let ids = world.gaussians_of(shape);
    let mut cloud = GaussianCloud::from_world_where(world, |i| ids.binary_search(&i).is_ok());
    let all: Vec<usize> = (0..cloud.len()).collect();
    let windows: Vec<Roi> = views
        .iter()
        .map(|v| footprint_roi(&cloud, &all, &v.camera, 8.0))
        .collect();
    let mut renderer = CpuRenderer::new(RenderSettings {
        background: Vec3::ZERO,
        ..render.clone()
    });
    let n = cloud.len();
    let (mut adam_o, mut adam_s) = (Adam::new(0.9, 0.999, 1e-8), Adam::new(0.9, 0.999, 1e-8));
    adam_o.reset(n);
    adam_s.reset(3 * n);
    let mut opacity: Vec<f32> = cloud.opacity_logit.clone();
    let mut scale: Vec<f32> = cloud.log_scale.iter().flat_map(|s| s.to_array()).collect();
    let start_scale = scale.clone();
    let mut fit = SilhouetteFit {
        steps,
        ..Default::default()
    };
    for step in 0..=steps {
        for i in 0..n {
            cloud.opacity_logit[i] = opacity[i];
            cloud.log_scale[i] = Vec3::from_slice(&scale[3 * i..]);
        }
        let last = step == steps;
        let (iou_sum, g_o, g_s) = mask_loss(&cloud, &mut renderer, views, &windows, ignore, !last)?;
        let iou = iou_sum / views.len().max(1) as f32;
        if step == 0 {
            fit.iou_before = iou;
        }
        if last {
            fit.iou_after = iou;
            break;
        }
        adam_o.step(&mut opacity, &g_o, 0.05);
        adam_s.step(&mut scale, &g_s, 0.01);
        // Sizes stay within a factor of two of the file's.
        for (s, s0) in scale.iter_mut().zip(&start_scale) {
            *s = s.clamp(s0 - std::f32::consts::LN_2, s0 + std::f32::consts::LN_2);
        }
    }
    for (k, &i) in ids.iter().enumerate() {
        world.gaussians.opacity[i] = crate::render::sigmoid(opacity[k]);
        let s = Vec3::from_slice(&scale[3 * k..]);
        world.gaussians.scale[i] = Vec3::new(s.x.exp(), s.y.exp(), s.z.exp());
    }
    Ok(fit)
}

/// The silhouette IoU summed over the views and, if `gradient`, the gradients of the mask loss with
/// respect to the opacity logits and log-scales.
fn mask_loss(
    cloud: &GaussianCloud,
    renderer: &mut CpuRenderer,
    views: &[MaskView],
    windows: &[Roi],
    ignore: &[Vec<bool>],
    gradient: bool,
) -> anyhow::Result<(f32, Vec<f32>, Vec<f32>)> {
    let n = cloud.len();
    let (mut g_o, mut g_s) = (vec![0.0f32; n], vec![0.0f32; 3 * n]);
    let mut iou_sum = 0.0;
    for ((v, w), skip) in views.iter().zip(windows).zip(ignore) {
        if w.pixels() == 0 {
            continue;
        }
        let out = renderer.forward(cloud, &v.camera, *w);
        let (mut inter, mut union) = (0usize, 0usize);
        let mut d_alpha = vec![0.0f32; w.pixels()];
        for y in w.y0..w.y1 {
            for x in w.x0..w.x1 {
                let k = ((y - w.y0) * w.width() + x - w.x0) as usize;
                let full_k = (y * v.camera.width + x) as usize;
                if skip[full_k] {
                    continue;
                }
                let (a, m) = (out.alpha[k], v.mask[full_k]);
                inter += (a > 0.5 && m) as usize;
                union += (a > 0.5 || m) as usize;
                d_alpha[k] = 2.0 * (a - m as u8 as f32) / w.pixels() as f32;
            }
        }
        iou_sum += if union == 0 {
            1.0
        } else {
            inter as f32 / union as f32
        };
        if !gradient {
            continue;
        }
        let pixels = crate::render::PixelGrads {
            colour: vec![Vec3::ZERO; w.pixels()],
            alpha: d_alpha,
            ..Default::default()
        };
        let g = renderer.backward(cloud, &pixels)?;
        for i in 0..n {
            g_o[i] += g.opacity_logit[i];
            for j in 0..3 {
                g_s[3 * i + j] += g.log_scale[i][j];
            }
        }
    }
    Ok((iou_sum, g_o, g_s))
}

/// Compass search: try a step up and down each coordinate, take the best gain, halve the steps
/// when nothing improves, stop at 0.5 mm / 0.25 degrees.
fn pattern_search(search: &mut Search, mut x: [f32; 3], mut score: f32) -> (f32, [f32; 3]) {
    let mut step = [0.02f32, 0.02, 8f32.to_radians()];
    let min = [0.0005f32, 0.0005, 0.25f32.to_radians()];
    while step.iter().zip(&min).any(|(s, m)| s >= m) {
        let mut improved = None;
        for k in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let mut y = x;
                y[k] += sign * step[k];
                let s = search.score(y);
                if s > improved.map_or(score, |(b, _)| b) {
                    improved = Some((s, y));
                }
            }
        }
        match improved {
            Some((s, y)) => (score, x) = (s, y),
            None => step.iter_mut().for_each(|s| *s *= 0.5),
        }
    }
    (score, x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{WorldBuilder, t_block_lattice};

    #[test]
    fn a_t_block_placed_off_and_turned_is_found_from_its_masks() {
        let cams = [
            Camera::look_at(
                320,
                240,
                300.0,
                Vec3::new(0.6, 0.0, 0.5),
                Vec3::new(0.0, 0.0, 0.0),
            ),
            Camera::look_at(
                320,
                240,
                300.0,
                Vec3::new(-0.2, 0.55, 0.45),
                Vec3::new(0.0, 0.0, 0.0),
            ),
        ];
        let truth_pose = Pose::new(Vec3::new(0.02, -0.01, 0.02), Quat::from_rotation_z(0.5));
        let lattice = t_block_lattice(0.2, 0.05, 0.04, 0.01);
        let build = |pose| {
            let mut b = WorldBuilder::new();
            let s = b.add_rigid("t", &lattice, 0.005, 0.001, pose, Vec3::new(1.0, 0.4, 0.1));
            (b.build(), s)
        };
        let (truth, s) = build(truth_pose);
        let mut renderer = CpuRenderer::new(RenderSettings::default());
        let views: Vec<MaskView> = cams
            .iter()
            .map(|c| MaskView {
                camera: *c,
                mask: renderer
                    .forward(&GaussianCloud::from_world(&truth), c, Roi::full(c))
                    .alpha
                    .iter()
                    .map(|a| *a > 0.5)
                    .collect(),
            })
            .collect();
        // Start 9 cm and 40 degrees away.
        let (mut world, _) = build(Pose::new(
            Vec3::new(0.08, 0.03, 0.02),
            Quat::from_rotation_z(0.5 + 40f32.to_radians()),
        ));
        let a = align_on_table(&mut world, s, &views, Vec3::Z, &RenderSettings::default());
        assert!(a.iou_before < 0.4 && a.iou_after > 0.9, "{a:?}");
        let error = world
            .shapes
            .range(s)
            .map(|i| world.particles.position[i].distance(truth.particles.position[i]))
            .fold(0.0, f32::max);
        assert!(
            error < 0.004,
            "largest particle error {error} m after {a:?}"
        );
    }
}

//! The static scene: the table as a grid of thin, flat Gaussians (disks) on the ground plane whose
//! colours are fitted by Adam to the first frames, so the background behind the objects renders
//! like the real table. Pixels of the objects (and anything else the caller masks) are left out.

use super::TableConfig;
use crate::correct::adam::Adam;
use crate::physics::GroundConfig;
use crate::render::cpu::CpuRenderer;
use crate::render::{
    Camera, GaussianCloud, GaussianParams, PixelGrads, RenderSettings, Roi, logit,
};
use anyhow::{Result, bail};
use glam::{Quat, Vec3, Vec4};
use serde::Serialize;

/// One frame the table is fitted to, with the pixels to leave out (objects, occluders).
pub struct FitFrame<'a> {
    pub camera: Camera,
    pub image: &'a [Vec3],
    pub ignore: Vec<bool>,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct ColourFit {
    pub gaussians: usize,
    pub steps: u32,
    /// Mean absolute colour error over the fitted pixels, before and after.
    pub error_before: f32,
    pub error_after: f32,
    pub seconds: f64,
}

/// Disks on (just below) the ground plane over the configured rectangle, coloured `colour`.
pub fn table_disks(table: &TableConfig, ground: &GroundConfig, colour: Vec3) -> GaussianCloud {
    let n = ground.normal.normalize_or(Vec3::Z);
    let q = Quat::from_rotation_arc(Vec3::Z, n);
    let mut cloud = GaussianCloud::default();
    let steps = |lo: f32, hi: f32| ((hi - lo) / table.spacing).floor().max(0.0) as usize + 1;
    for iy in 0..steps(table.min.y, table.max.y) {
        for ix in 0..steps(table.min.x, table.max.x) {
            let (x, y) = (
                table.min.x + ix as f32 * table.spacing,
                table.min.y + iy as f32 * table.spacing,
            );
            // On the plane n . p = height, directly above or below (x, y).
            let z = (ground.height - table.drop - n.x * x - n.y * y) / n.z.max(1e-3);
            let sigma = 0.6 * table.spacing;
            cloud.push(GaussianParams {
                mean: Vec3::new(x, y, z),
                rotation: Vec4::new(q.x, q.y, q.z, q.w),
                log_scale: Vec3::new(sigma.ln(), sigma.ln(), (0.02 * table.spacing).ln()),
                opacity_logit: logit(0.99),
                colour,
            });
        }
    }
    cloud
}

/// The colour under each Gaussian's centre: per channel, the median over the frames that see the
/// centre (inside the image, not ignored); None where fewer than two cameras do. A direct estimate that the fit
/// starts from and is held near, so Gaussians seen only through their neighbours stay plausible.
pub fn projected_colours(cloud: &GaussianCloud, frames: &[FitFrame]) -> Vec<Option<Vec3>> {
    cloud
        .mean
        .iter()
        .map(|&p| {
            let mut samples: Vec<Vec3> = Vec::new();
            let mut cameras: Vec<Camera> = Vec::new();
            for f in frames {
                let (u, v, z) = f.camera.project(p);
                if z > 0.0
                    && u >= 0.0
                    && v >= 0.0
                    && (u as u32) < f.camera.width
                    && (v as u32) < f.camera.height
                {
                    let k = (v as u32 * f.camera.width + u as u32) as usize;
                    if !f.ignore[k] {
                        samples.push(f.image[k]);
                        if !cameras.contains(&f.camera) {
                            cameras.push(f.camera);
                        }
                    }
                }
            }
            // A single camera cannot tell the table from something standing on it.
            if cameras.len() < 2 {
                return None;
            }
            let median = |axis: usize| {
                let mut c: Vec<f32> = samples.iter().map(|s| s[axis]).collect();
                c.sort_by(f32::total_cmp);
                c[c.len() / 2]
            };
            Some(Vec3::new(median(0), median(1), median(2)))
        })
        .collect()
}

/// Box-filter an image (and OR its ignore mask) down by an integer factor, with the camera.
fn shrink(frame: &FitFrame, factor: u32) -> (Camera, Vec<Vec3>, Vec<bool>) {
    let c = frame.camera;
    if factor <= 1 {
        return (c, frame.image.to_vec(), frame.ignore.clone());
    }
    let (w, h) = (c.width / factor, c.height / factor);
    let f = factor as f32;
    let camera = Camera {
        width: w,
        height: h,
        fx: c.fx / f,
        fy: c.fy / f,
        cx: c.cx / f,
        cy: c.cy / f,
        world_to_camera: c.world_to_camera,
    };
    let mut image = Vec::with_capacity((w * h) as usize);
    let mut ignore = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let (mut sum, mut any) = (Vec3::ZERO, false);
            for dy in 0..factor {
                for dx in 0..factor {
                    let i = ((y * factor + dy) * c.width + x * factor + dx) as usize;
                    sum += frame.image[i];
                    any |= frame.ignore[i];
                }
            }
            image.push(sum / (f * f));
            ignore.push(any);
        }
    }
    (camera, image, ignore)
}

/// Fit the disks' colours to `frames`: start from the colours under their centres (disks no
/// frame sees keep theirs), then `fit_colours`.
pub fn fit_table(
    cloud: &mut GaussianCloud,
    frames: &[FitFrame],
    table: &TableConfig,
    render: &RenderSettings,
    progress: bool,
) -> Result<ColourFit> {
    let seen = projected_colours(cloud, frames);
    for (c, seen) in cloud.colour.iter_mut().zip(seen) {
        if let Some(seen) = seen {
            *c = seen;
        }
    }
    fit_colours(
        cloud,
        frames,
        table.fit_steps,
        table.lr,
        table.fit_resolution,
        render,
        progress,
    )
}

/// Fit the colours of a cloud to `frames` with Adam on a robust (smoothed L1) colour loss, at
/// `resolution` times the cameras' size: where the cameras disagree about a Gaussian (something
/// stood in front of it in one view), the majority wins.
pub fn fit_colours(
    cloud: &mut GaussianCloud,
    frames: &[FitFrame],
    steps: u32,
    lr: f32,
    resolution: f32,
    render: &RenderSettings,
    progress: bool,
) -> Result<ColourFit> {
    let clock = std::time::Instant::now();
    if frames.iter().any(|f| {
        f.image.len() != (f.camera.width * f.camera.height) as usize
            || f.ignore.len() != f.image.len()
    }) {
        bail!("table fit: an image or mask does not match its camera");
    }
    let factor = (1.0 / resolution.clamp(0.05, 1.0)).round() as u32;
    let shrunk: Vec<Shrunk> = frames.iter().map(|f| shrink(f, factor)).collect();
    let mut renderer = CpuRenderer::new(render.clone());
    let mut adam = Adam::new(0.9, 0.999, 1e-8);
    let n = cloud.len();
    adam.reset(3 * n);
    let mut colours: Vec<f32> = cloud.colour.iter().flat_map(|c| c.to_array()).collect();
    let fitted = seen_by_enough_cameras(cloud, &shrunk, &mut renderer)?;
    let bar = progress_bar(progress, steps as u64 + 1, n);
    let mut fit = ColourFit {
        gaussians: n,
        steps,
        ..Default::default()
    };
    for step in 0..=steps {
        for (i, c) in cloud.colour.iter_mut().enumerate() {
            *c = Vec3::from_slice(&colours[3 * i..]);
        }
        let last = step == steps;
        let (error, mut grad) = colour_loss(cloud, &shrunk, &mut renderer, !last)?;
        if step == 0 {
            fit.error_before = error;
        }
        if last {
            fit.error_after = error;
            break;
        }
        // Adam's normalised steps would push a Gaussian seen only through a few pixels of its
        // tail to an extreme colour to explain them: those keep their starting colour, as do
        // those that a single camera sees.
        for (i, g) in grad.chunks_exact_mut(3).enumerate() {
            if !fitted[i] {
                g.fill(0.0);
            }
        }
        adam.step(&mut colours, &grad, lr);
        for c in colours.iter_mut() {
            *c = c.clamp(0.0, 1.0);
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    fit.seconds = clock.elapsed().as_secs_f64();
    Ok(fit)
}

/// A frame at the fit's resolution: camera, image, pixels left out.
type Shrunk = (Camera, Vec<Vec3>, Vec<bool>);

/// Pixels' worth of weight (sum of a Gaussian's blending weights over the fitted pixels) for a
/// camera to count as seeing a Gaussian.
const MIN_VISIBILITY: f32 = 1.0;

/// The Gaussians fitted: those that two cameras see (one camera cannot tell the table from
/// something standing on it), or all that one sees when there is only one camera.
fn seen_by_enough_cameras(
    cloud: &GaussianCloud,
    shrunk: &[Shrunk],
    renderer: &mut CpuRenderer,
) -> Result<Vec<bool>> {
    // Per Gaussian, the cameras that see it (distinct poses among the frames).
    let mut views: Vec<Camera> = Vec::new();
    let mut visibility = vec![Vec::<f32>::new(); cloud.len()];
    for (camera, _, ignore) in shrunk {
        let view = match views.iter().position(|c| c == camera) {
            Some(v) => v,
            None => {
                views.push(*camera);
                views.len() - 1
            }
        };
        renderer.forward(cloud, camera, Roi::full(camera));
        let ones: Vec<Vec3> = ignore
            .iter()
            .map(|&i| if i { Vec3::ZERO } else { Vec3::ONE })
            .collect();
        let pixels = PixelGrads {
            colour: ones,
            ..Default::default()
        };
        let g = renderer.backward(cloud, &pixels)?;
        for (v, c) in visibility.iter_mut().zip(&g.colour) {
            v.resize(views.len(), 0.0);
            v[view] += c.x;
        }
    }
    let needed = views.len().min(2);
    Ok(visibility
        .iter()
        .map(|v| v.iter().filter(|w| **w >= MIN_VISIBILITY).count() >= needed)
        .collect())
}

/// The mean absolute colour error over the used pixels and, if `gradient`, the smoothed-L1
/// gradient with respect to every colour channel (zero otherwise).
fn colour_loss(
    cloud: &GaussianCloud,
    shrunk: &[Shrunk],
    renderer: &mut CpuRenderer,
    gradient: bool,
) -> Result<(f32, Vec<f32>)> {
    const EPS: f32 = 0.02;
    let mut grad = vec![0.0f32; 3 * cloud.len()];
    let (mut error, mut counted) = (0.0f32, 0usize);
    for (camera, image, ignore) in shrunk {
        let out = renderer.forward(cloud, camera, Roi::full(camera));
        let mut d = vec![Vec3::ZERO; image.len()];
        for k in 0..image.len() {
            if ignore[k] {
                continue;
            }
            let r = out.colour[k] - image[k];
            error += r.abs().element_sum() / 3.0;
            counted += 1;
            d[k] = r / (r * r + Vec3::splat(EPS * EPS)).powf(0.5);
        }
        if !gradient {
            continue;
        }
        let pixels = PixelGrads {
            colour: d,
            ..Default::default()
        };
        let g = renderer.backward(cloud, &pixels)?;
        for (i, c) in g.colour.iter().enumerate() {
            for j in 0..3 {
                grad[3 * i + j] += c[j];
            }
        }
    }
    Ok((error / counted.max(1) as f32, grad))
}

fn progress_bar(progress: bool, len: u64, gaussians: usize) -> indicatif::ProgressBar {
    let bar = if progress {
        indicatif::ProgressBar::new(len)
    } else {
        indicatif::ProgressBar::hidden()
    };
    let style = indicatif::ProgressStyle::with_template(
        "fitting colours of {prefix} Gaussians [{bar:30}] {pos}/{len} {elapsed}",
    )
    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
    bar.set_style(style);
    bar.set_prefix(gaussians.to_string());
    bar
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;

    #[test]
    fn disks_lie_on_a_tilted_ground_plane_and_take_the_colours_they_see() {
        let ground = GroundConfig {
            normal: Vec3::new(0.02, 0.0, 1.0).normalize(),
            height: 0.01,
            ..Default::default()
        };
        let table = TableConfig {
            min: Vec2::new(-0.2, -0.2),
            max: Vec2::new(0.2, 0.2),
            spacing: 0.02,
            fit_steps: 150,
            lr: 0.05,
            fit_resolution: 1.0,
            ..Default::default()
        };
        let mut cloud = table_disks(&table, &ground, Vec3::splat(0.5));
        assert_eq!(cloud.len(), 21 * 21);
        for m in &cloud.mean {
            assert!((ground.normal.dot(*m) - (ground.height - table.drop)).abs() < 1e-6);
        }
        // A camera above the table sees a left half red and a right half blue; a block of pixels
        // in the middle of the red half is masked (e.g. an object) and painted green.
        let cam = Camera::look_at(40, 40, 40.0, Vec3::new(0.0, 0.0, 0.3), Vec3::ZERO);
        let mut image = vec![Vec3::ZERO; 1600];
        let mut ignore = vec![false; 1600];
        for y in 0..40 {
            for x in 0..40 {
                image[y * 40 + x] = if x < 20 {
                    Vec3::new(0.8, 0.1, 0.1)
                } else {
                    Vec3::new(0.1, 0.1, 0.8)
                };
                if (6..12).contains(&x) && (16..24).contains(&y) {
                    image[y * 40 + x] = Vec3::new(0.0, 1.0, 0.0);
                    ignore[y * 40 + x] = true;
                }
            }
        }
        let fit = fit_table(
            &mut cloud,
            &[FitFrame {
                camera: cam,
                image: &image,
                ignore,
            }],
            &table,
            &RenderSettings::default(),
            false,
        )
        .unwrap();
        assert!(fit.error_after < 0.25 * fit.error_before, "{fit:?}");
        let render =
            CpuRenderer::new(RenderSettings::default()).forward(&cloud, &cam, Roi::full(&cam));
        let at = |x: usize, y: usize| render.colour[y * 40 + x];
        assert!(
            at(5, 5).x > 0.6 && at(5, 5).z < 0.3,
            "left is red: {}",
            at(5, 5)
        );
        assert!(
            at(34, 30).z > 0.6 && at(34, 30).x < 0.3,
            "right is blue: {}",
            at(34, 30)
        );
        assert!(
            at(9, 20).y < 0.3,
            "the masked block is not learned: {}",
            at(9, 20)
        );
    }
}

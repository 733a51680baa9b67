//! Silhouette agreement: whether the camera still sees each tracked object where the model puts
//! it. Among an object's Gaussians whose centre the model renders as their own surface (not hidden
//! behind the robot or another object), the share whose observed pixel looks more like that
//! surface than like the static scene behind it (a relative test, so a camera's colour response
//! that differs from the model's does not read as disagreement).
//! Near 1 while tracking holds; near 0 once the rendered object no longer overlaps the observed one
//! (the photometric gradient is then gone too) or something unmodelled covers it.
//!
//! Owns the measure only; when a low agreement means a lost track is the tracker's call.

use super::same_surface;
use crate::render::{Camera, GaussianCloud, Roi};
use crate::world::World;
use glam::Vec3;

/// Chromaticity distance within which two colours are the same surface.
pub const SURFACE_THRESHOLD: f32 = 0.1;
/// Fewer visible Gaussians than this say nothing about an object.
pub const MIN_VISIBLE: usize = 8;

/// A window's pixels, row-major: the whole model rendered, the static scene alone, the image.
pub struct WindowPixels<'a> {
    pub rendered: &'a [Vec3],
    pub background: &'a [Vec3],
    pub observed: &'a [Vec3],
}

/// Per shape: the agreement in `camera` (None where the object shows fewer than `MIN_VISIBLE`
/// Gaussians in `window`).
pub fn silhouette_agreement(
    world: &World,
    cloud: &GaussianCloud,
    free: &[usize],
    (camera, window): (&Camera, Roi),
    pixels: &WindowPixels,
) -> Vec<Option<f32>> {
    let WindowPixels {
        rendered,
        background,
        observed,
    } = pixels;
    let mut seen = vec![(0usize, 0usize); world.shapes.len()];
    let width = window.x1 - window.x0;
    for &i in free {
        let (u, v, depth) = camera.project(cloud.mean[i]);
        if !(depth > 0.0 && u.is_finite() && v.is_finite()) {
            continue;
        }
        let (x, y) = (u.floor(), v.floor());
        let inside = x >= window.x0 as f32
            && y >= window.y0 as f32
            && x < window.x1 as f32
            && y < window.y1 as f32;
        if !inside {
            continue;
        }
        let k = (y as u32 - window.y0) as usize * width as usize + (x as u32 - window.x0) as usize;
        let (Some(model), Some(image), Some(behind)) =
            (rendered.get(k), observed.get(k), background.get(k))
        else {
            continue;
        };
        if !same_surface(*model, cloud.colour[i], SURFACE_THRESHOLD) {
            continue; // hidden behind something else the model knows
        }
        let shape = world.particles.shape[world.gaussians.parent[i] as usize] as usize;
        seen[shape].0 += 1;
        seen[shape].1 += (image.distance(*model) < image.distance(*behind)) as usize;
    }
    seen.iter()
        .map(|&(visible, matched)| {
            (visible >= MIN_VISIBLE).then(|| matched as f32 / visible as f32)
        })
        .collect()
}

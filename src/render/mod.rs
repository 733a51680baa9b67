//! Differentiable 3-D Gaussian splatting (spec section 3): render Gaussians into pinhole cameras
//! and back-propagate per-pixel loss gradients to every Gaussian parameter.
//!
//! This module owns the renderer's data types and its semantics; `project` holds the per-Gaussian
//! maths, `cpu` the multi-threaded CPU reference backend. It reads Gaussians, never the physics.
//!
//! Semantics every backend follows:
//! - EWA projection with a `blur` added to the 2-D covariance (`project`).
//! - A Gaussian is evaluated at a pixel iff the pixel centre lies within `cutoff_sigma`
//!   Mahalanobis distance of its mean; tiles only accelerate this, so results do not depend on
//!   the tiling and a region of interest renders exactly the crop of a full frame.
//! - Front-to-back compositing in depth order (depths within 2^-15 relative count as ties, broken
//!   by Gaussian index, so every backend orders alike):
//!   `alpha = min(max_alpha, o exp(-q/2))`, skipped below `min_alpha`; compositing stops before a
//!   Gaussian that would take the transmittance below `min_transmittance`.
//! - Outputs: colour (plus transmittance x background), accumulated alpha `1 - T`, and depth as
//!   the alpha-weighted sum of Gaussian depths (divide by alpha for the expected surface depth).

pub mod camera;
pub mod cpu;
pub mod gpu;
pub mod project;

pub use camera::Camera;
pub use project::{GaussianParams, ParamGrad, logit, sigmoid};

use crate::world::World;
use anyhow::Result;
use glam::{Vec3, Vec4};
use serde::{Deserialize, Serialize};

/// A rendering backend: forward over a window, then backward for the same cloud.
pub trait Renderer {
    fn name(&self) -> String;
    fn settings(&self) -> &RenderSettings;
    fn forward(&mut self, cloud: &GaussianCloud, camera: &Camera, roi: Roi)
    -> Result<RenderOutput>;
    fn backward(&mut self, cloud: &GaussianCloud, d_image: &PixelGrads) -> Result<CloudGrads>;
    /// Milliseconds spent per internal stage since the last call (e.g. project, sort, rasterise),
    /// for benchmarks; empty where a backend does not measure them.
    fn take_stage_ms(&mut self) -> Vec<(&'static str, f64)> {
        Vec::new()
    }
}

/// Which backend renders.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Backend {
    Cpu,
    Wgpu,
}

/// Open a renderer of the given backend.
pub fn open(backend: Backend, settings: RenderSettings) -> Result<Box<dyn Renderer + Send>> {
    Ok(match backend {
        Backend::Cpu => Box::new(cpu::CpuRenderer::new(settings)),
        Backend::Wgpu => Box::new(gpu::GpuRenderer::new(settings)?),
    })
}

impl Renderer for cpu::CpuRenderer {
    fn name(&self) -> String {
        "cpu".into()
    }
    fn settings(&self) -> &RenderSettings {
        &self.settings
    }
    fn forward(
        &mut self,
        cloud: &GaussianCloud,
        camera: &Camera,
        roi: Roi,
    ) -> Result<RenderOutput> {
        Ok(cpu::CpuRenderer::forward(self, cloud, camera, roi))
    }
    fn backward(&mut self, cloud: &GaussianCloud, d_image: &PixelGrads) -> Result<CloudGrads> {
        cpu::CpuRenderer::backward(self, cloud, d_image)
    }
    fn take_stage_ms(&mut self) -> Vec<(&'static str, f64)> {
        std::mem::take(&mut self.stage_ms).into_iter().collect()
    }
}

impl Renderer for gpu::GpuRenderer {
    fn name(&self) -> String {
        format!("wgpu: {}", self.adapter())
    }
    fn settings(&self) -> &RenderSettings {
        &self.settings
    }
    fn forward(
        &mut self,
        cloud: &GaussianCloud,
        camera: &Camera,
        roi: Roi,
    ) -> Result<RenderOutput> {
        gpu::GpuRenderer::forward(self, cloud, camera, roi)
    }
    fn backward(&mut self, cloud: &GaussianCloud, d_image: &PixelGrads) -> Result<CloudGrads> {
        gpu::GpuRenderer::backward(self, cloud, d_image)
    }
}

/// Every number of the renderer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RenderSettings {
    pub background: Vec3,
    /// Added to the diagonal of every 2-D covariance, px^2 (anti-aliasing).
    pub blur: f32,
    /// Gaussians closer than this (m) along the optical axis are culled.
    pub near: f32,
    /// Mahalanobis radius beyond which a Gaussian is not evaluated.
    pub cutoff_sigma: f32,
    pub min_alpha: f32,
    pub max_alpha: f32,
    pub min_transmittance: f32,
    /// Tile edge in pixels.
    pub tile: u32,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            background: Vec3::ZERO,
            blur: 0.3,
            near: 0.01,
            cutoff_sigma: 3.0,
            min_alpha: 1.0 / 255.0,
            max_alpha: 0.999,
            min_transmittance: 1e-4,
            tile: 16,
        }
    }
}

/// A pixel window `[x0, x1) x [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Roi {
    pub x0: u32,
    pub y0: u32,
    pub x1: u32,
    pub y1: u32,
}

impl Roi {
    pub fn full(camera: &Camera) -> Self {
        Self {
            x0: 0,
            y0: 0,
            x1: camera.width,
            y1: camera.height,
        }
    }

    /// Clamp to the image; an empty window stays empty.
    pub fn clamped(self, camera: &Camera) -> Self {
        let x1 = self.x1.min(camera.width);
        let y1 = self.y1.min(camera.height);
        Self {
            x0: self.x0.min(x1),
            y0: self.y0.min(y1),
            x1,
            y1,
        }
    }

    pub fn width(&self) -> u32 {
        self.x1 - self.x0
    }

    pub fn height(&self) -> u32 {
        self.y1 - self.y0
    }

    pub fn pixels(&self) -> usize {
        self.width() as usize * self.height() as usize
    }
}

/// Gaussians in the world frame in the optimiser's unconstrained form (structure of arrays).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GaussianCloud {
    pub mean: Vec<Vec3>,
    pub rotation: Vec<Vec4>,
    pub log_scale: Vec<Vec3>,
    pub opacity_logit: Vec<f32>,
    pub colour: Vec<Vec3>,
}

impl GaussianCloud {
    pub fn len(&self) -> usize {
        self.mean.len()
    }

    pub fn is_empty(&self) -> bool {
        self.mean.is_empty()
    }

    pub fn push(&mut self, g: GaussianParams) {
        self.mean.push(g.mean);
        self.rotation.push(g.rotation);
        self.log_scale.push(g.log_scale);
        self.opacity_logit.push(g.opacity_logit);
        self.colour.push(g.colour);
    }

    pub fn get(&self, i: usize) -> GaussianParams {
        GaussianParams {
            mean: self.mean[i],
            rotation: self.rotation[i],
            log_scale: self.log_scale[i],
            opacity_logit: self.opacity_logit[i],
            colour: self.colour[i],
        }
    }

    /// The world's Gaussians at the world's current state.
    pub fn from_world(world: &World) -> Self {
        Self::from_world_where(world, |_| true)
    }

    /// The world's Gaussians that `keep` selects (by index), at the world's current state; only
    /// those are transformed.
    pub fn from_world_where(world: &World, keep: impl Fn(usize) -> bool) -> Self {
        let g = &world.gaussians;
        let mut cloud = GaussianCloud::default();
        for i in (0..g.len()).filter(|&i| keep(i)) {
            let (mean, q) = world.gaussian_world_pose(i);
            cloud.push(GaussianParams {
                mean,
                rotation: Vec4::new(q.x, q.y, q.z, q.w),
                log_scale: Vec3::new(g.scale[i].x.ln(), g.scale[i].y.ln(), g.scale[i].z.ln()),
                opacity_logit: logit(g.opacity[i]),
                colour: g.colour[i],
            });
        }
        cloud
    }

    /// The static scene: Gaussians bonded to no particle.
    pub fn static_scene(world: &World) -> Self {
        Self::from_world_where(world, |i| {
            world.gaussians.parent[i] == crate::world::NO_PARENT
        })
    }
}

/// Grow a mask by `radius` pixels (square neighbourhood).
pub fn dilate(mask: &[bool], width: u32, height: u32, radius: i32) -> Vec<bool> {
    let mut out = vec![false; mask.len()];
    let (w, h) = (width as i32, height as i32);
    for y in 0..h {
        for x in 0..w {
            if !mask[(y * w + x) as usize] {
                continue;
            }
            for yy in (y - radius).max(0)..=(y + radius).min(h - 1) {
                for xx in (x - radius).max(0)..=(x + radius).min(w - 1) {
                    out[(yy * w + xx) as usize] = true;
                }
            }
        }
    }
    out
}

/// The pixel window covering the projected 3-sigma extent of the Gaussians `indices` in `camera`,
/// plus `margin` pixels, clamped to the image (empty if none is in front of the camera).
pub fn footprint_roi(
    cloud: &GaussianCloud,
    indices: &[usize],
    camera: &Camera,
    margin: f32,
) -> Roi {
    let (mut lo, mut hi) = (glam::Vec2::splat(f32::MAX), glam::Vec2::splat(f32::MIN));
    for &i in indices {
        let (u, v, z) = camera.project(cloud.mean[i]);
        if z.is_nan() || z <= 1e-3 {
            continue;
        }
        let r =
            3.0 * cloud.log_scale[i].max_element().exp() * camera.fx.max(camera.fy) / z + margin;
        lo = lo.min(glam::Vec2::new(u - r, v - r));
        hi = hi.max(glam::Vec2::new(u + r, v + r));
    }
    if lo.x > hi.x {
        return Roi {
            x0: 0,
            y0: 0,
            x1: 0,
            y1: 0,
        };
    }
    let clamp = |x: f32, max: u32| x.clamp(0.0, max as f32) as u32;
    Roi {
        x0: clamp(lo.x.floor(), camera.width),
        y0: clamp(lo.y.floor(), camera.height),
        x1: clamp(hi.x.ceil(), camera.width),
        y1: clamp(hi.y.ceil(), camera.height),
    }
}

/// What a render produces over its window, row-major.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RenderOutput {
    pub roi: Option<Roi>,
    pub colour: Vec<Vec3>,
    pub alpha: Vec<f32>,
    pub depth: Vec<f32>,
}

impl RenderOutput {
    /// Write the colour image as an 8-bit sRGB-less PNG (values clamped to [0, 1]).
    pub fn save_png(&self, path: &std::path::Path) -> anyhow::Result<()> {
        use anyhow::Context;
        let roi = self.roi.context("render output without a window")?;
        let mut img = image::RgbImage::new(roi.width(), roi.height());
        for (i, px) in img.pixels_mut().enumerate() {
            let c = (self.colour[i].clamp(Vec3::ZERO, Vec3::ONE) * 255.0).round();
            *px = image::Rgb([c.x as u8, c.y as u8, c.z as u8]);
        }
        img.save(path)
            .with_context(|| format!("cannot write {}", path.display()))
    }
}

/// Loss gradients with respect to a `RenderOutput`'s images (same window and layout).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PixelGrads {
    pub colour: Vec<Vec3>,
    /// Optional: empty means zero.
    pub alpha: Vec<f32>,
    /// Optional: empty means zero.
    pub depth: Vec<f32>,
}

/// Loss gradients with respect to a `GaussianCloud`, one entry per Gaussian.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CloudGrads {
    pub mean: Vec<Vec3>,
    pub rotation: Vec<Vec4>,
    pub log_scale: Vec<Vec3>,
    pub opacity_logit: Vec<f32>,
    pub colour: Vec<Vec3>,
}

impl CloudGrads {
    pub fn zeros(n: usize) -> Self {
        Self {
            mean: vec![Vec3::ZERO; n],
            rotation: vec![Vec4::ZERO; n],
            log_scale: vec![Vec3::ZERO; n],
            opacity_logit: vec![0.0; n],
            colour: vec![Vec3::ZERO; n],
        }
    }

    /// Add another camera's gradients.
    pub fn accumulate(&mut self, other: &CloudGrads) {
        for i in 0..self.mean.len() {
            self.mean[i] += other.mean[i];
            self.rotation[i] += other.rotation[i];
            self.log_scale[i] += other.log_scale[i];
            self.opacity_logit[i] += other.opacity_logit[i];
            self.colour[i] += other.colour[i];
        }
    }
}

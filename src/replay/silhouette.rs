//! Tracking quality without ground truth: the tracked object's rendered silhouette against its
//! colour mask in each camera (intersection over union), and a contact sheet of overlays.

use crate::init::ColourMask;
use crate::render::cpu::CpuRenderer;
use crate::render::{Camera, GaussianCloud, RenderSettings, footprint_roi};
use crate::world::{ShapeId, World};
use anyhow::{Context, Result};
use glam::Vec3;
use serde::Serialize;

#[derive(Clone, Debug, Default, Serialize)]
pub struct IouStats {
    pub mean: f32,
    pub p5: f32,
    pub frames: usize,
}

pub fn iou_stats(values: &[f32]) -> IouStats {
    if values.is_empty() {
        return IouStats::default();
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f32::total_cmp);
    IouStats { mean: values.iter().sum::<f32>() / values.len() as f32, p5: sorted[(values.len() as f32 * 0.05).floor() as usize], frames: values.len() }
}

/// The object's silhouette (rendered alpha > 0.5) as a full-frame mask.
pub fn silhouette(renderer: &mut CpuRenderer, world: &World, shape: ShapeId, camera: &Camera) -> Vec<bool> {
    let full = GaussianCloud::from_world(world);
    let mut cloud = GaussianCloud::default();
    for i in world.gaussians_of(shape) {
        cloud.push(full.get(i));
    }
    let all: Vec<usize> = (0..cloud.len()).collect();
    let roi = footprint_roi(&cloud, &all, camera, 2.0);
    let mut mask = vec![false; (camera.width * camera.height) as usize];
    if roi.pixels() == 0 {
        return mask;
    }
    let out = renderer.forward(&cloud, camera, roi);
    for y in roi.y0..roi.y1 {
        for x in roi.x0..roi.x1 {
            let a = out.alpha[((y - roi.y0) * roi.width() + x - roi.x0) as usize];
            mask[(y * camera.width + x) as usize] = a > 0.5;
        }
    }
    mask
}

/// Silhouette measurements of one object, and overlays kept for the contact sheet.
pub struct SilhouetteMeter {
    pub shape: ShapeId,
    pub object: String,
    pub mask: ColourMask,
    renderer: CpuRenderer,
    /// Per camera: (t, IoU).
    pub series: Vec<Vec<(f64, f32)>>,
}

impl SilhouetteMeter {
    pub fn new(shape: ShapeId, object: &str, mask: ColourMask, cameras: usize, render: &RenderSettings) -> Self {
        Self { shape, object: object.to_string(), mask, renderer: CpuRenderer::new(render.clone()), series: vec![Vec::new(); cameras] }
    }

    /// Measure camera `c`'s image; returns the overlay (green: both, red: mask only, blue:
    /// silhouette only) when `overlay` is asked for.
    pub fn measure(&mut self, world: &World, c: usize, camera: &Camera, image: &[Vec3], t: f64, overlay: bool) -> Option<Vec<Vec3>> {
        let sil = silhouette(&mut self.renderer, world, self.shape, camera);
        let mask = self.mask.segment(image, camera.width, camera.height);
        self.series[c].push((t, crate::init::mask::iou(&sil, &mask)));
        overlay.then(|| {
            image
                .iter()
                .zip(sil.iter().zip(&mask))
                .map(|(p, (&s, &m))| match (s, m) {
                    (true, true) => p.lerp(Vec3::new(0.0, 1.0, 0.0), 0.5),
                    (false, true) => p.lerp(Vec3::new(1.0, 0.0, 0.0), 0.6),
                    (true, false) => p.lerp(Vec3::new(0.0, 0.3, 1.0), 0.6),
                    (false, false) => *p,
                })
                .collect()
        })
    }
}

/// Tile overlays (rows of equal-size images) into one PNG.
pub fn write_contact_sheet(path: &std::path::Path, rows: &[Vec<(u32, u32, Vec<Vec3>)>]) -> Result<()> {
    let (w, h) = rows.iter().flatten().fold((0, 0), |(w, h), (iw, ih, _)| (w.max(*iw), h.max(*ih)));
    let cols = rows.iter().map(|r| r.len()).max().unwrap_or(0) as u32;
    let mut sheet = image::RgbImage::new((w + 4) * cols.max(1), (h + 4) * rows.len().max(1) as u32);
    for (r, row) in rows.iter().enumerate() {
        for (c, (iw, ih, pixels)) in row.iter().enumerate() {
            for y in 0..*ih {
                for x in 0..*iw {
                    let p = (pixels[(y * iw + x) as usize].clamp(Vec3::ZERO, Vec3::ONE) * 255.0).round();
                    sheet.put_pixel(c as u32 * (w + 4) + x, r as u32 * (h + 4) + y, image::Rgb([p.x as u8, p.y as u8, p.z as u8]));
                }
            }
        }
    }
    sheet.save(path).with_context(|| format!("cannot write {}", path.display()))
}

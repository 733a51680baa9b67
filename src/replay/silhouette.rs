//! Tracking quality without ground truth: the tracked object's rendered silhouette against its
//! colour mask in each camera (intersection over union), and a contact sheet of overlays.

use crate::correct::explained;
use crate::init::ColourMask;
use crate::init::ObjectConfig;
use crate::render::cpu::CpuRenderer;
use crate::render::{Camera, GaussianCloud, RenderSettings, Roi, footprint_roi};
use crate::tracker::{Observer, Tick};
use crate::world::{ShapeId, World};
use anyhow::{Context, Result};
use glam::Vec3;
use serde::Serialize;
use std::collections::BTreeMap;

/// IoU statistics over the frames: of the whole silhouette (`mean`, `p5`), and of its visible
/// part (`visible_mean`, `visible_p5`: pixels where something the model does not have, such as an
/// unmodelled arm, stands in front are left out of both masks).
#[derive(Clone, Debug, Default, Serialize)]
pub struct IouStats {
    pub mean: f32,
    pub p5: f32,
    pub visible_mean: f32,
    pub visible_p5: f32,
    pub frames: usize,
}

fn mean_p5(values: &[f32]) -> (f32, f32) {
    if values.is_empty() {
        return (0.0, 0.0);
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f32::total_cmp);
    (
        values.iter().sum::<f32>() / values.len() as f32,
        sorted[(values.len() as f32 * 0.05).floor() as usize],
    )
}

pub fn iou_stats(whole: &[f32], visible: &[f32]) -> IouStats {
    let ((mean, p5), (visible_mean, visible_p5)) = (mean_p5(whole), mean_p5(visible));
    IouStats {
        mean,
        p5,
        visible_mean,
        visible_p5,
        frames: whole.len(),
    }
}

/// The object's silhouette (rendered alpha > 0.5) as a full-frame mask, and the colours it renders
/// with (see `correct::palette`).
pub fn silhouette(
    renderer: &mut CpuRenderer,
    world: &World,
    shape: ShapeId,
    camera: &Camera,
) -> (Vec<bool>, Vec<Vec3>) {
    let ids = world.gaussians_of(shape);
    let cloud = GaussianCloud::from_world_where(world, |i| ids.binary_search(&i).is_ok());
    let all: Vec<usize> = (0..cloud.len()).collect();
    let roi = footprint_roi(&cloud, &all, camera, 2.0);
    let mut mask = vec![false; (camera.width * camera.height) as usize];
    if roi.pixels() == 0 {
        return (mask, Vec::new());
    }
    let out = renderer.forward(&cloud, camera, roi);
    let palette = crate::correct::rendered_palette(&out.colour, &out.alpha);
    for y in roi.y0..roi.y1 {
        for x in roi.x0..roi.x1 {
            let a = out.alpha[((y - roi.y0) * roi.width() + x - roi.x0) as usize];
            mask[(y * camera.width + x) as usize] = a > 0.5;
        }
    }
    (mask, palette)
}

/// Silhouette measurements of one object, and overlays kept for the contact sheet.
pub struct SilhouetteMeter {
    pub shape: ShapeId,
    pub object: String,
    pub mask: ColourMask,
    renderer: CpuRenderer,
    /// Pixel colour distance beyond which neither the object nor the static scene explains a pixel.
    occluder_threshold: f32,
    /// The static scene rendered into each camera (computed on first use).
    backgrounds: Vec<Option<Vec<Vec3>>>,
    /// Per camera: (t, IoU, IoU of the visible part).
    pub series: Vec<Vec<(f64, f32, f32)>>,
}

impl SilhouetteMeter {
    pub fn new(
        shape: ShapeId,
        object: &str,
        mask: ColourMask,
        cameras: usize,
        render: &RenderSettings,
        occluder_threshold: f32,
    ) -> Self {
        Self {
            shape,
            object: object.to_string(),
            mask,
            renderer: CpuRenderer::images_only(render.clone()),
            occluder_threshold,
            backgrounds: vec![None; cameras],
            series: vec![Vec::new(); cameras],
        }
    }

    /// Measure camera `c`'s image; returns the overlay (green: both, red: mask only, blue:
    /// silhouette only) when `overlay` is asked for.
    pub fn measure(
        &mut self,
        world: &World,
        c: usize,
        camera: &Camera,
        image: &[Vec3],
        t: f64,
        overlay: bool,
    ) -> Option<Vec<Vec3>> {
        let (sil, palette) = silhouette(&mut self.renderer, world, self.shape, camera);
        let mask = self.mask.segment(image, camera.width, camera.height);
        if self.backgrounds[c].is_none() {
            self.backgrounds[c] = Some(
                self.renderer
                    .forward(
                        &GaussianCloud::static_scene(world),
                        camera,
                        Roi::full(camera),
                    )
                    .colour,
            );
        }
        let background = self.backgrounds[c].as_deref().unwrap_or_default();
        let threshold = self.occluder_threshold;
        let (mut inter, mut union) = (0usize, 0usize);
        for k in 0..mask.len() {
            if !(sil[k] || mask[k]) {
                continue;
            }
            let o = image[k];
            let explained = mask[k]
                || background
                    .get(k)
                    .is_some_and(|b| explained(o, *b, &palette, threshold));
            if explained {
                inter += (sil[k] && mask[k]) as usize;
                union += 1;
            }
        }
        let visible = if union == 0 {
            1.0
        } else {
            inter as f32 / union as f32
        };
        self.series[c].push((t, crate::init::mask::iou(&sil, &mask), visible));
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

/// The silhouette meters of a replay (one per object with a colour mask) as one observer, and
/// the contact sheet of six moments spread over the recording.
pub struct Silhouettes {
    meters: Vec<SilhouetteMeter>,
    cameras: Vec<String>,
    sheet_ticks: Vec<usize>,
    sheet: Vec<Vec<(u32, u32, Vec<Vec3>)>>,
}

impl Silhouettes {
    /// Meters for the `objects` of `world` that have a mask, over `ticks` ticks of `cameras`.
    /// `occluder_threshold`: the correction's occluder test (0: its usual value, 0.35).
    pub fn new(
        world: &World,
        objects: &[ObjectConfig],
        cameras: Vec<String>,
        ticks: usize,
        render: &RenderSettings,
        occluder_threshold: f32,
    ) -> Self {
        let threshold = if occluder_threshold > 0.0 {
            occluder_threshold
        } else {
            0.35
        };
        let meters = objects
            .iter()
            .filter_map(|o| {
                let shape = world.shape_id(&o.name)?;
                Some(SilhouetteMeter::new(
                    shape,
                    &o.name,
                    o.mask?,
                    cameras.len(),
                    render,
                    threshold,
                ))
            })
            .collect();
        Self {
            meters,
            cameras,
            sheet_ticks: (0..6)
                .map(|i| 1 + i * ticks.saturating_sub(1) / 5)
                .collect(),
            sheet: Vec::new(),
        }
    }

    /// Per object and camera the IoU statistics; writes `silhouette_iou.csv` and
    /// `contact_sheet.png` into `out` (nothing without meters).
    pub fn finish(
        &self,
        out: &std::path::Path,
    ) -> Result<BTreeMap<String, BTreeMap<String, IouStats>>> {
        let mut table: BTreeMap<String, BTreeMap<String, IouStats>> = BTreeMap::new();
        if self.meters.is_empty() {
            return Ok(table);
        }
        let mut csv = String::from("t,object,camera,iou,visible_iou\n");
        for meter in &self.meters {
            let per_camera = table.entry(meter.object.clone()).or_default();
            for (series, camera) in meter.series.iter().zip(&self.cameras) {
                let whole: Vec<f32> = series.iter().map(|s| s.1).collect();
                let visible: Vec<f32> = series.iter().map(|s| s.2).collect();
                per_camera.insert(camera.clone(), iou_stats(&whole, &visible));
                for (t, v, visible) in series {
                    csv += &format!("{t:.6},{},{camera},{v:.4},{visible:.4}\n", meter.object);
                }
            }
        }
        let path = out.join("silhouette_iou.csv");
        std::fs::write(&path, csv).with_context(|| format!("cannot write {}", path.display()))?;
        write_contact_sheet(&out.join("contact_sheet.png"), &self.sheet)?;
        Ok(table)
    }
}

impl Observer for Silhouettes {
    /// Silhouettes of the corrected state against the images it was corrected with.
    fn tick(&mut self, tick: &Tick) -> Result<()> {
        let overlay = self.sheet_ticks.contains(&tick.index);
        let world = tick.tracker.world();
        let mut row = Vec::new();
        for meter in &mut self.meters {
            for image in &tick.inputs.images {
                let cam = &image.camera;
                let measured = meter.measure(
                    world,
                    image.index,
                    cam,
                    &image.pixels,
                    tick.inputs.time,
                    overlay,
                );
                if let Some(o) = measured {
                    row.push((cam.width, cam.height, o));
                }
            }
        }
        if !row.is_empty() {
            self.sheet.push(row);
        }
        Ok(())
    }
}

pub const TABLE_START: &str = "<!-- real-iou:start -->";
pub const TABLE_END: &str = "<!-- real-iou:end -->";

/// The silhouette IoU of a replay as a Markdown table, with its initialisation and tick times.
pub fn iou_table(m: &super::Metrics) -> String {
    let mut rows = vec![
        format!(
            "Silhouette IoU per camera over {} ticks ({:.1} s), generated by `pegs replay ... --readme README.md`: initialisation {:.1} s, {:.0} ms per tick.",
            m.ticks,
            m.seconds,
            m.init.as_ref().map_or(0.0, |i| i.seconds),
            m.wall_ms_per_tick
        ),
        String::new(),
        "| object | camera | mean | 5th percentile | visible part mean | visible part p5 | frames |".to_string(),
        "| --- | --- | ---: | ---: | ---: | ---: | ---: |".to_string(),
    ];
    for (object, cameras) in &m.silhouette_iou {
        for (camera, s) in cameras {
            rows.push(format!(
                "| {object} | {camera} | {:.3} | {:.3} | {:.3} | {:.3} | {} |",
                s.mean, s.p5, s.visible_mean, s.visible_p5, s.frames
            ));
        }
    }
    rows.join("\n")
}

/// Tile overlays (rows of equal-size images) into one PNG.
pub fn write_contact_sheet(
    path: &std::path::Path,
    rows: &[Vec<(u32, u32, Vec<Vec3>)>],
) -> Result<()> {
    let (w, h) = rows
        .iter()
        .flatten()
        .fold((0, 0), |(w, h), (iw, ih, _)| (w.max(*iw), h.max(*ih)));
    let cols = rows.iter().map(|r| r.len()).max().unwrap_or(0) as u32;
    let mut sheet = image::RgbImage::new((w + 4) * cols.max(1), (h + 4) * rows.len().max(1) as u32);
    for (r, row) in rows.iter().enumerate() {
        for (c, (iw, ih, pixels)) in row.iter().enumerate() {
            for y in 0..*ih {
                for x in 0..*iw {
                    let p = (pixels[(y * iw + x) as usize].clamp(Vec3::ZERO, Vec3::ONE) * 255.0)
                        .round();
                    sheet.put_pixel(
                        c as u32 * (w + 4) + x,
                        r as u32 * (h + 4) + y,
                        image::Rgb([p.x as u8, p.y as u8, p.z as u8]),
                    );
                }
            }
        }
    }
    sheet
        .save(path)
        .with_context(|| format!("cannot write {}", path.display()))
}

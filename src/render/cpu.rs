//! The CPU reference backend: project (parallel over Gaussians), bin into tiles and sort by
//! (tile, depth, index), composite front to back (parallel over tile rows); the backward pass
//! walks each pixel's list back to front and writes per-(tile, Gaussian) partial gradients into
//! disjoint slices, which are then summed in a fixed order. Deterministic, no atomics.

// Comparisons are written `!(x <= limit)` on purpose: NaN must fail them.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::project::{self, ParamGrad, Projected, ProjectedGrad};
use super::{Camera, CloudGrads, GaussianCloud, PixelGrads, RenderOutput, RenderSettings, Roi};
use anyhow::{Result, bail};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// Depth as a sort key: the f32 bits (monotonic for positive depths) with the low 8 mantissa bits
/// dropped, so depths within 2^-15 relative count as equal and fall back to index order. Without
/// it, Gaussians at equal depth in exact arithmetic (lattices) were ordered by rounding noise,
/// which differs between CPU and GPU arithmetic.
pub fn depth_key(depth: f32) -> u32 {
    depth.to_bits() & DEPTH_KEY_MASK
}

pub const DEPTH_KEY_MASK: u32 = 0xFFFF_FF00;

/// Partial gradient of one Gaussian from the pixels of one tile.
#[derive(Clone, Copy, Default)]
struct Partial {
    mean: Vec2,
    conic: Vec3,
    opacity: f32,
    colour: Vec3,
    depth: f32,
}

/// What the forward pass keeps for the backward pass.
struct Frame {
    camera: Camera,
    roi: Roi,
    projected: Vec<Option<Projected>>,
    /// Global tile coordinates of the first tile covering the window, and the grid size.
    tile_origin: (u32, u32),
    tiles: (u32, u32),
    /// Gaussian indices sorted by (tile, depth, index); `ranges[t]` is tile t's slice.
    order: Vec<u32>,
    /// The projected Gaussians in `order`, contiguous per tile so both passes read them in
    /// sequence.
    sorted: Vec<Projected>,
    ranges: Vec<(u32, u32)>,
    /// Per window pixel: transmittance after compositing, and the exclusive end of the entries of
    /// its tile list that were processed.
    final_t: Vec<f32>,
    last: Vec<u32>,
}

pub struct CpuRenderer {
    pub settings: RenderSettings,
    frame: Option<Frame>,
    /// Milliseconds per stage since last taken (`Renderer::take_stage_ms`).
    pub stage_ms: std::collections::BTreeMap<&'static str, f64>,
}

/// Add the time since `clock` to `stage` and restart the clock.
fn lap(
    stage_ms: &mut std::collections::BTreeMap<&'static str, f64>,
    stage: &'static str,
    clock: &mut std::time::Instant,
) {
    let now = std::time::Instant::now();
    *stage_ms.entry(stage).or_insert(0.0) += (now - *clock).as_secs_f64() * 1e3;
    *clock = now;
}

/// Per-pixel compositing outcome.
struct Pixel {
    colour: Vec3,
    depth: f32,
    t: f32,
    last: u32,
}

/// The per-pixel evaluation both passes share: `Some((alpha, gaussian value G, q))` when the
/// Gaussian contributes at `p`.
#[inline]
fn evaluate(g: &Projected, p: Vec2, s: &RenderSettings) -> Option<(f32, f32, Vec2)> {
    let d = p - g.mean;
    let q = g.conic.x * d.x * d.x + 2.0 * g.conic.y * d.x * d.y + g.conic.z * d.y * d.y;
    if !(q <= s.cutoff_sigma * s.cutoff_sigma) {
        return None;
    }
    let gauss = (-0.5 * q).exp();
    let alpha = (g.opacity * gauss).min(s.max_alpha);
    if alpha < s.min_alpha {
        return None;
    }
    Some((alpha, gauss, d))
}

fn composite(list: &[Projected], p: Vec2, s: &RenderSettings) -> Pixel {
    let mut out = Pixel {
        colour: Vec3::ZERO,
        depth: 0.0,
        t: 1.0,
        last: 0,
    };
    for (k, g) in list.iter().enumerate() {
        let Some((alpha, _, _)) = evaluate(g, p, s) else {
            continue;
        };
        let next_t = out.t * (1.0 - alpha);
        if next_t < s.min_transmittance {
            break;
        }
        out.colour += alpha * out.t * g.colour;
        out.depth += alpha * out.t * g.depth;
        out.t = next_t;
        out.last = k as u32 + 1;
    }
    out
}

impl CpuRenderer {
    pub fn new(settings: RenderSettings) -> Self {
        Self {
            settings,
            frame: None,
            stage_ms: Default::default(),
        }
    }

    /// Render `cloud` into `camera` over `roi` (clamped to the image).
    pub fn forward(&mut self, cloud: &GaussianCloud, camera: &Camera, roi: Roi) -> RenderOutput {
        let mut clock = std::time::Instant::now();
        let s = &self.settings;
        let roi = roi.clamped(camera);
        // Gaussians whose conservative footprint misses the window are culled before the full
        // projection: identical output, and a small window costs little more than its pixels.
        let (lo, hi) = (
            Vec2::new(roi.x0 as f32, roi.y0 as f32),
            Vec2::new(roi.x1 as f32, roi.y1 as f32),
        );
        let projected: Vec<Option<Projected>> = (0..cloud.len())
            .into_par_iter()
            .with_min_len(256)
            .map(|i| {
                let g = cloud.get(i);
                let (c, r) = project::footprint_bound(&g, camera, s)?;
                if c.x + r < lo.x || c.y + r < lo.y || c.x - r > hi.x || c.y - r > hi.y {
                    return None;
                }
                project::project(&g, camera, s)
            })
            .collect();
        lap(&mut self.stage_ms, "project", &mut clock);
        let s = &self.settings;
        let tile = s.tile.max(1);
        let tile_origin = (roi.x0 / tile, roi.y0 / tile);
        let tiles = if roi.pixels() == 0 {
            (0, 0)
        } else {
            (
                (roi.x1 - 1) / tile - tile_origin.0 + 1,
                (roi.y1 - 1) / tile - tile_origin.1 + 1,
            )
        };
        // Bin: one key per (tile, Gaussian) overlap of the square around the cut-off ellipse.
        let mut keys: Vec<(u64, u32)> = Vec::new();
        if tiles.0 > 0 {
            for (i, p) in projected.iter().enumerate() {
                let Some(p) = p else { continue };
                // Pixels whose centre (x + 0.5) lies within the radius of the mean.
                let lo = (p.mean - Vec2::splat(p.radius) - Vec2::splat(0.5)).ceil();
                let hi = (p.mean + Vec2::splat(p.radius) - Vec2::splat(0.5)).floor();
                let (x0, y0) = (lo.x.max(roi.x0 as f32), lo.y.max(roi.y0 as f32));
                let (x1, y1) = (hi.x.min(roi.x1 as f32 - 1.0), hi.y.min(roi.y1 as f32 - 1.0));
                if !(x0 <= x1 && y0 <= y1) {
                    continue;
                }
                let (tx0, tx1) = (
                    x0 as u32 / tile - tile_origin.0,
                    x1 as u32 / tile - tile_origin.0,
                );
                let (ty0, ty1) = (
                    y0 as u32 / tile - tile_origin.1,
                    y1 as u32 / tile - tile_origin.1,
                );
                for ty in ty0..=ty1 {
                    for tx in tx0..=tx1 {
                        let t = (ty * tiles.0 + tx) as u64;
                        keys.push(((t << 32) | depth_key(p.depth) as u64, i as u32));
                    }
                }
            }
        }
        keys.par_sort_unstable();
        let n_tiles = (tiles.0 * tiles.1) as usize;
        let mut ranges = vec![(0u32, 0u32); n_tiles];
        let mut k = 0;
        for (t, range) in ranges.iter_mut().enumerate() {
            let start = k;
            while k < keys.len() && (keys[k].0 >> 32) as usize == t {
                k += 1;
            }
            *range = (start as u32, k as u32);
        }
        let order: Vec<u32> = keys.iter().map(|k| k.1).collect();
        // Only Gaussians that projected were binned.
        let sorted: Vec<Projected> = order
            .iter()
            .map(|&i| projected[i as usize].unwrap_or_default())
            .collect();
        lap(&mut self.stage_ms, "sort", &mut clock);

        // Composite, one band of tile rows per task.
        let width = roi.width() as usize;
        let mut colour = vec![Vec3::ZERO; roi.pixels()];
        let mut alpha = vec![0.0f32; roi.pixels()];
        let mut depth = vec![0.0f32; roi.pixels()];
        let mut final_t = vec![1.0f32; roi.pixels()];
        let mut last = vec![0u32; roi.pixels()];
        let bands = tile_row_bands(roi, tile, tile_origin.1, tiles.1);
        let mut band_slices = split_rows(&mut colour, &bands, width)
            .into_iter()
            .zip(split_rows(&mut alpha, &bands, width))
            .zip(split_rows(&mut depth, &bands, width))
            .zip(split_rows(&mut final_t, &bands, width))
            .zip(split_rows(&mut last, &bands, width))
            .enumerate()
            .collect::<Vec<_>>();
        band_slices
            .par_iter_mut()
            .for_each(|(ty, ((((col, alp), dep), ft), la))| {
                let (row0, row1) = bands[*ty];
                for y in row0..row1 {
                    for x in roi.x0..roi.x1 {
                        let tx = x / tile - tile_origin.0;
                        let (a, b) = ranges[(*ty as u32 * tiles.0 + tx) as usize];
                        let px = composite(
                            &sorted[a as usize..b as usize],
                            Vec2::new(x as f32 + 0.5, y as f32 + 0.5),
                            s,
                        );
                        let i = (y - row0) as usize * width + (x - roi.x0) as usize;
                        col[i] = px.colour + px.t * s.background;
                        alp[i] = 1.0 - px.t;
                        dep[i] = px.depth;
                        ft[i] = px.t;
                        la[i] = px.last;
                    }
                }
            });
        lap(&mut self.stage_ms, "rasterise", &mut clock);
        self.frame = Some(Frame {
            camera: *camera,
            roi,
            projected,
            tile_origin,
            tiles,
            order,
            sorted,
            ranges,
            final_t,
            last,
        });
        RenderOutput {
            roi: Some(roi),
            colour,
            alpha,
            depth,
        }
    }

    /// Gradients of a loss with respect to `cloud`, given its gradients with respect to the images
    /// of the last `forward` (which must have rendered this same cloud).
    pub fn backward(&mut self, cloud: &GaussianCloud, d_image: &PixelGrads) -> Result<CloudGrads> {
        let clock = std::time::Instant::now();
        let Some(f) = &self.frame else {
            bail!("backward called before forward")
        };
        let s = &self.settings;
        let n_px = f.roi.pixels();
        if d_image.colour.len() != n_px
            || !(d_image.alpha.is_empty() || d_image.alpha.len() == n_px)
            || !(d_image.depth.is_empty() || d_image.depth.len() == n_px)
        {
            bail!(
                "pixel gradients do not match the rendered window ({} pixels)",
                n_px
            );
        }
        if f.projected.len() != cloud.len() {
            bail!(
                "backward for a cloud of {} Gaussians after rendering {}",
                cloud.len(),
                f.projected.len()
            );
        }
        let tile = s.tile.max(1);
        let width = f.roi.width() as usize;
        let bands = tile_row_bands(f.roi, tile, f.tile_origin.1, f.tiles.1);
        // Partials aligned with `order`; tile rows own contiguous ranges of it.
        let mut partials = vec![Partial::default(); f.order.len()];
        let mut band_parts: Vec<&mut [Partial]> = Vec::with_capacity(bands.len());
        {
            let mut rest: &mut [Partial] = &mut partials;
            for ty in 0..f.tiles.1 {
                let start = f.ranges[(ty * f.tiles.0) as usize].0 as usize;
                let end = f.ranges[((ty + 1) * f.tiles.0 - 1) as usize].1 as usize;
                let consumed = f.order.len() - rest.len();
                let (_, tail) = std::mem::take(&mut rest).split_at_mut(start - consumed);
                let (mine, tail) = tail.split_at_mut(end - start);
                band_parts.push(mine);
                rest = tail;
            }
        }
        band_parts
            .par_iter_mut()
            .enumerate()
            .for_each(|(ty, parts)| {
                let (row0, row1) = bands[ty];
                let band_start = f.ranges[ty * f.tiles.0 as usize].0 as usize;
                for y in row0..row1 {
                    for x in f.roi.x0..f.roi.x1 {
                        let i = (y - f.roi.y0) as usize * width + (x - f.roi.x0) as usize;
                        let tx = x / tile - f.tile_origin.0;
                        let (a, _) = f.ranges[(ty as u32 * f.tiles.0 + tx) as usize];
                        let grads = PixelUpstream {
                            colour: d_image.colour[i],
                            alpha: d_image.alpha.get(i).copied().unwrap_or(0.0),
                            depth: d_image.depth.get(i).copied().unwrap_or(0.0),
                        };
                        let list = &f.sorted[a as usize..a as usize + f.last[i] as usize];
                        let offset = a as usize - band_start;
                        backward_pixel(
                            list,
                            Vec2::new(x as f32 + 0.5, y as f32 + 0.5),
                            f.final_t[i],
                            &grads,
                            s,
                            &mut parts[offset..],
                        );
                    }
                }
            });
        let pixels_ms = clock.elapsed().as_secs_f64() * 1e3;
        // Sum partials per Gaussian in list order (fixed), then chain through the projection.
        let mut per_gaussian = vec![ProjectedGrad::default(); cloud.len()];
        let mut touched = vec![false; cloud.len()];
        for (k, &gi) in f.order.iter().enumerate() {
            touched[gi as usize] = true;
            let p = &partials[k];
            let g = &mut per_gaussian[gi as usize];
            g.mean += p.mean;
            g.conic += p.conic;
            g.opacity += p.opacity;
            g.colour += p.colour;
            g.depth += p.depth;
        }
        let grads: Vec<ParamGrad> = (0..cloud.len())
            .into_par_iter()
            .with_min_len(256)
            .map(|i| {
                if touched[i] {
                    project::project_backward(&cloud.get(i), &f.camera, s, &per_gaussian[i])
                } else {
                    ParamGrad::default()
                }
            })
            .collect();
        let mut out = CloudGrads::zeros(cloud.len());
        for (i, g) in grads.into_iter().enumerate() {
            out.mean[i] = g.mean;
            out.rotation[i] = g.rotation;
            out.log_scale[i] = g.log_scale;
            out.opacity_logit[i] = g.opacity_logit;
            out.colour[i] = g.colour;
        }
        *self.stage_ms.entry("backward_pixels").or_insert(0.0) += pixels_ms;
        let total = clock.elapsed().as_secs_f64() * 1e3;
        *self.stage_ms.entry("backward_project").or_insert(0.0) += total - pixels_ms;
        Ok(out)
    }
}

struct PixelUpstream {
    colour: Vec3,
    alpha: f32,
    depth: f32,
}

/// Walk one pixel's contributors back to front. With the colour "behind" each Gaussian, normalised
/// to the transmittance just after it (`behind`), `d out / d alpha_i = T_i (v_i - behind_i)` for
/// every channel: colour (v = c, background behind the last), alpha (v = 1, 0 behind) and depth.
fn backward_pixel(
    list: &[Projected],
    p: Vec2,
    final_t: f32,
    up: &PixelUpstream,
    s: &RenderSettings,
    parts: &mut [Partial],
) {
    let mut t_after = final_t;
    let mut behind_colour = s.background;
    let mut behind_alpha = 0.0f32;
    let mut behind_depth = 0.0f32;
    for (k, g) in list.iter().enumerate().rev() {
        let Some((alpha, gauss, d)) = evaluate(g, p, s) else {
            continue;
        };
        let t_before = t_after / (1.0 - alpha);
        let d_alpha = t_before
            * ((g.colour - behind_colour).dot(up.colour)
                + (1.0 - behind_alpha) * up.alpha
                + (g.depth - behind_depth) * up.depth);
        let weight = alpha * t_before;
        let part = &mut parts[k];
        part.colour += weight * up.colour;
        part.depth += weight * up.depth;
        if g.opacity * gauss < s.max_alpha {
            part.opacity += d_alpha * gauss;
            let d_power = d_alpha * alpha;
            let (a, b, c) = (g.conic.x, g.conic.y, g.conic.z);
            part.mean += d_power * Vec2::new(a * d.x + b * d.y, b * d.x + c * d.y);
            part.conic += d_power * Vec3::new(-0.5 * d.x * d.x, -d.x * d.y, -0.5 * d.y * d.y);
        }
        behind_colour = alpha * g.colour + (1.0 - alpha) * behind_colour;
        behind_alpha = alpha + (1.0 - alpha) * behind_alpha;
        behind_depth = alpha * g.depth + (1.0 - alpha) * behind_depth;
        t_after = t_before;
    }
}

/// Window rows covered by each global tile row: `[row0, row1)`.
fn tile_row_bands(roi: Roi, tile: u32, first_tile_row: u32, tile_rows: u32) -> Vec<(u32, u32)> {
    (0..tile_rows)
        .map(|k| {
            let ty = first_tile_row + k;
            ((ty * tile).max(roi.y0), ((ty + 1) * tile).min(roi.y1))
        })
        .collect()
}

/// Split a window-sized image into the row bands' slices.
fn split_rows<'a, T>(image: &'a mut [T], bands: &[(u32, u32)], width: usize) -> Vec<&'a mut [T]> {
    let mut out = Vec::with_capacity(bands.len());
    let mut rest = image;
    for &(r0, r1) in bands {
        let (mine, tail) = rest.split_at_mut((r1 - r0) as usize * width);
        out.push(mine);
        rest = tail;
    }
    out
}

//! The CPU reference backend: project (parallel over Gaussians), bin into tiles and sort by
//! (tile, depth, index), composite front to back (parallel over tile rows); the backward pass
//! walks each pixel's list back to front and writes per-(tile, Gaussian) partial gradients into
//! disjoint slices, which are then summed in a fixed order. Deterministic, no atomics.
//!
//! Both passes go one tile row of pixels at a time, Gaussian by Gaussian, each Gaussian over its
//! ellipse's chord through the row (`Chords`): a tile's list is long (about 130 Gaussians for 256
//! pixels on the T-block's correction window) but each Gaussian covers few of its pixels, and
//! testing every pair cost ten evaluations per contribution. Each pixel still meets its
//! contributors in the same order with the same arithmetic, so the images and gradients are
//! those of a pixel-by-pixel walk, bit for bit.
//!
//! The forward pass keeps every contribution it composited (`Contribution`: the pixel, the
//! Gaussian, its alpha and value there), row by row, and the backward pass walks those back to
//! front instead of evaluating each Gaussian again: the same values, so the same gradients, with
//! no exponential and no chord per contribution.

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
    /// Per window pixel: transmittance after compositing.
    final_t: Vec<f32>,
    /// Per tile row: the contributions composited there.
    bands: Vec<BandContributions>,
}

/// One Gaussian's share of one pixel, as the forward pass composited it.
#[derive(Clone, Copy)]
struct Contribution {
    /// Entry of the tile's list (its place in depth order).
    k: u32,
    /// The pixel's column within its tile's row.
    column: u32,
    alpha: f32,
    /// The Gaussian's value `exp(-q/2)` there.
    gauss: f32,
}

/// The contributions of one tile row, row by row and within a row tile by tile, each segment in
/// compositing order (list entry, then column).
#[derive(Default)]
struct BandContributions {
    contributions: Vec<Contribution>,
    /// Start of each (row, tile) segment in `contributions`, then the end of the last.
    starts: Vec<u32>,
}

impl BandContributions {
    fn clear(&mut self) {
        self.contributions.clear();
        self.starts.clear();
    }

    /// The segment of row `row` (counted from the band's first) and tile `tx` of `tiles` per row.
    fn segment(&self, row: usize, tx: usize, tiles: usize) -> &[Contribution] {
        let i = row * tiles + tx;
        &self.contributions[self.starts[i] as usize..self.starts[i + 1] as usize]
    }
}

pub struct CpuRenderer {
    pub settings: RenderSettings,
    /// Whether `forward` keeps its contributions for `backward` (`images_only`: it does not).
    keeps_contributions: bool,
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

/// One pixel's compositing state, then its outcome.
#[derive(Clone, Copy)]
struct Pixel {
    colour: Vec3,
    depth: f32,
    t: f32,
    /// Compositing stopped here (the next Gaussian would take `t` under `min_transmittance`).
    done: bool,
}

impl Pixel {
    const CLEAR: Pixel = Pixel {
        colour: Vec3::ZERO,
        depth: 0.0,
        t: 1.0,
        done: false,
    };
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

/// Where a Gaussian can pass `evaluate`, row by row: the ellipse `q <= q_max`, with `q_max` the
/// cut-off or, for a faint Gaussian, where its alpha falls under `min_alpha` (`o exp(-q/2) >=
/// min_alpha`). On the row `dy` from the mean, pixel centres within `sqrt(h2 - k dy^2)` of
/// `cx - slope dy`. Kept in f64 and widened (1 % in q, a thousandth of a pixel) so that f32
/// rounding in `evaluate` never accepts a pixel outside; `evaluate` still decides each pixel inside,
/// so skipping the rest changes no output.
#[derive(Clone, Copy)]
struct Chords {
    /// Column of the mean (pixel x has its centre at x + 0.5), and its row.
    cx: f64,
    cy: f64,
    slope: f64,
    h2: f64,
    k: f64,
    /// A conic that is not an ellipse keeps every row whole.
    whole: bool,
}

impl Chords {
    fn of(g: &Projected, s: &RenderSettings) -> Self {
        let (a, b, c) = (g.conic.x as f64, g.conic.y as f64, g.conic.z as f64);
        let det = a * c - b * b;
        let cutoff = (s.cutoff_sigma as f64).powi(2);
        let faint = 2.0 * (g.opacity as f64 / s.min_alpha as f64).ln();
        let q_max = cutoff.min(faint) * 1.01 + 1e-3;
        let whole = !(a > 0.0 && det > 0.0 && det.is_finite() && g.mean.is_finite());
        Self {
            cx: g.mean.x as f64 - 0.5,
            cy: g.mean.y as f64,
            slope: b / a,
            h2: q_max / a,
            k: det / (a * a),
            whole,
        }
    }

    /// The columns `[c0, c1)` of `[x0, x1)` on the row whose pixel centres lie at height `py`.
    #[inline]
    fn on_row(&self, py: f32, (x0, x1): (u32, u32)) -> Option<(u32, u32)> {
        if self.whole {
            return Some((x0, x1));
        }
        let dy = py as f64 - self.cy;
        let w2 = self.h2 - self.k * dy * dy;
        if !(w2 >= 0.0) {
            return None;
        }
        let half = w2.sqrt() + 1e-3;
        let centre = self.cx - self.slope * dy;
        // Ceil and floor by truncation of values clamped to the non-negative columns (a libm
        // call each on baseline x86-64).
        let lo = (centre - half).clamp(x0 as f64, x1 as f64);
        let c0 = lo as u32 + ((lo as u32 as f64) < lo) as u32;
        let hi = (centre + half).min(x1 as f64);
        if !(hi >= x0 as f64) {
            return None;
        }
        let c1 = (hi as u32 + 1).min(x1);
        (c0 < c1).then_some((c0, c1))
    }
}

/// Composite the pixels `[x0, x1)` of one tile's row at height `py`, Gaussian by Gaussian in depth
/// order, each over its chord only (`Chords`, aligned with `list`), appending what was composited
/// to `kept` where given. Every pixel meets its contributors in the same order and with the same
/// arithmetic as a walk of the whole list for that pixel alone.
fn composite_row(
    list: &[Projected],
    chords: &[Chords],
    (x0, x1): (u32, u32),
    py: f32,
    s: &RenderSettings,
    row: &mut Vec<Pixel>,
    mut kept: Option<&mut Vec<Contribution>>,
) {
    row.clear();
    row.resize((x1 - x0) as usize, Pixel::CLEAR);
    let mut open = row.len();
    for (k, (g, chord)) in list.iter().zip(chords).enumerate() {
        if open == 0 {
            break;
        }
        let Some((c0, c1)) = chord.on_row(py, (x0, x1)) else {
            continue;
        };
        for x in c0..c1 {
            let px = &mut row[(x - x0) as usize];
            if px.done {
                continue;
            }
            let Some((alpha, gauss, _)) = evaluate(g, Vec2::new(x as f32 + 0.5, py), s) else {
                continue;
            };
            let next_t = px.t * (1.0 - alpha);
            if next_t < s.min_transmittance {
                px.done = true;
                open -= 1;
                continue;
            }
            px.colour += alpha * px.t * g.colour;
            px.depth += alpha * px.t * g.depth;
            px.t = next_t;
            if let Some(kept) = kept.as_mut() {
                kept.push(Contribution {
                    k: k as u32,
                    column: x - x0,
                    alpha,
                    gauss,
                });
            }
        }
    }
}

impl CpuRenderer {
    pub fn new(settings: RenderSettings) -> Self {
        Self {
            settings,
            keeps_contributions: true,
            frame: None,
            stage_ms: Default::default(),
        }
    }

    /// A renderer for images alone (debug images, recordings, silhouettes): `forward` keeps no
    /// contributions (a full frame's are tens of MB at 640x360) and `backward` fails.
    pub fn images_only(settings: RenderSettings) -> Self {
        Self {
            keeps_contributions: false,
            ..Self::new(settings)
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
        let chords: Vec<Chords> = sorted
            .par_iter()
            .with_min_len(256)
            .map(|g| Chords::of(g, s))
            .collect();
        lap(&mut self.stage_ms, "sort", &mut clock);

        // Composite, one band of tile rows per task.
        let width = roi.width() as usize;
        let mut colour = vec![Vec3::ZERO; roi.pixels()];
        let mut alpha = vec![0.0f32; roi.pixels()];
        let mut depth = vec![0.0f32; roi.pixels()];
        let mut final_t = vec![1.0f32; roi.pixels()];
        let bands = tile_row_bands(roi, tile, tile_origin.1, tiles.1);
        // The last frame's contribution buffers are reused: they grow to a frame's size once.
        let mut kept = self.frame.take().map(|f| f.bands).unwrap_or_default();
        kept.resize_with(bands.len(), Default::default);
        let keep = self.keeps_contributions;
        let mut band_slices = split_rows(&mut colour, &bands, width)
            .into_iter()
            .zip(split_rows(&mut alpha, &bands, width))
            .zip(split_rows(&mut depth, &bands, width))
            .zip(split_rows(&mut final_t, &bands, width))
            .zip(kept.iter_mut())
            .enumerate()
            .collect::<Vec<_>>();
        band_slices
            .par_iter_mut()
            .for_each(|(ty, ((((col, alp), dep), ft), band))| {
                let ty = *ty as u32;
                let (row0, row1) = bands[ty as usize];
                let mut row = Vec::with_capacity(tile as usize);
                band.clear();
                for y in row0..row1 {
                    for tx in 0..tiles.0 {
                        let columns = tile_columns(roi, tile, tile_origin.0 + tx);
                        let (a, b) = ranges[(ty * tiles.0 + tx) as usize];
                        let list = &sorted[a as usize..b as usize];
                        let chords = &chords[a as usize..b as usize];
                        band.starts.push(band.contributions.len() as u32);
                        let kept = keep.then_some(&mut band.contributions);
                        composite_row(list, chords, columns, y as f32 + 0.5, s, &mut row, kept);
                        let i0 = (y - row0) as usize * width + (columns.0 - roi.x0) as usize;
                        for (i, px) in (i0..).zip(&row) {
                            col[i] = px.colour + px.t * s.background;
                            alp[i] = 1.0 - px.t;
                            dep[i] = px.depth;
                            ft[i] = px.t;
                        }
                    }
                }
                band.starts.push(band.contributions.len() as u32);
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
            bands: kept,
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
        if !self.keeps_contributions {
            bail!("backward on a renderer made for images only (CpuRenderer::images_only)")
        }
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
                let kept = &f.bands[ty];
                let mut row = Vec::with_capacity(tile as usize);
                for y in row0..row1 {
                    for tx in 0..f.tiles.0 {
                        let (x0, x1) = tile_columns(f.roi, tile, f.tile_origin.0 + tx);
                        let i0 = (y - f.roi.y0) as usize * width + (x0 - f.roi.x0) as usize;
                        row.clear();
                        row.extend((i0..i0 + (x1 - x0) as usize).map(|i| BackPixel {
                            t_after: f.final_t[i],
                            behind_colour: s.background,
                            behind_alpha: 0.0,
                            behind_depth: 0.0,
                            up_colour: d_image.colour[i],
                            up_alpha: d_image.alpha.get(i).copied().unwrap_or(0.0),
                            up_depth: d_image.depth.get(i).copied().unwrap_or(0.0),
                        }));
                        let (a, _) = f.ranges[ty * f.tiles.0 as usize + tx as usize];
                        let offset = a as usize - band_start;
                        backward_row(
                            &f.sorted[a as usize..],
                            kept.segment((y - row0) as usize, tx as usize, f.tiles.0 as usize),
                            x0,
                            y as f32 + 0.5,
                            s,
                            &mut row,
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

/// One pixel's state in the backward walk: the transmittance just after the Gaussian in hand, the
/// colour, alpha and depth "behind" it normalised to that transmittance, and the upstream gradient.
struct BackPixel {
    t_after: f32,
    behind_colour: Vec3,
    behind_alpha: f32,
    behind_depth: f32,
    up_colour: Vec3,
    up_alpha: f32,
    up_depth: f32,
}

/// Walk one tile's row back to front through the contributions the forward pass kept there,
/// Gaussian by Gaussian, each pixel from its own last contributor. With the colour "behind" each
/// Gaussian, normalised to the transmittance just after it (`behind`), `d out / d alpha_i = T_i
/// (v_i - behind_i)` for every channel: colour (v = c, background behind the last), alpha (v = 1,
/// 0 behind) and depth. A Gaussian's partial sums its pixels in row order, as a pixel-by-pixel
/// walk would.
fn backward_row(
    list: &[Projected],
    kept: &[Contribution],
    x0: u32,
    py: f32,
    s: &RenderSettings,
    row: &mut [BackPixel],
    parts: &mut [Partial],
) {
    // Kept in (entry, column) order: take the entries from the last, each one's columns in order.
    let mut end = kept.len();
    while end > 0 {
        let k = kept[end - 1].k;
        let start = kept[..end]
            .iter()
            .rposition(|c| c.k != k)
            .map_or(0, |i| i + 1);
        let (g, part) = (&list[k as usize], &mut parts[k as usize]);
        for c in &kept[start..end] {
            let px = &mut row[c.column as usize];
            let (alpha, gauss) = (c.alpha, c.gauss);
            let d = Vec2::new((x0 + c.column) as f32 + 0.5, py) - g.mean;
            let t_before = px.t_after / (1.0 - alpha);
            let d_alpha = t_before
                * ((g.colour - px.behind_colour).dot(px.up_colour)
                    + (1.0 - px.behind_alpha) * px.up_alpha
                    + (g.depth - px.behind_depth) * px.up_depth);
            let weight = alpha * t_before;
            part.colour += weight * px.up_colour;
            part.depth += weight * px.up_depth;
            if g.opacity * gauss < s.max_alpha {
                part.opacity += d_alpha * gauss;
                let d_power = d_alpha * alpha;
                let (a, b, c) = (g.conic.x, g.conic.y, g.conic.z);
                part.mean += d_power * Vec2::new(a * d.x + b * d.y, b * d.x + c * d.y);
                part.conic += d_power * Vec3::new(-0.5 * d.x * d.x, -d.x * d.y, -0.5 * d.y * d.y);
            }
            px.behind_colour = alpha * g.colour + (1.0 - alpha) * px.behind_colour;
            px.behind_alpha = alpha + (1.0 - alpha) * px.behind_alpha;
            px.behind_depth = alpha * g.depth + (1.0 - alpha) * px.behind_depth;
            px.t_after = t_before;
        }
        end = start;
    }
}

/// Window columns `[x0, x1)` covered by the global tile column `tx`.
fn tile_columns(roi: Roi, tile: u32, tx: u32) -> (u32, u32) {
    ((tx * tile).max(roi.x0), ((tx + 1) * tile).min(roi.x1))
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::GaussianParams;

    /// Uniform in [lo, hi) from a xorshift state.
    fn uniform(state: &mut u64, lo: f32, hi: f32) -> f32 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        lo + (hi - lo) * ((*state >> 40) as f32 / (1u64 << 24) as f32)
    }

    /// A renderer for images only keeps no contributions: it draws the same images, bit for
    /// bit, and refuses a backward pass rather than return gradients of nothing.
    #[test]
    fn a_renderer_for_images_only_draws_the_same_image_and_refuses_gradients() {
        let camera = Camera::look_at(64, 48, 60.0, Vec3::new(0.0, -0.3, 0.3), Vec3::ZERO);
        let mut state = 0x9E37_79B9_7F4A_7C15_u64;
        let mut cloud = GaussianCloud::default();
        for _ in 0..200 {
            let mean = Vec3::new(
                uniform(&mut state, -0.1, 0.1),
                uniform(&mut state, -0.1, 0.1),
                uniform(&mut state, 0.0, 0.05),
            );
            cloud.push(GaussianParams {
                mean,
                rotation: glam::Vec4::W,
                log_scale: Vec3::splat(0.01f32.ln()),
                opacity_logit: 1.5,
                colour: Vec3::new(uniform(&mut state, 0.0, 1.0), 0.5, 0.2),
            });
        }
        let (mut both, mut images) = (
            CpuRenderer::new(RenderSettings::default()),
            CpuRenderer::images_only(RenderSettings::default()),
        );
        let a = both.forward(&cloud, &camera, Roi::full(&camera));
        let b = images.forward(&cloud, &camera, Roi::full(&camera));
        assert!(
            a.alpha.iter().any(|&x| x > 0.5),
            "the Gaussians are in view"
        );
        assert_eq!(
            (&a.colour, &a.alpha, &a.depth),
            (&b.colour, &b.alpha, &b.depth)
        );
        let grads = PixelGrads {
            colour: vec![Vec3::ONE; a.colour.len()],
            alpha: Vec::new(),
            depth: Vec::new(),
        };
        assert!(both.backward(&cloud, &grads).is_ok());
        assert!(images.backward(&cloud, &grads).is_err());
    }

    /// The rasteriser visits only a Gaussian's chord of each row: that must hold every pixel
    /// `evaluate` accepts, for round, thin, tilted and faint Gaussians anywhere in the window,
    /// and stay close to the ellipse (a loose chord is correct but slow).
    #[test]
    fn every_pixel_a_gaussian_contributes_to_lies_on_its_chord_through_that_row() {
        let s = RenderSettings::default();
        let mut state = 0x2545_F491_4F6C_DD1D_u64;
        let (mut accepted, mut visited) = (0usize, 0usize);
        for _ in 0..3000 {
            let (sx, sy) = (uniform(&mut state, 0.3, 6.0), uniform(&mut state, 0.3, 6.0));
            let angle = uniform(&mut state, 0.0, std::f32::consts::PI);
            let (c, sn) = (angle.cos(), angle.sin());
            // Covariance R diag(sx^2, sy^2) R^T, and its inverse as the conic.
            let (xx, xy, yy) = (
                c * c * sx * sx + sn * sn * sy * sy,
                c * sn * (sx * sx - sy * sy),
                sn * sn * sx * sx + c * c * sy * sy,
            );
            let det = xx * yy - xy * xy;
            let g = Projected {
                mean: Vec2::new(
                    uniform(&mut state, -4.0, 36.0),
                    uniform(&mut state, -4.0, 36.0),
                ),
                conic: Vec3::new(yy / det, -xy / det, xx / det),
                depth: 1.0,
                radius: 3.0 * sx.max(sy),
                opacity: uniform(&mut state, 0.0, 1.0).powi(3),
                colour: Vec3::ONE,
            };
            let chords = Chords::of(&g, &s);
            for y in 0..32u32 {
                let py = y as f32 + 0.5;
                let span = chords.on_row(py, (0, 32));
                visited += span.map_or(0, |(c0, c1)| (c1 - c0) as usize);
                for x in 0..32u32 {
                    if evaluate(&g, Vec2::new(x as f32 + 0.5, py), &s).is_some() {
                        accepted += 1;
                        assert!(
                            span.is_some_and(|(c0, c1)| c0 <= x && x < c1),
                            "pixel ({x}, {y}) contributes but the chord is {span:?}"
                        );
                    }
                }
            }
        }
        assert!(
            accepted > 100_000,
            "too few contributing pixels to judge: {accepted}"
        );
        assert!(
            (visited as f64) < 1.1 * accepted as f64,
            "chords visit {visited} pixels for {accepted} contributions"
        );
    }
}

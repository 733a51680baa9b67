//! Objects from RGB-D and instance masks (the paper's dual Gaussian-particle initialisation, for
//! rigid objects resting on the table): the ground plane by RANSAC on the depth points; per object,
//! its masked depth points give an oriented bounding box standing on the ground (one in the air at
//! the first frame: from the lowest of its mask's edge up); a lattice of particles fills the box;
//! carving removes the cells a camera sees through (depth) or sees no object at (mask), and
//! `without_phantoms` those no camera saw the object over or under (hidden by the robot or by the
//! object itself); one Gaussian per particle gets its colour from the images by Adam; Gaussians are
//! bonded to their particles. Objects built side by side are parted where their particles overlap
//! (`part_overlapping`: the collision shape only, never the Gaussians).

use super::table::{ColourFit, FitFrame, fit_colours};
use crate::math::Pose;
use crate::render::{Camera, GaussianCloud, GaussianParams, RenderSettings, logit};
use crate::world::{BodyGaussian, ObjectModel};
use anyhow::{Context, Result, bail};
use glam::{Quat, Vec2, Vec3, Vec4};
use serde::Serialize;

/// One camera's RGB-D frame with instance labels (0: no object).
pub struct RgbdFrame<'a> {
    pub camera: Camera,
    pub colour: &'a [Vec3],
    /// Metres along the optical axis; 0 or non-finite where there is no measurement.
    pub depth: &'a [f32],
    pub labels: &'a [u8],
}

impl RgbdFrame<'_> {
    fn check(&self) -> Result<()> {
        let n = (self.camera.width * self.camera.height) as usize;
        if self.colour.len() != n || self.depth.len() != n || self.labels.len() != n {
            bail!("RGB-D frame: colour, depth and labels must all have {n} pixels");
        }
        Ok(())
    }

    /// World point seen at pixel `k`, if it has a depth.
    pub fn point(&self, k: usize) -> Option<Vec3> {
        self.point_at_depth(k, self.depth[k])
    }

    /// World point on pixel `k`'s ray at depth `d` (metres along the optical axis), if `d` is one.
    fn point_at_depth(&self, k: usize, d: f32) -> Option<Vec3> {
        if !(d.is_finite() && d > 0.0) {
            return None;
        }
        let c = &self.camera;
        let (u, v) = (
            (k as u32 % c.width) as f32 + 0.5,
            (k as u32 / c.width) as f32 + 0.5,
        );
        let p = Vec3::new((u - c.cx) / c.fx * d, (v - c.cy) / c.fy * d, d);
        Some(c.world_to_camera.inverse().transform_point(p))
    }
}

/// A plane `normal . p = height` fitted by RANSAC: the plane through three random points with the
/// most points within `tolerance`, refined by least squares on its inliers.
pub fn ground_ransac(
    points: &[Vec3],
    iterations: usize,
    tolerance: f32,
    seed: u64,
) -> Option<(Vec3, f32, usize)> {
    if points.len() < 3 {
        return None;
    }
    let mut state = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    let mut next = |n: usize| {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 33) as usize) % n
    };
    let mut best: Option<(Vec3, f32, usize)> = None;
    for _ in 0..iterations {
        let (a, b, c) = (
            points[next(points.len())],
            points[next(points.len())],
            points[next(points.len())],
        );
        let Some(n) = (b - a).cross(c - a).try_normalize() else {
            continue;
        };
        let n = if n.z < 0.0 { -n } else { n };
        let h = n.dot(a);
        let count = points
            .iter()
            .filter(|p| (n.dot(**p) - h).abs() < tolerance)
            .count();
        if best.is_none_or(|(_, _, k)| count > k) {
            best = Some((n, h, count));
        }
    }
    let (n, h, _) = best?;
    // Least squares on the inliers: the normal is the direction of least spread.
    let inliers: Vec<Vec3> = points
        .iter()
        .copied()
        .filter(|p| (n.dot(*p) - h).abs() < tolerance)
        .collect();
    let centre = inliers.iter().copied().sum::<Vec3>() / inliers.len() as f32;
    let mut cov = glam::Mat3::ZERO;
    for p in &inliers {
        let d = *p - centre;
        cov += glam::Mat3::from_cols(d * d.x, d * d.y, d * d.z);
    }
    let refined = smallest_eigenvector(cov, n);
    let refined = if refined.dot(n) < 0.0 {
        -refined
    } else {
        refined
    };
    Some((refined, refined.dot(centre), inliers.len()))
}

/// Eigenvector of the smallest eigenvalue of a symmetric positive semi-definite matrix, by inverse
/// iteration from `guess`.
fn smallest_eigenvector(m: glam::Mat3, guess: Vec3) -> Vec3 {
    let shifted = m + glam::Mat3::from_diagonal(Vec3::splat(
        1e-9 + 1e-6 * m.x_axis.x.abs().max(m.y_axis.y.abs()).max(m.z_axis.z.abs()),
    ));
    let inv = shifted.inverse();
    let mut v = guess.normalize();
    for _ in 0..20 {
        v = (inv * v).try_normalize().unwrap_or(v);
    }
    v
}

/// A rope lying on the ground, labelled `label`: the centre line of its masked depth points as a
/// chain of particle centres `2 * radius` apart, one particle radius above the ground, and its mean
/// colour. The points are binned on a grid of `radius` cells in the ground plane; the geodesic
/// distance (breadth first over neighbouring cells) from the cell farthest from an arbitrary start
/// orders them along the rope, which is cut into as many stretches as particles of `2 * radius`
/// fit its length; each particle is the mean of its stretch.
pub fn rope_from_rgbd(
    name: &str,
    label: u8,
    frames: &[RgbdFrame],
    ground: (Vec3, f32),
    radius: f32,
) -> Result<(Vec<Vec3>, Vec3)> {
    use std::collections::{HashMap, VecDeque};
    let (normal, height) = (ground.0.normalize(), ground.1);
    let e1 = normal.any_orthonormal_vector();
    let e2 = normal.cross(e1);
    let mut cells: HashMap<glam::IVec2, (Vec2, usize)> = HashMap::new();
    let (mut colour, mut seen) = (Vec3::ZERO, 0usize);
    for f in frames {
        f.check()?;
        for k in 0..f.depth.len() {
            if f.labels[k] != label {
                continue;
            }
            colour += f.colour[k];
            seen += 1;
            if let Some(p) = f.point(k) {
                let q = Vec2::new(p.dot(e1), p.dot(e2));
                let cell = cells
                    .entry((q / radius).floor().as_ivec2())
                    .or_insert((Vec2::ZERO, 0));
                cell.0 += q;
                cell.1 += 1;
            }
        }
    }
    if cells.len() < 2 {
        bail!("rope '{name}' (label {label}): too few depth points in its masks");
    }
    let neighbours = |c: glam::IVec2| {
        (-1..=1)
            .flat_map(move |dy| (-1..=1).map(move |dx| c + glam::IVec2::new(dx, dy)))
            .filter(move |n| *n != c)
    };
    let bfs = |start: glam::IVec2| {
        let mut dist: HashMap<glam::IVec2, f32> = HashMap::from([(start, 0.0)]);
        let mut queue = VecDeque::from([start]);
        while let Some(c) = queue.pop_front() {
            for n in neighbours(c) {
                if cells.contains_key(&n) && !dist.contains_key(&n) {
                    dist.insert(n, dist[&c] + (n - c).as_vec2().length() * radius);
                    queue.push_back(n);
                }
            }
        }
        dist
    };
    let mut keys: Vec<glam::IVec2> = cells.keys().copied().collect();
    keys.sort_by_key(|c| (c.x, c.y));
    let farthest = |d: &HashMap<glam::IVec2, f32>| {
        d.iter()
            .max_by(|a, b| a.1.total_cmp(b.1).then((b.0.x, b.0.y).cmp(&(a.0.x, a.0.y))))
            .map(|(c, _)| *c)
    };
    let end = farthest(&bfs(keys[0])).context("empty rope")?;
    let along = bfs(end);
    // Cell centres span the rope's length less one cell; its particles touch end to end.
    let length = along.values().copied().fold(0.0, f32::max) + radius;
    let n = ((length / (2.0 * radius)).round() as usize).max(2);
    let pitch = length / n as f32;
    let mut bins = vec![(Vec2::ZERO, 0usize); n];
    for (c, d) in &along {
        let (sum, count) = cells[c];
        let b = (((d + radius / 2.0) / pitch).floor().max(0.0) as usize).min(n - 1);
        bins[b].0 += sum;
        bins[b].1 += count;
    }
    let points: Vec<Vec3> = bins
        .iter()
        .filter(|b| b.1 > 0)
        .map(|(sum, count)| {
            let q = *sum / *count as f32;
            e1 * q.x + e2 * q.y + normal * (height + radius)
        })
        .collect();
    Ok((points, colour / seen.max(1) as f32))
}

/// Instance labels without masks: the depth points more than `min_height` above the ground and
/// farther than `clearance` from every point of `known` (e.g. the robot's particles), grouped into
/// connected clusters on a grid of `cell` metres; label k + 1 marks the k-th largest cluster.
pub fn cluster_labels(
    cameras: &[Camera],
    depths: &[&[f32]],
    ground: (Vec3, f32),
    known: &[Vec3],
    min_height: f32,
    clearance: f32,
    cell: f32,
) -> Vec<Vec<u8>> {
    use std::collections::HashMap;
    let key = |p: Vec3| (p / cell).floor().as_ivec3();
    let near_known: std::collections::HashSet<glam::IVec3> = {
        let reach = (clearance / cell).ceil() as i32;
        let mut set = std::collections::HashSet::new();
        for p in known {
            let k = key(*p);
            for dz in -reach..=reach {
                for dy in -reach..=reach {
                    for dx in -reach..=reach {
                        set.insert(k + glam::IVec3::new(dx, dy, dz));
                    }
                }
            }
        }
        set
    };
    // Candidate points per pixel, and the occupied cells.
    let mut pixel_cells: Vec<Vec<Option<glam::IVec3>>> = Vec::new();
    let mut occupied: HashMap<glam::IVec3, usize> = HashMap::new();
    for (camera, depth) in cameras.iter().zip(depths) {
        let frame = RgbdFrame {
            camera: *camera,
            colour: &[],
            depth,
            labels: &[],
        };
        let cells: Vec<Option<glam::IVec3>> = (0..depth.len())
            .map(|k| {
                let p = frame.point(k)?;
                let k = key(p);
                (ground.0.dot(p) - ground.1 > min_height && !near_known.contains(&k)).then_some(k)
            })
            .collect();
        for c in cells.iter().flatten() {
            *occupied.entry(*c).or_insert(0) += 1;
        }
        pixel_cells.push(cells);
    }
    // Connected components of occupied cells (26-neighbourhood).
    let mut component: HashMap<glam::IVec3, usize> = HashMap::new();
    let mut sizes = Vec::new();
    let mut cells: Vec<glam::IVec3> = occupied.keys().copied().collect();
    cells.sort_by_key(|c| (c.x, c.y, c.z));
    for start in cells {
        if component.contains_key(&start) {
            continue;
        }
        let id = sizes.len();
        let (mut stack, mut size) = (vec![start], 0usize);
        component.insert(start, id);
        while let Some(c) = stack.pop() {
            size += occupied[&c];
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let n = c + glam::IVec3::new(dx, dy, dz);
                        if occupied.contains_key(&n) && !component.contains_key(&n) {
                            component.insert(n, id);
                            stack.push(n);
                        }
                    }
                }
            }
        }
        sizes.push(size);
    }
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by(|a, b| sizes[*b].cmp(&sizes[*a]).then(a.cmp(b)));
    let mut rank = vec![0u8; sizes.len()];
    for (r, &c) in order.iter().enumerate().take(255) {
        rank[c] = r as u8 + 1;
    }
    pixel_cells
        .iter()
        .map(|cells| {
            cells
                .iter()
                .map(|c| c.map_or(0, |c| rank[component[&c]]))
                .collect()
        })
        .collect()
}

/// How an object was found.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RgbdObjectReport {
    pub points: usize,
    pub box_size: [f32; 3],
    pub lattice_cells: usize,
    pub carved: usize,
    pub particles: usize,
    /// Gaussians after densification.
    pub gaussians: usize,
    pub colour_fit: ColourFit,
    pub refine: RefineReport,
    pub densified: ColourFit,
    pub seconds: f64,
    /// How far (mm) its particles reached into another object's as built, before
    /// `part_overlapping` moved them apart (0: no overlap).
    pub parted_mm: f32,
    /// Cells carving kept that no camera saw the object over or under (`without_phantoms`):
    /// removed.
    pub phantom_cells: usize,
}

/// Build the object labelled `label` in `frames`: particles of `radius` filling what the cameras
/// cannot see through inside its bounding box on the ground `normal . p = height`. `surface_inset`
/// is how far below the true surface the depth measures it (0 for a depth camera; a Gaussian
/// render's expected depth lies about one Gaussian deviation inside).
pub fn object_from_rgbd(
    name: &str,
    label: u8,
    frames: &[RgbdFrame],
    ground: (Vec3, f32),
    radius: f32,
    surface_inset: f32,
    render: &RenderSettings,
) -> Result<(ObjectModel, RgbdObjectReport)> {
    let clock = std::time::Instant::now();
    for f in frames {
        f.check()?;
    }
    let points = masked_points(frames, label);
    if points.len() < 10 {
        bail!(
            "object '{name}' (label {label}): only {} depth points in its masks",
            points.len()
        );
    }
    let (points, bulk) = within_bulk(points, ground, radius);
    let step = 2.0 * radius;
    let carved_box = |bottom: f32| {
        let (pose, size) = standing_box(&points, ground, (bottom, bulk.1), surface_inset);
        let lattice = box_cells(size, radius);
        let carved = carve(&lattice, &pose, frames, label, step);
        (pose, size, lattice.len(), carved)
    };
    // Built standing on the ground first. Where the cameras see the ground under it (of the
    // columns of cells carving leaves, under half keep one within `IN_THE_AIR` of the ground) and
    // its lowest seen point is higher, it is in the air: built again from the lowest of its
    // mask's edge up (`lowest_edge`). (Seen only from above, a tall object resting on the table
    // keeps every cell under its top, so it is never taken for one in the air; one in the air
    // keeps cells only in the shadow all cameras have under it.)
    let standing = carved_box(0.0);
    let on_ground = grounded_share(&standing.3, standing.1, radius, super::IN_THE_AIR);
    let in_the_air = bulk.0 > super::IN_THE_AIR && on_ground < 0.5;
    let (pose, size, lattice_cells, carved) = match in_the_air {
        true => carved_box(lowest_edge(frames, label, ground, bulk.0, step)),
        false => standing,
    };
    let kept = without_phantoms(&carved, &pose, &points, frames, label, (radius, 0.5 * step));
    if kept.is_empty() {
        bail!("object '{name}': every cell of its bounding box was carved away");
    }
    // One spherical Gaussian per cell, coloured from the images inside the object's masks.
    let object_render = RenderSettings {
        background: Vec3::ZERO,
        ..render.clone()
    };
    let sigma = 0.6 * radius;
    let mut cloud = cell_gaussians(&kept, &pose, sigma, mean_colour(frames, label));
    let fit_frames: Vec<FitFrame> = frames
        .iter()
        .map(|f| FitFrame {
            camera: f.camera,
            image: f.colour,
            ignore: f.labels.iter().map(|l| *l != label).collect(),
        })
        .collect();
    let colour_fit = fit_colours(
        &mut cloud,
        &fit_frames,
        60,
        0.05,
        1.0,
        &object_render,
        false,
    )?;
    // Rounds of Adam on the positions (photometric + mask loss), each followed by Jacobi steps that
    // keep the Gaussians, as particle-sized spheres, apart and above the ground.
    let masks: Vec<Vec<bool>> = frames
        .iter()
        .map(|f| f.labels.iter().map(|l| *l == label).collect())
        .collect();
    let refine = refine_positions(&mut cloud, frames, &masks, ground, radius, &object_render)?;
    // Particles at the Gaussians' locations.
    let inv = pose.inverse();
    let body: Vec<Vec3> = cloud.mean.iter().map(|m| inv.transform_point(*m)).collect();
    let mut dense = densified(&cloud, &body, &kept, &pose, radius, sigma);
    let densified = fit_colours(
        &mut dense,
        &fit_frames,
        30,
        0.03,
        1.0,
        &object_render,
        false,
    )?;
    let gaussians = (0..dense.len())
        .map(|k| BodyGaussian {
            mean: inv.transform_point(dense.mean[k]),
            rotation: Quat::IDENTITY,
            scale: Vec3::splat(dense.log_scale[k].x.exp()),
            opacity: 0.95,
            colour: dense.colour[k],
        })
        .collect();
    let report = RgbdObjectReport {
        points: points.len(),
        box_size: size.to_array(),
        lattice_cells,
        carved: lattice_cells - carved.len(),
        phantom_cells: carved.len() - kept.len(),
        particles: kept.len(),
        gaussians: dense.len(),
        colour_fit,
        refine,
        densified,
        seconds: clock.elapsed().as_secs_f64(),
        parted_mm: 0.0,
    };
    let particles = body.iter().map(|b| (*b, radius)).collect();
    let model = ObjectModel {
        name: name.to_string(),
        pose,
        particles,
        gaussians,
    };
    Ok((model, report))
}

/// Jacobi rounds that move objects' particles out of other objects' (`part_overlapping`).
const PARTING_ROUNDS: usize = 10;

/// Objects built side by side from the same frames overlap: a particle sphere reaches up to a
/// radius past the surface the depth saw (cells are kept unless a camera sees past them, and
/// the refinement moves them to the silhouette), so two objects a few millimetres apart are
/// built reaching into each other, and the physics shoves them apart at its first tick (MuJoCo's
/// heavy5_702: two cylinders 9 mm apart built 6.5 mm into each other, each thrown 9 mm off and
/// held there by contact). Overlapping particles of different objects are moved apart along the
/// table, each half the overlap, for a few rounds; only the collision shape changes (the
/// Gaussians stay where the images put them). Returns per object the deepest overlap (mm) it
/// had with another before.
pub fn part_overlapping(models: &mut [ObjectModel], up: Vec3) -> Vec<f32> {
    let up = up.normalize();
    let mut deepest = vec![0.0f32; models.len()];
    for round in 0..PARTING_ROUNDS {
        let world: Vec<Vec<Vec3>> = (models.iter())
            .map(|m| {
                (m.particles.iter())
                    .map(|(b, _)| m.pose.transform_point(*b))
                    .collect()
            })
            .collect();
        let mut push: Vec<Vec<(Vec3, u32)>> = (models.iter())
            .map(|m| vec![(Vec3::ZERO, 0); m.particles.len()])
            .collect();
        let mut any = false;
        for a in 0..models.len() {
            for b in a + 1..models.len() {
                for (i, (pi, ri)) in world[a].iter().zip(&models[a].particles).enumerate() {
                    for (j, (pj, rj)) in world[b].iter().zip(&models[b].particles).enumerate() {
                        let along = *pi - *pj;
                        let flat = along - up * up.dot(along);
                        let overlap = ri.1 + rj.1 - along.length();
                        if overlap <= 0.0 || flat.length() < 1e-6 {
                            continue;
                        }
                        if round == 0 {
                            deepest[a] = deepest[a].max(overlap * 1e3);
                            deepest[b] = deepest[b].max(overlap * 1e3);
                        }
                        let d = flat.normalize() * (0.5 * overlap);
                        push[a][i].0 += d;
                        push[a][i].1 += 1;
                        push[b][j].0 -= d;
                        push[b][j].1 += 1;
                        any = true;
                    }
                }
            }
        }
        if !any {
            break;
        }
        for (m, push) in models.iter_mut().zip(&push) {
            let to_body = m.pose.rotation.inverse();
            for ((b, _), (d, n)) in m.particles.iter_mut().zip(push) {
                if *n > 0 {
                    *b += to_body * (*d / *n as f32);
                }
            }
        }
    }
    deepest
}

/// Masked depth points, away from the mask's edge (mixed depths at silhouettes).
fn masked_points(frames: &[RgbdFrame], label: u8) -> Vec<Vec3> {
    let mut points: Vec<Vec3> = Vec::new();
    for f in frames {
        let (w, h) = (f.camera.width as usize, f.camera.height as usize);
        for y in 1..h.saturating_sub(1) {
            for x in 1..w.saturating_sub(1) {
                let k = y * w + x;
                if interior(f, label, k)
                    && let Some(p) = f.point(k)
                {
                    points.push(p);
                }
            }
        }
    }
    points
}

/// Whether pixel `k` of `f` and its four neighbours are all labelled `label` (never a pixel on the
/// image's border).
fn interior(f: &RgbdFrame, label: u8, k: usize) -> bool {
    let (w, h) = (f.camera.width as usize, f.camera.height as usize);
    let (x, y) = (k % w.max(1), k / w.max(1));
    (1..w.saturating_sub(1)).contains(&x)
        && (1..h.saturating_sub(1)).contains(&y)
        && [k, k - 1, k + 1, k - w, k + w]
            .iter()
            .all(|&j| f.labels[j] == label)
}

/// The mask's edge where the object's depth continues up to it: every pixel of the mask beside
/// one outside it, on its ray at the depth its interior neighbours see (its own depth mixes the
/// object's with what lies behind). The interior points (`masked_points`) stop a pixel short of
/// these; its footprint, depth over focal length, is millimetres.
fn mask_edge_points(frames: &[RgbdFrame], label: u8) -> Vec<Vec3> {
    let mut points: Vec<Vec3> = Vec::new();
    for f in frames {
        let (w, h) = (f.camera.width as usize, f.camera.height as usize);
        for y in 1..h.saturating_sub(1) {
            for x in 1..w.saturating_sub(1) {
                let k = y * w + x;
                if f.labels[k] != label || interior(f, label, k) {
                    continue;
                }
                let inside: Vec<f32> = [k - 1, k + 1, k - w, k + w]
                    .into_iter()
                    .filter(|&j| interior(f, label, j))
                    .map(|j| f.depth[j])
                    .filter(|d| d.is_finite() && *d > 0.0)
                    .collect();
                if inside.is_empty() {
                    continue;
                }
                let depth = inside.iter().sum::<f32>() / inside.len() as f32;
                if let Some(p) = f.point_at_depth(k, depth) {
                    points.push(p);
                }
            }
        }
    }
    points
}

fn quantile(v: &[f32], q: f32) -> f32 {
    v[((v.len() - 1) as f32 * q).round() as usize]
}

/// Stray labels (a few pixels of something else) must not stretch the box: the points within the
/// bulk of the heights above the ground, and the bulk's lowest and highest height.
fn within_bulk(
    mut points: Vec<Vec3>,
    (normal, height): (Vec3, f32),
    radius: f32,
) -> (Vec<Vec3>, (f32, f32)) {
    let normal = normal.normalize();
    let mut heights: Vec<f32> = points.iter().map(|p| normal.dot(*p) - height).collect();
    heights.sort_by(f32::total_cmp);
    let bulk = (quantile(&heights, 0.005), quantile(&heights, 0.995));
    let (h_lo, h_hi) = (bulk.0 - 2.0 * radius, bulk.1 + 2.0 * radius);
    points.retain(|p| (h_lo..=h_hi).contains(&(normal.dot(*p) - height)));
    (points, bulk)
}

/// How high above the ground an object in the air begins: the lowest of its mask's edge
/// (`mask_edge_points`, the same share of the lowest left out as for the bulk), which lies a
/// pixel's footprint below `lowest_seen`, the bulk's lowest interior point; never more than
/// `reach` (a particle's width) below it, so stray labels at the edge cannot stretch the box.
fn lowest_edge(
    frames: &[RgbdFrame],
    label: u8,
    (normal, height): (Vec3, f32),
    lowest_seen: f32,
    reach: f32,
) -> f32 {
    let normal = normal.normalize();
    let mut heights: Vec<f32> = (mask_edge_points(frames, label).iter())
        .map(|p| normal.dot(*p) - height)
        .filter(|h| *h >= lowest_seen - reach)
        .collect();
    if heights.is_empty() {
        return lowest_seen;
    }
    heights.sort_by(f32::total_cmp);
    quantile(&heights, 0.005).min(lowest_seen)
}

/// The oriented box that holds `points`: the in-plane turn with the smallest rectangle, from
/// `bottom` to `top` above the ground (bottom 0: standing on it), grown by `surface_inset` (but
/// not into the ground). Its pose (body x, y along the rectangle, z along the ground normal,
/// origin at the centre) and size.
fn standing_box(
    points: &[Vec3],
    ground: (Vec3, f32),
    (bottom, top): (f32, f32),
    surface_inset: f32,
) -> (Pose, Vec3) {
    let (normal, height) = (ground.0.normalize(), ground.1);
    let e1 = normal.any_orthonormal_vector();
    let e2 = normal.cross(e1);
    let flat: Vec<Vec2> = points
        .iter()
        .map(|p| Vec2::new(p.dot(e1), p.dot(e2)))
        .collect();
    // The rectangle of the points along each rotated axis.
    let rect = |angle: f32| {
        let (s, c) = angle.sin_cos();
        let u: Vec<f32> = flat.iter().map(|q| c * q.x + s * q.y).collect();
        let v: Vec<f32> = flat.iter().map(|q| -s * q.x + c * q.y).collect();
        let span = |w: &[f32]| {
            let lo = w.iter().copied().fold(f32::INFINITY, f32::min);
            (lo, w.iter().copied().fold(f32::NEG_INFINITY, f32::max))
        };
        let (u, v) = (span(&u), span(&v));
        (Vec2::new(u.0, v.0), Vec2::new(u.1, v.1))
    };
    let area = |x: f32| {
        let (lo, hi) = rect(x);
        (hi - lo).x * (hi - lo).y
    };
    let angle = (0..180)
        .map(|k| (k as f32 * 0.5).to_radians())
        .min_by(|a, b| area(*a).total_cmp(&area(*b)))
        .unwrap_or(0.0);
    let (lo, hi) = rect(angle);
    let (lo, hi) = (
        lo - Vec2::splat(surface_inset),
        hi + Vec2::splat(surface_inset),
    );
    let (bottom, top) = ((bottom - surface_inset).max(0.0), top + surface_inset);
    let size = Vec3::new(hi.x - lo.x, hi.y - lo.y, top - bottom);
    let (s, c) = angle.sin_cos();
    let ax = e1 * c + e2 * s;
    let ay = normal.cross(ax);
    let mid = (lo + hi) / 2.0;
    let centre_flat = ax * mid.x + ay * mid.y;
    let centre =
        centre_flat - normal * normal.dot(centre_flat) + normal * (height + (bottom + top) / 2.0);
    let rotation = Quat::from_mat3(&glam::Mat3::from_cols(ax, ay, normal)).normalize();
    (Pose::new(centre, rotation), size)
}

/// Of the columns (along the body's z) that hold a cell of `cells` (a lattice from `box_cells` of
/// a box of `size`), the share that hold one within `reach` of the box's bottom.
fn grounded_share(cells: &[Vec3], size: Vec3, radius: f32, reach: f32) -> f32 {
    use std::collections::HashSet;
    let column = |b: &Vec3| ((b.x / radius).round() as i32, (b.y / radius).round() as i32);
    let all: HashSet<_> = cells.iter().map(column).collect();
    let low: HashSet<_> = (cells.iter())
        .filter(|b| b.z + size.z / 2.0 - radius <= reach)
        .map(column)
        .collect();
    low.len() as f32 / all.len().max(1) as f32
}

/// A lattice of touching particles (spacing 2 x radius) in the body frame: as many as fit `size`,
/// centred in the plane and stacked from the box's bottom up.
fn box_cells(size: Vec3, radius: f32) -> Vec<Vec3> {
    let cells = |extent: f32| ((extent / (2.0 * radius)).round() as usize).max(1);
    let (nx, ny, nz) = (cells(size.x), cells(size.y), cells(size.z));
    let step = 2.0 * radius;
    let mut lattice = Vec::with_capacity(nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let x = (i as f32 - (nx - 1) as f32 / 2.0) * step;
                let y = (j as f32 - (ny - 1) as f32 / 2.0) * step;
                lattice.push(Vec3::new(x, y, radius + k as f32 * step - size.z / 2.0));
            }
        }
    }
    lattice
}

/// Carving: a cell is empty if some camera sees past it (a surface further away at its pixel, the
/// object's own far side included), or sees no depth there and not the object (mask).
fn carve(lattice: &[Vec3], pose: &Pose, frames: &[RgbdFrame], label: u8, step: f32) -> Vec<Vec3> {
    let tolerance = 0.5 * step;
    let sees_past = |f: &RgbdFrame, p: Vec3| {
        let (u, v, z) = f.camera.project(p);
        let (w, h) = (f.camera.width as f32, f.camera.height as f32);
        if !(z > 0.0 && u >= 0.0 && v >= 0.0 && u < w && v < h) {
            return false;
        }
        let k = (v as u32 * f.camera.width + u as u32) as usize;
        let d = f.depth[k];
        if d.is_finite() && d > 0.0 {
            d > z + tolerance
        } else {
            f.labels[k] != label
        }
    };
    lattice
        .iter()
        .copied()
        .filter(|b| {
            let p = pose.transform_point(*b);
            !frames.iter().any(|f| sees_past(f, p))
        })
        .collect()
}

/// The cells of `kept` (body frame at `pose`) that no camera saw the object over or under, removed:
/// those with no depth point of the object within `2 * reach` of them seen from above (along the
/// body's z, the ground's normal), and those with none within `reach` that something other than
/// the object hides from a camera. Carving removes what a camera sees past, so a cell every camera
/// sees only through something else, or through the object itself, is kept. Beside an object the
/// robot hovers over at the first frame (as it does before a push) that built material that is
/// not there, and the rod struck it: MuJoCo's control_pushed_1300, a T-block built with its stem
/// 15 mm too wide on the rod's side (41 mm from its centre line against 26.7), was pushed 22 mm
/// by a rod that grazes it by 6 mm and moved it 4. A T-block's inner corners, hidden by its own
/// crossbar and stem, were built filled, up to 45 mm past its outline. A cell at the object's edge
/// (depth points lie a pixel or two inside the mask, fewer on a steep view) stays unless something
/// else hides it, or the object itself does from every camera that has it in view, at a point not
/// over or under it: a T-block's inner corner behind its crossbar and stem, where a column of
/// cells 12 mm past the stem stood on MuJoCo's control_pushed_2402 (its particles reached 17 mm
/// past the outline, 10.6 mm at most over seeds 2400-2403 after) and the rod met it 1.6 cm early.
/// A hole in the depth over the object (its label, no depth) hides nothing.
fn without_phantoms(
    kept: &[Vec3],
    pose: &Pose,
    points: &[Vec3],
    frames: &[RgbdFrame],
    label: u8,
    (reach, tolerance): (f32, f32),
) -> Vec<Vec3> {
    use std::collections::HashMap;
    let far = 2.0 * reach;
    let to_body = pose.inverse();
    let bin = |q: Vec2| ((q.x / far).floor() as i32, (q.y / far).floor() as i32);
    let mut bins: HashMap<(i32, i32), Vec<Vec2>> = HashMap::new();
    for p in points {
        let q = to_body.transform_point(*p).truncate();
        bins.entry(bin(q)).or_default().push(q);
    }
    // Distance (in the ground plane) to the nearest depth point of the object, up to `far`.
    let nearest = |b: Vec3| {
        let (q, (i, j)) = (b.truncate(), bin(b.truncate()));
        let around = (-1..=1).flat_map(|di| (-1..=1).map(move |dj| (i + di, j + dj)));
        (around.filter_map(|key| bins.get(&key)))
            .flatten()
            .map(|n| n.distance(q))
            .fold(f32::INFINITY, f32::min)
    };
    let hidden_by_another = |p: Vec3| {
        frames.iter().any(|f| {
            let Some(k) = f.camera.pixel_of(p) else {
                return false;
            };
            let (d, z) = (f.depth[k], f.camera.project(p).2);
            d.is_finite() && d > 0.0 && d < z - tolerance && f.labels[k] != label
        })
    };
    // Every camera that has the cell in view sees the object there, nearer than the cell, at a
    // point not over or under it: only the object's own material elsewhere (a T-block's
    // crossbar in front of its inner corner) hides it.
    let hidden_by_itself = |b: Vec3| {
        let p = pose.transform_point(b);
        let mut views = (frames.iter())
            .filter_map(|f| Some((f, f.camera.pixel_of(p)?)))
            .peekable();
        views.peek().is_some()
            && views.all(|(f, k)| {
                let z = f.camera.project(p).2;
                f.labels[k] == label
                    && f.point(k).is_some_and(|q| {
                        f.depth[k] < z - tolerance
                            && to_body.transform_point(q).truncate().distance(b.truncate()) > reach
                    })
            })
    };
    (kept.iter().copied())
        .filter(|b| {
            let d = nearest(*b);
            d <= reach
                || (d <= far
                    && !hidden_by_another(pose.transform_point(*b))
                    && !hidden_by_itself(*b))
        })
        .collect()
}

/// The mean colour inside the object's masks.
fn mean_colour(frames: &[RgbdFrame], label: u8) -> Vec3 {
    let (sum, n) = frames
        .iter()
        .flat_map(|f| f.colour.iter().zip(f.labels))
        .filter(|(_, l)| **l == label)
        .fold((Vec3::ZERO, 0usize), |(s, n), (c, _)| (s + *c, n + 1));
    sum / n.max(1) as f32
}

/// One spherical Gaussian of deviation `sigma` per kept cell.
fn cell_gaussians(kept: &[Vec3], pose: &Pose, sigma: f32, colour: Vec3) -> GaussianCloud {
    let mut cloud = GaussianCloud::default();
    let r = pose.rotation;
    let q = Vec4::new(r.x, r.y, r.z, r.w);
    for b in kept {
        cloud.push(GaussianParams {
            mean: pose.transform_point(*b),
            rotation: q,
            log_scale: Vec3::splat(sigma.ln()),
            opacity_logit: logit(0.95),
            colour,
        });
    }
    cloud
}

/// Densify: the Gaussians of surface particles (a lattice neighbour missing) split into eight of
/// half the size for finer appearance; all stay bonded to their particle.
fn densified(
    cloud: &GaussianCloud,
    body: &[Vec3],
    kept: &[Vec3],
    pose: &Pose,
    radius: f32,
    sigma: f32,
) -> GaussianCloud {
    let step = 2.0 * radius;
    let occupied: std::collections::HashSet<[i32; 3]> =
        kept.iter().map(|b| cell_key(*b, step)).collect();
    const FACES: [[i32; 3]; 6] = [
        [1, 0, 0],
        [-1, 0, 0],
        [0, 1, 0],
        [0, -1, 0],
        [0, 0, 1],
        [0, 0, -1],
    ];
    let surface = |b: Vec3| {
        let k = cell_key(b, step);
        FACES
            .iter()
            .any(|d| !occupied.contains(&[k[0] + d[0], k[1] + d[1], k[2] + d[2]]))
    };
    let mut dense = GaussianCloud::default();
    for (i, b) in body.iter().enumerate() {
        let g = cloud.get(i);
        if !surface(kept[i]) {
            dense.push(g);
            continue;
        }
        for corner in 0..8 {
            let half = |bit: usize| if corner & bit == 0 { -0.5 } else { 0.5 };
            let o = Vec3::new(half(1), half(2), half(4)) * radius;
            dense.push(GaussianParams {
                mean: pose.transform_point(*b + o),
                log_scale: Vec3::splat((sigma / 2.0).ln()),
                ..g
            });
        }
    }
    dense
}

fn cell_key(b: Vec3, step: f32) -> [i32; 3] {
    (b / step).round().as_ivec3().to_array()
}

/// What the position rounds did: the mean IoU of the object's rendered coverage with its masks
/// before and after, and how far the Gaussians moved.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RefineReport {
    pub rounds: u32,
    pub iou_before: f32,
    pub iou_after: f32,
    pub max_move_mm: f32,
}

/// Rounds of five Adam steps on the Gaussian means (colour error inside the masks plus coverage
/// error everywhere in the object's window), each followed by four Jacobi steps of sphere-sphere
/// separation (radius `radius`) and ground non-penetration, and a clamp to half a radius from the
/// start.
fn refine_positions(
    cloud: &mut GaussianCloud,
    frames: &[RgbdFrame],
    masks: &[Vec<bool>],
    ground: (Vec3, f32),
    radius: f32,
    render: &RenderSettings,
) -> Result<RefineReport> {
    use crate::correct::adam::Adam;
    use crate::render::{Roi, cpu::CpuRenderer, footprint_roi};
    const ROUNDS: u32 = 10;
    let n = cloud.len();
    let all: Vec<usize> = (0..n).collect();
    let start = cloud.mean.clone();
    let windows: Vec<Roi> = frames
        .iter()
        .map(|f| footprint_roi(cloud, &all, &f.camera, 6.0))
        .collect();
    let mut renderer = CpuRenderer::new(render.clone());
    let mut adam = Adam::new(0.9, 0.999, 1e-8);
    adam.reset(3 * n);
    let mut means: Vec<f32> = cloud.mean.iter().flat_map(|m| m.to_array()).collect();
    let mut report = RefineReport {
        rounds: ROUNDS,
        ..Default::default()
    };
    let views = MaskedViews {
        frames,
        masks,
        windows: &windows,
    };
    for round in 0..=ROUNDS {
        for it in 0..5 {
            for i in 0..n {
                cloud.mean[i] = Vec3::from_slice(&means[3 * i..]);
            }
            let last = round == ROUNDS;
            let (iou, grad) = views.loss(cloud, &mut renderer, !last)?;
            if round == 0 && it == 0 {
                report.iou_before = iou;
            }
            if last {
                report.iou_after = iou;
                break;
            }
            adam.step(&mut means, &grad, 0.0002);
        }
        if round == ROUNDS {
            break;
        }
        for _ in 0..4 {
            jacobi_separate(&mut means, radius, ground);
        }
        keep_near_cells(&mut means, &start, radius);
    }
    for i in 0..n {
        cloud.mean[i] = Vec3::from_slice(&means[3 * i..]);
    }
    report.max_move_mm = cloud
        .mean
        .iter()
        .zip(&start)
        .map(|(a, b)| a.distance(*b))
        .fold(0.0, f32::max)
        * 1e3;
    Ok(report)
}

/// Carving fixed the shape; the rounds only refine the surfaces: every Gaussian stays within half
/// a radius of its cell.
fn keep_near_cells(means: &mut [f32], start: &[Vec3], radius: f32) {
    for (i, s0) in start.iter().enumerate() {
        let m = Vec3::from_slice(&means[3 * i..]);
        let d = m - *s0;
        if d.length() > 0.5 * radius {
            means[3 * i..3 * i + 3]
                .copy_from_slice(&(*s0 + d.normalize() * 0.5 * radius).to_array());
        }
    }
}

/// The frames, the object's masks in them, and the window around the object in each.
struct MaskedViews<'a> {
    frames: &'a [RgbdFrame<'a>],
    masks: &'a [Vec<bool>],
    windows: &'a [crate::render::Roi],
}

impl MaskedViews<'_> {
    /// The mean silhouette IoU over the frames and, if `gradient`, the gradient with respect to
    /// the means of the photometric loss inside the masks plus the mask loss.
    fn loss(
        &self,
        cloud: &GaussianCloud,
        renderer: &mut crate::render::cpu::CpuRenderer,
        gradient: bool,
    ) -> Result<(f32, Vec<f32>)> {
        let mut grad = vec![0.0f32; 3 * cloud.len()];
        let mut iou = 0.0;
        let frames = self.frames;
        for ((f, w), mask) in frames.iter().zip(self.windows).zip(self.masks) {
            if w.pixels() == 0 {
                continue;
            }
            let out = renderer.forward(cloud, &f.camera, *w);
            let (mut d_colour, mut d_alpha) =
                (vec![Vec3::ZERO; w.pixels()], vec![0.0f32; w.pixels()]);
            let (mut inter, mut union) = (0usize, 0usize);
            for y in w.y0..w.y1 {
                for x in w.x0..w.x1 {
                    let k = ((y - w.y0) * w.width() + x - w.x0) as usize;
                    let full = (y * f.camera.width + x) as usize;
                    let m = mask[full];
                    if m {
                        d_colour[k] = 2.0 * (out.colour[k] - f.colour[full]) / w.pixels() as f32;
                    }
                    d_alpha[k] = 2.0 * (out.alpha[k] - m as u8 as f32) / w.pixels() as f32;
                    inter += (out.alpha[k] > 0.5 && m) as usize;
                    union += (out.alpha[k] > 0.5 || m) as usize;
                }
            }
            iou += inter as f32 / union.max(1) as f32 / frames.len() as f32;
            if !gradient {
                continue;
            }
            let pixels = crate::render::PixelGrads {
                colour: d_colour,
                alpha: d_alpha,
                ..Default::default()
            };
            let g = renderer.backward(cloud, &pixels)?;
            for (i, gm) in g.mean.iter().enumerate() {
                for j in 0..3 {
                    grad[3 * i + j] += gm[j];
                }
            }
        }
        Ok((iou, grad))
    }
}

/// One Jacobi step over spheres of `radius` at `means` (x, y, z flattened): overlapping pairs are
/// pushed apart equally, corrections averaged per sphere; then none below the ground.
fn jacobi_separate(means: &mut [f32], radius: f32, ground: (Vec3, f32)) {
    use std::collections::HashMap;
    let n = means.len() / 3;
    let pos: Vec<Vec3> = (0..n).map(|i| Vec3::from_slice(&means[3 * i..])).collect();
    let p = |i: usize| pos[i];
    let cell = 2.0 * radius;
    let mut grid: HashMap<[i32; 3], Vec<usize>> = HashMap::new();
    for i in 0..n {
        grid.entry((p(i) / cell).floor().as_ivec3().to_array())
            .or_default()
            .push(i);
    }
    let mut delta = vec![Vec3::ZERO; n];
    let mut count = vec![0u32; n];
    for i in 0..n {
        let c = (p(i) / cell).floor().as_ivec3();
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let Some(others) = grid.get(&(c + glam::IVec3::new(dx, dy, dz)).to_array())
                    else {
                        continue;
                    };
                    for &j in others {
                        if j <= i {
                            continue;
                        }
                        let d = p(j) - p(i);
                        let dist = d.length();
                        // 1e-4: lattice neighbours touch exactly; rounding must not push them.
                        if dist < 2.0 * radius - 1e-4 && dist > 1e-9 {
                            let push = d / dist * (2.0 * radius - dist) * 0.5;
                            delta[i] -= push;
                            delta[j] += push;
                            count[i] += 1;
                            count[j] += 1;
                        }
                    }
                }
            }
        }
    }
    let (normal, height) = ground;
    for i in 0..n {
        let mut q = p(i);
        if count[i] > 0 {
            q += delta[i] / count[i] as f32;
        }
        let below = height + radius - normal.dot(q);
        if below > 0.0 {
            q += normal * below;
        }
        means[3 * i..3 * i + 3].copy_from_slice(&q.to_array());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ransac_finds_a_tilted_plane_among_outliers() {
        let n = Vec3::new(0.01, -0.02, 1.0).normalize();
        let e1 = n.any_orthonormal_vector();
        let e2 = n.cross(e1);
        let mut points: Vec<Vec3> = (0..400)
            .map(|k| {
                n * 0.03 + e1 * ((k % 20) as f32 * 0.05 - 0.5) + e2 * ((k / 20) as f32 * 0.05 - 0.5)
            })
            .collect();
        // A box's worth of points above it.
        points.extend(
            (0..150).map(|k| Vec3::new(0.1 + (k % 10) as f32 * 0.01, (k / 10) as f32 * 0.01, 0.08)),
        );
        let (normal, height, inliers) = ground_ransac(&points, 200, 0.003, 7).unwrap();
        assert!(normal.angle_between(n) < 1e-3, "{normal} vs {n}");
        assert!(
            (height - 0.03).abs() < 1e-4 && inliers == 400,
            "{height} {inliers}"
        );
    }

    /// 1 cm cells filling a 4 x 3 x 3 cm box centred on its body origin (x 4, y 3, z 3: 36), and a
    /// row of 12 more beside it at each body y of `rows`, in the same order as the box's: by x,
    /// then height, then y.
    fn box_lattice_and_rows(rows: &[f32]) -> Vec<Vec3> {
        let mut lattice = Vec::new();
        for i in 0..4 {
            for k in 0..3 {
                let (x, z) = (-0.015 + i as f32 * 0.01, -0.01 + k as f32 * 0.01);
                let ys = [-0.01, 0.0, 0.01].iter().chain(rows);
                lattice.extend(ys.map(|y| Vec3::new(x, *y, z)));
            }
        }
        lattice
    }

    /// A 4 x 3 x 3 cm box seen from straight above, a plate (no object's label) 8 cm over the
    /// table hiding a strip 2 cm wide beside it, as the robot's hand hides the table beside an
    /// object it is about to push; a lattice of 1 cm cells over the box and the strip (carving
    /// keeps both: no camera sees past them). The strip goes; the box stays whole, its edge cells
    /// and those under a hole in the depth too.
    #[test]
    fn material_no_camera_saw_over_or_under_the_object_is_not_built() {
        let pose = Pose::new(Vec3::new(0.5, 0.1, 0.015), Quat::from_rotation_z(0.4));
        let camera = Camera::look_at(200, 200, 300.0, Vec3::new(0.5, 0.1, 0.6), pose.translation);
        let to_world = camera.world_to_camera.inverse();
        let eye = to_world.translation;
        let inside = |b: Vec3, x: (f32, f32), y: (f32, f32)| {
            (x.0..=x.1).contains(&b.x) && (y.0..=y.1).contains(&b.y)
        };
        let (box_x, box_y) = ((-0.02, 0.02), (-0.015, 0.015));
        let (mut depth, mut labels, mut top) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..(camera.width * camera.height) as usize {
            let (u, v) = ((k as u32 % 200) as f32 + 0.5, (k as u32 / 200) as f32 + 0.5);
            let ray = to_world.rotation
                * Vec3::new((u - camera.cx) / 300.0, (v - camera.cy) / 300.0, 1.0);
            // Optical depth of the ray's crossing of the plane z = h (the ray's z step is 1).
            let at = |h: f32| ((h - eye.z) / ray.z, eye + ray * (h - eye.z) / ray.z);
            let body = |p: Vec3| pose.inverse().transform_point(p);
            let (d, l) = match (at(0.08), at(0.03)) {
                ((d, p), _) if inside(body(p), (-0.04, 0.04), (0.016, 0.06)) => (d, 0),
                (_, (d, p)) if inside(body(p), box_x, box_y) => {
                    top.push(p);
                    (d, 1)
                }
                _ => (at(0.0).0, 0),
            };
            depth.push(d);
            labels.push(l);
        }
        let colour = vec![Vec3::ONE; depth.len()];
        // Beside the box, 6.5 and 16.5 mm past its +y face.
        let lattice = box_lattice_and_rows(&[0.0215, 0.0315]);
        let in_box = |kept: &[Vec3]| kept.iter().all(|b| inside(*b, box_x, box_y));
        let built = |points: &[Vec3], depth: &[f32]| {
            let frame = RgbdFrame {
                camera,
                colour: &colour,
                depth,
                labels: &labels,
            };
            without_phantoms(&lattice, &pose, points, &[frame], 1, (0.005, 0.005))
        };
        let kept = built(&top, &depth);
        assert!(kept.len() == 36 && in_box(&kept), "{kept:?}");
        // No depth over the middle of the top (a dark spot), and no point kept near the box's -x
        // end (a steep view's pixels are sparse): the box is hidden there by itself or by nothing.
        let body = |p: Vec3| pose.inverse().transform_point(p).truncate();
        let in_spot = |p: Vec3| body(p).distance(glam::Vec2::new(0.005, 0.0)) <= 0.008;
        let sparse: Vec<Vec3> = (top.iter().copied())
            .filter(|p| !in_spot(*p) && body(*p).x > -0.01)
            .collect();
        let seen = RgbdFrame {
            camera,
            colour: &colour,
            depth: &depth,
            labels: &labels,
        };
        let holes: Vec<f32> = (depth.iter().zip(&labels).enumerate())
            .map(
                |(k, (d, l))| match *l == 1 && seen.point(k).is_some_and(in_spot) {
                    true => 0.0,
                    false => *d,
                },
            )
            .collect();
        assert!(holes.iter().filter(|d| **d == 0.0).count() > 30);
        let kept = built(&sparse, &holes);
        assert!(kept.len() == 36 && in_box(&kept), "{kept:?}");
        // Where nothing hides the strip (the table seen there: carving's to remove), the row
        // within two particle radii of the box's depth stays and the row beyond goes.
        let table_only: Vec<f32> = (depth.iter().zip(&labels))
            .map(|(d, l)| if *l == 0 { 0.6 } else { *d })
            .collect();
        let kept = built(&top, &table_only);
        let beside = |y: f32| kept.iter().filter(|b| (b.y - y).abs() < 1e-4).count();
        assert_eq!((kept.len(), beside(0.0215), beside(0.0315)), (48, 12, 0));
    }

    /// A 4 x 3 x 3 cm box seen from one side at 45 degrees (depth and labels traced through it),
    /// and a row of 1 cm cells 6.5 mm past its far face, within two particle radii of the depth
    /// points on its top as a T-block's inner corner is of its crossbar and stem. The lower cells
    /// of the row are hidden by the box itself, at a point well away from them: they go. The top
    /// ones the camera sees past (carving's to judge) and the box's own cells stay.
    #[test]
    fn material_only_the_object_itself_hides_beside_it_is_not_built() {
        let pose = Pose::new(Vec3::new(0.5, 0.1, 0.015), Quat::from_rotation_z(0.4));
        let eye = pose.transform_point(Vec3::new(0.0, -0.4, 0.4));
        let camera = Camera::look_at(200, 200, 300.0, eye, pose.translation);
        let (depth, labels, points) = traced_box(&camera, &pose, Vec3::new(0.02, 0.015, 0.015));
        let colour = vec![Vec3::ONE; depth.len()];
        let lattice = box_lattice_and_rows(&[0.0215]);
        let frame = RgbdFrame {
            camera,
            colour: &colour,
            depth: &depth,
            labels: &labels,
        };
        let kept = without_phantoms(&lattice, &pose, &points, &[frame], 1, (0.005, 0.005));
        let beside: Vec<Vec3> = kept.iter().copied().filter(|b| b.y > 0.02).collect();
        assert_eq!(kept.len() - beside.len(), 36, "{kept:?}");
        assert!(
            beside.len() == 4 && beside.iter().all(|b| b.z > 0.005),
            "{beside:?}"
        );
    }

    /// Depth (optical, the table z = 0 behind), labels (1 on the box) and the box's seen surface
    /// points of a box of half extents `half` at `pose`, traced per pixel of `camera`.
    fn traced_box(camera: &Camera, pose: &Pose, half: Vec3) -> (Vec<f32>, Vec<u8>, Vec<Vec3>) {
        let to_world = camera.world_to_camera.inverse();
        let eye = to_world.translation;
        let (mut depth, mut labels, mut points) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..(camera.width * camera.height) as usize {
            let (u, v) = (
                (k as u32 % camera.width) as f32 + 0.5,
                (k as u32 / camera.width) as f32 + 0.5,
            );
            // The ray's optical z step is 1, so its parameter is the depth.
            let ray = to_world.rotation
                * Vec3::new(
                    (u - camera.cx) / camera.fx,
                    (v - camera.cy) / camera.fy,
                    1.0,
                );
            let (o, d) = (
                pose.inverse().transform_point(eye),
                pose.rotation.inverse() * ray,
            );
            let (t0, t1) = ((-half - o) / d, (half - o) / d);
            let (near, far) = (t0.min(t1).max_element(), t0.max(t1).min_element());
            let (measured, label) = match near <= far && near > 0.0 {
                true => {
                    points.push(eye + ray * near);
                    (near, 1)
                }
                false => (-eye.z / ray.z, 0),
            };
            depth.push(measured);
            labels.push(label);
        }
        (depth, labels, points)
    }

    /// Three 200 x 200 cameras (fx 300 px) looking down at 45 degrees on `target` from around
    /// it, `reach` (m) out and up.
    fn three_around(target: Vec3, reach: f32) -> Vec<Camera> {
        (0..3)
            .map(|k| {
                let (s, c) = (k as f32 * 2.1).sin_cos();
                let eye = target + Vec3::new(reach * c, reach * s, reach);
                Camera::look_at(200, 200, 300.0, eye, target)
            })
            .collect()
    }

    /// `with_frames` given the frames `cameras` see of a box of half extents `half` at `pose`
    /// (`traced_box`; white).
    fn seeing_box<R>(
        cameras: &[Camera],
        pose: &Pose,
        half: Vec3,
        with_frames: impl FnOnce(&[RgbdFrame]) -> R,
    ) -> R {
        let traced: Vec<_> = cameras.iter().map(|c| traced_box(c, pose, half)).collect();
        let colour = vec![Vec3::ONE; (cameras[0].width * cameras[0].height) as usize];
        let frames: Vec<RgbdFrame> = (cameras.iter().zip(&traced))
            .map(|(camera, (depth, labels, _))| RgbdFrame {
                camera: *camera,
                colour: &colour,
                depth,
                labels,
            })
            .collect();
        with_frames(&frames)
    }

    /// `object_from_rgbd` (particles of radius 5 mm) of a box of half extents `half` at `pose`
    /// seen by `cameras`; its particles' centres in the world.
    fn built_box(cameras: &[Camera], pose: &Pose, half: Vec3) -> Vec<Vec3> {
        let render = RenderSettings::default();
        let (model, _) = seeing_box(cameras, pose, half, |frames| {
            object_from_rgbd("box", 1, frames, (Vec3::Z, 0.0), 0.005, 0.0, &render).unwrap()
        });
        (model.particles.iter())
            .map(|(b, _)| model.pose.transform_point(*b))
            .collect()
    }

    /// A 4 x 3 x 3 cm box held with its bottom 6.5 cm over the table, seen by three cameras at 45
    /// degrees around it: built there, about its own size (36 cells of 1 cm), not down to the
    /// table through the shadow no camera sees under it. A box 10 cm tall resting on the table,
    /// seen only from straight above (its top, nothing of its sides), stands on the table.
    #[test]
    fn an_object_in_the_air_is_built_where_it_is_seen_and_one_seen_only_from_above_stands() {
        let pose = Pose::new(Vec3::new(0.5, 0.1, 0.08), Quat::from_rotation_z(0.4));
        let half = Vec3::new(0.02, 0.015, 0.015);
        let cameras = three_around(pose.translation, 0.35);
        let particles = built_box(&cameras, &pose, half);
        let lowest = (particles.iter().map(|p| p.z - 0.005)).fold(f32::INFINITY, f32::min);
        assert!((lowest - 0.065).abs() < 0.008, "lowest {lowest} m");
        assert!((30..=48).contains(&particles.len()), "{}", particles.len());
        let tall = Pose::new(Vec3::new(0.5, 0.1, 0.05), Quat::from_rotation_z(0.4));
        let above = Camera::look_at(200, 200, 300.0, Vec3::new(0.5, 0.1, 0.6), tall.translation);
        let particles = built_box(&[above], &tall, Vec3::new(0.02, 0.015, 0.05));
        let lowest = (particles.iter().map(|p| p.z - 0.005)).fold(f32::INFINITY, f32::min);
        assert!(lowest.abs() < 0.005, "lowest {lowest} m");
    }

    /// A box held 6.5 cm over the table, seen by three cameras looking down at 45 degrees from
    /// 0.6 m (fx 300 px: a pixel is 2 mm across there, 2.8 mm along its upright faces). Its lowest
    /// interior depth point (`masked_points` keeps pixels whose four neighbours are the object's
    /// too) lies over a pixel above its bottom; the lowest of its mask's edge, on the edge
    /// pixel's ray at the interior's depth, within one pixel of it and never below.
    #[test]
    fn the_bottom_of_an_object_in_the_air_is_where_its_mask_ends_not_a_pixel_inside() {
        let bottom = 0.065;
        let pose = Pose::new(
            Vec3::new(0.5, 0.1, bottom + 0.015),
            Quat::from_rotation_z(0.4),
        );
        let cameras = three_around(pose.translation, 0.42);
        let ground = (Vec3::Z, 0.0);
        let half = Vec3::new(0.02, 0.015, 0.015);
        let (bulk, edge) = seeing_box(&cameras, &pose, half, |frames| {
            let (_, bulk) = within_bulk(masked_points(frames, 1), ground, 0.005);
            (bulk, lowest_edge(frames, 1, ground, bulk.0, 0.01))
        });
        let pixel_along_face = 0.6 / 300.0 * 2f32.sqrt();
        assert!(bulk.0 - bottom > pixel_along_face, "interior {}", bulk.0);
        assert!(
            (0.0..pixel_along_face).contains(&(edge - bottom)),
            "edge {edge}, interior {}",
            bulk.0
        );
    }

    /// A column of particles (radius 5 mm) standing at `x`, turned by `yaw`.
    fn column(name: &str, x: f32, yaw: f32) -> ObjectModel {
        let pose = Pose::new(Vec3::new(x, 0.0, 0.02), Quat::from_rotation_z(yaw));
        let particles = (-2..=2)
            .flat_map(|i| (-2..=2).map(move |j| Vec3::new(i as f32, j as f32, 0.0) * 0.01))
            .map(|b| (b, 0.005))
            .collect();
        let gaussians = vec![BodyGaussian {
            mean: Vec3::ZERO,
            rotation: Quat::IDENTITY,
            scale: Vec3::splat(0.003),
            opacity: 0.95,
            colour: Vec3::ONE,
        }];
        ObjectModel {
            name: name.into(),
            pose,
            particles,
            gaussians,
        }
    }

    fn deepest_between(a: &ObjectModel, b: &ObjectModel) -> f32 {
        let mut deepest = f32::MIN;
        for (pa, ra) in &a.particles {
            for (pb, rb) in &b.particles {
                let d = a
                    .pose
                    .transform_point(*pa)
                    .distance(b.pose.transform_point(*pb));
                deepest = deepest.max(ra + rb - d);
            }
        }
        deepest
    }

    #[test]
    fn objects_built_into_each_other_are_parted_along_the_table_and_keep_their_looks() {
        // Two 5 x 5 columns, the second turned and built 6.8 mm into the first (5 of the first's
        // particles reach into it); a third well clear of both.
        let mut models = vec![
            column("a", 0.0, 0.0),
            column("b", 0.045, 0.3),
            column("c", 0.3, 0.0),
        ];
        let before = models.clone();
        assert!(deepest_between(&models[0], &models[1]) > 0.0065);
        let parted = part_overlapping(&mut models, Vec3::Z);
        assert!(
            (parted[0] - parted[1]).abs() < 1e-3 && parted[0] > 6.5,
            "{parted:?}"
        );
        assert_eq!(parted[2], 0.0);
        assert!(deepest_between(&models[0], &models[1]) < 2e-4);
        for (m, m0) in models.iter().zip(&before) {
            assert_eq!(m.gaussians[0].mean, m0.gaussians[0].mean);
            for ((p, r), (p0, r0)) in m.particles.iter().zip(&m0.particles) {
                // Moved along the table only, by at most the overlap.
                assert_eq!((p.z, r), (p0.z, r0));
                assert!(p.distance(*p0) < 0.006, "{p} {p0}");
            }
        }
        assert_eq!(models[2].particles, before[2].particles);
        // Only the facing particles moved: the far row of each column stays.
        let moved = |m: &ObjectModel, m0: &ObjectModel| {
            (m.particles.iter().zip(&m0.particles))
                .filter(|(p, p0)| p.0 != p0.0)
                .count()
        };
        assert!(
            moved(&models[0], &before[0]) <= 10,
            "{}",
            moved(&models[0], &before[0])
        );
    }
}

//! Silhouette agreement: whether the camera still sees each tracked object where the model puts
//! it. Among an object's Gaussians whose centre the model renders as their own surface (not hidden
//! behind the robot or another object), the share whose observed pixel looks more like that
//! surface than like the static scene behind it (a relative test, so a camera's colour response
//! that differs from the model's does not read as disagreement; beyond the modelled table, where
//! there is no scene to compare with, it must be that surface's colour: `looks_like`; where the
//! camera saw the floor there at the start, that stands in for the scene: `super::backdrop`).
//! Where the camera sends depth, a Gaussian whose pixel measures a surface further than the
//! model's own rendered there, by more than a tolerance, does not agree whatever the colour: seen
//! along a bar's width, a bar the model holds a few centimetres nearer the camera than it is
//! projects onto the bar's own pixels, and colour alone agreed with it (`depth_shows_behind`).
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

/// A pixel the static scene covers less than this is outside the model (beyond the modelled
/// table): there is nothing to compare it with, so it must be within `ABSOLUTE_MATCH` (RGB
/// distance, colours in [0, 1]) of the object's own colour to look like it.
pub const MIN_COVERAGE: f32 = 0.5;
const ABSOLUTE_MATCH: f32 = 0.2;

/// Whether an `observed` pixel looks like the object's `own` colour: nearer it than the static
/// scene rendered there (`scene`, covering the pixel `coverage`), or, where the model has no scene
/// (`MIN_COVERAGE`), within `ABSOLUTE_MATCH` of it. Compared with the black of an empty render
/// instead, the floor beyond the modelled table looked like an orange bar: MuJoCo's slippery_1602,
/// the bar tracked 96 mm from where it slid, agreed 0.97.
pub fn looks_like(observed: Vec3, own: Vec3, scene: Vec3, coverage: f32) -> bool {
    match coverage < MIN_COVERAGE {
        true => observed.distance(own) < ABSOLUTE_MATCH,
        false => observed.distance(own) < observed.distance(scene),
    }
}

/// A window's pixels, row-major: the whole model rendered, the static scene alone and how much of
/// each pixel it covers, the image, and depth where the camera sends one.
pub struct WindowPixels<'a> {
    pub rendered: &'a [Vec3],
    pub background: &'a [Vec3],
    pub coverage: &'a [f32],
    pub observed: &'a [Vec3],
    pub depth: Option<DepthPixels<'a>>,
}

/// A window's depth, row-major: the depth the camera measures aligned to its image (m, 0
/// unknown), the model's render (its alpha-weighted depth and its alpha: `surface_at`), and the
/// tolerance (m) between the two (`CorrectConfig::pose_search_depth`).
pub struct DepthPixels<'a> {
    pub measured: &'a [f32],
    pub rendered_depth: &'a [f32],
    pub alpha: &'a [f32],
    pub tolerance: f32,
}

/// Whether the camera measures a surface further than the model's own (both m, 0 unknown) by
/// more than `tolerance`: it sees past where the model has the object. A surface nearer than the
/// model's says nothing here (something unmodelled in front, which the colour judges). The
/// model's surface is that of its Gaussians' centres, a particle radius inside the object's:
/// at the right pose the camera measures nearer, never further.
pub fn depth_shows_behind(measured: f32, surface: f32, tolerance: f32) -> bool {
    measured > 0.0 && surface > 0.0 && measured > surface + tolerance
}

/// The model's rendered surface depth at a pixel (m, 0 where it covers it less than half): the
/// render's alpha-weighted `depth` over its `alpha`.
pub fn surface_at(depth: f32, alpha: f32) -> f32 {
    if alpha >= 0.5 { depth / alpha } else { 0.0 }
}

impl DepthPixels<'_> {
    /// Whether pixel `k` measures a surface behind the model's there (`depth_shows_behind`).
    fn shows_behind(&self, k: usize) -> bool {
        let (Some(m), Some(d), Some(a)) = (
            self.measured.get(k),
            self.rendered_depth.get(k),
            self.alpha.get(k),
        ) else {
            return false;
        };
        depth_shows_behind(*m, surface_at(*d, *a), self.tolerance)
    }
}

/// Per shape, the agreement with its depth where the camera sends one (what tells a lost track)
/// and by colour alone (what sets the pose pull's share, `super::pull::pull_share`: with depth, a
/// shape built from RGB-D a few millimetres past the object's edge agreed 0.99 instead of 0.999
/// at rest and was pulled on by the search's noise, MuJoCo's hand_4103 1.6 -> 6.1 mm off at
/// rest). Without depth the two are the same.
pub struct Agreement {
    pub with_depth: Vec<Option<f32>>,
    pub colour: Vec<Option<f32>>,
}

/// Per shape: the agreement in `camera`, with depth and by colour alone, in one pass (None where
/// the object shows fewer than `MIN_VISIBLE` Gaussians in `window`).
pub fn silhouette_agreement(
    world: &World,
    cloud: &GaussianCloud,
    free: &[usize],
    (camera, window): (&Camera, Roi),
    pixels: &WindowPixels,
) -> Agreement {
    let WindowPixels {
        rendered,
        background,
        coverage,
        observed,
        depth: measured_depth,
    } = pixels;
    // Per shape: visible, matched by colour, matched by colour and depth.
    let mut seen = vec![(0usize, 0usize, 0usize); world.shapes.len()];
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
        let (Some(model), Some(image), Some(behind), Some(covered)) = (
            rendered.get(k),
            observed.get(k),
            background.get(k),
            coverage.get(k),
        ) else {
            continue;
        };
        if !same_surface(*model, cloud.colour[i], SURFACE_THRESHOLD) {
            continue; // hidden behind something else the model knows
        }
        let shape = world.particles.shape[world.gaussians.parent[i] as usize] as usize;
        seen[shape].0 += 1;
        if looks_like(*image, *model, *behind, *covered) {
            seen[shape].1 += 1;
            let beyond = measured_depth.as_ref().is_some_and(|d| d.shows_behind(k));
            seen[shape].2 += !beyond as usize;
        }
    }
    let share = |visible: usize, matched: usize| {
        (visible >= MIN_VISIBLE).then(|| matched as f32 / visible as f32)
    };
    Agreement {
        with_depth: seen.iter().map(|&(v, _, m)| share(v, m)).collect(),
        colour: seen.iter().map(|&(v, m, _)| share(v, m)).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Pose;
    use crate::render::RenderSettings;
    use crate::render::cpu::CpuRenderer;
    use crate::world::{NO_PARENT, WorldBuilder, box_lattice};

    const ORANGE: Vec3 = Vec3::new(0.9, 0.4, 0.1);
    const FLOOR: Vec3 = Vec3::new(0.55, 0.55, 0.52);

    /// An orange slab 2 cm above the floor, seen from 0.3 m above: its world, the camera, its
    /// Gaussians, those bonded to it and the render of them over the whole frame.
    struct Slab {
        world: World,
        camera: Camera,
        cloud: GaussianCloud,
        free: Vec<usize>,
        out: crate::render::RenderOutput,
    }

    fn slab_from_above() -> Slab {
        let mut b = WorldBuilder::new();
        let points = box_lattice(Vec3::new(0.03, 0.02, 0.0), 0.005);
        let at = Pose::from_translation(Vec3::new(0.0, 0.0, 0.02));
        b.add_rigid("slab", &points, 0.0025, 0.001, at, ORANGE);
        let world = b.build();
        let camera = Camera::look_at(64, 48, 80.0, Vec3::new(0.0, 0.0, 0.3), Vec3::ZERO);
        let cloud = GaussianCloud::from_world(&world);
        let free: Vec<usize> = (0..cloud.len())
            .filter(|&i| world.gaussians.parent[i] != NO_PARENT)
            .collect();
        let out = CpuRenderer::new(RenderSettings::default()).forward(
            &cloud,
            &camera,
            Roi::full(&camera),
        );
        Slab {
            world,
            camera,
            cloud,
            free,
            out,
        }
    }

    impl Slab {
        /// The slab's agreement in the whole frame, seen as `pixels`.
        fn agreement(&self, pixels: &WindowPixels) -> f32 {
            let seen = (&self.camera, Roi::full(&self.camera));
            silhouette_agreement(&self.world, &self.cloud, &self.free, seen, pixels).with_depth[0]
                .expect("the slab is in view")
        }
    }

    /// An orange slab where the model has it, seen from above; the image shows the grey floor
    /// (the object has gone) or the slab itself; the static scene rendered there is the floor
    /// (covering every pixel) or nothing (beyond the modelled table: black, uncovered).
    #[test]
    fn beyond_the_modelled_table_only_the_objects_own_colour_agrees_with_it() {
        let slab = slab_from_above();
        let rendered = &slab.out.colour;
        let n = rendered.len();
        let agreement = |observed: &[Vec3], scene: Vec3, coverage: f32| {
            let pixels = WindowPixels {
                rendered,
                background: &vec![scene; n],
                coverage: &vec![coverage; n],
                observed,
                depth: None,
            };
            slab.agreement(&pixels)
        };
        let gone = vec![FLOOR; n];
        assert!(agreement(&gone, FLOOR, 1.0) < 0.05, "the floor, modelled");
        // Grey is nearer orange than black is: compared with an empty render, the floor agreed.
        assert!(FLOOR.distance(ORANGE) < FLOOR.distance(Vec3::ZERO));
        assert!(
            agreement(&gone, Vec3::ZERO, 0.0) < 0.05,
            "the floor, beyond the model"
        );
        assert!(
            agreement(rendered, Vec3::ZERO, 0.0) > 0.95,
            "the slab, beyond the model"
        );
        assert!(
            agreement(rendered, FLOOR, 1.0) > 0.95,
            "the slab, on the floor"
        );
    }

    /// The same slab 0.28 m below the camera, seen in its own colour everywhere (as a bar the model
    /// holds nearer the camera than it is still covers its own pixels, seen along its width). The
    /// depth there decides: the slab's own surface (0.28 m) or a hand above it (0.2 m) agree, the
    /// table 2 cm below the slab (0.3 m) does not, and no depth leaves it to the colour.
    #[test]
    fn an_object_whose_pixels_measure_a_surface_behind_it_does_not_agree_whatever_their_colour() {
        let slab = slab_from_above();
        let out = &slab.out;
        let rendered = &out.colour;
        let n = rendered.len();
        let agreement = |depth: Option<f32>| {
            let measured = depth.map(|d| vec![d; n]);
            let pixels = WindowPixels {
                rendered,
                background: &vec![FLOOR; n],
                coverage: &vec![1.0; n],
                observed: rendered,
                depth: measured.as_deref().map(|measured| DepthPixels {
                    measured,
                    rendered_depth: &out.depth,
                    alpha: &out.alpha,
                    tolerance: 0.01,
                }),
            };
            slab.agreement(&pixels)
        };
        assert!(agreement(None) > 0.95, "colour alone");
        assert!(agreement(Some(0.28)) > 0.95, "its own surface");
        assert!(agreement(Some(0.2)) > 0.95, "something nearer");
        assert!(agreement(Some(0.0)) > 0.95, "depth unknown");
        assert!(agreement(Some(0.3)) < 0.05, "the table behind it");
    }
}

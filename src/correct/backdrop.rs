//! The backdrop: what each camera saw at the first correction where the model has no static scene
//! (beyond the modelled table) and no object or robot either. There the agreement and the pose
//! search have nothing rendered to tell an object's pixels from the scene's, and an object's own
//! colour alone (`agreement::looks_like`'s absolute test) fails as soon as the light on it differs
//! from where its colours were fitted: MuJoCo's slippery_2901, a bar that slid 15 cm past the
//! modelled table's edge into dimmer light, was found 7 mm from where it lay but scored 0.53 there
//! (0.6 is needed), so it stayed lost 148 mm off to the end. The first image of a fixed camera
//! shows that floor; compared with it, the bar's pixels look like the bar.
//!
//! Taken once, at the first correction with views, for the cameras it had: a camera whose pose
//! changes (hung from a frame tf moves) never matches its first pose again and has none, and a
//! camera that starts late has none either (the absolute test stays theirs).
//!
//! Owns taking the backdrop and merging it into the static scene's render for the agreement and
//! the search; never used for the photometric loss or the occluder test (a floor pixel the model
//! cannot render would pull the objects' Gaussians towards it).

use super::agreement::MIN_COVERAGE;
use crate::render::{Camera, GaussianCloud, Renderer, Roi, dilate};
use crate::world::{NO_PARENT, World};
use anyhow::Result;
use glam::Vec3;

/// A pixel the objects and the robot cover more than this, or lies within `MODEL_MARGIN_PX` of
/// one, shows them rather than the backdrop (their Gaussians can fall short of their outline).
const MODEL_ABOVE: f32 = 0.02;
const MODEL_MARGIN_PX: i32 = 3;

/// One camera's backdrop: the observed colour where known (`None` where the model has a scene or
/// a body there, or the image had no finite colour).
#[derive(Clone, Debug)]
pub struct Backdrop {
    pub camera: Camera,
    pub colour: Vec<Option<Vec3>>,
}

impl Backdrop {
    /// The backdrop of `camera` from its `image` (row-major, full frame), where the static scene
    /// covers each pixel `scene_coverage` and the objects and the robot of `world` are rendered.
    pub fn take(
        renderer: &mut (dyn Renderer + Send),
        world: &World,
        camera: &Camera,
        image: &[Vec3],
        scene_coverage: &[f32],
    ) -> Result<Self> {
        let bodies =
            GaussianCloud::from_world_where(world, |i| world.gaussians.parent[i] != NO_PARENT);
        let pixels = (camera.width * camera.height) as usize;
        let body_alpha = match bodies.is_empty() {
            true => vec![0.0; pixels],
            false => renderer.forward(&bodies, camera, Roi::full(camera))?.alpha,
        };
        let near_body = near_a_body(&body_alpha, camera);
        let colour = (0..pixels)
            .map(|k| {
                let free =
                    scene_coverage.get(k).is_some_and(|c| *c < MIN_COVERAGE) && !near_body[k];
                image.get(k).copied().filter(|c| free && c.is_finite())
            })
            .collect();
        Ok(Self {
            camera: *camera,
            colour,
        })
    }

    /// The static scene's render (`colour`, `coverage`) with the backdrop where it is known: its
    /// colour, covering the pixel in full.
    pub fn merged(&self, colour: &[Vec3], coverage: &[f32]) -> (Vec<Vec3>, Vec<f32>) {
        (colour.iter().zip(coverage).zip(&self.colour))
            .map(|((c, a), b)| match b {
                Some(b) => (*b, 1.0),
                None => (*c, *a),
            })
            .unzip()
    }
}

/// Per pixel of `camera`, whether a pixel within `MODEL_MARGIN_PX` (a square) has `alpha` above
/// `MODEL_ABOVE`.
fn near_a_body(alpha: &[f32], camera: &Camera) -> Vec<bool> {
    let covered: Vec<bool> = alpha.iter().map(|a| *a > MODEL_ABOVE).collect();
    dilate(&covered, camera.width, camera.height, MODEL_MARGIN_PX)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::correct::relocate::Search;
    use crate::correct::{CorrectConfig, Corrector, View};
    use crate::math::Pose;
    use crate::render::RenderSettings;
    use crate::render::cpu::CpuRenderer;
    use crate::world::{ShapeId, WorldBuilder, box_lattice};

    const ORANGE: Vec3 = Vec3::new(0.9, 0.4, 0.1);
    const FLOOR: Vec3 = Vec3::new(0.55, 0.55, 0.52);

    /// An orange slab 6 x 3 cm, 2 cm above the ground at `x`, and nothing of the scene modelled.
    fn slab_at(x: f32) -> (World, ShapeId) {
        let mut b = WorldBuilder::new();
        let points = box_lattice(Vec3::new(0.03, 0.015, 0.0), 0.005);
        let at = Pose::from_translation(Vec3::new(x, 0.0, 0.02));
        let s = b.add_rigid("slab", &points, 0.0025, 0.001, at, ORANGE);
        (b.build(), s)
    }

    /// `world` rendered over the grey floor by `camera`, its colours scaled by `light`.
    fn seen(world: &World, camera: &Camera, light: f32) -> Vec<Vec3> {
        let out = CpuRenderer::new(RenderSettings::default()).forward(
            &GaussianCloud::from_world(world),
            camera,
            Roi::full(camera),
        );
        (out.colour.iter().zip(&out.alpha))
            .map(|(c, a)| *c * light + FLOOR * (1.0 - a))
            .collect()
    }

    #[test]
    fn beyond_the_modelled_table_an_object_in_dimmer_light_is_told_from_the_floor_seen_first() {
        // The model has no scene at all. At the first correction the camera sees the slab on the
        // grey floor; later the slab lies 10 cm along, clear of where it was, in light 0.6 as
        // bright: 0.4 of its colour from what the model has of it, beyond the absolute test's
        // 0.2. Searched for from where it was, it is found where it lies only by comparing with
        // the floor the camera saw there.
        let centre = Vec3::new(0.03, 0.0, 0.0);
        let camera = Camera::look_at(96, 72, 110.0, centre + Vec3::Z * 0.35, centre);
        let (mut world, s) = slab_at(-0.02);
        let first = seen(&world, &camera, 1.0);
        let (moved, _) = slab_at(0.08);
        let later = seen(&moved, &camera, 0.6);
        let view = |image| View {
            camera,
            image,
            depth: None,
        };
        let here = world.shapes.pose[s as usize];
        let search = Search::default();
        let found = |c: &mut Corrector, world: &World| {
            c.relocate(world, s, here, &[view(&later)], &search)
                .unwrap()
        };
        let corrector = || Corrector::new(CorrectConfig::default(), RenderSettings::default());
        let mut without = corrector().unwrap();
        let blind = found(&mut without, &world).map_or(0.0, |f| f.score);
        let mut with = corrector().unwrap();
        with.correct(&mut world, &[view(&first)], 1.0 / 30.0)
            .unwrap();
        let f = found(&mut with, &world).expect("a pose found");
        let off = f.pose.translation.distance(Vec3::new(0.08, 0.0, 0.02));
        assert!(blind < 0.6, "by its own colour alone it scores {blind}");
        assert!(
            f.score > 0.9,
            "against the floor seen first it scores {}",
            f.score
        );
        assert!(off < 0.004, "found {off} m from where it lies");
    }

    #[test]
    fn a_camera_that_moves_after_the_first_correction_has_no_backdrop() {
        // A camera hung from a frame tf moves: 2 cm along by the time the slab has slid. What it
        // saw first lies on other pixels now, so it keeps the absolute test, and the dimmed slab
        // scores as without a backdrop; the camera that stayed put scores it as at the start.
        let centre = Vec3::new(0.03, 0.0, 0.0);
        let eye = centre + Vec3::Z * 0.35;
        let fixed = Camera::look_at(96, 72, 110.0, eye, centre);
        let shifted = Vec3::new(0.0, 0.02, 0.0);
        let moved_camera = Camera::look_at(96, 72, 110.0, eye + shifted, centre + shifted);
        let (mut world, s) = slab_at(-0.02);
        let (slid, _) = slab_at(0.08);
        let here = world.shapes.pose[s as usize];
        let mut c = Corrector::new(CorrectConfig::default(), RenderSettings::default()).unwrap();
        let first = seen(&world, &fixed, 1.0);
        let start = [View {
            camera: fixed,
            image: &first,
            depth: None,
        }];
        c.correct(&mut world, &start, 1.0 / 30.0).unwrap();
        let mut score = |camera: Camera| {
            let image = seen(&slid, &camera, 0.6);
            let views = [View {
                camera,
                image: &image,
                depth: None,
            }];
            (c.relocate(&world, s, here, &views, &Search::default())
                .unwrap())
            .map_or(0.0, |f| f.score)
        };
        let (stayed, moved) = (score(fixed), score(moved_camera));
        assert!(stayed > 0.9, "the fixed camera: {stayed}");
        assert!(moved < 0.6, "the moved camera: {moved}");
    }

    #[test]
    fn the_backdrop_keeps_no_pixel_of_a_body_or_of_the_modelled_scene() {
        // Where the slab (or within the margin of it) or the static scene covers a pixel, the
        // backdrop does not know it; everywhere else it holds the image's colour.
        let camera = Camera::look_at(64, 48, 80.0, Vec3::new(0.0, 0.0, 0.3), Vec3::ZERO);
        let (world, _) = slab_at(0.0);
        let image = seen(&world, &camera, 1.0);
        let mut renderer = CpuRenderer::new(RenderSettings::default());
        let alpha = renderer
            .forward(
                &GaussianCloud::from_world(&world),
                &camera,
                Roi::full(&camera),
            )
            .alpha;
        // The static scene covers the image's left half.
        let coverage: Vec<f32> = (0..image.len())
            .map(|k| if k % 64 < 32 { 1.0 } else { 0.0 })
            .collect();
        let b = Backdrop::take(&mut renderer, &world, &camera, &image, &coverage).unwrap();
        let near = near_a_body(&alpha, &camera);
        for k in 0..image.len() {
            let expected = (coverage[k] < MIN_COVERAGE && !near[k]).then_some(image[k]);
            assert_eq!(b.colour[k], expected, "pixel {k}");
        }
        assert!(near.iter().any(|n| *n) && b.colour.iter().any(Option::is_some));
        assert!(
            alpha
                .iter()
                .zip(&b.colour)
                .all(|(a, c)| *a <= MODEL_ABOVE || c.is_none())
        );
    }
}

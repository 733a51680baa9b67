//! Renderer checks, each on every backend (CPU reference and wgpu): gradients against finite
//! differences, analytic footprints, compositing order, the cut-offs, region-of-interest rendering
//! against crops of full frames, determinism, and CPU/wgpu parity on a 20k-Gaussian scene.
//!
//! The wgpu backend must be present (CI installs Mesa's lavapipe); set PEGS_SKIP_GPU=1 to run the
//! CPU half only on a machine that has no Vulkan driver at all.

use glam::{Vec3, Vec4};
use pegs::math::Pose;
use pegs::render::{
    Backend, Camera, GaussianCloud, GaussianParams, PixelGrads, RenderOutput, RenderSettings,
    Renderer, Roi, logit, open,
};

fn backends(settings: &RenderSettings) -> Vec<Box<dyn Renderer + Send>> {
    let mut out = vec![open(Backend::Cpu, settings.clone()).unwrap()];
    match open(Backend::Wgpu, settings.clone()) {
        Ok(gpu) => out.push(gpu),
        Err(e) if std::env::var("PEGS_SKIP_GPU").as_deref() == Ok("1") => {
            eprintln!("skipping wgpu: {e:#}")
        }
        Err(e) => panic!(
            "wgpu backend unavailable ({e:#}); install mesa-vulkan-drivers or set PEGS_SKIP_GPU=1"
        ),
    }
    out
}

/// Deterministic pseudo-random numbers in [0, 1).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32) / (1u64 << 24) as f32
    }
    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next()
    }
}

fn random_cloud(n: usize, rng: &mut Rng, opacity: (f32, f32)) -> GaussianCloud {
    let mut c = GaussianCloud::default();
    for _ in 0..n {
        c.push(GaussianParams {
            mean: Vec3::new(
                rng.range(-0.08, 0.08),
                rng.range(-0.08, 0.08),
                rng.range(-0.05, 0.05),
            ),
            rotation: Vec4::new(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(0.2, 1.0),
            ),
            log_scale: Vec3::new(
                rng.range(-4.2, -3.0),
                rng.range(-4.2, -3.0),
                rng.range(-4.2, -3.0),
            ),
            opacity_logit: logit(rng.range(opacity.0, opacity.1)),
            colour: Vec3::new(rng.next(), rng.next(), rng.next()),
        });
    }
    c
}

fn cameras(width: u32, height: u32) -> Vec<Camera> {
    vec![
        Camera::look_at(
            width,
            height,
            1.1 * width as f32,
            Vec3::new(0.35, -0.25, 0.3),
            Vec3::ZERO,
        ),
        Camera::look_at(
            width,
            height,
            1.1 * width as f32,
            Vec3::new(-0.3, 0.35, 0.25),
            Vec3::new(0.01, 0.0, 0.0),
        ),
    ]
}

/// Settings that keep the loss smooth for finite differences: the cut-offs are moved where they
/// change nothing measurable (their own behaviour is tested separately).
fn smooth_settings() -> RenderSettings {
    RenderSettings {
        cutoff_sigma: 6.5,
        min_alpha: 1e-9,
        background: Vec3::new(0.1, 0.2, 0.3),
        ..RenderSettings::default()
    }
}

/// A linear functional of all outputs with random weights: L = sum w_c . colour + w_a alpha + w_d depth.
struct Loss {
    colour: Vec<Vec3>,
    alpha: Vec<f32>,
    depth: Vec<f32>,
}

impl Loss {
    fn random(pixels: usize, rng: &mut Rng) -> Self {
        Self {
            colour: (0..pixels)
                .map(|_| {
                    Vec3::new(
                        rng.range(-1.0, 1.0),
                        rng.range(-1.0, 1.0),
                        rng.range(-1.0, 1.0),
                    )
                })
                .collect(),
            alpha: (0..pixels).map(|_| rng.range(-1.0, 1.0)).collect(),
            depth: (0..pixels).map(|_| rng.range(-1.0, 1.0)).collect(),
        }
    }
    fn value(&self, out: &RenderOutput) -> f64 {
        let mut l = 0.0f64;
        for i in 0..out.colour.len() {
            l += self.colour[i].dot(out.colour[i]) as f64
                + (self.alpha[i] * out.alpha[i]) as f64
                + (self.depth[i] * out.depth[i]) as f64;
        }
        l
    }
    fn grads(&self) -> PixelGrads {
        PixelGrads {
            colour: self.colour.clone(),
            alpha: self.alpha.clone(),
            depth: self.depth.clone(),
        }
    }
}

#[test]
fn every_gradient_matches_finite_differences_on_small_random_scenes() {
    for mut r in backends(&smooth_settings()) {
        let backend = r.name();
        let mut rng = Rng(7);
        let (w, h) = (40, 30);
        for (scene, cam) in cameras(w, h).iter().enumerate() {
            let cloud = random_cloud(10, &mut rng, (0.3, 0.8));
            let loss = Loss::random((w * h) as usize, &mut rng);
            let out = r.forward(&cloud, cam, Roi::full(cam)).unwrap();
            assert!(
                out.alpha.iter().cloned().fold(0.0, f32::max) > 0.3,
                "scene {scene} must be visible"
            );
            let grads = r.backward(&cloud, &loss.grads()).unwrap();
            let mut eval =
                |c: &GaussianCloud| loss.value(&r.forward(c, cam, Roi::full(cam)).unwrap());
            // (group, analytic, numeric) for every scalar parameter of every Gaussian.
            let mut rows: Vec<(&str, f32, f32)> = Vec::new();
            for i in 0..cloud.len() {
                let mut fd = |group: &'static str,
                              analytic: f32,
                              h: f32,
                              set: &dyn Fn(&mut GaussianCloud, f32)| {
                    let eval = &mut eval;
                    let mut c = cloud.clone();
                    set(&mut c, h);
                    let up = eval(&c);
                    let mut c = cloud.clone();
                    set(&mut c, -h);
                    let down = eval(&c);
                    rows.push((group, analytic, ((up - down) / (2.0 * h as f64)) as f32));
                };
                for k in 0..3 {
                    fd("mean", grads.mean[i][k], 2e-4, &|c, d| c.mean[i][k] += d);
                    fd("log_scale", grads.log_scale[i][k], 2e-3, &|c, d| {
                        c.log_scale[i][k] += d
                    });
                    fd("colour", grads.colour[i][k], 1e-2, &|c, d| {
                        c.colour[i][k] += d
                    });
                }
                for k in 0..4 {
                    fd("rotation", grads.rotation[i][k], 2e-3, &|c, d| {
                        c.rotation[i][k] += d
                    });
                }
                fd("opacity", grads.opacity_logit[i], 2e-3, &|c, d| {
                    c.opacity_logit[i] += d
                });
            }
            for group in ["mean", "rotation", "log_scale", "opacity", "colour"] {
                let of: Vec<_> = rows.iter().filter(|r| r.0 == group).collect();
                let scale = of.iter().map(|r| r.2.abs()).fold(0.0f32, f32::max);
                assert!(scale > 0.0, "{group}: all gradients zero");
                let mut checked = 0;
                for (_, analytic, numeric) in &of {
                    if numeric.abs() > 0.02 * scale {
                        let rel = (analytic - numeric).abs() / numeric.abs();
                        assert!(
                            rel < 0.01,
                            "{backend} scene {scene} {group}: analytic {analytic} vs numeric {numeric} ({:.2} %)",
                            rel * 100.0
                        );
                        checked += 1;
                    } else {
                        assert!(
                            (analytic - numeric).abs() < 0.005 * scale,
                            "{backend} scene {scene} {group}: small gradient {analytic} vs {numeric}"
                        );
                    }
                }
                assert!(
                    checked >= 3,
                    "{backend} {group}: too few gradients large enough to check"
                );
            }
        }
    }
}

#[test]
fn single_isotropic_gaussian_renders_the_expected_footprint_and_peak_alpha() {
    // Mean on a pixel centre: pixel (50, 40) is sampled at (50.5, 40.5).
    let cam = Camera {
        width: 101,
        height: 81,
        fx: 200.0,
        fy: 200.0,
        cx: 50.5,
        cy: 40.5,
        world_to_camera: Pose::IDENTITY,
    };
    let s = RenderSettings::default();
    let (sigma, depth, opacity) = (0.05f32, 2.0f32, 0.8f32);
    let mut cloud = GaussianCloud::default();
    cloud.push(GaussianParams {
        mean: Vec3::new(0.0, 0.0, depth),
        rotation: Vec4::new(0.0, 0.0, 0.0, 1.0),
        log_scale: Vec3::splat(sigma.ln()),
        opacity_logit: logit(opacity),
        colour: Vec3::new(1.0, 0.5, 0.25),
    });
    for mut r in backends(&s) {
        let backend = r.name();
        let out = r.forward(&cloud, &cam, Roi::full(&cam)).unwrap();
        let var = (200.0 * sigma / depth).powi(2) + s.blur;
        let peak = out.alpha[40 * 101 + 50];
        assert!(
            (peak - opacity).abs() < 1e-5,
            "{backend}: peak alpha {peak}"
        );
        let mut lit = 0;
        for y in 0..81 {
            for x in 0..101 {
                let r2 = ((x as f32 - 50.0).powi(2) + (y as f32 - 40.0).powi(2)) / var;
                let a = opacity * (-0.5 * r2).exp();
                let want = if r2 <= 9.0 && a >= s.min_alpha {
                    a
                } else {
                    0.0
                };
                let got = out.alpha[y * 101 + x];
                assert!(
                    (got - want).abs() < 1e-5,
                    "{backend}: pixel ({x}, {y}): {got} vs {want}"
                );
                lit += (want > 0.0) as usize;
                // Colour is alpha times the Gaussian's colour on a black background; depth alpha-weighted.
                assert!(
                    (out.colour[y * 101 + x] - want * Vec3::new(1.0, 0.5, 0.25)).length() < 1e-5
                );
                assert!((out.depth[y * 101 + x] - want * depth).abs() < 1e-4);
            }
        }
        // The footprint is the 3-sigma disc: pi * 9 * var pixels.
        let disc = std::f32::consts::PI * 9.0 * var;
        assert!(
            (lit as f32 - disc).abs() < 0.05 * disc,
            "lit {lit} pixels, disc {disc}"
        );
    }
}

fn facing(depth: f32, colour: Vec3, opacity: f32) -> GaussianParams {
    GaussianParams {
        mean: Vec3::new(0.0, 0.0, depth),
        rotation: Vec4::new(0.0, 0.0, 0.0, 1.0),
        log_scale: Vec3::splat((0.05 * depth).ln()),
        opacity_logit: logit(opacity),
        colour,
    }
}

/// The centre pixel's colour and alpha from every backend (they must agree).
fn centre_pixel(cloud: &GaussianCloud, s: &RenderSettings) -> (Vec3, f32) {
    let cam = Camera {
        width: 21,
        height: 21,
        fx: 100.0,
        fy: 100.0,
        cx: 10.5,
        cy: 10.5,
        world_to_camera: Pose::IDENTITY,
    };
    let mut first: Option<(Vec3, f32)> = None;
    for mut r in backends(s) {
        let out = r.forward(cloud, &cam, Roi::full(&cam)).unwrap();
        let px = (out.colour[10 * 21 + 10], out.alpha[10 * 21 + 10]);
        if let Some(f) = first {
            assert!(
                (f.0 - px.0).abs().max_element() < 1e-6 && (f.1 - px.1).abs() < 1e-6,
                "{} disagrees: {px:?} vs {f:?}",
                r.name()
            );
        }
        first = Some(px);
    }
    first.unwrap()
}

#[test]
fn nearer_gaussians_occlude_farther_ones_whatever_their_order_in_the_list() {
    let s = RenderSettings {
        background: Vec3::new(0.0, 1.0, 0.0),
        ..RenderSettings::default()
    };
    let (red, blue) = (Vec3::X, Vec3::Z);
    let (ar, ab) = (0.7f32, 0.6f32);
    let composite = |front: (Vec3, f32), back: (Vec3, f32)| {
        front.0 * front.1
            + back.0 * back.1 * (1.0 - front.1)
            + s.background * (1.0 - front.1) * (1.0 - back.1)
    };
    for (red_depth, blue_depth) in [(1.0, 2.0), (2.0, 1.0)] {
        let want = if red_depth < blue_depth {
            composite((red, ar), (blue, ab))
        } else {
            composite((blue, ab), (red, ar))
        };
        for reversed in [false, true] {
            let mut cloud = GaussianCloud::default();
            let (a, b) = (facing(red_depth, red, ar), facing(blue_depth, blue, ab));
            if reversed {
                cloud.push(b);
                cloud.push(a);
            } else {
                cloud.push(a);
                cloud.push(b);
            }
            let (c, alpha) = centre_pixel(&cloud, &s);
            assert!(
                (c - want).length() < 1e-5,
                "red at {red_depth}, blue at {blue_depth}, reversed {reversed}: {c} vs {want}"
            );
            assert!((alpha - (1.0 - (1.0 - ar) * (1.0 - ab))).abs() < 1e-5);
        }
    }
}

#[test]
fn alpha_and_transmittance_cut_offs_behave_as_specified() {
    let s = RenderSettings {
        background: Vec3::new(0.2, 0.2, 0.2),
        ..RenderSettings::default()
    };
    // Below 1/255 a Gaussian is skipped entirely; just above it counts.
    let (c, a) = centre_pixel(
        &GaussianCloud {
            ..one(facing(1.0, Vec3::ONE, 0.9 / 255.0))
        },
        &s,
    );
    assert_eq!(a, 0.0);
    assert_eq!(c, s.background);
    let (_, a) = centre_pixel(&one(facing(1.0, Vec3::ONE, 1.2 / 255.0)), &s);
    assert!((a - 1.2 / 255.0).abs() < 1e-6);
    // Alpha is clamped at 0.999; the second opaque Gaussian would take T to 1e-6 < 1e-4, so
    // compositing stops before it: only the first colours the pixel, the background shows through T.
    let mut stack = GaussianCloud::default();
    stack.push(facing(1.0, Vec3::X, 0.99999));
    stack.push(facing(1.5, Vec3::Y, 0.99999));
    stack.push(facing(2.0, Vec3::Z, 0.99999));
    let (c, a) = centre_pixel(&stack, &s);
    assert!((a - 0.999).abs() < 1e-6, "alpha {a}");
    assert!(
        (c - (0.999 * Vec3::X + 0.001 * s.background)).length() < 1e-6,
        "colour {c}"
    );
    // Beyond cutoff_sigma the Gaussian is not evaluated even where its alpha would exceed 1/255.
    let cam = Camera {
        width: 41,
        height: 1,
        fx: 100.0,
        fy: 100.0,
        cx: 0.5,
        cy: 0.5,
        world_to_camera: Pose::IDENTITY,
    };
    let mut g = facing(1.0, Vec3::ONE, 1.0 - 1e-6);
    g.log_scale = Vec3::splat((0.05f32).ln()); // 5 px std-dev at 1 m, fx 100
    for mut r in backends(&s) {
        let out = r.forward(&one(g), &cam, Roi::full(&cam)).unwrap();
        let sd = (25.0f32 + s.blur).sqrt();
        for x in 0..41 {
            let d = x as f32 / sd;
            let a = out.alpha[x];
            if d > 3.0 {
                assert_eq!(a, 0.0, "pixel {x} at {d} sigma");
            } else {
                assert!(a > 0.01, "pixel {x} at {d} sigma should be lit: {a}");
            }
        }
    }
}

fn one(g: GaussianParams) -> GaussianCloud {
    let mut c = GaussianCloud::default();
    c.push(g);
    c
}

#[test]
fn region_of_interest_equals_the_crop_of_a_full_render_including_gradients() {
    let s = RenderSettings {
        background: Vec3::new(0.3, 0.1, 0.2),
        ..RenderSettings::default()
    };
    for (mut full_r, mut roi_r) in backends(&s).into_iter().zip(backends(&s)) {
        let mut rng = Rng(99);
        let cloud = random_cloud(400, &mut rng, (0.2, 0.99));
        let cam = cameras(96, 64)[0];
        let full = full_r.forward(&cloud, &cam, Roi::full(&cam)).unwrap();
        let roi = Roi {
            x0: 13,
            y0: 7,
            x1: 61,
            y1: 50,
        };
        let part = roi_r.forward(&cloud, &cam, roi).unwrap();
        assert_eq!(part.colour.len(), roi.pixels());
        let mut covered = 0;
        for y in roi.y0..roi.y1 {
            for x in roi.x0..roi.x1 {
                let f = (y * 96 + x) as usize;
                let p = ((y - roi.y0) * roi.width() + (x - roi.x0)) as usize;
                assert_eq!(full.colour[f], part.colour[p], "colour at ({x}, {y})");
                assert_eq!(full.alpha[f], part.alpha[p]);
                assert_eq!(full.depth[f], part.depth[p]);
                covered += (part.alpha[p] > 0.5) as usize;
            }
        }
        assert!(
            covered > roi.pixels() / 4,
            "the window must show the scene ({covered} opaque pixels)"
        );
        // Gradients of a loss on the window equal those of the same loss on the full frame with zero
        // gradient outside the window.
        let loss = Loss::random(roi.pixels(), &mut rng);
        let g_roi = roi_r.backward(&cloud, &loss.grads()).unwrap();
        let mut full_grads = PixelGrads {
            colour: vec![Vec3::ZERO; 96 * 64],
            alpha: vec![0.0; 96 * 64],
            depth: vec![0.0; 96 * 64],
        };
        for y in roi.y0..roi.y1 {
            for x in roi.x0..roi.x1 {
                let f = (y * 96 + x) as usize;
                let p = ((y - roi.y0) * roi.width() + (x - roi.x0)) as usize;
                full_grads.colour[f] = loss.colour[p];
                full_grads.alpha[f] = loss.alpha[p];
                full_grads.depth[f] = loss.depth[p];
            }
        }
        let g_full = full_r.backward(&cloud, &full_grads).unwrap();
        let scale = g_full
            .mean
            .iter()
            .map(|v| v.abs().max_element())
            .fold(0.0f32, f32::max);
        assert!(scale > 0.0);
        for i in 0..cloud.len() {
            assert!(
                (g_full.mean[i] - g_roi.mean[i]).abs().max_element() <= 1e-6 * scale,
                "{} Gaussian {i}",
                full_r.name()
            );
            assert!(
                (g_full.opacity_logit[i] - g_roi.opacity_logit[i]).abs() <= 1e-6 * scale.max(1.0)
            );
        }
    }
}

#[test]
fn rendering_and_gradients_are_deterministic() {
    let mut rng = Rng(3);
    let cloud = random_cloud(2000, &mut rng, (0.2, 0.99));
    let cam = cameras(128, 96)[1];
    let loss = Loss::random(128 * 96, &mut rng);
    for mut r in backends(&RenderSettings::default()) {
        let mut run = || {
            let out = r.forward(&cloud, &cam, Roi::full(&cam)).unwrap();
            (out, r.backward(&cloud, &loss.grads()).unwrap())
        };
        let (a, ga) = run();
        let (b, gb) = run();
        assert!(a == b && ga == gb, "two identical renders differ");
    }
}

#[test]
fn backward_rejects_mismatched_inputs() {
    let mut rng = Rng(5);
    let cloud = random_cloud(5, &mut rng, (0.3, 0.6));
    let cam = cameras(16, 16)[0];
    for mut r in backends(&RenderSettings::default()) {
        assert!(
            r.backward(&cloud, &PixelGrads::default()).is_err(),
            "backward before forward"
        );
        r.forward(&cloud, &cam, Roi::full(&cam)).unwrap();
        assert!(
            r.backward(
                &cloud,
                &PixelGrads {
                    colour: vec![Vec3::ZERO; 10],
                    ..Default::default()
                }
            )
            .is_err()
        );
        let fewer = random_cloud(4, &mut rng, (0.3, 0.6));
        assert!(
            r.backward(
                &fewer,
                &PixelGrads {
                    colour: vec![Vec3::ZERO; 256],
                    ..Default::default()
                }
            )
            .is_err()
        );
    }
}

#[test]
fn cpu_and_wgpu_agree_on_a_20k_gaussian_three_camera_scene() {
    let s = RenderSettings::default();
    let mut renderers = backends(&s);
    if renderers.len() < 2 {
        return; // PEGS_SKIP_GPU=1: nothing to compare
    }
    let (cloud, cams, _) = pegs::bench::tblock_render_scene(320, 180);
    assert!(cloud.len() >= 10_000 && cams.len() == 3);
    for cam in &cams {
        let outs: Vec<RenderOutput> = renderers
            .iter_mut()
            .map(|r| r.forward(&cloud, cam, Roi::full(cam)).unwrap())
            .collect();
        let diff = image_difference(&outs[0], &outs[1]);
        eprintln!("max |cpu - wgpu| over colour and alpha = {diff:.2e}");
        assert!(diff < 1e-3, "images differ by {diff}");
        // A photometric loss against a shifted copy of the image, as the correction step uses.
        let target: Vec<Vec3> = outs[0]
            .colour
            .iter()
            .map(|c| *c * 0.8 + Vec3::splat(0.05))
            .collect();
        let d = PixelGrads {
            colour: outs[0]
                .colour
                .iter()
                .zip(&target)
                .map(|(c, t)| 2.0 * (*c - *t))
                .collect(),
            ..Default::default()
        };
        let grads: Vec<_> = renderers
            .iter_mut()
            .map(|r| r.backward(&cloud, &d).unwrap())
            .collect();
        let worst = |f: &dyn Fn(&pegs::render::CloudGrads, usize) -> Vec4| {
            let scale = (0..cloud.len())
                .map(|i| f(&grads[0], i).abs().max_element())
                .fold(0.0f32, f32::max);
            let diff = (0..cloud.len())
                .map(|i| (f(&grads[0], i) - f(&grads[1], i)).abs().max_element())
                .fold(0.0f32, f32::max);
            (diff, scale)
        };
        for (name, (diff, scale)) in [
            ("mean", worst(&|g, i| g.mean[i].extend(0.0))),
            ("rotation", worst(&|g, i| g.rotation[i])),
            ("log_scale", worst(&|g, i| g.log_scale[i].extend(0.0))),
            (
                "opacity",
                worst(&|g, i| Vec4::new(g.opacity_logit[i], 0.0, 0.0, 0.0)),
            ),
            ("colour", worst(&|g, i| g.colour[i].extend(0.0))),
        ] {
            eprintln!("{name}: max |cpu - wgpu| {diff:.2e} of max |grad| {scale:.2e}");
            assert!(scale > 0.0, "{name}: no gradient");
            assert!(
                diff < 1e-3 * scale,
                "{name} gradients differ: {diff} vs scale {scale}"
            );
        }
    }
}

/// The largest difference between two renders of one window, colour and alpha.
fn image_difference(a: &RenderOutput, b: &RenderOutput) -> f32 {
    let colour = a
        .colour
        .iter()
        .zip(&b.colour)
        .map(|(x, y)| (*x - *y).abs().max_element());
    let alpha = a.alpha.iter().zip(&b.alpha).map(|(x, y)| (x - y).abs());
    colour.chain(alpha).fold(0.0f32, f32::max)
}

#[test]
fn a_frame_listing_more_tile_pairs_than_the_frames_before_renders_as_the_cpu_reference() {
    // The wgpu backend lists (tile, Gaussian) pairs into the capacity earlier frames needed and
    // renders again into a bigger buffer when a frame needs more: small Gaussians, then as many
    // large ones that each cover most of the image (far more pairs), then both again.
    let s = RenderSettings::default();
    let mut renderers = backends(&s);
    if renderers.len() < 2 {
        return; // PEGS_SKIP_GPU=1: nothing to compare
    }
    let mut rng = Rng(11);
    let mut small = random_cloud(300, &mut rng, (0.3, 0.9));
    for s in &mut small.log_scale {
        *s -= Vec3::splat(1.0);
    }
    let mut large = random_cloud(300, &mut rng, (0.05, 0.2));
    for s in &mut large.log_scale {
        *s += Vec3::splat(1.0);
    }
    let cam = cameras(320, 180)[0];
    for cloud in [&small, &large, &small, &large] {
        let outs: Vec<RenderOutput> = renderers
            .iter_mut()
            .map(|r| r.forward(cloud, &cam, Roi::full(&cam)).unwrap())
            .collect();
        let covered = outs[0].alpha.iter().filter(|a| **a > 0.01).count();
        let diff = image_difference(&outs[0], &outs[1]);
        eprintln!(
            "frame: {} Gaussians, image difference {diff:.2e}",
            cloud.len()
        );
        assert!(diff < 1e-3, "cpu and wgpu images differ by {diff}");
        assert!(covered > 1000, "the scene covers only {covered} pixels");
        let d = PixelGrads {
            colour: outs[0]
                .colour
                .iter()
                .map(|c| *c - Vec3::splat(0.5))
                .collect(),
            ..Default::default()
        };
        let grads: Vec<_> = renderers
            .iter_mut()
            .map(|r| r.backward(cloud, &d).unwrap())
            .collect();
        let scale = grads[0]
            .mean
            .iter()
            .map(|g| g.abs().max_element())
            .fold(0.0, f32::max);
        let diff = grads[0]
            .mean
            .iter()
            .zip(&grads[1].mean)
            .map(|(a, b)| (*a - *b).abs().max_element())
            .fold(0.0f32, f32::max);
        assert!(
            scale > 0.0 && diff < 1e-3 * scale,
            "mean gradients differ: {diff} of {scale}"
        );
    }
}

#[test]
fn an_empty_window_renders_no_pixels_and_no_gradients_on_every_backend() {
    // A tracked object that leaves a camera's view gets an empty window.
    let mut rng = Rng(5);
    let cloud = random_cloud(50, &mut rng, (0.3, 0.9));
    let cam = cameras(64, 48)[0];
    let empty = Roi {
        x0: 20,
        y0: 10,
        x1: 20,
        y1: 30,
    };
    for r in &mut backends(&RenderSettings::default()) {
        let out = r.forward(&cloud, &cam, empty).unwrap();
        assert!(out.colour.is_empty() && out.alpha.is_empty() && out.depth.is_empty());
        let g = r.backward(&cloud, &PixelGrads::default()).unwrap();
        assert_eq!(g.mean.len(), cloud.len());
        assert!(g.mean.iter().all(|m| *m == Vec3::ZERO));
    }
}

//! Initialisation: the tracker's world at the start of a recording or a live session. Objects
//! come from files (`ObjectModel`, e.g. the embodied-gaussians JSON format) or from RGB-D and
//! masks; the table is fitted to the first frames; objects are aligned to their masks before
//! tracking starts. This module builds worlds; it never steps them.

pub mod align;
pub mod mask;
pub mod rgbd;
pub mod table;

pub use mask::ColourMask;

use crate::config::Config;
use crate::math::Pose;
use crate::render::{Camera, GaussianCloud};
use crate::scene::WorldBuilder;
use crate::scene::builtin::Scene;
use crate::world::NO_PARENT;
use anyhow::{Context, Result, bail};
use glam::{Quat, Vec3};
use serde::Serialize;
use std::collections::BTreeMap;

/// Colour distance of the occluder test used while fitting silhouettes (see `correct::explained`).
const OCCLUDER_THRESHOLD: f32 = 0.35;

/// A Gaussian in an object's body frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyGaussian {
    pub mean: Vec3,
    pub rotation: Quat,
    /// Standard deviations, m.
    pub scale: Vec3,
    pub opacity: f32,
    /// RGB in [0, 1].
    pub colour: Vec3,
}

/// An object as particles and Gaussians in its body frame, with its body-to-world pose.
#[derive(Clone, Debug)]
pub struct ObjectModel {
    pub name: String,
    pub pose: Pose,
    /// Body-frame position and radius of each particle.
    pub particles: Vec<(Vec3, f32)>,
    pub gaussians: Vec<BodyGaussian>,
}

/// The first frames of one camera.
pub struct FirstFrames<'a> {
    pub name: String,
    pub camera: Camera,
    /// Linear RGB images, oldest first; the first one is the start of tracking.
    pub images: Vec<&'a [Vec3]>,
    /// Depth (m, 0 unknown) and instance labels aligned with the first image, if recorded.
    pub depth: Option<&'a [f32]>,
    pub labels: Option<&'a [u8]>,
}

#[derive(Clone, Debug, Default, Serialize)]
pub struct ObjectInit {
    pub particles: usize,
    pub gaussians: usize,
    pub mass_kg: f32,
    pub alignment: Option<align::Alignment>,
    pub colour_fit: Option<table::ColourFit>,
    pub silhouette_fit: Option<align::SilhouetteFit>,
}

/// What initialisation did and how long it took.
#[derive(Clone, Debug, Default, Serialize)]
pub struct InitReport {
    /// The ground plane fitted to the depth (unit normal, height along it), if asked for.
    pub ground: Option<(Vec3, f32)>,
    pub objects: BTreeMap<String, ObjectInit>,
    pub rgbd_objects: BTreeMap<String, rgbd::RgbdObjectReport>,
    /// No instance masks were recorded: labels are clusters of depth points, largest first.
    pub labels_from_clusters: bool,
    pub table: Option<table::ColourFit>,
    pub seconds: f64,
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

/// Move `shape` along the ground normal so that its lowest particle just touches the ground
/// `normal . p = height` (up out of it, or down onto it when it floats); returns the move in m.
pub fn settle_on_ground(
    world: &mut crate::world::World,
    shape: crate::world::ShapeId,
    normal: Vec3,
    height: f32,
) -> f32 {
    let n = normal.normalize_or(Vec3::Z);
    let gap = world
        .shapes
        .range(shape)
        .map(|i| n.dot(world.particles.position[i]) - height - world.particles.radius[i])
        .fold(f32::INFINITY, f32::min);
    if !gap.is_finite() {
        return 0.0;
    }
    world.move_shape(shape, Pose::from_translation(-gap * n));
    -gap
}

/// Build the tracker's world from the first frames: the robot from its URDF at the first joint
/// positions; the ground from depth (RANSAC) if asked; `scene.rgbd_objects` from depth and
/// instance masks (or, without masks, clusters of depth points above the ground that are not the
/// robot); `scene.objects` from their files, each aligned to its colour mask; every object settled
/// onto the ground; then the table fitted to the frames with the objects' pixels left out.
pub fn build_scene(
    config: &Config,
    frames: &[FirstFrames],
    initial_joints: &[(String, f64)],
    progress: bool,
) -> Result<(Scene, InitReport)> {
    let clock = std::time::Instant::now();
    if config.scene.objects.is_empty() && config.scene.rgbd_objects.is_empty() {
        bail!(
            "the configuration names no scene.scenario, scene.objects or scene.rgbd_objects: nothing to track"
        );
    }
    let mut report = InitReport::default();
    let mut builder = WorldBuilder::new();
    // The robot first, at its first recorded joint positions (the replay drives it from then on):
    // clustering needs to know which depth points are the robot.
    let robot = match &config.robot.urdf {
        Some(path) => {
            let model = crate::robot::RobotModel::load(
                path,
                &crate::robot::PackagePaths(config.robot.package_paths.clone()),
                config.robot.geometry,
            )?;
            let mut q = vec![0.0; model.joints.len()];
            for (name, v) in initial_joints {
                if let Some(j) = model.joint_index(name)
                    && v.is_finite()
                {
                    q[j] = *v;
                }
            }
            Some((
                crate::robot::RobotInWorld::add(&mut builder, model, &q, &config.robot)?,
                crate::robot::JointTrajectory::default(),
            ))
        }
        None => None,
    };
    let with_depth: Vec<(&FirstFrames, &[Vec3], &[f32])> = frames
        .iter()
        .filter_map(|f| Some((f, *f.images.first()?, f.depth?)))
        .collect();
    let mut ground = (
        config.physics.ground.normal.normalize_or(Vec3::Z),
        config.physics.ground.height,
    );
    let wants_depth = config.scene.ground_from_depth || !config.scene.rgbd_objects.is_empty();
    if wants_depth && with_depth.is_empty() {
        bail!(
            "the configuration builds the ground or objects from depth, but the recording has no depth images"
        );
    }
    if config.scene.ground_from_depth {
        // Background points: not labelled as an object where masks exist.
        let points: Vec<Vec3> = with_depth
            .iter()
            .flat_map(|(f, _, depth)| {
                let probe = rgbd::RgbdFrame {
                    camera: f.camera,
                    colour: &[],
                    depth,
                    labels: &[],
                };
                (0..depth.len())
                    .step_by(3)
                    .filter(|&k| f.labels.is_none_or(|l| l[k] == 0))
                    .filter_map(|k| probe.point(k))
                    .collect::<Vec<_>>()
            })
            .collect();
        let (normal, height, inliers) = rgbd::ground_ransac(&points, 300, 0.003, 1)
            .context("no depth to fit the ground plane to")?;
        if inliers < 100 {
            bail!("the ground plane fitted to the depth has only {inliers} points");
        }
        ground = (normal, height);
        report.ground = Some(ground);
    }
    if !config.scene.rgbd_objects.is_empty() {
        // Instance masks as recorded, or else clusters of the depth points above the ground.
        let labels: Vec<Vec<u8>> = if with_depth.iter().all(|(f, _, _)| f.labels.is_some()) {
            with_depth
                .iter()
                .map(|(f, _, _)| f.labels.map(|l| l.to_vec()).unwrap_or_default())
                .collect()
        } else {
            let w = builder.world();
            let known: Vec<Vec3> = w.particles.position.clone();
            let cameras: Vec<Camera> = with_depth.iter().map(|(f, _, _)| f.camera).collect();
            let depths: Vec<&[f32]> = with_depth.iter().map(|(_, _, d)| *d).collect();
            report.labels_from_clusters = true;
            rgbd::cluster_labels(&cameras, &depths, ground, &known, 0.004, 0.02, 0.01)
        };
        let rgbd: Vec<rgbd::RgbdFrame> = with_depth
            .iter()
            .zip(&labels)
            .map(|((f, colour, depth), l)| rgbd::RgbdFrame {
                camera: f.camera,
                colour,
                depth,
                labels: l,
            })
            .collect();
        for object in config.scene.rgbd_objects.iter().filter(|o| o.rope) {
            let (points, colour) = rgbd::rope_from_rgbd(
                &object.name,
                object.label,
                &rgbd,
                ground,
                object.particle_radius,
            )
            .with_context(|| format!("rope '{}'", object.name))?;
            let rope = builder.add_rope(
                &object.name,
                &points,
                object.particle_radius,
                object.mass / points.len() as f32,
                object.bending_stiffness,
                colour,
            );
            builder.set_gaussian_look(rope, object.particle_radius, 0.97);
            report.objects.insert(
                object.name.clone(),
                ObjectInit {
                    particles: points.len(),
                    gaussians: points.len(),
                    mass_kg: object.mass,
                    alignment: None,
                    colour_fit: None,
                    silhouette_fit: None,
                },
            );
        }
        let rigid: Vec<_> = config
            .scene
            .rgbd_objects
            .iter()
            .filter(|o| !o.rope)
            .collect();
        let bar = if progress {
            indicatif::ProgressBar::new(rigid.len() as u64)
        } else {
            indicatif::ProgressBar::hidden()
        };
        bar.set_style(
            indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        for object in rigid {
            bar.set_message(format!("building {} from RGB-D", object.name));
            bar.inc(1);
            let (model, r) = rgbd::object_from_rgbd(
                &object.name,
                object.label,
                &rgbd,
                ground,
                object.particle_radius,
                0.0,
                &config.render,
            )
            .with_context(|| format!("object '{}'", object.name))?;
            builder.add_rigid_model(
                &object.name,
                &model,
                object.mass / model.particles.len() as f32,
            );
            report.objects.insert(
                object.name.clone(),
                ObjectInit {
                    particles: model.particles.len(),
                    gaussians: model.gaussians.len(),
                    mass_kg: object.mass,
                    alignment: None,
                    colour_fit: Some(r.colour_fit.clone()),
                    silhouette_fit: None,
                },
            );
            report.rgbd_objects.insert(object.name.clone(), r);
        }
        bar.finish_and_clear();
    }
    let mut shapes = Vec::new();
    for object in &config.scene.objects {
        if object.name.is_empty() {
            bail!("every scene.objects entry needs a name");
        }
        let name = object.name.clone();
        let model = crate::import::embodied_gaussians::load_object(&object.embodied_gaussians)
            .with_context(|| format!("object '{name}'"))?;
        if !(object.mass.is_finite() && object.mass > 0.0) {
            bail!(
                "object '{name}': mass must be positive, got {}",
                object.mass
            );
        }
        let s = builder.add_rigid_model(&name, &model, object.mass / model.particles.len() as f32);
        report.objects.insert(
            name.clone(),
            ObjectInit {
                particles: model.particles.len(),
                gaussians: model.gaussians.len(),
                mass_kg: object.mass,
                alignment: None,
                colour_fit: None,
                silhouette_fit: None,
            },
        );
        shapes.push((s, name, object));
    }
    let mut world = builder.build();
    let config = &{
        let mut c = config.clone();
        (c.physics.ground.normal, c.physics.ground.height) = ground;
        c
    };
    let first: Vec<(&FirstFrames, &[Vec3])> = frames
        .iter()
        .filter_map(|f| f.images.first().map(|i| (f, *i)))
        .collect();
    // Pixels of every object in every camera's frames, left out of the table fit.
    let mut object_pixels: Vec<Vec<Vec<bool>>> = frames
        .iter()
        .map(|f| {
            f.images
                .iter()
                .map(|_| vec![false; (f.camera.width * f.camera.height) as usize])
                .collect()
        })
        .collect();
    for (s, name, object) in &shapes {
        let Some(mask) = object.mask else { continue };
        for (f, frame) in frames.iter().enumerate() {
            for (k, image) in frame.images.iter().enumerate() {
                let m = dilate(
                    &mask.apply(image),
                    frame.camera.width,
                    frame.camera.height,
                    6,
                );
                object_pixels[f][k]
                    .iter_mut()
                    .zip(m)
                    .for_each(|(a, b)| *a |= b);
            }
        }
        if object.align_at_start && !first.is_empty() {
            let views: Vec<align::MaskView> = first
                .iter()
                .map(|(f, image)| align::MaskView {
                    camera: f.camera,
                    mask: mask.segment(image, f.camera.width, f.camera.height),
                })
                .collect();
            let a = align::align_on_table(
                &mut world,
                *s,
                &views,
                config.physics.ground.normal,
                &config.render,
            );
            if let Some(o) = report.objects.get_mut(name) {
                o.alignment = Some(a);
            }
        }
        // The object's colours under this recording's lighting: fitted to the inside of its masks.
        if object.colour_fit_steps > 0 && !first.is_empty() {
            let ids = world.gaussians_of(*s);
            let mut cloud =
                GaussianCloud::from_world_where(&world, |i| ids.binary_search(&i).is_ok());
            let fit_frames: Vec<table::FitFrame> = first
                .iter()
                .map(|(f, image)| {
                    let outside: Vec<bool> = mask
                        .segment(image, f.camera.width, f.camera.height)
                        .iter()
                        .map(|m| !m)
                        .collect();
                    table::FitFrame {
                        camera: f.camera,
                        image,
                        ignore: dilate(&outside, f.camera.width, f.camera.height, 2),
                    }
                })
                .collect();
            let fit = table::fit_colours(
                &mut cloud,
                &fit_frames,
                object.colour_fit_steps,
                0.02,
                1.0,
                &config.render,
                progress,
            )?;
            for (k, &i) in ids.iter().enumerate() {
                world.gaussians.colour[i] = cloud.colour[k];
            }
            if let Some(o) = report.objects.get_mut(name) {
                o.colour_fit = Some(fit);
            }
        }
    }
    // Objects start resting on the ground, not in it: the physics would turn a penetration into
    // a jump (a 2 mm overlap resolved in one substep is a 1 m/s kick).
    if config.physics.ground.enabled {
        for s in world.shapes.dynamic_ids().collect::<Vec<_>>() {
            settle_on_ground(
                &mut world,
                s,
                config.physics.ground.normal,
                config.physics.ground.height,
            );
        }
    }
    if let Some(table_config) = &config.scene.table {
        // Objects without a mask: leave out where they render now (after alignment).
        let cloud = crate::render::GaussianCloud::from_world(&world);
        let mut renderer = crate::render::cpu::CpuRenderer::new(config.render.clone());
        for (f, frame) in frames.iter().enumerate() {
            let out = renderer.forward(
                &cloud,
                &frame.camera,
                crate::render::Roi::full(&frame.camera),
            );
            let rendered = dilate(
                &out.alpha.iter().map(|a| *a > 0.05).collect::<Vec<_>>(),
                frame.camera.width,
                frame.camera.height,
                3,
            );
            for k in 0..frame.images.len() {
                object_pixels[f][k]
                    .iter_mut()
                    .zip(&rendered)
                    .for_each(|(a, b)| *a |= *b);
            }
        }
        let fit_frames: Vec<table::FitFrame> = frames
            .iter()
            .zip(object_pixels)
            .flat_map(|(f, ignores)| {
                f.images
                    .iter()
                    .zip(ignores)
                    .take(table_config.fit_frames.max(1) as usize)
                    .map(move |(image, ignore)| table::FitFrame {
                        camera: f.camera,
                        image,
                        ignore,
                    })
            })
            .collect();
        let mean_colour = {
            let (sum, n) = fit_frames
                .iter()
                .flat_map(|f| f.image.iter().zip(&f.ignore))
                .filter(|(_, i)| !**i)
                .fold((Vec3::ZERO, 0usize), |(s, n), (c, _)| (s + *c, n + 1));
            if n > 0 {
                sum / n as f32
            } else {
                Vec3::splat(0.5)
            }
        };
        let mut disks = table::table_disks(table_config, &config.physics.ground, mean_colour);
        let fit = table::fit_table(
            &mut disks,
            &fit_frames,
            table_config,
            &config.render,
            progress,
        )?;
        for i in 0..disks.len() {
            let r = disks.rotation[i];
            let scale = Vec3::new(
                disks.log_scale[i].x.exp(),
                disks.log_scale[i].y.exp(),
                disks.log_scale[i].z.exp(),
            );
            world.gaussians.push(
                NO_PARENT,
                disks.mean[i],
                Quat::from_xyzw(r.x, r.y, r.z, r.w).normalize(),
                scale,
                crate::render::sigmoid(disks.opacity_logit[i]),
                disks.colour[i],
            );
        }
        report.table = Some(fit);
    }
    // Silhouettes: each masked object's coverage fitted to its masks in the first frames, leaving
    // out pixels that neither it nor the table explains (an unmodelled arm in front of it).
    for (s, name, object) in &shapes {
        let (Some(mask), true) = (object.mask, object.silhouette_fit_steps > 0) else {
            continue;
        };
        let scene = GaussianCloud::static_scene(&world);
        let ids = world.gaussians_of(*s);
        let object_cloud =
            GaussianCloud::from_world_where(&world, |i| ids.binary_search(&i).is_ok());
        let mut renderer = crate::render::cpu::CpuRenderer::new(config.render.clone());
        let mut views = Vec::new();
        let mut ignores = Vec::new();
        for (f, image) in &first {
            let m = mask.segment(image, f.camera.width, f.camera.height);
            let table = renderer
                .forward(&scene, &f.camera, crate::render::Roi::full(&f.camera))
                .colour;
            let own = renderer.forward(
                &object_cloud,
                &f.camera,
                crate::render::Roi::full(&f.camera),
            );
            let palette = crate::correct::rendered_palette(&own.colour, &own.alpha);
            let ignore: Vec<bool> = (0..m.len())
                .map(|k| {
                    !m[k]
                        && !crate::correct::explained(
                            image[k],
                            table[k],
                            &palette,
                            OCCLUDER_THRESHOLD,
                        )
                })
                .collect();
            views.push(align::MaskView {
                camera: f.camera,
                mask: m,
            });
            ignores.push(dilate(&ignore, f.camera.width, f.camera.height, 2));
        }
        let fit = align::fit_silhouette(
            &mut world,
            *s,
            &views,
            &ignores,
            object.silhouette_fit_steps,
            &config.render,
        )?;
        if let Some(o) = report.objects.get_mut(name) {
            o.silhouette_fit = Some(fit);
        }
    }
    report.seconds = clock.elapsed().as_secs_f64();
    Ok((
        Scene {
            world,
            scripts: Vec::new(),
            robot,
        },
        report,
    ))
}

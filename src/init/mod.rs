//! Initialisation: the tracker's world at the start of a recording or a live session. Objects
//! come from files (`ObjectModel`, e.g. the embodied-gaussians JSON format) or from RGB-D and
//! masks; the table is fitted to the first frames; objects are aligned to their masks before
//! tracking starts. This module builds worlds; it never steps them.

pub mod align;
mod config;
pub mod mask;
pub mod object_file;
pub mod rgbd;
pub mod rig;
pub mod table;

pub use config::{ObjectConfig, RgbdObjectConfig, SceneConfig, TableConfig};
pub use mask::ColourMask;

use crate::correct::{explained, rendered_palette};
use crate::math::Pose;
use crate::physics::GroundConfig;
use crate::render::cpu::CpuRenderer;
use crate::render::{Camera, GaussianCloud, RenderSettings, Roi, dilate};
use crate::robot::{JointTrajectory, PackagePaths, RobotConfig, RobotInWorld, RobotModel};
use crate::scene::Scene;
use crate::world::{NO_PARENT, ShapeId, World, WorldBuilder};
use anyhow::{Context, Result, bail};
use glam::{Quat, Vec3};
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::Path;

/// Colour distance of the occluder test used while fitting silhouettes (see `correct::explained`).
const OCCLUDER_THRESHOLD: f32 = 0.35;

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
    /// How far (m) its lowest point was above the ground at the first frame, when more than
    /// `IN_THE_AIR`: built there, to fall when tracking starts.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub in_the_air_m: Option<f32>,
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

impl InitReport {
    /// What a user should read of it, a line per fact: objects built in the air, objects aligned
    /// to their masks.
    pub fn lines(&self) -> Vec<String> {
        let mut lines = Vec::new();
        for (name, o) in &self.objects {
            if let Some(h) = o.in_the_air_m {
                lines.push(format!(
                    "{name}: {:.1} cm above the ground at the first frame: built where it is seen, it falls when tracking starts",
                    h * 100.0
                ));
            }
            if let Some(a) = &o.alignment {
                lines.push(format!(
                    "{name}: aligned to its masks, moved {:.1} mm, turned {:.1} deg, silhouette IoU {:.2} -> {:.2} ({:.1} s)",
                    a.moved_mm, a.turned_deg, a.iou_before, a.iou_after, a.seconds
                ));
            }
        }
        lines
    }
}

/// An object whose lowest point is more than this (m) above the ground at the first frame is in
/// the air there (dropped, thrown, held up): it is built where it is seen and left there to fall,
/// not put down on the table. Resting objects are built within a few millimetres of the ground
/// (depth noise, the lattice's steps), well under it; MuJoCo's drops start 5-13 cm up.
pub const IN_THE_AIR: f32 = 0.02;

/// How far (m) `shape`'s lowest particle is above the ground `normal . p = height` (negative: in
/// it), or None for a shape without particles.
pub fn height_above_ground(
    world: &World,
    shape: ShapeId,
    normal: Vec3,
    height: f32,
) -> Option<f32> {
    let n = normal.normalize_or(Vec3::Z);
    let gap = (world.shapes.range(shape))
        .map(|i| n.dot(world.particles.position[i]) - height - world.particles.radius[i])
        .fold(f32::INFINITY, f32::min);
    gap.is_finite().then_some(gap)
}

/// Move `shape` along the ground normal so that its lowest particle just touches the ground
/// `normal . p = height`: up out of it, or down onto it when it floats by less than
/// `IN_THE_AIR`. Returns the move in m (0 for a shape in the air, which stays where it is).
pub fn settle_on_ground(world: &mut World, shape: ShapeId, normal: Vec3, height: f32) -> f32 {
    let Some(gap) = height_above_ground(world, shape, normal, height) else {
        return 0.0;
    };
    let n = normal.normalize_or(Vec3::Z);
    if gap > IN_THE_AIR {
        return 0.0;
    }
    world.move_shape(shape, Pose::from_translation(-gap * n));
    -gap
}

/// What initialisation reads from the configuration: the scene section, the robot, the ground
/// plane (replaced by a fitted one with `scene.ground_from_depth`) and the renderer.
pub struct Settings<'a> {
    pub scene: &'a SceneConfig,
    pub robot: &'a RobotConfig,
    pub ground: &'a GroundConfig,
    pub render: &'a RenderSettings,
}

/// Build the tracker's world from the first frames: the robot from its URDF at the first joint
/// positions; the ground from depth (RANSAC) if asked; `scene.rgbd_objects` from depth and
/// instance masks (or, without masks, clusters of depth points above the ground that are not the
/// robot); `scene.objects` from their files, each aligned to its colour mask; every object settled
/// onto the ground; then the table fitted to the frames with the objects' pixels left out, and
/// the objects' silhouettes to their masks.
pub fn build_scene(
    settings: &Settings,
    frames: &[FirstFrames],
    initial_joints: &[(String, f64)],
    progress: bool,
) -> Result<(Scene, InitReport)> {
    let clock = std::time::Instant::now();
    let scene = settings.scene;
    scene.check_tracks_something()?;
    let mut report = InitReport::default();
    let mut builder = WorldBuilder::new();
    // The robot first, at its first recorded joint positions (the replay drives it from then on):
    // clustering needs to know which depth points are the robot.
    let robot = add_robot(&mut builder, settings.robot, initial_joints)?;
    let depth: Vec<DepthFrame> = frames
        .iter()
        .filter_map(|f| Some((f, *f.images.first()?, f.depth?)))
        .collect();
    if (scene.ground_from_depth || !scene.rgbd_objects.is_empty()) && depth.is_empty() {
        bail!(
            "the configuration builds the ground or objects from depth, but the recording has no depth images"
        );
    }
    let ground = GroundConfig {
        normal: settings.ground.normal.normalize_or(Vec3::Z),
        ..settings.ground.clone()
    };
    let ground = match scene.ground_from_depth {
        true => fitted_ground(&depth, ground, &mut report)?,
        false => ground,
    };
    if !scene.rgbd_objects.is_empty() {
        add_rgbd_objects(
            &mut builder,
            settings,
            &depth,
            &ground,
            progress,
            &mut report,
        )?;
    }
    let files = add_file_objects(&mut builder, scene, &mut report)?;
    let mut world = builder.build();
    let mut object_pixels = fit_file_objects(
        &mut world,
        &files,
        frames,
        &ground,
        settings.render,
        progress,
        &mut report,
    )?;
    // Objects start resting on the ground, not in it: the physics would turn a penetration into
    // a jump (a 2 mm overlap resolved in one substep is a 1 m/s kick). One in the air stays there.
    if ground.enabled {
        for s in world.shapes.dynamic_ids().collect::<Vec<_>>() {
            settle_on_ground(&mut world, s, ground.normal, ground.height);
            let above = height_above_ground(&world, s, ground.normal, ground.height);
            if let Some(above) = above.filter(|h| *h > IN_THE_AIR) {
                let name = &world.shapes.name[s as usize];
                report.objects.entry(name.clone()).or_default().in_the_air_m = Some(above);
            }
        }
    }
    if let Some(table) = &scene.table {
        leave_out_rendered_objects(&world, frames, settings.render, &mut object_pixels);
        let fit = add_table(
            &mut world,
            table,
            frames,
            object_pixels,
            &ground,
            settings.render,
            progress,
        )?;
        report.table = Some(fit);
    }
    fit_silhouettes(&mut world, &files, frames, settings.render, &mut report)?;
    report.seconds = clock.elapsed().as_secs_f64();
    let scene = Scene {
        world,
        scripts: Vec::new(),
        robot,
    };
    Ok((scene, report))
}

/// A camera's first image and depth.
type DepthFrame<'a> = (&'a FirstFrames<'a>, &'a [Vec3], &'a [f32]);

/// An object loaded from a file: its shape, name and configuration.
type FileObject<'a> = (ShapeId, String, &'a ObjectConfig);

/// The robot from its URDF, placed at `initial_joints` (missing or non-finite ones at zero).
fn add_robot(
    builder: &mut WorldBuilder,
    config: &RobotConfig,
    initial_joints: &[(String, f64)],
) -> Result<Option<(RobotInWorld, JointTrajectory)>> {
    let ament = std::env::var("AMENT_PREFIX_PATH").ok();
    let packages = PackagePaths::with_ament(&config.package_paths, ament.as_deref());
    let model = match (&config.description, &config.urdf) {
        (Some(text), _) => RobotModel::parse(text, Path::new("."), &packages, config.geometry)
            .with_context(|| format!("in the URDF received on {}", config.description_topic))?,
        (None, Some(path)) => RobotModel::load(path, &packages, config.geometry)?,
        (None, None) => return Ok(None),
    };
    let mut q = vec![0.0; model.joints.len()];
    for (name, v) in initial_joints {
        if let Some(j) = model.joint_index(name)
            && v.is_finite()
        {
            q[j] = *v;
        }
    }
    let robot = RobotInWorld::add(builder, model, &q, config)?;
    Ok(Some((robot, JointTrajectory::default())))
}

/// The ground plane by RANSAC through the depth points not labelled as an object.
fn fitted_ground(
    depth: &[DepthFrame],
    ground: GroundConfig,
    report: &mut InitReport,
) -> Result<GroundConfig> {
    let points: Vec<Vec3> = depth
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
    report.ground = Some((normal, height));
    Ok(GroundConfig {
        normal,
        height,
        ..ground
    })
}

/// `scene.rgbd_objects`: ropes as chains along their centre line, rigid objects as carved
/// lattices with fitted Gaussians, from instance masks as recorded or, without them, clusters of
/// the depth points above the ground that are not the robot.
fn add_rgbd_objects(
    builder: &mut WorldBuilder,
    settings: &Settings,
    depth: &[DepthFrame],
    ground: &GroundConfig,
    progress: bool,
    report: &mut InitReport,
) -> Result<()> {
    let plane = (ground.normal, ground.height);
    let labels: Vec<Vec<u8>> = if depth.iter().all(|(f, _, _)| f.labels.is_some()) {
        depth
            .iter()
            .map(|(f, _, _)| f.labels.map(|l| l.to_vec()).unwrap_or_default())
            .collect()
    } else {
        let known: Vec<Vec3> = builder.world().particles.position.clone();
        let cameras: Vec<Camera> = depth.iter().map(|(f, _, _)| f.camera).collect();
        let depths: Vec<&[f32]> = depth.iter().map(|(_, _, d)| *d).collect();
        report.labels_from_clusters = true;
        rgbd::cluster_labels(&cameras, &depths, plane, &known, 0.004, 0.02, 0.01)
    };
    let rgbd: Vec<rgbd::RgbdFrame> = depth
        .iter()
        .zip(&labels)
        .map(|((f, colour, depth), l)| rgbd::RgbdFrame {
            camera: f.camera,
            colour,
            depth,
            labels: l,
        })
        .collect();
    let objects = &settings.scene.rgbd_objects;
    for object in objects.iter().filter(|o| o.rope) {
        let (points, colour) = rgbd::rope_from_rgbd(
            &object.name,
            object.label,
            &rgbd,
            plane,
            object.particle_radius,
        )
        .with_context(|| format!("rope '{}'", object.name))?;
        let mass = object.mass / points.len() as f32;
        let rope = builder.add_rope(
            &object.name,
            &points,
            object.particle_radius,
            mass,
            object.bending_stiffness,
            colour,
        );
        builder.set_gaussian_look(rope, object.particle_radius, 0.97);
        let init = ObjectInit {
            particles: points.len(),
            gaussians: points.len(),
            mass_kg: object.mass,
            ..Default::default()
        };
        report.objects.insert(object.name.clone(), init);
    }
    let rigid: Vec<_> = objects.iter().filter(|o| !o.rope).collect();
    let bar = progress_bar(progress, rigid.len());
    let (mut models, mut reports) = (Vec::new(), Vec::new());
    for object in &rigid {
        bar.set_message(format!("building {} from RGB-D", object.name));
        bar.inc(1);
        let (model, r) = rgbd::object_from_rgbd(
            &object.name,
            object.label,
            &rgbd,
            plane,
            object.particle_radius,
            0.0,
            settings.render,
        )
        .with_context(|| format!("object '{}'", object.name))?;
        models.push(model);
        reports.push(r);
    }
    bar.finish_and_clear();
    let parted = rgbd::part_overlapping(&mut models, plane.0);
    for (((object, model), mut r), parted_mm) in rigid.iter().zip(models).zip(reports).zip(parted) {
        r.parted_mm = parted_mm;
        builder.add_rigid_model(
            &object.name,
            &model,
            object.mass / model.particles.len() as f32,
        );
        let init = ObjectInit {
            particles: model.particles.len(),
            gaussians: model.gaussians.len(),
            mass_kg: object.mass,
            colour_fit: Some(r.colour_fit.clone()),
            ..Default::default()
        };
        report.objects.insert(object.name.clone(), init);
        report.rgbd_objects.insert(object.name.clone(), r);
    }
    Ok(())
}

fn progress_bar(progress: bool, len: usize) -> indicatif::ProgressBar {
    let bar = if progress {
        indicatif::ProgressBar::new(len as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    let style = indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed}")
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar());
    bar.set_style(style);
    bar
}

/// `scene.objects` from their files (the embodied-gaussians format).
fn add_file_objects<'a>(
    builder: &mut WorldBuilder,
    scene: &'a SceneConfig,
    report: &mut InitReport,
) -> Result<Vec<FileObject<'a>>> {
    let mut shapes = Vec::new();
    for object in &scene.objects {
        if object.name.is_empty() {
            bail!("every scene.objects entry needs a name");
        }
        let name = object.name.clone();
        let model = object_file::load_object(&object.embodied_gaussians)
            .with_context(|| format!("object '{name}'"))?;
        if !(object.mass.is_finite() && object.mass > 0.0) {
            bail!(
                "object '{name}': mass must be positive, got {}",
                object.mass
            );
        }
        let s = builder.add_rigid_model(&name, &model, object.mass / model.particles.len() as f32);
        let init = ObjectInit {
            particles: model.particles.len(),
            gaussians: model.gaussians.len(),
            mass_kg: object.mass,
            ..Default::default()
        };
        report.objects.insert(name.clone(), init);
        shapes.push((s, name, object));
    }
    Ok(shapes)
}

/// Objects from files with a colour mask: aligned on the table to their masks in the first
/// frames and their colours fitted to the inside of the masks. Returns, per camera and frame, the
/// pixels of every masked object (dilated), to leave out of the table's fit.
#[allow(clippy::too_many_arguments)]
fn fit_file_objects(
    world: &mut World,
    files: &[FileObject],
    frames: &[FirstFrames],
    ground: &GroundConfig,
    render: &RenderSettings,
    progress: bool,
    report: &mut InitReport,
) -> Result<Vec<Vec<Vec<bool>>>> {
    let first: Vec<(&FirstFrames, &[Vec3])> = frames
        .iter()
        .filter_map(|f| f.images.first().map(|i| (f, *i)))
        .collect();
    let mut object_pixels: Vec<Vec<Vec<bool>>> = frames
        .iter()
        .map(|f| {
            let pixels = (f.camera.width * f.camera.height) as usize;
            f.images.iter().map(|_| vec![false; pixels]).collect()
        })
        .collect();
    for (s, name, object) in files {
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
            let a = align::align_on_table(world, *s, &views, ground.normal, render);
            if let Some(o) = report.objects.get_mut(name) {
                o.alignment = Some(a);
            }
        }
        // The object's colours under this recording's lighting: fitted to the inside of its masks.
        if object.colour_fit_steps > 0 && !first.is_empty() {
            let fit = fit_object_colours(
                world,
                *s,
                &mask,
                &first,
                object.colour_fit_steps,
                render,
                progress,
            )?;
            if let Some(o) = report.objects.get_mut(name) {
                o.colour_fit = Some(fit);
            }
        }
    }
    Ok(object_pixels)
}

/// Adam on the colours of shape `s`'s Gaussians against the inside of `mask` in the first frames.
fn fit_object_colours(
    world: &mut World,
    s: ShapeId,
    mask: &ColourMask,
    first: &[(&FirstFrames, &[Vec3])],
    steps: u32,
    render: &RenderSettings,
    progress: bool,
) -> Result<table::ColourFit> {
    let ids = world.gaussians_of(s);
    let mut cloud = GaussianCloud::from_world_where(world, |i| ids.binary_search(&i).is_ok());
    let fit_frames: Vec<table::FitFrame> = first
        .iter()
        .map(|(f, image)| {
            let (w, h) = (f.camera.width, f.camera.height);
            let outside: Vec<bool> = mask.segment(image, w, h).iter().map(|m| !m).collect();
            table::FitFrame {
                camera: f.camera,
                image,
                ignore: dilate(&outside, w, h, 2),
            }
        })
        .collect();
    let fit = table::fit_colours(&mut cloud, &fit_frames, steps, 0.02, 1.0, render, progress)?;
    for (k, &i) in ids.iter().enumerate() {
        world.gaussians.colour[i] = cloud.colour[k];
    }
    Ok(fit)
}

/// Objects without a mask: leave out of the table's fit where they render now (after alignment).
fn leave_out_rendered_objects(
    world: &World,
    frames: &[FirstFrames],
    render: &RenderSettings,
    object_pixels: &mut [Vec<Vec<bool>>],
) {
    let cloud = GaussianCloud::from_world(world);
    let mut renderer = CpuRenderer::new(render.clone());
    for (f, frame) in frames.iter().enumerate() {
        let (w, h) = (frame.camera.width, frame.camera.height);
        let out = renderer.forward(&cloud, &frame.camera, Roi::full(&frame.camera));
        let covered: Vec<bool> = out.alpha.iter().map(|a| *a > 0.05).collect();
        let rendered = dilate(&covered, w, h, 3);
        for pixels in &mut object_pixels[f] {
            pixels.iter_mut().zip(&rendered).for_each(|(a, b)| *a |= *b);
        }
    }
}

/// The table's disks on the ground plane, fitted to the frames with `object_pixels` left out, added
/// to the world as static Gaussians.
fn add_table(
    world: &mut World,
    table_config: &TableConfig,
    frames: &[FirstFrames],
    object_pixels: Vec<Vec<Vec<bool>>>,
    ground: &GroundConfig,
    render: &RenderSettings,
    progress: bool,
) -> Result<table::ColourFit> {
    let per_camera = table_config.fit_frames.max(1) as usize;
    let fit_frames: Vec<table::FitFrame> = frames
        .iter()
        .zip(object_pixels)
        .flat_map(|(f, ignores)| {
            let frames = f.images.iter().zip(ignores).take(per_camera);
            frames.map(move |(image, ignore)| table::FitFrame {
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
    let mut disks = table::table_disks(table_config, ground, mean_colour);
    let fit = table::fit_table(&mut disks, &fit_frames, table_config, render, progress)?;
    for i in 0..disks.len() {
        let r = disks.rotation[i];
        let l = disks.log_scale[i];
        let scale = Vec3::new(l.x.exp(), l.y.exp(), l.z.exp());
        let rotation = Quat::from_xyzw(r.x, r.y, r.z, r.w).normalize();
        let opacity = crate::render::sigmoid(disks.opacity_logit[i]);
        world.gaussians.push(
            NO_PARENT,
            disks.mean[i],
            rotation,
            scale,
            opacity,
            disks.colour[i],
        );
    }
    Ok(fit)
}

/// Each masked object's coverage fitted to its masks in the first frames, leaving out pixels that
/// neither it nor the table explains (an unmodelled arm in front of it).
fn fit_silhouettes(
    world: &mut World,
    files: &[FileObject],
    frames: &[FirstFrames],
    render: &RenderSettings,
    report: &mut InitReport,
) -> Result<()> {
    let first: Vec<(&FirstFrames, &[Vec3])> = frames
        .iter()
        .filter_map(|f| f.images.first().map(|i| (f, *i)))
        .collect();
    for (s, name, object) in files {
        let (Some(mask), true) = (object.mask, object.silhouette_fit_steps > 0) else {
            continue;
        };
        let scene = GaussianCloud::static_scene(world);
        let ids = world.gaussians_of(*s);
        let object_cloud =
            GaussianCloud::from_world_where(world, |i| ids.binary_search(&i).is_ok());
        let mut renderer = CpuRenderer::new(render.clone());
        let mut views = Vec::new();
        let mut ignores = Vec::new();
        for (f, image) in &first {
            let (w, h) = (f.camera.width, f.camera.height);
            let m = mask.segment(image, w, h);
            let table = renderer
                .forward(&scene, &f.camera, Roi::full(&f.camera))
                .colour;
            let own = renderer.forward(&object_cloud, &f.camera, Roi::full(&f.camera));
            let palette = rendered_palette(&own.colour, &own.alpha);
            let ignore: Vec<bool> = (0..m.len())
                .map(|k| !m[k] && !explained(image[k], table[k], &palette, OCCLUDER_THRESHOLD))
                .collect();
            views.push(align::MaskView {
                camera: f.camera,
                mask: m,
            });
            ignores.push(dilate(&ignore, w, h, 2));
        }
        let fit = align::fit_silhouette(
            world,
            *s,
            &views,
            &ignores,
            object.silhouette_fit_steps,
            render,
        )?;
        if let Some(o) = report.objects.get_mut(name) {
            o.silhouette_fit = Some(fit);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2 x 2 x 1 lattice of 5 mm particles whose lowest point is `gap` above the ground z = 0.
    fn slab_at(gap: f32) -> (World, ShapeId) {
        let mut builder = WorldBuilder::new();
        let points =
            [(0.0, 0.0), (0.01, 0.0), (0.0, 0.01), (0.01, 0.01)].map(|(x, y)| Vec3::new(x, y, 0.0));
        let pose = Pose::from_translation(Vec3::new(0.5, 0.0, 0.005 + gap));
        let s = builder.add_rigid("slab", &points, 0.005, 0.01, pose, Vec3::ONE);
        (builder.build(), s)
    }

    #[test]
    fn the_report_says_which_objects_were_built_in_the_air_and_nothing_of_resting_ones() {
        let mut report = InitReport::default();
        report
            .objects
            .insert("resting".into(), ObjectInit::default());
        let dropped = ObjectInit {
            in_the_air_m: Some(0.1304),
            ..Default::default()
        };
        report.objects.insert("dropped".into(), dropped);
        let lines = report.lines();
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(
            lines[0].starts_with("dropped: 13.0 cm above the ground"),
            "{lines:?}"
        );
    }

    #[test]
    fn an_object_resting_is_put_on_the_ground_and_one_in_the_air_is_left_where_it_is() {
        for (gap, moved) in [
            (-0.003, 0.003),
            (0.004, -0.004),
            (0.019, -0.019),
            (0.06, 0.0),
        ] {
            let (mut world, s) = slab_at(gap);
            let got = settle_on_ground(&mut world, s, Vec3::Z, 0.0);
            let after = height_above_ground(&world, s, Vec3::Z, 0.0).unwrap();
            assert!((got - moved).abs() < 1e-6, "{gap}: moved {got}");
            assert!((after - (gap + moved)).abs() < 1e-6, "{gap}: {after} above");
        }
    }
}

//! Synthetic scenarios with ground truth: a "true world" simulated by pegs' own physics (possibly
//! with extra effects the tracker's model lacks) and rendered into three cameras with sensor noise
//! and exposure drift, and a "model world" the tracker starts from (possibly off the true pose).
//! Both are built by the same function, so particle i of an object is the same material point in
//! both and the 3-D tracking error is a per-particle distance.

use crate::config::Config;
use crate::math::Pose;
use crate::physics::Effect;
use crate::physics::effects::{ConstantForce, ViscousDrag};
use crate::render::{Camera, GaussianCloud, RenderSettings, Roi, cpu::CpuRenderer, logit, sigmoid};
use crate::robot::{RobotConfig, RobotInWorld};
use crate::scene::{self, Scene, pusher_trajectory};
use crate::world::ShapeId;
use crate::world::World;
use crate::world::{WorldBuilder, box_lattice};
use anyhow::{Context, Result, bail};

pub mod concealed;
pub mod generate;
use glam::{DVec3, Quat, Vec3};

pub const NAMES: [&str; 7] = [
    "resting_box",
    "pushed_box",
    "pushed_tblock",
    "tblock_pushed_over",
    "two_boxes",
    "dragged_rope",
    "hidden_box",
];

/// Every scenario `generate` knows: the tracking scenarios, then the concealed-physics ones.
pub fn all_names() -> impl Iterator<Item = &'static str> {
    NAMES.into_iter().chain(concealed::NAMES)
}

/// The natural length of scenario `name`'s recording, s.
pub fn seconds(name: &str) -> f64 {
    if name.starts_with("concealed_") {
        concealed::SECONDS
    } else {
        4.5
    }
}

/// What each scenario shows, for listings and the README table.
pub fn description(name: &str) -> &'static str {
    match name {
        n if n.starts_with("concealed_") => concealed::description(n),
        "resting_box" => "a box at rest; the robot stays away",
        "pushed_box" => "the rod pushes a box 15 cm",
        "pushed_tblock" => "the rod pushes the T-block 15 cm, turning it",
        "tblock_pushed_over" => {
            "the T-block stands on its bar; the rod tips it over and it falls flat (gravity prior)"
        }
        "two_boxes" => "the rod pushes one box into another (collision prior)",
        "dragged_rope" => "a rope tied to the rod tip is dragged across the table",
        "hidden_box" => {
            "the hand passes over a box while an unmodelled pull moves it; the box reappears"
        }
        _ => "",
    }
}

/// The tracked objects of scenario `name`.
pub fn object_names(name: &str) -> &'static [&'static str] {
    match name {
        n if n.contains("tblock") => &["tblock"],
        "two_boxes" => &["box", "box2"],
        "concealed_heavy" => &["box", "box2", "box3"],
        "dragged_rope" => &["rope"],
        _ => &["box"],
    }
}

/// The configuration of the scenario's true world: pegs' defaults plus the effects the tracker's
/// model does not have.
pub fn truth_config(name: &str) -> Config {
    let mut config = model_config(name);
    if name.starts_with("concealed_") {
        config.physics.effects = concealed::truth(name).effects;
    }
    if name == "hidden_box" {
        // A hidden string drags the box along +y at about 1.7 cm/s (a pull above static friction,
        // balanced by drag), so while the hand hides it the model's prediction goes stale.
        config.physics.effects = vec![
            Effect::ConstantForce(ConstantForce {
                object: Some("box".into()),
                force: Vec3::new(0.0, 2.2, 0.0),
            }),
            Effect::ViscousDrag(ViscousDrag {
                object: Some("box".into()),
                coefficient: 40.0,
            }),
        ];
    }
    config
}

/// The configuration the tracker of scenario `name` starts from: pegs' defaults, or the slippery
/// table of the concealed scenarios.
pub fn model_config(name: &str) -> Config {
    if name.starts_with("concealed_") {
        concealed::model_config()
    } else {
        Config::default()
    }
}

/// Particle radius and mass of scenario objects.
const R: f32 = 0.005;
const MASS: f32 = 0.001;

/// A flat textured table of static Gaussians (no particles: the ground plane is the physics).
fn add_table(b: &mut WorldBuilder) {
    for iy in 0..60 {
        for ix in 0..60 {
            let shade = if (ix / 6 + iy / 6) % 2 == 0 {
                0.12
            } else {
                0.2
            };
            // Sizes and opacity through their logarithm and logit, as the renderer stores them.
            let log_scale = Vec3::new(0.006f32.ln(), 0.006f32.ln(), 0.0008f32.ln());
            b.add_scene_gaussian(
                Vec3::new(0.2 + ix as f32 * 0.01, -0.3 + iy as f32 * 0.01, -0.001),
                Quat::IDENTITY,
                Vec3::new(log_scale.x.exp(), log_scale.y.exp(), log_scale.z.exp()),
                sigmoid(logit(0.97)),
                Vec3::splat(shade),
            );
        }
    }
}

/// The three cameras of scenario `name`, looking at the workspace around (0.5, 0, 0). In
/// `hidden_box` they look over the robot's shoulder, as a head or wall camera behind the arm does.
pub fn cameras(name: &str, width: u32, height: u32) -> Vec<Camera> {
    let fx = 0.9 * width as f32;
    let target = Vec3::new(0.5, 0.0, 0.02);
    let eyes = if name == "hidden_box" {
        [
            Vec3::new(-0.05, -0.12, 0.9),
            Vec3::new(-0.05, 0.12, 0.9),
            Vec3::new(0.05, -0.02, 1.0),
        ]
    } else {
        [
            Vec3::new(1.0, -0.45, 0.55),
            Vec3::new(0.95, 0.5, 0.6),
            Vec3::new(0.25, -0.55, 0.65),
        ]
    };
    eyes.iter()
        .map(|&eye| Camera::look_at(width, height, fx, eye, target))
        .collect()
}

/// `offset` applied to a true pose: translated, and turned about the object's own centre.
fn displaced(rest: Pose, offset: Pose) -> Pose {
    Pose::new(
        rest.translation + offset.translation,
        offset.rotation * rest.rotation,
    )
}

/// A 12 x 6 x 5 cm box, blue with a yellow end, so no rotation of it looks the same.
fn add_box(b: &mut WorldBuilder, rest: Pose, offset: Pose) -> ShapeId {
    add_painted_box(
        b,
        "box",
        rest,
        offset,
        Vec3::new(0.15, 0.35, 0.9),
        Vec3::new(0.95, 0.8, 0.1),
    )
}

/// A 12 x 6 x 5 cm box of 1 g particles named `name`, coloured `body` with an `end` of another
/// colour along its +x end.
fn add_painted_box(
    b: &mut WorldBuilder,
    name: &str,
    rest: Pose,
    offset: Pose,
    body: Vec3,
    end: Vec3,
) -> ShapeId {
    let bx = b.add_rigid(
        name,
        &box_lattice(Vec3::new(0.06, 0.03, 0.025), 2.0 * R),
        R,
        MASS,
        displaced(rest, offset),
        body,
    );
    b.set_gaussian_look(bx, R, 0.97);
    b.paint(bx, |p| if p.x > 0.02 { Some(end) } else { None });
    bx
}

/// The push-T block of the paper's real scenes: 20 x 20 cm, 3 cm thick, orange.
fn add_tblock(b: &mut WorldBuilder, rest: Pose, offset: Pose) -> ShapeId {
    let t = b.add_rigid(
        "tblock",
        &crate::world::t_block_lattice(0.2, 0.05, 0.03, 2.0 * R),
        R,
        MASS,
        displaced(rest, offset),
        Vec3::new(1.0, 0.45, 0.1),
    );
    b.set_gaussian_look(t, R, 0.97);
    t
}

/// Height of a box's centre resting on the table (5 cm tall, particle centres R above it).
const BOX_Z: f32 = R + 2.0 * 2.0 * R;

/// Build scenario `name`'s world with the object placed `offset` away from its true start.
pub fn build(name: &str, offset: Pose) -> Result<Scene> {
    if name.starts_with("concealed_") && concealed::NAMES.contains(&name) {
        return concealed::build(name, offset);
    }
    let mut b = WorldBuilder::new();
    add_table(&mut b);
    let model = scene::panda_pusher()?;
    let tip = |x: f64, y: f64, z: f64| DVec3::new(x, y, z);
    // Pusher-tip waypoints (time, point); the rod points down.
    let waypoints: Vec<(f64, DVec3)> = match name {
        "resting_box" => {
            add_box(
                &mut b,
                Pose::new(Vec3::new(0.5, 0.0, BOX_Z), Quat::from_rotation_z(0.2)),
                offset,
            );
            // The robot parks away from the box.
            vec![(0.0, tip(0.3, -0.3, 0.2)), (10.0, tip(0.3, -0.3, 0.2))]
        }
        "pushed_box" | "two_boxes" => {
            add_box(
                &mut b,
                Pose::new(Vec3::new(0.5, 0.0, BOX_Z), Quat::from_rotation_z(0.2)),
                offset,
            );
            if name == "two_boxes" {
                // A second, 8 x 8 x 5 cm red box with a white end, in the first one's path.
                let rest = Pose::new(Vec3::new(0.51, 0.13, BOX_Z), Quat::from_rotation_z(-0.3));
                let b2 = b.add_rigid(
                    "box2",
                    &box_lattice(Vec3::new(0.04, 0.04, 0.025), 2.0 * R),
                    R,
                    MASS,
                    displaced(rest, offset),
                    Vec3::new(0.85, 0.15, 0.15),
                );
                b.set_gaussian_look(b2, R, 0.97);
                b.paint(b2, |p| {
                    if p.y > 0.02 {
                        Some(Vec3::splat(0.9))
                    } else {
                        None
                    }
                });
            }
            // The rod comes down behind the box and pushes it 15 cm along +y.
            vec![
                (0.0, tip(0.5, -0.16, 0.12)),
                (0.5, tip(0.5, -0.16, 0.02)),
                (3.5, tip(0.5, 0.1, 0.02)),
                (4.0, tip(0.5, 0.1, 0.12)),
            ]
        }
        "pushed_tblock" => {
            add_tblock(
                &mut b,
                Pose::new(
                    Vec3::new(0.5, 0.0, R + 2.0 * R),
                    Quat::from_rotation_z(0.35),
                ),
                offset,
            );
            // The rod comes down behind the stem and pushes the T 15 cm along +y, turning it.
            vec![
                (0.0, tip(0.5, -0.22, 0.12)),
                (0.5, tip(0.5, -0.22, 0.015)),
                (3.5, tip(0.5, 0.04, 0.015)),
                (4.0, tip(0.5, 0.04, 0.12)),
            ]
        }
        "tblock_pushed_over" => {
            // Standing on its bar (body +y down), stem up, its thickness along world y.
            let standing =
                Quat::from_rotation_z(0.15) * Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2);
            add_tblock(
                &mut b,
                Pose::new(Vec3::new(0.5, 0.0, R + 0.095), standing),
                offset,
            );
            // The rod touches the top of the stem from -y and tips the T over; it falls flat.
            vec![
                (0.0, tip(0.5, -0.1, 0.25)),
                (0.5, tip(0.5, -0.06, 0.17)),
                (1.5, tip(0.5, 0.04, 0.17)),
                (2.0, tip(0.5, 0.04, 0.3)),
            ]
        }
        "dragged_rope" => vec![
            (0.0, tip(0.35, 0.1, 0.012)),
            (0.5, tip(0.35, 0.1, 0.012)),
            (4.0, tip(0.6, 0.15, 0.012)),
        ],
        "hidden_box" => {
            add_box(
                &mut b,
                Pose::new(Vec3::new(0.5, -0.1, BOX_Z), Quat::from_rotation_z(0.2)),
                offset,
            );
            // The hand comes in between the cameras and the box, follows it, and leaves.
            vec![
                (0.0, tip(0.2, 0.4, 0.3)),
                (1.0, tip(0.36, -0.11, 0.12)),
                (2.4, tip(0.36, -0.08, 0.12)),
                (3.0, tip(0.2, 0.4, 0.3)),
            ]
        }
        other => bail!(
            "unknown scenario '{other}' (known: {})",
            all_names().collect::<Vec<_>>().join(", ")
        ),
    };
    let trajectory = pusher_trajectory(&model, &waypoints, 30.0)?;
    let q0 = trajectory.at(0.0).context("empty trajectory")?;
    let robot = RobotInWorld::add(&mut b, model, &q0, &RobotConfig::default())?;
    if name == "dragged_rope" {
        add_rope_tied_to_tip(&mut b, &robot, &q0, offset)?;
    }
    Ok(Scene {
        world: b.build(),
        scripts: Vec::new(),
        robot: Some((robot, trajectory)),
    })
}

/// A 30 cm green rope lying along -y on the table, its first particle tied to the rod tip.
fn add_rope_tied_to_tip(
    b: &mut WorldBuilder,
    robot: &RobotInWorld,
    q0: &[f64],
    offset: Pose,
) -> Result<()> {
    let link = robot
        .model
        .link_index("panda_pusher")
        .context("no pusher link")?;
    let tip_world = (robot.base * robot.model.forward_kinematics(q0)[link])
        .transform_point3(scene::PUSHER_TIP)
        .as_vec3();
    let spacing = 2.0 * R;
    let start = Vec3::new(tip_world.x, tip_world.y - spacing, R);
    let rest: Vec<Vec3> = (0..30)
        .map(|k| start - Vec3::new(0.0, k as f32 * spacing, 0.0))
        .collect();
    let centre = rest.iter().copied().sum::<Vec3>() / rest.len() as f32;
    let points: Vec<Vec3> = rest
        .iter()
        .map(|&p| offset.rotation * (p - centre) + centre + offset.translation)
        .collect();
    let rope = b.add_rope("rope", &points, R, MASS, 0.3, Vec3::new(0.2, 0.8, 0.3));
    b.set_gaussian_look(rope, R, 0.97);
    // The rod particle nearest the tip holds the rope's first particle where it lies (a model
    // started off the true pose gets a slightly different tie: no constraint starts violated).
    let world = b.world();
    let pusher = world
        .shape_id("robot/panda_pusher")
        .context("no pusher shape")?;
    let holder = world
        .shapes
        .range(pusher)
        .min_by(|&i, &j| {
            world.particles.position[i]
                .distance(tip_world)
                .total_cmp(&world.particles.position[j].distance(tip_world))
        })
        .context("empty pusher")?;
    let first = world.shapes.range(rope).start;
    b.attach(holder, first);
    Ok(())
}

/// Per camera, the fraction of `object`'s silhouette that is visible (not hidden by anything in
/// front of it): pixels the object covers when rendered alone, against pixels whose colour
/// changes when it is removed from the full scene.
pub fn visible_fraction(world: &World, cameras: &[Camera], object: &str) -> Vec<f32> {
    let Some(s) = world.shape_id(object) else {
        return vec![0.0; cameras.len()];
    };
    let range = world.shapes.range(s);
    let full = GaussianCloud::from_world(world);
    let mine: Vec<bool> = world
        .gaussians
        .parent
        .iter()
        .map(|&p| range.contains(&(p as usize)))
        .collect();
    let mut without = full.clone();
    let mut alone = full.clone();
    for (i, &m) in mine.iter().enumerate() {
        if m {
            without.opacity_logit[i] = -30.0;
        } else {
            alone.opacity_logit[i] = -30.0;
        }
    }
    let mut renderer = CpuRenderer::images_only(RenderSettings::default());
    cameras
        .iter()
        .map(|c| {
            let a = renderer.forward(&full, c, Roi::full(c));
            let b = renderer.forward(&without, c, Roi::full(c));
            let o = renderer.forward(&alone, c, Roi::full(c));
            let silhouette = o.alpha.iter().filter(|&&x| x > 0.5).count();
            let seen = o
                .alpha
                .iter()
                .zip(a.colour.iter().zip(&b.colour))
                .filter(|(x, (p, q))| **x > 0.5 && (**p - **q).abs().max_element() > 0.05)
                .count();
            if silhouette == 0 {
                0.0
            } else {
                seen as f32 / silhouette as f32
            }
        })
        .collect()
}

/// Render what the cameras see of `world`, with sensor noise (std-dev `noise`) and an exposure
/// factor; deterministic for a given `seed`.
pub fn observe(
    world: &World,
    cameras: &[Camera],
    noise: f32,
    exposure: f32,
    seed: u64,
) -> Vec<Vec<Vec3>> {
    let cloud = GaussianCloud::from_world(world);
    let mut renderer = CpuRenderer::images_only(RenderSettings::default());
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut gauss = move || {
        // Sum of uniforms: cheap, deterministic, close enough to normal for sensor noise.
        let mut s = 0.0f32;
        for _ in 0..4 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            s += (state >> 40) as f32 / (1u64 << 24) as f32;
        }
        (s - 2.0) * 1.732
    };
    cameras
        .iter()
        .map(|c| {
            let out = renderer.forward(&cloud, c, Roi::full(c));
            out.colour
                .into_iter()
                .map(|px| {
                    (px * exposure + Vec3::new(gauss(), gauss(), gauss()) * noise)
                        .clamp(Vec3::ZERO, Vec3::ONE)
                })
                .collect()
        })
        .collect()
}

/// Tick `k` of tracking on rendered truth: the true world moves on a tick, is rendered into
/// `cameras` (`observe`, noise 0.01 drawn from `k`), and `model` tracks those images, its tick
/// ending `dt` after its clock.
pub fn tick_on_truth(
    (truth, model): (&mut crate::tracker::Tracker, &mut crate::tracker::Tracker),
    cameras: &[Camera],
    k: usize,
    dt: f64,
) -> Result<crate::tracker::TickReport> {
    truth.predict()?;
    let images = observe(truth.world(), cameras, 0.01, 1.0, k as u64);
    let inputs = crate::inputs::TickInputs::with_images(model.time() + dt, cameras, images);
    model.tick(&inputs)
}

/// What an ideal depth camera with instance segmentation sees: per pixel, the depth (m along the
/// optical axis, 0 where the ray meets nothing) of the first solid its centre ray meets, and the
/// label of that solid (k + 1 for `objects[k]`, 0 for anything else). Solids are the particles'
/// cubes (edge twice the radius, in their shape's frame; ropes' particles as cubes along the world
/// axes) and the ground plane z = 0.
pub fn observe_depth_and_labels(
    world: &World,
    cameras: &[Camera],
    objects: &[&str],
) -> Vec<(Vec<f32>, Vec<u8>)> {
    use rayon::prelude::*;
    let p = &world.particles;
    // Per shape: its frame, its cubes' centres and half edges in that frame, and a bounding sphere.
    type Solid = (Pose, Vec<(Vec3, f32)>, Vec3, f32, u8);
    let shapes: Vec<Solid> = (0..world.shapes.len() as u32)
        .map(|s| {
            let frame = if world.shapes.kind[s as usize] == crate::world::ShapeKind::Rope {
                Pose::IDENTITY
            } else {
                world.shapes.pose[s as usize]
            };
            let to_frame = frame.inverse();
            let cubes: Vec<(Vec3, f32)> = world
                .shapes
                .range(s)
                .map(|i| (to_frame.transform_point(p.position[i]), p.radius[i]))
                .collect();
            let centre = cubes.iter().map(|c| c.0).sum::<Vec3>() / cubes.len().max(1) as f32;
            let reach = cubes
                .iter()
                .map(|(c, r)| c.distance(centre) + r * 1.8)
                .fold(0.0, f32::max);
            let label = objects
                .iter()
                .position(|o| *o == world.shapes.name[s as usize])
                .map_or(0, |k| k as u8 + 1);
            (frame, cubes, frame.transform_point(centre), reach, label)
        })
        .collect();
    cameras
        .iter()
        .map(|c| {
            let to_world = c.world_to_camera.inverse();
            let origin = to_world.translation;
            let pixels: Vec<(f32, u8)> = (0..c.width * c.height)
                .into_par_iter()
                .map(|k| {
                    let (u, v) = ((k % c.width) as f32 + 0.5, (k / c.width) as f32 + 0.5);
                    // Unnormalised: the ray parameter is the depth along the optical axis.
                    let dir =
                        to_world.rotation * Vec3::new((u - c.cx) / c.fx, (v - c.cy) / c.fy, 1.0);
                    let mut best = (
                        if dir.z < 0.0 {
                            -origin.z / dir.z
                        } else {
                            f32::INFINITY
                        },
                        0u8,
                    );
                    for (frame, cubes, centre, reach, label) in &shapes {
                        // Skip shapes whose bounding sphere the ray misses or lies behind the best hit.
                        let along = (*centre - origin).dot(dir) / dir.length_squared();
                        let closest = origin + dir * along;
                        if closest.distance(*centre) > *reach
                            || (along - reach / dir.length()) > best.0
                        {
                            continue;
                        }
                        let inv = frame.rotation.inverse();
                        let (o, d) = (inv * (origin - frame.translation), inv * dir);
                        for (q, r) in cubes {
                            if let Some(t) = ray_cube(o - *q, d, *r)
                                && t < best.0
                            {
                                best = (t, *label);
                            }
                        }
                    }
                    if best.0.is_finite() { best } else { (0.0, 0) }
                })
                .collect();
            (
                pixels.iter().map(|x| x.0).collect(),
                pixels.iter().map(|x| x.1).collect(),
            )
        })
        .collect()
}

/// Where a ray `o + t d` (t > 0) enters the cube `|x|_inf <= h` centred at the origin.
fn ray_cube(o: Vec3, d: Vec3, h: f32) -> Option<f32> {
    let inv = d.recip();
    let (a, b) = ((Vec3::splat(-h) - o) * inv, (Vec3::splat(h) - o) * inv);
    let (near, far) = (a.min(b).max_element(), a.max(b).min_element());
    (near <= far && near > 0.0).then_some(near)
}

/// Mean distance (m) between the particles of `object` in the two worlds.
pub fn tracking_error(truth: &World, model: &World, object: &str) -> Option<f32> {
    let (a, b) = (truth.shape_id(object)?, model.shape_id(object)?);
    let (ra, rb) = (truth.shapes.range(a), model.shapes.range(b));
    if ra.len() != rb.len() || ra.is_empty() {
        return None;
    }
    let sum: f32 = ra
        .clone()
        .zip(rb)
        .map(|(i, j)| truth.particles.position[i].distance(model.particles.position[j]))
        .sum();
    Some(sum / ra.len() as f32)
}

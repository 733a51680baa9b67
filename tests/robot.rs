//! The robot: forward kinematics of the bundled Panda against an independent Denavit-Hartenberg
//! chain and published poses, the real recording's mesh URDF, link particles under motion, a
//! pushing motion replayed from joint states, and bad input.

use glam::{DAffine3, DMat3, DVec3, Vec3};
use pegs::math::Pose;
use pegs::physics::PhysicsConfig;
use pegs::physics::Solver;
use pegs::robot::{
    GeometrySource, JointStateTracker, JointTrajectory, PackagePaths, RobotConfig, RobotInWorld,
    RobotModel,
};
use pegs::world::{WorldBuilder, box_lattice};
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};
use std::path::{Path, PathBuf};

fn bundled(name: &str) -> RobotModel {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("urdf")
        .join(name);
    RobotModel::load(&path, &PackagePaths::default(), GeometrySource::Collision).unwrap()
}

fn shared_robot() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/pusht_real/robot/panda.urdf")
}

const ARM: [&str; 7] = [
    "panda_joint1",
    "panda_joint2",
    "panda_joint3",
    "panda_joint4",
    "panda_joint5",
    "panda_joint6",
    "panda_joint7",
];

/// Joint vector for the model from the seven arm angles.
fn q_of(model: &RobotModel, arm: &[f64; 7]) -> Vec<f64> {
    let mut q = vec![0.0; model.joints.len()];
    for (name, v) in ARM.iter().zip(arm) {
        q[model.joint_index(name).unwrap()] = *v;
    }
    q
}

/// The flange pose from Franka's published modified Denavit-Hartenberg parameters (Craig's
/// convention: T = RotX(alpha) TransX(a) RotZ(theta) TransZ(d)), computed independently of URDF.
fn dh_flange(arm: &[f64; 7]) -> DAffine3 {
    let params = [
        (0.0, 0.333, 0.0),
        (0.0, 0.0, -FRAC_PI_2),
        (0.0, 0.316, FRAC_PI_2),
        (0.0825, 0.0, FRAC_PI_2),
        (-0.0825, 0.384, -FRAC_PI_2),
        (0.0, 0.0, FRAC_PI_2),
        (0.088, 0.0, FRAC_PI_2),
        (0.0, 0.107, 0.0),
    ];
    let mut t = DAffine3::IDENTITY;
    for (k, (a, d, alpha)) in params.iter().enumerate() {
        let theta = if k < 7 { arm[k] } else { 0.0 };
        t = t
            * DAffine3::from_mat3(DMat3::from_rotation_x(*alpha))
            * DAffine3::from_translation(DVec3::new(*a, 0.0, 0.0))
            * DAffine3::from_mat3(DMat3::from_rotation_z(theta))
            * DAffine3::from_translation(DVec3::new(0.0, 0.0, *d));
    }
    t
}

fn flange(model: &RobotModel, arm: &[f64; 7]) -> DAffine3 {
    model.forward_kinematics(&q_of(model, arm))[model.link_index("panda_link8").unwrap()]
}

fn pose_error(a: &DAffine3, b: &DAffine3) -> (f64, f64) {
    let d = a.matrix3.transpose() * b.matrix3;
    let angle = ((d.x_axis.x + d.y_axis.y + d.z_axis.z - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos();
    ((a.translation - b.translation).length(), angle)
}

fn random_configs(n: usize) -> Vec<[f64; 7]> {
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut r = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n)
        .map(|_| [(); 7].map(|_| (r() * 2.0 - 1.0) * 2.5))
        .collect()
}

#[test]
fn bundled_panda_forward_kinematics_matches_published_values_within_1mm() {
    for file in ["panda.urdf", "panda_pusher.urdf"] {
        let m = bundled(file);
        // Zero configuration: flange at (0.088, 0, 0.926), its z axis pointing down.
        let f = flange(&m, &[0.0; 7]);
        assert!(
            (f.translation - DVec3::new(0.088, 0.0, 0.926)).length() < 1e-3,
            "{file}: {}",
            f.translation
        );
        assert!((f.matrix3.z_axis - DVec3::NEG_Z).length() < 1e-6);
        // The "ready" pose: flange at (0.3069, 0, 0.5903).
        let ready = [
            0.0,
            -FRAC_PI_4,
            0.0,
            -3.0 * FRAC_PI_4,
            0.0,
            FRAC_PI_2,
            FRAC_PI_4,
        ];
        let f = flange(&m, &ready);
        assert!(
            (f.translation - DVec3::new(0.3069, 0.0, 0.5903)).length() < 1e-3,
            "{file}: {}",
            f.translation
        );
        // Any configuration: the whole flange pose agrees with the DH chain.
        for q in random_configs(50)
            .iter()
            .chain([ready, [0.0; 7], [PI / 3.0, 0.5, -1.0, -2.0, 1.5, 2.5, -0.7]].iter())
        {
            let (dp, da) = pose_error(&flange(&m, q), &dh_flange(q));
            assert!(dp < 1e-3 && da < 1e-3, "{file}: {q:?}: {dp} m, {da} rad");
        }
    }
}

#[test]
fn the_real_recordings_mesh_urdf_loads_and_agrees_with_the_bundled_kinematics() {
    let real = RobotModel::load(
        &shared_robot(),
        &PackagePaths::default(),
        GeometrySource::Collision,
    )
    .expect("../shared robot URDF");
    let meshes = real
        .links
        .iter()
        .filter(|l| {
            l.geometry
                .iter()
                .any(|g| matches!(g.shape, pegs::robot::model::Shape::Mesh { .. }))
        })
        .count();
    assert_eq!(meshes, 12, "every link but link8 has an STL mesh");
    let ours = bundled("panda_pusher.urdf");
    for q in random_configs(20) {
        let (dp, da) = pose_error(&flange(&real, &q), &flange(&ours, &q));
        assert!(dp < 1e-3 && da < 1e-3);
        // The pusher frame too.
        let p_real =
            real.forward_kinematics(&q_of(&real, &q))[real.link_index("panda_pusher").unwrap()];
        let p_ours =
            ours.forward_kinematics(&q_of(&ours, &q))[ours.link_index("panda_pusher").unwrap()];
        assert!((p_real.translation - p_ours.translation).length() < 1e-3);
    }
    // Its STL links become particles on the meshes.
    let mut b = WorldBuilder::new();
    let robot = RobotInWorld::add(&mut b, real, &[0.0; 12], &RobotConfig::default()).unwrap();
    let w = b.build();
    assert_eq!(robot.link_shapes.len(), 12);
    for &(_, s) in &robot.link_shapes {
        assert!(
            w.shapes.range(s).len() > 20,
            "link {} has {} particles",
            w.shapes.name[s as usize],
            w.shapes.range(s).len()
        );
    }
}

fn arm_motion(t: f64) -> [f64; 7] {
    let s = (t * 1.3).sin();
    [
        0.6 * s,
        -FRAC_PI_4 + 0.4 * (t * 0.9).sin(),
        0.3 * s,
        -3.0 * FRAC_PI_4 + 0.5 * (t * 1.7).sin(),
        0.8 * s,
        FRAC_PI_2 + 0.3 * s,
        FRAC_PI_4 + s,
    ]
}

#[test]
fn every_link_gets_particles_that_stay_on_their_link_under_motion() {
    let model = bundled("panda.urdf");
    let config = RobotConfig {
        base_position: Vec3::new(0.1, -0.2, 0.0),
        ..RobotConfig::default()
    };
    let mut b = WorldBuilder::new();
    let robot = RobotInWorld::add(
        &mut b,
        model.clone(),
        &q_of(&model, &arm_motion(0.0)),
        &config,
    )
    .unwrap();
    let mut world = b.build();
    let with_geometry = model
        .links
        .iter()
        .filter(|l| !l.geometry.is_empty())
        .count();
    assert_eq!(robot.link_shapes.len(), with_geometry);
    for &(li, s) in &robot.link_shapes {
        let n = world.shapes.range(s).len();
        assert!(n >= 4, "link {} got {n} particles", model.links[li].name);
        // Every particle's sphere touches one of its link's collision shapes from inside (body
        // frame = link frame): the particle lies a radius in from that shape's surface.
        let radius = RobotConfig::default().particle_radius as f64;
        for i in world.shapes.range(s) {
            let p = world.particles.rest[i].as_dvec3();
            let off = model.links[li]
                .geometry
                .iter()
                .map(|g| {
                    let d = pegs::robot::sampling::distance_to_surface(
                        &g.shape,
                        g.origin.inverse().transform_point3(p),
                    );
                    (d - radius).abs()
                })
                .fold(f64::INFINITY, f64::min);
            assert!(
                off < 1e-5,
                "particle {off} m from a radius in from link {}'s surface",
                model.links[li].name
            );
        }
        // Gaussians take the URDF material colour.
        let gi = world
            .gaussians
            .parent
            .iter()
            .position(|&p| p as usize == world.shapes.range(s).start)
            .unwrap();
        assert_eq!(world.gaussians.colour[gi], model.links[li].colour.unwrap());
    }
    // Replay joint states at 20 Hz; the physics interpolates and runs FK every substep.
    let mut trajectory = JointTrajectory::default();
    let mut tracker = JointStateTracker::new(&model);
    let names: Vec<String> = ARM.iter().map(|s| s.to_string()).collect();
    for k in 0..=40 {
        let t = k as f64 * 0.05;
        tracker.update(&names, &arm_motion(t));
        assert!(trajectory.push(t, tracker.positions.clone()));
    }
    let mut solver = Solver::new(PhysicsConfig::default(), &world).unwrap();
    let dt = solver.config().dt as f64;
    let mut worst = 0.0f64;
    for tick in 0..55 {
        let t0 = tick as f64 * dt;
        let mut driver = robot.driver(&trajectory, t0, dt);
        solver.step_driven(&mut world, &mut driver).unwrap();
        let q = trajectory.at(t0 + dt).unwrap();
        for (s, pose) in robot.link_poses(&q) {
            for i in world.shapes.range(s) {
                let want = pose.transform_point(world.particles.rest[i]);
                worst = worst.max((world.particles.position[i] - want).length() as f64);
            }
        }
    }
    eprintln!(
        "largest particle distance from its link under motion: {:.4} mm",
        worst * 1e3
    );
    assert!(worst < 0.5e-3, "particles left their links by {} m", worst);
}

#[test]
fn a_pushing_motion_replayed_from_joint_states_pushes_a_box() {
    let model = bundled("panda_pusher.urdf");
    let ready = [
        0.0,
        -FRAC_PI_4,
        0.0,
        -3.0 * FRAC_PI_4,
        0.0,
        FRAC_PI_2,
        FRAC_PI_4,
    ];
    let pusher =
        model.forward_kinematics(&q_of(&model, &ready))[model.link_index("panda_pusher").unwrap()];
    // The rod points along the pusher frame's -z, 0.14 m long: its tip.
    let tip = pusher.transform_point3(DVec3::new(0.0, 0.0, -0.14));
    let table = tip.z as f32 - 0.02;
    let radius = tip.truncate().length();
    let mut b = WorldBuilder::new();
    let robot = RobotInWorld::add(
        &mut b,
        model.clone(),
        &q_of(&model, &ready),
        &RobotConfig::default(),
    )
    .unwrap();
    // A 6 cm cube on the table, on the tip's arc, a little ahead of it.
    let (r, spacing) = (0.005, 0.01);
    let box_angle = 0.28f32;
    let centre = Vec3::new(
        radius as f32 * box_angle.cos(),
        radius as f32 * box_angle.sin(),
        table + 0.03,
    );
    let bx = b.add_rigid(
        "box",
        &box_lattice(Vec3::splat(0.03), spacing),
        r,
        0.002,
        Pose::new(centre, glam::Quat::from_rotation_z(box_angle)),
        Vec3::X,
    );
    let mut world = b.build();
    let mut config = PhysicsConfig::default();
    config.ground.height = table;
    let mut solver = Solver::new(config, &world).unwrap();
    // Joint states at 10 Hz: joint 1 sweeps 0 -> 0.7 rad in 2.5 s, the tip moving along its arc.
    let mut trajectory = JointTrajectory::default();
    let mut tracker = JointStateTracker::new(&model);
    let names: Vec<String> = ARM.iter().map(|s| s.to_string()).collect();
    for k in 0..=30 {
        let t = k as f64 * 0.1;
        let mut q = ready;
        q[0] = 0.7 * (t / 2.5).min(1.0);
        tracker.update(&names, &q);
        trajectory.push(t, tracker.positions.clone());
    }
    let start = world.shape_centroid(bx);
    let dt = solver.config().dt as f64;
    for tick in 0..90 {
        let mut driver = robot.driver(&trajectory, tick as f64 * dt, dt);
        solver.step_driven(&mut world, &mut driver).unwrap();
    }
    let end = world.shape_centroid(bx);
    let moved = end - start;
    // Pushed along the arc: the angle about the base grew, the box stayed on the table.
    let angle = |p: Vec3| p.y.atan2(p.x);
    eprintln!(
        "box moved {:.3} m, from {:.3} to {:.3} rad about the base, height change {:.2} mm",
        moved.length(),
        angle(start),
        angle(end),
        (end.z - start.z) * 1e3
    );
    assert!(
        moved.truncate().length() > 0.05,
        "the pusher must move the box (moved {moved})"
    );
    assert!(angle(end) > angle(start) + 0.1, "pushed the wrong way");
    assert!((end.z - start.z).abs() < 2e-3, "box left the table");
    assert!(
        angle(end) < 0.7 + 0.35,
        "box cannot get far ahead of the pusher"
    );
}

#[test]
fn package_uris_and_obj_meshes_resolve_and_missing_meshes_are_clear_errors() {
    let dir = std::env::temp_dir().join(format!("pegs-robot-{}", std::process::id()));
    let pkg = dir.join("pkgs/mybot/meshes");
    std::fs::create_dir_all(&pkg).unwrap();
    std::fs::write(
        pkg.join("plate.obj"),
        "v 0 0 0\nv 0.1 0 0\nv 0.1 0.1 0\nv 0 0.1 0\nf 1 2 3 4\n",
    )
    .unwrap();
    let urdf = r#"<robot name="m"><link name="base"><collision><geometry><mesh filename="package://mybot/meshes/plate.obj" scale="2 2 2"/></geometry></collision></link></robot>"#;
    let paths = PackagePaths(vec![dir.join("pkgs")]);
    let m = RobotModel::parse(urdf, &dir, &paths, GeometrySource::Collision).unwrap();
    let pegs::robot::model::Shape::Mesh { triangles, .. } = &m.links[0].geometry[0].shape else {
        panic!("mesh expected")
    };
    assert_eq!(triangles.len(), 2, "the quad is triangulated");
    let max = triangles.iter().flatten().fold(0.0f64, |a, p| a.max(p.x));
    assert!((max - 0.2).abs() < 1e-6, "scale applied: max x {max}");
    let missing = urdf.replace("plate.obj", "gone.obj");
    let e = format!(
        "{:#}",
        RobotModel::parse(&missing, &dir, &paths, GeometrySource::Collision).unwrap_err()
    );
    assert!(e.contains("gone.obj"), "{e}");
    let e = format!(
        "{:#}",
        RobotModel::load(&dir.join("absent.urdf"), &paths, GeometrySource::Collision).unwrap_err()
    );
    assert!(e.contains("absent.urdf"), "{e}");
}

#[test]
fn bad_robot_configuration_is_rejected() {
    let model = bundled("panda.urdf");
    let mut b = WorldBuilder::new();
    let bad = RobotConfig {
        particle_radius: -1.0,
        ..RobotConfig::default()
    };
    assert!(RobotInWorld::add(&mut b, model.clone(), &[0.0; 12], &bad).is_err());
    let nan = RobotConfig {
        base_position: Vec3::new(f32::NAN, 0.0, 0.0),
        ..RobotConfig::default()
    };
    assert!(RobotInWorld::add(&mut b, model, &[0.0; 12], &nan).is_err());
}

#[test]
fn robot_gaussians_render_and_occlude_objects_behind_them() {
    use pegs::render::{Camera, GaussianCloud, RenderSettings, Roi, cpu::CpuRenderer};
    let model = bundled("panda_pusher.urdf");
    let ready = [
        0.0,
        -FRAC_PI_4,
        0.0,
        -3.0 * FRAC_PI_4,
        0.0,
        FRAC_PI_2,
        FRAC_PI_4,
    ];
    let mut b = WorldBuilder::new();
    RobotInWorld::add(
        &mut b,
        model.clone(),
        &q_of(&model, &ready),
        &RobotConfig::default(),
    )
    .unwrap();
    let pusher =
        model.forward_kinematics(&q_of(&model, &ready))[model.link_index("panda_pusher").unwrap()];
    let rod_mid = pusher
        .transform_point3(DVec3::new(0.0, 0.0, -0.07))
        .as_vec3();
    // An orange plate 15 cm behind the rod, seen from the side by a camera 40 cm in front of it.
    let orange = Vec3::new(1.0, 0.45, 0.1);
    let plate = b.add_static(
        "block",
        &box_lattice(Vec3::new(0.08, 0.01, 0.08), 0.01),
        0.005,
        Pose::from_translation(rod_mid + Vec3::new(0.0, 0.15, 0.0)),
        orange,
    );
    b.set_gaussian_look(plate, 0.005, 0.98);
    let world = b.build();
    let camera = Camera::look_at(120, 120, 200.0, rod_mid - Vec3::new(0.0, 0.4, 0.0), rod_mid);
    let out = CpuRenderer::new(RenderSettings::default()).forward(
        &GaussianCloud::from_world(&world),
        &camera,
        Roi::full(&camera),
    );
    let (u, v, _) = camera.project(rod_mid);
    let at = |x: f32, y: f32| out.colour[(y as usize) * 120 + x as usize];
    let on_rod = at(u, v);
    let beside = at(u + 25.0, v);
    let rod_colour = model.links[model.link_index("panda_pusher").unwrap()]
        .colour
        .unwrap();
    assert!(
        (on_rod - rod_colour).length() < 0.05,
        "the rod must hide the block: {on_rod} vs rod {rod_colour}"
    );
    assert!(
        (beside - orange).length() < 0.1,
        "beside the rod the block shows: {beside}"
    );
}

/// The bundled pusher alone in a world, at the start of `arm_motion`, built with `config`.
fn pusher_world(config: RobotConfig) -> (RobotInWorld, pegs::world::World) {
    let model = bundled("panda_pusher.urdf");
    let q = q_of(&model, &arm_motion(0.0));
    let mut b = WorldBuilder::new();
    let robot = RobotInWorld::add(&mut b, model, &q, &config).unwrap();
    (robot, b.build())
}

/// With `robot.contact: exact` every link whose collision geometry is all primitives (the bundled
/// pusher: boxes and cylinders) is met as those solids, placed where the URDF has them; by
/// default none is (the links' particles).
#[test]
fn exact_contact_gives_every_primitive_link_its_urdf_solids_and_the_default_none() {
    let model = bundled("panda_pusher.urdf");
    let build = |contact| {
        pusher_world(RobotConfig {
            contact,
            ..RobotConfig::default()
        })
    };
    let (robot, world) = build(pegs::robot::RobotContact::Exact);
    for &(li, s) in &robot.link_shapes {
        let link = &model.links[li];
        let solids = &world.shapes.primitives[s as usize];
        assert_eq!(solids.len(), link.geometry.len(), "link {}", link.name);
        for (solid, g) in solids.iter().zip(&link.geometry) {
            let at = g.origin.translation.as_vec3();
            assert!(
                solid.origin.translation.distance(at) < 1e-6,
                "link {}: solid at {} against {at}",
                link.name,
                solid.origin.translation
            );
        }
    }
    let (_, world) = build(pegs::robot::RobotContact::Particles);
    assert!(world.shapes.primitives.iter().all(|p| p.is_empty()));
}

/// `robot.stiffness` makes every link give way as a spring of that stiffness (compliance 1/k), and
/// a stiffness that is not a positive number is refused by name; left out, every link is rigid.
#[test]
fn a_stiffness_makes_every_link_yield_by_its_inverse_and_none_keeps_them_rigid() {
    let build = |stiffness| {
        pusher_world(RobotConfig {
            stiffness,
            ..RobotConfig::default()
        })
    };
    let (robot, world) = build(Some(1000.0));
    assert!(!robot.link_shapes.is_empty());
    for &(_, s) in &robot.link_shapes {
        assert!((world.shapes.compliance[s as usize] - 1e-3).abs() < 1e-9);
    }
    let (_, world) = build(None);
    assert!(world.shapes.compliance.iter().all(|&c| c == 0.0));
    for bad in [0.0, -5.0, f32::NAN] {
        let config = RobotConfig {
            stiffness: Some(bad),
            ..RobotConfig::default()
        };
        let err = config.validate().unwrap_err().to_string();
        assert!(err.contains("robot.stiffness"), "{err}");
    }
}

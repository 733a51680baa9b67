//! The tick: one owner for predict / correct. `Tracker::tick` takes what a tick consumes
//! (`inputs::TickInputs`: the time it ends at, the newest usable image of every camera and the
//! robot's joint trajectory), predicts with the physics (the robot driven by the trajectory),
//! corrects against the images and returns what happened (`TickReport`). Offline replay and the
//! live node are drivers: they feed ticks and publish or write what comes back, through
//! `Observer`s that see the tracker read-only after every tick. Nothing else touches the world
//! between ticks.

pub mod health;
mod observer;
mod table_edge;

pub use health::{Change, TrackEvent, TrackHealth};
pub use observer::{Observer, Tick};
pub use table_edge::{OFF_TABLE_ADVICE, TableEdge};

use crate::config::Config;
use crate::correct::{CorrectConfig, CorrectStats, Corrector, Plant, Support, View, relocate};
use crate::inputs::{Inputs, TickInputs};
use crate::math::Pose;
use crate::physics::{PhysicsConfig, Solver, Touched};
use crate::render::Camera;
use crate::robot::{JointTrajectory, RobotInWorld};
use crate::scene::Scene;
use crate::world::{ShapeId, ShapeKind, World};
use anyhow::Result;
use std::time::Instant;

/// At most this many missed ticks are caught up by prediction alone; beyond it the clock jumps.
pub const MAX_CATCH_UP_TICKS: usize = 10;

/// The first tick after a start predicts across the whole set-up, up to this long (s): the world
/// begins at the first frames, and a jump there would put the robot at once where its joint states
/// took it meanwhile, into what it pushed (`Tracker::first_tick`).
pub const START_CATCH_UP_S: f64 = 10.0;

pub struct Tracker {
    scene: Scene,
    solver: Solver,
    /// None: physics only (no visual forces).
    corrector: Option<Corrector>,
    /// Which tracked objects are lost (their silhouettes no longer agree with the images).
    health: TrackHealth,
    /// Per shape: its pose at the newest tick the images agreed with it (where a search for it
    /// starts), and when it was last searched for.
    well_tracked: Vec<Option<Pose>>,
    searched_at: Vec<f64>,
    /// Per shape: its pose when tracking began, standing as it stood then (`upright_at`).
    start: Vec<Pose>,
    /// Which objects stand off the modelled table (`table_edge`).
    table_edge: TableEdge,
}

/// A search from a pose tipped more than this (rad) from how the object stood when tracking
/// began also looks for it standing that way (`upright_at`).
pub const TIPPED_BEYOND: f32 = 0.35;

/// Seconds between two searches for the same object.
pub const SEARCH_EVERY: f64 = 0.15;
/// A search moves the object only where the images agree with it at least this well
/// (`health::FOUND_ABOVE`) and this much better than where the model has it.
pub const RELOCATE_MARGIN: f32 = 0.25;

/// What one tick did.
#[derive(Clone, Debug, Default)]
pub struct TickReport {
    /// When the tick ended (the world's clock after it), s.
    pub time: f64,
    /// Ticks predicted without correction before this one, to catch up with a clock that ran
    /// ahead (the live node after an overrun).
    pub caught_up: usize,
    /// Seconds the world's clock jumped over without prediction (a gap beyond
    /// `MAX_CATCH_UP_TICKS`).
    pub jumped_s: f64,
    /// The correction: photometric loss, visual forces and the wrench on every shape. None when
    /// the tick was not corrected (physics only, or correction disabled).
    pub correction: Option<CorrectStats>,
    /// Images the correction compared with.
    pub cameras_used: usize,
    /// Non-finite visual forces and robot poses the physics refused in this tick.
    pub rejected_forces: usize,
    pub rejected_poses: usize,
    /// Per shape: the bodies it touched during the tick's prediction (ticks caught up included).
    pub touched: Vec<Touched>,
    /// Wall time of the prediction (catching up included) and of the correction, ms.
    pub predict_ms: f64,
    pub correct_ms: f64,
    /// Objects lost or found again in this tick (`health`).
    pub track_events: Vec<TrackEvent>,
}

impl TickReport {
    /// Adds one physics step's touches to the tick's.
    fn note_touches(&mut self, step: &[Touched]) {
        self.touched.resize(step.len(), Touched::default());
        for (all, now) in self.touched.iter_mut().zip(step) {
            *all = all.or(*now);
        }
    }
}

impl Tracker {
    /// A tracker of `scene` from its world's clock on, with the configuration's physics, and its
    /// correction when `visual_forces` (and `correct.enabled`).
    pub fn new(scene: Scene, config: &Config, visual_forces: bool) -> Result<Self> {
        let correct = visual_forces.then(|| (config.correct.clone(), config.render.clone()));
        Self::with(scene, config.physics.clone(), correct)
    }

    /// A tracker with explicit physics and, if any, correction settings.
    pub fn with(
        scene: Scene,
        physics: PhysicsConfig,
        correct: Option<(CorrectConfig, crate::render::RenderSettings)>,
    ) -> Result<Self> {
        let support = physics.ground.enabled.then_some(Support {
            normal: physics.ground.normal,
            height: physics.ground.height,
            kinetic_friction: physics.ground.kinetic_friction,
            gravity: physics.gravity,
        });
        let plant = Plant::of(&physics);
        let solver = Solver::new(physics, &scene.world)?;
        let corrector = match correct {
            Some((c, render)) if c.enabled => Some(
                Corrector::new(c, render)?
                    .with_support(support)
                    .with_plant(plant),
            ),
            _ => None,
        };
        let table_edge = TableEdge::of(&scene.world);
        let start = scene.world.shapes.pose.clone();
        Ok(Self {
            scene,
            solver,
            corrector,
            health: TrackHealth::default(),
            well_tracked: Vec::new(),
            searched_at: Vec::new(),
            start,
            table_edge,
        })
    }

    /// Run the tick that ends at `inputs.time`: catch up with the clock if it ran ahead (at most
    /// `MAX_CATCH_UP_TICKS`), follow the joint trajectory, predict, correct.
    pub fn tick(&mut self, inputs: &TickInputs) -> Result<TickReport> {
        self.tick_catching_up(inputs, MAX_CATCH_UP_TICKS)
    }

    /// The first tick of a live run: as `tick`, but it predicts across every tick since the world
    /// began (up to `START_CATCH_UP_S`), however long building the tracker took, so the robot's
    /// joint states since the first frames move it through the physics, pushing what it meets.
    pub fn first_tick(&mut self, inputs: &TickInputs) -> Result<TickReport> {
        let dt = self.solver.config().dt as f64;
        self.tick_catching_up(inputs, (START_CATCH_UP_S / dt).ceil() as usize)
    }

    fn tick_catching_up(&mut self, inputs: &TickInputs, limit: usize) -> Result<TickReport> {
        // The robot follows the newest joint states, also across ticks caught up.
        if let (Some(trajectory), Some((_, followed))) = (&inputs.trajectory, &mut self.scene.robot)
        {
            followed.clone_from(trajectory);
        }
        let clock = Instant::now();
        let mut report = self.catch_up(inputs.time, limit)?;
        self.scene.advance(&mut self.solver)?;
        report.note_touches(&self.solver.stats.touched);
        report.rejected_forces = self.solver.stats.rejected_forces;
        report.rejected_poses = self.solver.stats.rejected_poses;
        report.predict_ms = clock.elapsed().as_secs_f64() * 1e3;
        if let Some(corrector) = self.corrector.as_mut().filter(|c| c.config.enabled) {
            let clock = Instant::now();
            let views = inputs.views();
            let dt = self.solver.config().dt;
            corrector.note_contacts(&self.solver.stats.touched);
            corrector.note_masses(self.solver.inv_mass());
            let mut stats = corrector.correct(&mut self.scene.world, &views, dt)?;
            for &(shape, speed) in &stats.nudged_in_contact {
                self.solver.settle_below(shape, speed);
            }
            let time = self.scene.world.time;
            report.track_events = self.health.update(time, &stats.agreement);
            let searching = Instant::now();
            let relocated = Self::relocate_lost(
                corrector,
                &mut self.scene.world,
                &mut self.health,
                (&mut self.well_tracked, &mut self.searched_at, &self.start),
                &views,
                &stats.agreement,
            )?;
            for event in &relocated {
                self.solver.settle(event.shape);
            }
            report.track_events.extend(relocated);
            let search_ms = searching.elapsed().as_secs_f64() * 1e3;
            stats.stage_ms.insert("relocate".into(), search_ms);
            let edge = self.table_edge.update(&self.scene.world, time);
            report.track_events.extend(edge);
            report.correction = Some(stats);
            report.cameras_used = views.len();
            report.correct_ms = clock.elapsed().as_secs_f64() * 1e3;
        }
        report.time = self.scene.world.time;
        Ok(report)
    }

    /// Objects whose silhouettes have disagreed with the images for a few ticks are searched for
    /// around where they were last well tracked (`correct::relocate`), and moved where the
    /// images show them; each move is an event. A search from a pose the model has tipped over
    /// (a strike it got wrong) also looks for the object standing as it stood at the start.
    fn relocate_lost(
        corrector: &mut Corrector,
        world: &mut World,
        health: &mut TrackHealth,
        (well_tracked, searched_at, start): (&mut Vec<Option<Pose>>, &mut Vec<f64>, &[Pose]),
        views: &[View],
        agreement: &[Option<f32>],
    ) -> Result<Vec<TrackEvent>> {
        let n = world.shapes.len();
        well_tracked.resize(n, None);
        searched_at.resize(n, f64::NEG_INFINITY);
        let mut events = Vec::new();
        for s in 0..n {
            if world.shapes.kind[s] != ShapeKind::Rigid {
                continue;
            }
            let shape = s as ShapeId;
            let here = world.shapes.pose[s];
            if !health.is_lost(shape)
                && agreement
                    .get(s)
                    .copied()
                    .flatten()
                    .is_some_and(|a| a > health::FOUND_ABOVE)
            {
                well_tracked[s] = Some(here);
            }
            if !health.wants_search(shape) || world.time - searched_at[s] < SEARCH_EVERY {
                continue;
            }
            searched_at[s] = world.time;
            let reference = well_tracked[s].unwrap_or(here);
            let search = relocate::Search {
                occluder_threshold: corrector.config.occluder_threshold,
                ..Default::default()
            };
            let mut found = corrector.relocate(world, shape, reference, views, &search)?;
            if let Some(upright) = start.get(s).and_then(|st| upright_at(&reference, st)) {
                let standing = corrector.relocate(world, shape, upright, views, &search)?;
                if standing.is_some_and(|b| found.is_none_or(|a| b.score > a.score)) {
                    found = standing;
                }
            }
            let Some(found) = found else {
                continue;
            };
            if found.score < health::FOUND_ABOVE || found.score < found.score_here + RELOCATE_MARGIN
            {
                continue;
            }
            world.move_shape(shape, found.pose.mul(&here.inverse()));
            corrector.forget(world, shape);
            health.relocated(shape);
            well_tracked[s] = Some(found.pose);
            let turn = crate::math::rotation_angle_between(here.rotation, found.pose.rotation);
            events.push(TrackEvent {
                shape,
                time: world.time,
                change: Change::Relocated {
                    from: here.translation.to_array(),
                    to: found.pose.translation.to_array(),
                    jump_m: here.translation.distance(found.pose.translation),
                    turn_deg: turn.to_degrees(),
                },
                agreement: found.score,
            });
        }
        Ok(events)
    }

    /// One tick of the physics alone, with the robot on its current trajectory (a ground-truth
    /// world, or a tracker whose cameras are all gone).
    pub fn predict(&mut self) -> Result<()> {
        self.scene.advance(&mut self.solver)
    }

    /// Predict across ticks the clock has already passed (their images are gone), up to `limit`;
    /// beyond that, jump the world's clock (the robot then stands at once where its joint states
    /// put it).
    fn catch_up(&mut self, t: f64, limit: usize) -> Result<TickReport> {
        let dt = self.solver.config().dt as f64;
        let behind = ((t - dt - self.scene.world.time) / dt).round().max(0.0) as usize;
        let mut report = TickReport::default();
        if behind > limit {
            report.jumped_s = (behind - limit) as f64 * dt;
            self.scene.world.time += report.jumped_s;
        }
        report.caught_up = behind.min(limit);
        for _ in 0..report.caught_up {
            self.scene.advance(&mut self.solver)?;
            report.note_touches(&self.solver.stats.touched);
        }
        Ok(report)
    }

    /// The inputs that feed this tracker: `cameras`, and the robot's joint states starting from
    /// where the robot stands now.
    pub fn inputs(&self, cameras: Vec<(String, Camera)>) -> Inputs {
        let robot_start = self.robot().map(|(r, trajectory)| {
            let q = trajectory
                .at(self.time())
                .unwrap_or_else(|| vec![0.0; r.model.joints.len()]);
            (r.model.clone(), q)
        });
        Inputs::new(
            cameras,
            robot_start.as_ref().map(|(m, q)| (m, q.as_slice())),
        )
    }

    /// The tracked world after the last tick.
    pub fn world(&self) -> &World {
        &self.scene.world
    }

    /// The world's clock: when the last tick ended, s.
    pub fn time(&self) -> f64 {
        self.scene.world.time
    }

    /// Which objects stand off the modelled table.
    pub fn table_edge(&self) -> &TableEdge {
        &self.table_edge
    }

    /// Which objects are lost, and their newest silhouette agreement.
    pub fn health(&self) -> &TrackHealth {
        &self.health
    }

    /// The robot and the joint trajectory it followed in the last tick.
    pub fn robot(&self) -> Option<(&RobotInWorld, &JointTrajectory)> {
        self.scene.robot.as_ref().map(|(r, t)| (r, t))
    }

    pub fn physics(&self) -> &PhysicsConfig {
        self.solver.config()
    }

    /// Whether ticks are corrected (visual forces on and enabled).
    pub fn corrects(&self) -> bool {
        self.corrector.as_ref().is_some_and(|c| c.config.enabled)
    }

    /// The visual-force gain (1/s^2) the corrections take, scaled for the model's physics
    /// (`correct::plant`); None without visual forces.
    pub fn visual_gain(&self) -> Option<f32> {
        self.corrector.as_ref().map(|c| c.gain())
    }

    /// Restart the world's clock at `t` (the node's clock went back: a recording played again).
    /// The world stays where it is; the next tick ends at `t` + dt.
    pub fn restart_clock(&mut self, t: f64) {
        self.scene.world.time = t;
    }

    /// New correction settings from the next tick on (a live parameter change).
    pub fn set_correct(&mut self, config: CorrectConfig) {
        if let Some(corrector) = &mut self.corrector {
            corrector.config = config;
        }
    }
}

/// `pose` standing as `start` stood (its tilt from the vertical taken back, its turn about the
/// vertical and its place on the table kept, at the height it started at), where it is tipped
/// more than `TIPPED_BEYOND` from it; None otherwise.
pub fn upright_at(pose: &Pose, start: &Pose) -> Option<Pose> {
    let relative = (pose.rotation * start.rotation.inverse()).normalize();
    let up = relative * glam::Vec3::Z;
    if up.z.clamp(-1.0, 1.0).acos() <= TIPPED_BEYOND {
        return None;
    }
    // The turn about the vertical in the relative rotation (its twist about z).
    let twist = glam::Quat::from_xyzw(0.0, 0.0, relative.z, relative.w);
    let twist = match twist.length() > 1e-3 {
        true => twist.normalize(),
        false => glam::Quat::IDENTITY,
    };
    let mut at = pose.translation;
    at.z = start.translation.z;
    Some(Pose::new(at, (twist * start.rotation).normalize()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::inputs::TickInputs;
    use crate::render::Camera;
    use crate::robot::JointTrajectory;
    use glam::{DVec3, Vec3};

    fn physics_only(scene: Scene) -> Tracker {
        Tracker::with(scene, PhysicsConfig::default(), None).unwrap()
    }

    fn at(time: f64) -> TickInputs {
        TickInputs {
            time,
            ..Default::default()
        }
    }

    /// A pose tipped onto its side stands up as the object started (its up axis back to the
    /// start's, at the start's height), keeping its place and its turn about the vertical; a pose
    /// only turned, or tipped a little, is left to the search as it is.
    #[test]
    fn a_tipped_object_is_looked_for_standing_as_it_started_with_its_turn_kept() {
        use glam::Quat;
        let start = Pose::new(Vec3::new(0.5, 0.0, 0.025), Quat::from_rotation_z(0.3));
        let turn = Quat::from_rotation_z(1.1);
        let tipped = Pose::new(
            Vec3::new(0.6, -0.02, 0.06),
            turn * Quat::from_rotation_x(1.6) * start.rotation,
        );
        let up = upright_at(&tipped, &start).expect("tipped 92 deg");
        assert!(up.translation.distance(Vec3::new(0.6, -0.02, 0.025)) < 1e-6);
        let up_axis = |p: &Pose| p.rotation * start.rotation.inverse() * Vec3::Z;
        assert!(up_axis(&up).distance(Vec3::Z) < 1e-4, "{:?}", up_axis(&up));
        // The turn about the vertical: a body axis in the horizontal plane keeps its heading.
        let heading = |q: Quat| {
            let x = q * Vec3::X;
            x.y.atan2(x.x)
        };
        let turned = (turn * start.rotation).normalize();
        assert!((heading(up.rotation) - heading(turned)).abs() < 1e-3);
        let only_turned = Pose::new(tipped.translation, turned);
        assert!(upright_at(&only_turned, &start).is_none());
        let leaning = Pose::new(tipped.translation, Quat::from_rotation_y(0.2) * turned);
        assert!(upright_at(&leaning, &start).is_none());
    }

    /// A tick whose end lies three ticks ahead predicts across the two it missed: the same world
    /// as three ticks of the physics alone.
    #[test]
    fn a_tick_that_ends_late_predicts_across_the_ticks_it_missed() {
        let mut late = physics_only(crate::scene::tabletop().unwrap());
        let mut stepped = physics_only(crate::scene::tabletop().unwrap());
        let dt = late.physics().dt as f64;
        let report = late.tick(&at(late.time() + 3.0 * dt)).unwrap();
        for _ in 0..3 {
            stepped.predict().unwrap();
        }
        assert_eq!(report.caught_up, 2);
        assert_eq!(report.jumped_s, 0.0);
        assert!((report.time - stepped.time()).abs() < 1e-9);
        assert_eq!(
            late.world().particles.position,
            stepped.world().particles.position
        );
        assert!(report.correction.is_none(), "physics only");
    }

    /// Beyond `MAX_CATCH_UP_TICKS` the clock jumps: the world is predicted for the last ticks
    /// only, and the jump is reported.
    #[test]
    fn a_gap_beyond_the_catch_up_limit_jumps_the_clock_and_says_so() {
        let mut tracker = physics_only(crate::scene::tabletop().unwrap());
        let dt = tracker.physics().dt as f64;
        let t = tracker.time() + 100.0 * dt;
        let report = tracker.tick(&at(t)).unwrap();
        assert_eq!(report.caught_up, MAX_CATCH_UP_TICKS);
        assert!((report.jumped_s - (100 - 1 - MAX_CATCH_UP_TICKS) as f64 * dt).abs() < 1e-9);
        assert!(
            (tracker.time() - t).abs() < 1e-6,
            "{} vs {t}",
            tracker.time()
        );
    }

    /// A live start whose set-up outlasted the catch-up limit (the world began at the first frames,
    /// 3 s before its first tick) is predicted tick by tick across the whole of it: the same world
    /// as ticking through it, so the rod that reached the T-block meanwhile pushes it along at the
    /// rod's pace (0.075 m/s) instead of landing inside it and throwing it.
    #[test]
    fn a_slow_start_is_predicted_through_so_the_rod_pushes_what_it_reached_meanwhile() {
        let scene = || crate::scene::tblock_and_robot().unwrap();
        let mut started = physics_only(scene());
        let mut stepped = physics_only(scene());
        let dt = started.physics().dt as f64;
        let t0 = started.time();
        let ticks = 90;
        let report = started.first_tick(&at(t0 + ticks as f64 * dt)).unwrap();
        for _ in 0..ticks {
            stepped.predict().unwrap();
        }
        assert_eq!(report.caught_up, ticks - 1);
        assert_eq!(report.jumped_s, 0.0);
        assert_eq!(
            started.world().particles.position,
            stepped.world().particles.position
        );
        let world = started.world();
        let start = scene().world;
        let id = world
            .shapes
            .name
            .iter()
            .position(|n| n == "tblock")
            .unwrap() as ShapeId;
        let moved =
            world.shapes.pose[id as usize].translation - start.shapes.pose[id as usize].translation;
        let range = world.shapes.range(id);
        let fastest = world.particles.velocity[range]
            .iter()
            .map(|v| v.length())
            .fold(0.0, f32::max);
        assert!(moved.y > 0.01, "the T-block was pushed along +y: {moved:?}");
        assert!(fastest < 0.3, "the T-block moves at {fastest} m/s");
    }

    /// The robot is driven by the trajectory the tick brings: its pusher link ends the tick where
    /// forward kinematics of the trajectory at the tick's end puts it.
    #[test]
    fn the_robot_follows_the_joint_trajectory_its_ticks_bring() {
        let scene = crate::scene::tblock_and_robot().unwrap();
        let mut tracker = physics_only(scene);
        let (robot, _) = tracker.robot().unwrap();
        let model = robot.model.clone();
        let q0 = vec![0.0, -0.3, 0.0, -2.2, 0.0, 1.9, 0.785];
        let mut q1 = q0.clone();
        q1[0] = 0.4;
        let dt = tracker.physics().dt as f64;
        let t = tracker.time() + dt;
        let mut trajectory = JointTrajectory::default();
        trajectory.push(tracker.time(), q0);
        trajectory.push(t, q1.clone());
        let inputs = TickInputs {
            time: t,
            trajectory: Some(trajectory),
            ..Default::default()
        };
        tracker.tick(&inputs).unwrap();
        let (robot, followed) = tracker.robot().unwrap();
        assert_eq!(
            followed.at(t).unwrap(),
            q1,
            "the tick's trajectory is followed"
        );
        let link = model.link_index("panda_pusher").unwrap();
        let tip = (robot.base * model.forward_kinematics(&q1)[link])
            .transform_point3(DVec3::ZERO)
            .as_vec3();
        let shape = tracker.world().shape_id("robot/panda_pusher").unwrap();
        let pose = tracker.world().shapes.pose[shape as usize];
        assert!(
            pose.translation.distance(tip) < 1e-4,
            "{} vs {tip}",
            pose.translation
        );
    }

    /// The gain the node reports is the one the corrections take: the configured one on pegs's
    /// table, a third of it where the model's table is a third as slippery as `slippery_friction`.
    #[test]
    fn the_reported_gain_is_the_one_the_model_s_table_scales_to() {
        let mut config = crate::config::Config::default();
        let rough = Tracker::new(crate::scene::tabletop().unwrap(), &config, true).unwrap();
        assert_eq!(rough.visual_gain(), Some(config.correct.gain));
        config.physics.ground.kinetic_friction = config.correct.slippery_friction / 3.0;
        let slippery = Tracker::new(crate::scene::tabletop().unwrap(), &config, true).unwrap();
        let gain = slippery.visual_gain().unwrap();
        assert!((gain - config.correct.gain / 3.0).abs() < 1e-2, "{gain}");
        let off = Tracker::new(crate::scene::tabletop().unwrap(), &config, false).unwrap();
        assert_eq!(off.visual_gain(), None);
    }

    /// Correction runs while it is enabled, stops when a live change disables it and resumes when
    /// it is enabled again; each corrected tick compares with every image it was given.
    #[test]
    fn corrections_follow_the_live_setting() {
        let mut config = crate::config::Config::default();
        config.correct.iterations = 1;
        let scene = crate::scene::tabletop().unwrap();
        let mut tracker = Tracker::new(scene, &config, true).unwrap();
        let camera = Camera::look_at(32, 18, 30.0, Vec3::new(1.0, 0.0, 0.6), Vec3::ZERO);
        let dt = tracker.physics().dt as f64;
        let tick = |tracker: &mut Tracker| {
            let image = vec![vec![Vec3::splat(0.5); 32 * 18]];
            let inputs = TickInputs::with_images(tracker.time() + dt, &[camera], image);
            tracker.tick(&inputs).unwrap()
        };
        let on = tick(&mut tracker);
        assert!(on.correction.is_some() && on.cameras_used == 1);
        let mut off = config.correct.clone();
        off.enabled = false;
        tracker.set_correct(off);
        assert!(tick(&mut tracker).correction.is_none() && !tracker.corrects());
        tracker.set_correct(config.correct.clone());
        assert!(tick(&mut tracker).correction.is_some());
    }
}

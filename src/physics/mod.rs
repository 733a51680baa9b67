//! Predict: position-based dynamics (spec section 2). One `Solver::step` advances the world by one
//! tick of `substeps` substeps; each substep integrates gravity, external forces and effects, then
//! runs `iterations` Jacobi sweeps over ground, contacts, distance constraints and shape matching,
//! and finally derives velocities from positions. Velocities are damped once per tick. A shape put
//! into an overlap from outside (a relocation) can be settled for one tick (`Solver::settle`): its
//! speed is capped while the contacts push it out. What each shape touched in any substep is kept
//! in `TickStats::touched` (a strike can be over before the tick ends).
//!
//! The solver owns scratch buffers and the effect model bound to the world; the world itself stays
//! plain data. Nothing here renders or reads sensors.

mod collide;
mod config;
mod distance;
pub mod effects;
mod ground;
mod sdf;
mod shape_matching;
mod spatial_hash;
mod yielding;

pub use config::{CollisionConfig, GroundConfig, GroundPins, GroundSupport, PhysicsConfig};
pub use effects::Effect;
pub use ground::Plane;

use crate::math::Pose;
use crate::world::{Phase, ShapeId, ShapeKind, World};
use anyhow::Result;
use effects::{EffectModel, ShapeState};
use glam::{Quat, Vec3};
use rayon::prelude::*;
use spatial_hash::{NeighbourLists, SpatialHash};

/// Supplies kinematic shape poses within a tick. `tick_fraction` runs over (0, 1]; returning `None`
/// interpolates between the shape's pose at the start of the tick and its `target`.
pub trait KinematicDriver: Send {
    fn pose_at(&mut self, shape: ShapeId, tick_fraction: f32) -> Option<Pose>;
}

/// The default driver: linear/spherical interpolation towards `Shapes::target`.
pub struct InterpolateTargets;

impl KinematicDriver for InterpolateTargets {
    fn pose_at(&mut self, _: ShapeId, _: f32) -> Option<Pose> {
        None
    }
}

/// What the last tick did, for diagnostics and benchmarks.
#[derive(Clone, Debug, Default)]
pub struct TickStats {
    /// Candidate contact pairs in the last substep (ordered pairs).
    pub contact_candidates: usize,
    /// Per shape: number of its particles touching the ground at the end of the tick.
    pub ground_contacts: Vec<u32>,
    /// External forces ignored in the last tick because they were not finite.
    pub rejected_forces: usize,
    /// Kinematic poses ignored in the last tick because they were not finite (shape kept its pose).
    pub rejected_poses: usize,
    /// Per shape: the bodies it touched in any substep of the last tick. A hard strike can be
    /// over within a tick, the struck object gone from the striker by the tick's end.
    pub touched: Vec<Touched>,
}

/// Which kinds of body a shape touched (within `TOUCH_SLACK`) during a tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Touched {
    /// A kinematic body: the robot, or a scripted pusher.
    pub kinematic: bool,
    /// Another dynamic shape.
    pub dynamic: bool,
}

impl Touched {
    /// Both ticks' touches (for ticks reported as one).
    pub fn or(self, other: Touched) -> Touched {
        Touched {
            kinematic: self.kinematic || other.kinematic,
            dynamic: self.dynamic || other.dynamic,
        }
    }
}

/// Gap (m) between two particles' surfaces within which they count as touching.
pub const TOUCH_SLACK: f32 = 0.001;

pub struct Solver {
    config: PhysicsConfig,
    effects: EffectModel,
    /// Layout the effect model and masses were bound to (particle and shape counts).
    bound_to: (usize, usize),
    inv_mass: Vec<f32>,
    shape_mass: Vec<f32>,
    /// How each particle meets the ground (its radius, less `SUPPORT_RELIEF` where it does not
    /// bear on `Corners` support; the weight it bears).
    footing: ground::Footing,
    shape_velocity: Vec<Vec3>,
    /// Per shape: ground restitution, and the normal speed before this substep's contacts.
    restitution: Vec<f32>,
    normal_speed: Vec<f32>,
    prev: Vec<Vec3>,
    accel: Vec<Vec3>,
    delta: Vec<Vec3>,
    count: Vec<u32>,
    /// Particles held by something immovable in the current sweep: a kinematic or static body
    /// they touch, or the ground where static friction holds every contact of their shape.
    pinned: Vec<bool>,
    /// How each particle touches the ground in the current sweep.
    grip: Vec<ground::Grip>,
    hash: SpatialHash,
    neighbours: NeighbourLists,
    tick_start: Vec<Pose>,
    /// Each shape's pose at the start of the current substep (how far a solid's surface moved).
    substep_start: Vec<Pose>,
    /// Per particle, how much further than `r_i + r_j + margin` a pushable particle lists it as a
    /// contact candidate: a shape met as its exact solids (`Shapes::primitives`) has its surface a
    /// particle radius outside its particles, and between them.
    further: Vec<f32>,
    /// The largest of `further` (0: no shape is met as its solids).
    furthest: f32,
    /// Per particle, the mass a contact on it moves (`Yielding::body_mass`); empty where no shape
    /// gives way.
    body_mass: Vec<f32>,
    /// Per particle, in contact with a yielding shape in the current sweep; per shape, the share of
    /// its weight those carried at the last one (`yielding::contact_share`).
    soft: Vec<bool>,
    held_share: Vec<f32>,
    attachments: distance::LongRangeAttachments,
    /// Shapes whose speed the coming tick caps at `SETTLING_SPEED` (`settle`).
    settling: Vec<(ShapeId, f32)>,
    pub stats: TickStats,
}

/// Fastest (m/s) a settling shape's particles move: an overlap it was put into is pushed out in
/// position within a substep, which would otherwise leave it with the overlap's depth per substep
/// as speed (7 mm in 1.7 ms is 4 m/s). About a pusher's speed, so a pushed object keeps up.
pub const SETTLING_SPEED: f32 = 0.3;

impl Solver {
    /// A solver for `world` with `config` (validated; effects bound to the world's objects).
    pub fn new(config: PhysicsConfig, world: &World) -> Result<Self> {
        config.validate()?;
        let mut solver = Solver {
            effects: EffectModel::bind(&config.effects, world)?,
            config,
            bound_to: (usize::MAX, usize::MAX),
            inv_mass: Vec::new(),
            shape_mass: Vec::new(),
            footing: ground::Footing::default(),
            pinned: Vec::new(),
            grip: Vec::new(),
            shape_velocity: Vec::new(),
            restitution: Vec::new(),
            normal_speed: Vec::new(),
            prev: Vec::new(),
            accel: Vec::new(),
            delta: Vec::new(),
            count: Vec::new(),
            hash: SpatialHash::default(),
            neighbours: NeighbourLists::default(),
            tick_start: Vec::new(),
            substep_start: Vec::new(),
            body_mass: Vec::new(),
            soft: Vec::new(),
            held_share: Vec::new(),
            further: Vec::new(),
            furthest: 0.0,
            attachments: distance::LongRangeAttachments::default(),
            settling: Vec::new(),
            stats: TickStats::default(),
        };
        solver.bind(world)?;
        Ok(solver)
    }

    pub fn config(&self) -> &PhysicsConfig {
        &self.config
    }

    /// Replace the effects (e.g. after a diagnosis adds one) and rebind them to `world`.
    pub fn set_effects(&mut self, effects: Vec<Effect>, world: &World) -> Result<()> {
        let model = EffectModel::bind(&effects, world)?;
        self.effects = model;
        self.config.effects = effects;
        self.bind(world)
    }

    /// Effective inverse masses (nominal masses with mass effects applied).
    pub fn inv_mass(&self) -> &[f32] {
        &self.inv_mass
    }

    /// Recompute everything derived from the world's layout: effective masses, shape mass
    /// properties and scratch sizes. Called automatically when the layout changes.
    pub fn bind(&mut self, world: &World) -> Result<()> {
        let (n, ns) = (world.particles.len(), world.shapes.len());
        if self.bound_to.0 != n || self.bound_to.1 != ns {
            self.effects = EffectModel::bind(&self.config.effects, world)?;
        }
        self.inv_mass = self.effects.effective_inv_mass(world)?;
        self.shape_mass = (0..ns)
            .map(|s| {
                world
                    .shapes
                    .range(s as ShapeId)
                    .filter(|&i| self.inv_mass[i] > 0.0)
                    .map(|i| 1.0 / self.inv_mass[i])
                    .sum()
            })
            .collect();
        self.footing = self.ground_footing(world);
        self.shape_velocity = vec![Vec3::ZERO; ns];
        self.restitution = self.effects.restitution(ns);
        self.normal_speed = vec![0.0; ns];
        self.prev = vec![Vec3::ZERO; n];
        self.accel = vec![Vec3::ZERO; n];
        self.delta = vec![Vec3::ZERO; n];
        self.count = vec![0; n];
        self.pinned = vec![false; n];
        self.grip = vec![ground::Grip::Free; n];
        self.attachments = distance::LongRangeAttachments::build(world, &self.inv_mass);
        self.further = (0..n)
            .map(|i| {
                let s = world.particles.shape[i] as usize;
                match world
                    .shapes
                    .primitives
                    .get(s)
                    .is_some_and(|p| !p.is_empty())
                {
                    true => SOLID_REACH * world.particles.radius[i],
                    false => 0.0,
                }
            })
            .collect();
        self.furthest = self.further.iter().copied().fold(0.0, f32::max);
        self.body_mass = match world.shapes.compliance.iter().any(|&c| c > 0.0) {
            true => (0..n)
                .map(|i| {
                    let s = world.particles.shape[i] as usize;
                    match world.shapes.kind[s] {
                        ShapeKind::Rigid => self.shape_mass[s],
                        _ if self.inv_mass[i] > 0.0 => 1.0 / self.inv_mass[i],
                        _ => 0.0,
                    }
                })
                .collect(),
            false => Vec::new(),
        };
        self.soft = vec![false; n];
        self.held_share = vec![1.0; ns];
        self.stats.ground_contacts = vec![0; ns];
        self.bound_to = (n, ns);
        Ok(())
    }

    /// Each particle's radius towards the ground and the particles' weight it bears there (at
    /// least 1): on `Corners` support the corners of a rigid shape (found in its rest frame, with
    /// the ground's normal as it stands at binding) bear its lowest layer's weight, and the rest
    /// reach `SUPPORT_RELIEF` less far.
    fn ground_footing(&self, world: &World) -> ground::Footing {
        let p = &world.particles;
        let (mut radius, mut load) = (p.radius.clone(), vec![1.0; p.len()]);
        if self.config.ground.support == GroundSupport::Face {
            return ground::Footing { radius, load };
        }
        let shapes = &world.shapes;
        for s in (0..shapes.len()).filter(|&s| shapes.kind[s] == ShapeKind::Rigid) {
            let range = shapes.range(s as ShapeId);
            let down = -(shapes.pose[s].rotation.inverse() * self.config.ground.normal);
            let bears =
                ground::bearing_loads(&p.rest[range.clone()], &p.radius[range.clone()], down);
            for (i, bears) in range.zip(bears) {
                if bears > 0.0 {
                    load[i] = bears.max(1.0);
                } else {
                    radius[i] -= ground::SUPPORT_RELIEF;
                }
            }
        }
        ground::Footing { radius, load }
    }

    /// For the coming tick, `shape` moves no faster than `SETTLING_SPEED`: it was put where it may
    /// overlap others (an object moved where the images show it, into a pusher whose model
    /// differs by millimetres from the real one), and the overlap is to be resolved in position
    /// without being turned into speed.
    pub fn settle(&mut self, shape: ShapeId) {
        self.settle_below(shape, SETTLING_SPEED);
    }

    /// As `settle`, at no more than `speed` (m/s; at least `SETTLING_SPEED`): an object moved
    /// while it was already moving keeps the speed it had.
    pub fn settle_below(&mut self, shape: ShapeId, speed: f32) {
        self.settling.push((shape, speed.max(SETTLING_SPEED)));
    }

    /// Advance one tick, kinematic shapes moving towards their targets.
    pub fn step(&mut self, world: &mut World) -> Result<()> {
        self.step_driven(world, &mut InterpolateTargets)
    }

    /// Advance one tick with kinematic poses from `driver` (e.g. forward kinematics per substep).
    pub fn step_driven(
        &mut self,
        world: &mut World,
        driver: &mut dyn KinematicDriver,
    ) -> Result<()> {
        if self.bound_to != (world.particles.len(), world.shapes.len()) {
            self.bind(world)?;
        }
        // Run the tick on a pool thread: the passes below are many small parallel loops, and from a
        // thread outside the pool each would be a cross-thread hand-off (measured: ~45 % of a
        // T-block + robot tick); from inside, loops too small to split simply run inline.
        rayon::scope(|_| self.run_substeps(world, driver));
        Ok(())
    }

    fn run_substeps(&mut self, world: &mut World, driver: &mut dyn KinematicDriver) {
        let substeps = self.config.substeps;
        let h = self.config.dt / substeps as f32;
        self.sanitise_inputs(world);
        self.tick_start.clone_from(&world.shapes.pose);
        self.stats.touched.clear();
        self.stats
            .touched
            .resize(world.shapes.len(), Touched::default());
        for sub in 0..substeps {
            let fraction = (sub + 1) as f32 / substeps as f32;
            self.place_kinematic(world, driver, fraction);
            self.integrate(world, h);
            self.record_normal_speeds(world);
            if self.config.collisions.enabled {
                self.find_contacts(world);
            }
            for iteration in 0..self.config.iterations {
                self.solve_constraints(world, iteration);
            }
            if self.config.collisions.enabled && self.neighbours.pair_count() > 0 {
                collide::note_touches(&world.particles, &self.neighbours, &mut self.stats.touched);
            }
            self.update_velocities(world, h);
            self.bounce(world, h);
        }
        self.finish_tick(world);
        world.time += self.config.dt as f64;
    }

    /// Inputs from outside the physics (visual forces, prescribed poses) must not poison the state:
    /// a non-finite force is dropped and a non-finite target keeps the shape where it is. Both are
    /// counted in `stats` so callers can report them.
    fn sanitise_inputs(&mut self, world: &mut World) {
        self.stats.rejected_forces = 0;
        for f in &mut world.particles.external_force {
            if !f.is_finite() {
                *f = Vec3::ZERO;
                self.stats.rejected_forces += 1;
            }
        }
        self.stats.rejected_poses = 0;
        let shapes = &mut world.shapes;
        for s in 0..shapes.len() {
            let t = shapes.target[s];
            if shapes.kind[s] == ShapeKind::Kinematic
                && !(t.translation.is_finite() && t.rotation.is_finite())
            {
                shapes.target[s] = shapes.pose[s];
                self.stats.rejected_poses += 1;
            }
        }
    }

    fn place_kinematic(
        &mut self,
        world: &mut World,
        driver: &mut dyn KinematicDriver,
        fraction: f32,
    ) {
        self.substep_start.clone_from(&world.shapes.pose);
        for s in 0..world.shapes.len() {
            if world.shapes.kind[s] != ShapeKind::Kinematic {
                continue;
            }
            let interpolated = || self.tick_start[s].interpolate(&world.shapes.target[s], fraction);
            let pose = match driver.pose_at(s as ShapeId, fraction) {
                Some(p) if p.translation.is_finite() && p.rotation.is_finite() => p,
                Some(_) => {
                    self.stats.rejected_poses += 1;
                    interpolated()
                }
                None => interpolated(),
            };
            world.shapes.pose[s] = pose;
            for i in world.shapes.range(s as ShapeId) {
                self.prev[i] = world.particles.position[i];
                world.particles.position[i] = pose.transform_point(world.particles.rest[i]);
            }
        }
    }

    /// v += h a; x* = x + h v for dynamic particles, with a = gravity + external force / m + effects.
    fn integrate(&mut self, world: &mut World, h: f32) {
        let gravity = self.config.gravity;
        let p = &mut world.particles;
        let inv_mass = &self.inv_mass;
        self.accel
            .par_iter_mut()
            .with_min_len(PAR_MIN)
            .enumerate()
            .for_each(|(i, a)| {
                *a = if inv_mass[i] > 0.0 {
                    gravity + p.external_force[i] * inv_mass[i]
                } else {
                    Vec3::ZERO
                };
            });
        if !self.effects.is_empty() {
            for s in 0..world.shapes.len() {
                self.shape_velocity[s] = crate::world::mass_weighted_mean(
                    world.shapes.range(s as ShapeId),
                    &world.particles.velocity,
                    inv_mass,
                );
            }
            let state = ShapeState {
                mass: &self.shape_mass,
                velocity: &self.shape_velocity,
            };
            self.effects.add_accelerations(
                world,
                inv_mass,
                &state,
                gravity,
                self.config.ground.normal,
                &mut self.accel,
            );
        }
        let p = &mut world.particles;
        let accel = &self.accel;
        p.position
            .par_iter_mut()
            .zip(p.velocity.par_iter_mut())
            .zip(self.prev.par_iter_mut())
            .with_min_len(PAR_MIN)
            .enumerate()
            .for_each(|(i, ((x, v), prev))| {
                if inv_mass[i] > 0.0 {
                    *prev = *x;
                    *v += h * accel[i];
                    *x += h * *v;
                } else if p.phase[i] == Phase::Static {
                    *prev = *x;
                }
            });
    }

    fn find_contacts(&mut self, world: &World) {
        let p = &world.particles;
        let max_radius = p.radius.iter().copied().fold(0.0f32, f32::max);
        let margin = self.config.collisions.margin * max_radius;
        // Only particles within reach of one that can be pushed can be a contact partner: the
        // rest (most of a robot, far from the objects) stay out of the hash.
        let reach = 2.0 * max_radius + margin + self.furthest;
        let pushed = (0..p.len()).filter(|&i| self.inv_mass[i] > 0.0);
        let (lo, hi) = pushed.fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), i| {
            (lo.min(p.position[i]), hi.max(p.position[i]))
        });
        let slack = Vec3::splat(1.5 * reach);
        self.hash
            .build_within(&p.position, reach, (lo - slack, hi + slack));
        spatial_hash::find_neighbours(
            &self.hash,
            &p.position,
            &p.radius,
            &p.shape,
            &self.inv_mass,
            (
                margin,
                if self.furthest > 0.0 {
                    &self.further
                } else {
                    &[]
                },
            ),
            &mut self.neighbours,
        );
        self.stats.contact_candidates = self.neighbours.pair_count();
    }

    /// One Jacobi sweep: each group's corrections are averaged per particle and applied before the
    /// next group, ending with shape matching so rigid shapes leave every sweep rigid.
    fn solve_constraints(&mut self, world: &mut World, iteration: u32) {
        let cfg = &self.config;
        let p = &mut world.particles;
        self.pinned.fill(false);
        self.grip.fill(ground::Grip::Free);
        if cfg.ground.enabled {
            let plane = Plane {
                normal: cfg.ground.normal,
                height: cfg.ground.height,
            };
            let base = (cfg.ground.static_friction, cfg.ground.kinetic_friction);
            let effects = &self.effects;
            if effects.has_friction_patches() {
                ground::project_ground(
                    &mut p.position,
                    &self.prev,
                    &self.footing,
                    &self.inv_mass,
                    plane,
                    &|x| effects.ground_friction(x, base),
                    &mut self.grip,
                );
            } else {
                ground::project_ground(
                    &mut p.position,
                    &self.prev,
                    &self.footing,
                    &self.inv_mass,
                    plane,
                    &|_| base,
                    &mut self.grip,
                );
            }
        }
        if cfg.collisions.enabled && self.neighbours.pair_count() > 0 {
            let c = &cfg.collisions;
            collide::collision_corrections(
                &p.position,
                &self.prev,
                &self.inv_mass,
                &p.radius,
                match self.furthest > 0.0 {
                    true => collide::Solids {
                        shape: &p.shape,
                        primitives: &world.shapes.primitives,
                        now: &world.shapes.pose,
                        before: &self.substep_start,
                    },
                    // Nothing met as a solid: no per-pair lookups in the hot loop.
                    false => collide::Solids::NONE,
                },
                match self.body_mass.is_empty() {
                    true => yielding::Yielding::NONE,
                    false => yielding::Yielding {
                        shape: &p.shape,
                        compliance: &world.shapes.compliance,
                        body_mass: &self.body_mass,
                        held_share: &self.held_share,
                        h2: (cfg.dt / cfg.substeps as f32).powi(2),
                        iterations: cfg.iterations,
                    },
                },
                &self.neighbours,
                c.static_friction,
                c.kinetic_friction,
                &mut self.delta,
                &mut self.count,
                (&mut self.pinned, &mut self.soft),
            );
            collide::apply_averaged(&mut p.position, &self.delta, &self.count, cfg.relaxation);
        }
        if !world.distance.is_empty() {
            let sweeps = cfg.distance_sweeps;
            for sweep in 0..sweeps {
                distance::project_distances(
                    &world.distance,
                    &mut p.position,
                    &self.inv_mass,
                    (iteration * sweeps + sweep) % 2 == 1,
                );
                self.attachments.project(&mut p.position);
            }
        }
        self.pin_shapes_held_by_the_ground(world);
        if !self.body_mass.is_empty() {
            yielding::contact_share(
                (0..world.shapes.len()).map(|s| world.shapes.range(s as ShapeId)),
                &self.inv_mass,
                &self.pinned,
                &self.soft,
                self.config.pin_weight,
                &mut self.held_share,
            );
        }
        self.match_rigid_shapes(world);
    }

    /// Ground contacts held by static friction are pinned in shape matching, so forces below
    /// static friction (a tilt, a corrective force) do not creep a shape: every one of them, or
    /// with `GroundPins::WholeShape` only those of a shape whose every contact sticks (where some
    /// slide, as in a spin or a push that turns it, a pinned contact would outweigh the sliding
    /// ones' friction in the fit and halve the friction torque).
    fn pin_shapes_held_by_the_ground(&mut self, world: &World) {
        let shapes = &world.shapes;
        let whole = self.config.ground_pins == GroundPins::WholeShape;
        for s in 0..shapes.len() {
            let range = shapes.range(s as ShapeId);
            let grip = &self.grip[range.clone()];
            if whole && grip.contains(&ground::Grip::Slips) {
                continue;
            }
            for (pinned, grip) in self.pinned[range].iter_mut().zip(grip) {
                *pinned |= *grip == ground::Grip::Sticks;
            }
        }
    }

    fn match_rigid_shapes(&mut self, world: &mut World) {
        let shapes = &world.shapes;
        let stiffness = self.config.shape_stiffness;
        let pin_weight = self.config.pin_weight;
        // Split the position array into each rigid shape's own slice so shapes run in parallel.
        let mut jobs: Vec<(usize, &mut [Vec3])> = Vec::new();
        let mut rest_of: &mut [Vec3] = &mut world.particles.position;
        let mut offset = 0;
        for s in 0..shapes.len() {
            if shapes.kind[s] != ShapeKind::Rigid || self.shape_mass[s] <= 0.0 {
                continue;
            }
            let range = shapes.range(s as ShapeId);
            let (_, tail) = std::mem::take(&mut rest_of).split_at_mut(range.start - offset);
            let (mine, tail) = tail.split_at_mut(range.len());
            jobs.push((s, mine));
            rest_of = tail;
            offset = range.end;
        }
        let rest = &world.particles.rest;
        let inv_mass = &self.inv_mass;
        let pinned = &self.pinned;
        let poses = &world.shapes.pose;
        let results: Vec<(usize, Pose)> = jobs
            .into_par_iter()
            .map(|(s, pos)| {
                let range = shapes.range(s as ShapeId);
                let mut rotation: Quat = poses[s].rotation;
                let (centroid, rest_centroid) = shape_matching::match_shape(
                    pos,
                    &rest[range.clone()],
                    &inv_mass[range.clone()],
                    &pinned[range],
                    pin_weight,
                    &mut rotation,
                    stiffness,
                );
                (s, Pose::new(centroid - rotation * rest_centroid, rotation))
            })
            .collect();
        for (s, pose) in results {
            world.shapes.pose[s] = pose;
        }
    }

    fn update_velocities(&mut self, world: &mut World, h: f32) {
        let p = &mut world.particles;
        let prev = &self.prev;
        p.velocity
            .par_iter_mut()
            .zip(p.position.par_iter())
            .with_min_len(PAR_MIN)
            .enumerate()
            .for_each(|(i, (v, x))| {
                *v = (*x - prev[i]) / h;
            });
        for &(s, speed) in &self.settling {
            for i in world.shapes.range(s) {
                let v = &mut world.particles.velocity[i];
                *v = v.clamp_length_max(speed);
            }
        }
    }

    /// Before contacts are solved: each bouncing shape's speed along the ground normal.
    fn record_normal_speeds(&mut self, world: &World) {
        let n = self.config.ground.normal;
        for s in (0..world.shapes.len()).filter(|&s| self.restitution[s] > 0.0) {
            self.normal_speed[s] = n.dot(crate::world::mass_weighted_mean(
                world.shapes.range(s as ShapeId),
                &world.particles.velocity,
                &self.inv_mass,
            ));
        }
    }

    /// Ground restitution at shape level: a shape that struck the ground in this substep leaves
    /// it at `e` times the normal speed it came in with. Slower impacts (about what gravity adds
    /// in two substeps) are resting contact and do not bounce.
    fn bounce(&mut self, world: &mut World, h: f32) {
        if !self.config.ground.enabled {
            return;
        }
        let (n, height) = (self.config.ground.normal, self.config.ground.height);
        let resting = 2.0 * self.config.gravity.length() * h;
        for s in (0..world.shapes.len()).filter(|&s| self.restitution[s] > 0.0) {
            let range = world.shapes.range(s as ShapeId);
            let p = &world.particles;
            let touching = range
                .clone()
                .any(|i| n.dot(p.position[i]) - height <= p.radius[i] * 1.01);
            let incoming = self.normal_speed[s];
            if !touching || incoming > -resting {
                continue;
            }
            let outgoing = n.dot(crate::world::mass_weighted_mean(
                range.clone(),
                &p.velocity,
                &self.inv_mass,
            ));
            let kick = -self.restitution[s] * incoming - outgoing;
            if kick > 0.0 {
                range.for_each(|i| world.particles.velocity[i] += kick * n);
            }
        }
    }

    fn finish_tick(&mut self, world: &mut World) {
        self.settling.clear();
        let damping = self.config.damping;
        let p = &mut world.particles;
        for i in 0..p.len() {
            if p.phase[i] == Phase::Dynamic {
                p.velocity[i] *= damping;
            }
            p.external_force[i] = Vec3::ZERO;
        }
        let plane_normal = self.config.ground.normal;
        let height = self.config.ground.height;
        for s in 0..world.shapes.len() {
            let range = world.shapes.range(s as ShapeId);
            if world.shapes.kind[s] == ShapeKind::Rope {
                world.shapes.pose[s] = Pose::from_translation(world.shape_centroid(s as ShapeId));
            }
            self.stats.ground_contacts[s] = if self.config.ground.enabled {
                let p = &world.particles;
                range
                    .filter(|&i| plane_normal.dot(p.position[i]) - height <= p.radius[i] * 1.01)
                    .count() as u32
            } else {
                0
            };
        }
    }
}

/// How much further (in its radii) a particle of a shape met as its solids is listed as a contact
/// candidate: its solid's surface lies a radius outside it, and up to half a diagonal of the
/// sampling between it and the next (at 0.5, the default margin, a bar pushed end-on by the
/// rod met it 3 mm deep at once, and was thrown).
const SOLID_REACH: f32 = 1.5;

/// Smallest number of particles a cheap per-particle loop hands to one thread.
const PAR_MIN: usize = 8192;

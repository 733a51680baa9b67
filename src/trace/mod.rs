//! What a replay keeps of its run for the diagnosis: the tracked state after every tick, the
//! robot's recorded trajectory and the residuals (`residuals`: each object's state, contacts and
//! corrective wrench per tick). The physics can be rerun open loop from any tracked state: start
//! from the state at `t`, let the physics alone (with or without an extra effect) predict the next
//! second, and compare with where tracking found the object. It records and predicts; it never
//! corrects and never judges.

pub mod residuals;

pub use residuals::Sample;

use crate::math::Pose;
use crate::physics::PhysicsConfig;
use crate::physics::Solver;
use crate::robot::{JointTrajectory, RobotInWorld};
use crate::scene::Scene;
use crate::tracker::{Observer, Tick, Tracker};
use crate::world::{ShapeId, World};
use anyhow::{Context, Result};
use glam::Vec3;
use rayon::prelude::*;

/// Ticks either side of a state used to difference its velocity.
pub const VELOCITY_SPAN: usize = 2;

/// The dynamic part of a world after one tick.
#[derive(Clone, Debug, Default)]
pub struct State {
    pub time: f64,
    pub position: Vec<Vec3>,
    pub velocity: Vec<Vec3>,
    pub pose: Vec<Pose>,
}

impl State {
    pub fn of(world: &World) -> Self {
        Self {
            time: world.time,
            position: world.particles.position.clone(),
            velocity: world.particles.velocity.clone(),
            pose: world.shapes.pose.clone(),
        }
    }
}

/// A replay's world layout, the physics it ran, the robot with its recorded motion, the tracked
/// state after every tick (`states[0]` is the initial state) and the residuals of every object
/// per tick.
#[derive(Clone, Debug, Default)]
pub struct Trace {
    pub base: World,
    pub physics: PhysicsConfig,
    pub robot: Option<(RobotInWorld, JointTrajectory)>,
    pub states: Vec<State>,
    pub samples: Vec<Sample>,
    /// Objects the tracker moved to where the images showed them (`tracker::Change::Relocated`):
    /// something outside the model moved them, so no prediction spanning the jump is physics.
    pub jumps: Vec<Jump>,
}

/// An object relocated at the end of the tick that left `state` (an index into `states`).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Jump {
    pub object: String,
    #[serde(skip)]
    pub shape: ShapeId,
    #[serde(skip)]
    pub state: usize,
    pub time: f64,
    pub jump_m: f32,
}

/// Keeps a trace of a tracking run, as an observer of its ticks: the world and physics at the
/// start, the tracked state after every tick, and the robot's trajectory as recorded (every joint
/// sample the ticks received; the scene's own trajectory if none came).
#[derive(Default)]
pub struct Recorder {
    trace: Trace,
    recorded: JointTrajectory,
}

impl Observer for Recorder {
    fn start(&mut self, tracker: &Tracker) -> Result<()> {
        let world = tracker.world();
        self.trace = Trace {
            base: world.clone(),
            physics: tracker.physics().clone(),
            robot: tracker.robot().map(|(r, t)| (r.clone(), t.clone())),
            states: vec![State::of(world)],
            samples: Vec::new(),
            jumps: Vec::new(),
        };
        Ok(())
    }

    fn tick(&mut self, tick: &Tick) -> Result<()> {
        let world = tick.tracker.world();
        self.trace.states.push(State::of(world));
        for e in &tick.report.track_events {
            if let crate::tracker::Change::Relocated { jump_m, .. } = e.change {
                self.trace.jumps.push(Jump {
                    object: world.shapes.name[e.shape as usize].clone(),
                    shape: e.shape,
                    state: self.trace.states.len() - 1,
                    time: e.time,
                    jump_m,
                });
            }
        }
        for (t, q) in &tick.inputs.joint_samples {
            self.recorded.push(*t, q.clone());
        }
        Ok(())
    }
}

impl Recorder {
    /// The trace, with the residuals logged over the same run.
    pub fn finish(self, samples: Vec<Sample>) -> Trace {
        let mut trace = self.trace;
        if let Some((_, trajectory)) = &mut trace.robot
            && !self.recorded.is_empty()
        {
            *trajectory = self.recorded;
        }
        trace.samples = samples;
        trace
    }
}

/// An open-loop prediction from one tracked state.
#[derive(Clone, Debug)]
pub struct Prediction {
    pub start: usize,
    /// Mean distance (m) between the object's predicted and tracked particles at the horizon.
    pub error: f32,
    /// The object's predicted centre of mass per tick, start included.
    pub path: Vec<Vec3>,
}

impl Trace {
    pub fn dt(&self) -> f64 {
        self.physics.dt as f64
    }

    /// Whether `object` was relocated between states `from` and `to` (a prediction from `from`
    /// to `to` would compare the physics with a jump it cannot make).
    pub fn jumps_between(&self, object: ShapeId, from: usize, to: usize) -> bool {
        self.jumps
            .iter()
            .any(|j| j.shape == object && j.state > from && j.state <= to)
    }

    /// The world as tracked at state `k`, with no visual forces pending. Velocities are central
    /// differences of the tracked positions over `VELOCITY_SPAN` ticks each way: the tracker's
    /// own particle velocities carry the visual forces' kicks, which on a slippery table would
    /// send an open-loop prediction far off.
    pub fn world_at(&self, k: usize) -> World {
        let mut world = self.base.clone();
        let s = &self.states[k];
        world.time = s.time;
        world.particles.position.clone_from(&s.position);
        let (a, b) = (
            k.saturating_sub(VELOCITY_SPAN),
            (k + VELOCITY_SPAN).min(self.states.len() - 1),
        );
        let span = (self.states[b].time - self.states[a].time) as f32;
        world.particles.velocity = if span > 0.0 {
            self.states[b]
                .position
                .iter()
                .zip(&self.states[a].position)
                .map(|(p, q)| (*p - *q) / span)
                .collect()
        } else {
            s.velocity.clone()
        };
        world.shapes.pose.clone_from(&s.pose);
        world.shapes.target.clone_from(&s.pose);
        world
            .particles
            .external_force
            .iter_mut()
            .for_each(|f| *f = Vec3::ZERO);
        world
    }

    /// Tracked centre of mass of `object` at state `k`.
    pub fn centroid(&self, object: ShapeId, k: usize) -> Vec3 {
        let range = self.base.shapes.range(object);
        let n = range.len().max(1) as f32;
        self.states[k].position[range].iter().copied().sum::<Vec3>() / n
    }

    /// Predict `horizon` ticks from each state in `starts` with `physics` alone and measure the
    /// error against the tracked states. A prediction the physics refuses (a parameter that makes
    /// no sense) is an error.
    pub fn predict(
        &self,
        physics: &PhysicsConfig,
        object: ShapeId,
        starts: &[usize],
        horizon: usize,
    ) -> Result<Vec<Prediction>> {
        starts
            .par_iter()
            .map(|&start| {
                let end = (start + horizon).min(self.states.len() - 1);
                let world = self.world_at(start);
                let mut solver = Solver::new(physics.clone(), &world)?;
                let mut scene = Scene {
                    world,
                    scripts: Vec::new(),
                    robot: self.robot.clone(),
                };
                let range = self.base.shapes.range(object);
                let n = range.len().max(1) as f32;
                let mut path = vec![self.centroid(object, start)];
                for _ in start..end {
                    scene.advance(&mut solver)?;
                    path.push(
                        scene.world.particles.position[range.clone()]
                            .iter()
                            .copied()
                            .sum::<Vec3>()
                            / n,
                    );
                }
                let tracked = &self.states[end].position[range.clone()];
                let error = scene.world.particles.position[range]
                    .iter()
                    .zip(tracked)
                    .map(|(p, q)| p.distance(*q))
                    .sum::<f32>()
                    / n;
                Ok(Prediction { start, error, path })
            })
            .collect::<Result<Vec<_>>>()
            .context("open-loop prediction")
    }
}

/// Traces made by the physics itself, for tests of what reads traces.
#[cfg(test)]
impl Trace {
    /// `world` stepped `ticks` times by `truth`, shape `kicked` set to velocity `kick(k)` before
    /// tick k where that is Some, traced as a run of `physics` (the model, which may lack what
    /// `truth` has).
    pub(crate) fn simulated(
        mut world: World,
        physics: PhysicsConfig,
        truth: PhysicsConfig,
        ticks: usize,
        kicked: ShapeId,
        kick: impl Fn(usize) -> Option<Vec3>,
    ) -> Trace {
        let mut trace = Trace {
            base: world.clone(),
            physics,
            robot: None,
            states: vec![State::of(&world)],
            samples: Vec::new(),
            jumps: Vec::new(),
        };
        let mut solver = Solver::new(truth, &world).unwrap();
        for k in 0..ticks {
            if let Some(v) = kick(k) {
                let range = world.shapes.range(kicked);
                world.particles.velocity[range].fill(v);
            }
            solver.step(&mut world).unwrap();
            trace.states.push(State::of(&world));
        }
        trace
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{WorldBuilder, box_lattice};

    /// A box sliding on the ground, traced by the physics itself: open-loop predictions with the
    /// same physics reproduce the trace; with extra drag they fall short.
    #[test]
    fn open_loop_reproduces_its_own_physics_and_sees_a_missing_drag() {
        let mut b = WorldBuilder::new();
        let s = b.add_rigid(
            "box",
            &box_lattice(Vec3::new(0.03, 0.02, 0.01), 0.01),
            0.005,
            0.001,
            Pose::from_translation(Vec3::new(0.0, 0.0, 0.015)),
            Vec3::ONE,
        );
        let world = b.build();
        let mut physics = PhysicsConfig::default();
        physics.ground.static_friction = 0.04;
        physics.ground.kinetic_friction = 0.03;
        let kick = |k| (k == 0).then_some(Vec3::new(0.4, 0.0, 0.0));
        let trace = Trace::simulated(world, physics.clone(), physics.clone(), 45, s, kick);
        // From states inside the trace (velocities centrally differenced) the replay is exact up
        // to the difference's error.
        let same = trace.predict(&physics, s, &[3, 8], 30).unwrap();
        assert!(
            same.iter().all(|p| p.error < 2e-3 && p.path.len() == 31),
            "{:?}",
            same.iter().map(|p| p.error).collect::<Vec<_>>()
        );
        let mut dragged = physics.clone();
        dragged.effects = vec![crate::physics::Effect::ViscousDrag(
            crate::physics::effects::ViscousDrag {
                object: None,
                coefficient: 0.1,
            },
        )];
        let short = trace.predict(&dragged, s, &[3], 30).unwrap();
        // The drag shortens the slide: the prediction ends behind the traced box.
        assert!(
            short[0].error > 0.01 && short[0].path[30].x < trace.centroid(s, 33).x - 0.01,
            "{}",
            short[0].error
        );
    }
}

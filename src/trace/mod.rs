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
use crate::world::{ShapeId, ShapeKind, World};
use anyhow::{Context, Result};
use glam::{DMat3, DVec3, Vec3};
use rayon::prelude::*;

/// Ticks either side of a state whose tracked positions' difference gives its velocity where its
/// object's track is smooth: a kink in the motion (a slide reaching a grippy patch or coming to
/// rest) blurs into the velocities of this many states either side.
pub const VELOCITY_SPAN: usize = 2;

/// The span where the object's track rings about its motion (`Trace::velocity_spans`), over which
/// a parabola is fitted (`velocity_weights`): a ring of
/// 10 ticks (the pose pull's in a fast slide) passes 0.76 of its speed into a velocity over two
/// ticks each way, 0.22 into one over five.
pub const ROUGH_VELOCITY_SPAN: usize = 5;

/// Median distance (m, RMS) of a moving object's tracked centroid from a parabola over
/// `ROUGH_VELOCITY_SPAN` ticks each way above which its track counts as ringing. A slide whose
/// braking changes by 1 m/s^2 (friction by 0.1) leaves 0.9 mm at the kink and nothing elsewhere;
/// a ring of amplitude A leaves 0.24 A to 0.51 A at every state.
pub const ROUGH_TRACK_M: f64 = 1.5e-3;

/// Speed (m/s) above which an object counts as moving for `ROUGH_TRACK_M`.
const MOVING_M_PER_S: f64 = 0.05;

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
    /// Velocity spans chosen on another trace of the same recording and kept here
    /// (`keep_velocity_spans`); `None`: chosen on this trace's own tracks.
    pub kept_spans: Option<Vec<usize>>,
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
            kept_spans: None,
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

/// The inverse normal matrix of a least-squares parabola (in time) through samples at `times`;
/// `None` for fewer than three distinct times.
fn parabola_normal_inverse(times: &[f64]) -> Option<DMat3> {
    let normal = times.iter().fold(DMat3::ZERO, |m, &t| {
        let r = parabola_row(t);
        m + DMat3::from_cols(r * r.x, r * r.y, r * r.z)
    });
    (times.len() >= 3 && normal.determinant().abs() >= 1e-18).then(|| normal.inverse())
}

fn parabola_row(t: f64) -> DVec3 {
    DVec3::new(1.0, t, t * t)
}

/// Weights that turn positions sampled at `times` (s, relative to the state whose velocity is
/// wanted) into the slope at 0 of the least-squares parabola through them: exact for a constant
/// acceleration (a slide braked by friction) whether the samples lie either side or one side (the
/// trace's ends, a relocation); on a symmetric span, the least-squares line's slope. `None` for
/// fewer than three distinct times.
pub fn velocity_weights(times: &[f64]) -> Option<Vec<f64>> {
    let slope = parabola_normal_inverse(times)?.row(1);
    Some(times.iter().map(|&t| slope.dot(parabola_row(t))).collect())
}

/// The RMS distance (m) of `points`, sampled at `times`, from the least-squares parabola through
/// them; `None` where no parabola is fitted (`velocity_weights`).
fn parabola_misfit(times: &[f64], points: &[Vec3]) -> Option<f64> {
    let inverse = parabola_normal_inverse(times)?;
    // Columns: each axis's moments, then its parabola's coefficients.
    let moments = times.iter().zip(points).fold(DMat3::ZERO, |m, (&t, p)| {
        let r = parabola_row(t);
        let p = p.as_dvec3();
        m + DMat3::from_cols(r * p.x, r * p.y, r * p.z)
    });
    let along = (inverse * moments).transpose();
    let squares: f64 = times
        .iter()
        .zip(points)
        .map(|(&t, p)| (along * parabola_row(t) - p.as_dvec3()).length_squared())
        .sum();
    Some((squares / times.len() as f64).sqrt())
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

    /// The world as tracked at state `k`, with no visual forces pending. Velocities come from each
    /// object's tracked positions over its `velocity_spans` ticks each way, cut at its relocations
    /// (a fit across a jump would read it as motion): their difference across a smooth track's
    /// span, the slope at `k` of a parabola fitted over a ringing one's. The tracker's own
    /// particle velocities carry the visual forces' kicks, which on a slippery table would send
    /// an open-loop prediction far off.
    pub fn world_at(&self, k: usize) -> World {
        self.world_with_spans_at(k, &self.velocity_spans())
    }

    fn world_with_spans_at(&self, k: usize, spans: &[usize]) -> World {
        let mut world = self.base.clone();
        let s = &self.states[k];
        world.time = s.time;
        world.particles.position.clone_from(&s.position);
        world.particles.velocity.clone_from(&s.velocity);
        let last = self.states.len() - 1;
        for (shape, &span) in (0..).zip(spans) {
            let (a, b) = self.unbroken(shape, k, (k.saturating_sub(span), (k + span).min(last)));
            let range = self.base.shapes.range(shape);
            if span < ROUGH_VELOCITY_SPAN {
                // A smooth track: the difference across the span.
                let duration = (self.states[b].time - self.states[a].time) as f32;
                if duration > 0.0 {
                    for i in range {
                        world.particles.velocity[i] =
                            (self.states[b].position[i] - self.states[a].position[i]) / duration;
                    }
                }
                continue;
            }
            let times: Vec<f64> = (a..=b).map(|j| self.states[j].time - s.time).collect();
            if let Some(w) = velocity_weights(&times) {
                for i in range {
                    world.particles.velocity[i] = (a..=b)
                        .zip(&w)
                        .map(|(j, w)| self.states[j].position[i] * *w as f32)
                        .sum();
                }
            }
        }
        world.shapes.pose.clone_from(&s.pose);
        world.shapes.target.clone_from(&s.pose);
        world
            .particles
            .external_force
            .iter_mut()
            .for_each(|f| *f = Vec3::ZERO);
        world
    }

    /// Per shape, the ticks either side of a state over which its velocity is fitted:
    /// `ROUGH_VELOCITY_SPAN` where a tracked object's track rings while it moves (`roughness`
    /// above `ROUGH_TRACK_M`), else `VELOCITY_SPAN`, which keeps kinks in the motion sharp.
    /// Robot links and pushers follow their recorded joints, which do not ring: a fast turn of the
    /// hand reads as 2 mm of misfit, and fitting it wide blunts the pushes the diagnosis replays.
    pub fn velocity_spans(&self) -> Vec<usize> {
        if let Some(kept) = &self.kept_spans {
            return kept.clone();
        }
        (0..self.base.shapes.len() as ShapeId)
            .map(|object| {
                let tracked = matches!(
                    self.base.shapes.kind[object as usize],
                    ShapeKind::Rigid | ShapeKind::Rope
                );
                // Robot links' roughness is never computed: it decides nothing.
                let rings = tracked && self.roughness(object).is_some_and(|r| r > ROUGH_TRACK_M);
                if rings {
                    ROUGH_VELOCITY_SPAN
                } else {
                    VELOCITY_SPAN
                }
            })
            .collect()
    }

    /// Start this trace's predictions from velocities fitted over `spans` (one per shape), as
    /// chosen on another replay of the same recording: a diagnosis compares and refines
    /// predictions on replays tracked with different models, and a model that fights the images
    /// can make a track ring that did not (concealed_weight's box: 1.0 mm, 1.8 mm tracked with the
    /// named weight); a change of estimator between them would be read as the model's doing.
    /// Ignored unless there is one span per shape.
    pub fn keep_velocity_spans(&mut self, spans: Vec<usize>) {
        if spans.len() == self.base.shapes.len() {
            self.kept_spans = Some(spans);
        }
    }

    /// The median, over the states where `object` moves, of its tracked centroid's RMS distance
    /// (m) from a parabola over `ROUGH_VELOCITY_SPAN` ticks each way (spans no relocation
    /// breaks); `None` where it never moves over such a span. Kinks in a slide touch a few
    /// states; a ring touches every state of the slide.
    pub fn roughness(&self, object: ShapeId) -> Option<f64> {
        let n = ROUGH_VELOCITY_SPAN;
        let path: Vec<Vec3> = (0..self.states.len())
            .map(|k| self.centroid(object, k))
            .collect();
        let mut misfits: Vec<f64> = (n..self.states.len().saturating_sub(n))
            .filter(|&k| !self.jumps_between(object, k - n, k + n))
            .filter_map(|k| {
                let times: Vec<f64> = (k - n..=k + n)
                    .map(|j| self.states[j].time - self.states[k].time)
                    .collect();
                let points = &path[k - n..=k + n];
                let w = velocity_weights(&times)?;
                let velocity: Vec3 = points.iter().zip(&w).map(|(p, w)| *p * *w as f32).sum();
                (velocity.length() as f64 > MOVING_M_PER_S).then_some(())?;
                parabola_misfit(&times, points)
            })
            .collect();
        misfits.sort_by(f64::total_cmp);
        misfits.get(misfits.len() / 2).copied()
    }

    /// The states `a..=b` around `k` that no relocation of `object` separates from `k`.
    fn unbroken(
        &self,
        object: ShapeId,
        k: usize,
        (mut a, mut b): (usize, usize),
    ) -> (usize, usize) {
        for j in self.jumps.iter().filter(|j| j.shape == object) {
            if j.state <= k {
                a = a.max(j.state);
            } else {
                b = b.min(j.state - 1);
            }
        }
        (a, b)
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
        let spans = self.velocity_spans();
        starts
            .par_iter()
            .map(|&start| {
                let end = (start + horizon).min(self.states.len() - 1);
                let world = self.world_with_spans_at(start, &spans);
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
            kept_spans: None,
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

    /// A 6 x 4 x 2 cm box on a table of the given (static, kinetic) friction, struck along x at
    /// `speed` (m/s) and traced by the physics itself for 45 ticks.
    fn struck_box(
        static_friction: f32,
        kinetic_friction: f32,
        speed: f32,
    ) -> (Trace, ShapeId, PhysicsConfig) {
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
        physics.ground.static_friction = static_friction;
        physics.ground.kinetic_friction = kinetic_friction;
        let kick = |k| (k == 0).then_some(Vec3::new(speed, 0.0, 0.0));
        let trace = Trace::simulated(world, physics.clone(), physics.clone(), 45, s, kick);
        (trace, s, physics)
    }

    /// A box sliding on the ground, traced by the physics itself: open-loop predictions with the
    /// same physics reproduce the trace; with extra drag they fall short.
    #[test]
    fn open_loop_reproduces_its_own_physics_and_sees_a_missing_drag() {
        let (trace, s, physics) = struck_box(0.04, 0.03, 0.4);
        // From states inside the trace (velocities fitted to the tracked positions) the replay is
        // exact up to the fit's error.
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

    /// A box struck across a table that brakes it to rest: its track, made by the physics, is
    /// smooth but for the kink where it stops, so its velocities are fitted over
    /// `VELOCITY_SPAN`; the same track ringing 10 mm about its slide (as the pose pull rings on
    /// another engine's images) is fitted over `ROUGH_VELOCITY_SPAN`, unless a robot drives it or
    /// spans chosen on another replay are kept. A velocity is never fitted across a relocation: moved 10 cm sideways, the box's sideways velocity stays its own.
    #[test]
    fn a_ringing_track_is_fitted_wide_a_kink_narrow_and_no_fit_crosses_a_relocation() {
        let (smooth, s, _) = struck_box(0.12, 0.1, 0.8);
        let moving = |trace: &Trace| {
            (1..trace.states.len())
                .filter(|&k| trace.centroid(s, k).x - trace.centroid(s, k - 1).x > 1e-3)
                .count()
        };
        assert!(moving(&smooth) >= 20, "{} ticks of slide", moving(&smooth));
        let rough = smooth.roughness(s).unwrap();
        assert!(rough < 0.3 * ROUGH_TRACK_M, "{rough}");
        assert_eq!(smooth.velocity_spans()[s as usize], VELOCITY_SPAN);

        let mut ringing = smooth.clone();
        let sliding = moving(&smooth);
        let range = ringing.base.shapes.range(s);
        for (k, state) in ringing.states.iter_mut().enumerate().take(sliding) {
            let ring = 0.01 * (2.0 * std::f32::consts::PI * k as f32 / 10.0).sin();
            state.position[range.clone()]
                .iter_mut()
                .for_each(|p| p.x += ring);
        }
        let rough = ringing.roughness(s).unwrap();
        assert!(rough > 1.5 * ROUGH_TRACK_M, "{rough}");
        assert_eq!(ringing.velocity_spans()[s as usize], ROUGH_VELOCITY_SPAN);
        // The same path driven by a robot's joints is not a tracked ring: it keeps the narrow span.
        let mut driven = ringing.clone();
        driven.base.shapes.kind[s as usize] = ShapeKind::Kinematic;
        assert_eq!(driven.velocity_spans()[s as usize], VELOCITY_SPAN);
        // Spans kept from another replay of the recording win over the track's own; a list that
        // does not match the shapes is not kept.
        let mut kept = ringing.clone();
        kept.keep_velocity_spans(smooth.velocity_spans());
        assert_eq!(kept.velocity_spans()[s as usize], VELOCITY_SPAN);
        kept.keep_velocity_spans(vec![ROUGH_VELOCITY_SPAN; 3]);
        assert_eq!(kept.velocity_spans()[s as usize], VELOCITY_SPAN);

        let mut moved = ringing.clone();
        let at = 12;
        for state in &mut moved.states[at..] {
            state.position[range.clone()]
                .iter_mut()
                .for_each(|p| p.y += 0.1);
        }
        moved.jumps.push(Jump {
            object: "box".into(),
            shape: s,
            state: at,
            time: moved.states[at].time,
            jump_m: 0.1,
        });
        for k in at - 2..at + 2 {
            let v = moved.world_at(k).particles.velocity[range.start];
            assert!(v.y.abs() < 1e-3 && v.x > 0.1, "state {k}: {v}");
        }
    }

    /// The velocity fitted to positions on a parabola is its slope, on both sides of the state or
    /// one (the trace's ends); a ring of 10 ticks about a steady slide (the pose pull's, 20 mm
    /// either way) passes into it at a quarter or less of its own speed, against three quarters
    /// through a difference over two ticks each way.
    #[test]
    fn a_fitted_velocity_is_a_parabolas_slope_and_damps_a_ring_of_ten_ticks() {
        let dt = 1.0 / 30.0;
        let path = |t: f64| 0.05 + 0.6 * t - 0.5 * 4.0 * t * t;
        let slope = |t: f64| 0.6 - 4.0 * t;
        for (from, to, at) in [(-5, 5, 0.3), (0, 5, 0.0), (-5, 0, 0.5), (-1, 1, 0.2)] {
            let times: Vec<f64> = (from..=to).map(|j| j as f64 * dt).collect();
            let w = velocity_weights(&times).unwrap();
            let v: f64 = times.iter().zip(&w).map(|(t, w)| w * path(at + t)).sum();
            assert!(
                (v - slope(at)).abs() < 1e-9,
                "{from}..{to}: {v} against {}",
                slope(at)
            );
        }
        assert_eq!(velocity_weights(&[0.0, dt]), None);
        assert_eq!(velocity_weights(&[0.0, 0.0, 0.0]), None);
        // A ring of amplitude 20 mm and period 10 ticks: its own speed peaks at 2 pi A / T.
        let omega = 2.0 * std::f64::consts::PI / (10.0 * dt);
        let peak = 0.02 * omega;
        // The worst phase: the ring's speed at its peak at the state.
        let passed = |times: &[f64], w: &[f64]| {
            let v: f64 = times
                .iter()
                .zip(w)
                .map(|(t, w)| w * 0.02 * (omega * t).sin())
                .sum();
            v.abs() / peak
        };
        let span = ROUGH_VELOCITY_SPAN as i32;
        let times: Vec<f64> = (-span..=span).map(|j| j as f64 * dt).collect();
        let fitted = passed(&times, &velocity_weights(&times).unwrap());
        let two = 2.0 * dt;
        let differenced = passed(&[-two, two], &[-0.5 / two, 0.5 / two]);
        assert!(fitted < 0.25, "{fitted}");
        assert!(differenced > 0.7, "{differenced}");
    }
}

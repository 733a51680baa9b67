//! The recording offered to `inputs::Inputs` exactly as the live node offers its topics: each
//! colour image when the clock passes its stamp, streamed from the bag as the clock advances
//! (read ahead by `LOOKAHEAD_S` of bag time and held in stamp order, so a bag written slightly
//! out of order replays in order, and memory is bounded by the look-ahead, not the bag). Moving
//! cameras get their pose from `/tf` at each image's stamp. Where the pose search scores depth
//! (`correct.pose_search_depth`), each camera's depth images are offered alike. Refusals are
//! counted and explained by `Inputs`; the feed passes the explanations on as warnings and reports
//! cameras that went stale.

use super::Metrics;
use super::recording::{Colour, Role, Streams};
use crate::config::Config;
use crate::inputs::{Inputs, TickInputs};
use crate::msgs::{self, Image, TfMessage};
use crate::record::{BagReader, RawMessage, TfTree};
use crate::tracker::Tracker;
use anyhow::Result;
use std::collections::VecDeque;

/// At most this many input explanations are kept among a replay's warnings.
const MAX_WARNINGS: usize = 50;
/// Bag time read beyond the clock (s).
const LOOKAHEAD_S: f64 = 0.5;
/// At most this many images wait per camera; beyond, the oldest is offered early and that said.
const MAX_PENDING: usize = 90;

pub struct Feed<'a> {
    streams: &'a Streams,
    reader: std::iter::Peekable<BagReader>,
    inputs: Inputs,
    /// Per camera: read images waiting for the clock, in stamp order.
    pending: Vec<VecDeque<(f64, Colour)>>,
    /// Per camera: read depth images waiting for the clock, in stamp order; None where depth is
    /// not used.
    pending_depth: Option<Vec<VecDeque<(f64, Image)>>>,
    depth_unit: f32,
    joint_cursor: usize,
    /// `/tf_static` and the `/tf` read so far (for moving cameras).
    tf: TfTree,
    overflow_said: bool,
}

impl<'a> Feed<'a> {
    /// A feed for `tracker`, whose robot (if any) starts at its trajectory's first positions.
    pub fn new(streams: &'a Streams, tracker: &Tracker, config: &Config) -> Result<Self> {
        let cameras = streams
            .cameras
            .iter()
            .map(|c| (c.name.clone(), c.camera))
            .collect();
        let mut inputs = tracker.inputs(cameras);
        let robot = &config.robot;
        inputs.rename_joints(&robot.joint_prefix_received, &robot.joint_prefix_urdf);
        Ok(Self {
            streams,
            reader: BagReader::open(&streams.path)?.peekable(),
            inputs,
            pending: streams.cameras.iter().map(|_| VecDeque::new()).collect(),
            pending_depth: (config.correct.pose_search_depth > 0.0)
                .then(|| streams.cameras.iter().map(|_| VecDeque::new()).collect()),
            depth_unit: config.node.depth_unit,
            joint_cursor: 0,
            tf: streams.tf.clone(),
            overflow_said: false,
        })
    }

    /// Offer every message stamped up to `t`, then take what the tick ending at `t` consumes.
    pub fn tick(&mut self, t: f64, config: &Config, metrics: &mut Metrics) -> TickInputs {
        self.read_until(t + self.streams.log_offset + LOOKAHEAD_S, metrics);
        for c in 0..self.pending.len() {
            while let Some((stamp, _)) = self.pending[c].front()
                && *stamp <= t + 1e-6
            {
                if let Some((stamp, colour)) = self.pending[c].pop_front() {
                    self.offer(c, stamp, colour, t);
                }
            }
        }
        if let Some(pending) = &mut self.pending_depth {
            for (c, queue) in pending.iter_mut().enumerate() {
                while let Some((stamp, _)) = queue.front()
                    && *stamp <= t + 1e-6
                {
                    if let Some((_, image)) = queue.pop_front() {
                        // Refusals are counted and explained by `inputs`.
                        let _ = self.inputs.offer_depth(c, &image, self.depth_unit, t);
                    }
                }
            }
        }
        let joints = &self.streams.joint_states;
        while let Some((stamp, js)) = joints.get(self.joint_cursor)
            && *stamp <= t + 1e-6
        {
            let _ = self.inputs.offer_joint_state(js, t);
            self.joint_cursor += 1;
        }
        for line in self.inputs.log.take_lines() {
            if metrics.warnings.len() < MAX_WARNINGS {
                metrics.warnings.push(line);
            }
        }
        self.tf.forget_before(t - 1.0);
        let tick = self
            .inputs
            .tick_inputs(t, config.correct.max_image_age as f64);
        report_stale(&tick, metrics);
        tick
    }

    /// Read the bag up to log time `until`, keeping the used cameras' colour images and `/tf`.
    fn read_until(&mut self, until: f64, metrics: &mut Metrics) {
        while let Some(m) = self.reader.next_if(|m| m.time <= until) {
            if let Err(e) = self.take(&m)
                && metrics.warnings.len() < MAX_WARNINGS
            {
                metrics
                    .warnings
                    .push(format!("skipped a message on {}: {e:#}", m.topic));
            }
        }
    }

    fn take(&mut self, m: &RawMessage) -> Result<()> {
        match self.streams.topics.role(&m.topic) {
            Role::Colour { camera, compressed } => {
                let Some(c) = self.streams.cameras.iter().position(|s| s.name == camera) else {
                    return Ok(());
                };
                let colour = Colour::decode(m, compressed)?;
                let stamp = colour.header().stamp.seconds();
                let (lo, hi) = self.streams.window;
                if !(lo..=hi).contains(&stamp) {
                    return Ok(()); // refused and said by the survey
                }
                let queue = &mut self.pending[c];
                let at = queue.partition_point(|p| p.0 <= stamp);
                queue.insert(at, (stamp, colour));
                if queue.len() > MAX_PENDING
                    && let Some((early, colour)) = queue.pop_front()
                {
                    if !self.overflow_said {
                        self.overflow_said = true;
                        self.inputs.log.say(format!(
                            "camera {camera}: over {MAX_PENDING} images wait for the clock (the \
                             bag is not in time order, or its log times are far from the stamps); \
                             offering them early to bound memory (stamp {early:.3} s)"
                        ));
                    }
                    self.offer(c, early, colour, early);
                }
            }
            Role::Depth(camera) if self.pending_depth.is_some() => {
                let Some(c) = self.streams.cameras.iter().position(|s| s.name == camera) else {
                    return Ok(());
                };
                let image: Image = msgs::from_cdr(&m.data)?;
                let stamp = image.header.stamp.seconds();
                if let Some(queue) = self.pending_depth.as_mut().map(|p| &mut p[c]) {
                    let at = queue.partition_point(|p| p.0 <= stamp);
                    queue.insert(at, (stamp, image));
                    // Bounded as the colour: the oldest is offered early.
                    if queue.len() > MAX_PENDING
                        && let Some((early, image)) = queue.pop_front()
                    {
                        let _ = self.inputs.offer_depth(c, &image, self.depth_unit, early);
                    }
                }
            }
            Role::Tf if self.streams.cameras.iter().any(|c| c.moving) => {
                let tf: TfMessage = msgs::from_cdr(&m.data)?;
                for line in self.tf.add(&tf, false) {
                    self.inputs.log.say(line);
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// Offer camera `c`'s image at the clock `now`, moving a wrist camera to its pose at the
    /// image's stamp first.
    fn offer(&mut self, c: usize, stamp: f64, colour: Colour, now: f64) {
        let stream = &self.streams.cameras[c];
        if stream.moving {
            let world = &self.streams.topics.node.world_frame;
            match self.tf.lookup(world, &stream.frame, stamp) {
                Ok(world_from_optical) => {
                    self.inputs.cameras[c].camera.world_to_camera = world_from_optical.inverse()
                }
                Err(why) => {
                    self.inputs.log.refuse_image(format!(
                        "camera {}: image at {stamp:.3} s skipped: {why}",
                        stream.name
                    ));
                    return;
                }
            }
        }
        match colour.into_image() {
            // Refusals are counted and explained by `inputs`.
            Ok(image) => {
                let _ = self.inputs.offer_image(c, &image, now);
            }
            Err(why) => {
                self.inputs.log.refuse_image(format!(
                    "camera {}: image at {stamp:.3} s: {why}",
                    stream.name
                ));
            }
        }
    }

    /// The refusals' counts, and why the bag ended early if it did.
    pub fn finish(&mut self, metrics: &mut Metrics) {
        metrics.rejected_images = self.inputs.log.images_rejected;
        metrics.rejected_joint_states = self.inputs.log.joint_states_rejected;
    }
}

/// Count the ticks each camera was stale for, and say so the first time.
fn report_stale(tick: &TickInputs, metrics: &mut Metrics) {
    for name in &tick.stale {
        let n = metrics.stale_camera_ticks.entry(name.clone()).or_insert(0);
        if *n == 0 {
            let t = tick.time;
            let age = tick.ages.iter().find(|(c, _)| c == name).and_then(|a| a.1);
            let stamp = age.map_or(f64::NAN, |a| t - a);
            let line = format!(
                "camera {name}: no image since {stamp:.3} s (at {t:.3} s); continuing with the other cameras"
            );
            eprintln!("warning: {line}");
            metrics.warnings.push(line);
        }
        *n += 1;
    }
}

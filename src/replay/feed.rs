//! The recording offered to `inputs::Inputs` exactly as the live node offers its topics: each
//! message when the clock passes its stamp. Refusals are counted and explained by `Inputs`; the
//! feed passes the explanations on as warnings and reports cameras that went stale.

use super::Metrics;
use super::recording::Streams;
use crate::config::Config;
use crate::inputs::{Inputs, TickInputs};
use crate::tracker::Tracker;

/// At most this many input explanations are kept among a replay's warnings.
const MAX_WARNINGS: usize = 50;

pub struct Feed<'a> {
    streams: &'a Streams,
    inputs: Inputs,
    /// Per camera: the next image to offer.
    cursor: Vec<usize>,
    joint_cursor: usize,
}

impl<'a> Feed<'a> {
    /// A feed for `tracker`, whose robot (if any) starts at its trajectory's first positions.
    pub fn new(streams: &'a Streams, tracker: &Tracker) -> Self {
        Self {
            streams,
            inputs: tracker.inputs(streams.cameras.clone()),
            cursor: vec![0; streams.cameras.len()],
            joint_cursor: 0,
        }
    }

    /// Offer every message stamped up to `t`, then take what the tick ending at `t` consumes.
    pub fn tick(&mut self, t: f64, config: &Config, metrics: &mut Metrics) -> TickInputs {
        for (c, stream) in self.streams.images.iter().enumerate() {
            while let Some((stamp, image)) = stream.get(self.cursor[c])
                && *stamp <= t + 1e-6
            {
                // Refusals are counted and explained by `inputs`.
                let _ = self.inputs.offer_image(c, image, t);
                self.cursor[c] += 1;
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
        let tick = self
            .inputs
            .tick_inputs(t, config.correct.max_image_age as f64);
        report_stale(&tick, metrics);
        tick
    }

    /// The refusals' counts.
    pub fn finish(&self, metrics: &mut Metrics) {
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

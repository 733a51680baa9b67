//! Locate: where the model's predictions fail. From every tracked state the physics alone
//! predicts a short horizon ahead; a start whose prediction misses the tracked state by clearly
//! more than the tracking noise is a mismatch. Runs of such starts are the mismatch windows,
//! each with its time span, the table region the object crossed and its contact phase.

use super::Sample;
use super::trace::{Prediction, Trace};
use crate::config::PhysicsConfig;
use crate::world::ShapeId;
use anyhow::Result;
use glam::Vec2;
use serde::Serialize;

/// Short prediction horizon of the locator, s: long enough for a missing effect to show,
/// short enough to pin down when and where it acts.
pub const HORIZON: f64 = 0.2;
/// Errors below this (m) are tracking noise whatever the statistics say.
pub const MIN_ERROR: f32 = 0.003;

#[derive(Clone, Debug, Serialize)]
pub struct Mismatch {
    pub object: String,
    pub t_start: f64,
    pub t_end: f64,
    /// The box of table positions (world x, y; m) the object's centre crossed.
    pub region_min: [f32; 2],
    pub region_max: [f32; 2],
    /// Contact phase: "sliding", "pushed by the robot", "touching another object" or "at rest".
    pub phase: String,
    /// Largest short-horizon prediction error in the window, mm.
    pub peak_error_mm: f32,
}

impl Mismatch {
    pub fn region(&self) -> (Vec2, Vec2) {
        (Vec2::from(self.region_min), Vec2::from(self.region_max))
    }
}

/// The locator's findings for one object.
#[derive(Clone, Debug, Serialize)]
pub struct Located {
    pub windows: Vec<Mismatch>,
    /// Error a start must exceed to count (m), and the per-start errors `(t, m)`.
    pub threshold: f32,
    #[serde(skip)]
    pub errors: Vec<(f64, f32)>,
}

/// Short-horizon predictions from every other tracked state of `object` with `physics`, and the
/// windows where they fail. `samples` are the object's residual samples (for contact phases);
/// starts in the first `settle` seconds are skipped.
pub fn locate(trace: &Trace, physics: &PhysicsConfig, object: ShapeId, samples: &[Sample], settle: f64) -> Result<Located> {
    let horizon = (HORIZON / trace.dt()).round().max(1.0) as usize;
    let last = trace.states.len().saturating_sub(horizon + 1);
    // Skip the first `settle` seconds: tracking is still pulling the model onto its start pose.
    let t0 = trace.states.first().map_or(0.0, |s| s.time);
    let starts: Vec<usize> = (0..=last).step_by(2).filter(|&k| trace.states[k].time >= t0 + settle).collect();
    let predictions = trace.predict(physics, object, &starts, horizon)?;
    let errors: Vec<(f64, f32)> = predictions.iter().map(|p| (trace.states[p.start].time, p.error)).collect();
    // Noise: the median error (most of a recording is predicted well) scaled as a robust 3 sigma.
    let mut sorted: Vec<f32> = errors.iter().map(|e| e.1).collect();
    sorted.sort_by(f32::total_cmp);
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    let threshold = (4.0 * median).max(MIN_ERROR);
    let name = trace.base.shapes.name[object as usize].clone();
    let mut windows = Vec::new();
    let mut run: Vec<&Prediction> = Vec::new();
    let flush = |run: &mut Vec<&Prediction>, windows: &mut Vec<Mismatch>| {
        if run.len() >= 2 {
            windows.push(window(trace, object, &name, run, horizon, samples));
        }
        run.clear();
    };
    for p in &predictions {
        if p.error > threshold {
            run.push(p);
        } else {
            flush(&mut run, &mut windows);
        }
    }
    flush(&mut run, &mut windows);
    Ok(Located { windows, threshold, errors })
}

fn window(trace: &Trace, object: ShapeId, name: &str, run: &[&Prediction], horizon: usize, samples: &[Sample]) -> Mismatch {
    let (first, last) = (run[0].start, run[run.len() - 1].start + horizon);
    let (t_start, t_end) = (trace.states[first].time, trace.states[last.min(trace.states.len() - 1)].time);
    let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
    // Where the object was when its prediction started to fail: the first half of each horizon.
    for p in run {
        for k in p.start..=(p.start + horizon / 2).min(trace.states.len() - 1) {
            let c = trace.centroid(object, k).truncate();
            lo = lo.min(c);
            hi = hi.max(c);
        }
    }
    let inside: Vec<&Sample> = samples.iter().filter(|s| s.t >= t_start - 1e-9 && s.t <= t_end + 1e-9).collect();
    let count = |f: &dyn Fn(&Sample) -> bool| inside.iter().filter(|s| f(s)).count();
    let phases = [
        ("pushed by the robot", count(&|s| s.touching_robot)),
        ("touching another object", count(&|s| s.touching_object && !s.touching_robot)),
        ("sliding", count(&|s| !s.touching_robot && !s.touching_object && s.velocity.truncate().length() > 0.01)),
        ("at rest", count(&|s| !s.touching_robot && !s.touching_object && s.velocity.truncate().length() <= 0.01)),
    ];
    let phase = phases.iter().max_by_key(|p| p.1).map_or("at rest", |p| p.0).to_string();
    Mismatch {
        object: name.to_string(),
        t_start,
        t_end,
        region_min: lo.to_array(),
        region_max: hi.to_array(),
        phase,
        peak_error_mm: run.iter().map(|p| p.error).fold(0.0, f32::max) * 1e3,
    }
}

//! The node's clock, as rcl keeps it: the wall clock, or with `use_sim_time` the time of the
//! newest `/clock` message (`ros2 bag play --clock`, a simulator). Ticks are scheduled, inputs
//! judged and outputs stamped on it; log lines and run statistics keep the wall clock.
//!
//! Owns the reading of time only; what a jump back does to the tracking is the tick thread's.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

#[derive(Clone, Debug, Default)]
pub struct RosClock {
    /// With `use_sim_time`: the newest `/clock` time (f64 bits; NaN until the first message).
    simulated: Option<Arc<AtomicU64>>,
}

impl RosClock {
    pub fn new(use_sim_time: bool) -> Self {
        Self {
            simulated: use_sim_time.then(|| Arc::new(AtomicU64::new(f64::NAN.to_bits()))),
        }
    }

    /// Seconds since the Unix epoch, on the wall clock.
    pub fn wall() -> f64 {
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64())
    }

    /// The time now: the wall clock, or the newest `/clock` (None before the first).
    pub fn now(&self) -> Option<f64> {
        match &self.simulated {
            None => Some(Self::wall()),
            Some(t) => Some(f64::from_bits(t.load(Ordering::SeqCst))).filter(|t| t.is_finite()),
        }
    }

    pub fn is_simulated(&self) -> bool {
        self.simulated.is_some()
    }

    /// A `/clock` message (ignored on the wall clock, and when not finite).
    pub fn set(&self, t: f64) {
        if let Some(at) = &self.simulated
            && t.is_finite()
        {
            at.store(t.to_bits(), Ordering::SeqCst);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simulated_time_is_the_newest_clock_message_and_unknown_before_the_first() {
        let wall = RosClock::new(false);
        wall.set(5.0);
        assert!((wall.now().unwrap() - RosClock::wall()).abs() < 1.0);
        let sim = RosClock::new(true);
        assert_eq!(sim.now(), None);
        let shared = sim.clone();
        shared.set(12.5);
        assert_eq!(sim.now(), Some(12.5));
        shared.set(3.0);
        assert_eq!(
            sim.now(),
            Some(3.0),
            "a clock may go back (a bag replayed again)"
        );
        shared.set(f64::NAN);
        assert_eq!(sim.now(), Some(3.0));
    }
}

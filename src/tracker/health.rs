//! Lost-track detection: each tracked object's silhouette agreement (`correct::agreement`) over
//! ticks. An object whose agreement stays below `LOST_BELOW` for `LOST_AFTER` measured ticks is
//! lost (the model no longer overlaps what the cameras see, so no visual force can bring it back);
//! it is found again after `FOUND_AFTER` measured ticks above `FOUND_ABOVE`. Ticks that measure
//! nothing (too little of the object in view) change nothing.
//!
//! Owns the state per object and the events; what is done about a lost object is its caller's.

use crate::world::ShapeId;
use serde::Serialize;

pub const LOST_BELOW: f32 = 0.35;
pub const LOST_AFTER: usize = 10;
pub const FOUND_ABOVE: f32 = 0.6;
pub const FOUND_AFTER: usize = 3;

/// An object lost or found again, at the end of the tick that decided it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TrackEvent {
    pub shape: ShapeId,
    pub time: f64,
    pub lost: bool,
    /// The agreement that decided it.
    pub agreement: f32,
}

#[derive(Clone, Debug, Default)]
pub struct TrackHealth {
    /// Per shape: consecutive measured ticks against the current state, whether lost, and the
    /// newest agreement measured.
    streak: Vec<usize>,
    lost: Vec<bool>,
    last: Vec<Option<f32>>,
}

impl TrackHealth {
    /// Count one tick's agreements (per shape) ending at `time`; the events it decided.
    pub fn update(&mut self, time: f64, agreement: &[Option<f32>]) -> Vec<TrackEvent> {
        let n = agreement.len();
        self.streak.resize(n, 0);
        self.lost.resize(n, false);
        self.last.resize(n, None);
        let mut events = Vec::new();
        for (s, a) in agreement.iter().enumerate() {
            let Some(a) = *a else { continue };
            self.last[s] = Some(a);
            let against = match self.lost[s] {
                false => a < LOST_BELOW,
                true => a > FOUND_ABOVE,
            };
            self.streak[s] = if against { self.streak[s] + 1 } else { 0 };
            let needed = if self.lost[s] {
                FOUND_AFTER
            } else {
                LOST_AFTER
            };
            if self.streak[s] >= needed {
                self.lost[s] = !self.lost[s];
                self.streak[s] = 0;
                events.push(TrackEvent {
                    shape: s as ShapeId,
                    time,
                    lost: self.lost[s],
                    agreement: a,
                });
            }
        }
        events
    }

    /// Whether shape `s` is lost now.
    pub fn is_lost(&self, s: ShapeId) -> bool {
        self.lost.get(s as usize).copied().unwrap_or(false)
    }

    /// The newest agreement measured for shape `s`.
    pub fn agreement(&self, s: ShapeId) -> Option<f32> {
        self.last.get(s as usize).copied().flatten()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A short dip is not a loss; a lasting one is, once; recovery needs a few good ticks; ticks
    /// without a measurement neither count nor break a streak.
    #[test]
    fn an_object_is_lost_only_after_a_lasting_disagreement_and_found_after_a_lasting_agreement() {
        let mut h = TrackHealth::default();
        let tick = |h: &mut TrackHealth, t: usize, a: Option<f32>| h.update(t as f64, &[a]);
        for t in 0..5 {
            assert!(tick(&mut h, t, Some(0.1)).is_empty());
        }
        assert!(tick(&mut h, 5, Some(0.9)).is_empty(), "a dip of 5 ticks");
        let mut events = Vec::new();
        for t in 6..30 {
            let a = if t % 3 == 0 { None } else { Some(0.1) };
            events.extend(tick(&mut h, t, a));
        }
        assert_eq!(events.len(), 1, "{events:?}");
        assert!(events[0].lost && h.is_lost(0));
        assert!(tick(&mut h, 30, Some(0.9)).is_empty() && tick(&mut h, 31, Some(0.9)).is_empty());
        let found = tick(&mut h, 32, Some(0.9));
        assert!(found.len() == 1 && !found[0].lost && !h.is_lost(0));
    }
}

//! The modelled table's edge: which tracked objects stand beyond the static scene's Gaussians
//! (the table fitted to the first frames, `init::table` over `scene.table`).
//!
//! Behind an object off that rectangle nothing of the scene is modelled, so the correction
//! cannot tell the object's pixels from the table's (agreement and the pose search compare an
//! object's colour with the static scene rendered behind it) and its tracking degrades. On
//! MuJoCo's recordings a box that slid 3.5 cm past a 0.6 m table's edge rested 13 mm from where
//! the tracker held it, against 7 mm with the table configured over what the cameras see. The
//! tracker says so once, when an object leaves the rectangle (and when it is back), so that the
//! user widens `scene.table` instead of guessing. Where a fixed camera saw the floor there at the
//! first correction, the agreement and the search compare with that (`correct::backdrop`), which
//! takes back part of the loss (MuJoCo's slippery_2901: 101 -> 21 mm mean).
//!
//! Owns the rectangle and the per-object state; the events go out with the tick's others.

use super::{Change, TrackEvent};
use crate::world::{NO_PARENT, ShapeId, World};
use glam::Vec2;

/// What an object off the modelled table means and what to do, for its log line and its status.
pub const OFF_TABLE_ADVICE: &str = "nothing behind it is modelled and its tracking degrades; \
     widen scene.table to what the cameras see of the table";

/// An object off the table is back on it once its centre is this far (m) inside the edge.
const BACK_INSIDE: f32 = 0.005;
/// Fewer static Gaussians than this are no table (a scene without one is never off it).
const MIN_DISKS: usize = 16;

#[derive(Clone, Debug, Default)]
pub struct TableEdge {
    /// The static Gaussians' footprint on the table plane (x, y), None without a table.
    rect: Option<(Vec2, Vec2)>,
    off: Vec<bool>,
}

impl TableEdge {
    /// The footprint of `world`'s static Gaussians (those bonded to no particle).
    pub fn of(world: &World) -> Self {
        let g = &world.gaussians;
        let statics: Vec<Vec2> = (0..g.len())
            .filter(|&i| g.parent[i] == NO_PARENT)
            .map(|i| g.local_mean[i].truncate())
            .filter(|p| p.is_finite())
            .collect();
        let rect = (statics.len() >= MIN_DISKS).then(|| {
            let lo = statics.iter().copied().fold(Vec2::MAX, Vec2::min);
            let hi = statics.iter().copied().fold(Vec2::MIN, Vec2::max);
            (lo, hi)
        });
        Self {
            rect,
            off: Vec::new(),
        }
    }

    /// Each dynamic object's centre against the rectangle at `time`: an event for each one that
    /// left it or came back.
    pub fn update(&mut self, world: &World, time: f64) -> Vec<TrackEvent> {
        let Some((lo, hi)) = self.rect else {
            return Vec::new();
        };
        self.off.resize(world.shapes.len(), false);
        let mut events = Vec::new();
        for s in world.shapes.dynamic_ids() {
            let c = world.shape_centroid(s);
            let p = c.truncate();
            let i = s as usize;
            let change = match self.off[i] {
                false if p.cmplt(lo).any() || p.cmpgt(hi).any() => Change::OffTable {
                    at: c.to_array(),
                    table_min: lo.to_array(),
                    table_max: hi.to_array(),
                },
                true if (p - lo).min_element() >= BACK_INSIDE
                    && (hi - p).min_element() >= BACK_INSIDE =>
                {
                    Change::BackOnTable { at: c.to_array() }
                }
                _ => continue,
            };
            self.off[i] = !self.off[i];
            events.push(TrackEvent {
                shape: s as ShapeId,
                time,
                change,
                agreement: f32::NAN,
            });
        }
        events
    }

    /// Whether shape `s` stands off the modelled table now.
    pub fn is_off(&self, s: ShapeId) -> bool {
        self.off.get(s as usize).copied().unwrap_or(false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Pose;
    use crate::world::{WorldBuilder, box_lattice};
    use glam::{Quat, Vec3};

    /// A 0.6 m table of disks, and a box on it at `x`.
    fn table_and_box(x: f32) -> World {
        let mut b = WorldBuilder::new();
        for i in 0..=6 {
            for j in 0..=6 {
                let p = Vec3::new(0.2 + 0.1 * i as f32, -0.3 + 0.1 * j as f32, 0.0);
                b.add_scene_gaussian(p, Quat::IDENTITY, Vec3::splat(0.05), 1.0, Vec3::ONE);
            }
        }
        let at = Pose::new(Vec3::new(x, 0.0, 0.025), Quat::IDENTITY);
        let points = box_lattice(Vec3::splat(0.025), 0.01);
        b.add_rigid("box", &points, 0.005, 0.01, at, Vec3::X);
        b.build()
    }

    #[test]
    fn an_object_that_slides_off_the_modelled_table_is_reported_once_and_again_when_back() {
        let mut edge = TableEdge::of(&table_and_box(0.5));
        let on = table_and_box(0.5);
        assert!(
            edge.update(&on, 0.1).is_empty(),
            "on the table: nothing to say"
        );
        let off = table_and_box(0.85);
        let events = edge.update(&off, 0.2);
        assert_eq!(events.len(), 1, "{events:?}");
        assert!(matches!(events[0].change, Change::OffTable { .. }));
        assert!(edge.is_off(events[0].shape));
        assert!(edge.update(&off, 0.3).is_empty(), "said once");
        // Just inside the edge is not yet back (no flicker at the edge).
        assert!(edge.update(&table_and_box(0.798), 0.4).is_empty());
        let back = edge.update(&on, 0.5);
        assert_eq!(back.len(), 1);
        assert!(matches!(back[0].change, Change::BackOnTable { .. }));
    }

    #[test]
    fn a_scene_without_a_table_has_no_edge() {
        let mut b = WorldBuilder::new();
        let at = Pose::new(Vec3::new(5.0, 0.0, 0.025), Quat::IDENTITY);
        let points = box_lattice(Vec3::splat(0.025), 0.01);
        b.add_rigid("box", &points, 0.005, 0.01, at, Vec3::X);
        let world = b.build();
        assert!(TableEdge::of(&world).update(&world, 0.1).is_empty());
    }
}

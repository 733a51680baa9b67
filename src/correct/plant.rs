//! The model the visual forces push (`Plant`: what of its physics closes the loop with them) and
//! the rule that turns the one configured gain and damping into the ones that model takes
//! (`loop_gains`). Two properties of the model change how a push of gain x displacement plays out,
//! so they, not the scene, set the gain:
//! - its table's kinetic friction, which damps the loop: on a slippery table nothing but the
//!   visual damping does, and a gain that settles a box on a rough table rings there; below
//!   `slippery_friction` the gain falls in proportion to the friction, down to `slippery_floor`
//!   of it.
//! - the share of its velocity a particle keeps at the end of a tick (`physics.damping`): a
//!   model that keeps half keeps half of each push, so the gain is set for `reference_damping`
//!   and grows by reference / kept.
//!
//! The damping stays as configured: where the table damps less, the visual damping's share of the
//! loop's grows, and a model's own velocity damping adds to it. At or above `slippery_friction`
//! and at `reference_damping` the configured gain is returned unchanged, bit for bit.
//!
//! This module owns that rule and nothing else: it never measures displacements or applies
//! forces (`correct`), and never reads images.

use super::CorrectConfig;
use crate::physics::PhysicsConfig;

/// Least share of its velocity a model may keep for the rule (`physics.damping` can be 0): the
/// gain grows at most 1 / this times the reference.
const MIN_KEPT: f32 = 0.1;

/// What of the model's physics closes the loop with the visual forces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plant {
    /// Kinetic friction of the table the objects stand on; None where the model has no table.
    pub table_friction: Option<f32>,
    /// Share of its velocity a particle keeps at the end of a tick (`physics.damping`).
    pub velocity_kept: f32,
}

impl Plant {
    pub fn of(physics: &PhysicsConfig) -> Self {
        Self {
            table_friction: physics
                .ground
                .enabled
                .then_some(physics.ground.kinetic_friction),
            velocity_kept: physics.damping,
        }
    }
}

impl Default for Plant {
    fn default() -> Self {
        Self::of(&PhysicsConfig::default())
    }
}

/// The gain (1/s^2) and damping (1/s) the visual forces take on `plant`.
pub fn loop_gains(c: &CorrectConfig, plant: &Plant) -> (f32, f32) {
    let slip = plant.table_friction.map_or(1.0, |friction| {
        (friction / c.slippery_friction).clamp(c.slippery_floor, 1.0)
    });
    let kept = c.reference_damping / plant.velocity_kept.max(MIN_KEPT);
    (c.gain * slip * kept, c.damping)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plant(friction: f32, kept: f32) -> Plant {
        Plant {
            table_friction: Some(friction),
            velocity_kept: kept,
        }
    }

    #[test]
    fn a_rough_table_and_the_reference_damping_take_the_configured_gain_bit_for_bit() {
        let c = CorrectConfig::default();
        let (gain, damping) = (c.gain, c.damping);
        for friction in [c.slippery_friction, 0.15, 0.4, 1.2] {
            let got = loop_gains(&c, &plant(friction, c.reference_damping));
            assert_eq!(got, (gain, damping), "friction {friction}");
        }
        let defaults = Plant::default();
        assert_eq!(loop_gains(&c, &defaults), (gain, damping));
        let no_table = Plant {
            table_friction: None,
            ..defaults
        };
        assert_eq!(loop_gains(&c, &no_table), (gain, damping));
    }

    #[test]
    fn on_a_slippery_table_the_gain_falls_with_friction_and_the_damping_stays() {
        let c = CorrectConfig::default();
        let rough = loop_gains(&c, &plant(0.4, c.reference_damping));
        let mut last = rough.0;
        for friction in [0.08, 0.05, 0.03] {
            let slippery = loop_gains(&c, &plant(friction, c.reference_damping));
            let share = friction / c.slippery_friction;
            assert!(
                (slippery.0 - share * c.gain).abs() < 1e-3 * c.gain,
                "{slippery:?}"
            );
            assert_eq!(slippery.1, c.damping);
            assert!(slippery.0 < last);
            last = slippery.0;
        }
        // A frictionless table keeps the floor's share, not a gain of nothing.
        let ice = loop_gains(&c, &plant(0.0, c.reference_damping));
        assert!((ice.0 - c.slippery_floor * c.gain).abs() < 1e-3, "{ice:?}");
    }

    #[test]
    fn a_model_keeping_half_its_velocity_each_tick_takes_twice_the_reference_push() {
        let c = CorrectConfig::default();
        let (gain, damping) = loop_gains(&c, &plant(0.4, 0.5));
        assert!(
            (gain * 0.5 - c.gain * c.reference_damping).abs() < 1e-3,
            "{gain}"
        );
        assert_eq!(damping, c.damping);
        // What survives the tick's damping, gain x kept, is the same whatever is kept.
        for kept in [0.3, 0.7, 0.9, 1.0] {
            let (g, _) = loop_gains(&c, &plant(0.4, kept));
            assert!(
                (g * kept - c.gain * c.reference_damping).abs() < 1e-2,
                "{kept}: {g}"
            );
        }
        let (stopped, _) = loop_gains(&c, &plant(0.4, 0.0));
        assert!(stopped.is_finite() && stopped <= c.gain * c.reference_damping / MIN_KEPT + 1e-2);
    }
}

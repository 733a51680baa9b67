//! Diagnose: what physics the model is missing (spec section 5). The visual force is the force the
//! physics failed to predict; logged per object and tick together with the object's state, it is
//! a residual that candidate physical effects try to explain.
//!
//! The pipeline (`diagnose`, in `pipeline/`): replay with the current model, keeping its trace in
//! memory (`crate::trace`: tracked states, recorded robot motion, residuals); locate where
//! open-loop predictions fail (`locate`); explain the corrective forces by sparse regression over
//! candidate effects with held-out validation (`candidates`, `select`); fit each candidate
//! family's physical parameter by open-loop simulation (the families are defined with their
//! effects in `physics::effects`) and name the one that cuts the held-out prediction error
//! (`refit`); fit the named effect again on a replay tracked with it (tracking with a model that
//! lacks an effect lags what it does); rerun with the augmented model and report before / after
//! (`report`, `plots`).
//! Diagnose never changes the tracker; it only replays with different physics.

pub mod candidates;
pub mod locate;
mod pipeline;
pub mod plots;
pub mod refit;
pub mod report;
pub mod select;

pub use pipeline::{DiagnoseOptions, diagnose};

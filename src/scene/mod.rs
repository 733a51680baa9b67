//! Building worlds: particle lattices for primitive solids, a builder that adds shapes with their
//! particles and bonded Gaussians, and the built-in scenes used by the demo, tests and benchmarks.
//! Initialisation from cameras (issue: scene from RGB-D) will also produce worlds through this
//! builder; nothing here steps physics.

mod builder;
pub mod builtin;
mod lattice;

pub use builder::WorldBuilder;
pub use lattice::{box_lattice, cylinder_lattice, t_block_lattice};

//! Importers: recordings and objects in other projects' layouts converted into pegs recordings
//! (MCAP) and configurations. Foreign conventions end here.

pub mod embodied_gaussians;

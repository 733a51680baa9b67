//! pegs: a realtime, correctable world model. Particles simulated with position-based dynamics
//! predict where objects go; Gaussians bonded to the particles are rendered and compared with
//! camera images, and the photometric error becomes visual forces that correct the particles.
//!
//! The modules follow the loop: `world` (plain data) -> `physics` (predict) -> ... Scenes are
//! built in `scene`; `config` holds every number; `demo` and `bench` are the command-line jobs.

pub mod bench;
pub mod config;
pub mod correct;
pub mod demo;
pub mod diagnose;
pub mod evaluate;
pub mod import;
pub mod init;
pub mod inputs;
pub mod math;
pub mod msgs;
pub mod physics;
pub mod plot;
pub mod record;
pub mod render;
pub mod replay;
pub mod robot;
pub mod ros;
pub mod scenario;
pub mod scene;
pub mod topics;
pub mod trace;
pub mod tracker;
pub mod trajectory;
pub mod world;

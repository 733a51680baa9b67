//! pegs: a realtime, correctable world model. Particles simulated with position-based dynamics
//! predict where objects go; Gaussians bonded to the particles are rendered and compared with
//! camera images, and the photometric error becomes visual forces that correct the particles.
//!
//! The modules are layered (the README's Layout table, checked by `tests/architecture.rs`): plain
//! data (`world`), the passes (`physics` predicts, `render` and `correct` correct), what feeds a
//! tick (`scene`, `init`, `inputs`), the tick itself (`tracker::Tracker::tick`), what keeps a run
//! (`trace`), and the jobs that drive ticks (`replay`, `ros`) or judge them (`diagnose`,
//! `evaluate`, `demo`, `bench`). Each configuration section lives beside what it configures;
//! `config` assembles them.

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

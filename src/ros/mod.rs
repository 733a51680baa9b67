//! `pegs node`: the tracker as a ROS 2 node (ros2-client on tokio). Subscriptions feed
//! `inputs::Inputs`; a dedicated thread drives `Tracker::tick` at the physics rate on the newest
//! data and hands what each tick produced to a publishing thread, so neither waits on the network.
//!
//! - `params`: the configuration as ROS parameters and `--ros-args` overrides.
//! - `parameters`: the parameter services, with descriptors, on the running configuration.
//! - `node`: the node itself: parameters, the three kinds of threads, run statistics.
//! - `clock`: the node's clock (wall, or `/clock` with `use_sim_time`).
//! - `subscribe`: topics in, checked and handed to the shared state.
//! - `tick`: the tick thread: starts the tracker once cameras are known, then drives it.
//! - `diagnostics`: `/diagnostics` from the last window of ticks.
//! - `publish`: the publishing thread.
//! - `outputs`: messages built from the tracked world (pure functions).

mod clock;
mod diagnostics;
pub mod node;
pub mod outputs;
pub mod parameters;
pub mod params;
mod publish;
mod subscribe;
mod tick;

pub use clock::RosClock;

/// Where `log` also sends its lines while a node runs: the node forwards them to `/rosout`.
static ROSOUT: std::sync::Mutex<Option<tokio::sync::mpsc::UnboundedSender<String>>> =
    std::sync::Mutex::new(None);

/// A line for the operator: on stderr, and on `/rosout` while the node runs.
fn log(line: &str) {
    eprintln!("[pegs {:.3}] {line}", RosClock::wall());
    if let Ok(rosout) = ROSOUT.lock()
        && let Some(tx) = rosout.as_ref()
    {
        let _ = tx.send(line.to_string());
    }
}

/// Resident memory of this process in MB (Linux; 0 elsewhere).
pub fn rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<f64>().ok())
        .map_or(0.0, |pages| pages * 4096.0 / 1e6)
}

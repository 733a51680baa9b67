//! The running node. Three kinds of threads, none of which waits on another for long:
//! - tokio tasks (two workers) receive messages, check them and hand them to `Inputs`
//!   (`subscribe`);
//! - the tick thread starts the tracker once cameras are known, then drives its ticks at the
//!   physics rate on whatever is newest, counting overruns instead of queueing ticks (`tick`);
//! - the publishing thread renders debug images and publishes, dropping a tick's output if the
//!   previous one is still being sent (`publish`).

use super::log;
use super::params::LaunchArgs;
use super::publish::{Output, create_publishers, publish_loop};
use super::subscribe::{Shared, subscribe};
use super::tick::tick_loop;
use crate::config::Config;
use anyhow::{Context as _, Result, anyhow};
use ros2_client::{Context, NodeName, NodeOptions};
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::sync_channel;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Options of `pegs node` beyond the configuration.
#[derive(Clone, Debug, Default)]
pub struct RunOptions {
    /// Stop after this many seconds (None: until SIGINT / SIGTERM).
    pub duration: Option<f64>,
    /// Write run statistics (JSON) here on exit.
    pub stats: Option<std::path::PathBuf>,
}

/// What the node measured over its run (also the content of `--stats`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct RunStats {
    pub ticks: usize,
    pub overruns: usize,
    pub skipped_ticks: usize,
    /// Seconds the world's clock jumped without prediction (ticks later than
    /// `tracker::MAX_CATCH_UP_TICKS`).
    pub jumped_s: f64,
    pub dropped_outputs: usize,
    pub achieved_rate_hz: f64,
    pub tick_ms_mean: f64,
    pub tick_ms_p95: f64,
    /// Newest image stamp used by a tick to the publication of that tick's poses.
    pub latency_ms_p50: f64,
    pub latency_ms_p95: f64,
    pub images_rejected: usize,
    pub joint_states_rejected: usize,
    pub malformed_messages: usize,
    pub rss_mb_start: f64,
    pub rss_mb_end: f64,
    pub rejections: BTreeMap<String, usize>,
    /// Images accepted per camera over the tracking run (a rate far below the camera's says the
    /// network lost them: large best-effort samples arrive only if every fragment does).
    pub images_accepted: BTreeMap<String, usize>,
}

fn ros_context() -> Result<Context> {
    let domain = match std::env::var("ROS_DOMAIN_ID") {
        Ok(s) if !s.trim().is_empty() => s
            .trim()
            .parse::<u16>()
            .with_context(|| format!("ROS_DOMAIN_ID='{s}' is not a domain id"))?,
        _ => 0,
    };
    // As with rmw implementations: LOCALHOST keeps discovery and traffic on the loopback interface.
    let localhost = std::env::var("ROS_AUTOMATIC_DISCOVERY_RANGE")
        .is_ok_and(|v| v.eq_ignore_ascii_case("LOCALHOST"));
    let participant = ros2_client::dds::rustdds::DomainParticipantBuilder::new(domain);
    let participant = if localhost {
        participant.with_only_networks([std::net::Ipv4Addr::LOCALHOST])
    } else {
        participant
    };
    let participant = participant
        .build()
        .map_err(|e| anyhow!("cannot start DDS on domain {domain}: {e:?}"))?;
    log(&format!(
        "DDS domain {domain}{}",
        if localhost { ", loopback only" } else { "" }
    ));
    Context::from_domain_participant(participant)
        .map_err(|e| anyhow!("cannot create the ROS context: {e:?}"))
}

/// Run the node until SIGINT / SIGTERM or `options.duration`.
pub fn run(config: Config, launch: &LaunchArgs, options: RunOptions) -> Result<RunStats> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    runtime.block_on(run_async(config, launch, options))
}

async fn run_async(config: Config, launch: &LaunchArgs, options: RunOptions) -> Result<RunStats> {
    config.node.validate_live()?;
    config.scene.check_tracks_something()?;
    config.check_files()?;
    let context = ros_context()?;
    let live = Arc::new(Mutex::new(config.clone()));
    let node_name = launch.node_name.clone().unwrap_or_else(|| "pegs".into());
    let namespace = launch.namespace.clone().unwrap_or_else(|| "/".into());
    let node_name =
        NodeName::new(&namespace, &node_name).map_err(|e| anyhow!("bad node name: {e:?}"))?;
    // The parameter services are pegs's own (`parameters`): ros2-client's have no descriptors.
    let node_options = NodeOptions::new()
        .enable_rosout(true)
        .start_parameter_services(false);
    let mut node = context
        .new_node(node_name.clone(), node_options)
        .map_err(|e| anyhow!("cannot create node: {e:?}"))?;
    tokio::spawn(node.spinner().map_err(|e| anyhow!("{e:?}"))?.spin());
    super::parameters::start(&context, &mut node, live.clone())?;
    let (rosout_tx, mut rosout_rx) = tokio::sync::mpsc::unbounded_channel::<String>();
    if let Ok(mut rosout) = super::ROSOUT.lock() {
        *rosout = Some(rosout_tx);
    }
    let nc = config.node.clone();
    let clock = super::RosClock::new(nc.use_sim_time);
    let shared = Arc::new(Mutex::new(Shared {
        clock: clock.clone(),
        tracking_depth_unit: (config.correct.pose_search_depth > 0.0).then_some(nc.depth_unit),
        ..Default::default()
    }));
    let publishers = create_publishers(&mut node, &nc, &launch.remaps)?;
    let remaps = &launch.remaps;
    let robot = &config.robot;
    subscribe(
        &context,
        &node_name,
        &mut node,
        &nc,
        robot,
        shared.clone(),
        remaps,
    )?;
    log(&format!(
        "node {} up: cameras {:?}, rate {:.1} Hz, {}",
        node.fully_qualified_name(),
        nc.cameras,
        1.0 / config.physics.dt,
        match nc.use_sim_time {
            true => "simulated time from /clock",
            false => "wall clock",
        }
    ));
    let stop = Arc::new(AtomicBool::new(false));
    let (tx, rx) = sync_channel::<Output>(1);
    let latencies = Arc::new(Mutex::new(Vec::<f64>::new()));
    let publisher_thread = {
        let latencies = latencies.clone();
        let render = config.render.clone();
        std::thread::Builder::new()
            .name("pegs-publish".into())
            .spawn(move || publish_loop(rx, publishers, render, latencies, clock))?
    };
    // The tick thread says when it ends, so an error in it (initialisation included) stops the
    // node at once, exiting non-zero with the reason, instead of waiting for a signal.
    let (ended_tx, ended) = tokio::sync::oneshot::channel::<()>();
    let tick_thread = {
        let (shared, stop, live) = (shared.clone(), stop.clone(), live.clone());
        std::thread::Builder::new()
            .name("pegs-tick".into())
            .spawn(move || {
                let result = tick_loop(config, shared, live, tx, stop);
                let _ = ended_tx.send(());
                result
            })?
    };
    // Log lines go to /rosout from here on (and those queued since start-up).
    let to_rosout = async {
        use ros2_client::RosoutRaw;
        while let Some(line) = rosout_rx.recv().await {
            let stamp = ros2_client::builtin_interfaces::Time::now();
            let level = ros2_client::log::LogLevel::Info;
            node.rosout_raw(
                stamp,
                level,
                node.base_name(),
                &line,
                file!(),
                "pegs",
                line!(),
            );
        }
    };
    tokio::select! {
        stopped = wait_for_stop(options.duration, ended) => stopped?,
        _ = to_rosout => {}
    }
    if let Ok(mut rosout) = super::ROSOUT.lock() {
        *rosout = None;
    }
    stop.store(true, Ordering::SeqCst);
    let mut stats = tick_thread
        .join()
        .map_err(|_| anyhow!("the tick thread panicked"))??;
    publisher_thread
        .join()
        .map_err(|_| anyhow!("the publishing thread panicked"))?;
    stats.add_latencies(
        &latencies
            .lock()
            .map_err(|_| anyhow!("latency lock poisoned"))?,
    );
    if let Ok(s) = shared.lock() {
        stats.malformed_messages = s.malformed.values().sum();
    }
    node.stop_spinner();
    if let Some(path) = &options.stats {
        std::fs::write(path, serde_json::to_string_pretty(&stats)?)
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(stats)
}

/// Until SIGINT, SIGTERM, `duration` seconds or the tick thread's end.
async fn wait_for_stop(
    duration: Option<f64>,
    tick_ended: tokio::sync::oneshot::Receiver<()>,
) -> Result<()> {
    let deadline = duration.map(|d| tokio::time::Instant::now() + Duration::from_secs_f64(d));
    let mut terminate = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    tokio::select! {
        _ = tokio::signal::ctrl_c() => log("SIGINT: stopping"),
        _ = terminate.recv() => log("SIGTERM: stopping"),
        _ = tick_ended => log("the tick thread ended: stopping"),
        _ = async { match deadline { Some(d) => tokio::time::sleep_until(d).await, None => std::future::pending().await } } => log("duration reached: stopping"),
    }
    Ok(())
}

impl RunStats {
    /// The median and 95th percentile of image-to-publication latencies (s), in ms.
    fn add_latencies(&mut self, latencies: &[f64]) {
        let mut l = latencies.to_vec();
        l.sort_by(f64::total_cmp);
        let pick = |q: f64| match l.len() {
            0 => f64::NAN,
            n => l[((n as f64 * q) as usize).min(n - 1)] * 1e3,
        };
        self.latency_ms_p50 = pick(0.5);
        self.latency_ms_p95 = pick(0.95);
    }
}

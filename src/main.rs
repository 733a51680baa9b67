//! The `pegs` command line. Each subcommand is a thin shell over the library.

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use pegs::config::Config;
use std::path::{Path, PathBuf};

#[derive(Parser)]
#[command(
    name = "pegs",
    version,
    about = "Physically embodied Gaussian splatting: a realtime, correctable world model"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the built-in demo scene and write its trajectory.
    Demo(DemoArgs),
    /// Measure speed; prints JSON with --json.
    Bench {
        #[command(subcommand)]
        what: BenchTarget,
    },
    /// Synthetic scenarios with ground truth.
    Scenario {
        #[command(subcommand)]
        what: ScenarioCommand,
    },
    /// Run predict/correct on a recording (a rosbag2 directory with MCAP or SQLite3 storage, or
    /// an .mcap / .db3 file) and write objects.csv and metrics.json.
    Replay(ReplayArgs),
    /// Inspect rosbag2 bags.
    Bag {
        #[command(subcommand)]
        what: BagCommand,
    },
    /// Find the physics the model misses: locate where open-loop predictions fail, name the
    /// effect that explains it with its parameter, rerun with it and compare. Writes
    /// DIR/report.md, DIR/report.json, DIR/model.yaml (for `replay --model`), plots and both replays.
    Diagnose(DiagnoseArgs),
    /// Run as a ROS 2 node: subscribe to the cameras and /joint_states, track at the physics rate
    /// and publish poses, particle clouds, debug images, /tf and /diagnostics. Configuration:
    /// --config (or the defaults), then `--ros-args --params-file FILE -p name:=value ...`.
    Node(NodeArgs),
    /// Convert another project's recording layout into a pegs recording and replay configuration.
    Import {
        #[command(subcommand)]
        what: ImportFormat,
    },
    /// Reproduce the supplementary's ablations on synthetic scenarios: PNG plots of tracking
    /// error over time per ablation and OUT/summary.md. Lists are comma-separated.
    Ablate(AblateArgs),
}

#[derive(Subcommand)]
enum BagCommand {
    /// What pegs will use from a bag: cameras found by the node.* templates (encodings, rates,
    /// tf chains), depth and masks, joint names matched against the configured URDF, warnings.
    Info {
        bag: PathBuf,
        /// The configuration a replay would use (its node templates and robot); defaults if none.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Subcommand)]
enum ImportFormat {
    /// The PEGS authors' sample layout (videos/*.mp4 + *.json, cameras.json, object JSON files,
    /// ground_plane.json, ground.npy); videos are decoded with the ffmpeg tool.
    EmbodiedGaussians(EmbodiedGaussiansArgs),
}

/// The configuration at `config`, with the effects of the model file at `model` (if any) added.
/// The configuration file (the defaults without one) with a model file's effects added.
fn load_with_model(
    config: Option<&std::path::Path>,
    model: Option<&std::path::Path>,
) -> Result<Config> {
    let config = match config {
        Some(path) => Config::load(path)?,
        None => Config::default(),
    };
    let Some(path) = model else { return Ok(config) };
    let model = pegs::config::ModelFile::load(path)?;
    println!(
        "model {}: {} effect(s) added",
        path.display(),
        model.effects.len()
    );
    Ok(model.apply(&config))
}

fn parse_resolution(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| format!("'{s}' is not WIDTHxHEIGHT"))?;
    let (w, h) = (
        w.parse::<u32>().map_err(|e| format!("{s}: {e}"))?,
        h.parse::<u32>().map_err(|e| format!("{s}: {e}"))?,
    );
    if w == 0 || h == 0 {
        return Err(format!("{s}: empty image"));
    }
    Ok((w, h))
}

#[derive(Subcommand)]
enum ScenarioCommand {
    /// List the scenarios.
    List,
    /// Generate and diagnose the concealed-physics scenarios, check each diagnosis against the
    /// hidden truth and print a Markdown table; with --readme, write it between the
    /// concealed-table markers of that file. Fails if a scenario's diagnosis is wrong.
    Concealed(ConcealedScenarioArgs),
    /// Generate every scenario, replay each with --compare, and print a Markdown table of the
    /// tracking errors; with --readme, write it between the scenario-table markers of that file.
    Table(TableScenarioArgs),
    /// Simulate a scenario and write DIR/recording, DIR/ground_truth.csv and DIR/config.yaml.
    Generate(GenerateScenarioArgs),
}

#[derive(Subcommand)]
enum BenchTarget {
    /// Time one physics tick for particle scenes of 1k/10k/50k and the T-block + robot scene.
    Physics(PhysicsBenchArgs),
    /// Time forward and forward+backward rendering of the 20k-Gaussian T-block scene into three
    /// cameras at 640x360 and 320x180, full frame and region of interest, per backend.
    Render(RenderBenchArgs),
    /// Time full predict + correct ticks of the pushed T-block scenario, 3 cameras at 320x180
    /// and 640x360, per backend.
    Tick(TickBenchArgs),
    /// Write an uncompressed rosbag2 bag of the resting box (3 cameras, colour, depth, masks,
    /// joint states) of --seconds, replay it and report its size and the replay's peak memory.
    Bag(BagBenchArgs),
}

#[derive(Args)]
struct BagBenchArgs {
    #[arg(long)]
    pub json: bool,
    /// Seconds of recording (at 640x360 about 150 MB per second).
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    #[arg(long, default_value_t = 360)]
    pub height: u32,
    /// Where the bag is written (kept); a temporary folder, removed after, when not given.
    #[arg(long)]
    pub dir: Option<PathBuf>,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum BackendArg {
    Cpu,
    Wgpu,
}

/// Write `table` between the `start` and `end` markers of the Markdown file `readme`, if given.
fn write_readme(readme: Option<PathBuf>, start: &str, end: &str, table: &str) -> Result<()> {
    if let Some(path) = readme {
        pegs::evaluate::write_between(&path, start, end, table)?;
        println!("updated {}", path.display());
    }
    Ok(())
}

fn load_config(path: &Option<PathBuf>) -> Result<Config> {
    match path {
        Some(p) => Config::load(p),
        None => Ok(Config::default()),
    }
}

#[derive(Args)]
struct DemoArgs {
    /// Configuration (YAML, ROS parameter-file layout); defaults apply without it.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Output directory for trajectory.csv and summary.json.
    #[arg(long, default_value = "demo_out")]
    pub out: PathBuf,
    /// Simulated seconds.
    #[arg(long, default_value_t = 5.0)]
    pub seconds: f64,
    /// Concealed scenario of the diagnosis story (generate, track, diagnose, refit, report;
    /// a few minutes), or `none` to skip it.
    #[arg(long, default_value = "concealed_drag")]
    pub story: String,
}

#[derive(Args)]
struct ReplayArgs {
    pub recording: PathBuf,
    #[arg(long)]
    pub config: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
    /// Physics only.
    #[arg(long)]
    pub no_visual_forces: bool,
    /// Visual forces only: no gravity, ground or collisions.
    #[arg(long)]
    pub no_physics: bool,
    /// Also replay physics-only and visual-forces-only and report the error ratios.
    #[arg(long, conflicts_with_all = ["no_visual_forces", "no_physics"])]
    pub compare: bool,
    /// Use only the first N cameras (by name).
    #[arg(long)]
    pub cameras: Option<usize>,
    /// Write the silhouette IoU table into this Markdown file between its real-iou markers.
    #[arg(long)]
    pub readme: Option<PathBuf>,
    /// A model file from `pegs diagnose`: its effects are added to the configuration's physics.
    #[arg(long)]
    pub model: Option<PathBuf>,
}

#[derive(Args)]
struct DiagnoseArgs {
    pub recording: PathBuf,
    #[arg(long)]
    pub config: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
    /// Start from this model file's effects (e.g. a previous diagnosis).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Fit and judge on windows where the robot pushes the object too (see the README: on
    /// another engine's recordings this names differences in contact as missing physics).
    #[arg(long)]
    pub robot_contact: bool,
}

#[derive(Args)]
struct NodeArgs {
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// A model file from `pegs diagnose`: its effects are added to the physics.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Stop after this many seconds (default: run until SIGINT / SIGTERM).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Write run statistics (JSON: tick rate, overruns, latency, memory) here on exit.
    #[arg(long)]
    pub stats: Option<PathBuf>,
    /// ROS arguments: --ros-args [-p name:=value] [--params-file FILE] [-r __node:=NAME].
    #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
    pub ros_args: Vec<String>,
}

/// Every sweep option left out takes `pegs::evaluate::ablation::SweepOptions::default()`'s value.
#[derive(Args)]
struct AblateArgs {
    #[arg(long)]
    pub out: PathBuf,
    /// Scenarios (default: two_boxes, pushed_tblock).
    #[arg(long, value_delimiter = ',')]
    pub scenarios: Option<Vec<String>>,
    /// Resolution of every run outside the resolution ablation, WxH (default: 320x180).
    #[arg(long, value_parser = parse_resolution)]
    pub base: Option<(u32, u32)>,
    /// Seconds per run (default: 4.5).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// WxH,... (default: 1280x720 to 160x90).
    #[arg(long, value_delimiter = ',', value_parser = parse_resolution)]
    pub resolutions: Option<Vec<(u32, u32)>>,
    /// Camera counts (default: 1, 2, 3).
    #[arg(long, value_delimiter = ',')]
    pub cameras: Option<Vec<usize>>,
    /// Visual-force gains, 1/s^2 (default: 500 to 6000).
    #[arg(long, value_delimiter = ',')]
    pub gains: Option<Vec<f32>>,
    /// Gaussian position learning rates (default: 0.0005 to 0.015).
    #[arg(long, value_delimiter = ',')]
    pub learning_rates: Option<Vec<f32>>,
    /// Adam iterations per tick (default: 1, 2, 5, 10).
    #[arg(long, value_delimiter = ',')]
    pub iterations: Option<Vec<u32>>,
    /// Also write the summary table into this Markdown file between its ablation markers.
    #[arg(long)]
    pub readme: Option<PathBuf>,
}

#[derive(Args)]
struct ConcealedScenarioArgs {
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, value_delimiter = ',')]
    pub scenarios: Vec<String>,
    /// The cameras' size: 160 x 90 by default, as the README's table, the demo's story and the
    /// full tier's diagnosis tests have them (320 x 180 took four times as long per render).
    #[arg(long, default_value_t = 160)]
    pub width: u32,
    #[arg(long, default_value_t = 90)]
    pub height: u32,
    #[arg(long)]
    pub readme: Option<PathBuf>,
}

#[derive(Args)]
struct TableScenarioArgs {
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 320)]
    pub width: u32,
    #[arg(long, default_value_t = 180)]
    pub height: u32,
    /// Also replay each scenario from this many more starts as far off as the table's, in
    /// directions spread evenly around the true pose (a column of their mean and range).
    #[arg(long, default_value_t = 0)]
    pub starts: usize,
    /// A parameter set in every scenario's config, by its path (`correct.pose_nudge=0`), to
    /// make the table of a setting without a build; repeatable.
    #[arg(long = "set", value_name = "PATH=VALUE")]
    pub settings: Vec<String>,
    #[arg(long)]
    pub readme: Option<PathBuf>,
}

#[derive(Args)]
struct GenerateScenarioArgs {
    pub name: String,
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    #[arg(long, default_value_t = 360)]
    pub height: u32,
    /// Recording length, s (default: the scenario's own, 4.5 s or 5.5 s for concealed ones).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Initial position error (m, along x) the replay config gives the tracker.
    #[arg(long, default_value_t = 0.01)]
    pub offset: f32,
    /// Initial rotation error about z (degrees) the replay config gives the tracker.
    #[arg(long, default_value_t = 5.0)]
    pub offset_yaw_deg: f32,
}

#[derive(Args)]
struct PhysicsBenchArgs {
    #[arg(long)]
    pub json: bool,
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Timed ticks per scene.
    #[arg(long, default_value_t = 30)]
    pub ticks: usize,
    /// Untimed ticks before timing.
    #[arg(long, default_value_t = 5)]
    pub warmup: usize,
    /// Only these scenes (cube_field_1k, cube_field_10k, cube_field_50k, tblock_robot).
    #[arg(long)]
    pub scene: Vec<String>,
}

#[derive(Args)]
struct RenderBenchArgs {
    #[arg(long)]
    pub json: bool,
    /// Timed repetitions per case.
    #[arg(long, default_value_t = 5)]
    pub repetitions: usize,
    /// Also write the full-frame renders of each camera as PNG into this directory.
    #[arg(long)]
    pub save: Option<PathBuf>,
}

#[derive(Args)]
struct TickBenchArgs {
    #[arg(long)]
    pub json: bool,
    #[arg(long, default_value_t = 10)]
    pub ticks: usize,
    /// Backends to time (default: cpu and wgpu).
    #[arg(long, value_enum)]
    pub backend: Vec<BackendArg>,
}

#[derive(Args)]
struct EmbodiedGaussiansArgs {
    pub dir: PathBuf,
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long)]
    pub config_out: PathBuf,
    /// Seconds after the first frame to start at.
    #[arg(long, default_value_t = 0.0)]
    pub start: f64,
    /// Seconds to import (all by default).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Keep at most this many frames per second per camera (0 keeps all).
    #[arg(long, default_value_t = 30.0)]
    pub max_rate: f64,
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::Demo(a) => demo(a),
        Command::Replay(a) => replay(a),
        Command::Bag {
            what: BagCommand::Info { bag, config, json },
        } => bag_info(&bag, config.as_deref(), json),
        Command::Diagnose(a) => diagnose(a),
        Command::Node(a) => node(a),
        Command::Scenario {
            what: ScenarioCommand::List,
        } => scenario_list(),
        Command::Scenario {
            what: ScenarioCommand::Generate(a),
        } => scenario_generate(a),
        Command::Scenario {
            what: ScenarioCommand::Table(a),
        } => scenario_table(a),
        Command::Scenario {
            what: ScenarioCommand::Concealed(a),
        } => scenario_concealed(a),
        Command::Ablate(a) => ablate(a),
        Command::Import {
            what: ImportFormat::EmbodiedGaussians(a),
        } => import_embodied_gaussians(a),
        Command::Bench {
            what: BenchTarget::Physics(a),
        } => bench_physics(a),
        Command::Bench {
            what: BenchTarget::Render(a),
        } => bench_render(a),
        Command::Bench {
            what: BenchTarget::Tick(a),
        } => bench_tick(a),
        Command::Bench {
            what: BenchTarget::Bag(a),
        } => bench_bag(a),
    }
}

fn demo(a: DemoArgs) -> Result<()> {
    let DemoArgs {
        config,
        out,
        seconds,
        story,
    } = a;
    let config = load_config(&config)?;
    let summary = pegs::demo::run(&config, &out, seconds)?;
    println!(
        "demo '{}': {} ticks, {} particles, {} Gaussians, {:.2} ms per tick",
        summary.scene,
        summary.ticks,
        summary.particles,
        summary.gaussians,
        summary.wall_ms_per_tick
    );
    for o in &summary.objects {
        println!(
            "  {:<8} start ({:+.3}, {:+.3}, {:+.3}) end ({:+.3}, {:+.3}, {:+.3}) travelled {:.3} m, max rigid deviation {:.2} mm",
            o.object,
            o.start[0],
            o.start[1],
            o.start[2],
            o.end[0],
            o.end[1],
            o.end[2],
            o.travelled_m,
            o.max_rigid_deviation_m * 1e3
        );
    }
    println!(
        "wrote trajectory.csv, summary.json, start.png and end.png in {}",
        out.display()
    );
    if story != "none" {
        println!("diagnosis story on {story} (a few minutes)");
        let v = pegs::demo::story(&out, &story)?;
        println!(
            "  hidden {}, named {}{}; 1 s open-loop error {:.1} -> {:.1} mm; {}",
            v.truth,
            v.named,
            v.estimate
                .zip(v.truth_value)
                .map_or(String::new(), |(e, t)| format!(" {e:.4} (truth {t:.4})")),
            v.open_loop_before_mm,
            v.open_loop_after_mm,
            if v.passed() { "passed" } else { "failed" }
        );
        println!("wrote {}", out.join("story.md").display());
    }
    Ok(())
}

fn bag_info(bag: &Path, config: Option<&Path>, json: bool) -> Result<()> {
    let config = load_config(&config.map(Path::to_path_buf))?;
    let info = pegs::replay::info(bag, &config)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&info)?);
    } else {
        print!("{info}");
    }
    if info.usable_cameras.is_empty() {
        anyhow::bail!("no usable camera in {}", bag.display());
    }
    Ok(())
}

fn replay(a: ReplayArgs) -> Result<()> {
    let ReplayArgs {
        recording,
        config,
        out,
        no_visual_forces,
        no_physics,
        compare,
        cameras,
        readme,
        model,
    } = a;
    let config = load_with_model(Some(&config), model.as_deref())?;
    let opts = pegs::replay::ReplayOptions {
        visual_forces: !no_visual_forces,
        physics: !no_physics,
        max_cameras: cameras,
        ..Default::default()
    };
    let m = if compare {
        pegs::replay::run_compare(&recording, &config, &out, true)?
    } else {
        pegs::replay::run(&recording, &config, &out, opts)?
    };
    print_replay(&m);
    println!("wrote {0}/objects.csv and {0}/metrics.json", out.display());
    write_readme(
        readme,
        pegs::replay::silhouette::TABLE_START,
        pegs::replay::silhouette::TABLE_END,
        &pegs::replay::silhouette::iou_table(&m),
    )?;
    Ok(())
}

/// What a replay measured, one line per object and measure.
fn print_replay(m: &pegs::replay::Metrics) {
    println!(
        "replayed {} ticks ({:.1} s) from cameras {:?} [{}], {:.1} ms per tick",
        m.ticks, m.seconds, m.cameras, m.mode, m.wall_ms_per_tick
    );
    for (object, e) in &m.tracking_error {
        println!(
            "  {object}: tracking error mean {:.2} mm, p95 {:.2} mm, final {:.2} mm",
            e.mean_mm, e.p95_mm, e.final_mm
        );
    }
    for (object, cams) in &m.silhouette_iou {
        for (camera, s) in cams {
            println!(
                "  {object} in {camera}: silhouette IoU mean {:.3}, p5 {:.3}; visible part {:.3}, p5 {:.3}; over {} frames",
                s.mean, s.p5, s.visible_mean, s.visible_p5, s.frames
            );
        }
    }
    for (object, c) in &m.comparison {
        println!(
            "  {object}: physics only {:.2} mm, visual forces only {:.2} mm (ratios {:.2} / {:.2})",
            c.physics_only_mean_mm,
            c.visual_forces_only_mean_mm,
            c.ratio_to_physics_only,
            c.ratio_to_visual_forces_only
        );
    }
    if m.rejected_images + m.rejected_joint_states > 0 {
        println!(
            "  rejected {} images and {} joint states (see metrics.json warnings)",
            m.rejected_images, m.rejected_joint_states
        );
    }
}

fn diagnose(a: DiagnoseArgs) -> Result<()> {
    let DiagnoseArgs {
        recording,
        config,
        out,
        model,
        robot_contact,
    } = a;
    let config = load_with_model(Some(&config), model.as_deref())?;
    let opts = pegs::diagnose::DiagnoseOptions {
        robot_contact,
        ..Default::default()
    };
    let report = pegs::diagnose::diagnose(&recording, &config, &out, opts)?;
    for o in &report.objects {
        let driven: Vec<String> = o
            .unexplained
            .iter()
            .filter(|m| m.sped_up)
            .map(|m| format!("{:.1}-{:.1} s", m.t_start, m.t_end))
            .collect();
        if !driven.is_empty() {
            println!(
                "{}: moved by something outside the model (sped up, no modelled contact, unexplained) at {}",
                o.object,
                driven.join(", ")
            );
        }
        if o.effect == "none" {
            use pegs::diagnose::report::Verdict;
            let why = match o.verdict {
                Verdict::NotEnoughEvidence => format!(
                    "not enough evidence ({} windows of motion, too few to cross-validate on)",
                    o.windows
                ),
                Verdict::ExplainedByAnother => format!(
                    "explained by {}",
                    o.explained_by.as_deref().unwrap_or("another object")
                ),
                Verdict::NotConfirmed => format!(
                    "{} not confirmed: the replay with it predicts worse ({:.1} -> {:.1} mm at 1 s)",
                    o.not_confirmed
                        .as_ref()
                        .map_or("an effect", |f| f.effect.as_str()),
                    o.before.open_loop_error_mm,
                    o.after.open_loop_error_mm
                ),
                Verdict::NotLocated => format!(
                    "not located: {} cuts the held-out 1 s error by {:.0} %, but explains no miss of 0.2 s predictions beyond {:.1} mm (the tracking noise); not named",
                    o.unlocated
                        .as_ref()
                        .map_or("an effect", |f| f.effect.as_str()),
                    o.unlocated
                        .as_ref()
                        .map_or(0.0, |f| f.heldout_gain() * 100.0),
                    o.locate_threshold_mm
                ),
                _ => "no significant missing physics in the effect library".to_string(),
            };
            println!("{}: {why}", o.object);
            continue;
        }
        let params: Vec<String> = o
            .parameters
            .iter()
            .map(|p| format!("{} {:.4} {}", p.name, p.value, p.unit))
            .collect();
        println!(
            "{}: {} ({}); held-out 1 s prediction error {:.1} -> {:.1} mm",
            o.object,
            o.effect,
            params.join(", "),
            o.before.open_loop_error_mm,
            o.after.open_loop_error_mm
        );
    }
    println!(
        "wrote {0}/report.md, {0}/report.json and {0}/model.yaml",
        out.display()
    );
    Ok(())
}

fn node(a: NodeArgs) -> Result<()> {
    let NodeArgs {
        config,
        model,
        duration,
        stats,
        ros_args,
    } = a;
    let base = load_with_model(config.as_deref(), model.as_deref())?;
    let launch = pegs::ros::params::parse_ros_args(&ros_args)?;
    let config = pegs::ros::params::launch_config(base, &launch)?;
    let s = pegs::ros::node::run(
        config,
        &launch,
        pegs::ros::node::RunOptions { duration, stats },
    )?;
    println!("{}", serde_json::to_string_pretty(&s)?);
    Ok(())
}

fn scenario_list() -> Result<()> {
    for n in pegs::scenario::all_names() {
        println!("{n:<20} {}", pegs::scenario::description(n));
    }
    Ok(())
}

fn scenario_generate(a: GenerateScenarioArgs) -> Result<()> {
    let GenerateScenarioArgs {
        name,
        out,
        width,
        height,
        seconds,
        offset,
        offset_yaw_deg,
    } = a;
    let opts = pegs::scenario::generate::GenerateOptions {
        width,
        height,
        seconds: seconds.unwrap_or_else(|| pegs::scenario::seconds(&name)),
        offset_position: glam::Vec3::new(offset, 0.0, 0.0),
        offset_yaw: offset_yaw_deg.to_radians(),
        ..Default::default()
    };
    pegs::scenario::generate::generate(&name, &out, &opts)?;
    println!(
        "wrote {0}/recording, {0}/ground_truth.csv and {0}/config.yaml",
        out.display()
    );
    Ok(())
}

fn scenario_table(a: TableScenarioArgs) -> Result<()> {
    let TableScenarioArgs {
        out,
        width,
        height,
        starts,
        settings,
        readme,
    } = a;
    // Applied as the node applies `-p PATH:=VALUE` at launch (`ros::params::launch_config`).
    let mut overrides = pegs::ros::params::LaunchArgs::default();
    for setting in &settings {
        let Some((path, value)) = setting.split_once('=') else {
            anyhow::bail!("--set {setting:?}: expected PATH=VALUE, e.g. correct.pose_nudge=0");
        };
        overrides
            .overrides
            .push((path.to_string(), value.to_string()));
    }
    let adjust = |config: Config| pegs::ros::params::launch_config(config, &overrides);
    // A setting that names no parameter, or the wrong type, stops the table before any scenario.
    adjust(Config::default()).context("--set")?;
    let opts = pegs::evaluate::scenario_table::TableOptions {
        width,
        height,
        starts,
        adjust: &adjust,
        changed: &settings,
    };
    let table = pegs::evaluate::scenario_table::run(&out, &opts)?;
    println!("{table}");
    write_readme(
        readme,
        pegs::evaluate::scenario_table::START,
        pegs::evaluate::scenario_table::END,
        &table,
    )?;
    Ok(())
}

fn scenario_concealed(a: ConcealedScenarioArgs) -> Result<()> {
    let ConcealedScenarioArgs {
        out,
        scenarios,
        width,
        height,
        readme,
    } = a;
    let names: Vec<String> = if scenarios.is_empty() {
        pegs::scenario::concealed::NAMES
            .iter()
            .map(|s| s.to_string())
            .collect()
    } else {
        scenarios
    };
    let (verdicts, table) =
        pegs::evaluate::concealed_table::run(&out, &names, width, height, true)?;
    println!("{table}");
    write_readme(
        readme,
        pegs::evaluate::concealed_table::START,
        pegs::evaluate::concealed_table::END,
        &table,
    )?;
    let failed: Vec<&str> = verdicts
        .iter()
        .filter(|v| !v.passed())
        .map(|v| v.scenario.as_str())
        .collect();
    if !failed.is_empty() {
        anyhow::bail!("diagnosis wrong for: {}", failed.join(", "));
    }
    Ok(())
}

fn ablate(a: AblateArgs) -> Result<()> {
    let AblateArgs {
        out,
        scenarios,
        base,
        seconds,
        resolutions,
        cameras,
        gains,
        learning_rates,
        iterations,
        readme,
    } = a;
    let d = pegs::evaluate::ablation::SweepOptions::default();
    let opts = pegs::evaluate::ablation::SweepOptions {
        scenarios: scenarios.unwrap_or(d.scenarios),
        base: base.unwrap_or(d.base),
        seconds: seconds.unwrap_or(d.seconds),
        resolutions: resolutions.unwrap_or(d.resolutions),
        cameras: cameras.unwrap_or(d.cameras),
        gains: gains.unwrap_or(d.gains),
        learning_rates: learning_rates.unwrap_or(d.learning_rates),
        iterations: iterations.unwrap_or(d.iterations),
    };
    let rows = pegs::evaluate::ablation::run(&opts, &out)?;
    let table = pegs::evaluate::ablation::summary_table(&rows);
    println!("{table}");
    println!("plots and runs in {}", out.display());
    let caption = pegs::evaluate::ablation::caption(&opts);
    write_readme(
        readme,
        pegs::evaluate::ablation::START,
        pegs::evaluate::ablation::END,
        &format!("{caption}\n\n{table}"),
    )?;
    Ok(())
}

fn import_embodied_gaussians(a: EmbodiedGaussiansArgs) -> Result<()> {
    let EmbodiedGaussiansArgs {
        dir,
        out,
        config_out,
        start,
        duration,
        max_rate,
    } = a;
    let opts = pegs::import::embodied_gaussians::ImportOptions {
        start,
        duration,
        max_rate,
        progress: true,
    };
    let report = pegs::import::embodied_gaussians::import(&dir, &out, &config_out, &opts)?;
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    println!(
        "imported {:.2} s to {:.2} s: {:?} frames; wrote {} and {}",
        report.first_stamp,
        report.last_stamp,
        report.frames_per_camera,
        out.display(),
        config_out.display()
    );
    Ok(())
}

fn bench_physics(a: PhysicsBenchArgs) -> Result<()> {
    let PhysicsBenchArgs {
        json,
        config,
        ticks,
        warmup,
        scene,
    } = a;
    let config = load_config(&config)?;
    let report = pegs::bench::physics(&config.physics, ticks.max(1), warmup, &scene)?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        for s in &report.scenes {
            println!(
                "{:<16} {:>6} dynamic {:>6} kinematic: {:8.2} ms/tick (median of {})",
                s.scene, s.dynamic_particles, s.kinematic_particles, s.ms_per_tick_median, s.ticks
            );
        }
    }
    Ok(())
}

fn bench_render(a: RenderBenchArgs) -> Result<()> {
    let RenderBenchArgs {
        json,
        repetitions,
        save,
    } = a;
    let report = pegs::bench::render(repetitions, save.as_deref())?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        for r in &report.runs {
            println!(
                "{:<4} {}x{} {:<4} {:>7} px/cam: forward {:8.2} ms, forward+backward {:8.2} ms ({:.2} ms per camera)",
                r.backend,
                r.resolution[0],
                r.resolution[1],
                r.window,
                r.pixels_per_camera,
                r.forward_ms,
                r.forward_backward_ms,
                r.forward_backward_ms_per_camera
            );
        }
    }
    Ok(())
}

fn bench_bag(a: BagBenchArgs) -> Result<()> {
    let temporary = a.dir.is_none();
    let dir = a.dir.unwrap_or_else(|| {
        std::env::temp_dir().join(format!("pegs-bench-bag-{}", std::process::id()))
    });
    std::fs::create_dir_all(&dir)?;
    let report = pegs::bench::bag(a.seconds, (a.width, a.height), &dir);
    if temporary {
        let _ = std::fs::remove_dir_all(&dir);
    }
    let r = report?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&r)?);
    } else {
        println!(
            "{:.1} s bag of {}x{} ({:.2} GB, {} messages, written in {:.0} s): replayed {} ticks in \
             {:.0} s ({:.1} ms per tick), peak resident memory {:.0} MB (before {:.0} MB), tracking \
             {:.2} mm",
            r.seconds,
            r.width,
            r.height,
            r.bag_bytes as f64 / 1e9,
            r.messages,
            r.write_s,
            r.ticks,
            r.replay_s,
            r.ms_per_tick,
            r.peak_rss_mb,
            r.rss_before_mb,
            r.tracking_mean_mm
        );
    }
    Ok(())
}

fn bench_tick(a: TickBenchArgs) -> Result<()> {
    let TickBenchArgs {
        json,
        ticks,
        backend,
    } = a;
    use pegs::render::Backend;
    let backends: Vec<Backend> = if backend.is_empty() {
        vec![Backend::Cpu, Backend::Wgpu]
    } else {
        backend
            .iter()
            .map(|b| match b {
                BackendArg::Cpu => Backend::Cpu,
                BackendArg::Wgpu => Backend::Wgpu,
            })
            .collect()
    };
    let report = pegs::bench::tick(ticks.max(1), &backends, &[(320, 180), (640, 360)])?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        for r in &report.runs {
            println!(
                "{:<5} {} x {}x{}: predict {:7.2} ms + correct {:8.2} ms = {:8.2} ms per tick ({:.1} ticks/s)",
                r.backend,
                r.cameras,
                r.resolution[0],
                r.resolution[1],
                r.predict_ms,
                r.correct_ms,
                r.tick_ms,
                r.ticks_per_second
            );
        }
        for s in &report.skipped {
            println!("skipped {s}");
        }
    }
    Ok(())
}

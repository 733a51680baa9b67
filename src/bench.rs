//! `pegs bench`: speed measurements printed as JSON (targets live here, not in tests).

use crate::config::PhysicsConfig;
use crate::physics::Solver;
use crate::scene::builtin::{self, Scene};
use crate::world::Phase;
use anyhow::Result;
use serde::Serialize;
use std::time::Instant;

#[derive(Debug, Serialize)]
pub struct SceneTiming {
    pub scene: String,
    pub dynamic_particles: usize,
    pub kinematic_particles: usize,
    pub shapes: usize,
    pub ticks: usize,
    pub contact_candidates: usize,
    pub ms_per_tick_median: f64,
    pub ms_per_tick_mean: f64,
    pub ms_per_tick_min: f64,
    pub ms_per_tick_max: f64,
}

#[derive(Debug, Serialize)]
pub struct PhysicsBench {
    pub benchmark: &'static str,
    pub threads: usize,
    pub dt: f32,
    pub substeps: u32,
    pub iterations: u32,
    pub scenes: Vec<SceneTiming>,
}

/// A named scene constructor.
pub type SceneMaker = (&'static str, fn() -> Scene);

/// The scenes `pegs bench physics` measures, by name.
pub fn physics_scenes() -> Vec<SceneMaker> {
    vec![
        ("cube_field_1k", || builtin::cube_field(1_000)),
        ("cube_field_10k", || builtin::cube_field(10_000)),
        ("cube_field_50k", || builtin::cube_field(50_000)),
        ("tblock_robot", builtin::tblock_and_robot),
    ]
}

pub fn physics(config: &PhysicsConfig, ticks: usize, warmup: usize, only: &[String]) -> Result<PhysicsBench> {
    let mut scenes = Vec::new();
    for (name, make) in physics_scenes() {
        if !only.is_empty() && !only.iter().any(|o| o == name) {
            continue;
        }
        let mut scene = make();
        let mut solver = Solver::new(config.clone(), &scene.world)?;
        for _ in 0..warmup {
            scene.advance(&mut solver)?;
        }
        let mut times = Vec::with_capacity(ticks);
        for _ in 0..ticks {
            let t = Instant::now();
            scene.advance(&mut solver)?;
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let mut sorted = times.clone();
        sorted.sort_by(f64::total_cmp);
        let p = &scene.world.particles;
        scenes.push(SceneTiming {
            scene: name.to_string(),
            dynamic_particles: p.phase.iter().filter(|&&ph| ph == Phase::Dynamic).count(),
            kinematic_particles: p.phase.iter().filter(|&&ph| ph == Phase::Kinematic).count(),
            shapes: scene.world.shapes.len(),
            ticks,
            contact_candidates: solver.stats.contact_candidates,
            ms_per_tick_median: sorted[sorted.len() / 2],
            ms_per_tick_mean: times.iter().sum::<f64>() / times.len() as f64,
            ms_per_tick_min: sorted[0],
            ms_per_tick_max: sorted[sorted.len() - 1],
        });
    }
    Ok(PhysicsBench {
        benchmark: "physics",
        threads: rayon::current_num_threads(),
        dt: config.dt,
        substeps: config.substeps,
        iterations: config.iterations,
        scenes,
    })
}

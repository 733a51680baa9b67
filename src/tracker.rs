//! The predict / correct loop, shared by offline replay and the live node: each tick the physics
//! predicts (robot driven by its joint trajectory), then the correction step compares renders with
//! the tick's images and leaves visual forces for the next prediction.

use crate::config::Config;
use crate::correct::{CorrectStats, Corrector, View};
use crate::physics::Solver;
use crate::scene::builtin::Scene;
use anyhow::Result;

pub struct Tracker {
    pub scene: Scene,
    pub solver: Solver,
    /// None: physics only (no visual forces).
    pub corrector: Option<Corrector>,
}

impl Tracker {
    pub fn new(scene: Scene, config: &Config, visual_forces: bool) -> Result<Self> {
        let solver = Solver::new(config.physics.clone(), &scene.world)?;
        let corrector = if visual_forces && config.correct.enabled {
            Some(Corrector::new(
                config.correct.clone(),
                config.render.clone(),
            )?)
        } else {
            None
        };
        Ok(Self {
            scene,
            solver,
            corrector,
        })
    }

    /// Predict one tick, then correct against `views` (images taken at the end of the tick).
    pub fn tick(&mut self, views: &[View]) -> Result<Option<CorrectStats>> {
        self.scene.advance(&mut self.solver)?;
        match &mut self.corrector {
            Some(c) => Ok(Some(c.correct(
                &mut self.scene.world,
                views,
                self.solver.config().dt,
            )?)),
            None => Ok(None),
        }
    }
}

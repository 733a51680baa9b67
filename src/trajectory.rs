//! Object trajectories as CSV, one row per dynamic object per tick, world frame, metres, ROS
//! quaternion order: `t,object,x,y,z,qx,qy,qz,qw`. The same layout as `pegs replay`'s objects.csv
//! (where the writer observes the ticks); particles of deformable objects likewise.

use crate::tracker::{Observer, Tick, Tracker};
use crate::world::World;
use anyhow::{Context, Result};
use std::io::Write;
use std::path::Path;

pub const HEADER: &str = "t,object,x,y,z,qx,qy,qz,qw";

/// A buffered CSV file that starts with `header`.
fn create_csv(path: &Path, header: &str) -> Result<std::io::BufWriter<std::fs::File>> {
    let file =
        std::fs::File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    let mut out = std::io::BufWriter::new(file);
    writeln!(out, "{header}")?;
    Ok(out)
}

pub struct TrajectoryWriter {
    out: std::io::BufWriter<std::fs::File>,
}

impl TrajectoryWriter {
    pub fn create(path: &Path) -> Result<Self> {
        Ok(Self {
            out: create_csv(path, HEADER)?,
        })
    }

    /// Append the pose of every dynamic object at the world's current time.
    pub fn record(&mut self, world: &World) -> Result<()> {
        for s in world.shapes.dynamic_ids() {
            let pose = world.shapes.pose[s as usize];
            let (p, q) = (pose.translation, pose.rotation);
            writeln!(
                self.out,
                "{:.6},{},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6}",
                world.time, world.shapes.name[s as usize], p.x, p.y, p.z, q.x, q.y, q.z, q.w
            )?;
        }
        Ok(())
    }

    pub fn finish(&mut self) -> Result<()> {
        self.out.flush().context("cannot write trajectory")
    }
}

/// As an observer: the start state, then the state after every tick.
impl Observer for TrajectoryWriter {
    fn start(&mut self, tracker: &Tracker) -> Result<()> {
        self.record(tracker.world())
    }

    fn tick(&mut self, tick: &Tick) -> Result<()> {
        self.record(tick.tracker.world())
    }
}

/// Particle positions of deformable objects (ropes), whose pose alone does not say where their
/// material points are: `t,object,particle,x,y,z`, particle numbered within its object.
pub const PARTICLE_HEADER: &str = "t,object,particle,x,y,z";

pub struct ParticleWriter {
    out: std::io::BufWriter<std::fs::File>,
}

impl ParticleWriter {
    pub fn create(path: &Path) -> Result<Self> {
        Ok(Self {
            out: create_csv(path, PARTICLE_HEADER)?,
        })
    }

    /// Append every rope particle at the world's current time.
    pub fn record(&mut self, world: &World) -> Result<()> {
        for s in world
            .shapes
            .dynamic_ids()
            .filter(|&s| world.shapes.kind[s as usize] == crate::world::ShapeKind::Rope)
        {
            for (k, i) in world.shapes.range(s).enumerate() {
                let p = world.particles.position[i];
                writeln!(
                    self.out,
                    "{:.6},{},{k},{:.6},{:.6},{:.6}",
                    world.time, world.shapes.name[s as usize], p.x, p.y, p.z
                )?;
            }
        }
        Ok(())
    }

    pub fn finish(mut self) -> Result<()> {
        self.out.flush().context("cannot write particle trajectory")
    }
}

//! Shapes group particles into objects: rigid shape-matching groups, rope chains, kinematic robot
//! links and static fixtures. A shape's particles are one contiguous index range.

use crate::math::Pose;
use serde::{Deserialize, Serialize};
use std::ops::Range;

pub type ShapeId = u32;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ShapeKind {
    /// Shape matching keeps the particles at their rest configuration (one rigid object).
    Rigid,
    /// A chain held by distance and bending constraints.
    Rope,
    /// Follows a prescribed pose (robot link, pusher).
    Kinematic,
    /// Never moves.
    Static,
}

/// Structure of arrays over shapes.
#[derive(Clone, Debug, Default)]
pub struct Shapes {
    pub name: Vec<String>,
    pub kind: Vec<ShapeKind>,
    pub first_particle: Vec<u32>,
    pub particle_count: Vec<u32>,
    /// Body frame to world. Rigid: from shape matching; kinematic: the prescribed pose;
    /// rope: centroid with identity rotation.
    pub pose: Vec<Pose>,
    /// Kinematic shapes: the pose to reach at the end of the coming tick.
    pub target: Vec<Pose>,
}

impl Shapes {
    pub fn len(&self) -> usize {
        self.name.len()
    }

    pub fn is_empty(&self) -> bool {
        self.name.is_empty()
    }

    pub fn range(&self, s: ShapeId) -> Range<usize> {
        let first = self.first_particle[s as usize] as usize;
        first..first + self.particle_count[s as usize] as usize
    }

    pub fn push(&mut self, name: &str, kind: ShapeKind, particles: Range<usize>, pose: Pose) -> ShapeId {
        self.name.push(name.to_string());
        self.kind.push(kind);
        self.first_particle.push(particles.start as u32);
        self.particle_count.push((particles.end - particles.start) as u32);
        self.pose.push(pose);
        self.target.push(pose);
        (self.name.len() - 1) as ShapeId
    }

    /// Ids of the shapes that physics moves (rigid objects and ropes).
    pub fn dynamic_ids(&self) -> impl Iterator<Item = ShapeId> + '_ {
        (0..self.len() as ShapeId).filter(|&s| matches!(self.kind[s as usize], ShapeKind::Rigid | ShapeKind::Rope))
    }
}

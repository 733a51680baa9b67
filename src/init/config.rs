//! The `scene` section of the configuration: where the tracker's world comes from (a built-in
//! scenario, objects from files, objects from the first RGB-D frames) and the table fitted to the
//! first frames. Validated here, beside the initialisation it configures.

use super::ColourMask;
use anyhow::{Result, bail};
use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Where the tracker's world comes from: a built-in scenario's world (with its tracked object
/// moved by an initial pose error), or objects loaded from files plus a table fitted to the first
/// frames (`init`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SceneConfig {
    /// A name from `pegs scenario list`; when set, `objects` and `table` are not used.
    pub scenario: Option<String>,
    /// Initial pose error of the scenario's tracked object: translation (m) and rotation about z (rad).
    pub offset_position: Vec3,
    pub offset_yaw: f32,
    /// Objects loaded from files.
    pub objects: Vec<ObjectConfig>,
    /// Objects built from the first frames' depth and instance masks (`node.depth_topic`,
    /// `node.mask_topic`; without masks, clusters of depth points, largest first).
    pub rgbd_objects: Vec<RgbdObjectConfig>,
    /// Fit the ground plane to the first depth frames (RANSAC) instead of `physics.ground`.
    pub ground_from_depth: bool,
    /// The table as thin-disk Gaussians on the ground plane, fitted to the first frames.
    pub table: Option<TableConfig>,
}

/// An object found in the first RGB-D frames by its instance-mask label.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RgbdObjectConfig {
    pub name: String,
    /// Its value in the mask images (1..=255).
    pub label: u8,
    /// Total mass, kg.
    pub mass: f32,
    pub particle_radius: f32,
    /// A rope (a chain of particles along its centre line) instead of a rigid object.
    pub rope: bool,
    /// Rope only: stiffness of the bending constraints in (0, 1].
    pub bending_stiffness: f32,
}

impl Default for RgbdObjectConfig {
    fn default() -> Self {
        Self {
            name: String::new(),
            label: 1,
            mass: 0.2,
            particle_radius: 0.005,
            rope: false,
            bending_stiffness: 0.3,
        }
    }
}

/// One tracked object loaded from a file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObjectConfig {
    pub name: String,
    /// Object file in the embodied-gaussians JSON format (pose, Gaussians, particles).
    pub embodied_gaussians: PathBuf,
    /// Total mass, kg, shared equally by the particles.
    pub mass: f32,
    /// Colour band that picks this object out of the images: aligns it at the start and measures
    /// the silhouette overlap of the tracking in `pegs replay`.
    pub mask: Option<ColourMask>,
    /// Before tracking, move the object on the table to best match `mask` in the first frames.
    pub align_at_start: bool,
    /// Adam steps fitting the object's colours to the inside of `mask` in the first frame, after
    /// the alignment (the file's colours were captured under other lighting); 0 keeps them.
    pub colour_fit_steps: u32,
    /// Adam steps fitting the Gaussians' opacities and sizes to `mask` in the first frames, after
    /// the table is fitted; 0 keeps them.
    pub silhouette_fit_steps: u32,
}

impl Default for ObjectConfig {
    fn default() -> Self {
        Self {
            name: String::new(),
            embodied_gaussians: PathBuf::new(),
            mass: 0.2,
            mask: None,
            align_at_start: true,
            colour_fit_steps: 100,
            silhouette_fit_steps: 100,
        }
    }
}

/// The table: a grid of flat Gaussians on the ground plane over a rectangle of world x, y.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TableConfig {
    pub min: Vec2,
    pub max: Vec2,
    /// Grid spacing, m.
    pub spacing: f32,
    /// Adam steps on the disks' colours, and frames used per camera: the first one and others
    /// spread over the first `fit_span` seconds (0: the first frames).
    pub fit_steps: u32,
    pub fit_frames: u32,
    pub fit_span: f32,
    pub lr: f32,
    /// The fit renders at this fraction of the camera resolution (the disks are coarser than pixels).
    pub fit_resolution: f32,
    /// The disks lie this far (m) below the ground plane: object Gaussians that reach into the
    /// table (the soft bottom of a reconstruction) would otherwise be hidden by it, and the
    /// photometric loss would lift the object to show them.
    pub drop: f32,
}

impl Default for TableConfig {
    fn default() -> Self {
        Self {
            min: Vec2::splat(-0.5),
            max: Vec2::splat(0.5),
            spacing: 0.01,
            fit_steps: 500,
            fit_frames: 3,
            fit_span: 0.0,
            lr: 0.02,
            fit_resolution: 0.5,
            drop: 0.01,
        }
    }
}

impl SceneConfig {
    /// Refused when nothing would be tracked: no scenario, no object files, no RGB-D objects.
    pub fn check_tracks_something(&self) -> Result<()> {
        if self.scenario.is_none() && self.objects.is_empty() && self.rgbd_objects.is_empty() {
            bail!(
                "the configuration names no scene.scenario, scene.objects or scene.rgbd_objects: \
                 nothing to track (e.g. scene.rgbd_objects: [{{name: box, label: 1, mass: 0.2}}])"
            );
        }
        Ok(())
    }

    /// Relative file paths (object files) made relative to `dir`, the configuration's folder.
    pub fn resolve_paths(&mut self, dir: &std::path::Path) {
        for o in &mut self.objects {
            if o.embodied_gaussians.is_relative() {
                o.embodied_gaussians = dir.join(&o.embodied_gaussians);
            }
        }
    }

    pub fn validate(&self) -> Result<()> {
        for o in &self.objects {
            if o.name.is_empty() || !(o.mass.is_finite() && o.mass > 0.0) {
                bail!(
                    "scene.objects: every object needs a name and a positive mass ('{}', {})",
                    o.name,
                    o.mass
                );
            }
        }
        for o in &self.rgbd_objects {
            if o.name.is_empty()
                || o.label == 0
                || !(o.mass.is_finite() && o.mass > 0.0)
                || !(o.particle_radius.is_finite() && o.particle_radius > 0.0)
            {
                bail!(
                    "scene.rgbd_objects: '{}' needs a name, a label of 1 to 255, a positive mass and particle radius",
                    o.name
                );
            }
            if o.rope && !(o.bending_stiffness > 0.0 && o.bending_stiffness <= 1.0) {
                bail!(
                    "scene.rgbd_objects: rope '{}' needs bending_stiffness in (0, 1]",
                    o.name
                );
            }
        }
        if let Some(t) = &self.table {
            let cells = ((t.max - t.min) / t.spacing).max_element();
            let positive = t.spacing.is_finite() && t.spacing > 0.0;
            if !positive || !t.min.cmplt(t.max).all() || cells.is_nan() || cells > 2000.0 {
                bail!(
                    "scene.table: spacing must be positive, min below max, at most 2000 disks a side"
                );
            }
            let in_unit = t.fit_resolution > 0.0 && t.fit_resolution <= 1.0;
            let lr = t.lr.is_finite() && t.lr >= 0.0;
            let span = t.fit_span.is_finite() && t.fit_span >= 0.0;
            if !in_unit || !lr || !span || !t.drop.is_finite() {
                bail!("scene.table: fit_resolution in (0, 1], lr and fit_span >= 0, drop finite");
            }
        }
        Ok(())
    }
}

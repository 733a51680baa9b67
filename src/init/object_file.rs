//! Object files in the embodied-gaussians JSON format (the PEGS authors' layout): the body-to-world
//! pose at capture time (row-major 4x4), Gaussians with w,x,y,z quaternions and B,G,R colours, and
//! particles, all in the body frame. Their conventions are converted here, at the boundary, into
//! the neutral `ObjectModel` (x,y,z,w quaternions, RGB); nothing else reads the format.

use crate::math::Pose;
use crate::world::{BodyGaussian, ObjectModel};
use anyhow::{Context, Result, bail};
use glam::{DMat3, DQuat, DVec3, Quat, Vec3};
use serde::Deserialize;
use std::path::Path;

#[derive(Deserialize)]
struct GaussianSet {
    means: Vec<[f32; 3]>,
    /// w, x, y, z.
    quats: Vec<[f32; 4]>,
    /// Standard deviations, m.
    scales: Vec<[f32; 3]>,
    opacities: Vec<f32>,
    /// B, G, R in (0, 1).
    colors: Vec<[f32; 3]>,
}

#[derive(Deserialize)]
struct ParticleSet {
    means: Vec<[f32; 3]>,
    radii: Vec<f32>,
}

/// An object file: body-to-world pose at capture time, Gaussians and particles in the body frame.
#[derive(Deserialize)]
struct ObjectFile {
    name: String,
    #[serde(rename = "X_WB")]
    x_wb: [[f64; 4]; 4],
    gaussians: GaussianSet,
    particles: ParticleSet,
}

/// A row-major 4x4 rigid transform as a `Pose`; rejects matrices that are not rigid.
pub fn pose_from_rows(m: &[[f64; 4]; 4]) -> Result<Pose> {
    let r = DMat3::from_cols(
        DVec3::new(m[0][0], m[1][0], m[2][0]),
        DVec3::new(m[0][1], m[1][1], m[2][1]),
        DVec3::new(m[0][2], m[1][2], m[2][2]),
    );
    let t = DVec3::new(m[0][3], m[1][3], m[2][3]);
    let orthonormality = (r.transpose() * r - DMat3::IDENTITY)
        .to_cols_array()
        .iter()
        .fold(0.0f64, |a, v| a.max(v.abs()));
    if !t.is_finite()
        || orthonormality > 1e-3
        || (r.determinant() - 1.0).abs() > 1e-3
        || m[3] != [0.0, 0.0, 0.0, 1.0]
    {
        bail!(
            "not a rigid transform (rotation off by {orthonormality:.1e}, det {:.4})",
            r.determinant()
        );
    }
    let q = DQuat::from_mat3(&r).normalize();
    Ok(Pose::new(t.as_vec3(), q.as_quat().normalize()))
}

/// A quaternion stored w, x, y, z.
pub fn quat_from_wxyz(q: [f32; 4]) -> Quat {
    Quat::from_xyzw(q[1], q[2], q[3], q[0]).normalize()
}

/// A colour stored B, G, R.
pub fn rgb_from_bgr(c: [f32; 3]) -> Vec3 {
    Vec3::new(c[2], c[1], c[0])
}

/// A JSON file as `T`, naming the file in every error.
pub fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{} is not in the expected format", path.display()))
}

/// Load an object file into the neutral object model (RGB colours, x,y,z,w quaternions).
pub fn load_object(path: &Path) -> Result<ObjectModel> {
    let f: ObjectFile = read_json(path)?;
    let g = &f.gaussians;
    let n = g.means.len();
    if [
        g.quats.len(),
        g.scales.len(),
        g.opacities.len(),
        g.colors.len(),
    ]
    .iter()
    .any(|&k| k != n)
    {
        bail!(
            "{}: the Gaussian arrays have different lengths",
            path.display()
        );
    }
    if f.particles.means.len() != f.particles.radii.len() || f.particles.means.is_empty() {
        bail!(
            "{}: particles need as many radii as means, and at least one",
            path.display()
        );
    }
    let gaussians: Vec<BodyGaussian> = (0..n)
        .map(|i| BodyGaussian {
            mean: Vec3::from_array(g.means[i]),
            rotation: quat_from_wxyz(g.quats[i]),
            scale: Vec3::from_array(g.scales[i]),
            opacity: g.opacities[i],
            colour: rgb_from_bgr(g.colors[i]),
        })
        .collect();
    let particles: Vec<(Vec3, f32)> = f
        .particles
        .means
        .iter()
        .zip(&f.particles.radii)
        .map(|(m, r)| (Vec3::from_array(*m), *r))
        .collect();
    let finite = gaussians.iter().all(|g| {
        g.mean.is_finite()
            && g.rotation.is_finite()
            && g.scale.is_finite()
            && g.scale.min_element() > 0.0
            && g.opacity.is_finite()
            && g.colour.is_finite()
    }) && particles
        .iter()
        .all(|(p, r)| p.is_finite() && r.is_finite() && *r > 0.0);
    if !finite {
        bail!(
            "{}: non-finite or non-positive values in Gaussians or particles",
            path.display()
        );
    }
    let pose = pose_from_rows(&f.x_wb).with_context(|| format!("{}: X_WB", path.display()))?;
    Ok(ObjectModel {
        name: f.name,
        pose,
        particles,
        gaussians,
    })
}

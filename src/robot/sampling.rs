//! Particle positions over link geometry, in the geometry's own frame: surface samples at a given
//! spacing (primitives analytically, meshes by subdividing triangles), or a volume lattice for
//! primitives. Points closer than the spacing are merged on a voxel grid so density is even.

use super::model::Shape;
use glam::DVec3;
use std::collections::HashSet;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Sampling {
    #[default]
    Surface,
    /// Primitives are filled; meshes (whose inside is not known reliably) are sampled on the surface.
    Volume,
}

/// `shape` shrunk by `by` on every side (a primitive's sizes less `by`, never below zero), so that
/// spheres of radius `by` centred on its surface fill the original shape and no more. Meshes are
/// returned as they are: their inside is not known reliably.
pub fn inset(shape: &Shape, by: f64) -> Shape {
    let less = |x: f64| (x - by).max(0.0);
    match shape {
        Shape::Box { size } => Shape::Box {
            size: (*size - DVec3::splat(2.0 * by)).max(DVec3::ZERO),
        },
        Shape::Cylinder { radius, length } => Shape::Cylinder {
            radius: less(*radius),
            length: (length - 2.0 * by).max(0.0),
        },
        // The caps shrink with the radius: the length between their centres stays.
        Shape::Capsule { radius, length } => Shape::Capsule {
            radius: less(*radius),
            length: *length,
        },
        Shape::Sphere { radius } => Shape::Sphere {
            radius: less(*radius),
        },
        mesh @ Shape::Mesh { .. } => mesh.clone(),
    }
}

/// Keep one point per cubic cell of edge `spacing` (the first in input order: deterministic).
pub fn thin(points: Vec<DVec3>, spacing: f64) -> Vec<DVec3> {
    let mut seen = HashSet::new();
    points
        .into_iter()
        .filter(|p| seen.insert((*p / spacing).floor().as_ivec3()))
        .collect()
}

fn steps(length: f64, spacing: f64) -> usize {
    ((length / spacing).ceil() as usize).max(1)
}

/// Evenly spaced values covering [-half, half] inclusive.
fn span(half: f64, spacing: f64) -> Vec<f64> {
    let n = steps(2.0 * half, spacing);
    (0..=n)
        .map(|k| -half + 2.0 * half * k as f64 / n as f64)
        .collect()
}

fn disc(radius: f64, spacing: f64, z: f64, out: &mut Vec<DVec3>) {
    out.push(DVec3::new(0.0, 0.0, z));
    let rings = steps(radius, spacing);
    for r in 1..=rings {
        let rr = radius * r as f64 / rings as f64;
        let n = steps(std::f64::consts::TAU * rr, spacing);
        for k in 0..n {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            out.push(DVec3::new(rr * a.cos(), rr * a.sin(), z));
        }
    }
}

fn sphere_surface(
    radius: f64,
    spacing: f64,
    centre: DVec3,
    keep: impl Fn(DVec3) -> bool,
    out: &mut Vec<DVec3>,
) {
    // Fibonacci lattice: near-uniform points, about one per spacing^2 of area.
    let n = ((4.0 * std::f64::consts::PI * radius * radius) / (spacing * spacing))
        .ceil()
        .max(1.0) as usize;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    for k in 0..n {
        let z = 1.0 - 2.0 * (k as f64 + 0.5) / n as f64;
        let r = (1.0 - z * z).sqrt();
        let a = golden * k as f64;
        let d = DVec3::new(r * a.cos(), r * a.sin(), z);
        if keep(d) {
            out.push(centre + radius * d);
        }
    }
}

fn triangle_surface(t: &[DVec3; 3], spacing: f64, out: &mut Vec<DVec3>) {
    let longest = (t[1] - t[0])
        .length()
        .max((t[2] - t[1]).length())
        .max((t[0] - t[2]).length());
    let n = steps(longest, spacing * 0.5);
    for i in 0..=n {
        for j in 0..=(n - i) {
            let (a, b) = (i as f64 / n as f64, j as f64 / n as f64);
            out.push(t[0] + a * (t[1] - t[0]) + b * (t[2] - t[0]));
        }
    }
}

/// Sample `shape` at `spacing`.
pub fn sample(shape: &Shape, spacing: f64, mode: Sampling) -> Vec<DVec3> {
    let mut pts = Vec::new();
    match (shape, mode) {
        (Shape::Box { size }, Sampling::Surface) => {
            let h = *size / 2.0;
            for (axis, other) in [(0usize, [1usize, 2usize]), (1, [0, 2]), (2, [0, 1])] {
                for sign in [-1.0, 1.0] {
                    for u in span(h[other[0]], spacing) {
                        for v in span(h[other[1]], spacing) {
                            let mut p = DVec3::ZERO;
                            p[axis] = sign * h[axis];
                            p[other[0]] = u;
                            p[other[1]] = v;
                            pts.push(p);
                        }
                    }
                }
            }
        }
        (Shape::Box { size }, Sampling::Volume) => {
            let h = *size / 2.0;
            for x in span(h.x, spacing) {
                for y in span(h.y, spacing) {
                    for z in span(h.z, spacing) {
                        pts.push(DVec3::new(x, y, z));
                    }
                }
            }
        }
        (Shape::Cylinder { radius, length }, mode) => {
            let half = length / 2.0;
            for z in span(half, spacing) {
                let n = steps(std::f64::consts::TAU * radius, spacing);
                for k in 0..n {
                    let a = std::f64::consts::TAU * k as f64 / n as f64;
                    pts.push(DVec3::new(radius * a.cos(), radius * a.sin(), z));
                }
                if mode == Sampling::Volume {
                    disc(radius - spacing, spacing, z, &mut pts);
                }
            }
            disc(*radius, spacing, -half, &mut pts);
            disc(*radius, spacing, half, &mut pts);
        }
        (Shape::Capsule { radius, length }, mode) => {
            let half = length / 2.0;
            let cylinder = Shape::Cylinder {
                radius: *radius,
                length: *length,
            };
            pts.extend(
                sample(&cylinder, spacing, mode)
                    .into_iter()
                    .filter(|p| p.z.abs() < half - 1e-9 || mode == Sampling::Volume),
            );
            sphere_surface(
                *radius,
                spacing,
                DVec3::new(0.0, 0.0, half),
                |d| d.z >= 0.0,
                &mut pts,
            );
            sphere_surface(
                *radius,
                spacing,
                DVec3::new(0.0, 0.0, -half),
                |d| d.z <= 0.0,
                &mut pts,
            );
        }
        (Shape::Sphere { radius }, Sampling::Surface) => {
            sphere_surface(*radius, spacing, DVec3::ZERO, |_| true, &mut pts)
        }
        (Shape::Sphere { radius }, Sampling::Volume) => {
            for x in span(*radius, spacing) {
                for y in span(*radius, spacing) {
                    for z in span(*radius, spacing) {
                        let p = DVec3::new(x, y, z);
                        if p.length() <= *radius {
                            pts.push(p);
                        }
                    }
                }
            }
            sphere_surface(*radius, spacing, DVec3::ZERO, |_| true, &mut pts);
        }
        (Shape::Mesh { triangles, .. }, _) => {
            for t in triangles {
                triangle_surface(t, spacing, &mut pts);
            }
        }
    }
    thin(pts, spacing)
}

/// Distance from `p` to the surface of `shape` (for primitives; meshes: to the nearest triangle).
pub fn distance_to_surface(shape: &Shape, p: DVec3) -> f64 {
    match shape {
        Shape::Box { size } => {
            let q = p.abs() - *size / 2.0;
            let outside = q.max(DVec3::ZERO).length();
            let inside = q.max_element().min(0.0);
            (outside + inside).abs()
        }
        Shape::Cylinder { radius, length } => {
            let d = DVec3::new(
                p.truncate().length() - radius,
                p.z.abs() - length / 2.0,
                0.0,
            );
            let outside = DVec3::new(d.x.max(0.0), d.y.max(0.0), 0.0).length();
            (outside + d.x.max(d.y).min(0.0)).abs()
        }
        Shape::Capsule { radius, length } => {
            let z = p.z.clamp(-length / 2.0, length / 2.0);
            ((p - DVec3::new(0.0, 0.0, z)).length() - radius).abs()
        }
        Shape::Sphere { radius } => (p.length() - radius).abs(),
        Shape::Mesh { triangles, .. } => triangles
            .iter()
            .map(|t| point_triangle_distance(p, t))
            .fold(f64::INFINITY, f64::min),
    }
}

fn point_triangle_distance(p: DVec3, t: &[DVec3; 3]) -> f64 {
    // Closest point by barycentric region tests (Ericson, Real-Time Collision Detection, 5.1.5).
    let (a, b, c) = (t[0], t[1], t[2]);
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return (p - a).length();
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return (p - b).length();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return (p - (a + ab * (d1 / (d1 - d3)))).length();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return (p - c).length();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return (p - (a + ac * (d2 / (d2 - d6)))).length();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return (p - (b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))))).length();
    }
    let denom = 1.0 / (va + vb + vc);
    (p - (a + ab * (vb * denom) + ac * (vc * denom))).length()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn surface_samples_lie_on_the_surface_and_cover_it() {
        let shapes = [
            Shape::Box {
                size: DVec3::new(0.2, 0.1, 0.05),
            },
            Shape::Cylinder {
                radius: 0.05,
                length: 0.3,
            },
            Shape::Capsule {
                radius: 0.04,
                length: 0.2,
            },
            Shape::Sphere { radius: 0.07 },
        ];
        let spacing = 0.01;
        for s in &shapes {
            let pts = sample(s, spacing, Sampling::Surface);
            assert!(pts.len() > 50, "{s:?}: {} points", pts.len());
            for p in &pts {
                assert!(
                    distance_to_surface(s, *p) < 1e-9,
                    "{s:?}: {p} off the surface"
                );
            }
            // Coverage: probe points on the surface have a sample within 1.5 spacings.
            let probe = sample(s, spacing / 3.0, Sampling::Surface);
            let worst = probe
                .iter()
                .map(|q| {
                    pts.iter()
                        .map(|p| (*p - *q).length())
                        .fold(f64::INFINITY, f64::min)
                })
                .fold(0.0, f64::max);
            assert!(
                worst < 1.5 * spacing,
                "{s:?}: a surface point is {worst} m from any sample"
            );
        }
    }

    #[test]
    fn spheres_on_an_inset_surface_reach_the_original_surface_and_no_further() {
        let by = 0.006;
        let shapes = [
            Shape::Box {
                size: DVec3::new(0.2, 0.1, 0.05),
            },
            Shape::Cylinder {
                radius: 0.015,
                length: 0.152,
            },
            Shape::Capsule {
                radius: 0.03,
                length: 0.1,
            },
            Shape::Sphere { radius: 0.04 },
        ];
        for shape in &shapes {
            let pts = sample(&inset(shape, by), 0.004, Sampling::Surface);
            assert!(!pts.is_empty());
            // Along each axis, the furthest sphere reaches the original extent.
            for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
                let reach = pts.iter().map(|p| p.dot(axis)).fold(f64::MIN, f64::max) + by;
                let extent = match shape {
                    Shape::Box { size } => size.dot(axis) / 2.0,
                    Shape::Cylinder { radius, length } if axis == DVec3::Z => length / 2.0,
                    Shape::Cylinder { radius, .. } => *radius,
                    Shape::Capsule { radius, length } if axis == DVec3::Z => length / 2.0 + radius,
                    Shape::Capsule { radius, .. } | Shape::Sphere { radius } => *radius,
                    Shape::Mesh { .. } => unreachable!(),
                };
                assert!(
                    (reach - extent).abs() < 1e-3,
                    "{shape:?} along {axis}: spheres reach {reach}, the shape {extent}"
                );
            }
        }
    }

    #[test]
    fn mesh_samples_cover_its_triangles() {
        // A unit-square of two triangles, 10 cm.
        let t = vec![
            [
                DVec3::ZERO,
                DVec3::new(0.1, 0.0, 0.0),
                DVec3::new(0.1, 0.1, 0.0),
            ],
            [
                DVec3::ZERO,
                DVec3::new(0.1, 0.1, 0.0),
                DVec3::new(0.0, 0.1, 0.0),
            ],
        ];
        let mesh = Shape::Mesh {
            triangles: t,
            source: "square".into(),
        };
        let pts = sample(&mesh, 0.01, Sampling::Surface);
        assert!(
            pts.iter()
                .all(|p| p.z.abs() < 1e-12 && distance_to_surface(&mesh, *p) < 1e-12)
        );
        assert!(
            (80..=200).contains(&pts.len()),
            "{} points for 100 cm^2 at 1 cm",
            pts.len()
        );
    }

    #[test]
    fn volume_lattice_fills_primitives() {
        let pts = sample(
            &Shape::Box {
                size: DVec3::splat(0.1),
            },
            0.01,
            Sampling::Volume,
        );
        assert!(pts.iter().any(|p| p.length() < 0.006), "centre is filled");
        assert!(pts.iter().all(|p| p.abs().max_element() <= 0.05 + 1e-12));
    }
}

//! Particle centres filling primitive solids, in the solid's body frame (centred at the origin).
//! Spheres of radius `spacing / 2` at these centres fit inside the solid and touch their neighbours.

use glam::Vec3;

/// Number of particles along an edge of length `2 * half` at `spacing` (at least one).
fn count_along(half: f32, spacing: f32) -> usize {
    ((2.0 * half / spacing) + 1e-4).floor().max(1.0) as usize
}

/// Centres along one axis, symmetric about zero.
fn axis(half: f32, spacing: f32) -> Vec<f32> {
    let n = count_along(half, spacing);
    (0..n)
        .map(|k| (k as f32 - (n - 1) as f32 / 2.0) * spacing)
        .collect()
}

/// A box with half extents `half`, body origin at its centre.
pub fn box_lattice(half: Vec3, spacing: f32) -> Vec<Vec3> {
    let (xs, ys, zs) = (
        axis(half.x, spacing),
        axis(half.y, spacing),
        axis(half.z, spacing),
    );
    let mut out = Vec::with_capacity(xs.len() * ys.len() * zs.len());
    for &z in &zs {
        for &y in &ys {
            for &x in &xs {
                out.push(Vec3::new(x, y, z));
            }
        }
    }
    out
}

/// A vertical cylinder (axis z) of `radius` and `height`, body origin at its centre.
pub fn cylinder_lattice(radius: f32, height: f32, spacing: f32) -> Vec<Vec3> {
    let zs = axis(height / 2.0, spacing);
    let xs = axis(radius, spacing);
    let inner = (radius - spacing / 2.0).max(0.0);
    let mut out = Vec::new();
    for &z in &zs {
        for &y in &xs {
            for &x in &xs {
                if x * x + y * y <= inner * inner + 1e-9 {
                    out.push(Vec3::new(x, y, z));
                }
            }
        }
    }
    if out.is_empty() {
        out.extend(zs.iter().map(|&z| Vec3::new(0.0, 0.0, z)));
    }
    out
}

/// The push-T block: a `width` x `bar` top bar and a `bar` wide stem, `width` long overall, of
/// `thickness`. Body frame: x along the bar, y along the stem (bar at +y), z up, origin at the
/// bounding-box centre. The paper's block is 0.2 x 0.2 m with 0.05 m bars and 0.04 m thick.
pub fn t_block_lattice(width: f32, bar: f32, thickness: f32, spacing: f32) -> Vec<Vec3> {
    let half = width / 2.0;
    let top = box_lattice(Vec3::new(half, bar / 2.0, thickness / 2.0), spacing)
        .into_iter()
        .map(|p| p + Vec3::new(0.0, half - bar / 2.0, 0.0));
    let stem_len = width - bar;
    let stem = box_lattice(
        Vec3::new(bar / 2.0, stem_len / 2.0, thickness / 2.0),
        spacing,
    )
    .into_iter()
    .map(|p| p + Vec3::new(0.0, -half + stem_len / 2.0, 0.0));
    top.chain(stem).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_lattice_fills_the_box_and_touches_its_faces() {
        let pts = box_lattice(Vec3::new(0.05, 0.03, 0.02), 0.01);
        assert_eq!(pts.len(), 10 * 6 * 4);
        let max = pts.iter().fold(Vec3::splat(-1.0), |m, p| m.max(*p));
        // Outermost centres sit half a spacing inside each face.
        assert!((max - Vec3::new(0.045, 0.025, 0.015)).length() < 1e-6);
        let mean: Vec3 = pts.iter().copied().sum::<Vec3>() / pts.len() as f32;
        assert!(mean.length() < 1e-6);
    }

    #[test]
    fn t_block_has_the_expected_extent() {
        let pts = t_block_lattice(0.2, 0.05, 0.04, 0.0125);
        let min = pts.iter().fold(Vec3::splat(1.0), |m, p| m.min(*p));
        let max = pts.iter().fold(Vec3::splat(-1.0), |m, p| m.max(*p));
        assert!((max.x - min.x - (0.2 - 0.0125)).abs() < 1e-5);
        assert!((max.y - min.y - (0.2 - 0.0125)).abs() < 1e-5);
        // The stem is narrow: no particle below the bar is farther than 2.5 cm from x = 0.
        assert!(pts.iter().filter(|p| p.y < 0.05).all(|p| p.x.abs() < 0.025));
    }

    #[test]
    fn cylinder_lattice_stays_inside_the_cylinder() {
        let pts = cylinder_lattice(0.02, 0.1, 0.01);
        assert!(!pts.is_empty());
        assert!(
            pts.iter().all(
                |p| (p.x * p.x + p.y * p.y).sqrt() <= 0.015 + 1e-6 && p.z.abs() <= 0.045 + 1e-6
            )
        );
    }
}

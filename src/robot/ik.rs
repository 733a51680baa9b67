//! Inverse kinematics for scripted motions (demos, synthetic scenarios): damped least squares on
//! a point of one link and the direction of one of its axes, with a finite-difference Jacobian of
//! the model's own forward kinematics. Joint limits are respected by clamping.

use super::model::{JointKind, RobotModel};
use glam::DVec3;

/// What the end effector should do: bring `point` (in `link`'s frame) to `target` and, if given,
/// point the link's `axis` along `direction` (world frame of the model root).
#[derive(Clone, Debug)]
pub struct IkGoal {
    pub link: usize,
    pub point: DVec3,
    pub target: DVec3,
    pub axis: DVec3,
    pub direction: Option<DVec3>,
}

fn residual(model: &RobotModel, q: &[f64], goal: &IkGoal) -> [f64; 6] {
    let pose = model.forward_kinematics(q)[goal.link];
    let p = pose.transform_point3(goal.point) - goal.target;
    let o = match goal.direction {
        Some(d) => {
            pose.transform_vector3(goal.axis)
                .normalize()
                .cross(d.normalize())
                * 0.3
        }
        None => DVec3::ZERO,
    };
    [p.x, p.y, p.z, o.x, o.y, o.z]
}

/// Solve from `q0`; returns the joint vector and the remaining position error (m).
pub fn solve(model: &RobotModel, q0: &[f64], goal: &IkGoal, iterations: usize) -> (Vec<f64>, f64) {
    let free: Vec<usize> = model.actuated_joints().collect();
    let mut q = q0.to_vec();
    let clamp = |k: usize, v: f64| {
        let j = &model.joints[k];
        if j.kind == JointKind::Continuous || j.lower >= j.upper {
            v
        } else {
            v.clamp(j.lower, j.upper)
        }
    };
    let damping = 1e-4;
    for _ in 0..iterations {
        let r = residual(model, &q, goal);
        if r.iter().map(|x| x * x).sum::<f64>().sqrt() < 1e-7 {
            break;
        }
        // Jacobian columns by central differences.
        let h = 1e-6;
        let cols: Vec<[f64; 6]> = free
            .iter()
            .map(|&k| {
                let (mut a, mut b) = (q.clone(), q.clone());
                a[k] += h;
                b[k] -= h;
                let (ra, rb) = (residual(model, &a, goal), residual(model, &b, goal));
                std::array::from_fn(|i| (ra[i] - rb[i]) / (2.0 * h))
            })
            .collect();
        // dq = -J^T (J J^T + lambda I)^-1 r, with the 6x6 system solved by Gaussian elimination.
        let mut m = [[0.0f64; 7]; 6];
        for i in 0..6 {
            for j in 0..6 {
                m[i][j] = cols.iter().map(|c| c[i] * c[j]).sum::<f64>()
                    + if i == j { damping } else { 0.0 };
            }
            m[i][6] = r[i];
        }
        for c in 0..6 {
            let pivot = (c..6)
                .max_by(|&a, &b| m[a][c].abs().total_cmp(&m[b][c].abs()))
                .unwrap_or(c);
            m.swap(c, pivot);
            let p = m[c][c];
            if p.abs() < 1e-15 {
                continue;
            }
            for row in 0..6 {
                if row != c {
                    let f = m[row][c] / p;
                    let pivot_row = m[c];
                    for (dst, src) in m[row][c..].iter_mut().zip(&pivot_row[c..]) {
                        *dst -= f * src;
                    }
                }
            }
        }
        let y: Vec<f64> = (0..6)
            .map(|i| {
                if m[i][i].abs() > 1e-15 {
                    m[i][6] / m[i][i]
                } else {
                    0.0
                }
            })
            .collect();
        for (c, &k) in free.iter().enumerate() {
            let step: f64 = (0..6).map(|i| cols[c][i] * y[i]).sum();
            q[k] = clamp(k, q[k] - step);
        }
    }
    let r = residual(model, &q, goal);
    (q, DVec3::new(r[0], r[1], r[2]).length())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::{GeometrySource, PackagePaths};

    #[test]
    fn reaches_table_points_with_the_pusher_pointing_down() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("urdf/panda_pusher.urdf");
        let m =
            RobotModel::load(&path, &PackagePaths::default(), GeometrySource::Collision).unwrap();
        let link = m.link_index("panda_pusher").unwrap();
        let mut q = vec![0.0; m.joints.len()];
        for (name, v) in [
            ("panda_joint2", -0.3),
            ("panda_joint4", -2.2),
            ("panda_joint6", 1.9),
            ("panda_joint7", 0.785),
        ] {
            q[m.joint_index(name).unwrap()] = v;
        }
        for target in [
            DVec3::new(0.45, 0.0, 0.03),
            DVec3::new(0.5, -0.2, 0.05),
            DVec3::new(0.35, 0.15, 0.02),
        ] {
            let goal = IkGoal {
                link,
                point: DVec3::new(0.0, 0.0, -0.14),
                target,
                axis: DVec3::NEG_Z,
                direction: Some(DVec3::NEG_Z),
            };
            let (sol, err) = solve(&m, &q, &goal, 200);
            assert!(err < 1e-4, "{target}: error {err}");
            let pose = m.forward_kinematics(&sol)[link];
            assert!(
                (pose.transform_vector3(DVec3::NEG_Z) - DVec3::NEG_Z).length() < 1e-3,
                "rod points down"
            );
            for k in m.actuated_joints() {
                let j = &m.joints[k];
                assert!(
                    sol[k] >= j.lower - 1e-9 && sol[k] <= j.upper + 1e-9,
                    "{} out of its limits",
                    j.name
                );
            }
        }
    }
}

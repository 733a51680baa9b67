//! Adam over a flat slice of parameters (Kingma and Ba), with moments reset by `reset()`: the
//! correction step restarts the optimiser every tick, as the paper does. Parameters may come in
//! groups (a Gaussian's mean: x, y, z) that share one second moment, so a step's direction is
//! the gradient's within the group instead of the sign of each coordinate: the step of a point
//! then does not depend on the axes of the world frame. A noise floor relative to the typical
//! gradient (`with_noise_floor`) lets the weak gradients of image noise take small steps where
//! plain Adam would give every parameter a full step.

#[derive(Clone, Debug, Default)]
pub struct Adam {
    m: Vec<f32>,
    v: Vec<f32>,
    step: i32,
    /// Consecutive parameters sharing a second moment (1: plain Adam).
    group: usize,
    pub beta1: f32,
    pub beta2: f32,
    pub epsilon: f32,
    /// Added to `epsilon` in multiples of the median over the groups of sqrt(v_hat) (0: off).
    noise_floor: f32,
    /// The groups' sqrt(v_hat), for the median.
    scratch: Vec<f32>,
}

impl Adam {
    pub fn new(beta1: f32, beta2: f32, epsilon: f32) -> Self {
        Self {
            m: Vec::new(),
            v: Vec::new(),
            step: 0,
            group: 1,
            beta1,
            beta2,
            epsilon,
            noise_floor: 0.0,
            scratch: Vec::new(),
        }
    }

    /// Zero the moments for `n` parameters.
    pub fn reset(&mut self, n: usize) {
        self.m.clear();
        self.m.resize(n, 0.0);
        self.v.clear();
        self.v.resize(n, 0.0);
        self.step = 0;
    }

    /// The same optimiser with consecutive runs of `group` parameters sharing a second moment
    /// (the mean of their squared gradients).
    pub fn grouped(self, group: usize) -> Self {
        Self {
            group: group.max(1),
            ..self
        }
    }

    /// The same optimiser with `floor` times the median RMS gradient (over the groups, bias
    /// corrected) added to epsilon at every step. A parameter whose gradient is typical steps
    /// about lr / (1 + floor); one whose gradient is far below the median (noise where the
    /// images agree) steps in proportion to its gradient instead of by a full lr. Relative, so
    /// scaling every gradient (a brighter scene, more pixels) leaves the steps unchanged.
    pub fn with_noise_floor(self, floor: f32) -> Self {
        Self {
            noise_floor: floor.max(0.0),
            ..self
        }
    }

    /// One step: `params -= lr * m_hat / (sqrt(v_hat) + eps)`, with eps = epsilon + the noise
    /// floor. `params` and `grads` have the length given to `reset`, a multiple of the group
    /// size.
    pub fn step(&mut self, params: &mut [f32], grads: &[f32], lr: f32) {
        self.step += 1;
        let (b1, b2) = (self.beta1, self.beta2);
        let c1 = 1.0 - b1.powi(self.step);
        let c2 = 1.0 - b2.powi(self.step);
        let k = self.group;
        let n = params.len();
        let moments = self.m[..n].chunks_mut(k).zip(self.v[..n].chunks_mut(k));
        for ((m, v), g) in moments.zip(grads[..n].chunks(k)) {
            let g2 = g.iter().map(|g| g * g).sum::<f32>() / g.len() as f32;
            for (m, g) in m.iter_mut().zip(g) {
                *m = b1 * *m + (1.0 - b1) * g;
            }
            for v in v.iter_mut() {
                *v = b2 * *v + (1.0 - b2) * g2;
            }
        }
        let eps = self.epsilon + self.noise_floor * self.median_rms(n, c2);
        for ((p, m), v) in params.iter_mut().zip(&self.m).zip(&self.v) {
            *p -= lr * (m / c1) / ((v / c2).sqrt() + eps);
        }
    }

    /// Each group's RMS gradient over the steps since `reset`, sqrt(v_hat), for the first `n`
    /// parameters (0 before the first step).
    pub fn rms(&self, n: usize) -> Vec<f32> {
        let c2 = 1.0 - self.beta2.powi(self.step);
        if self.step == 0 || c2 <= 0.0 {
            return vec![0.0; n.div_ceil(self.group)];
        }
        self.v[..n]
            .iter()
            .step_by(self.group)
            .map(|v| (v / c2).sqrt())
            .collect()
    }

    /// The median over the first `n` parameters' groups of sqrt(v_hat); 0 when the floor is off.
    fn median_rms(&mut self, n: usize, c2: f32) -> f32 {
        if self.noise_floor == 0.0 || n == 0 {
            return 0.0;
        }
        self.scratch.clear();
        let rms = self.v[..n]
            .iter()
            .step_by(self.group)
            .map(|v| (v / c2).sqrt());
        self.scratch.extend(rms);
        let middle = self.scratch.len() / 2;
        *self
            .scratch
            .select_nth_unstable_by(middle, f32::total_cmp)
            .1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rms_gradient_of_a_steady_gradient_is_its_size_whatever_the_steps() {
        // Grouped as a Gaussian's mean: one RMS over x, y, z.
        let mut adam = Adam::new(0.9, 0.999, 1e-8).grouped(3);
        adam.reset(6);
        assert_eq!(
            adam.rms(6),
            vec![0.0, 0.0],
            "nothing measured before a step"
        );
        let grads = [3.0, 0.0, 4.0, 0.0, 0.5, 0.0];
        let mut params = [0.0; 6];
        for _ in 0..5 {
            adam.step(&mut params, &grads, 0.01);
        }
        let rms = adam.rms(6);
        let expected = [(25.0f32 / 3.0).sqrt(), (0.25f32 / 3.0).sqrt()];
        for (r, e) in rms.iter().zip(expected) {
            assert!((r - e).abs() < 1e-4 * e, "{rms:?} vs {expected:?}");
        }
    }

    #[test]
    fn first_step_moves_each_parameter_by_the_learning_rate_against_its_gradient() {
        let mut adam = Adam::new(0.9, 0.999, 1e-12);
        adam.reset(3);
        let mut p = [1.0, 2.0, 3.0];
        adam.step(&mut p, &[10.0, -0.001, 0.0], 0.01);
        assert!((p[0] - 0.99).abs() < 1e-6 && (p[1] - 2.01).abs() < 1e-6 && p[2] == 3.0);
    }

    #[test]
    fn a_grouped_first_step_follows_the_gradient_direction_whatever_the_axes() {
        // Plain Adam moves both coordinates by lr (the gradient's signs); grouped, the step is
        // parallel to the gradient, and rotating the gradient rotates the step.
        let mut adam = Adam::new(0.9, 0.999, 1e-12).grouped(2);
        adam.reset(2);
        let mut p = [0.0f32, 0.0];
        adam.step(&mut p, &[3.0, 1.0], 0.01);
        assert!((p[0] / p[1] - 3.0).abs() < 1e-4, "{p:?}");
        let (c, s) = (0.6f32, 0.8f32);
        let mut q = [0.0f32, 0.0];
        adam.reset(2);
        adam.step(&mut q, &[c * 3.0 - s * 1.0, s * 3.0 + c * 1.0], 0.01);
        let rotated = [c * p[0] - s * p[1], s * p[0] + c * p[1]];
        assert!((q[0] - rotated[0]).abs() < 1e-6 && (q[1] - rotated[1]).abs() < 1e-6);
        // The step length: lr * |g| / rms(g) = lr * sqrt(2) for two coordinates.
        assert!(((p[0] * p[0] + p[1] * p[1]).sqrt() - 0.01 * 2f32.sqrt()).abs() < 1e-6);
    }

    #[test]
    fn under_a_noise_floor_a_step_scales_with_its_gradient_against_the_median() {
        // Median RMS gradient 1: with floor 1 each step is lr * g / (|g| + 1). Plain Adam would
        // move all three by lr.
        let mut adam = Adam::new(0.9, 0.999, 1e-12).with_noise_floor(1.0);
        adam.reset(3);
        let mut p = [0.0f32; 3];
        adam.step(&mut p, &[10.0, 1.0, 0.1], 0.01);
        let want = [-0.01 * 10.0 / 11.0, -0.01 * 0.5, -0.01 * 0.1 / 1.1];
        for (got, want) in p.iter().zip(want) {
            assert!((got - want).abs() < 1e-7, "{p:?}");
        }
    }

    #[test]
    fn the_noise_floor_is_relative_so_scaling_every_gradient_leaves_the_steps_unchanged() {
        let steps = |scale: f32| {
            let mut adam = Adam::new(0.9, 0.999, 1e-12)
                .grouped(3)
                .with_noise_floor(0.5);
            adam.reset(9);
            let mut p = [0.0f32; 9];
            let g = [3.0, -1.0, 0.5, 0.01, 0.02, 0.0, -2.0, 2.0, 1.0].map(|g| g * scale);
            for _ in 0..3 {
                adam.step(&mut p, &g, 0.01);
            }
            p
        };
        let (a, b) = (steps(1.0), steps(1000.0));
        for (a, b) in a.iter().zip(&b) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
        // The weak group (row 2) moves far less than lr per step; the strong ones nearly lr.
        let length = |r: &[f32]| r.iter().map(|x| x * x).sum::<f32>().sqrt();
        assert!(length(&a[3..6]) < 0.1 * length(&a[0..3]), "{a:?}");
    }

    #[test]
    fn minimises_a_quadratic() {
        let mut adam = Adam::new(0.9, 0.999, 1e-8);
        adam.reset(2);
        let mut p = [3.0f32, -2.0];
        for _ in 0..2000 {
            let g = [2.0 * (p[0] - 1.0), 20.0 * (p[1] + 0.5)];
            adam.step(&mut p, &g, 0.01);
        }
        assert!(
            (p[0] - 1.0).abs() < 1e-2 && (p[1] + 0.5).abs() < 1e-2,
            "{p:?}"
        );
    }
}

//! Adam over a flat slice of parameters (Kingma and Ba), with moments reset by `reset()`: the
//! correction step restarts the optimiser every tick, as the paper does. Parameters may come in
//! groups (a Gaussian's mean: x, y, z) that share one second moment, so a step's direction is
//! the gradient's within the group instead of the sign of each coordinate: the step of a point
//! then does not depend on the axes of the world frame.

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

    /// One step: `params -= lr * m_hat / (sqrt(v_hat) + eps)`. `params` and `grads` have the
    /// length given to `reset`, a multiple of the group size.
    pub fn step(&mut self, params: &mut [f32], grads: &[f32], lr: f32) {
        self.step += 1;
        let (b1, b2) = (self.beta1, self.beta2);
        let c1 = 1.0 - b1.powi(self.step);
        let c2 = 1.0 - b2.powi(self.step);
        let k = self.group;
        for start in (0..params.len()).step_by(k) {
            let end = (start + k).min(params.len());
            let g2 = grads[start..end].iter().map(|g| g * g).sum::<f32>() / (end - start) as f32;
            for i in start..end {
                self.m[i] = b1 * self.m[i] + (1.0 - b1) * grads[i];
                self.v[i] = b2 * self.v[i] + (1.0 - b2) * g2;
                params[i] -= lr * (self.m[i] / c1) / ((self.v[i] / c2).sqrt() + self.epsilon);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

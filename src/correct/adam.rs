//! Adam over a flat slice of parameters (Kingma and Ba), with moments reset by `reset()`: the
//! correction step restarts the optimiser every tick, as the paper does.

#[derive(Clone, Debug, Default)]
pub struct Adam {
    m: Vec<f32>,
    v: Vec<f32>,
    step: i32,
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

    /// One step: `params -= lr * m_hat / (sqrt(v_hat) + eps)`. `params` and `grads` have the
    /// length given to `reset`.
    pub fn step(&mut self, params: &mut [f32], grads: &[f32], lr: f32) {
        self.step += 1;
        let (b1, b2) = (self.beta1, self.beta2);
        let c1 = 1.0 - b1.powi(self.step);
        let c2 = 1.0 - b2.powi(self.step);
        for i in 0..params.len() {
            let g = grads[i];
            self.m[i] = b1 * self.m[i] + (1.0 - b1) * g;
            self.v[i] = b2 * self.v[i] + (1.0 - b2) * g * g;
            params[i] -= lr * (self.m[i] / c1) / ((self.v[i] / c2).sqrt() + self.epsilon);
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

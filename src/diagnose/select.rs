//! Sparse regression with model selection: candidates enter one at a time (forward selection),
//! each fitted by least squares on the first part of the recording and judged on the held-out
//! rest; a candidate stays only if it cuts the held-out residual by a clear margin and its
//! coefficients are significant and physically plausible. Coefficient intervals are 95 %, with the
//! standard errors widened for the residual's autocorrelation (successive ticks are not independent).

use super::candidates::{Candidate, observed};
use crate::trace::Sample;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

#[derive(Clone, Debug, Serialize)]
pub struct Coefficient {
    pub name: String,
    pub unit: String,
    pub value: f64,
    pub low: f64,
    pub high: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct Found {
    pub effect: String,
    pub coefficients: Vec<Coefficient>,
    /// Fraction of the held-out residual (sum of squares) that adding this effect removed.
    pub explained_fraction: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct Selection {
    pub found: Vec<Found>,
    pub train_samples: usize,
    pub heldout_samples: usize,
    /// Held-out residual RMS (N) before and after the selected effects.
    pub heldout_rms_before: f64,
    pub heldout_rms_after: f64,
}

#[derive(Clone, Copy, Debug)]
pub struct SelectOptions {
    /// Fraction of the samples (in time order) used for fitting; the rest judges.
    pub train_fraction: f64,
    /// A candidate must cut the held-out sum of squares by at least this fraction of its
    /// value before the selection started.
    pub min_gain: f64,
    /// And each of its coefficients must be this many (widened) standard errors from zero.
    pub min_t: f64,
}

impl Default for SelectOptions {
    fn default() -> Self {
        Self {
            train_fraction: 0.7,
            min_gain: 0.1,
            min_t: 3.0,
        }
    }
}

struct Rows {
    x: Vec<Vec<f64>>,
    y: Vec<f64>,
}

fn rows(samples: &[&Sample], set: &[Candidate]) -> Rows {
    let mut x = Vec::new();
    let mut y = Vec::new();
    for s in samples {
        let cols: Vec<Vec<[f32; 3]>> = set.iter().map(|c| c.columns(s)).collect();
        let obs = observed(s);
        for r in 0..3 {
            y.push(obs[r] as f64);
            x.push(cols.iter().flatten().map(|c| c[r] as f64).collect());
        }
    }
    Rows { x, y }
}

/// Least squares: coefficients and the residual of `rows`.
fn solve(r: &Rows) -> Option<(DVector<f64>, DMatrix<f64>)> {
    let k = r.x.first()?.len();
    let n = r.y.len();
    if k == 0 || n <= k {
        return None;
    }
    let x = DMatrix::from_fn(n, k, |i, j| r.x[i][j]);
    let y = DVector::from_vec(r.y.clone());
    let beta = x.clone().svd(true, true).solve(&y, 1e-12).ok()?;
    Some((beta, x))
}

fn sse(r: &Rows, beta: Option<&DVector<f64>>) -> f64 {
    r.y.iter()
        .zip(&r.x)
        .map(|(y, x)| {
            let p: f64 = beta.map_or(0.0, |b| x.iter().zip(b.iter()).map(|(a, c)| a * c).sum());
            (y - p) * (y - p)
        })
        .sum()
}

/// Standard errors of the coefficients, widened by `sqrt((1 + rho) / (1 - rho))` for the lag-one
/// autocorrelation `rho` of each row stream's residual.
fn standard_errors(r: &Rows, beta: &DVector<f64>, x: &DMatrix<f64>) -> Option<Vec<f64>> {
    let n = r.y.len();
    let k = beta.len();
    let residual: Vec<f64> =
        r.y.iter()
            .zip(&r.x)
            .map(|(y, row)| y - row.iter().zip(beta.iter()).map(|(a, c)| a * c).sum::<f64>())
            .collect();
    let sigma2 = residual.iter().map(|e| e * e).sum::<f64>() / (n - k) as f64;
    // Rows interleave three streams (f_x, f_y, tau_z): autocorrelation at a lag of one sample.
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..n {
        den += residual[i] * residual[i];
        if i + 3 < n {
            num += residual[i] * residual[i + 3];
        }
    }
    let rho = if den > 0.0 {
        (num / den).clamp(0.0, 0.95)
    } else {
        0.0
    };
    let widen = ((1.0 + rho) / (1.0 - rho)).sqrt();
    let xtx = x.transpose() * x;
    let inv = xtx.try_inverse()?;
    Some(
        (0..k)
            .map(|j| (sigma2 * inv[(j, j)]).max(0.0).sqrt() * widen)
            .collect(),
    )
}

/// Select the candidates that explain the samples' corrective forces.
pub fn select(samples: &[Sample], candidates: &[Candidate], opts: SelectOptions) -> Selection {
    let mut ordered: Vec<&Sample> = samples.iter().collect();
    ordered.sort_by(|a, b| a.t.total_cmp(&b.t));
    let cut = ((ordered.len() as f64) * opts.train_fraction).round() as usize;
    let (train, heldout) = ordered.split_at(cut.min(ordered.len()));
    let base = sse(&rows(heldout, &[]), None);
    let mut chosen: Vec<Candidate> = Vec::new();
    let mut current = base;
    let mut gains = Vec::new();
    loop {
        let mut best: Option<(Candidate, f64)> = None;
        for &c in candidates.iter().filter(|c| !chosen.contains(c)) {
            let mut set = chosen.clone();
            set.push(c);
            let Some((beta, x)) = solve(&rows(train, &set)) else {
                continue;
            };
            let Some(se) = standard_errors(&rows(train, &set), &beta, &x) else {
                continue;
            };
            // The newcomer's coefficients are the last ones.
            let n_new = c.coefficients().len();
            let first = beta.len() - n_new;
            let new: Vec<f64> = beta.iter().skip(first).copied().collect();
            // Its strongest coefficient must be significant (a constant force along one axis has
            // a zero partner), and the whole fit plausible.
            let t_max = (first..beta.len())
                .map(|j| (beta[j] / se[j].max(1e-12)).abs())
                .fold(0.0, f64::max);
            if t_max < opts.min_t || !c.plausible(&new) {
                continue;
            }
            let s = sse(&rows(heldout, &set), Some(&beta));
            if s < current - opts.min_gain * base && best.is_none_or(|(_, b)| s < b) {
                best = Some((c, s));
            }
        }
        let Some((c, s)) = best else { break };
        gains.push((current - s) / base.max(1e-12));
        chosen.push(c);
        current = s;
    }
    // Final coefficients and intervals from all samples.
    let all: Vec<&Sample> = ordered.clone();
    let mut found = Vec::new();
    if let Some((beta, x)) = solve(&rows(&all, &chosen)) {
        let se = standard_errors(&rows(&all, &chosen), &beta, &x)
            .unwrap_or_else(|| vec![f64::NAN; beta.len()]);
        let mut j = 0;
        for (c, gain) in chosen.iter().zip(&gains) {
            let coefficients = c
                .coefficients()
                .iter()
                .map(|(name, unit)| {
                    let (value, e) = (beta[j], se[j]);
                    j += 1;
                    Coefficient {
                        name: name.to_string(),
                        unit: unit.to_string(),
                        value,
                        low: value - 1.96 * e,
                        high: value + 1.96 * e,
                    }
                })
                .collect();
            found.push(Found {
                effect: c.name().to_string(),
                coefficients,
                explained_fraction: *gain,
            });
        }
    }
    let n_held = (heldout.len() * 3).max(1) as f64;
    Selection {
        found,
        train_samples: train.len(),
        heldout_samples: heldout.len(),
        heldout_rms_before: (base / n_held).sqrt(),
        heldout_rms_after: (current / n_held).sqrt(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::candidates::ALL;
    use glam::Vec3;

    /// A box sliding about on the ground: smooth wandering velocity, positions integrated, a
    /// little measurement noise on the corrective wrench; `truth` adds the missing effect.
    fn recording(truth: impl Fn(&Sample) -> (Vec3, f32), seed: u64) -> Vec<Sample> {
        let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let mut noise = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32 - 0.5
        };
        let dt = 1.0 / 30.0;
        let mut position = Vec3::new(0.5, 0.0, 0.025);
        let mut out = Vec::new();
        for k in 0..450 {
            let t = k as f32 * dt;
            let velocity = Vec3::new(
                0.12 * (0.7 * t).sin() + 0.05 * (2.3 * t).cos(),
                0.1 * (0.5 * t + 1.0).cos() - 0.03,
                0.0,
            );
            let acceleration = Vec3::new(
                0.084 * (0.7 * t).cos() - 0.115 * (2.3 * t).sin(),
                -0.05 * (0.5 * t + 1.0).sin(),
                0.0,
            );
            position += velocity * dt;
            let mut s = Sample {
                t: t as f64,
                object: "box".into(),
                position,
                velocity,
                acceleration,
                angular_velocity: Vec3::new(0.0, 0.0, 0.8 * (0.9 * t).sin()),
                mass: 0.36,
                inertia_z: 5.4e-4,
                on_ground: true,
                ..Default::default()
            };
            let (f, tau) = truth(&s);
            s.force = f + Vec3::new(noise(), noise(), noise()) * 0.02;
            s.torque = Vec3::new(0.0, 0.0, tau + noise() * 0.002);
            out.push(s);
        }
        out
    }

    fn only(sel: &Selection) -> &Found {
        assert_eq!(sel.found.len(), 1, "{:#?}", sel.found);
        &sel.found[0]
    }

    #[test]
    fn drag_is_named_with_its_coefficient_and_an_interval_that_covers_it() {
        let sel = select(
            &recording(
                |s| (-0.8 * Vec3::new(s.velocity.x, s.velocity.y, 0.0), 0.0),
                1,
            ),
            &ALL,
            SelectOptions::default(),
        );
        let f = only(&sel);
        assert_eq!(f.effect, "viscous_drag");
        let c = &f.coefficients[0];
        assert!(
            (c.value - 0.8).abs() < 0.04 && c.low < 0.8 && c.high > 0.8,
            "{c:?}"
        );
        assert!(
            f.explained_fraction > 0.5 && sel.heldout_rms_after < 0.5 * sel.heldout_rms_before,
            "{sel:?}"
        );
    }

    #[test]
    fn a_tilt_is_a_constant_force_and_a_tether_a_spring() {
        let sel = select(
            &recording(|_| (Vec3::new(0.3, -0.1, 0.0), 0.0), 2),
            &ALL,
            SelectOptions::default(),
        );
        let f = only(&sel);
        assert_eq!(f.effect, "constant_force");
        assert!(
            (f.coefficients[0].value - 0.3).abs() < 0.01
                && (f.coefficients[1].value + 0.1).abs() < 0.01,
            "{f:?}"
        );
        let anchor = Vec3::new(0.45, 0.1, 0.0);
        let sel = select(
            &recording(
                |s| {
                    (
                        -2.5 * (Vec3::new(s.position.x, s.position.y, 0.0) - anchor),
                        0.0,
                    )
                },
                3,
            ),
            &ALL,
            SelectOptions::default(),
        );
        let f = only(&sel);
        assert_eq!(f.effect, "spring");
        let k = f.coefficients[0].value;
        assert!((k - 2.5).abs() < 0.25, "{f:?}");
        assert!(
            ((f.coefficients[1].value / k) - 0.45).abs() < 0.01
                && ((f.coefficients[2].value / k) - 0.1).abs() < 0.01,
            "anchor {f:?}"
        );
    }

    #[test]
    fn friction_mass_and_angular_damping_are_told_apart() {
        let sel = select(
            &recording(
                |s| {
                    (
                        -0.15
                            * s.mass
                            * 9.81
                            * Vec3::new(s.velocity.x, s.velocity.y, 0.0).normalize(),
                        0.0,
                    )
                },
                4,
            ),
            &ALL,
            SelectOptions::default(),
        );
        let f = only(&sel);
        assert_eq!(f.effect, "ground_friction");
        assert!((f.coefficients[0].value - 0.15).abs() < 0.01, "{f:?}");
        let sel = select(
            &recording(
                |s| {
                    (
                        -0.2 * Vec3::new(s.acceleration.x, s.acceleration.y, 0.0),
                        0.0,
                    )
                },
                5,
            ),
            &ALL,
            SelectOptions::default(),
        );
        let f = only(&sel);
        assert_eq!(f.effect, "mass_error");
        assert!((f.coefficients[0].value - 0.2).abs() < 0.03, "{f:?}");
        let sel = select(
            &recording(
                |s| (Vec3::ZERO, -3.0 * s.inertia_z * s.angular_velocity.z),
                6,
            ),
            &ALL,
            SelectOptions::default(),
        );
        let f = only(&sel);
        assert_eq!(f.effect, "angular_damping");
        assert!((f.coefficients[0].value - 3.0).abs() < 0.3, "{f:?}");
    }

    #[test]
    fn noise_alone_names_nothing() {
        for seed in 10..15 {
            let sel = select(
                &recording(|_| (Vec3::ZERO, 0.0), seed),
                &ALL,
                SelectOptions::default(),
            );
            assert!(sel.found.is_empty(), "seed {seed}: {:#?}", sel.found);
        }
    }
}

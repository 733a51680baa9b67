//! Candidate physical effects: each predicts, per unit of its parameters, the corrective force
//! (in the ground plane) and torque (about the vertical) that the missing effect would demand.
//! Rows of the regression are `[f_x, f_y, tau_z / L]` per sample, `L` a length that makes torques
//! comparable to forces.

use crate::trace::Sample;
use glam::Vec3;

/// Length scale of the torque rows, m (about an object's size).
pub const TORQUE_LENGTH: f32 = 0.1;
/// Speeds below this (m/s) count as at rest for sliding friction.
const SLIDING: f32 = 0.01;
const G: f32 = 9.81;

/// One candidate effect of the library.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Candidate {
    /// Linear drag `-c v`: air or fluid resistance, a dragging cable.
    ViscousDrag,
    /// Ground Coulomb friction off by `dmu`: `-dmu m g v/|v|` while sliding on the ground.
    GroundFriction,
    /// A constant horizontal force: a tilted table (`m g sin(angle)` downhill) or airflow.
    ConstantForce,
    /// A spring or tether to a fixed anchor: `-k (x - anchor)` in the plane.
    Spring,
    /// Mass error `dm`: `-dm a` (the true object is heavier by `dm`).
    MassError,
    /// Angular damping `-c I w_z` about the vertical.
    AngularDamping,
}

pub const ALL: [Candidate; 6] = [
    Candidate::ViscousDrag,
    Candidate::GroundFriction,
    Candidate::ConstantForce,
    Candidate::Spring,
    Candidate::MassError,
    Candidate::AngularDamping,
];

impl Candidate {
    /// The candidate called `name`.
    pub fn from_name(name: &str) -> Option<Candidate> {
        ALL.into_iter().find(|c| c.name() == name)
    }

    pub fn name(self) -> &'static str {
        match self {
            Candidate::ViscousDrag => "viscous_drag",
            Candidate::GroundFriction => "ground_friction",
            Candidate::ConstantForce => "constant_force",
            Candidate::Spring => "spring",
            Candidate::MassError => "mass_error",
            Candidate::AngularDamping => "angular_damping",
        }
    }

    /// Names and units of the regression coefficients, in column order.
    pub fn coefficients(self) -> &'static [(&'static str, &'static str)] {
        match self {
            Candidate::ViscousDrag => &[("coefficient", "N s/m")],
            Candidate::GroundFriction => &[("friction_change", "")],
            Candidate::ConstantForce => &[("force_x", "N"), ("force_y", "N")],
            Candidate::Spring => &[
                ("stiffness", "N/m"),
                ("stiffness_x_anchor_x", "N"),
                ("stiffness_x_anchor_y", "N"),
            ],
            Candidate::MassError => &[("mass_change", "kg")],
            Candidate::AngularDamping => &[("coefficient", "1/s")],
        }
    }

    /// The regression columns for one sample: per coefficient, its `[f_x, f_y, tau_z / L]`.
    pub fn columns(self, s: &Sample) -> Vec<[f32; 3]> {
        let v = Vec3::new(s.velocity.x, s.velocity.y, 0.0);
        match self {
            Candidate::ViscousDrag => vec![[-v.x, -v.y, 0.0]],
            Candidate::GroundFriction => {
                let speed = v.length();
                if s.on_ground && speed > SLIDING {
                    let f = -s.mass * G * v / speed;
                    vec![[f.x, f.y, 0.0]]
                } else {
                    vec![[0.0; 3]]
                }
            }
            Candidate::ConstantForce => vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            Candidate::Spring => vec![
                [-s.position.x, -s.position.y, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
            ],
            Candidate::MassError => vec![[-s.acceleration.x, -s.acceleration.y, 0.0]],
            Candidate::AngularDamping => vec![[
                0.0,
                0.0,
                -s.inertia_z * s.angular_velocity.z / TORQUE_LENGTH,
            ]],
        }
    }

    /// Whether fitted coefficients make physical sense (a drag that pushes, a spring that repels
    /// do not).
    pub fn plausible(self, c: &[f64]) -> bool {
        match self {
            Candidate::ViscousDrag | Candidate::AngularDamping | Candidate::Spring => c[0] > 0.0,
            _ => true,
        }
    }
}

/// The observed rows of a sample: `[f_x, f_y, tau_z / L]`.
pub fn observed(s: &Sample) -> [f32; 3] {
    [s.force.x, s.force.y, s.torque.z / TORQUE_LENGTH]
}

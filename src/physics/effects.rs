//! Extra physical effects as named terms with parameters. The base model (gravity, ground,
//! contacts, shape matching) is in the solver; each effect here adds one well-defined piece of
//! physics that a scene may or may not have: forces, mass distribution, or local ground friction.
//! Effects are data (serde, tagged by `effect:` name) so configuration files and the diagnosis
//! can add them and fit their parameters by name.

use crate::world::{ShapeId, ShapeKind, World};
use anyhow::{Result, anyhow, bail};
use glam::{Mat3, Vec2, Vec3};
use serde::{Deserialize, Serialize};

/// One extra physical effect. `object: None` means every dynamic object.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "effect", rename_all = "snake_case", deny_unknown_fields)]
pub enum Effect {
    /// Linear viscous drag on the object's motion: total force `-coefficient * v_com` (N s/m).
    ViscousDrag {
        #[serde(default)]
        object: Option<String>,
        coefficient: f32,
    },
    /// Damps motion relative to the centre of mass (rotation): acceleration
    /// `-coefficient * (v_i - v_com)` on every particle, i.e. torque `-coefficient * I * omega` (1/s).
    AngularDamping {
        #[serde(default)]
        object: Option<String>,
        coefficient: f32,
    },
    /// A constant force on the object (N), e.g. airflow or a hidden push.
    ConstantForce {
        #[serde(default)]
        object: Option<String>,
        force: Vec3,
    },
    /// Ground contacts give back `coefficient` of the normal speed an object strikes the ground
    /// with (0, the base model: contacts absorb it; 1: a perfect bounce).
    Restitution {
        #[serde(default)]
        object: Option<String>,
        coefficient: f32,
    },
    /// The table is tilted by `angle` (rad) with its downhill direction at `azimuth` (rad, from
    /// the ground plane's first tangent, +x for a horizontal table): gravity gains an in-plane part.
    TableTilt { angle: f32, azimuth: f32 },
    /// The object's true mass is `factor` times its modelled mass (same distribution).
    MassScale { object: String, factor: f32 },
    /// The object's centre of mass is shifted by `offset` (body frame, m); total mass unchanged.
    CenterOfMassOffset { object: String, offset: Vec3 },
    /// Ground friction differs inside an axis-aligned rectangle of the table (world x, y).
    FrictionPatch {
        center: Vec2,
        half_size: Vec2,
        static_friction: f32,
        kinetic_friction: f32,
    },
    /// A spring from a point of the object (body frame) to a world anchor. With `tether: true` it
    /// only pulls when stretched beyond `rest_length` (a string). `damping` acts along the spring.
    Spring {
        object: String,
        point: Vec3,
        anchor: Vec3,
        stiffness: f32,
        #[serde(default)]
        rest_length: f32,
        #[serde(default)]
        damping: f32,
        #[serde(default)]
        tether: bool,
    },
}

impl Effect {
    pub fn name(&self) -> &'static str {
        match self {
            Effect::ViscousDrag { .. } => "viscous_drag",
            Effect::AngularDamping { .. } => "angular_damping",
            Effect::Restitution { .. } => "restitution",
            Effect::ConstantForce { .. } => "constant_force",
            Effect::TableTilt { .. } => "table_tilt",
            Effect::MassScale { .. } => "mass_scale",
            Effect::CenterOfMassOffset { .. } => "center_of_mass_offset",
            Effect::FrictionPatch { .. } => "friction_patch",
            Effect::Spring { .. } => "spring",
        }
    }

    /// The object this effect acts on, if it names one.
    pub fn object(&self) -> Option<&str> {
        match self {
            Effect::ViscousDrag { object, .. }
            | Effect::AngularDamping { object, .. }
            | Effect::ConstantForce { object, .. }
            | Effect::Restitution { object, .. } => object.as_deref(),
            Effect::MassScale { object, .. }
            | Effect::CenterOfMassOffset { object, .. }
            | Effect::Spring { object, .. } => Some(object),
            Effect::TableTilt { .. } | Effect::FrictionPatch { .. } => None,
        }
    }

    /// The scalar parameters, by name, in a fixed order (vectors expand to `_x`, `_y`, `_z`).
    pub fn parameters(&self) -> Vec<(&'static str, f32)> {
        match *self {
            Effect::ViscousDrag { coefficient, .. }
            | Effect::AngularDamping { coefficient, .. }
            | Effect::Restitution { coefficient, .. } => {
                vec![("coefficient", coefficient)]
            }
            Effect::ConstantForce { force, .. } => vec![
                ("force_x", force.x),
                ("force_y", force.y),
                ("force_z", force.z),
            ],
            Effect::TableTilt { angle, azimuth } => vec![("angle", angle), ("azimuth", azimuth)],
            Effect::MassScale { factor, .. } => vec![("factor", factor)],
            Effect::CenterOfMassOffset { offset, .. } => vec![
                ("offset_x", offset.x),
                ("offset_y", offset.y),
                ("offset_z", offset.z),
            ],
            Effect::FrictionPatch {
                center,
                half_size,
                static_friction,
                kinetic_friction,
            } => vec![
                ("center_x", center.x),
                ("center_y", center.y),
                ("half_size_x", half_size.x),
                ("half_size_y", half_size.y),
                ("static_friction", static_friction),
                ("kinetic_friction", kinetic_friction),
            ],
            Effect::Spring {
                point,
                anchor,
                stiffness,
                rest_length,
                damping,
                ..
            } => vec![
                ("point_x", point.x),
                ("point_y", point.y),
                ("point_z", point.z),
                ("anchor_x", anchor.x),
                ("anchor_y", anchor.y),
                ("anchor_z", anchor.z),
                ("stiffness", stiffness),
                ("rest_length", rest_length),
                ("damping", damping),
            ],
        }
    }

    /// Set one scalar parameter by the name `parameters()` reports.
    pub fn set_parameter(&mut self, name: &str, value: f32) -> Result<()> {
        let effect_name = self.name();
        let slot: Option<&mut f32> = match self {
            Effect::ViscousDrag { coefficient, .. }
            | Effect::AngularDamping { coefficient, .. }
            | Effect::Restitution { coefficient, .. } => {
                (name == "coefficient").then_some(coefficient)
            }
            Effect::ConstantForce { force, .. } => vec3_slot(force, name, "force"),
            Effect::TableTilt { angle, azimuth } => match name {
                "angle" => Some(angle),
                "azimuth" => Some(azimuth),
                _ => None,
            },
            Effect::MassScale { factor, .. } => (name == "factor").then_some(factor),
            Effect::CenterOfMassOffset { offset, .. } => vec3_slot(offset, name, "offset"),
            Effect::FrictionPatch {
                center,
                half_size,
                static_friction,
                kinetic_friction,
            } => match name {
                "center_x" => Some(&mut center.x),
                "center_y" => Some(&mut center.y),
                "half_size_x" => Some(&mut half_size.x),
                "half_size_y" => Some(&mut half_size.y),
                "static_friction" => Some(static_friction),
                "kinetic_friction" => Some(kinetic_friction),
                _ => None,
            },
            Effect::Spring {
                point,
                anchor,
                stiffness,
                rest_length,
                damping,
                ..
            } => match name {
                "stiffness" => Some(stiffness),
                "rest_length" => Some(rest_length),
                "damping" => Some(damping),
                _ if name.starts_with("point_") => vec3_slot(point, name, "point"),
                _ => vec3_slot(anchor, name, "anchor"),
            },
        };
        let slot = slot.ok_or_else(|| anyhow!("effect {effect_name} has no parameter {name}"))?;
        *slot = value;
        self.validate()
    }

    pub fn validate(&self) -> Result<()> {
        let bad = self.parameters().into_iter().find(|(_, v)| !v.is_finite());
        if let Some((p, v)) = bad {
            bail!(
                "effect {}: parameter {p} must be finite, got {v}",
                self.name()
            );
        }
        match *self {
            Effect::ViscousDrag { coefficient, .. }
            | Effect::AngularDamping { coefficient, .. }
                if coefficient < 0.0 =>
            {
                bail!("effect {}: coefficient must be >= 0", self.name())
            }
            Effect::MassScale { factor, .. } if factor <= 0.0 => {
                bail!("effect mass_scale: factor must be > 0")
            }
            Effect::Restitution { coefficient, .. } if !(0.0..=1.0).contains(&coefficient) => {
                bail!("effect restitution: coefficient must be within 0 ..= 1")
            }
            Effect::FrictionPatch {
                half_size,
                static_friction,
                kinetic_friction,
                ..
            } if half_size.min_element() < 0.0
                || static_friction < 0.0
                || kinetic_friction < 0.0 =>
            {
                bail!("effect friction_patch: sizes and friction coefficients must be >= 0")
            }
            Effect::Spring {
                stiffness,
                rest_length,
                damping,
                ..
            } if stiffness < 0.0 || rest_length < 0.0 || damping < 0.0 => {
                bail!("effect spring: stiffness, rest_length and damping must be >= 0")
            }
            _ => Ok(()),
        }
    }
}

fn vec3_slot<'a>(v: &'a mut Vec3, name: &str, prefix: &str) -> Option<&'a mut f32> {
    match name.strip_prefix(prefix)? {
        "_x" => Some(&mut v.x),
        "_y" => Some(&mut v.y),
        "_z" => Some(&mut v.z),
        _ => None,
    }
}

/// Effects bound to a particular world: object names resolved to shapes, spring points to
/// particles. Built by the solver whenever the world's layout or the effects change.
pub struct EffectModel {
    terms: Vec<Bound>,
}

struct Bound {
    effect: Effect,
    shapes: Vec<ShapeId>,
    /// Spring: the particle nearest to the attachment point.
    particle: Option<usize>,
}

/// Per-shape quantities the force terms need, computed once per substep.
pub struct ShapeState<'a> {
    pub mass: &'a [f32],
    pub velocity: &'a [Vec3],
}

impl EffectModel {
    pub fn bind(effects: &[Effect], world: &World) -> Result<Self> {
        let mut terms = Vec::with_capacity(effects.len());
        for effect in effects {
            effect.validate()?;
            let shapes: Vec<ShapeId> = match effect.object() {
                Some(name) => {
                    let s = world.shape_id(name).ok_or_else(|| {
                        anyhow!(
                            "effect {}: no object named '{name}' in the scene",
                            effect.name()
                        )
                    })?;
                    if !matches!(
                        world.shapes.kind[s as usize],
                        ShapeKind::Rigid | ShapeKind::Rope
                    ) {
                        bail!("effect {}: object '{name}' is not dynamic", effect.name());
                    }
                    vec![s]
                }
                None => world.shapes.dynamic_ids().collect(),
            };
            let particle = match effect {
                Effect::Spring { point, .. } => {
                    let range = world.shapes.range(shapes[0]);
                    let rest = &world.particles.rest[range.clone()];
                    let nearest = (0..rest.len()).min_by(|&a, &b| {
                        rest[a]
                            .distance_squared(*point)
                            .total_cmp(&rest[b].distance_squared(*point))
                    });
                    nearest.map(|k| range.start + k)
                }
                _ => None,
            };
            terms.push(Bound {
                effect: effect.clone(),
                shapes,
                particle,
            });
        }
        Ok(Self { terms })
    }

    pub fn is_empty(&self) -> bool {
        self.terms.is_empty()
    }

    /// Inverse masses with mass effects applied to the world's nominal ones.
    pub fn effective_inv_mass(&self, world: &World) -> Result<Vec<f32>> {
        let mut inv_mass = world.particles.inv_mass.clone();
        for t in &self.terms {
            match t.effect {
                Effect::MassScale { factor, .. } => {
                    for i in world.shapes.range(t.shapes[0]) {
                        inv_mass[i] /= factor;
                    }
                }
                Effect::CenterOfMassOffset { offset, .. } => {
                    shift_center_of_mass(world, t.shapes[0], offset, &mut inv_mass)?
                }
                _ => {}
            }
        }
        Ok(inv_mass)
    }

    /// Add the effects' accelerations (m/s^2) of every particle to `accel`.
    pub fn add_accelerations(
        &self,
        world: &World,
        inv_mass: &[f32],
        shape: &ShapeState,
        gravity: Vec3,
        ground_normal: Vec3,
        accel: &mut [Vec3],
    ) {
        let p = &world.particles;
        for t in &self.terms {
            match t.effect {
                Effect::ViscousDrag { coefficient, .. } => {
                    for &s in &t.shapes {
                        let a = -coefficient / shape.mass[s as usize] * shape.velocity[s as usize];
                        world.shapes.range(s).for_each(|i| accel[i] += a);
                    }
                }
                Effect::AngularDamping { coefficient, .. } => {
                    for &s in &t.shapes {
                        let v_com = shape.velocity[s as usize];
                        world
                            .shapes
                            .range(s)
                            .for_each(|i| accel[i] -= coefficient * (p.velocity[i] - v_com));
                    }
                }
                Effect::ConstantForce { force, .. } => {
                    for &s in &t.shapes {
                        let a = force / shape.mass[s as usize];
                        world.shapes.range(s).for_each(|i| accel[i] += a);
                    }
                }
                Effect::TableTilt { angle, azimuth } => {
                    let (t1, t2) = tangent_basis(ground_normal);
                    let downhill = azimuth.cos() * t1 + azimuth.sin() * t2;
                    let g = gravity.length();
                    let tilted = g * (angle.sin() * downhill - angle.cos() * ground_normal);
                    let extra = tilted - gravity;
                    for &s in &t.shapes {
                        world.shapes.range(s).for_each(|i| accel[i] += extra);
                    }
                }
                Effect::Spring {
                    anchor,
                    stiffness,
                    rest_length,
                    damping,
                    tether,
                    ..
                } => {
                    let Some(i) = t.particle else { continue };
                    let d = p.position[i] - anchor;
                    let len = d.length();
                    if len < 1e-9 {
                        continue;
                    }
                    let dir = d / len;
                    let stretch = len - rest_length;
                    if tether && stretch <= 0.0 {
                        continue;
                    }
                    let force = -(stiffness * stretch + damping * p.velocity[i].dot(dir)) * dir;
                    accel[i] += force * inv_mass[i];
                }
                Effect::MassScale { .. }
                | Effect::CenterOfMassOffset { .. }
                | Effect::FrictionPatch { .. }
                | Effect::Restitution { .. } => {}
            }
        }
    }

    /// Each of `shapes` shapes' ground restitution (0 where no effect gives one; the last wins).
    pub fn restitution(&self, shapes: usize) -> Vec<f32> {
        let mut e = vec![0.0; shapes];
        for t in &self.terms {
            if let Effect::Restitution { coefficient, .. } = t.effect {
                t.shapes.iter().for_each(|&s| e[s as usize] = coefficient);
            }
        }
        e
    }

    pub fn has_friction_patches(&self) -> bool {
        self.terms
            .iter()
            .any(|t| matches!(t.effect, Effect::FrictionPatch { .. }))
    }

    /// Ground friction coefficients at `p`: the last patch containing it, else `base`.
    pub fn ground_friction(&self, p: Vec3, base: (f32, f32)) -> (f32, f32) {
        let mut mu = base;
        for t in &self.terms {
            if let Effect::FrictionPatch {
                center,
                half_size,
                static_friction,
                kinetic_friction,
            } = t.effect
            {
                let d = (Vec2::new(p.x, p.y) - center).abs();
                if d.x <= half_size.x && d.y <= half_size.y {
                    mu = (static_friction, kinetic_friction);
                }
            }
        }
        mu
    }
}

/// Two unit vectors spanning the plane with normal `n`; (x, y) for a horizontal table.
pub fn tangent_basis(n: Vec3) -> (Vec3, Vec3) {
    let seed = if n.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
    let t1 = (seed - seed.dot(n) * n).normalize();
    (t1, n.cross(t1))
}

/// Re-weight the masses of one shape linearly over its rest positions, `m_i' = m_i (1 + a . u_i)`,
/// so that the total mass stays the same and the centre of mass moves by `offset` (body frame).
fn shift_center_of_mass(
    world: &World,
    s: ShapeId,
    offset: Vec3,
    inv_mass: &mut [f32],
) -> Result<()> {
    let range = world.shapes.range(s);
    let rest = &world.particles.rest[range.clone()];
    let masses: Vec<f32> = inv_mass[range.clone()].iter().map(|w| 1.0 / w).collect();
    let total: f32 = masses.iter().sum();
    let com = rest.iter().zip(&masses).map(|(r, m)| *r * *m).sum::<Vec3>() / total;
    let mut cov = Mat3::ZERO;
    for (r, m) in rest.iter().zip(&masses) {
        let u = *r - com;
        cov += Mat3::from_cols(u * u.x, u * u.y, u * u.z) * *m;
    }
    if cov.determinant().abs() < 1e-18 {
        bail!(
            "center_of_mass_offset: object '{}' is flat or a line; its centre of mass cannot move off that set",
            world.shapes.name[s as usize]
        );
    }
    let a = cov.inverse() * (offset * total);
    for (k, i) in range.enumerate() {
        let weight = 1.0 + a.dot(rest[k] - com);
        if weight < 0.05 {
            bail!(
                "center_of_mass_offset: offset {offset} is too large for object '{}' (it would need negative mass)",
                world.shapes.name[s as usize]
            );
        }
        inv_mass[i] = 1.0 / (masses[k] * weight);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Pose;
    use crate::scene::{WorldBuilder, box_lattice};

    fn one_box() -> World {
        let mut b = WorldBuilder::new();
        b.add_rigid(
            "box",
            &box_lattice(Vec3::new(0.05, 0.04, 0.02), 0.01),
            0.005,
            0.002,
            Pose::IDENTITY,
            Vec3::ONE,
        );
        b.build()
    }

    #[test]
    fn center_of_mass_offset_moves_the_com_and_keeps_the_mass() {
        let w = one_box();
        let offset = Vec3::new(0.008, -0.004, 0.001);
        let model = EffectModel::bind(
            &[Effect::CenterOfMassOffset {
                object: "box".into(),
                offset,
            }],
            &w,
        )
        .unwrap();
        let inv = model.effective_inv_mass(&w).unwrap();
        let m: Vec<f32> = inv.iter().map(|x| 1.0 / x).collect();
        let total: f32 = m.iter().sum();
        let nominal: f32 = w.particles.inv_mass.iter().map(|x| 1.0 / x).sum();
        assert!((total - nominal).abs() / nominal < 1e-5);
        let com = w
            .particles
            .rest
            .iter()
            .zip(&m)
            .map(|(r, m)| *r * *m)
            .sum::<Vec3>()
            / total;
        assert!((com - offset).length() < 1e-5, "com {com} want {offset}");
        // Too far: outside the body needs negative masses, which is refused.
        let far = EffectModel::bind(
            &[Effect::CenterOfMassOffset {
                object: "box".into(),
                offset: Vec3::new(0.2, 0.0, 0.0),
            }],
            &w,
        )
        .unwrap();
        assert!(far.effective_inv_mass(&w).is_err());
    }

    #[test]
    fn parameters_round_trip_by_name_and_unknown_names_fail() {
        let mut e = Effect::Spring {
            object: "box".into(),
            point: Vec3::ZERO,
            anchor: Vec3::ONE,
            stiffness: 3.0,
            rest_length: 0.1,
            damping: 0.0,
            tether: true,
        };
        for (name, _) in e.parameters() {
            let mut f = e.clone();
            f.set_parameter(name, 0.25).unwrap();
            assert_eq!(
                f.parameters().iter().find(|(n, _)| *n == name).unwrap().1,
                0.25,
                "{name}"
            );
        }
        assert!(e.set_parameter("mass", 1.0).is_err());
        assert!(
            e.set_parameter("stiffness", -1.0).is_err(),
            "validation runs after setting"
        );
    }

    #[test]
    fn binding_reports_unknown_objects() {
        let w = one_box();
        let err = EffectModel::bind(
            &[Effect::MassScale {
                object: "mug".into(),
                factor: 2.0,
            }],
            &w,
        )
        .err()
        .unwrap();
        assert!(err.to_string().contains("mug"));
    }

    #[test]
    fn table_tilt_adds_the_downhill_component_of_gravity() {
        let w = one_box();
        let model = EffectModel::bind(
            &[Effect::TableTilt {
                angle: 0.1,
                azimuth: std::f32::consts::FRAC_PI_2,
            }],
            &w,
        )
        .unwrap();
        let n = w.particles.len();
        let mut accel = vec![Vec3::ZERO; n];
        let state = ShapeState {
            mass: &[1.0],
            velocity: &[Vec3::ZERO],
        };
        let g = Vec3::new(0.0, 0.0, -9.81);
        model.add_accelerations(&w, &w.particles.inv_mass, &state, g, Vec3::Z, &mut accel);
        let total = g + accel[0];
        assert!(
            (total.y - 9.81 * 0.1f32.sin()).abs() < 1e-5,
            "downhill along +y: {total}"
        );
        assert!(
            (total.length() - 9.81).abs() < 1e-4,
            "tilt only turns gravity"
        );
    }
}

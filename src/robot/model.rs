//! A robot description loaded from URDF (urdf-rs): links with their geometry and colour, joints
//! with origins, axes, limits and mimics, in a topological order for forward kinematics. Meshes
//! (STL, OBJ) are loaded here, resolved relative to the URDF file or through `package://` URIs.

use anyhow::{Context, Result, anyhow, bail};
use glam::{DAffine3, DMat3, DQuat, DVec3, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Which URDF geometry becomes particles.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GeometrySource {
    #[default]
    Collision,
    Visual,
}

#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// Full edge lengths.
    Box {
        size: DVec3,
    },
    /// Along the local z axis.
    Cylinder {
        radius: f64,
        length: f64,
    },
    /// Cylinder of `length` along z with hemispherical caps.
    Capsule {
        radius: f64,
        length: f64,
    },
    Sphere {
        radius: f64,
    },
    /// Triangles in the geometry frame, scale applied.
    Mesh {
        triangles: Vec<[DVec3; 3]>,
        source: PathBuf,
    },
}

/// One geometry element of a link, placed in the link frame.
#[derive(Clone, Debug, PartialEq)]
pub struct LinkGeometry {
    pub origin: DAffine3,
    pub shape: Shape,
}

#[derive(Clone, Debug)]
pub struct Link {
    pub name: String,
    pub geometry: Vec<LinkGeometry>,
    /// Linear RGB from the link's visual material, if it has one.
    pub colour: Option<Vec3>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointKind {
    Revolute,
    Continuous,
    Prismatic,
    Fixed,
}

#[derive(Clone, Debug)]
pub struct Joint {
    pub name: String,
    pub kind: JointKind,
    pub parent: usize,
    pub child: usize,
    /// Child frame relative to the parent link at zero joint position.
    pub origin: DAffine3,
    /// Unit axis in the joint frame.
    pub axis: DVec3,
    pub lower: f64,
    pub upper: f64,
    /// `(master joint, multiplier, offset)`: this joint follows another.
    pub mimic: Option<(usize, f64, f64)>,
}

#[derive(Clone, Debug)]
pub struct RobotModel {
    pub name: String,
    pub links: Vec<Link>,
    pub joints: Vec<Joint>,
    /// The link no joint moves: the robot's base frame.
    pub root: usize,
    /// Joint indices, each after the joint that moves its parent link.
    pub order: Vec<usize>,
    joint_by_name: HashMap<String, usize>,
    link_by_name: HashMap<String, usize>,
}

/// Where `package://` URIs are looked up: each directory is searched for `<package>/<path>`, and
/// a directory that is itself named `<package>` also matches.
#[derive(Clone, Debug, Default)]
pub struct PackagePaths(pub Vec<PathBuf>);

impl PackagePaths {
    /// `dirs`, then the `share` directory of every install prefix in `ament_prefix_path` (the
    /// value of `AMENT_PREFIX_PATH`, colon-separated), where colcon installs `<package>/...`.
    pub fn with_ament(dirs: &[PathBuf], ament_prefix_path: Option<&str>) -> Self {
        let mut all = dirs.to_vec();
        all.extend(
            ament_prefix_path
                .unwrap_or_default()
                .split(':')
                .filter(|p| !p.is_empty())
                .map(|p| Path::new(p).join("share")),
        );
        Self(all)
    }

    fn resolve(&self, uri: &str, base_dir: &Path) -> Result<PathBuf> {
        if let Some(rest) = uri.strip_prefix("package://") {
            let (package, relative) = rest
                .split_once('/')
                .ok_or_else(|| anyhow!("malformed package URI '{uri}'"))?;
            for dir in &self.0 {
                let mut candidates = vec![dir.join(package).join(relative)];
                if dir.file_name().is_some_and(|n| n == package) {
                    candidates.push(dir.join(relative));
                }
                if let Some(found) = candidates.into_iter().find(|c| c.is_file()) {
                    return Ok(found);
                }
            }
            bail!(
                "mesh '{uri}' not found: package '{package}' is not under any package path {:?}",
                self.0
            );
        }
        let path = uri.strip_prefix("file://").unwrap_or(uri);
        let p = Path::new(path);
        Ok(if p.is_absolute() {
            p.to_path_buf()
        } else {
            base_dir.join(p)
        })
    }
}

fn pose_to_affine(p: &urdf_rs::Pose) -> DAffine3 {
    let [r, pi, y] = p.rpy.0;
    // URDF rpy: fixed-axis roll about x, then pitch about y, then yaw about z: R = Rz(y) Ry(p) Rx(r).
    let rot = DQuat::from_rotation_z(y) * DQuat::from_rotation_y(pi) * DQuat::from_rotation_x(r);
    DAffine3::from_rotation_translation(rot, DVec3::from_array(p.xyz.0))
}

fn load_mesh(path: &Path, scale: DVec3) -> Result<Vec<[DVec3; 3]>> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let tris: Vec<[DVec3; 3]> = match ext.as_str() {
        "stl" => {
            let mut file = std::fs::File::open(path)
                .with_context(|| format!("cannot open mesh {}", path.display()))?;
            let mesh = stl_io::read_stl(&mut file)
                .with_context(|| format!("cannot read STL mesh {}", path.display()))?;
            let v = |i: usize| -> Result<DVec3> {
                let p = mesh
                    .vertices
                    .get(i)
                    .ok_or_else(|| anyhow!("STL {} references a missing vertex", path.display()))?;
                Ok(DVec3::new(p.0[0] as f64, p.0[1] as f64, p.0[2] as f64))
            };
            mesh.faces
                .iter()
                .map(|f| Ok([v(f.vertices[0])?, v(f.vertices[1])?, v(f.vertices[2])?]))
                .collect::<Result<_>>()?
        }
        "obj" => {
            let (models, _) = tobj::load_obj(path, &tobj::GPU_LOAD_OPTIONS)
                .with_context(|| format!("cannot read OBJ mesh {}", path.display()))?;
            let mut out = Vec::new();
            for m in models {
                let p = &m.mesh.positions;
                let v = |i: u32| -> Result<DVec3> {
                    let i = i as usize * 3;
                    if i + 2 >= p.len() {
                        bail!("OBJ {} references a missing vertex", path.display());
                    }
                    Ok(DVec3::new(p[i] as f64, p[i + 1] as f64, p[i + 2] as f64))
                };
                for f in m.mesh.indices.chunks_exact(3) {
                    out.push([v(f[0])?, v(f[1])?, v(f[2])?]);
                }
            }
            out
        }
        _ => bail!(
            "mesh {} has an unsupported format (STL and OBJ are)",
            path.display()
        ),
    };
    let tris: Vec<[DVec3; 3]> = tris.into_iter().map(|t| t.map(|p| p * scale)).collect();
    if tris.iter().any(|t| t.iter().any(|p| !p.is_finite())) {
        bail!("mesh {} has non-finite vertices", path.display());
    }
    Ok(tris)
}

fn convert_geometry(
    g: &urdf_rs::Geometry,
    base_dir: &Path,
    packages: &PackagePaths,
) -> Result<Shape> {
    let positive = |name: &str, v: f64| -> Result<f64> {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            bail!("{name} must be positive and finite, got {v}")
        }
    };
    Ok(match g {
        urdf_rs::Geometry::Box { size } => {
            let s = DVec3::from_array(size.0);
            for v in size.0 {
                positive("box size", v)?;
            }
            Shape::Box { size: s }
        }
        urdf_rs::Geometry::Cylinder { radius, length } => Shape::Cylinder {
            radius: positive("cylinder radius", *radius)?,
            length: positive("cylinder length", *length)?,
        },
        urdf_rs::Geometry::Capsule { radius, length } => Shape::Capsule {
            radius: positive("capsule radius", *radius)?,
            length: positive("capsule length", *length)?,
        },
        urdf_rs::Geometry::Sphere { radius } => Shape::Sphere {
            radius: positive("sphere radius", *radius)?,
        },
        urdf_rs::Geometry::Mesh { filename, scale } => {
            let path = packages.resolve(filename, base_dir)?;
            if !path.is_file() {
                bail!(
                    "mesh file {} (from '{filename}') does not exist",
                    path.display()
                );
            }
            let scale = scale.map(|s| DVec3::from_array(s.0)).unwrap_or(DVec3::ONE);
            Shape::Mesh {
                triangles: load_mesh(&path, scale)?,
                source: path,
            }
        }
    })
}

fn material_colour(m: &urdf_rs::Material, named: &HashMap<String, Vec3>) -> Option<Vec3> {
    match &m.color {
        Some(c) => Some(Vec3::new(
            c.rgba.0[0] as f32,
            c.rgba.0[1] as f32,
            c.rgba.0[2] as f32,
        )),
        None => named.get(&m.name).copied(),
    }
}

/// The name of the link no joint of the URDF `text` moves (its base frame).
pub fn root_link_name(text: &str) -> Result<String> {
    let urdf = urdf_rs::read_from_string(text).map_err(|e| anyhow!("malformed URDF: {e}"))?;
    let moved: std::collections::HashSet<&str> =
        urdf.joints.iter().map(|j| j.child.link.as_str()).collect();
    let roots: Vec<&str> = urdf
        .links
        .iter()
        .map(|l| l.name.as_str())
        .filter(|l| !moved.contains(l))
        .collect();
    match roots[..] {
        [root] => Ok(root.to_string()),
        _ => bail!("a robot needs exactly one root link, found {roots:?}"),
    }
}

impl RobotModel {
    /// Load a URDF file; meshes resolve relative to its directory or through `packages`.
    pub fn load(path: &Path, packages: &PackagePaths, source: GeometrySource) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read URDF {}", path.display()))?;
        let base = path.parent().unwrap_or(Path::new("."));
        Self::parse(&text, base, packages, source)
            .with_context(|| format!("in URDF {}", path.display()))
    }

    /// Parse URDF text; relative mesh paths resolve against `base_dir`.
    pub fn parse(
        text: &str,
        base_dir: &Path,
        packages: &PackagePaths,
        source: GeometrySource,
    ) -> Result<Self> {
        let urdf = urdf_rs::read_from_string(text).map_err(|e| anyhow!("malformed URDF: {e}"))?;
        let named: HashMap<String, Vec3> = urdf
            .materials
            .iter()
            .filter_map(|m| Some((m.name.clone(), material_colour(m, &HashMap::new())?)))
            .collect();
        let mut links = Vec::with_capacity(urdf.links.len());
        let mut link_by_name = HashMap::new();
        for l in &urdf.links {
            if link_by_name.insert(l.name.clone(), links.len()).is_some() {
                bail!("link '{}' is defined twice", l.name);
            }
            let elements: Vec<(&urdf_rs::Pose, &urdf_rs::Geometry)> = match source {
                GeometrySource::Collision => l
                    .collision
                    .iter()
                    .map(|c| (&c.origin, &c.geometry))
                    .collect(),
                GeometrySource::Visual => {
                    l.visual.iter().map(|v| (&v.origin, &v.geometry)).collect()
                }
            };
            let geometry = elements
                .into_iter()
                .map(|(origin, g)| {
                    Ok(LinkGeometry {
                        origin: pose_to_affine(origin),
                        shape: convert_geometry(g, base_dir, packages)
                            .with_context(|| format!("link '{}'", l.name))?,
                    })
                })
                .collect::<Result<Vec<_>>>()?;
            let colour = l
                .visual
                .iter()
                .find_map(|v| v.material.as_ref().and_then(|m| material_colour(m, &named)));
            links.push(Link {
                name: l.name.clone(),
                geometry,
                colour,
            });
        }
        let mut joints = Vec::with_capacity(urdf.joints.len());
        let mut joint_by_name = HashMap::new();
        let mut parent_of_link: Vec<Option<usize>> = vec![None; links.len()];
        for j in &urdf.joints {
            let kind = match j.joint_type {
                urdf_rs::JointType::Revolute => JointKind::Revolute,
                urdf_rs::JointType::Continuous => JointKind::Continuous,
                urdf_rs::JointType::Prismatic => JointKind::Prismatic,
                urdf_rs::JointType::Fixed => JointKind::Fixed,
                ref other => bail!(
                    "joint '{}' has type {other:?}, which pegs does not support (revolute, continuous, prismatic, fixed)",
                    j.name
                ),
            };
            let parent = *link_by_name.get(&j.parent.link).ok_or_else(|| {
                anyhow!(
                    "joint '{}' names unknown parent link '{}'",
                    j.name,
                    j.parent.link
                )
            })?;
            let child = *link_by_name.get(&j.child.link).ok_or_else(|| {
                anyhow!(
                    "joint '{}' names unknown child link '{}'",
                    j.name,
                    j.child.link
                )
            })?;
            if parent_of_link[child].is_some() {
                bail!("link '{}' is the child of two joints", j.child.link);
            }
            parent_of_link[child] = Some(joints.len());
            let axis = DVec3::from_array(j.axis.xyz.0);
            let axis = if kind == JointKind::Fixed {
                axis
            } else {
                axis.try_normalize()
                    .ok_or_else(|| anyhow!("joint '{}' has a zero axis", j.name))?
            };
            if joint_by_name.insert(j.name.clone(), joints.len()).is_some() {
                bail!("joint '{}' is defined twice", j.name);
            }
            joints.push(Joint {
                name: j.name.clone(),
                kind,
                parent,
                child,
                origin: pose_to_affine(&j.origin),
                axis,
                lower: j.limit.lower,
                upper: j.limit.upper,
                mimic: None,
            });
        }
        for (k, j) in urdf.joints.iter().enumerate() {
            if let Some(m) = &j.mimic {
                let master = *joint_by_name.get(&m.joint).ok_or_else(|| {
                    anyhow!("joint '{}' mimics unknown joint '{}'", j.name, m.joint)
                })?;
                joints[k].mimic =
                    Some((master, m.multiplier.unwrap_or(1.0), m.offset.unwrap_or(0.0)));
            }
        }
        let roots: Vec<usize> = (0..links.len())
            .filter(|&l| parent_of_link[l].is_none())
            .collect();
        let [root] = roots[..] else {
            bail!(
                "a robot needs exactly one root link, found {}: {:?}",
                roots.len(),
                roots.iter().map(|&l| &links[l].name).collect::<Vec<_>>()
            );
        };
        // Breadth-first from the root: each joint after the one that moves its parent link.
        let mut order = Vec::with_capacity(joints.len());
        let mut frontier = vec![root];
        while let Some(link) = frontier.pop() {
            for (k, j) in joints.iter().enumerate() {
                if j.parent == link {
                    order.push(k);
                    frontier.push(j.child);
                }
            }
        }
        if order.len() != joints.len() {
            bail!(
                "the joints do not form a tree from root link '{}'",
                links[root].name
            );
        }
        Ok(Self {
            name: urdf.name,
            links,
            joints,
            root,
            order,
            joint_by_name,
            link_by_name,
        })
    }

    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joint_by_name.get(name).copied()
    }

    pub fn link_index(&self, name: &str) -> Option<usize> {
        self.link_by_name.get(name).copied()
    }

    /// Joints with their own position (not fixed, not mimicking another).
    pub fn actuated_joints(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.joints.len())
            .filter(|&k| self.joints[k].kind != JointKind::Fixed && self.joints[k].mimic.is_none())
    }

    /// Poses of every link in the root frame for joint positions `q` (one per joint; fixed joints
    /// ignore theirs, mimic joints follow their master).
    pub fn forward_kinematics(&self, q: &[f64]) -> Vec<DAffine3> {
        let mut poses = vec![DAffine3::IDENTITY; self.links.len()];
        for &k in &self.order {
            let j = &self.joints[k];
            let value = match j.mimic {
                Some((master, mult, offset)) => {
                    mult * q.get(master).copied().unwrap_or(0.0) + offset
                }
                None => q.get(k).copied().unwrap_or(0.0),
            };
            let motion = match j.kind {
                JointKind::Revolute | JointKind::Continuous => {
                    DAffine3::from_mat3(DMat3::from_axis_angle(j.axis, value))
                }
                JointKind::Prismatic => DAffine3::from_translation(j.axis * value),
                JointKind::Fixed => DAffine3::IDENTITY,
            };
            poses[j.child] = poses[j.parent] * j.origin * motion;
        }
        poses
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TWO_LINK: &str = r#"<robot name="t">
      <material name="red"><color rgba="1 0 0 1"/></material>
      <link name="base"/>
      <link name="arm"><visual><geometry><box size="0.1 0.1 0.1"/></geometry><material name="red"/></visual>
        <collision><origin xyz="0.5 0 0"/><geometry><cylinder radius="0.02" length="1"/></geometry></collision></link>
      <link name="tip"/>
      <joint name="j1" type="revolute"><parent link="base"/><child link="arm"/><origin xyz="0 0 1" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
      <joint name="j2" type="prismatic"><parent link="arm"/><child link="tip"/><origin xyz="1 0 0"/><axis xyz="1 0 0"/><limit lower="0" upper="0.5" effort="1" velocity="1"/></joint>
    </robot>"#;

    #[test]
    fn revolute_and_prismatic_chain_moves_as_expected() {
        let m = RobotModel::parse(
            TWO_LINK,
            Path::new("."),
            &PackagePaths::default(),
            GeometrySource::Collision,
        )
        .unwrap();
        assert_eq!(
            m.links[m.link_index("arm").unwrap()].colour,
            Some(Vec3::new(1.0, 0.0, 0.0)),
            "named material resolved"
        );
        let q = vec![std::f64::consts::FRAC_PI_2, 0.25];
        let poses = m.forward_kinematics(&q);
        let tip = poses[m.link_index("tip").unwrap()].translation;
        // Arm turned 90 degrees about z at height 1: the tip (1 + 0.25 along the arm) lies along +y.
        assert!((tip - DVec3::new(0.0, 1.25, 1.0)).length() < 1e-12, "{tip}");
    }

    #[test]
    fn urdf_rpy_is_fixed_axis_roll_pitch_yaw() {
        let p = urdf_rs::Pose {
            xyz: urdf_rs::Vec3([0.0; 3]),
            rpy: urdf_rs::Vec3([0.3, -0.2, 1.1]),
        };
        let a = pose_to_affine(&p);
        let want = DMat3::from_rotation_z(1.1)
            * DMat3::from_rotation_y(-0.2)
            * DMat3::from_rotation_x(0.3);
        assert!(
            (a.matrix3 - want)
                .abs()
                .to_cols_array()
                .iter()
                .all(|d| *d < 1e-12)
        );
    }

    #[test]
    fn malformed_or_inconsistent_urdf_is_a_clear_error() {
        let p = PackagePaths::default();
        let err = |text: &str| {
            format!(
                "{:#}",
                RobotModel::parse(text, Path::new("."), &p, GeometrySource::Collision).unwrap_err()
            )
        };
        assert!(err("<robot name=\"x\"><link name=\"a\"").contains("malformed URDF"));
        assert!(
            err(&TWO_LINK.replace("<parent link=\"arm\"/>", "<parent link=\"nope\"/>"))
                .contains("unknown parent link 'nope'")
        );
        assert!(
            err(&TWO_LINK.replace("type=\"prismatic\"", "type=\"floating\""))
                .contains("does not support")
        );
        let missing = TWO_LINK.replace(
            "<cylinder radius=\"0.02\" length=\"1\"/>",
            "<mesh filename=\"meshes/none.stl\"/>",
        );
        let e = err(&missing);
        assert!(
            e.contains("none.stl") && e.contains("does not exist"),
            "{e}"
        );
        let e = err(&TWO_LINK.replace(
            "<cylinder radius=\"0.02\" length=\"1\"/>",
            "<mesh filename=\"package://nopkg/m.stl\"/>",
        ));
        assert!(e.contains("nopkg"), "{e}");
    }

    /// `package://` URIs are found in the configured directories first, then under
    /// `<prefix>/share/<package>` of every AMENT_PREFIX_PATH entry, as colcon installs them.
    #[test]
    fn package_uris_resolve_through_ament_install_prefixes() {
        let root = std::env::temp_dir().join(format!("pegs-ament-{}", std::process::id()));
        let mesh = root.join("install/franka_description/share/franka_description/meshes/l0.stl");
        std::fs::create_dir_all(mesh.parent().unwrap()).unwrap();
        std::fs::write(&mesh, b"solid x\nendsolid x\n").unwrap();
        let uri = "package://franka_description/meshes/l0.stl";
        let prefixes = format!(
            "/nonexistent:{}",
            root.join("install/franka_description").display()
        );
        let found = PackagePaths::with_ament(&[], Some(&prefixes))
            .resolve(uri, Path::new("."))
            .unwrap();
        assert_eq!(found, mesh);
        let e = PackagePaths::with_ament(&[], None)
            .resolve(uri, Path::new("."))
            .unwrap_err();
        assert!(
            format!("{e:#}").contains("package 'franka_description'"),
            "{e:#}"
        );
    }
}

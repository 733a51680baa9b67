//! Messages built from the tracked world at one tick: object states with their visual-force
//! wrenches, poses, particle clouds, object frames and debug images. Pure functions of the world
//! and the tick's correction; nothing here touches DDS.

use crate::correct::CorrectStats;
use crate::math::Pose;
use crate::msgs::{
    self, CompressedImage, Header, Image, PointCloud2, PointField, PoseArray, PoseMsg, TfMessage,
    TrackedObject, TrackedObjectArray, Transform, TransformStamped, Twist, Vector3, Wrench,
};
use crate::world::World;
use glam::{Mat3, Vec3};

fn vector(v: Vec3) -> Vector3 {
    Vector3 {
        x: v.x as f64,
        y: v.y as f64,
        z: v.z as f64,
    }
}

pub fn pose_msg(p: &Pose) -> PoseMsg {
    let q = p.rotation.normalize();
    PoseMsg {
        position: msgs::Point {
            x: p.translation.x as f64,
            y: p.translation.y as f64,
            z: p.translation.z as f64,
        },
        orientation: msgs::Quaternion {
            x: q.x as f64,
            y: q.y as f64,
            z: q.z as f64,
            w: q.w as f64,
        },
    }
}

/// Angular velocity of a group of particles moving (nearly) rigidly: the least-squares `w` with
/// `v_i = v + w x (x_i - c)`, from the particles' angular momentum about their centroid.
pub fn angular_velocity(positions: &[Vec3], velocities: &[Vec3], masses: &[f32]) -> Vec3 {
    let total: f32 = masses.iter().sum();
    if total <= 0.0 || positions.len() < 2 {
        return Vec3::ZERO;
    }
    let c = positions
        .iter()
        .zip(masses)
        .map(|(p, m)| *p * *m)
        .sum::<Vec3>()
        / total;
    let v = velocities
        .iter()
        .zip(masses)
        .map(|(p, m)| *p * *m)
        .sum::<Vec3>()
        / total;
    let mut inertia = Mat3::ZERO;
    let mut momentum = Vec3::ZERO;
    for ((x, u), m) in positions.iter().zip(velocities).zip(masses) {
        let r = *x - c;
        inertia += (Mat3::from_diagonal(Vec3::splat(r.length_squared()))
            - Mat3::from_cols(r * r.x, r * r.y, r * r.z))
            * *m;
        momentum += r.cross(*u - v) * *m;
    }
    if inertia.determinant().abs() < 1e-12 {
        return Vec3::ZERO;
    }
    inertia.inverse() * momentum
}

/// Every dynamic object at the tick: pose, twist and the visual-force wrench of this tick.
pub fn tracked_objects(
    world: &World,
    stats: Option<&CorrectStats>,
    header: &Header,
) -> TrackedObjectArray {
    let mut out = TrackedObjectArray {
        header: header.clone(),
        objects: Vec::new(),
    };
    for s in world.shapes.dynamic_ids() {
        let i = s as usize;
        let range = world.shapes.range(s);
        let p = &world.particles;
        let masses: Vec<f32> = range
            .clone()
            .map(|k| {
                if p.inv_mass[k] > 0.0 {
                    1.0 / p.inv_mass[k]
                } else {
                    0.0
                }
            })
            .collect();
        let w = angular_velocity(&p.position[range.clone()], &p.velocity[range], &masses);
        let (force, torque) = stats.map_or((Vec3::ZERO, Vec3::ZERO), |st| {
            (
                st.force.get(i).copied().unwrap_or_default(),
                st.torque.get(i).copied().unwrap_or_default(),
            )
        });
        out.objects.push(TrackedObject {
            name: world.shapes.name[i].clone(),
            pose: pose_msg(&world.shapes.pose[i]),
            twist: Twist {
                linear: vector(world.shape_velocity(s)),
                angular: vector(w),
            },
            visual_wrench: Wrench {
                force: vector(force),
                torque: vector(torque),
            },
        });
    }
    out
}

pub fn pose_array(objects: &TrackedObjectArray) -> PoseArray {
    PoseArray {
        header: objects.header.clone(),
        poses: objects.objects.iter().map(|o| o.pose).collect(),
    }
}

/// Object frames on /tf: world -> each object's body frame.
pub fn object_frames(objects: &TrackedObjectArray) -> TfMessage {
    TfMessage {
        transforms: objects
            .objects
            .iter()
            .map(|o| TransformStamped {
                header: objects.header.clone(),
                child_frame_id: o.name.clone(),
                transform: Transform {
                    translation: Vector3 {
                        x: o.pose.position.x,
                        y: o.pose.position.y,
                        z: o.pose.position.z,
                    },
                    rotation: o.pose.orientation,
                },
            })
            .collect(),
    }
}

/// Bytes per point of the particle cloud: x, y, z (float32) and the object id (uint32, the
/// shape index: robot links and objects alike).
pub const CLOUD_POINT_STEP: u32 = 16;

/// All particles as an unordered PointCloud2 with fields x, y, z, object_id (little-endian).
pub fn particle_cloud(world: &World, header: &Header) -> PointCloud2 {
    let p = &world.particles;
    let mut data = Vec::with_capacity(p.len() * CLOUD_POINT_STEP as usize);
    for (x, s) in p.position.iter().zip(&p.shape) {
        for v in [x.x, x.y, x.z] {
            data.extend_from_slice(&v.to_le_bytes());
        }
        data.extend_from_slice(&s.to_le_bytes());
    }
    let field = |name: &str, offset: u32, datatype: u8| PointField {
        name: name.into(),
        offset,
        datatype,
        count: 1,
    };
    PointCloud2 {
        header: header.clone(),
        height: 1,
        width: p.len() as u32,
        fields: vec![
            field("x", 0, PointField::FLOAT32),
            field("y", 4, PointField::FLOAT32),
            field("z", 8, PointField::FLOAT32),
            field("object_id", 12, PointField::UINT32),
        ],
        is_bigendian: false,
        point_step: CLOUD_POINT_STEP,
        row_step: CLOUD_POINT_STEP * p.len() as u32,
        data,
        is_dense: true,
    }
}

/// A rendered colour image (linear [0, 1]) as rgb8, and the same pixels PNG-compressed
/// (lossless, for remote viewers).
pub fn debug_images(
    colour: &[Vec3],
    width: u32,
    height: u32,
    header: &Header,
) -> anyhow::Result<(Image, CompressedImage)> {
    let data: Vec<u8> = colour
        .iter()
        .flat_map(|c| {
            (c.clamp(Vec3::ZERO, Vec3::ONE) * 255.0)
                .round()
                .to_array()
                .map(|v| v as u8)
        })
        .collect();
    anyhow::ensure!(
        data.len() == (width * height * 3) as usize,
        "render of {} pixels for a {width}x{height} image",
        colour.len()
    );
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new_with_quality(
        &mut png,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Sub,
    )
    .write_image(&data, width, height, image::ExtendedColorType::Rgb8)?;
    let raw = Image {
        header: header.clone(),
        height,
        width,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: width * 3,
        data,
    };
    Ok((
        raw,
        CompressedImage {
            header: header.clone(),
            format: "rgb8; png compressed rgb8".into(),
            data: png,
        },
    ))
}

use image::ImageEncoder;

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;

    #[test]
    fn angular_velocity_of_a_rigid_spin_is_recovered() {
        let positions: Vec<Vec3> = (0..20)
            .map(|k| {
                Vec3::new(
                    (k as f32 * 0.7).sin(),
                    (k as f32 * 1.3).cos(),
                    (k as f32 * 0.4).sin() * 0.5,
                ) * 0.1
                    + Vec3::new(0.5, 0.0, 0.1)
            })
            .collect();
        let masses: Vec<f32> = (0..20).map(|k| 0.01 + 0.001 * k as f32).collect();
        let total: f32 = masses.iter().sum();
        let c = positions
            .iter()
            .zip(&masses)
            .map(|(p, m)| *p * *m)
            .sum::<Vec3>()
            / total;
        let (v, w) = (Vec3::new(0.1, -0.2, 0.0), Vec3::new(0.3, -1.0, 2.0));
        let velocities: Vec<Vec3> = positions.iter().map(|x| v + w.cross(*x - c)).collect();
        let got = angular_velocity(&positions, &velocities, &masses);
        assert!((got - w).length() < 1e-3, "{got} vs {w}");
        assert_eq!(
            angular_velocity(&positions[..1], &velocities[..1], &masses[..1]),
            Vec3::ZERO
        );
    }

    #[test]
    fn particle_cloud_layout_decodes_back_to_the_particles() {
        let mut world = World::default();
        world.particles.push(
            Vec3::new(1.0, 2.0, 3.0),
            1.0,
            0.01,
            0,
            crate::world::Phase::Dynamic,
            Vec3::ZERO,
        );
        world.particles.push(
            Vec3::new(-1.0, 0.5, 0.25),
            1.0,
            0.01,
            7,
            crate::world::Phase::Dynamic,
            Vec3::ZERO,
        );
        let cloud = particle_cloud(&world, &Header::default());
        assert_eq!(cloud.data.len(), 2 * CLOUD_POINT_STEP as usize);
        assert_eq!(cloud.row_step as usize, cloud.data.len());
        let f = |at: usize| f32::from_le_bytes(cloud.data[at..at + 4].try_into().unwrap());
        let point = CLOUD_POINT_STEP as usize;
        assert_eq!([f(point), f(point + 4), f(point + 8)], [-1.0, 0.5, 0.25]);
        assert_eq!(
            u32::from_le_bytes(cloud.data[point + 12..point + 16].try_into().unwrap()),
            7
        );
        assert_eq!(
            cloud
                .fields
                .iter()
                .map(|f| f.name.as_str())
                .collect::<Vec<_>>(),
            ["x", "y", "z", "object_id"]
        );
    }

    #[test]
    fn debug_png_holds_exactly_the_raw_pixels() {
        let colour: Vec<Vec3> = (0..12)
            .map(|k| Vec3::new(k as f32 / 11.0, 0.5, 1.0 - k as f32 / 11.0))
            .collect();
        let (raw, compressed) = debug_images(&colour, 4, 3, &Header::default()).unwrap();
        let decoded =
            image::load_from_memory_with_format(&compressed.data, image::ImageFormat::Png)
                .unwrap()
                .to_rgb8();
        assert_eq!(decoded.as_raw(), &raw.data);
        assert!(debug_images(&colour, 5, 3, &Header::default()).is_err());
    }

    #[test]
    fn object_frames_carry_the_poses() {
        let pose = Pose::new(Vec3::new(0.1, 0.2, 0.3), Quat::from_rotation_z(0.5));
        let objects = TrackedObjectArray {
            header: Header::default(),
            objects: vec![TrackedObject {
                name: "box".into(),
                pose: pose_msg(&pose),
                ..Default::default()
            }],
        };
        let tf = object_frames(&objects);
        assert_eq!(tf.transforms[0].child_frame_id, "box");
        assert!((tf.transforms[0].transform.rotation.z - (0.25f64).sin()).abs() < 1e-6);
        assert_eq!(pose_array(&objects).poses[0].position.y, 0.2f32 as f64);
    }
}

//! The publishing thread: each tick's output (objects, poses, /tf, the particle cloud, sometimes
//! diagnostics and debug renders) goes out here, so the tick thread never waits on the network;
//! a tick's output is dropped if the previous one is still being sent. Failures are logged (the
//! first few) and never stop the thread.

use super::params::Remaps;
use super::subscribe::{sensor_qos, state_qos, topic_name};
use super::{RosClock, log, outputs};
use crate::msgs::{
    CompressedImage, DiagnosticArray, Header, Image, PointCloud2, PoseArray, TfMessage,
    TrackedObjectArray,
};
use crate::render::{Camera, GaussianCloud, Roi};
use crate::topics::NodeConfig;
use anyhow::{Result, anyhow};
use ros2_client::{MessageTypeName, Node, Publisher, QosProfile};
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

/// One tick's results for the publishing thread.
pub struct TickOutput {
    pub header: Header,
    pub objects: TrackedObjectArray,
    pub cloud: PointCloud2,
    /// Newest image stamp used (for the end-to-end latency).
    pub newest_image: Option<f64>,
    /// The world's Gaussians and the cameras to render them into.
    pub debug: Option<(GaussianCloud, Vec<DebugView>)>,
    pub diagnostics: Option<DiagnosticArray>,
}

/// What the tick thread hands the publishing thread: a tick's messages, or, before tracking
/// starts, diagnostics saying what the node waits for.
pub enum Output {
    Tick(Box<TickOutput>),
    Waiting(DiagnosticArray),
}

/// A camera to render a debug image for: name, model and optical frame (the image's frame_id).
pub type DebugView = (String, Camera, String);

pub struct Publishers {
    objects: Publisher<TrackedObjectArray>,
    poses: Publisher<PoseArray>,
    cloud: Publisher<PointCloud2>,
    tf: Publisher<TfMessage>,
    pub diagnostics: Publisher<DiagnosticArray>,
    debug: BTreeMap<String, (Publisher<Image>, Publisher<CompressedImage>)>,
}

/// Every output topic, under `node.output_prefix`.
pub fn create_publishers(node: &mut Node, nc: &NodeConfig, remaps: &Remaps) -> Result<Publishers> {
    fn make<T: serde::Serialize>(
        (node, remaps): (&mut Node, &Remaps),
        name: &str,
        package: &str,
        ty: &str,
        qos: QosProfile,
    ) -> Result<Publisher<T>> {
        let name = &remaps.apply(name);
        let topic = node
            .create_topic(&topic_name(name)?, MessageTypeName::new(package, ty), &qos)
            .map_err(|e| anyhow!("topic {name}: {e:?}"))?;
        node.create_publisher(&topic, None)
            .map_err(|e| anyhow!("publisher {name}: {e:?}"))
    }
    let p = &nc.output_prefix;
    let mut debug = BTreeMap::new();
    for cam in &nc.cameras {
        let raw = make(
            (node, remaps),
            &format!("{p}/debug/{cam}/image"),
            "sensor_msgs",
            "Image",
            sensor_qos(),
        )?;
        let compressed = make(
            (node, remaps),
            &format!("{p}/debug/{cam}/image/compressed"),
            "sensor_msgs",
            "CompressedImage",
            sensor_qos(),
        )?;
        debug.insert(cam.clone(), (raw, compressed));
    }
    Ok(Publishers {
        objects: make(
            (node, remaps),
            &format!("{p}/objects"),
            "pegs_msgs",
            "TrackedObjectArray",
            state_qos(10),
        )?,
        poses: make(
            (node, remaps),
            &format!("{p}/poses"),
            "geometry_msgs",
            "PoseArray",
            state_qos(10),
        )?,
        cloud: make(
            (node, remaps),
            &format!("{p}/particles"),
            "sensor_msgs",
            "PointCloud2",
            sensor_qos(),
        )?,
        tf: make(
            (node, remaps),
            "/tf",
            "tf2_msgs",
            "TFMessage",
            state_qos(100),
        )?,
        diagnostics: make(
            (node, remaps),
            "/diagnostics",
            "diagnostic_msgs",
            "DiagnosticArray",
            state_qos(10),
        )?,
        debug,
    })
}

/// Publish every output that arrives until the tick thread hangs up.
pub fn publish_loop(
    rx: std::sync::mpsc::Receiver<Output>,
    publishers: Publishers,
    render: crate::render::RenderSettings,
    latencies: Arc<Mutex<Vec<f64>>>,
    clock: RosClock,
) {
    let mut renderer = crate::render::cpu::CpuRenderer::images_only(render);
    let mut failures = 0usize;
    let mut fail = |what: &str, e: String| {
        failures += 1;
        if failures <= 5 {
            log(&format!("publishing {what} failed: {e}"));
        }
    };
    while let Ok(out) = rx.recv() {
        let out = match out {
            Output::Tick(out) => *out,
            Output::Waiting(d) => {
                if let Err(e) = publishers.diagnostics.publish(d) {
                    fail("diagnostics", format!("{e:?}"));
                }
                continue;
            }
        };
        let tf = outputs::object_frames(&out.objects);
        let poses = outputs::pose_array(&out.objects);
        if let Err(e) = publishers.objects.publish(out.objects) {
            fail("objects", format!("{e:?}"));
        }
        if let Some(stamp) = out.newest_image
            && let Some(now) = clock.now()
            && let Ok(mut l) = latencies.lock()
            && l.len() < 1_000_000
        {
            l.push(now - stamp);
        }
        if let Err(e) = publishers.poses.publish(poses) {
            fail("poses", format!("{e:?}"));
        }
        if let Err(e) = publishers.tf.publish(tf) {
            fail("tf", format!("{e:?}"));
        }
        if let Err(e) = publishers.cloud.publish(out.cloud) {
            fail("particles", format!("{e:?}"));
        }
        if let Some(d) = out.diagnostics
            && let Err(e) = publishers.diagnostics.publish(d)
        {
            fail("diagnostics", format!("{e:?}"));
        }
        if let Some((cloud, cameras)) = out.debug {
            for (name, camera, frame_id) in cameras {
                let Some((raw_pub, compressed_pub)) = publishers.debug.get(&name) else {
                    continue;
                };
                let rendered = crate::render::Renderer::forward(
                    &mut renderer,
                    &cloud,
                    &camera,
                    Roi::full(&camera),
                );
                match rendered.and_then(|r| {
                    outputs::debug_images(
                        &r.colour,
                        camera.width,
                        camera.height,
                        &Header {
                            frame_id,
                            ..out.header.clone()
                        },
                    )
                }) {
                    Ok((raw, compressed)) => {
                        if let Err(e) = raw_pub.publish(raw) {
                            fail("debug image", format!("{e:?}"));
                        }
                        if let Err(e) = compressed_pub.publish(compressed) {
                            fail("debug image", format!("{e:?}"));
                        }
                    }
                    Err(e) => fail("debug image", format!("{e:#}")),
                }
            }
        }
    }
}

//! The wgpu compute backend: the CPU reference's semantics as WGSL kernels, one pipeline per
//! kernel (`*.wgsl` beside this file, each prefixed with `common.wgsl`):
//! project -> scan_tiles -> emit -> sort_tiles -> raster_forward, and raster_backward ->
//! gather_backward. Per-tile lists are sorted by (depth, index) and gradients are reduced in a
//! fixed order, so results are deterministic like the CPU backend's. Runs on any Vulkan/Metal/DX12
//! adapter, including Mesa's lavapipe on CPU-only machines (used in CI).

use super::{Camera, CloudGrads, GaussianCloud, PixelGrads, RenderOutput, RenderSettings, Roi};
use anyhow::{Context, Result, anyhow, bail};
use bytemuck::{Pod, Zeroable};
use glam::{Vec3, Vec4};
use std::borrow::Cow;

const COMMON: &str = include_str!("common.wgsl");

/// Kernels and the bindings each one uses (indices into `Buffers::by_binding`).
const KERNELS: [(&str, &str, &[u32]); 7] = [
    ("project", include_str!("project.wgsl"), &[0, 1, 2, 3, 4]),
    ("scan_tiles", include_str!("scan.wgsl"), &[0, 4, 5]),
    ("emit", include_str!("emit.wgsl"), &[0, 3, 5, 6, 7]),
    ("sort_tiles", include_str!("sort.wgsl"), &[0, 2, 5, 7]),
    (
        "raster_forward",
        include_str!("raster.wgsl"),
        &[0, 2, 5, 7, 8, 9],
    ),
    (
        "raster_backward",
        include_str!("backward.wgsl"),
        &[0, 2, 5, 7, 9, 10, 11],
    ),
    (
        "gather_backward",
        include_str!("gather.wgsl"),
        &[0, 1, 2, 3, 5, 7, 11, 12],
    ),
];

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Params {
    rot: [[f32; 4]; 3],
    trans: [f32; 4],
    intr: [f32; 4],
    background: [f32; 4],
    cut: [f32; 4],
    misc: [f32; 4],
    size: [u32; 4],
    roi: [u32; 4],
    tiles: [u32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct GpuGaussian {
    mean_opacity: [f32; 4],
    rotation: [f32; 4],
    log_scale: [f32; 4],
    colour: [f32; 4],
}

/// Sizes in bytes of one element of each binding's array.
const PROJECTED_SIZE: u64 = 48;
const PARTIAL_SIZE: u64 = 48;
const GRAD_SIZE: u64 = 64;
const PIXEL_GRAD_SIZE: u64 = 32;

struct Kernel {
    pipeline: wgpu::ComputePipeline,
    bindings: &'static [u32],
}

/// A storage buffer that grows to the largest size asked of it.
struct Slot {
    buffer: Option<wgpu::Buffer>,
    usage: wgpu::BufferUsages,
}

impl Slot {
    fn ensure(&mut self, device: &wgpu::Device, bytes: u64, label: &str) {
        // At least one element of the largest binding type (a Gaussian's gradient, 64 bytes):
        // an empty frame still binds every buffer.
        let bytes = bytes.max(GRAD_SIZE).next_multiple_of(16);
        if self.buffer.as_ref().is_none_or(|b| b.size() < bytes) {
            self.buffer = Some(device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes,
                usage: self.usage,
                mapped_at_creation: false,
            }));
        }
    }
}

struct Frame {
    roi: Roi,
    n_gaussians: usize,
    n_pairs: u64,
    tiles: (u32, u32),
}

pub struct GpuRenderer {
    pub settings: RenderSettings,
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: String,
    kernels: Vec<Kernel>,
    /// Binding index -> buffer slot (binding 0 is the uniform).
    slots: Vec<Slot>,
    frame: Option<Frame>,
    /// Where read-backs land (`read`), grown like the storage slots.
    staging: Slot,
}

/// The elements in bytes read back: borrowed where the bytes are aligned for `T`, else copied
/// out one by one (an empty read-back is never aligned).
fn rows<T: Pod>(bytes: &[u8]) -> Cow<'_, [T]> {
    match bytemuck::try_cast_slice(bytes) {
        Ok(rows) => Cow::Borrowed(rows),
        Err(_) => Cow::Owned(
            bytes
                .chunks_exact(std::mem::size_of::<T>())
                .map(bytemuck::pod_read_unaligned)
                .collect(),
        ),
    }
}

fn storage() -> wgpu::BufferUsages {
    wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC
}

impl GpuRenderer {
    /// Open the first adapter wgpu offers (honours `WGPU_BACKEND`, e.g. `vulkan` for lavapipe).
    pub fn new(settings: RenderSettings) -> Result<Self> {
        if settings.tile != 16 {
            bail!(
                "the wgpu backend renders 16 x 16 tiles (render.tile = {})",
                settings.tile
            );
        }
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|e| {
            anyhow!(
                "no GPU adapter for the wgpu backend (install mesa-vulkan-drivers for a CPU one; \
                 on a headless NVIDIA machine set VK_ICD_FILENAMES to a JSON file naming \
                 libEGL_nvidia.so.0, see the README's GPU figures): {e}"
            )
        })?;
        let info = adapter.get_info();
        let adapter_name = format!("{} ({:?}, {:?})", info.name, info.backend, info.device_type);
        // Ask for what the adapter offers: large scenes need big storage buffers.
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("pegs-render"),
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .context("cannot open the GPU device")?;
        let kernels = KERNELS
            .iter()
            .map(|(entry, source, bindings)| {
                let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some(entry),
                    source: wgpu::ShaderSource::Wgsl(format!("{COMMON}\n{source}").into()),
                });
                let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(entry),
                    layout: None,
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    cache: None,
                });
                Kernel { pipeline, bindings }
            })
            .collect();
        let mut slots: Vec<Slot> = (0..13)
            .map(|_| Slot {
                buffer: None,
                usage: storage(),
            })
            .collect();
        slots[0].usage = wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST;
        Ok(Self {
            settings,
            device,
            queue,
            adapter: adapter_name,
            kernels,
            slots,
            frame: None,
            staging: Slot {
                buffer: None,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            },
        })
    }

    /// The adapter in use, e.g. "llvmpipe (LLVM 15.0.6, 256 bits) (Vulkan, Cpu)".
    pub fn adapter(&self) -> &str {
        &self.adapter
    }

    fn buffer(&self, binding: u32) -> &wgpu::Buffer {
        self.slots[binding as usize]
            .buffer
            .as_ref()
            .expect("buffer allocated before use")
    }

    fn dispatch(&self, encoder: &mut wgpu::CommandEncoder, kernel: usize, groups: (u32, u32)) {
        if groups.0 == 0 || groups.1 == 0 {
            return;
        }
        let k = &self.kernels[kernel];
        let entries: Vec<wgpu::BindGroupEntry> = k
            .bindings
            .iter()
            .map(|&b| wgpu::BindGroupEntry {
                binding: b,
                resource: self.buffer(b).as_entire_binding(),
            })
            .collect();
        let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &k.pipeline.get_bind_group_layout(0),
            entries: &entries,
        });
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some(KERNELS[kernel].0),
            timestamp_writes: None,
        });
        pass.set_pipeline(&k.pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(groups.0, groups.1, 1);
    }

    /// Copy `(binding, byte offset, bytes)` ranges back to the host in one submission and one
    /// wait: each wait is a round trip to the device, which costs more than these small copies.
    fn read(
        &mut self,
        encoder: wgpu::CommandEncoder,
        ranges: &[(u32, u64, u64)],
    ) -> Result<Vec<Vec<u8>>> {
        let mut encoder = encoder;
        // Copies move whole 4-byte words: each range is padded up to one.
        let padded: Vec<u64> = ranges
            .iter()
            .map(|r| r.2.max(4).next_multiple_of(4))
            .collect();
        let total: u64 = padded.iter().sum();
        self.staging.ensure(&self.device, total, "readback");
        let staging = self.staging.buffer.as_ref().expect("ensured above");
        let mut at = 0;
        for (&(binding, offset, _), &bytes) in ranges.iter().zip(&padded) {
            let source = self.slots[binding as usize]
                .buffer
                .as_ref()
                .expect("buffer allocated before use");
            encoder.copy_buffer_to_buffer(source, offset, staging, at, bytes);
            at += bytes;
        }
        self.queue.submit(Some(encoder.finish()));
        let slice = staging.slice(..total);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| anyhow!("GPU poll failed: {e}"))?;
        rx.recv()
            .context("GPU read-back never completed")?
            .map_err(|e| anyhow!("GPU read-back failed: {e}"))?;
        let data = {
            let mapped = slice
                .get_mapped_range()
                .map_err(|e| anyhow!("cannot map read-back: {e:?}"))?;
            let mut at = 0;
            ranges
                .iter()
                .zip(&padded)
                .map(|(r, &bytes)| {
                    let part = mapped[at as usize..(at + r.2) as usize].to_vec();
                    at += bytes;
                    part
                })
                .collect()
        };
        staging.unmap();
        Ok(data)
    }

    fn params(
        &self,
        camera: &Camera,
        roi: Roi,
        n: usize,
        tiles: (u32, u32),
        tile_origin: (u32, u32),
    ) -> Params {
        let r = camera.rotation();
        let s = &self.settings;
        let t = camera.world_to_camera.translation;
        Params {
            rot: [
                r.x_axis.extend(0.0).to_array(),
                r.y_axis.extend(0.0).to_array(),
                r.z_axis.extend(0.0).to_array(),
            ],
            trans: t.extend(0.0).to_array(),
            intr: [camera.fx, camera.fy, camera.cx, camera.cy],
            background: s.background.extend(s.blur).to_array(),
            cut: [s.near, s.cutoff_sigma, s.min_alpha, s.max_alpha],
            misc: [s.min_transmittance, 0.0, 0.0, 0.0],
            size: [camera.width, camera.height, n as u32, 16],
            roi: [roi.x0, roi.y0, roi.x1, roi.y1],
            tiles: [tile_origin.0, tile_origin.1, tiles.0, tiles.1],
        }
    }

    /// Render `cloud` into `camera` over `roi` (clamped to the image).
    pub fn forward(
        &mut self,
        cloud: &GaussianCloud,
        camera: &Camera,
        roi: Roi,
    ) -> Result<RenderOutput> {
        let roi = roi.clamped(camera);
        let n = cloud.len();
        let tile_origin = (roi.x0 / 16, roi.y0 / 16);
        let tiles = if roi.pixels() == 0 {
            (0, 0)
        } else {
            (
                (roi.x1 - 1) / 16 - tile_origin.0 + 1,
                (roi.y1 - 1) / 16 - tile_origin.1 + 1,
            )
        };
        let n_tiles = (tiles.0 * tiles.1) as u64;
        let d = &self.device;
        let params = self.params(camera, roi, n, tiles, tile_origin);
        self.slots[0].ensure(d, std::mem::size_of::<Params>() as u64, "params");
        self.slots[1].ensure(d, 64 * n as u64, "gaussians");
        self.slots[2].ensure(d, PROJECTED_SIZE * n as u64, "projected");
        self.slots[3].ensure(d, 16 * n as u64, "rects");
        self.slots[4].ensure(d, 4 * n_tiles, "tile_counts");
        self.slots[5].ensure(d, 4 * (n_tiles + 1), "tile_offsets");
        self.slots[6].ensure(d, 4 * n_tiles, "tile_fill");
        self.slots[8].ensure(d, 16 * roi.pixels() as u64, "image");
        self.slots[9].ensure(d, 16 * roi.pixels() as u64, "aux");
        let gaussians: Vec<GpuGaussian> = (0..n)
            .map(|i| GpuGaussian {
                mean_opacity: cloud.mean[i].extend(cloud.opacity_logit[i]).to_array(),
                rotation: cloud.rotation[i].to_array(),
                log_scale: cloud.log_scale[i].extend(0.0).to_array(),
                colour: cloud.colour[i].extend(0.0).to_array(),
            })
            .collect();
        self.queue
            .write_buffer(self.buffer(0), 0, bytemuck::bytes_of(&params));
        if n > 0 {
            self.queue
                .write_buffer(self.buffer(1), 0, bytemuck::cast_slice(&gaussians));
        }
        let mut enc = d.create_command_encoder(&Default::default());
        enc.clear_buffer(self.buffer(4), 0, None);
        self.dispatch(&mut enc, 0, ((n as u32).div_ceil(256), 1));
        if n_tiles > 0 {
            self.dispatch(&mut enc, 1, (1, 1));
        } else {
            enc.clear_buffer(self.buffer(5), 0, None);
        }
        // The (tile, Gaussian) pair lists are written into the capacity the last frames needed,
        // and their total comes back with the image: one wait per frame. A frame that needs more
        // (the first, or a view that grew) is listed and rastered again into a bigger buffer.
        let pixels = roi.pixels();
        let wanted = [
            (5, 4 * n_tiles, 4),
            (8, 0, 16 * pixels as u64),
            (9, 0, 16 * pixels as u64),
        ];
        let capacity = self.pair_capacity(n);
        let mut data = self.list_and_raster(enc, capacity, tiles, n, &wanted)?;
        let n_pairs = u32::from_le_bytes(data[0][..4].try_into().expect("4 bytes read")) as u64;
        if n_pairs > capacity {
            let enc = self.device.create_command_encoder(&Default::default());
            data = self.list_and_raster(enc, n_pairs + n_pairs / 4, tiles, n, &wanted)?;
        }
        let image: Cow<[[f32; 4]]> = rows(&data[1]);
        let aux: Cow<[[f32; 4]]> = rows(&data[2]);
        self.frame = Some(Frame {
            roi,
            n_gaussians: n,
            n_pairs,
            tiles,
        });
        Ok(RenderOutput {
            roi: Some(roi),
            colour: image.iter().map(|p| Vec3::new(p[0], p[1], p[2])).collect(),
            alpha: image.iter().map(|p| p[3]).collect(),
            depth: aux.iter().map(|p| p[0]).collect(),
        })
    }

    /// Pairs the pair buffer holds: at least what the last frames needed, and 16 per Gaussian.
    fn pair_capacity(&mut self, n: usize) -> u64 {
        self.slots[7].ensure(&self.device, 4 * 16 * n as u64, "pairs");
        self.buffer(7).size() / 4
    }

    /// Grow the pair buffer to `capacity`, then emit, sort and raster the projected frame and
    /// read `wanted` back. The kernels leave the lists alone when they do not fit; the total
    /// read back then says how many are needed.
    fn list_and_raster(
        &mut self,
        mut enc: wgpu::CommandEncoder,
        capacity: u64,
        tiles: (u32, u32),
        n: usize,
        wanted: &[(u32, u64, u64)],
    ) -> Result<Vec<Vec<u8>>> {
        self.slots[7].ensure(&self.device, 4 * capacity, "pairs");
        enc.clear_buffer(self.buffer(6), 0, None);
        self.dispatch(&mut enc, 2, ((n as u32).div_ceil(256), 1));
        self.dispatch(&mut enc, 3, tiles);
        self.dispatch(&mut enc, 4, tiles);
        self.read(enc, wanted)
    }

    /// Gradients of a loss with respect to `cloud` given its gradients with respect to the images
    /// of the last `forward` (which must have rendered this same cloud).
    pub fn backward(&mut self, cloud: &GaussianCloud, d_image: &PixelGrads) -> Result<CloudGrads> {
        let Some(f) = &self.frame else {
            bail!("backward called before forward")
        };
        let n_px = f.roi.pixels();
        if d_image.colour.len() != n_px
            || !(d_image.alpha.is_empty() || d_image.alpha.len() == n_px)
            || !(d_image.depth.is_empty() || d_image.depth.len() == n_px)
        {
            bail!(
                "pixel gradients do not match the rendered window ({} pixels)",
                n_px
            );
        }
        if f.n_gaussians != cloud.len() {
            bail!(
                "backward for a cloud of {} Gaussians after rendering {}",
                cloud.len(),
                f.n_gaussians
            );
        }
        let (n, n_pairs, tiles) = (f.n_gaussians, f.n_pairs, f.tiles);
        let upstream: Vec<[f32; 8]> = (0..n_px)
            .map(|i| {
                let c = d_image.colour[i];
                let a = d_image.alpha.get(i).copied().unwrap_or(0.0);
                let z = d_image.depth.get(i).copied().unwrap_or(0.0);
                [c.x, c.y, c.z, a, z, 0.0, 0.0, 0.0]
            })
            .collect();
        let d = &self.device;
        self.slots[10].ensure(d, PIXEL_GRAD_SIZE * n_px as u64, "pixel_grads");
        self.slots[11].ensure(d, PARTIAL_SIZE * n_pairs, "partials");
        self.slots[12].ensure(d, GRAD_SIZE * n as u64, "grads");
        if n_px > 0 {
            self.queue
                .write_buffer(self.buffer(10), 0, bytemuck::cast_slice(&upstream));
        }
        let mut enc = self.device.create_command_encoder(&Default::default());
        enc.clear_buffer(self.buffer(11), 0, None);
        self.dispatch(&mut enc, 5, tiles);
        self.dispatch(&mut enc, 6, ((n as u32).div_ceil(256), 1));
        let raw = self.read(enc, &[(12, 0, GRAD_SIZE * n as u64)])?;
        let g: Cow<[[f32; 16]]> = rows(&raw[0]);
        let mut out = CloudGrads::zeros(n);
        for (i, v) in g.iter().enumerate() {
            out.mean[i] = Vec3::new(v[0], v[1], v[2]);
            out.rotation[i] = Vec4::new(v[4], v[5], v[6], v[7]);
            out.log_scale[i] = Vec3::new(v[8], v[9], v[10]);
            out.opacity_logit[i] = v[11];
            out.colour[i] = Vec3::new(v[12], v[13], v[14]);
        }
        Ok(out)
    }
}

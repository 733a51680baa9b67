// Declarations shared by every kernel of the wgpu backend (prepended to each kernel's source).
// Semantics mirror src/render/project.rs and src/render/cpu.rs exactly.

struct Params {
    // World-to-camera rotation (columns) and translation.
    rot0: vec4<f32>,
    rot1: vec4<f32>,
    rot2: vec4<f32>,
    trans: vec4<f32>,
    // fx, fy, cx, cy
    intr: vec4<f32>,
    // background rgb, blur
    background: vec4<f32>,
    // near, cutoff_sigma, min_alpha, max_alpha
    cut: vec4<f32>,
    // min_transmittance
    misc: vec4<f32>,
    // width, height, number of Gaussians, tile edge
    size: vec4<u32>,
    // window x0, y0, x1, y1
    roi: vec4<u32>,
    // first tile x, first tile y, tiles across, tiles down
    tiles: vec4<u32>,
}

struct Gaussian {
    mean_opacity: vec4<f32>,
    rotation: vec4<f32>,
    log_scale: vec4<f32>,
    colour: vec4<f32>,
}

struct Projected {
    // mean x, mean y, depth, radius
    mean_depth_radius: vec4<f32>,
    // conic a, b, c, opacity
    conic_opacity: vec4<f32>,
    // colour rgb, 1 when valid
    colour_valid: vec4<f32>,
}

struct PixelGrad {
    colour_alpha: vec4<f32>,
    depth: vec4<f32>,
}

struct Partial {
    // mean x, mean y, opacity, depth
    mean_opacity_depth: vec4<f32>,
    conic: vec4<f32>,
    colour: vec4<f32>,
}

struct GaussianGrad {
    mean: vec4<f32>,
    rotation: vec4<f32>,
    // log-scale xyz, opacity logit
    log_scale_opacity: vec4<f32>,
    colour: vec4<f32>,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> gaussians: array<Gaussian>;
@group(0) @binding(2) var<storage, read_write> projected: array<Projected>;
// Tile rectangle of each Gaussian in the window's tile grid: x0, y0, x1, y1 (exclusive).
@group(0) @binding(3) var<storage, read_write> rects: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read_write> tile_counts: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> tile_offsets: array<u32>;
@group(0) @binding(6) var<storage, read_write> tile_fill: array<atomic<u32>>;
@group(0) @binding(7) var<storage, read_write> pairs: array<u32>;
// Per window pixel: colour rgb + alpha; depth, final transmittance, processed count (bits), 0.
@group(0) @binding(8) var<storage, read_write> image: array<vec4<f32>>;
@group(0) @binding(9) var<storage, read_write> aux: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read> pixel_grads: array<PixelGrad>;
@group(0) @binding(11) var<storage, read_write> partials: array<Partial>;
@group(0) @binding(12) var<storage, read_write> grads: array<GaussianGrad>;

fn tile_count() -> u32 {
    return params.tiles.z * params.tiles.w;
}

// Whether every tile's list fits the pair buffer (the scan's last offset is their total).
fn pairs_fit() -> bool {
    return tile_offsets[tile_count()] <= arrayLength(&pairs);
}

// Alpha, Gaussian value and offset of a Gaussian at pixel centre p; alpha < 0 when it does not
// contribute (beyond the cut-off ellipse or below min_alpha).
struct Eval {
    alpha: f32,
    gauss: f32,
    d: vec2<f32>,
}

fn evaluate(g: Projected, p: vec2<f32>) -> Eval {
    var e: Eval;
    e.alpha = -1.0;
    e.d = p - g.mean_depth_radius.xy;
    let c = g.conic_opacity;
    let q = c.x * e.d.x * e.d.x + 2.0 * c.y * e.d.x * e.d.y + c.z * e.d.y * e.d.y;
    let cutoff = params.cut.y;
    if (!(q <= cutoff * cutoff)) {
        return e;
    }
    e.gauss = exp(-0.5 * q);
    let alpha = min(c.w * e.gauss, params.cut.w);
    if (alpha < params.cut.z) {
        return e;
    }
    e.alpha = alpha;
    return e;
}

// Sort key order within a tile: depth (bits with the low 8 mantissa bits dropped, as
// cpu::depth_key), then Gaussian index.
fn key_less(a: u32, b: u32) -> bool {
    let da = bitcast<u32>(projected[a].mean_depth_radius.z) & 0xFFFFFF00u;
    let db = bitcast<u32>(projected[b].mean_depth_radius.z) & 0xFFFFFF00u;
    return da < db || (da == db && a < b);
}

// Rotation matrix (columns) of a unit quaternion x, y, z, w.
fn rotation_matrix(q: vec4<f32>) -> mat3x3<f32> {
    let x = q.x; let y = q.y; let z = q.z; let w = q.w;
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
}

// The intermediate quantities of the EWA projection, as `forward_intermediate` in project.rs.
// Callers check validity: t.z >= near, qn > 0, and a positive 2-D determinant.
struct Ewa {
    w: mat3x3<f32>,
    t: vec3<f32>,
    // x/z, y/z before and after the field-of-view clamp
    raw: vec2<f32>,
    u: vec2<f32>,
    j0: vec3<f32>,
    j1: vec3<f32>,
    q: vec4<f32>,
    qn: f32,
    r: mat3x3<f32>,
    // variances along the Gaussian's own axes
    d: vec3<f32>,
    // camera-frame 3-D covariance
    m: mat3x3<f32>,
    // 2-D covariance entries A, B, C with the blur
    abc: vec3<f32>,
}

fn ewa(g: Gaussian) -> Ewa {
    var e: Ewa;
    e.w = mat3x3<f32>(params.rot0.xyz, params.rot1.xyz, params.rot2.xyz);
    e.t = e.w * g.mean_opacity.xyz + params.trans.xyz;
    let fx = params.intr.x; let fy = params.intr.y;
    let lim = vec2<f32>(1.3 * f32(params.size.x) / (2.0 * fx), 1.3 * f32(params.size.y) / (2.0 * fy));
    e.raw = vec2<f32>(e.t.x / e.t.z, e.t.y / e.t.z);
    e.u = clamp(e.raw, -lim, lim);
    e.j0 = vec3<f32>(fx / e.t.z, 0.0, -fx * e.u.x / e.t.z);
    e.j1 = vec3<f32>(0.0, fy / e.t.z, -fy * e.u.y / e.t.z);
    e.qn = length(g.rotation);
    e.q = g.rotation / e.qn;
    e.r = rotation_matrix(e.q);
    e.d = exp(2.0 * g.log_scale.xyz);
    let sigma = e.r * mat3x3<f32>(vec3<f32>(e.d.x, 0.0, 0.0), vec3<f32>(0.0, e.d.y, 0.0), vec3<f32>(0.0, 0.0, e.d.z)) * transpose(e.r);
    e.m = e.w * sigma * transpose(e.w);
    let blur = params.background.w;
    e.abc = vec3<f32>(dot(e.j0, e.m * e.j0) + blur, dot(e.j0, e.m * e.j1), dot(e.j1, e.m * e.j1) + blur);
    return e;
}

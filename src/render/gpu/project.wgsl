// Project every Gaussian (EWA), find its tile rectangle, count Gaussians per tile.

fn sigmoid(x: f32) -> f32 {
    return 1.0 / (1.0 + exp(-x));
}

@compute @workgroup_size(256)
fn project(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (i >= params.size.z) {
        return;
    }
    var out: Projected;
    out.colour_valid = vec4<f32>(0.0);
    rects[i] = vec4<u32>(0u);
    let g = gaussians[i];
    let e = ewa(g);
    let t = e.t;
    let fx = params.intr.x; let fy = params.intr.y;
    if (!(t.z >= params.cut.x) || !(e.qn > 1e-12)) {
        projected[i] = out;
        return;
    }
    let a = e.abc.x;
    let b = e.abc.y;
    let c = e.abc.z;
    let det = a * c - b * b;
    if (!(det > 0.0)) {
        projected[i] = out;
        return;
    }
    let mid = 0.5 * (a + c);
    let lambda_max = mid + sqrt(max(mid * mid - det, 0.0));
    let radius = params.cut.y * sqrt(lambda_max);
    let mean = vec2<f32>(fx * t.x / t.z + params.intr.z, fy * t.y / t.z + params.intr.w);
    out.mean_depth_radius = vec4<f32>(mean, t.z, radius);
    out.conic_opacity = vec4<f32>(c / det, -b / det, a / det, sigmoid(g.mean_opacity.w));
    out.colour_valid = vec4<f32>(g.colour.xyz, 1.0);
    projected[i] = out;

    // Pixels whose centre lies within the radius, clipped to the window, then their tiles.
    let lo = ceil(mean - vec2<f32>(radius) - vec2<f32>(0.5));
    let hi = floor(mean + vec2<f32>(radius) - vec2<f32>(0.5));
    let x0 = max(lo.x, f32(params.roi.x));
    let y0 = max(lo.y, f32(params.roi.y));
    let x1 = min(hi.x, f32(params.roi.z) - 1.0);
    let y1 = min(hi.y, f32(params.roi.w) - 1.0);
    if (!(x0 <= x1 && y0 <= y1)) {
        return;
    }
    let tile = params.size.w;
    let tx0 = u32(x0) / tile - params.tiles.x;
    let tx1 = u32(x1) / tile - params.tiles.x + 1u;
    let ty0 = u32(y0) / tile - params.tiles.y;
    let ty1 = u32(y1) / tile - params.tiles.y + 1u;
    rects[i] = vec4<u32>(tx0, ty0, tx1, ty1);
    for (var ty = ty0; ty < ty1; ty++) {
        for (var tx = tx0; tx < tx1; tx++) {
            atomicAdd(&tile_counts[ty * params.tiles.z + tx], 1u);
        }
    }
}

// Back-to-front gradient walk, one workgroup per tile. All invocations step through the tile's
// list in lockstep; each entry's contributions from the tile's pixels are summed by a tree
// reduction in a fixed order (deterministic, no float atomics) into partials[entry].

var<workgroup> red0: array<vec4<f32>, 256>;
var<workgroup> red1: array<vec4<f32>, 256>;
var<workgroup> red2: array<vec4<f32>, 256>;
var<workgroup> longest: atomic<u32>;

@compute @workgroup_size(16, 16)
fn raster_backward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid3: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let tile = params.size.w;
    let px = (params.tiles.x + wg.x) * tile + lid3.x;
    let py = (params.tiles.y + wg.y) * tile + lid3.y;
    let inside = px >= params.roi.x && px < params.roi.z && py >= params.roi.y && py < params.roi.w;
    let t = wg.y * params.tiles.z + wg.x;
    let start = tile_offsets[t];
    let p = vec2<f32>(f32(px) + 0.5, f32(py) + 0.5);
    var last = 0u;
    var t_after = 1.0;
    var up_colour = vec3<f32>(0.0);
    var up_alpha = 0.0;
    var up_depth = 0.0;
    if (inside) {
        let i = (py - params.roi.y) * (params.roi.z - params.roi.x) + (px - params.roi.x);
        let a = aux[i];
        t_after = a.y;
        last = bitcast<u32>(a.z);
        let g = pixel_grads[i];
        up_colour = g.colour_alpha.xyz;
        up_alpha = g.colour_alpha.w;
        up_depth = g.depth.x;
    }
    if (lid == 0u) {
        atomicStore(&longest, 0u);
    }
    workgroupBarrier();
    atomicMax(&longest, last);
    let steps = workgroupUniformLoad(&longest);
    var behind_colour = params.background.xyz;
    var behind_alpha = 0.0;
    var behind_depth = 0.0;
    for (var s = steps; s > 0u; s--) {
        let k = s - 1u;
        var c0 = vec4<f32>(0.0);
        var c1 = vec4<f32>(0.0);
        var c2 = vec4<f32>(0.0);
        if (k < last) {
            let g = projected[pairs[start + k]];
            let e = evaluate(g, p);
            if (e.alpha >= 0.0) {
                let alpha = e.alpha;
                let colour = g.colour_valid.xyz;
                let depth = g.mean_depth_radius.z;
                let t_before = t_after / (1.0 - alpha);
                let d_alpha = t_before * (dot(colour - behind_colour, up_colour) + (1.0 - behind_alpha) * up_alpha + (depth - behind_depth) * up_depth);
                let weight = alpha * t_before;
                c2 = vec4<f32>(weight * up_colour, 0.0);
                c0.w = weight * up_depth;
                if (g.conic_opacity.w * e.gauss < params.cut.w) {
                    c0.z = d_alpha * e.gauss;
                    let d_power = d_alpha * alpha;
                    let cc = g.conic_opacity;
                    let d = e.d;
                    c0.x = d_power * (cc.x * d.x + cc.y * d.y);
                    c0.y = d_power * (cc.y * d.x + cc.z * d.y);
                    c1 = vec4<f32>(d_power * vec3<f32>(-0.5 * d.x * d.x, -d.x * d.y, -0.5 * d.y * d.y), 0.0);
                }
                behind_colour = alpha * colour + (1.0 - alpha) * behind_colour;
                behind_alpha = alpha + (1.0 - alpha) * behind_alpha;
                behind_depth = alpha * depth + (1.0 - alpha) * behind_depth;
                t_after = t_before;
            }
        }
        red0[lid] = c0;
        red1[lid] = c1;
        red2[lid] = c2;
        workgroupBarrier();
        for (var stride = 128u; stride > 0u; stride >>= 1u) {
            if (lid < stride) {
                red0[lid] += red0[lid + stride];
                red1[lid] += red1[lid + stride];
                red2[lid] += red2[lid + stride];
            }
            workgroupBarrier();
        }
        if (lid == 0u) {
            var part: Partial;
            part.mean_opacity_depth = red0[0];
            part.conic = red1[0];
            part.colour = red2[0];
            partials[start + k] = part;
        }
        workgroupBarrier();
    }
}

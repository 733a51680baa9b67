// Front-to-back compositing: one workgroup per tile, one invocation per pixel.

@compute @workgroup_size(16, 16)
fn raster_forward(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    let tile = params.size.w;
    let px = (params.tiles.x + wg.x) * tile + lid.x;
    let py = (params.tiles.y + wg.y) * tile + lid.y;
    if (px < params.roi.x || px >= params.roi.z || py < params.roi.y || py >= params.roi.w) {
        return;
    }
    let t = wg.y * params.tiles.z + wg.x;
    let start = tile_offsets[t];
    let end = tile_offsets[t + 1u];
    let p = vec2<f32>(f32(px) + 0.5, f32(py) + 0.5);
    var colour = vec3<f32>(0.0);
    var depth = 0.0;
    var tr = 1.0;
    var last = 0u;
    for (var k = start; k < end; k++) {
        let g = projected[pairs[k]];
        let e = evaluate(g, p);
        if (e.alpha < 0.0) {
            continue;
        }
        let next_t = tr * (1.0 - e.alpha);
        if (next_t < params.misc.x) {
            break;
        }
        colour += e.alpha * tr * g.colour_valid.xyz;
        depth += e.alpha * tr * g.mean_depth_radius.z;
        tr = next_t;
        last = k - start + 1u;
    }
    let i = (py - params.roi.y) * (params.roi.z - params.roi.x) + (px - params.roi.x);
    image[i] = vec4<f32>(colour + tr * params.background.xyz, 1.0 - tr);
    aux[i] = vec4<f32>(depth, tr, bitcast<f32>(last), 0.0);
}

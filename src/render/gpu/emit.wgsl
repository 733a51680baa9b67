// Write each Gaussian's index into the lists of the tiles it touches (order fixed later by sort).
// Lists that do not fit the pair buffer are not written: the host reads their total and grows it.

@compute @workgroup_size(256)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (i >= params.size.z || !pairs_fit()) {
        return;
    }
    let r = rects[i];
    for (var ty = r.y; ty < r.w; ty++) {
        for (var tx = r.x; tx < r.z; tx++) {
            let t = ty * params.tiles.z + tx;
            let slot = atomicAdd(&tile_fill[t], 1u);
            pairs[tile_offsets[t] + slot] = i;
        }
    }
}

// Sort each tile's list by (depth, index): one workgroup per tile, a bitonic network whose
// comparators all put the smaller key first, so the list can be padded virtually with +infinity
// up to a power of two without storing the padding.

var<workgroup> count_shared: u32;

// Put the smaller key of entries a < b first; entries at or past n are virtual +infinity.
fn compare_swap(start: u32, a: u32, b: u32, n: u32) {
    if (b < n) {
        let ga = pairs[start + a];
        let gb = pairs[start + b];
        if (key_less(gb, ga)) {
            pairs[start + a] = gb;
            pairs[start + b] = ga;
        }
    }
}

@compute @workgroup_size(256)
fn sort_tiles(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let t = wg.y * params.tiles.z + wg.x;
    if (lid == 0u) {
        count_shared = select(0u, tile_offsets[t + 1u] - tile_offsets[t], pairs_fit());
    }
    let n = workgroupUniformLoad(&count_shared);
    let start = tile_offsets[t];
    var np = 1u;
    while (np < n) {
        np <<= 1u;
    }
    for (var k = 2u; k <= np; k <<= 1u) {
        // Flip stage: compare a with its mirror in the block of size k.
        let half_k = k >> 1u;
        for (var i = lid; i < np / 2u; i += 256u) {
            let a = (i / half_k) * k + (i % half_k);
            let b = (i / half_k) * k + k - 1u - (i % half_k);
            compare_swap(start, a, b, n);
        }
        storageBarrier();
        workgroupBarrier();
        // Half-cleaners at distances k/4 .. 1.
        for (var j = k >> 2u; j > 0u; j >>= 1u) {
            for (var i = lid; i < np / 2u; i += 256u) {
                let a = (i / j) * 2u * j + (i % j);
                let b = a + j;
                compare_swap(start, a, b, n);
            }
            storageBarrier();
            workgroupBarrier();
        }
    }
}

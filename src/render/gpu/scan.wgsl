// Exclusive prefix sum of the per-tile counts into tile_offsets (one workgroup, chunks of 256);
// tile_offsets[tiles] is the total number of (tile, Gaussian) pairs.

var<workgroup> chunk: array<u32, 256>;
var<workgroup> carry: u32;

@compute @workgroup_size(256)
fn scan_tiles(@builtin(local_invocation_index) lid: u32) {
    let n = tile_count();
    if (lid == 0u) {
        carry = 0u;
    }
    for (var base = 0u; base < n; base += 256u) {
        let i = base + lid;
        var v = 0u;
        if (i < n) {
            v = atomicLoad(&tile_counts[i]);
        }
        chunk[lid] = v;
        workgroupBarrier();
        // Hillis-Steele inclusive scan.
        for (var offset = 1u; offset < 256u; offset <<= 1u) {
            var add = 0u;
            if (lid >= offset) {
                add = chunk[lid - offset];
            }
            workgroupBarrier();
            chunk[lid] += add;
            workgroupBarrier();
        }
        let base_carry = carry;
        if (i < n) {
            tile_offsets[i] = base_carry + chunk[lid] - v;
        }
        workgroupBarrier();
        if (lid == 255u) {
            carry = base_carry + chunk[255];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        tile_offsets[n] = carry;
    }
}

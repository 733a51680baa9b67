// Per Gaussian: find its entry in every tile it touches (binary search by (depth, index) in the
// sorted list), sum the partial gradients in tile order, then chain through the projection
// (the same maths as project_backward in src/render/project.rs).

fn outer(a: vec3<f32>, b: vec3<f32>) -> mat3x3<f32> {
    return mat3x3<f32>(a * b.x, a * b.y, a * b.z);
}

fn frobenius(a: mat3x3<f32>, b: mat3x3<f32>) -> f32 {
    return dot(a[0], b[0]) + dot(a[1], b[1]) + dot(a[2], b[2]);
}

fn diag(d: vec3<f32>) -> mat3x3<f32> {
    return mat3x3<f32>(vec3<f32>(d.x, 0.0, 0.0), vec3<f32>(0.0, d.y, 0.0), vec3<f32>(0.0, 0.0, d.z));
}

@compute @workgroup_size(256)
fn gather_backward(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (i >= params.size.z) {
        return;
    }
    var out: GaussianGrad;
    out.mean = vec4<f32>(0.0);
    out.rotation = vec4<f32>(0.0);
    out.log_scale_opacity = vec4<f32>(0.0);
    out.colour = vec4<f32>(0.0);
    if (projected[i].colour_valid.w == 0.0) {
        grads[i] = out;
        return;
    }
    // Sum this Gaussian's partials over its tiles, in tile order.
    var g_mean2 = vec2<f32>(0.0);
    var g_conic = vec3<f32>(0.0);
    var g_opacity = 0.0;
    var g_depth = 0.0;
    var g_colour = vec3<f32>(0.0);
    let r = rects[i];
    for (var ty = r.y; ty < r.w; ty++) {
        for (var tx = r.x; tx < r.z; tx++) {
            let t = ty * params.tiles.z + tx;
            var lo = tile_offsets[t];
            var hi = tile_offsets[t + 1u];
            while (lo < hi) {
                let mid = (lo + hi) / 2u;
                if (key_less(pairs[mid], i)) {
                    lo = mid + 1u;
                } else {
                    hi = mid;
                }
            }
            if (lo < tile_offsets[t + 1u] && pairs[lo] == i) {
                let part = partials[lo];
                g_mean2 += part.mean_opacity_depth.xy;
                g_opacity += part.mean_opacity_depth.z;
                g_depth += part.mean_opacity_depth.w;
                g_conic += part.conic.xyz;
                g_colour += part.colour.xyz;
            }
        }
    }

    let g = gaussians[i];
    let e = ewa(g);
    let w = e.w;
    let t = e.t;
    let fx = params.intr.x; let fy = params.intr.y;
    let raw = e.raw;
    let u = e.u;
    let j0 = e.j0;
    let j1 = e.j1;
    let q = e.q;
    let qn = e.qn;
    let rm = e.r;
    let d = e.d;
    let m = e.m;
    let a = e.abc.x;
    let b = e.abc.y;
    let c = e.abc.z;
    let det = a * c - b * b;
    let inv2 = 1.0 / (det * det);
    let ga = g_conic.x; let gb = g_conic.y; let gc = g_conic.z;
    let d_a = inv2 * (-c * c * ga + b * c * gb - b * b * gc);
    let d_b = inv2 * (2.0 * b * c * ga - (a * c + b * b) * gb + 2.0 * a * b * gc);
    let d_c = inv2 * (-b * b * ga + a * b * gb - a * a * gc);
    let g_m = outer(j0, j0) * d_a + outer(j0, j1) * d_b + outer(j1, j1) * d_c;
    let mm = m + transpose(m);
    let g_j0 = mm * j0 * d_a + m * j1 * d_b;
    let g_j1 = transpose(m) * j0 * d_b + mm * j1 * d_c;
    let z = t.z;
    var g_t = vec3<f32>(0.0);
    g_t.z += g_j0.x * (-fx / (z * z)) + g_j1.y * (-fy / (z * z));
    if (raw.x != u.x) {
        g_t.z += g_j0.z * fx * u.x / (z * z);
    } else {
        g_t.x += g_j0.z * (-fx / (z * z));
        g_t.z += g_j0.z * 2.0 * fx * t.x / (z * z * z);
    }
    if (raw.y != u.y) {
        g_t.z += g_j1.z * fy * u.y / (z * z);
    } else {
        g_t.y += g_j1.z * (-fy / (z * z));
        g_t.z += g_j1.z * 2.0 * fy * t.y / (z * z * z);
    }
    g_t.x += g_mean2.x * fx / z;
    g_t.y += g_mean2.y * fy / z;
    g_t.z += -g_mean2.x * fx * t.x / (z * z) - g_mean2.y * fy * t.y / (z * z) + g_depth;
    out.mean = vec4<f32>(transpose(w) * g_t, 0.0);

    let g_sigma = transpose(w) * g_m * w;
    let g_r = (g_sigma + transpose(g_sigma)) * rm * diag(d);
    let rt_g_r = transpose(rm) * g_sigma * rm;
    let g_log_scale = 2.0 * d * vec3<f32>(rt_g_r[0].x, rt_g_r[1].y, rt_g_r[2].z);

    let x = q.x; let y = q.y; let zq = q.z; let ww = q.w;
    let dr_dx = mat3x3<f32>(vec3<f32>(0.0, 2.0 * y, 2.0 * zq), vec3<f32>(2.0 * y, -4.0 * x, 2.0 * ww), vec3<f32>(2.0 * zq, -2.0 * ww, -4.0 * x));
    let dr_dy = mat3x3<f32>(vec3<f32>(-4.0 * y, 2.0 * x, -2.0 * ww), vec3<f32>(2.0 * x, 0.0, 2.0 * zq), vec3<f32>(2.0 * ww, 2.0 * zq, -4.0 * y));
    let dr_dz = mat3x3<f32>(vec3<f32>(-4.0 * zq, 2.0 * ww, 2.0 * x), vec3<f32>(-2.0 * ww, -4.0 * zq, 2.0 * y), vec3<f32>(2.0 * x, 2.0 * y, 0.0));
    let dr_dw = mat3x3<f32>(vec3<f32>(0.0, 2.0 * zq, -2.0 * y), vec3<f32>(-2.0 * zq, 0.0, 2.0 * x), vec3<f32>(2.0 * y, -2.0 * x, 0.0));
    let g_q = vec4<f32>(frobenius(g_r, dr_dx), frobenius(g_r, dr_dy), frobenius(g_r, dr_dz), frobenius(g_r, dr_dw));
    out.rotation = (g_q - q * dot(q, g_q)) / qn;

    let o = 1.0 / (1.0 + exp(-g.mean_opacity.w));
    out.log_scale_opacity = vec4<f32>(g_log_scale, g_opacity * o * (1.0 - o));
    out.colour = vec4<f32>(g_colour, 0.0);
    grads[i] = out;
}

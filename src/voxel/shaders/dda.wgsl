// Shared by the SVO and N-tree compute shaders: the slab test and the Amanatides–Woo DDA of
// src/voxel/traverse.rs, operation for operation (same order of f32 operations), so the GPU
// reaches the same cells as the CPU. Infinities are avoided (WGSL leaves them indeterminate):
// axes with a zero direction component are handled by branches, and BIG stands for ∞.

const BIG: f32 = 3.0e38;

// Entry and exit t of the box [lo, hi] (traverse::box_interval).
fn box_interval(o: vec3<f32>, d: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> vec2<f32> {
    var t0 = -BIG;
    var t1 = BIG;
    for (var k = 0; k < 3; k++) {
        if (d[k] == 0.0) {
            // The CPU's ±∞ slab: empty when the origin is outside it, else no constraint.
            if (o[k] < lo[k] || o[k] > hi[k]) {
                return vec2<f32>(BIG, -BIG);
            }
            continue;
        }
        let inv = 1.0 / d[k];
        var a = (lo[k] - o[k]) * inv;
        var b = (hi[k] - o[k]) * inv;
        if (a > b) {
            let s = a;
            a = b;
            b = s;
        }
        if (a > t0) {
            t0 = a;
        }
        if (b < t1) {
            t1 = b;
        }
    }
    return vec2<f32>(t0, t1);
}

struct Dda {
    c: vec3<i32>,
    step: vec3<i32>,
    t_max: vec3<f32>,
    t_delta: vec3<f32>,
}

// traverse::Dda::new: starts in the cell holding the point at t, clamped into 0..n.
fn dda_new(o: vec3<f32>, d: vec3<f32>, base: vec3<f32>, cell: f32, n: vec3<i32>, t: f32) -> Dda {
    var r: Dda;
    r.c = vec3<i32>(0);
    r.step = vec3<i32>(0);
    r.t_max = vec3<f32>(BIG);
    r.t_delta = vec3<f32>(BIG);
    for (var k = 0; k < 3; k++) {
        let p = o[k] + d[k] * t;
        let f = floor((p - base[k]) / cell);
        let c = i32(clamp(f, 0.0, f32(n[k] - 1)));
        r.c[k] = c;
        if (d[k] > 0.0) {
            r.step[k] = 1;
            let edge = base[k] + f32(c + 1) * cell;
            r.t_max[k] = (edge - o[k]) / d[k];
            r.t_delta[k] = cell / d[k];
        } else if (d[k] < 0.0) {
            r.step[k] = -1;
            let edge = base[k] + f32(c) * cell;
            r.t_max[k] = (edge - o[k]) / d[k];
            r.t_delta[k] = -cell / d[k];
        }
    }
    return r;
}

// Exit t of the current cell.
fn dda_exit(d: Dda) -> f32 {
    return min(min(d.t_max.x, d.t_max.y), d.t_max.z);
}

// Steps to the next cell; false when it leaves 0..n.
fn dda_advance(d: ptr<function, Dda>, n: i32) -> bool {
    var k = 2;
    if ((*d).t_max.x <= (*d).t_max.y && (*d).t_max.x <= (*d).t_max.z) {
        k = 0;
    } else if ((*d).t_max.y <= (*d).t_max.z) {
        k = 1;
    }
    (*d).c[k] += (*d).step[k];
    (*d).t_max[k] += (*d).t_delta[k];
    return (*d).c[k] >= 0 && (*d).c[k] < n;
}

// Index of invocation `gid` in a 2D dispatch `stride` invocations wide.
fn flat_index(gid: vec3<u32>, stride: u32) -> u32 {
    return gid.y * stride + gid.x;
}

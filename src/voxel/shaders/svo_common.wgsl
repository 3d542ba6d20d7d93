// Shared by the SVO traversal shaders (svo_trace.wgsl, svo_lod.wgsl): Morton slots and 64-bit
// masks as (low, high) u32 pairs, the bricks of the packed `leaves` array (src/voxel/packed.rs)
// and the voxel entry t of src/voxel/traverse.rs. The including shader declares the `leaves`
// binding (bytes, little endian in u32 words).

// Morton slot of a 2-bit cell coordinate inside a 4³ node.
fn slot_of(c: vec3<i32>) -> u32 {
    let u = vec3<u32>(c);
    return (u.x & 1u) | ((u.y & 1u) << 1u) | ((u.z & 1u) << 2u)
        | ((u.x & 2u) << 2u) | ((u.y & 2u) << 3u) | ((u.z & 2u) << 4u);
}

fn mask_bit(m: vec2<u32>, s: u32) -> bool {
    let w = select(m.x, m.y, s >= 32u);
    return ((w >> (s & 31u)) & 1u) == 1u;
}

// popcount(mask & ((1 << s) − 1)).
fn count_below(m: vec2<u32>, s: u32) -> u32 {
    if (s < 32u) {
        return countOneBits(m.x & ((1u << s) - 1u));
    }
    return countOneBits(m.x) + countOneBits(m.y & ((1u << (s - 32u)) - 1u));
}

fn leaf_byte(b: u32) -> u32 {
    return (leaves[b >> 2u] >> ((b & 3u) * 8u)) & 0xffu;
}

// The 64-bit mask (low, high) of brick `index` among the bricks starting at byte `first`.
fn brick_mask(first: u32, index: u32) -> vec2<u32> {
    var at = first;
    for (var i = 0u; i < index; i++) {
        at += 1u + countOneBits(leaf_byte(at));
    }
    let octants = leaf_byte(at);
    var m = vec2<u32>(0u);
    var k = at + 1u;
    for (var o = 0u; o < 8u; o++) {
        if (((octants >> o) & 1u) == 1u) {
            let b = leaf_byte(k);
            k += 1u;
            if (o < 4u) {
                m.x |= b << (8u * o);
            } else {
                m.y |= b << (8u * (o - 4u));
            }
        }
    }
    return m;
}

fn voxel_entry_t(o: vec3<f32>, d: vec3<f32>, t_min: f32, v: vec3<u32>) -> f32 {
    let lo = vec3<f32>(v);
    return max(box_interval(o, d, lo, lo + vec3<f32>(1.0)).x, t_min);
}


// Voxels of the bricks before brick `index` among the bricks starting at byte `first`.
fn voxels_before(first: u32, index: u32) -> u32 {
    var at = first;
    var n = 0u;
    for (var i = 0u; i < index; i++) {
        let k = countOneBits(leaf_byte(at));
        for (var j = 1u; j <= k; j++) {
            n += countOneBits(leaf_byte(at + j));
        }
        at += 1u + k;
    }
    return n;
}

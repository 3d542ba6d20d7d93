//! Texture filtering as the GPU samplers do it, shared by the CPU reference renderer and the
//! ambient term's light maps.

/// Bilinear filtering at `uv` of a `size` texture whose texel (i, j) `at` returns (any integer
/// i, j: `at` wraps or clamps), texel centres at (i + ½)/W, lerped in x then y as the shaders do.
pub fn bilinear_with<const N: usize>(
    size: (u32, u32),
    uv: [f32; 2],
    at: impl Fn(i64, i64) -> [f32; N],
) -> [f32; N] {
    let x = uv[0] * size.0 as f32 - 0.5;
    let y = uv[1] * size.1 as f32 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let (a, b, c, d) = (
        at(x0, y0),
        at(x0 + 1, y0),
        at(x0, y0 + 1),
        at(x0 + 1, y0 + 1),
    );
    std::array::from_fn(|k| {
        let top = a[k] + (b[k] - a[k]) * fx;
        let bottom = c[k] + (d[k] - c[k]) * fx;
        top + (bottom - top) * fy
    })
}

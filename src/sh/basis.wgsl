// Shared WGSL (prepended to the shaders that need it: render's ambient term, the GPU PRT).
// The order-4 real SH basis of src/sh.rs (`eval_basis16`, Condon–Shortley phase).
fn sh_basis16(d: vec3<f32>) -> array<f32, 16> {
    let x = d.x;
    let y = d.y;
    let z = d.z;
    let x2 = x * x;
    let y2 = y * y;
    let z2 = z * z;
    return array<f32, 16>(
        0.2820948,
        -0.4886025 * y,
        0.4886025 * z,
        -0.4886025 * x,
        1.0925484 * x * y,
        -1.0925484 * y * z,
        0.31539157 * (3.0 * z2 - 1.0),
        -1.0925484 * x * z,
        0.5462742 * (x2 - y2),
        -0.5900436 * y * (3.0 * x2 - y2),
        2.8906114 * x * y * z,
        -0.4570458 * y * (5.0 * z2 - 1.0),
        0.37317633 * z * (5.0 * z2 - 3.0),
        -0.4570458 * x * (5.0 * z2 - 1.0),
        1.4453057 * z * (x2 - y2),
        -0.5900436 * x * (x2 - 3.0 * y2),
    );
}

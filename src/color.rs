//! Colour conversions, written once for every stage and the renderer: the sRGB transfer function
//! (IEC 61966-2-1, piecewise with a linear toe) both ways, and Rec. 709 luminance.

/// sRGB transfer function, decoding (display value in [0, 1] to linear).
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// sRGB transfer function, encoding (linear value in [0, 1] to display value).
pub fn linear_to_srgb(l: f32) -> f32 {
    if l <= 0.003_130_8 {
        l * 12.92
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    }
}

/// Rec. 709 luminance of a linear RGB value (the first three components of `c`).
pub fn luminance(c: impl AsRef<[f32]>) -> f32 {
    let c = c.as_ref();
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_round_trips_and_matches_published_values() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(0.5) - 0.214_041).abs() < 1e-5);
        for i in 0..=255 {
            let e = i as f32 / 255.0;
            assert!((linear_to_srgb(srgb_to_linear(e)) - e).abs() < 1e-5);
        }
        assert!((luminance([1.0, 1.0, 1.0]) - 1.0).abs() < 1e-6);
        assert_eq!(luminance([0.0, 1.0, 0.0, 9.0]), 0.7152);
    }
}

//! The error of a transfer: RMS over vertices, sides, sets, coefficients and channels of its
//! difference from a reference, relative to the reference's RMS (`bake bench prt-error`).
//!
//! A Monte-Carlo reference is itself noisy, and its noise adds to the measured difference:
//! for an estimate A independent of an unbiased reference R, E‖A − R‖² = ‖bias(A)‖² + Var A +
//! Var R. The reference is therefore baked as two independent halves R₁, R₂ (other seeds), so
//! that Var R = E‖R₁ − R₂‖²/4 can be measured and subtracted: the corrected mean square
//! ‖A − R‖² − ‖R₁ − R₂‖²/4, R = (R₁ + R₂)/2, estimates A's true mean square error (bias
//! included) without a converged reference.

use super::transfer::{COEFFS, SETS, SIDES, Transfer};

/// The error of an estimate against a two-half reference, each as a fraction of the
/// reference's RMS (0.01 = 1 %).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TransferError {
    /// The corrected RMS error: √max(0, ‖A − R‖² − ‖R₁ − R₂‖²/4), relative.
    pub rms_error: f64,
    /// The RMS difference from the reference, uncorrected, relative.
    pub rms_difference: f64,
    /// The reference's own RMS noise, √(‖R₁ − R₂‖²/4), relative.
    pub reference_noise: f64,
}

/// Mean over all components of the squared difference of two transfers of the same vertices.
pub fn mean_square_difference(a: &Transfer, b: &Transfer) -> f64 {
    assert_eq!(
        a.coeffs.len(),
        b.coeffs.len(),
        "transfers of different vertices"
    );
    let sum: f64 = a
        .coeffs
        .iter()
        .flatten()
        .zip(b.coeffs.iter().flatten())
        .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
        .sum();
    sum / (a.coeffs.len() * 3).max(1) as f64
}

/// RMS over all components of a transfer.
pub fn rms(t: &Transfer) -> f64 {
    let sum: f64 = t.coeffs.iter().flatten().map(|&x| (x as f64).powi(2)).sum();
    (sum / (t.coeffs.len() * 3).max(1) as f64).sqrt()
}

/// The component-wise mean of two transfers of the same vertices (rays and samples added).
pub fn mean_transfer(a: &Transfer, b: &Transfer) -> Transfer {
    assert_eq!(
        a.coeffs.len(),
        b.coeffs.len(),
        "transfers of different vertices"
    );
    Transfer {
        samples: a.samples + b.samples,
        rays: a.rays + b.rays,
        coeffs: a
            .coeffs
            .iter()
            .zip(&b.coeffs)
            .map(|(x, y)| std::array::from_fn(|c| 0.5 * (x[c] + y[c])))
            .collect(),
        ..a.clone()
    }
}

/// The error of `estimate` against the reference made of the independent halves `r1`, `r2`.
pub fn transfer_error(estimate: &Transfer, r1: &Transfer, r2: &Transfer) -> TransferError {
    let reference = mean_transfer(r1, r2);
    let scale = rms(&reference).max(f64::MIN_POSITIVE);
    let difference = mean_square_difference(estimate, &reference);
    let noise = mean_square_difference(r1, r2) / 4.0;
    TransferError {
        rms_error: (difference - noise).max(0.0).sqrt() / scale,
        rms_difference: difference.sqrt() / scale,
        reference_noise: noise.sqrt() / scale,
    }
}

/// Where a quantity lies over the parts of a transfer: fractions (summing to 1 in each group)
/// by vertex side (front, back), by set (all paths, bounced paths) and by SH band (0–3).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct Shares {
    pub side: [f64; SIDES],
    pub set: [f64; SETS],
    pub band: [f64; 4],
}

/// The band of SH coefficient `i` (l with l² ≤ i < (l + 1)²).
fn band(i: usize) -> usize {
    (i as f64).sqrt() as usize
}

/// Sums `f(component index, channel value pairs)` per side, set and band, then normalizes each
/// group to fractions of its total (negative parts, from the noise correction, count as 0).
fn shares(n: usize, mut f: impl FnMut(usize) -> f64) -> Shares {
    let (mut side, mut set, mut bands) = ([0.0; SIDES], [0.0; SETS], [0.0; 4]);
    for k in 0..n {
        let v = f(k);
        let i = k % COEFFS;
        let s = (k / COEFFS) % SETS;
        let d = (k / (COEFFS * SETS)) % SIDES;
        side[d] += v;
        set[s] += v;
        bands[band(i)] += v;
    }
    fn norm<const N: usize>(a: [f64; N]) -> [f64; N] {
        let a = a.map(|x: f64| x.max(0.0));
        let t: f64 = a.iter().sum();
        if t > 0.0 { a.map(|x| x / t) } else { a }
    }
    Shares {
        side: norm(side),
        set: norm(set),
        band: norm(bands),
    }
}

/// Where the reference's signal energy (its squared coefficients) lies.
pub fn signal_shares(r1: &Transfer, r2: &Transfer) -> Shares {
    let r = mean_transfer(r1, r2);
    shares(r.coeffs.len(), |k| {
        r.coeffs[k].iter().map(|&x| (x as f64).powi(2)).sum()
    })
}

/// Where the estimate's squared error lies, each part corrected for the reference's noise as
/// [`transfer_error`] is (‖A − R‖² − ‖R₁ − R₂‖²/4 over the part's components).
pub fn error_shares(estimate: &Transfer, r1: &Transfer, r2: &Transfer) -> Shares {
    assert_eq!(
        estimate.coeffs.len(),
        r1.coeffs.len(),
        "transfers of different vertices"
    );
    shares(estimate.coeffs.len(), |k| {
        (0..3)
            .map(|c| {
                let (a, x, y) = (
                    estimate.coeffs[k][c] as f64,
                    r1.coeffs[k][c] as f64,
                    r2.coeffs[k][c] as f64,
                );
                (a - 0.5 * (x + y)).powi(2) - (x - y).powi(2) / 4.0
            })
            .sum()
    })
}

#[cfg(test)]
mod tests;

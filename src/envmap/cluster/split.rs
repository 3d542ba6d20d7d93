//! Splitting a cluster: its representative member, and the plane through its mean position
//! orthogonal to its principal axis (eigenvectors by Jacobi rotation).

use super::*;

/// The member nearest to the mean position (ties: lowest index).
pub(super) fn representative(positions: &[[f32; 3]], members: &[u32]) -> u32 {
    let m = mean(positions, members);
    *members
        .iter()
        .min_by(|&&a, &&b| {
            dist2(positions[a as usize], m)
                .total_cmp(&dist2(positions[b as usize], m))
                .then(a.cmp(&b))
        })
        .expect("clusters are never empty")
}

pub(super) fn mean(positions: &[[f32; 3]], members: &[u32]) -> [f32; 3] {
    let mut s = [0.0f64; 3];
    for &i in members {
        for a in 0..3 {
            s[a] += positions[i as usize][a] as f64;
        }
    }
    let n = members.len().max(1) as f64;
    [(s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32]
}

/// Splits by the plane through the mean orthogonal to the principal axis; falls back to halving
/// the members sorted along that axis when all of them lie on one side.
pub(super) fn split_cluster(positions: &[[f32; 3]], members: &[u32]) -> (Vec<u32>, Vec<u32>) {
    let m = mean(positions, members);
    let mut cov = [[0.0f64; 3]; 3];
    for &i in members {
        let p = positions[i as usize];
        let d = [
            (p[0] - m[0]) as f64,
            (p[1] - m[1]) as f64,
            (p[2] - m[2]) as f64,
        ];
        for r in 0..3 {
            for c in 0..3 {
                cov[r][c] += d[r] * d[c];
            }
        }
    }
    let (vals, vecs) = jacobi_eigen(cov);
    let axis_idx = (0..3)
        .max_by(|&a, &b| vals[a].total_cmp(&vals[b]))
        .unwrap_or(0);
    let axis = [vecs[0][axis_idx], vecs[1][axis_idx], vecs[2][axis_idx]];
    let proj = |i: u32| {
        let p = positions[i as usize];
        (p[0] - m[0]) as f64 * axis[0]
            + (p[1] - m[1]) as f64 * axis[1]
            + (p[2] - m[2]) as f64 * axis[2]
    };
    let (a, b): (Vec<u32>, Vec<u32>) = members.iter().partition(|&&i| proj(i) < 0.0);
    if !a.is_empty() && !b.is_empty() {
        return (a, b);
    }
    let mut sorted = members.to_vec();
    sorted.sort_by(|&x, &y| proj(x).total_cmp(&proj(y)).then(x.cmp(&y)));
    let half = sorted.len() / 2;
    let b = sorted.split_off(half);
    (sorted, b)
}

/// Eigen-decomposition of a symmetric 3×3 matrix by cyclic Jacobi rotations
/// ([`crate::envmap::local::jacobi_eigen_with`]: at most 50 sweeps, until the squared
/// off-diagonal norm is below 1e-30). Returns the eigenvalues and the eigenvectors as columns.
pub fn jacobi_eigen(a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    use crate::envmap::local::{JacobiStop, jacobi_eigen_with};
    let flat = a.iter().flatten().copied().collect();
    let (vals, v) = jacobi_eigen_with(flat, 3, 50, JacobiStop::OffSquaredBelow(1e-30));
    let row = |r: usize| [v[r * 3], v[r * 3 + 1], v[r * 3 + 2]];
    ([vals[0], vals[1], vals[2]], [row(0), row(1), row(2)])
}

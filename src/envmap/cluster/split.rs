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

/// Eigen-decomposition of a symmetric 3×3 matrix by cyclic Jacobi rotations (Press et al. 1992).
/// Returns the eigenvalues and the eigenvectors as columns.
pub fn jacobi_eigen(mut a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _sweep in 0..50 {
        let off = a[0][1].powi(2) + a[0][2].powi(2) + a[1][2].powi(2);
        if off < 1e-30 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q].abs() < 1e-300 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // A' = Jᵀ A J with the rotation in the (p, q) plane.
            for row in a.iter_mut() {
                let (akp, akq) = (row[p], row[q]);
                row[p] = c * akp - s * akq;
                row[q] = s * akp + c * akq;
            }
            let (rp, rq) = (a[p], a[q]);
            for k in 0..3 {
                a[p][k] = c * rp[k] - s * rq[k];
                a[q][k] = s * rp[k] + c * rq[k];
            }
            for row in v.iter_mut() {
                let (vkp, vkq) = (row[p], row[q]);
                row[p] = c * vkp - s * vkq;
                row[q] = s * vkp + c * vkq;
            }
        }
    }
    ([a[0][0], a[1][1], a[2][2]], v)
}

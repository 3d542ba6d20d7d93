//! A static 3-d tree over points for k-nearest-neighbour queries (cluster samples, instances).
//!
//! Built once by median splits on the widest axis (implicit layout: the node of a range is its
//! middle element); queries keep the k best in a small sorted array. Ties are broken by point
//! index so results do not depend on build or query order.

/// A k-d tree over 3-d points; stores a permutation of the input indices.
#[derive(Debug, Clone)]
pub struct KdTree {
    points: Vec<[f32; 3]>,
    /// Permuted indices; the subtree of range [lo, hi) has its split point at (lo + hi) / 2.
    order: Vec<u32>,
    /// Split axis per range midpoint, indexed like `order`.
    axis: Vec<u8>,
}

impl KdTree {
    pub fn build(points: &[[f32; 3]]) -> KdTree {
        let mut order: Vec<u32> = (0..points.len() as u32).collect();
        let mut axis = vec![0u8; points.len()];
        build_range(points, &mut order, &mut axis, 0, points.len());
        KdTree {
            points: points.to_vec(),
            order,
            axis,
        }
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    pub fn point(&self, i: u32) -> [f32; 3] {
        self.points[i as usize]
    }

    /// The k nearest points to `q` as (squared distance, index), nearest first; ties by index.
    pub fn nearest(&self, q: [f32; 3], k: usize, out: &mut Vec<(f32, u32)>) {
        out.clear();
        if k == 0 {
            return;
        }
        self.search(q, k, 0, self.points.len(), out);
    }

    fn search(&self, q: [f32; 3], k: usize, lo: usize, hi: usize, best: &mut Vec<(f32, u32)>) {
        if lo >= hi {
            return;
        }
        let mid = (lo + hi) / 2;
        let i = self.order[mid];
        let p = self.points[i as usize];
        let d2 = dist2(p, q);
        insert_best(best, k, (d2, i));
        let ax = self.axis[mid] as usize;
        let diff = q[ax] - p[ax];
        let (near, far) = if diff < 0.0 {
            ((lo, mid), (mid + 1, hi))
        } else {
            ((mid + 1, hi), (lo, mid))
        };
        self.search(q, k, near.0, near.1, best);
        if best.len() < k || diff * diff <= best[best.len() - 1].0 {
            self.search(q, k, far.0, far.1, best);
        }
    }
}

fn build_range(points: &[[f32; 3]], order: &mut [u32], axis: &mut [u8], lo: usize, hi: usize) {
    if hi - lo <= 1 {
        return;
    }
    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    for &i in &order[lo..hi] {
        for a in 0..3 {
            min[a] = min[a].min(points[i as usize][a]);
            max[a] = max[a].max(points[i as usize][a]);
        }
    }
    let ax = (0..3)
        .max_by(|&a, &b| (max[a] - min[a]).total_cmp(&(max[b] - min[b])))
        .unwrap_or(0);
    let mid = (lo + hi) / 2;
    order[lo..hi].select_nth_unstable_by(mid - lo, |&a, &b| {
        points[a as usize][ax]
            .total_cmp(&points[b as usize][ax])
            .then(a.cmp(&b))
    });
    axis[mid] = ax as u8;
    build_range(points, order, axis, lo, mid);
    build_range(points, order, axis, mid + 1, hi);
}

fn insert_best(best: &mut Vec<(f32, u32)>, k: usize, cand: (f32, u32)) {
    let less = |a: &(f32, u32), b: &(f32, u32)| a.0 < b.0 || (a.0 == b.0 && a.1 < b.1);
    if best.len() == k && !less(&cand, &best[k - 1]) {
        return;
    }
    let pos = best
        .iter()
        .position(|b| less(&cand, b))
        .unwrap_or(best.len());
    best.insert(pos, cand);
    best.truncate(k);
}

pub fn dist2(a: [f32; 3], b: [f32; 3]) -> f32 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixtures::Rng;

    #[test]
    fn nearest_equals_brute_force() {
        let mut rng = Rng::new(1);
        let pts: Vec<[f32; 3]> = (0..700)
            .map(|_| [rng.f32() * 10.0, rng.f32() * 10.0, rng.f32()])
            .collect();
        let tree = KdTree::build(&pts);
        let mut got = Vec::new();
        for _ in 0..200 {
            let q = [rng.f32() * 12.0 - 1.0, rng.f32() * 12.0 - 1.0, rng.f32()];
            for k in [1, 5, 16] {
                tree.nearest(q, k, &mut got);
                let mut all: Vec<(f32, u32)> = pts
                    .iter()
                    .enumerate()
                    .map(|(i, p)| (dist2(*p, q), i as u32))
                    .collect();
                all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                all.truncate(k);
                assert_eq!(got, all);
            }
        }
    }
}

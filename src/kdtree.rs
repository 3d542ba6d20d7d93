//! A static 3-d tree over points for k-nearest-neighbour queries (cluster samples, instances,
//! leaf-card centres).
//!
//! Built once by median splits on the widest axis (implicit layout: the node of a range is its
//! middle element; ranges of up to 8 points are leaves); queries keep the k best in a small
//! sorted array. Ties are broken by point
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
        self.nearest_within(q, k, f32::INFINITY, out);
    }

    /// [`Self::nearest`] among the points within squared distance `bound2` of `q`: the same
    /// answer whenever the k-th nearest point lies within the bound (then `out` holds k points),
    /// found faster the tighter the bound.
    pub fn nearest_within(&self, q: [f32; 3], k: usize, bound2: f32, out: &mut Vec<(f32, u32)>) {
        out.clear();
        if k == 0 {
            return;
        }
        self.search(q, k, bound2, 0, self.points.len(), out);
    }

    /// The k nearest points to `q`, starting from a previous query's answer: the k-th nearest
    /// neighbour of `q` is at most `sqrt(prev_kth2) + |q − prev|` away (triangle inequality), a
    /// bound that makes queries in spatial order cheap. Exactly [`Self::nearest`]'s answer.
    pub fn nearest_after(
        &self,
        q: [f32; 3],
        k: usize,
        prev: Option<([f32; 3], f32)>,
        out: &mut Vec<(f32, u32)>,
    ) {
        if let Some((p, kth2)) = prev.filter(|&(_, d)| d.is_finite()) {
            let reach = kth2.sqrt() + dist2(p, q).sqrt();
            // Widened against rounding in the distances.
            let bound2 = reach * reach * (1.0 + 1e-4) + f32::MIN_POSITIVE;
            self.nearest_within(q, k, bound2, out);
            if out.len() == k.min(self.points.len()) {
                return;
            }
        }
        self.nearest(q, k, out);
    }

    fn search(
        &self,
        q: [f32; 3],
        k: usize,
        bound2: f32,
        lo: usize,
        hi: usize,
        best: &mut Vec<(f32, u32)>,
    ) {
        if hi - lo <= LEAF {
            for &i in &self.order[lo..hi] {
                let d2 = dist2(self.points[i as usize], q);
                if d2 <= bound2 {
                    insert_best(best, k, (d2, i));
                }
            }
            return;
        }
        let mid = (lo + hi) / 2;
        let i = self.order[mid];
        let p = self.points[i as usize];
        let d2 = dist2(p, q);
        if d2 <= bound2 {
            insert_best(best, k, (d2, i));
        }
        let ax = self.axis[mid] as usize;
        let diff = q[ax] - p[ax];
        let (near, far) = if diff < 0.0 {
            ((lo, mid), (mid + 1, hi))
        } else {
            ((mid + 1, hi), (lo, mid))
        };
        self.search(q, k, bound2, near.0, near.1, best);
        let limit = if best.len() < k {
            bound2
        } else {
            best[k - 1].0
        };
        if diff * diff <= limit {
            self.search(q, k, bound2, far.0, far.1, best);
        }
    }
}

/// Ranges of at most this many points are leaves, scanned linearly (cheaper than splitting
/// them further: fewer branches and recursive calls per query).
const LEAF: usize = 8;

fn build_range(points: &[[f32; 3]], order: &mut [u32], axis: &mut [u8], lo: usize, hi: usize) {
    if hi - lo <= LEAF {
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

/// Indices of `points` along a Morton (Z-order) curve over their bounding box (ties by index):
/// queries made in this order are spatially coherent, so consecutive ones tend to find the same
/// neighbours.
pub(crate) fn morton_order(points: &[[f32; 3]]) -> Vec<u32> {
    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    for p in points {
        for a in 0..3 {
            min[a] = min[a].min(p[a]);
            max[a] = max[a].max(p[a]);
        }
    }
    let quantize = |v: f32, a: usize| {
        let extent = max[a] - min[a];
        if extent > 0.0 && v.is_finite() {
            (((v - min[a]) / extent) * 1_048_575.0) as u64
        } else {
            0
        }
    };
    // Spreads the low 21 bits of v to every third bit.
    let spread = |mut v: u64| {
        v &= 0x1f_ffff;
        v = (v | v << 32) & 0x1f00000000ffff;
        v = (v | v << 16) & 0x1f0000ff0000ff;
        v = (v | v << 8) & 0x100f00f00f00f00f;
        v = (v | v << 4) & 0x10c30c30c30c30c3;
        (v | v << 2) & 0x1249249249249249
    };
    let mut keyed: Vec<(u64, u32)> = points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let c = [0, 1, 2].map(|a| spread(quantize(p[a], a)));
            (c[0] | c[1] << 1 | c[2] << 2, i as u32)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

pub(crate) fn dist2(a: [f32; 3], b: [f32; 3]) -> f32 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn morton_order_is_a_permutation_following_the_z_curve() {
        // A 4×4 grid: the Z curve visits the 2×2 quadrants one after the other.
        let pts: Vec<[f32; 3]> = (0..16)
            .map(|i| [(i % 4) as f32, (i / 4) as f32, 0.0])
            .collect();
        let order = morton_order(&pts);
        let quadrant =
            |i: u32| (pts[i as usize][0] >= 2.0) as u32 + 2 * (pts[i as usize][1] >= 2.0) as u32;
        let q: Vec<u32> = order.iter().map(|&i| quadrant(i)).collect();
        assert_eq!(q, [0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3]);
        assert_eq!(&order[..4], &[0, 1, 4, 5]);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..16).collect::<Vec<u32>>());
    }

    #[test]
    fn nearest_after_a_previous_query_equals_nearest() {
        let mut rng = Rng::new(5);
        let pts: Vec<[f32; 3]> = (0..500)
            .map(|_| [rng.f32() * 10.0, rng.f32() * 10.0, rng.f32()])
            .collect();
        let tree = KdTree::build(&pts);
        let qs: Vec<[f32; 3]> = (0..300)
            .map(|_| [rng.f32() * 12.0 - 1.0, rng.f32() * 12.0 - 1.0, rng.f32()])
            .collect();
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for k in [1, 4, 16, 600] {
            let mut prev = None;
            for &q in &qs {
                tree.nearest_after(q, k, prev, &mut a);
                tree.nearest(q, k, &mut b);
                assert_eq!(a, b);
                prev = Some((q, a.last().map_or(f32::INFINITY, |x| x.0)));
            }
        }
    }

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

//! The stored (pack and GPU) form of the octree's leaves: 4³ bricks as 2³ sub-masks, which takes
//! thin surfaces below 0.5 B/voxel of topology (a plane through a brick fills 4 of its 8 octants
//! with 16 voxels: 5 bytes instead of a 64-bit mask's 8; see docs/PERFORMANCE.md, issue 6).
//!
//! `leaves` (bytes, bricks in Morton order): per brick one byte O of non-empty octants (bit o:
//! octant o, the 8 slots o·8 … o·8 + 7 of the brick, i.e. byte o of its 64-bit mask), then for
//! each set bit of O in ascending order that octant's 8-bit mask. Neither byte is ever zero.
//! The inner nodes are stored as in memory ([`super::svo::Node`]) except on the last inner
//! level, where `first_child` is the byte offset of the node's first brick in `leaves`; brick k
//! of such a node is found by skipping k bricks (each 1 + popcount(O) bytes).
//!
//! Example: a brick whose voxels (0,0,0) and (3,0,0) are set has mask bits 0 and 9 (slot 9:
//! x = 3 → x bits 0 and 1 → slot bits 0 and 3), octants 0 and 1: bytes 0b11, 0b1, 0b10.
//!
//! In memory the octree keeps plain u64 masks (`Svo::bricks`); [`pack_leaves`] and
//! [`unpack_leaves`] convert, and the CPU and GPU traversals see the same masks.

use super::svo::{Node, Svo};

/// Bytes of one brick in the packed form.
pub fn brick_bytes(mask: u64) -> usize {
    1 + (0..8).filter(|o| mask >> (8 * o) & 0xff != 0).count()
}

/// The stored node array and the packed leaves of an octree.
pub fn pack_leaves(svo: &Svo) -> (Vec<Node>, Vec<u8>) {
    let mut offsets = Vec::with_capacity(svo.bricks.len());
    let mut leaves = Vec::new();
    for &m in &svo.bricks {
        offsets.push(leaves.len() as u32);
        let octants: Vec<u8> = (0..8).map(|o| (m >> (8 * o)) as u8).collect();
        let header = (0..8).fold(0u8, |h, o| h | ((octants[o] != 0) as u8) << o);
        leaves.push(header);
        leaves.extend(octants.iter().filter(|&&b| b != 0));
    }
    let mut nodes = svo.nodes.clone();
    if let Some(&last) = svo.level_start.get(svo.inner_levels().saturating_sub(1)) {
        for n in &mut nodes[last as usize..] {
            // Out-of-range children keep an out-of-range offset (validation reports them).
            n.first_child = offsets
                .get(n.first_child as usize)
                .copied()
                .unwrap_or(u32::MAX);
        }
    }
    (nodes, leaves)
}

/// Decodes packed leaves into u64 masks and maps the last inner level's byte offsets back to
/// brick indices. Errors name the byte or node that is wrong.
pub fn unpack_leaves(
    nodes: &[Node],
    level_start: &[u32],
    leaves: &[u8],
) -> Result<(Vec<Node>, Vec<u64>), String> {
    let mut offsets = Vec::new();
    let mut bricks = Vec::new();
    let mut at = 0usize;
    while at < leaves.len() {
        let header = leaves[at];
        let count = header.count_ones() as usize;
        if header == 0 || at + 1 + count > leaves.len() {
            return Err(format!("leaves byte {at}: empty or truncated brick"));
        }
        let mut mask = 0u64;
        let mut k = at + 1;
        for o in (0..8).filter(|o| header >> o & 1 == 1) {
            if leaves[k] == 0 {
                return Err(format!("leaves byte {k}: an empty octant mask"));
            }
            mask |= (leaves[k] as u64) << (8 * o);
            k += 1;
        }
        offsets.push(at as u32);
        bricks.push(mask);
        at = k;
    }
    let mut out = nodes.to_vec();
    let inner = level_start.len().saturating_sub(1);
    let last = match inner.checked_sub(1).and_then(|l| level_start.get(l)) {
        Some(&l) if (l as usize) <= out.len() => l as usize,
        _ => return Err("bad level table".into()),
    };
    for (i, n) in out.iter_mut().enumerate().skip(last) {
        n.first_child = offsets
            .binary_search(&n.first_child)
            .map_err(|_| format!("node {i}: first child is not the start of a brick"))?
            as u32;
    }
    Ok((out, bricks))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::voxel::svo::voxels_to_svo;
    use crate::voxel::tests::{Rng, random_voxels};

    #[test]
    fn the_worked_example_packs_to_three_bytes() {
        let m = 1u64 | 1 << 9;
        assert_eq!(brick_bytes(m), 3);
        let mut rng = Rng::new(3);
        let mut svo = voxels_to_svo(&random_voxels(&mut rng, [8, 8, 8]));
        svo.bricks[0] = m;
        let (_, leaves) = pack_leaves(&svo);
        assert_eq!(&leaves[..3], &[0b11, 0b1, 0b10]);
    }

    #[test]
    fn leaves_round_trip_and_offsets_point_at_bricks() {
        let mut rng = Rng::new(8);
        for dims in [[4, 4, 4], [37, 20, 45], [130, 17, 9]] {
            let svo = voxels_to_svo(&random_voxels(&mut rng, dims));
            let (nodes, leaves) = pack_leaves(&svo);
            let size: usize = svo.bricks.iter().map(|&m| brick_bytes(m)).sum();
            assert_eq!(leaves.len(), size);
            let (back, bricks) = unpack_leaves(&nodes, &svo.level_start, &leaves).unwrap();
            assert_eq!(back, svo.nodes, "dims {dims:?}");
            assert_eq!(bricks, svo.bricks, "dims {dims:?}");
        }
    }

    #[test]
    fn corrupt_leaves_are_errors_naming_the_byte() {
        let svo = voxels_to_svo(&random_voxels(&mut Rng::new(4), [16, 16, 16]));
        let (nodes, mut leaves) = pack_leaves(&svo);
        let err = unpack_leaves(&nodes, &svo.level_start, &leaves[..leaves.len() - 1]);
        assert!(err.unwrap_err().contains("truncated"));
        leaves[1] = 0;
        let err = unpack_leaves(&nodes, &svo.level_start, &leaves).unwrap_err();
        assert!(err.contains("byte 1"), "{err}");
        let mut bad = nodes.clone();
        let last = bad.len() - 1;
        bad[last].first_child += 1;
        let (_, leaves) = pack_leaves(&svo);
        assert!(unpack_leaves(&bad, &svo.level_start, &leaves).is_err());
    }
}

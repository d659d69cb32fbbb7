//! A static k-d tree of small leaves over a point set, for the searches awl runs by the million:
//! all k-NN rows at once (`allknn`) and ICP's bounded nearest-point queries (the growing model in
//! `awl fuse`'s sequential registration, any target not in a camera frame).
//!
//! Median splits on the widest axis, 24-48 points a leaf, the coordinates copied in tree order, one
//! array per axis (a leaf scan is a plain loop), the box of every node's points, and each inner
//! node's split (axis, children's extents along it) for the descent to a query's leaf. The tree is
//! implicit: node `i`'s children are `2i + 1` and `2i + 2`, its range of tree positions is halved
//! at each level, so no node stores its range. Distances are `dx² + dy² + dz²` in f32, as
//! [`super::KdIndex`] computes them, and a box's distance is, in floating point too, at most the
//! distance of any point in it (rounding is monotonic), so pruning by boxes is exact.

use nalgebra::Point3;
use rayon::prelude::*;

use super::{Neighbor, dist_sq};

use crate::error::Result;

/// Largest leaf: a node with more points is split at its median. 48 rather than 32: normals and
/// SOR 3-5 % faster on sim300k, ICP the same (BENCHMARKS.md 52).
pub(super) const LEAF: usize = 48;
/// Below this many points a subtree is ordered on one thread.
const PARALLEL_SPLIT: usize = 16_384;

/// The points in k-d tree order and the boxes of the implicit tree over them: node `i` covers
/// tree positions `start..end`, its children are `2i + 1` (`start..mid`) and `2i + 2`
/// (`mid..end`) with `mid = start + (end - start) / 2`, and it is a leaf when it holds at most
/// [`LEAF`] points.
pub(crate) struct LeafTree {
    pub(super) xs: Vec<f32>,
    pub(super) ys: Vec<f32>,
    pub(super) zs: Vec<f32>,
    /// Index (in the input) of the point at each tree position.
    pub(super) ids: Vec<u32>,
    pub(super) boxes: Vec<Aabb>,
    /// Of each inner node (leaves hold the default), what the descent to a query's leaf reads: the
    /// axis its points were split on (the widest of its box), the left child's box's top and the
    /// right child's box's bottom along it (one small read a level instead of three boxes).
    splits: Vec<Split>,
}

/// See [`LeafTree::splits`].
#[derive(Clone, Copy, Default)]
struct Split {
    axis: u32,
    l_hi: f32,
    r_lo: f32,
}

/// The box of a node's points.
#[derive(Clone, Copy)]
pub(super) struct Aabb {
    pub(super) lo: [f32; 3],
    pub(super) hi: [f32; 3],
}

impl Aabb {
    const EMPTY: Self = Self { lo: [f32::INFINITY; 3], hi: [f32::NEG_INFINITY; 3] };

    fn grow(&mut self, p: [f32; 3]) {
        self.lo = [0, 1, 2].map(|a| self.lo[a].min(p[a]));
        self.hi = [0, 1, 2].map(|a| self.hi[a].max(p[a]));
    }

    /// The axis along which the box is widest (the first of equals).
    pub(super) fn widest(&self) -> usize {
        (0..3).fold(0, |best, a| if self.hi[a] - self.lo[a] > self.hi[best] - self.lo[best] { a } else { best })
    }

    fn union(&self, o: &Self) -> Self {
        Self { lo: [0, 1, 2].map(|a| self.lo[a].min(o.lo[a])), hi: [0, 1, 2].map(|a| self.hi[a].max(o.hi[a])) }
    }

    /// Squared distance to the box `o` (0 when they overlap): at most the distance from any point
    /// in one to any point in the other, in floating point too.
    pub(super) fn gap_box(&self, o: &Self) -> f32 {
        let g = [0, 1, 2].map(|a| (o.lo[a] - self.hi[a]).max(self.lo[a] - o.hi[a]).max(0.0));
        g[0] * g[0] + g[1] * g[1] + g[2] * g[2]
    }

    /// Squared distance from `q` (0 inside).
    pub(super) fn gap(&self, q: [f32; 3]) -> f32 {
        self.gap_box(&Self { lo: q, hi: q })
    }
}

/// A node: heap index and its range of tree positions.
#[derive(Clone, Copy)]
pub(super) struct Node {
    pub(super) id: usize,
    pub(super) start: usize,
    pub(super) end: usize,
}

impl Node {
    pub(super) fn is_leaf(&self) -> bool {
        self.end - self.start <= LEAF
    }

    pub(super) fn children(&self) -> (Node, Node) {
        let mid = self.start + (self.end - self.start) / 2;
        (
            Node { id: 2 * self.id + 1, start: self.start, end: mid },
            Node { id: 2 * self.id + 2, start: mid, end: self.end },
        )
    }
}

/// A candidate point as one integer that orders as (squared distance, index): a non-negative
/// f32's bits order as the float does.
pub(super) fn candidate(dist_sq: f32, index: u32) -> u64 {
    (u64::from(dist_sq.to_bits()) << 32) | u64::from(index)
}

/// The neighbour a [`candidate`] stands for.
pub(super) fn neighbor(c: u64) -> Neighbor {
    Neighbor { index: c as u32, dist_sq: f32::from_bits((c >> 32) as u32) }
}

/// A point and its index, moved as one while the tree is ordered.
#[derive(Clone, Copy)]
struct Entry {
    p: [f32; 3],
    id: u32,
}

/// Orders `entries` as the tree's positions: each node's range split at its median along the
/// widest axis of its points' box (ties by index).
fn partition(entries: &mut [Entry]) {
    if entries.len() <= LEAF {
        return;
    }
    let mut bounds = Aabb::EMPTY;
    for e in entries.iter() {
        bounds.grow(e.p);
    }
    let axis = bounds.widest();
    let mid = entries.len() / 2;
    entries.select_nth_unstable_by(mid, |a, b| a.p[axis].total_cmp(&b.p[axis]).then(a.id.cmp(&b.id)));
    let (left, right) = entries.split_at_mut(mid);
    if left.len() + right.len() > PARALLEL_SPLIT {
        rayon::join(|| partition(left), || partition(right));
    } else {
        partition(left);
        partition(right);
    }
}

impl LeafTree {
    /// The tree over `points` (built in parallel; the same tree with any number of threads).
    ///
    /// # Errors
    /// [`Error::Invalid`] for a non-finite point or more than `u32::MAX` points.
    pub(crate) fn new(points: &[Point3<f32>]) -> Result<Self> {
        super::check_points(points)?;
        let mut entries: Vec<Entry> =
            points.par_iter().enumerate().map(|(i, p)| Entry { p: [p.x, p.y, p.z], id: i as u32 }).collect();
        partition(&mut entries);
        let axis = |a: usize| entries.par_iter().map(|e| e.p[a]).collect::<Vec<f32>>();
        let (xs, ys, zs) = (axis(0), axis(1), axis(2));
        let ids = entries.par_iter().map(|e| e.id).collect();
        let mut depth = 0;
        let mut largest = points.len();
        while largest > LEAF {
            largest = largest.div_ceil(2);
            depth += 1;
        }
        let nodes = (1usize << (depth + 1)) - 1;
        let mut tree = Self { xs, ys, zs, ids, boxes: vec![Aabb::EMPTY; nodes], splits: vec![Split::default(); nodes] };
        if !points.is_empty() {
            tree.fill_boxes(Node { id: 0, start: 0, end: points.len() });
        }
        Ok(tree)
    }

    fn fill_boxes(&mut self, node: Node) {
        self.boxes[node.id] = if node.is_leaf() {
            let mut b = Aabb::EMPTY;
            for j in node.start..node.end {
                b.grow([self.xs[j], self.ys[j], self.zs[j]]);
            }
            b
        } else {
            let (l, r) = node.children();
            self.fill_boxes(l);
            self.fill_boxes(r);
            let b = self.boxes[l.id].union(&self.boxes[r.id]);
            let axis = b.widest();
            self.splits[node.id] =
                Split { axis: axis as u32, l_hi: self.boxes[l.id].hi[axis], r_lo: self.boxes[r.id].lo[axis] };
            b
        };
    }

    /// The leaves, in tree order.
    pub(super) fn leaves(&self) -> Vec<Node> {
        let mut out = Vec::new();
        let mut stack = vec![Node { id: 0, start: 0, end: self.ids.len() }];
        while let Some(node) = stack.pop() {
            if node.is_leaf() {
                out.push(node);
            } else {
                let (l, r) = node.children();
                stack.push(r);
                stack.push(l);
            }
        }
        out
    }

    /// Squared distances from `q` to the points of `node`, into `dist`.
    pub(super) fn distances(&self, q: [f32; 3], node: Node, dist: &mut Vec<f32>) {
        let r = node.start..node.end;
        dist.clear();
        dist.extend(
            self.xs[r.clone()]
                .iter()
                .zip(&self.ys[r.clone()])
                .zip(&self.zs[r])
                .map(|((&x, &y), &z)| dist_sq([x, y, z], q)),
        );
    }

    /// The nearest point within `radius_m` (inclusive) of `q`, the lowest index among equally
    /// near ones (`None` when there is none), and the squared distance of the next nearest point
    /// within `radius_m` (`radius_m²` when there is none): every other point is at least that far.
    /// Depth first: down the split planes to the query's leaf, each farther child kept with its
    /// distance across the plane (a lower bound of its box's), and a kept child searched only while
    /// that bound and then its box are within the runner-up's distance so far. One comparison a
    /// level on the way down: ICP's queries mostly end in one or two leaves.
    pub(crate) fn nearest_two_within(&self, q: &Point3<f32>, radius_m: f32) -> (Option<Neighbor>, f32) {
        let q = [q.x, q.y, q.z];
        let reach = radius_m * radius_m;
        if self.ids.is_empty() || reach.is_nan() {
            return (None, reach);
        }
        // the best two so far as candidates: the smallest is the nearest, then the lowest index
        let mut best = candidate(reach, u32::MAX);
        let mut second = best;
        let bound = |second: u64| neighbor(second).dist_sq;
        // the pending farther children: at most one per level, and a tree over at most 2^32
        // points has fewer than 32 levels of splits (leaves hold 16 or more); (gap, id, start, end)
        let mut stack = [(0.0f32, 0u32, 0u32, 0u32); 32];
        let node_of = |(_, id, start, end): (f32, u32, u32, u32)| Node {
            id: id as usize,
            start: start as usize,
            end: end as usize,
        };
        let entry = |gap: f32, n: Node| (gap, n.id as u32, n.start as u32, n.end as u32);
        stack[0] = entry(0.0, Node { id: 0, start: 0, end: self.ids.len() });
        let mut top = 1;
        while top > 0 {
            top -= 1;
            if stack[top].0 > bound(second) {
                continue;
            }
            let mut node = node_of(stack[top]);
            // its box, then down to a leaf by the split planes (the axis the partition split on),
            // the farther child of each step left on the stack with its distance across the split
            if self.boxes[node.id].gap(q) > bound(second) {
                continue;
            }
            while !node.is_leaf() {
                let (near, far, across) = self.near_far(node, q);
                if across * across <= bound(second) {
                    stack[top] = entry(across * across, far);
                    top += 1;
                }
                node = near;
            }
            // the leaf's points as candidates, the smallest two kept (no branch)
            let r = node.start..node.end;
            let candidates = self.xs[r.clone()]
                .iter()
                .zip(&self.ys[r.clone()])
                .zip(&self.zs[r.clone()])
                .zip(&self.ids[r])
                .map(|(((&x, &y), &z), &i)| candidate(dist_sq([x, y, z], q), i));
            for c in candidates {
                second = second.min(c.max(best));
                best = best.min(c);
            }
        }
        let best = neighbor(best);
        ((best.index != u32::MAX).then_some(best), bound(second))
    }

    /// An inner node's children for `q`: the one on `q`'s side of the split first, then the other
    /// and `q`'s distance across the split to it (0 when `q` lies in the gap between them).
    #[inline]
    fn near_far(&self, node: Node, q: [f32; 3]) -> (Node, Node, f32) {
        let (l, r) = node.children();
        let Split { axis, l_hi, r_lo } = self.splits[node.id];
        let axis = axis as usize;
        if q[axis] - l_hi <= r_lo - q[axis] {
            (l, r, (r_lo - q[axis]).max(0.0))
        } else {
            (r, l, (q[axis] - l_hi).max(0.0))
        }
    }

    /// Whether some point lies within squared distance `reach_sq` (inclusive) of `q`: whether the
    /// nearest point is that near, answered at the first point found that near (a crop's test).
    /// The descent of [`LeafTree::nearest_two_within`], its bound fixed at `reach_sq`.
    pub(crate) fn any_within(&self, q: &Point3<f32>, reach_sq: f32) -> bool {
        let q = [q.x, q.y, q.z];
        if self.ids.is_empty() || reach_sq.is_nan() {
            return false;
        }
        // the pending farther children, as in `nearest_two_within`: (gap, id, start, end)
        let mut stack = [(0.0f32, 0u32, 0u32, 0u32); 32];
        stack[0] = (0.0, 0, 0, self.ids.len() as u32);
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (gap, id, start, end) = stack[top];
            let mut node = Node { id: id as usize, start: start as usize, end: end as usize };
            if gap > reach_sq || self.boxes[node.id].gap(q) > reach_sq {
                continue;
            }
            while !node.is_leaf() {
                let (near, far, across) = self.near_far(node, q);
                if across * across <= reach_sq {
                    stack[top] = (across * across, far.id as u32, far.start as u32, far.end as u32);
                    top += 1;
                }
                node = near;
            }
            let r = node.start..node.end;
            if self.xs[r.clone()]
                .iter()
                .zip(&self.ys[r.clone()])
                .zip(&self.zs[r])
                .any(|((&x, &y), &z)| dist_sq([x, y, z], q) <= reach_sq)
            {
                return true;
            }
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spatial::brute;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn nearest_two_within_and_any_within_equal_brute_force_ties_by_index() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let random: Vec<Point3<f32>> = (0..5000)
            .map(|_| Point3::new(rng.random::<f32>(), rng.random::<f32>(), 0.1 * rng.random::<f32>()))
            .collect();
        // a lattice (many equal distances) with duplicated points
        let mut lattice: Vec<Point3<f32>> = (0..3000)
            .map(|i| Point3::new((i % 30) as f32 * 0.01, (i / 30 % 10) as f32 * 0.01, (i / 300) as f32 * 0.01))
            .collect();
        lattice.extend_from_within(..500);
        for points in [random, lattice, vec![Point3::new(0.5, 0.5, 0.05)]] {
            let tree = LeafTree::new(&points).expect("tree");
            let kd = crate::spatial::KdIndex::new(&points).expect("kd");
            for _ in 0..500 {
                let q = Point3::new(
                    rng.random::<f32>() * 1.2 - 0.1,
                    rng.random::<f32>() * 1.2 - 0.1,
                    rng.random::<f32>() * 0.2,
                );
                // on lattice points and half-way between them: exact ties
                let q = if rng.random::<f32>() < 0.3 {
                    Point3::from((q.coords * 200.0).map(f32::round) / 200.0)
                } else {
                    q
                };
                // the runner-up: the second smallest squared distance within the radius
                let mut all: Vec<f32> = points.iter().map(|p| (p - q).norm_squared()).collect();
                all.sort_by(f32::total_cmp);
                for radius in [0.0, 0.004, 0.01, 0.05, 3.0] {
                    let want = brute::nearest(&points, &q).filter(|n| n.dist_sq <= radius * radius);
                    let (nearest, next_sq) = tree.nearest_two_within(&q, radius);
                    assert_eq!(nearest, want, "{q:?} within {radius}");
                    // the crop's test: as the bounded search on the k-d index (`pierce::locate`'s before)
                    let reach = radius * radius;
                    let any = points.iter().any(|p| dist_sq([p.x, p.y, p.z], [q.x, q.y, q.z]) <= reach);
                    assert_eq!(tree.any_within(&q, reach), any, "{q:?} within {radius}");
                    let kd_says = kd.nearest_within(&q, radius * 1.0001).is_some_and(|n| n.dist_sq <= reach);
                    assert_eq!(kd_says, any, "{q:?} within {radius}");
                    let want_next = all.get(1).copied().filter(|&d| d <= radius * radius).unwrap_or(radius * radius);
                    assert!(
                        (next_sq - want_next).abs() <= 1e-6 * want_next.max(1e-9),
                        "{q:?}: {next_sq} vs {want_next}"
                    );
                }
            }
        }
        let empty = LeafTree::new(&[]).expect("empty");
        assert_eq!(empty.nearest_two_within(&Point3::origin(), 1.0), (None, 1.0));
        assert!(!empty.any_within(&Point3::origin(), 1.0));
        assert!(LeafTree::new(&[Point3::new(0.0, f32::INFINITY, 0.0)]).is_err());
    }
}

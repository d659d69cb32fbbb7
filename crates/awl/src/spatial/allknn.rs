//! The `k` nearest neighbours of every point of a set at once (outlier removal, normals).
//!
//! The points are ordered into a [`LeafTree`] (median splits on the widest axis, 24-48 points a
//! leaf, one coordinate array per axis in tree order) and answered leaf by leaf. A leaf's first
//! query is a tree search within a reach that surely holds its `k` nearest points: the `k`-th
//! distance among its seed (the smallest subtree about it with `2k` points). Then the points within
//! 1.3x that query's `k`-th distance of the leaf's box are gathered once ([`SPREAD`]: about 240
//! points at k = 20 on sim300k; a leaf that would gather more than [`GATHER_CAP`] times `k`, spread
//! out beside denser points, is left to the tree search), and every other query of the leaf scans
//! them: first within a guess of 1.15x the previous query's `k`-th distance, then within the whole
//! gathered reach. A ball about the query that holds `k` points holds its `k` nearest, and the
//! gathered points hold every point of any ball within the gathered reach, so the rows are exact;
//! 91 % of sim300k's queries are answered so. The others (the reach did not hold `k` points) fall
//! back to the tree search, within the least, over the leaf's queries already answered, of their
//! `k`-th distance plus the step to them (first a guess of 1.15x the `k`-th distance of the query
//! giving it). A tree search starts below every ancestor whose other side is out of reach.
//! Candidates are kept as one integer (distance bits, index) that sorts without a comparator.
//!
//! Each row holds the `k` points smallest by (squared distance, index), nearest first: the
//! distances [`super::KdIndex::knn`] gives (computed the same way, `dx² + dy² + dz²` in f32), and
//! among points tied at the `k`-th distance the lowest indices. Reaches are widened by 1e-4
//! relative + 1 um against rounding, and a box's distance is, in floating point too, at most the
//! distance of any point in it (rounding is monotonic): the rows are exact. Parallel over leaves;
//! the rows do not depend on the number of threads.

use nalgebra::Point3;
use rayon::prelude::*;

use super::leaftree::{Aabb, LeafTree, Node, candidate, neighbor};
use super::{Neighbor, dist_sq, widen};

use crate::error::Result;

/// Scratch space of one worker: a query's candidates (see [`candidate`]), the traversal stack,
/// one leaf's distances.
#[derive(Default)]
struct Scratch {
    found: Vec<u64>,
    stack: Vec<Node>,
    dist: Vec<f32>,
    /// The current leaf's ancestors, root first, each with its child off the path to the leaf.
    path: Vec<(Node, usize)>,
    /// The leaf's queries answered so far and their `k`-th distances (m).
    done: Vec<([f32; 3], f32)>,
    /// The points near the current leaf (see [`LeafTree::near_box`]), one array per axis.
    near: [Vec<f32>; 3],
    near_ids: Vec<u32>,
    /// Room for a candidate of every `near` point (see [`near_within`]).
    near_found: Vec<u64>,
}

impl LeafTree {
    /// Every point of the subtree `from` within squared distance `reach` of `q`, into `found`.
    fn within(&self, from: Node, q: [f32; 3], reach: f32, scratch: &mut Scratch) {
        let Scratch { found, stack, dist, .. } = scratch;
        found.clear();
        stack.clear();
        stack.push(from);
        // down the left children in registers, the right ones left on the stack: a node pushed
        // and at once popped would wait on its own store (40 % slower rows)
        while let Some(mut node) = stack.pop() {
            while self.boxes[node.id].gap(q) <= reach {
                if node.is_leaf() {
                    self.distances(q, node, dist);
                    let start = found.len();
                    found.resize(start + dist.len(), 0);
                    let count = compact_within(&mut found[start..], dist, &self.ids[node.start..node.end], reach);
                    found.truncate(start + count);
                    break;
                }
                let (l, r) = node.children();
                stack.push(r);
                node = l;
            }
        }
    }

    /// Every point whose squared distance to the box `b` is at most `reach`, into the scratch's
    /// `near` arrays: they hold every point within `sqrt(reach)` of any point in `b`. Stops and
    /// returns `false` once more than `cap` points are found.
    fn near_box(&self, from: Node, b: &Aabb, reach: f32, cap: usize, scratch: &mut Scratch) -> bool {
        let Scratch { stack, near, near_ids, .. } = scratch;
        for axis in near.iter_mut() {
            axis.clear();
        }
        near_ids.clear();
        stack.clear();
        stack.push(from);
        while let Some(node) = stack.pop() {
            if self.boxes[node.id].gap_box(b) > reach {
                continue;
            }
            if node.is_leaf() {
                // every point written, the count advanced for those within reach (no branch)
                let mut count = near_ids.len();
                let len = count + node.end - node.start;
                for axis in near.iter_mut() {
                    axis.resize(len, 0.0);
                }
                near_ids.resize(len, 0);
                for j in node.start..node.end {
                    let p = [self.xs[j], self.ys[j], self.zs[j]];
                    for (axis, v) in near.iter_mut().zip(p) {
                        axis[count] = v;
                    }
                    near_ids[count] = self.ids[j];
                    count += usize::from(b.gap(p) <= reach);
                }
                for axis in near.iter_mut() {
                    axis.truncate(count);
                }
                near_ids.truncate(count);
                if count > cap {
                    return false;
                }
            } else {
                let (l, r) = node.children();
                stack.push(r);
                stack.push(l);
            }
        }
        true
    }
}

/// The candidates (see [`candidate`]) of the points with squared distances `dist` and indices
/// `ids` that are within `reach`, written to the start of `out` (as long as `dist` at least): every
/// point written, the count advanced for those within reach (no branch). Returns the count.
fn compact_within(out: &mut [u64], dist: &[f32], ids: &[u32], reach: f32) -> usize {
    let mut count = 0;
    for (&d, &i) in dist.iter().zip(ids) {
        out[count] = candidate(d, i);
        count += usize::from(d <= reach);
    }
    count
}

/// Every point of the scratch's `near` arrays within squared distance `reach` of `q`, into
/// `found`: the distances first (in vector registers), then the candidates, compacted in
/// `near_found` (which only grows: not cleared per query).
fn near_within(q: [f32; 3], reach: f32, scratch: &mut Scratch) {
    let Scratch { found, near: [xs, ys, zs], near_ids, near_found, dist, .. } = scratch;
    dist.clear();
    dist.extend(xs.iter().zip(ys.iter()).zip(zs.iter()).map(|((&x, &y), &z)| dist_sq([x, y, z], q)));
    if near_found.len() < dist.len() {
        near_found.resize(dist.len(), 0);
    }
    let count = compact_within(near_found, dist, near_ids, reach);
    found.clear();
    found.extend_from_slice(&near_found[..count]);
}

/// The highest ancestor on `path` (a leaf's, as in [`leaf_rows`]) with a child off the path whose
/// box is within squared distance `reach` of the box `b`, or `leaf` when there is none: every
/// point outside the subtree returned is farther than that from `b`.
fn search_root(tree: &LeafTree, path: &[(Node, usize)], leaf: Node, b: &Aabb, reach: f32) -> Node {
    path.iter().find(|(_, off)| tree.boxes[*off].gap_box(b) <= reach).map_or(leaf, |p| p.0)
}

/// The reach about a leaf's box within which its points are gathered once for all its queries,
/// as a multiple of its first query's `k`-th distance. On sim300k at k = 20: 75 / 92 / 94 % of
/// the queries answered from 188 / 226 / 267 gathered points at 1.1 / 1.3 / 1.5 (32-point leaves,
/// no [`GATHER_CAP`]); normals fastest at 1.3 (BENCHMARKS.md 51), and still so with both (1.2 and
/// 1.4 within noise).
const SPREAD: f32 = 1.3;

/// The most points a leaf gathers, as a multiple of `k` (1000 at k = 20): scanning more per query
/// costs more than the tree search. Without it, 4 of sim300k's leaves (of 16 k, at 32 points a
/// leaf) gathered 130-500 k points each, 23 % of all the points scanned; 265 of its 8 k leaves
/// are left to the tree search (BENCHMARKS.md 52).
const GATHER_CAP: usize = 50;

/// The first reach tried for a query, as a multiple of a nearby answered query's `k`-th distance:
/// the previous one among the gathered points, the one giving the least bound in a tree search.
/// In the tree search alone, on sim300k at k = 20, 6 % of the queries need the second search at
/// 1.2, 16 % at 1.15, 19 % at 1.1; SOR and normals 11-15 % faster at 1.15 than with the bound
/// alone (BENCHMARKS.md 36).
const GUESS: f32 = 1.15;

/// The rows of `leaf`'s queries (tree order) into `rows` (`k` per query); see the module docs.
fn leaf_rows(tree: &LeafTree, k: usize, leaf: Node, scratch: &mut Scratch, rows: &mut [Neighbor]) {
    let (mut path, mut done) = (std::mem::take(&mut scratch.path), std::mem::take(&mut scratch.done));
    path.clear();
    done.clear();
    let root = Node { id: 0, start: 0, end: tree.ids.len() };
    let mut node = root;
    while node.id != leaf.id {
        let (l, r) = node.children();
        let (on, off) = if leaf.start < l.end { (l, r) } else { (r, l) };
        path.push((node, off.id));
        node = on;
    }
    // the seed: the smallest subtree about the leaf with at least 2k points (the root holds k)
    let seed = path.iter().map(|p| p.0).chain([leaf]).rev().find(|n| n.end - n.start >= 2 * k).unwrap_or(root);
    let seed_reach = |q: [f32; 3], dist: &mut Vec<f32>| {
        tree.distances(q, seed, dist);
        let (_, kth, _) = dist.select_nth_unstable_by(k - 1, f32::total_cmp);
        widen(kth.sqrt())
    };
    // the gathered reach, once gathered (after the first query)
    let mut spread = None;
    for (j, row) in (leaf.start..leaf.end).zip(rows.chunks_exact_mut(k)) {
        let q = [tree.xs[j], tree.ys[j], tree.zs[j]];
        // the leaf's gathered points hold every point within `spread` of the query: first a
        // guess near the previous query's k-th distance, then all of them
        let mut searched = false;
        if let (Some(spread), Some(&(_, previous))) = (spread, done.last()) {
            let guess = widen(GUESS * previous).min(spread);
            near_within(q, guess * guess, scratch);
            searched = scratch.found.len() >= k;
            if !searched && guess < spread {
                near_within(q, spread * spread, scratch);
                searched = scratch.found.len() >= k;
            }
        }
        if !searched {
            // each query done bounds this one's k-th distance by its own plus the step: the least,
            // and the k-th distance of the query that gives it
            let (bound, near) = done
                .iter()
                .map(|&(p, d)| (dist_sq(q, p).sqrt() + d, d))
                .fold((f32::INFINITY, 0.0), |best, b| if b.0 < best.0 { b } else { best });
            let reach = if done.is_empty() { seed_reach(q, &mut scratch.dist) } else { widen(bound) };
            // the search starts below every ancestor whose other side is out of reach (with a
            // margin against rounding)
            let at_q = Aabb { lo: q, hi: q };
            let from = |r: f32| {
                let r = widen(r);
                search_root(tree, &path, leaf, &at_q, r * r)
            };
            // first a guess near that query's k-th distance: a ball holding k points holds the k
            // nearest, so the guess is kept when it does and only costs a second search when not
            let guess = widen(GUESS * near);
            if guess < reach {
                tree.within(from(guess), q, guess * guess, scratch);
                searched = scratch.found.len() >= k;
            }
            if !searched {
                tree.within(from(reach), q, reach * reach, scratch);
            }
            if scratch.found.len() < k {
                // rounding: the seed's reach always holds k points
                let reach = seed_reach(q, &mut scratch.dist);
                tree.within(from(reach), q, reach * reach, scratch);
            }
        }
        // sorting up to 2k candidates whole is cheaper than selecting the k first (normals 10 %)
        let found = &mut scratch.found;
        if found.len() > 2 * k {
            found.select_nth_unstable(k - 1);
            found.truncate(k);
        }
        found.sort_unstable();
        found.truncate(k);
        for (slot, &c) in row.iter_mut().zip(found.iter()) {
            *slot = neighbor(c);
        }
        done.push((q, row[k - 1].dist_sq.sqrt()));
        if done.len() == 1 {
            let r = SPREAD * row[k - 1].dist_sq.sqrt();
            let b = &tree.boxes[leaf.id];
            // a leaf spread out beside denser points would gather thousands: left to the tree search
            spread =
                tree.near_box(search_root(tree, &path, leaf, b, r * r), b, r * r, GATHER_CAP * k, scratch).then_some(r);
        }
    }
    (scratch.path, scratch.done) = (path, done);
}

/// The tree over `points` and its leaves, after the checks; `None` when `k` is 0 or there are no
/// points.
fn tree_for(points: &[Point3<f32>], k: usize) -> Result<Option<(LeafTree, Vec<Node>)>> {
    let tree = LeafTree::new(points)?;
    if k == 0 || points.is_empty() {
        return Ok(None);
    }
    let leaves = tree.leaves();
    Ok(Some((tree, leaves)))
}

/// The leaves a parallel task answers (see [`by_leaf`]): sim300k's 8 k leaves in 64 tasks.
const LEAVES_PER_TASK: usize = 128;

/// `width` values per point in tree order: each leaf's rows handed to `fill(input indices of
/// the leaf's points, their rows, their values)`, leaves in parallel.
///
/// The leaves are answered in tasks of [`LEAVES_PER_TASK`], each task on its own: rayon's own
/// split (a quarter of the leaves a task at 2 threads) can leave one thread idle while the other
/// answers its last quarter, the leaves being of unequal cost (before the gathering cap, one
/// thread idled for the last 28 % of sim300k's rows).
fn by_leaf<T: Clone + Default + Send>(
    tree: &LeafTree,
    leaves: &[Node],
    k: usize,
    width: usize,
    fill: impl Fn(&[u32], &[Neighbor], &mut [T]) + Sync,
) -> Vec<T> {
    let mut out = vec![T::default(); tree.ids.len() * width];
    let mut tasks = Vec::with_capacity(leaves.len().div_ceil(LEAVES_PER_TASK));
    let mut rest = out.as_mut_slice();
    // the leaves are in tree order: a task's values are one run of `out`
    for task in leaves.chunks(LEAVES_PER_TASK) {
        let points = task.iter().map(|leaf| leaf.end - leaf.start).sum::<usize>();
        let (values, tail) = rest.split_at_mut(points * width);
        tasks.push((task, values));
        rest = tail;
    }
    tasks.into_par_iter().with_max_len(1).for_each_init(
        || (Scratch::default(), Vec::new()),
        |(scratch, rows), (task, values)| {
            let mut values = &mut values[..];
            for &leaf in task {
                let n = leaf.end - leaf.start;
                rows.clear();
                rows.resize(n * k, Neighbor::default());
                leaf_rows(tree, k, leaf, scratch, rows);
                let (these, tail) = std::mem::take(&mut values).split_at_mut(n * width);
                fill(&tree.ids[leaf.start..leaf.end], rows, these);
                values = tail;
            }
        },
    );
    out
}

/// The tree position of each input point.
fn positions(tree: &LeafTree) -> Vec<u32> {
    let mut position = vec![0u32; tree.ids.len()];
    for (j, &i) in tree.ids.iter().enumerate() {
        position[i as usize] = j as u32;
    }
    position
}

/// The `k` nearest points of every point (`min(k, n)` per row, the point itself included), see
/// the module docs: `(k, rows in tree order, the tree position of each point)`.
///
/// # Errors
/// [`Error::Invalid`] for a non-finite point or more than `u32::MAX` points.
pub(crate) fn knn_rows(points: &[Point3<f32>], k: usize) -> Result<(usize, Vec<Neighbor>, Vec<u32>)> {
    let k = k.min(points.len());
    let Some((tree, leaves)) = tree_for(points, k)? else { return Ok((0, Vec::new(), Vec::new())) };
    let rows = by_leaf(&tree, &leaves, k, k, |_, rows, out: &mut [Neighbor]| out.copy_from_slice(rows));
    Ok((k, rows, positions(&tree)))
}

/// `f(i, row)` for every point `i` and its row (the `min(k, n)` nearest points, see the module
/// docs), in input order, without storing the rows.
///
/// # Errors
/// [`Error::Invalid`] for a non-finite point or more than `u32::MAX` points.
pub(crate) fn knn_map<T: Copy + Default + Send + Sync>(
    points: &[Point3<f32>],
    k: usize,
    f: impl Fn(usize, &[Neighbor]) -> T + Sync,
) -> Result<Vec<T>> {
    let k = k.min(points.len());
    // no tree: k is 0 (k <= n), every row empty
    let Some((tree, leaves)) = tree_for(points, k)? else { return Ok((0..points.len()).map(|i| f(i, &[])).collect()) };
    let values = by_leaf(&tree, &leaves, k, 1, |ids, rows, out: &mut [T]| {
        for ((v, &i), row) in out.iter_mut().zip(ids).zip(rows.chunks_exact(k)) {
            *v = f(i as usize, row);
        }
    });
    let position = positions(&tree);
    Ok(position.par_iter().with_min_len(4096).map(|&j| values[j as usize]).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::spatial::brute;
    use rand::{RngExt, SeedableRng};

    fn check(points: &[Point3<f32>], k: usize) {
        let (kk, rows, position) = knn_rows(points, k).expect("rows");
        assert_eq!(kk, k.min(points.len()));
        let firsts =
            knn_map(points, k, |i, row| (i, row.first().map(|n| n.index), row.last().map(|n| n.dist_sq))).expect("map");
        assert_eq!(firsts.len(), points.len());
        for (i, p) in points.iter().enumerate() {
            let want = brute::knn(points, p, kk);
            let j = position[i] as usize;
            assert_eq!(&rows[j * kk..(j + 1) * kk], want.as_slice(), "point {i} of {}", points.len());
            assert_eq!(firsts[i], (i, want.first().map(|n| n.index), want.last().map(|n| n.dist_sq)));
        }
    }

    #[test]
    fn rows_equal_brute_force_ties_by_index() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let random: Vec<Point3<f32>> =
            (0..5000).map(|_| Point3::new(rng.random::<f32>(), rng.random::<f32>(), rng.random::<f32>())).collect();
        check(&random, 20);
        // a lattice: many equal distances, ties at the k-th decided by index
        let lattice: Vec<Point3<f32>> = (0..4000)
            .map(|i| Point3::new((i % 40) as f32 * 0.002, (i / 40 % 10) as f32 * 0.002, (i / 400) as f32 * 0.002))
            .collect();
        check(&lattice, 21);
        // duplicates, a far cluster, fewer points than k
        let mut dup = vec![Point3::new(1.0, 2.0, 3.0); 70];
        dup.extend((0..30).map(|i| Point3::new(50.0 + i as f32, -2.0, 0.5)));
        check(&dup, 40);
        check(&random[..7], 20);
        check(&[], 5);
    }

    #[test]
    fn sparse_leaves_beside_dense_points_are_exact() {
        // a dense blob and a sparse line through it: the line's leaves reach the blob and are left
        // to the tree search (more than GATHER_CAP times k points to gather)
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut points: Vec<Point3<f32>> = (0..3000)
            .map(|_| Point3::new(0.01 * rng.random::<f32>(), 0.01 * rng.random::<f32>(), 0.01 * rng.random::<f32>()))
            .collect();
        points.extend((0..200).map(|i| Point3::new(-1.0 + 0.01 * i as f32, 0.005, 0.02 * rng.random::<f32>())));
        check(&points, 3);
        check(&points, 8);
    }

    #[test]
    fn same_rows_with_one_and_two_threads() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(6);
        let points: Vec<Point3<f32>> = (0..60_000)
            .map(|_| Point3::new(rng.random::<f32>(), rng.random::<f32>(), 0.01 * rng.random::<f32>()))
            .collect();
        let run = |t: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(t).build().expect("pool").install(|| knn_rows(&points, 20))
        };
        assert_eq!(run(1).expect("1"), run(2).expect("2"));
    }

    #[test]
    fn non_finite_point_is_an_error() {
        assert!(knn_rows(&[Point3::new(0.0, f32::NAN, 0.0)], 3).is_err());
    }
}

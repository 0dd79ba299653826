//! Nested dissection of a pile's contact graph from the bodies' positions: the elimination
//! order the interior point's sparse Cholesky uses with `ipm:nd` (issue #51).
//!
//! A pile is a planar graph laid out in the plane, so its bodies' coordinates find small
//! separators without any graph partitioner (recursive coordinate bisection): split a set of
//! bodies at the median of its longer extent, take as separator the bodies of one half that touch
//! the other half (the shorter of the two boundaries), order both halves (recursively) before
//! the separator; sets of at most [`LEAF`] bodies are ordered by minimum degree (faer's AMD on
//! the graph they induce). A 2D mesh so ordered fills `O(n log n)` and factorises in `O(n^1.5)`.
//! The order is computed on bodies, not on their three velocity dofs (faer's minimum degree on
//! the whole system works on the nine times larger scalar pattern).
//!
//! Measured (docs/solvers.md): on piles of 400 to 4,000 bodies minimum degree fills less (a
//! 600-body lattice: 71k entries against 52k; 4,000: 0.99M against 0.73M) and factorises as
//! fast or faster; dissection's gain is a cheaper analysis, and it is kept as `ipm:nd` for that
//! measurement, not as a default.
//!
//! The bodies' positions are not part of a solve's input: they are read off the rows' lever arms
//! ([`super::placement`]); parts not joined by a row need no separator between them.

use super::placement::Placement;
use super::rows::ContactRow;
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::amd;
use faer::sparse::SymbolicSparseColMatRef;

/// Sets of at most this many bodies are not split further: minimum degree orders them (on
/// small graphs it fills less than dissection's separators do).
const LEAF: usize = 64;

/// Reusable buffers of the ordering.
#[derive(Debug, Default, Clone)]
pub(super) struct Dissection {
    adjacency_start: Vec<u32>,
    adjacency: Vec<u32>,
    placement: Placement,
    /// Per block: the id of the set it belongs to now, and its side in that set's split.
    set_of: Vec<u32>,
    side: Vec<u8>,
    next_set: u32,
    /// A leaf's minimum-degree ordering: its blocks' local index, its pattern, the permutation.
    local: Vec<u32>,
    leaf_col_ptr: Vec<usize>,
    leaf_row_idx: Vec<usize>,
    leaf_perm: Vec<usize>,
    leaf_perm_inv: Vec<usize>,
}

impl Dissection {
    /// The elimination order of `blocks` blocks joined by the off-diagonal block `pairs`: `order[k]`
    /// is the block eliminated `k`-th. `rows` and `block_of` (per body: its block, `u32::MAX` when
    /// it is not a variable) place the blocks in the plane.
    pub(super) fn order(
        &mut self,
        blocks: usize,
        pairs: &[(u32, u32)],
        rows: &[ContactRow],
        block_of: &[u32],
        order: &mut Vec<u32>,
    ) {
        self.adjacency_of(blocks, pairs);
        self.place(blocks, rows, block_of);
        self.set_of.clear();
        self.set_of.resize(blocks, 0);
        self.side.clear();
        self.side.resize(blocks, 0);
        self.next_set = 1;
        let mut set: Vec<u32> = (0..blocks as u32).collect();
        order.clear();
        order.reserve(blocks);
        self.dissect(&mut set, order);
    }

    /// The symmetric adjacency of the blocks (CSR), without the diagonal.
    fn adjacency_of(&mut self, blocks: usize, pairs: &[(u32, u32)]) {
        let mut degree = vec![0u32; blocks + 1];
        for &(i, j) in pairs.iter().filter(|(i, j)| i != j) {
            degree[i as usize] += 1;
            degree[j as usize] += 1;
        }
        self.adjacency_start.clear();
        self.adjacency_start.push(0);
        let mut total = 0;
        for d in &degree[..blocks] {
            total += d;
            self.adjacency_start.push(total);
        }
        self.adjacency.clear();
        self.adjacency.resize(total as usize, 0);
        let mut fill: Vec<u32> = self.adjacency_start[..blocks].to_vec();
        for &(i, j) in pairs.iter().filter(|(i, j)| i != j) {
            self.adjacency[fill[i as usize] as usize] = j;
            fill[i as usize] += 1;
            self.adjacency[fill[j as usize] as usize] = i;
            fill[j as usize] += 1;
        }
    }

    fn neighbours(&self, block: u32) -> &[u32] {
        let b = block as usize;
        &self.adjacency[self.adjacency_start[b] as usize..self.adjacency_start[b + 1] as usize]
    }

    /// Every block's centre, relative to the first placed block of its connected part: `r_a - r_b`
    /// of every row joining two blocks.
    fn place(&mut self, blocks: usize, rows: &[ContactRow], block_of: &[u32]) {
        let block = |body: u32| block_of.get(body as usize).copied().filter(|&k| k != u32::MAX);
        let joints = rows.iter().filter_map(move |r| {
            Some((block(r.body_a)?, block(r.body_b)?, [(r.ra.x - r.rb.x) as f64, (r.ra.y - r.rb.y) as f64]))
        });
        self.placement.place(blocks, joints);
    }

    /// Appends the elimination order of `set` to `order`: its two halves' (recursively), then its
    /// separator. `set` is reordered in place.
    fn dissect(&mut self, set: &mut [u32], order: &mut Vec<u32>) {
        if set.len() <= LEAF {
            self.minimum_degree(set, order);
            return;
        }
        let id = self.next_set;
        self.next_set += 1;
        // The longer extent's axis, split at its median.
        let (mut low, mut high) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for &b in set.iter() {
            let p = self.placement.positions()[b as usize];
            for k in 0..2 {
                low[k] = low[k].min(p[k]);
                high[k] = high[k].max(p[k]);
            }
        }
        let axis = if high[0] - low[0] >= high[1] - low[1] { 0 } else { 1 };
        let middle = set.len() / 2;
        let position = self.placement.positions();
        // Ties broken by block index: the order is a function of the input alone.
        set.select_nth_unstable_by(middle, |&a, &b| {
            position[a as usize][axis].total_cmp(&position[b as usize][axis]).then(a.cmp(&b))
        });
        for (k, &b) in set.iter().enumerate() {
            self.set_of[b as usize] = id;
            self.side[b as usize] = (k >= middle) as u8;
        }
        // Each half's boundary: its blocks with a neighbour in the other half of this set.
        let on_boundary: Vec<bool> = set
            .iter()
            .map(|&b| {
                let side = self.side[b as usize];
                self.neighbours(b).iter().any(|&n| self.set_of[n as usize] == id && self.side[n as usize] != side)
            })
            .collect();
        let mut boundary_size = [0usize; 2];
        for (&b, _) in set.iter().zip(&on_boundary).filter(|(_, &on)| on) {
            boundary_size[self.side[b as usize] as usize] += 1;
        }
        // The shorter boundary separates (the left one on a tie).
        let separating_side = (boundary_size[1] < boundary_size[0]) as u8;
        // Partition into [left without separator | right without separator | separator].
        let mut parts: [Vec<u32>; 3] = Default::default();
        for (&b, &on) in set.iter().zip(&on_boundary) {
            let side = self.side[b as usize];
            parts[if on && side == separating_side { 2 } else { side as usize }].push(b);
        }
        // Stable within each part: sort by index so the order does not depend on the selection.
        for part in parts.iter_mut() {
            part.sort_unstable();
        }
        let (left, rest) = set.split_at_mut(parts[0].len());
        let (right, separator) = rest.split_at_mut(parts[1].len());
        left.copy_from_slice(&parts[0]);
        right.copy_from_slice(&parts[1]);
        separator.copy_from_slice(&parts[2]);
        self.dissect(left, order);
        self.dissect(right, order);
        order.extend_from_slice(separator);
    }

    /// Appends `set`'s blocks to `order` in faer's approximate minimum degree order of the graph
    /// they induce (in `set`'s order if that fails, which it does only out of memory).
    fn minimum_degree(&mut self, set: &[u32], order: &mut Vec<u32>) {
        if set.len() <= 2 {
            order.extend_from_slice(set);
            return;
        }
        let id = self.next_set;
        self.next_set += 1;
        self.local.resize(self.set_of.len(), 0);
        for (k, &b) in set.iter().enumerate() {
            self.set_of[b as usize] = id;
            self.local[b as usize] = k as u32;
        }
        self.leaf_col_ptr.clear();
        self.leaf_row_idx.clear();
        self.leaf_col_ptr.push(0);
        for &b in set {
            let start = self.leaf_row_idx.len();
            let b = b as usize;
            for &n in &self.adjacency[self.adjacency_start[b] as usize..self.adjacency_start[b + 1] as usize] {
                if self.set_of[n as usize] == id {
                    self.leaf_row_idx.push(self.local[n as usize] as usize);
                }
            }
            self.leaf_row_idx[start..].sort_unstable();
            self.leaf_col_ptr.push(self.leaf_row_idx.len());
        }
        let m = set.len();
        self.leaf_perm.resize(m, 0);
        self.leaf_perm_inv.resize(m, 0);
        let structure = SymbolicSparseColMatRef::new_checked(m, m, &self.leaf_col_ptr, None, &self.leaf_row_idx);
        let ordered =
            MemBuffer::try_new(amd::order_scratch::<usize>(m, self.leaf_row_idx.len())).ok().and_then(|mut buffer| {
                amd::order(
                    &mut self.leaf_perm,
                    &mut self.leaf_perm_inv,
                    structure,
                    Default::default(),
                    MemStack::new(&mut buffer),
                )
                .ok()
            });
        match ordered {
            Some(_) => order.extend(self.leaf_perm.iter().map(|&k| set[k])),
            None => order.extend_from_slice(set),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::rows::fixtures::lattice;

    /// A `w` x `h` lattice of balls on the floor ([`lattice`]): its rows, per body its block (the
    /// floor none, ball `k` block `k - 1`) and the blocks' pairs.
    fn grid(w: usize, h: usize) -> (Vec<ContactRow>, Vec<u32>, Vec<(u32, u32)>) {
        let (_, rows) = lattice(w, h);
        let block_of: Vec<u32> = std::iter::once(u32::MAX).chain(0..(w * h) as u32).collect();
        let pairs = rows
            .iter()
            .filter(|r| r.body_a != 0)
            .map(|r| {
                let (a, b) = (block_of[r.body_a as usize], block_of[r.body_b as usize]);
                (a.min(b), a.max(b))
            })
            .collect();
        (rows, block_of, pairs)
    }

    /// The elimination order of `grid(w, h)`, checked to be a permutation of `blocks` blocks.
    fn order_of(blocks: usize, rows: &[ContactRow], block_of: &[u32], pairs: &[(u32, u32)]) -> Vec<u32> {
        let mut order = Vec::new();
        Dissection::default().order(blocks, pairs, rows, block_of, &mut order);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..blocks as u32).collect::<Vec<_>>());
        order
    }

    #[test]
    fn the_order_is_a_permutation_ending_in_the_top_separator() {
        let (rows, block_of, pairs) = grid(20, 12);
        let blocks = 240;
        let order = order_of(blocks, &rows, &block_of, &pairs);
        // The first split is across the longer (x) extent: the last 12 eliminated are one column.
        let last: Vec<u32> = order[blocks - 12..].to_vec();
        let column = last[0] % 20;
        assert!(last.iter().all(|b| b % 20 == column), "{last:?}");
        assert!(column == 9 || column == 10, "{column}");
    }

    #[test]
    fn positions_are_read_off_the_rows_up_to_a_shift() {
        let (rows, block_of, pairs) = grid(5, 4);
        let mut d = Dissection::default();
        d.adjacency_of(20, &pairs);
        d.place(20, &rows, &block_of);
        for b in 0..20 {
            let expected = [(b % 5) as f64, (b / 5) as f64];
            let p = d.placement.positions()[b];
            assert!((p[0] - expected[0]).abs() < 1e-6 && (p[1] - expected[1]).abs() < 1e-6);
        }
    }

    #[test]
    fn parts_without_rows_between_them_and_lone_blocks_are_ordered() {
        // Two grids side by side with no row between them, and three blocks on no row at all.
        let (mut rows, mut block_of, mut pairs) = grid(4, 4);
        let (rows2, _, pairs2) = grid(4, 4);
        rows.extend(rows2.into_iter().filter(|r| r.body_a != 0).map(|r| ContactRow {
            body_a: r.body_a + 16,
            body_b: r.body_b + 16,
            ..r
        }));
        pairs.extend(pairs2.into_iter().map(|(a, b)| (a + 16, b + 16)));
        let blocks = 35;
        block_of.extend(16..blocks as u32);
        order_of(blocks, &rows, &block_of, &pairs);
    }
}

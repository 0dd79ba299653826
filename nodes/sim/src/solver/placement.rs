//! Bodies placed in the plane from a solve's rows alone.
//!
//! A solve's input holds no positions, but a row's lever arms fix its two bodies' centres
//! relative to each other (`c_b = c_a + r_a - r_b`). A breadth-first walk from the first node of
//! each connected part places the others, relative to that first one; parts joined by no row
//! keep unrelated origins. Nested dissection splits on these positions ([`super::dissection`]),
//! the coarse correction cuts them into cells ([`super::coarse`]).

/// The walk's buffers, reused across solves.
#[derive(Debug, Default, Clone)]
pub(super) struct Placement {
    /// Per node, its joints `(other, other's centre minus this one's)`: `start[n]..start[n + 1]`.
    start: Vec<u32>,
    joints: Vec<(u32, [f64; 2])>,
    position: Vec<[f64; 2]>,
    placed: Vec<bool>,
    queue: Vec<u32>,
}

impl Placement {
    /// Places `nodes` nodes joined by `joints` `(a, b, c_b - c_a)` (a joint of a node with
    /// itself is ignored) and returns every node's centre. A node's joints are walked in the
    /// order given, so the positions are a function of the input alone.
    pub(super) fn place(
        &mut self,
        nodes: usize,
        joints: impl Iterator<Item = (u32, u32, [f64; 2])> + Clone,
    ) -> &[[f64; 2]] {
        let joints = joints.filter(|&(a, b, _)| a != b);
        self.start.clear();
        self.start.resize(nodes + 1, 0);
        for (a, b, _) in joints.clone() {
            self.start[a as usize + 1] += 1;
            self.start[b as usize + 1] += 1;
        }
        for n in 0..nodes {
            self.start[n + 1] += self.start[n];
        }
        self.joints.clear();
        self.joints.resize(self.start[nodes] as usize, (0, [0.0; 2]));
        let mut fill: Vec<u32> = self.start[..nodes].to_vec();
        for (a, b, d) in joints {
            self.joints[fill[a as usize] as usize] = (b, d);
            fill[a as usize] += 1;
            self.joints[fill[b as usize] as usize] = (a, [-d[0], -d[1]]);
            fill[b as usize] += 1;
        }
        self.position.clear();
        self.position.resize(nodes, [0.0; 2]);
        self.placed.clear();
        self.placed.resize(nodes, false);
        for root in 0..nodes {
            if self.placed[root] {
                continue;
            }
            self.placed[root] = true;
            self.queue.clear();
            self.queue.push(root as u32);
            let mut head = 0;
            while head < self.queue.len() {
                let a = self.queue[head] as usize;
                head += 1;
                for &(b, d) in &self.joints[self.start[a] as usize..self.start[a + 1] as usize] {
                    if !self.placed[b as usize] {
                        self.placed[b as usize] = true;
                        self.position[b as usize] = [self.position[a][0] + d[0], self.position[a][1] + d[1]];
                        self.queue.push(b);
                    }
                }
            }
        }
        &self.position
    }

    /// The centres of the last [`Self::place`].
    pub(super) fn positions(&self) -> &[[f64; 2]] {
        &self.position
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_chain_and_a_lone_part_are_placed_relative_to_their_first_node() {
        // 0 - 1 - 2 along x (joints listed out of order, one reversed), 3 - 4 apart, 5 alone,
        // and a self-joint that changes nothing.
        let joints = [(1, 2, [1.0, 0.0]), (1, 0, [-1.0, 0.5]), (4, 3, [0.0, 2.0]), (2, 2, [9.0, 9.0])];
        let mut placement = Placement::default();
        let p = placement.place(6, joints.iter().copied()).to_vec();
        assert_eq!(p, [[0.0, 0.0], [1.0, -0.5], [2.0, -0.5], [0.0, 0.0], [0.0, -2.0], [0.0, 0.0]]);
        assert_eq!(placement.positions(), p);
    }
}

//! Matching two streams (bodies and contacts) by step header.
//!
//! The simulator publishes bodies(k) and contacts(k) with the same `StepHeader`; the node needs both
//! before it can publish grids of step k. Frames arrive in order on each stream, but one stream can
//! run ahead of the other, and a frame can be missing (a dropped sample, a node restarted mid-run).
//! The pairer queues each stream and pairs equal headers; a frame that can no longer find a partner
//! (the other stream has moved past its step) is dropped and counted, never paired with another step.
//! Several simulators may feed one node: each run (run id) has its own lane, in order within
//! itself, whatever the interleaving between runs.

use msgs::StepHeader;
use std::collections::{BTreeMap, VecDeque};

/// Pairs frames of two streams that carry the same [`StepHeader`].
#[derive(Debug)]
pub struct StepPairer<A, B> {
    lanes: BTreeMap<u64, Lane<A, B>>,
    dropped: u64,
}

/// The queued frames of one run.
#[derive(Debug)]
struct Lane<A, B> {
    a: VecDeque<(StepHeader, A)>,
    b: VecDeque<(StepHeader, B)>,
}

impl<A, B> Default for Lane<A, B> {
    fn default() -> Self {
        Lane { a: VecDeque::new(), b: VecDeque::new() }
    }
}

impl<A, B> Default for StepPairer<A, B> {
    fn default() -> Self {
        StepPairer { lanes: BTreeMap::new(), dropped: 0 }
    }
}

/// Order of steps within one run.
fn key(h: &StepHeader) -> (u32, u32) {
    (h.simulation, h.step)
}

impl<A, B> StepPairer<A, B> {
    /// An empty pairer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Queues a frame of the first stream.
    pub fn push_a(&mut self, header: StepHeader, frame: A) {
        self.lanes.entry(header.run_id).or_default().a.push_back((header, frame));
    }

    /// Queues a frame of the second stream.
    pub fn push_b(&mut self, header: StepHeader, frame: B) {
        self.lanes.entry(header.run_id).or_default().b.push_back((header, frame));
    }

    /// Frames dropped so far for want of a partner.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Frames waiting for a partner.
    pub fn pending(&self) -> usize {
        self.pending_a() + self.pending_b()
    }

    /// Frames of the first stream waiting for a partner.
    pub fn pending_a(&self) -> usize {
        self.lanes.values().map(|l| l.a.len()).sum()
    }

    /// Frames of the second stream waiting for a partner.
    pub fn pending_b(&self) -> usize {
        self.lanes.values().map(|l| l.b.len()).sum()
    }

    /// The next pair with equal headers (of any run), dropping frames whose step the other stream
    /// of their run has passed.
    pub fn pop(&mut self) -> Option<(StepHeader, A, B)> {
        let mut found = None;
        for lane in self.lanes.values_mut() {
            while let (Some(fa), Some(fb)) = (lane.a.front(), lane.b.front()) {
                let (ha, hb) = (fa.0, fb.0);
                if ha == hb {
                    let (h, a) = lane.a.pop_front().expect("front exists");
                    let (_, b) = lane.b.pop_front().expect("front exists");
                    found = Some((h, a, b));
                    break;
                }
                // The older of the two fronts can never be paired: its partner would have come first.
                if key(&ha) < key(&hb) {
                    lane.a.pop_front();
                } else {
                    lane.b.pop_front();
                }
                self.dropped += 1;
            }
            if found.is_some() {
                break;
            }
        }
        self.lanes.retain(|_, l| !l.a.is_empty() || !l.b.is_empty());
        found
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn h(simulation: u32, step: u32) -> StepHeader {
        StepHeader { run_id: 1, simulation, step }
    }

    #[test]
    fn frames_pair_by_step_whichever_stream_runs_ahead() {
        let mut p = StepPairer::new();
        p.push_a(h(0, 0), "b0");
        p.push_a(h(0, 1), "b1");
        assert!(p.pop().is_none());
        p.push_b(h(0, 0), 'c');
        assert_eq!(p.pop(), Some((h(0, 0), "b0", 'c')));
        p.push_b(h(0, 1), 'd');
        assert_eq!(p.pop(), Some((h(0, 1), "b1", 'd')));
        assert_eq!((p.dropped(), p.pending()), (0, 0));
    }

    #[test]
    fn a_frame_without_partner_is_dropped_not_mispaired() {
        let mut p = StepPairer::new();
        p.push_a(h(0, 4), 4);
        p.push_a(h(0, 5), 5);
        p.push_b(h(0, 5), 50); // contacts of step 4 never came
        assert_eq!(p.pop(), Some((h(0, 5), 5, 50)));
        assert_eq!(p.dropped(), 1);
        // A new simulation's step 0 is after the old simulation's last step.
        p.push_b(h(0, 9), 90);
        p.push_a(h(1, 0), 100);
        p.push_b(h(1, 0), 1000);
        assert_eq!(p.pop(), Some((h(1, 0), 100, 1000)));
        assert_eq!(p.dropped(), 2);
    }

    #[test]
    fn interleaved_runs_of_several_simulators_pair_within_their_own_run() {
        let mut p = StepPairer::new();
        let r = |run_id: u64, step: u32| StepHeader { run_id, simulation: run_id as u32, step };
        // Run 1's bodies, then run 2's bodies and contacts, then run 1's contacts.
        p.push_a(r(1, 0), 10);
        p.push_a(r(2, 0), 20);
        p.push_b(r(2, 0), 21);
        p.push_a(r(1, 1), 12);
        p.push_b(r(1, 0), 11);
        p.push_b(r(1, 1), 13);
        let mut pairs = Vec::new();
        while let Some((h, a, b)) = p.pop() {
            pairs.push((h.run_id, h.step, a, b));
        }
        pairs.sort();
        assert_eq!(pairs, [(1, 0, 10, 11), (1, 1, 12, 13), (2, 0, 20, 21)]);
        assert_eq!((p.dropped(), p.pending()), (0, 0));
    }
}

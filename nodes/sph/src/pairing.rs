//! Matching two streams (bodies and contacts) by step header.
//!
//! The simulator publishes bodies(k) and contacts(k) with the same `StepHeader`; the node needs both
//! before it can publish grids of step k. Frames arrive in order on each stream, but one stream can
//! run ahead of the other, and a frame can be missing (a dropped sample, a node restarted mid-run).
//! The pairer queues each stream and pairs equal headers; a frame that can no longer find a partner
//! (the other stream has moved past its step) is dropped and counted, never paired with another step.

use msgs::StepHeader;
use std::collections::VecDeque;

/// Pairs frames of two streams that carry the same [`StepHeader`].
#[derive(Debug)]
pub struct StepPairer<A, B> {
    a: VecDeque<(StepHeader, A)>,
    b: VecDeque<(StepHeader, B)>,
    run_id: Option<u64>,
    dropped: u64,
}

impl<A, B> Default for StepPairer<A, B> {
    fn default() -> Self {
        StepPairer { a: VecDeque::new(), b: VecDeque::new(), run_id: None, dropped: 0 }
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
        self.new_run(header.run_id);
        self.a.push_back((header, frame));
    }

    /// Queues a frame of the second stream.
    pub fn push_b(&mut self, header: StepHeader, frame: B) {
        self.new_run(header.run_id);
        self.b.push_back((header, frame));
    }

    /// Frames dropped so far for want of a partner.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Frames waiting for a partner.
    pub fn pending(&self) -> usize {
        self.a.len() + self.b.len()
    }

    /// Frames of the first stream waiting for a partner.
    pub fn pending_a(&self) -> usize {
        self.a.len()
    }

    /// Frames of the second stream waiting for a partner.
    pub fn pending_b(&self) -> usize {
        self.b.len()
    }

    /// The next pair with equal headers, dropping frames whose step the other stream has passed.
    pub fn pop(&mut self) -> Option<(StepHeader, A, B)> {
        loop {
            let (ha, hb) = (self.a.front()?.0, self.b.front()?.0);
            if ha == hb {
                let (h, a) = self.a.pop_front()?;
                let (_, b) = self.b.pop_front()?;
                return Some((h, a, b));
            }
            // The older of the two fronts can never be paired: its partner would have come first.
            if key(&ha) < key(&hb) {
                self.a.pop_front();
            } else {
                self.b.pop_front();
            }
            self.dropped += 1;
        }
    }

    /// A frame of another run makes everything queued from the previous run stale.
    fn new_run(&mut self, run_id: u64) {
        if self.run_id != Some(run_id) {
            self.dropped += (self.a.len() + self.b.len()) as u64;
            self.a.clear();
            self.b.clear();
            self.run_id = Some(run_id);
        }
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
    fn a_new_run_clears_the_old_one() {
        let mut p = StepPairer::new();
        p.push_a(h(0, 7), 1);
        p.push_b(StepHeader { run_id: 2, simulation: 0, step: 0 }, 2);
        p.push_a(StepHeader { run_id: 2, simulation: 0, step: 0 }, 3);
        assert_eq!(p.pop().map(|(_, a, b)| (a, b)), Some((3, 2)));
        assert_eq!(p.dropped(), 1);
    }
}

//! The trainer's view of recordings: steps joined per (run, simulation, step).
//!
//! ```no_run
//! for step in recorder::Steps::open("recordings".as_ref())? {
//!     let step = step?;
//!     println!("{:?}: {} bodies, {} contacts", step.key, step.bodies.items.len(), step.contacts.items.len());
//! }
//! # Ok::<(), recorder::Error>(())
//! ```

use crate::read::{Item, RecordingReader};
use crate::{recording_files, Error, Result};
use msgs::{topics, Bodies, Contacts, ProblemBodies, ProblemContacts, SolveStats, StepHeader};
use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};

/// One simulation step: the bodies at its end, its contacts with their impulses, the solver
/// statistics when the recording has them, and the step's velocity problem when it has those
/// (a simulator run with `--publish-problem`).
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    pub key: StepHeader,
    pub bodies: Bodies,
    pub contacts: Contacts,
    pub stats: Option<SolveStats>,
    pub problem: Option<(ProblemBodies, ProblemContacts)>,
}

/// Steps still waiting for one of their parts.
const DEFAULT_WINDOW: usize = 64;

#[derive(Default)]
struct Partial {
    bodies: Option<Bodies>,
    contacts: Option<Contacts>,
    stats: Option<SolveStats>,
    problem_bodies: Option<ProblemBodies>,
    problem_contacts: Option<ProblemContacts>,
}

type Key = (u64, u32, u32);

/// Iterates the steps of one recording or of a folder of recordings (files in name order), in
/// (run, simulation, step) order within a file, holding at most a window of incomplete steps in
/// memory. A step missing its bodies or contacts (or its statistics, when the file has a stats
/// channel) is skipped and counted in [`Steps::incomplete`]; a payload that does not decode is
/// skipped and counted in [`Steps::undecodable`].
pub struct Steps {
    files: VecDeque<PathBuf>,
    reader: Option<RecordingReader>,
    pending: BTreeMap<Key, Partial>,
    ready: VecDeque<Step>,
    window: usize,
    has_stats: bool,
    /// The file has problem channels (the recorder makes every channel up front, used or not) ...
    has_problem: bool,
    /// ... and problem frames were seen in it: from then on a step needs its problem.
    problem_seen: bool,
    incomplete: u64,
    undecodable: u64,
}

impl Steps {
    /// Steps of `path`: an `.mcap` file or a folder of them.
    pub fn open(path: &Path) -> Result<Steps> {
        Ok(Steps::of_files(recording_files(path)?))
    }

    /// Steps of these recordings, in this order.
    pub fn of_files(files: Vec<std::path::PathBuf>) -> Steps {
        Steps {
            files: files.into(),
            reader: None,
            pending: BTreeMap::new(),
            ready: VecDeque::new(),
            window: DEFAULT_WINDOW,
            has_stats: false,
            has_problem: false,
            problem_seen: false,
            incomplete: 0,
            undecodable: 0,
        }
    }

    /// At most `window` incomplete steps are held before the oldest is given up.
    pub fn with_window(mut self, window: usize) -> Steps {
        self.window = window.max(1);
        self
    }

    /// Steps skipped because a part never arrived.
    pub fn incomplete(&self) -> u64 {
        self.incomplete
    }

    /// Payloads skipped because they did not decode.
    pub fn undecodable(&self) -> u64 {
        self.undecodable
    }

    fn complete(&self, p: &Partial) -> bool {
        p.bodies.is_some()
            && p.contacts.is_some()
            && (p.stats.is_some() || !self.has_stats)
            && (Self::has_its_problem(p) || !self.problem_seen)
    }

    fn has_its_problem(p: &Partial) -> bool {
        p.problem_bodies.is_some() && p.problem_contacts.is_some()
    }

    /// Moves complete steps at the front to `ready`; gives up the oldest beyond the window, or all
    /// at the end of a file.
    fn release(&mut self, end_of_file: bool) {
        while let Some((&key, front)) = self.pending.first_key_value() {
            let complete = self.complete(front);
            // Without a problem yet in a file with problem channels, its problem may still come:
            // wait for it as for a missing part (a file whose channels stay empty releases its
            // steps once the window is full).
            let may_get_problem = self.has_problem && !Self::has_its_problem(front);
            if (!complete || may_get_problem) && !end_of_file && self.pending.len() <= self.window {
                break;
            }
            let p = self.pending.remove(&key).expect("the first key");
            if complete {
                let key = StepHeader { run_id: key.0, simulation: key.1, step: key.2 };
                self.ready.push_back(Step {
                    key,
                    bodies: p.bodies.expect("complete"),
                    contacts: p.contacts.expect("complete"),
                    stats: p.stats,
                    problem: p.problem_bodies.zip(p.problem_contacts),
                });
            } else {
                self.incomplete += 1;
            }
        }
    }

    fn take(&mut self, topic: &str, data: &[u8]) {
        let key = |s: StepHeader| (s.run_id, s.simulation, s.step);
        if topic == topics::BODIES.name {
            match msgs::decode::<StepHeader, msgs::Body>(data) {
                Ok(f) => {
                    let k = key(f.header);
                    self.pending.entry(k).or_default().bodies = Some(f)
                }
                Err(_) => self.undecodable += 1,
            }
        } else if topic == topics::CONTACTS.name {
            match msgs::decode::<StepHeader, msgs::Contact>(data) {
                Ok(f) => {
                    let k = key(f.header);
                    self.pending.entry(k).or_default().contacts = Some(f)
                }
                Err(_) => self.undecodable += 1,
            }
        } else if topic == topics::SOLVE_STATS.name {
            match msgs::decode::<msgs::SolveStatsHeader, f32>(data) {
                Ok(f) => {
                    let k = key(f.header.step);
                    self.pending.entry(k).or_default().stats = Some(f)
                }
                Err(_) => self.undecodable += 1,
            }
        } else if topic == topics::PROBLEM_BODIES.name {
            match msgs::decode::<StepHeader, msgs::ProblemBody>(data) {
                Ok(f) => {
                    let k = key(f.header);
                    self.problem_seen = true;
                    self.pending.entry(k).or_default().problem_bodies = Some(f)
                }
                Err(_) => self.undecodable += 1,
            }
        } else if topic == topics::PROBLEM_CONTACTS.name {
            match msgs::decode::<msgs::ProblemHeader, msgs::ProblemContact>(data) {
                Ok(f) => {
                    let k = key(f.header.step);
                    self.problem_seen = true;
                    self.pending.entry(k).or_default().problem_contacts = Some(f)
                }
                Err(_) => self.undecodable += 1,
            }
        }
    }
}

impl Iterator for Steps {
    type Item = Result<Step, Error>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(step) = self.ready.pop_front() {
                return Some(Ok(step));
            }
            let reader = match &mut self.reader {
                Some(r) => r,
                None => {
                    let file = self.files.pop_front()?;
                    self.has_stats = false;
                    self.has_problem = false;
                    self.problem_seen = false;
                    match RecordingReader::open(&file) {
                        Ok(r) => self.reader.insert(r),
                        Err(e) => return Some(Err(e)),
                    }
                }
            };
            match reader.next_item() {
                None => {
                    self.reader = None;
                    self.release(true);
                }
                Some(Err(e)) => {
                    self.reader = None;
                    self.pending.clear();
                    return Some(Err(e));
                }
                Some(Ok(Item::Channel(c))) => {
                    if c.topic == topics::SOLVE_STATS.name {
                        self.has_stats = true;
                    }
                    if c.topic == topics::PROBLEM_CONTACTS.name {
                        self.has_problem = true;
                    }
                }
                Some(Ok(Item::Message(m))) => {
                    self.take(&m.channel.topic, &m.data);
                    self.release(false);
                }
                Some(Ok(_)) => {}
            }
        }
    }
}

//! `dc-record info`: what a recording holds, like `ros2 bag info`.

use crate::read::{Damage, Item, ReadOptions, RecordingReader};
use crate::summary::SummaryProblem;
use crate::{Error, Result};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::path::{Path, PathBuf};

/// One topic of a recording.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TopicInfo {
    pub topic: String,
    /// Frame type from the channel metadata (or the encoding for a foreign channel).
    pub type_name: String,
    pub encoding: String,
    pub messages: u64,
    /// Payload bytes (uncompressed).
    pub bytes: u64,
    /// Payloads that do not decode as the channel's frame type.
    pub undecodable: u64,
}

/// Steps seen of one simulation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StepRange {
    pub first: u32,
    pub last: u32,
    /// Distinct steps with a `bodies` message.
    pub steps: u64,
}

/// Summary of a recording, from one full pass over it.
#[derive(Debug, Clone, Default)]
pub struct Info {
    pub path: PathBuf,
    pub file_size: u64,
    pub topics: BTreeMap<String, TopicInfo>,
    pub messages: u64,
    /// First and last log time (ns since the epoch).
    pub time_range: Option<(u64, u64)>,
    /// (run id, simulation) -> steps.
    pub simulations: BTreeMap<(u64, u32), StepRange>,
    pub chunks: u64,
    pub compressed_bytes: u64,
    pub uncompressed_bytes: u64,
    pub compressions: BTreeSet<String>,
    /// Metadata records: name and entries.
    pub metadata: Vec<(String, BTreeMap<String, String>)>,
    /// Damaged regions skipped (a lenient read only; a strict one stops with an error).
    pub damage: Vec<Damage>,
    /// Messages lost in the skipped regions, per topic, as far as the file tells.
    pub skipped: BTreeMap<String, u64>,
    /// Where each recording after the first starts (files concatenated; a lenient read only).
    pub recordings: Vec<u64>,
    /// What is wrong with the summary section (what indexed readers go by).
    pub summary_problems: Vec<SummaryProblem>,
}

impl Info {
    /// Reads `path` once. A damaged file, a non-MCAP file or an unknown wire version is an error
    /// naming the file.
    pub fn read(path: &Path) -> Result<Info> {
        Self::from_reader(RecordingReader::open(path)?)
    }

    /// Reads `path` once with `options`: with [`ReadOptions::lenient`], damaged regions are
    /// skipped, listed in [`Info::damage`], and everything intact is counted.
    pub fn read_with(path: &Path, options: ReadOptions) -> Result<Info> {
        Self::from_reader(RecordingReader::open_with(path, options)?)
    }

    /// Reads what `reader` has left.
    pub fn from_reader(mut reader: RecordingReader) -> Result<Info> {
        let mut info = Info { path: reader.path().to_path_buf(), file_size: reader.size(), ..Default::default() };
        let mut last_step: BTreeMap<(u64, u32), u32> = BTreeMap::new();
        while let Some(item) = reader.next_item() {
            match item? {
                Item::Channel(c) => {
                    let t = info.topics.entry(c.topic.clone()).or_default();
                    t.topic = c.topic.clone();
                    t.encoding = c.encoding.clone();
                    t.type_name =
                        c.kind.map(|k| k.type_name().to_string()).unwrap_or_else(|| format!("({})", c.encoding));
                }
                Item::Message(m) => {
                    info.messages += 1;
                    info.time_range = Some(match info.time_range {
                        None => (m.log_time, m.log_time),
                        Some((a, b)) => (a.min(m.log_time), b.max(m.log_time)),
                    });
                    let t = info.topics.entry(m.channel.topic.clone()).or_default();
                    t.messages += 1;
                    t.bytes += m.data.len() as u64;
                    let Some(kind) = m.channel.kind else { continue };
                    match kind.step_of(&m.data) {
                        Err(_) => t.undecodable += 1,
                        Ok(s) if kind == crate::FrameKind::Bodies && m.channel.topic == msgs::topics::BODIES.name => {
                            let key = (s.run_id, s.simulation);
                            let r = info.simulations.entry(key).or_insert(StepRange {
                                first: s.step,
                                last: s.step,
                                steps: 0,
                            });
                            r.first = r.first.min(s.step);
                            r.last = r.last.max(s.step);
                            if last_step.insert(key, s.step) != Some(s.step) {
                                r.steps += 1;
                            }
                        }
                        Ok(_) => {}
                    }
                }
                Item::Metadata(m) => info.metadata.push((m.name, m.metadata)),
                Item::Chunk { compression, compressed, uncompressed } => {
                    info.chunks += 1;
                    info.compressed_bytes = info.compressed_bytes.saturating_add(compressed);
                    info.uncompressed_bytes = info.uncompressed_bytes.saturating_add(uncompressed);
                    info.compressions.insert(if compression.is_empty() { "none".into() } else { compression });
                }
            }
        }
        info.damage = reader.damage().to_vec();
        info.skipped = reader.skipped().clone();
        info.recordings = reader.recordings().to_vec();
        info.summary_problems = reader.summary_problems().to_vec();
        Ok(info)
    }

    /// The first thing wrong with the file as an error naming it: damage skipped, then recordings
    /// concatenated, then a summary that does not match the data; `None` for a sound file.
    pub fn problem(&self) -> Option<Error> {
        let path = self.path.clone();
        if let Some(d) = self.damage.first() {
            return Some(d.to_error(&path));
        }
        if let Some(&second) = self.recordings.first() {
            return Some(Error::Concatenated { path, recordings: self.recordings.len() + 1, second });
        }
        let first = self.summary_problems.first()?;
        let more = match self.summary_problems.len() - 1 {
            0 => String::new(),
            n => format!(" (and {n} more problem(s))"),
        };
        Some(Error::BadSummary { path, offset: first.offset, detail: first.detail.clone(), more })
    }

    /// Uncompressed over compressed chunk bytes.
    pub fn compression_ratio(&self) -> f64 {
        if self.compressed_bytes == 0 {
            1.0
        } else {
            self.uncompressed_bytes as f64 / self.compressed_bytes as f64
        }
    }

    pub fn undecodable(&self) -> u64 {
        self.topics.values().map(|t| t.undecodable).sum()
    }
}

fn mib(b: u64) -> String {
    if b >= 1 << 20 {
        format!("{:.2} MiB", b as f64 / (1u64 << 20) as f64)
    } else {
        format!("{:.1} KiB", b as f64 / 1024.0)
    }
}

impl fmt::Display for Info {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "Files:             {}", self.path.display())?;
        writeln!(f, "Bag size:          {}", mib(self.file_size))?;
        writeln!(f, "Storage id:        mcap")?;
        match self.time_range {
            Some((a, b)) => {
                writeln!(f, "Duration:          {:.3} s", (b - a) as f64 * 1e-9)?;
                writeln!(f, "Start:             {} ({:.3} s since the epoch)", crate::utc_text(a), a as f64 * 1e-9)?;
                writeln!(f, "End:               {} ({:.3} s since the epoch)", crate::utc_text(b), b as f64 * 1e-9)?;
            }
            None => writeln!(f, "Duration:          (no messages)")?,
        }
        writeln!(f, "Messages:          {}", self.messages)?;
        writeln!(
            f,
            "Chunks:            {} ({}), {} -> {} (ratio {:.2})",
            self.chunks,
            self.compressions.iter().cloned().collect::<Vec<_>>().join(", "),
            mib(self.uncompressed_bytes),
            mib(self.compressed_bytes),
            self.compression_ratio()
        )?;
        writeln!(f, "Topic information:")?;
        for t in self.topics.values() {
            writeln!(
                f,
                "  Topic: {:<16} | Type: {:<16} | Count: {:>7} | Payload: {:>11} | Serialization format: {}{}",
                t.topic,
                t.type_name,
                t.messages,
                mib(t.bytes),
                t.encoding,
                if t.undecodable > 0 { format!(" | UNDECODABLE: {}", t.undecodable) } else { String::new() }
            )?;
        }
        writeln!(f, "Simulations:       {}", self.simulations.len())?;
        for ((run, sim), r) in &self.simulations {
            writeln!(f, "  run {run} simulation {sim}: steps {}..={} ({} steps)", r.first, r.last, r.steps)?;
        }
        if !self.damage.is_empty() {
            writeln!(f, "Damage:            {} region(s) skipped", self.damage.len())?;
            for d in &self.damage {
                writeln!(f, "  {d}")?;
            }
            for (topic, n) in &self.skipped {
                writeln!(f, "  lost on {topic}: {n} messages")?;
            }
        }
        if !self.recordings.is_empty() {
            writeln!(f, "Recordings:        {} concatenated in this one file", self.recordings.len() + 1)?;
            for at in &self.recordings {
                writeln!(f, "  another recording starts at byte {at}")?;
            }
        }
        if !self.summary_problems.is_empty() {
            writeln!(f, "Summary section:   {} problem(s)", self.summary_problems.len())?;
            for p in &self.summary_problems {
                writeln!(f, "  {p}")?;
            }
        }
        for (name, m) in &self.metadata {
            writeln!(f, "Metadata `{name}`:")?;
            for (k, v) in m {
                writeln!(f, "  {k}: {v}")?;
            }
        }
        Ok(())
    }
}

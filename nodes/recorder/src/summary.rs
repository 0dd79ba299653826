//! Checking a recording's summary section (footer, chunk indexes, statistics, metadata indexes,
//! summary offsets) against what its data section holds, as [`crate::read::RecordingReader`]
//! walks the file. Indexed readers (the `mcap` CLI, Foxglove, Python's `mcap`) go by the summary:
//! a wrong offset there makes them refuse the file, or lose or garble messages, although every
//! chunk is intact. Every value checked is a number read from the file, compared with what the
//! walk found; none is used to read anything.

use crate::fields::{record_name, Fields};
use mcap::records::op;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt;

/// What is wrong with a summary section: where, and what.
#[derive(Debug, Clone, PartialEq)]
pub struct SummaryProblem {
    /// Byte offset of the record at fault (the footer, a chunk index ...).
    pub offset: u64,
    pub detail: String,
}

impl fmt::Display for SummaryProblem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "at byte {}: {}", self.offset, self.detail)
    }
}

/// A chunk of the data section as found: its record's length, compression and sizes.
#[derive(Debug, Clone, PartialEq)]
struct SeenChunk {
    record_len: u64,
    compression: String,
    compressed: u64,
    uncompressed: u64,
}

/// A summary offset record: a group of records of one opcode.
struct Group {
    at: u64,
    opcode: u8,
    start: u64,
    len: u64,
}

/// One recording's data section as walked, and the checks of its summary. Offsets are absolute
/// in the file; the ones the summary states are relative to `base`, where the recording's magic
/// is (0, unless recordings were concatenated).
#[derive(Default)]
pub(crate) struct SummaryCheck {
    base: u64,
    chunks: BTreeMap<u64, SeenChunk>,
    /// Message index records: offset -> channel id.
    message_indexes: BTreeMap<u64, u16>,
    /// Metadata records: offset -> (record length, name).
    metadata: BTreeMap<u64, (u64, String)>,
    messages: u64,
    /// The end of the data end record: where the summary section starts.
    data_end: Option<u64>,
    /// The summary section's records: offset -> opcode.
    records: BTreeMap<u64, u8>,
    /// Chunks that a chunk index names.
    indexed: BTreeSet<u64>,
    chunk_indexes: u64,
    /// The statistics record: its offset, message count, chunk count and metadata count.
    statistics: Option<(u64, u64, u32, u32)>,
    groups: Vec<Group>,
    problems: Vec<SummaryProblem>,
}

impl SummaryCheck {
    /// The checks of a recording whose magic is at `base`.
    pub(crate) fn new(base: u64) -> SummaryCheck {
        SummaryCheck { base, ..Default::default() }
    }

    /// Where the recording's magic is.
    pub(crate) fn base(&self) -> u64 {
        self.base
    }

    /// An intact chunk record at `offset`, `record_len` bytes with its header.
    pub(crate) fn chunk(
        &mut self,
        offset: u64,
        record_len: u64,
        compression: &str,
        compressed: u64,
        uncompressed: u64,
    ) {
        let chunk = SeenChunk { record_len, compression: compression.to_string(), compressed, uncompressed };
        self.chunks.insert(offset, chunk);
    }

    pub(crate) fn message_index(&mut self, offset: u64, channel_id: u16) {
        self.message_indexes.insert(offset, channel_id);
    }

    pub(crate) fn metadata(&mut self, offset: u64, record_len: u64, name: &str) {
        self.metadata.insert(offset, (record_len, name.to_string()));
    }

    pub(crate) fn message(&mut self) {
        self.messages += 1;
    }

    /// The data end record ends at `end`: the summary section starts there.
    pub(crate) fn data_end(&mut self, end: u64) {
        self.data_end = Some(end);
    }

    /// Whether the content of a summary record of `opcode` is checked (and must be read).
    pub(crate) fn reads(opcode: u8) -> bool {
        matches!(opcode, op::CHUNK_INDEX | op::STATISTICS | op::METADATA_INDEX | op::SUMMARY_OFFSET)
    }

    /// Where the summary section starts as walked: after the data end record (or at the footer).
    pub(crate) fn summary_start(&self, footer_at: u64) -> u64 {
        self.data_end.unwrap_or(footer_at).min(footer_at)
    }

    fn problem(&mut self, offset: u64, detail: String) {
        self.problems.push(SummaryProblem { offset, detail });
    }

    /// A summary record at `offset`; `body` is its content when [`SummaryCheck::reads`] its opcode
    /// (`None`: too long to read).
    pub(crate) fn summary_record(&mut self, offset: u64, opcode: u8, body: Option<&[u8]>) {
        self.records.insert(offset, opcode);
        if !Self::reads(opcode) {
            return;
        }
        let Some(body) = body else {
            return self.problem(offset, format!("a {} of implausible length", record_name(opcode)));
        };
        let checked = match opcode {
            op::CHUNK_INDEX => self.chunk_index(body),
            op::STATISTICS => self.statistics(offset, body),
            op::METADATA_INDEX => self.metadata_index(body),
            _ => self.summary_offset(offset, body),
        };
        if let Err(detail) = checked {
            self.problem(offset, format!("{}: {detail}", record_name(opcode)));
        }
    }

    fn chunk_index(&mut self, body: &[u8]) -> Result<(), String> {
        let mut f = Fields::new(body);
        let _start_time = f.u64("the start time")?;
        let _end_time = f.u64("the end time")?;
        let start = f.u64("the chunk start offset")?;
        let length = f.u64("the chunk length")?;
        let offsets = int_map(&mut f, "the message index offsets")?;
        let _index_len = f.u64("the message index length")?;
        let compression = f.string("the compression")?;
        let compressed = f.u64("the compressed size")?;
        let uncompressed = f.u64("the uncompressed size")?;
        f.end("chunk index")?;
        self.chunk_indexes += 1;
        let Some((&offset, chunk)) = self.base.checked_add(start).and_then(|o| self.chunks.get_key_value(&o)) else {
            return Err(format!("its chunk start offset {start} is no intact chunk of the data section"));
        };
        let mut wrong = Vec::new();
        if length != chunk.record_len {
            wrong.push(format!("a chunk length of {length} (the chunk's record has {})", chunk.record_len));
        }
        if compression != chunk.compression || compressed != chunk.compressed || uncompressed != chunk.uncompressed {
            wrong.push(format!(
                "compression `{}`, {compressed} -> {uncompressed} bytes (the chunk says `{}`, {} -> {})",
                compression.escape_debug(),
                chunk.compression,
                chunk.compressed,
                chunk.uncompressed
            ));
        }
        for (channel, o) in offsets {
            let found = self.base.checked_add(o).and_then(|o| self.message_indexes.get(&o));
            if found != Some(&channel) {
                wrong.push(format!("channel {channel}'s message index at offset {o}, where there is none of it"));
            }
        }
        self.indexed.insert(offset);
        match wrong.is_empty() {
            true => Ok(()),
            false => Err(format!("the chunk at byte {offset}: {}", wrong.join("; "))),
        }
    }

    fn statistics(&mut self, at: u64, body: &[u8]) -> Result<(), String> {
        let mut f = Fields::new(body);
        let messages = f.u64("the message count")?;
        let _schemas = f.u16("the schema count")?;
        let _channels = f.u32("the channel count")?;
        let _attachments = f.u32("the attachment count")?;
        let metadata = f.u32("the metadata count")?;
        let chunks = f.u32("the chunk count")?;
        self.statistics = Some((at, messages, chunks, metadata));
        Ok(())
    }

    fn metadata_index(&mut self, body: &[u8]) -> Result<(), String> {
        let mut f = Fields::new(body);
        let offset = f.u64("the offset")?;
        let length = f.u64("the length")?;
        let name = f.string("the name")?;
        f.end("metadata index")?;
        match self.base.checked_add(offset).and_then(|o| self.metadata.get(&o)) {
            Some((len, n)) if *len == length && *n == name => Ok(()),
            Some((len, n)) => Err(format!(
                "metadata `{}` of {length} bytes at offset {offset}, where there is `{}` of {len}",
                name.escape_debug(),
                n.escape_debug()
            )),
            None => {
                Err(format!("metadata `{}` at offset {offset}, where there is no metadata record", name.escape_debug()))
            }
        }
    }

    fn summary_offset(&mut self, at: u64, body: &[u8]) -> Result<(), String> {
        let mut f = Fields::new(body);
        let opcode = f.array::<1>("the group opcode")?[0];
        let start = f.u64("the group start")?;
        let len = f.u64("the group length")?;
        f.end("summary offset")?;
        self.groups.push(Group { at, opcode, start, len });
        Ok(())
    }

    /// The footer at `footer_at` with its fields; `crc_matches`: whether its summary CRC checks
    /// out over the summary as walked (`None`: no CRC); `intact`: no damage was skipped in this
    /// recording (the counts can be compared). Returns the problems of this recording's summary.
    pub(crate) fn footer(
        mut self,
        footer_at: u64,
        summary_start: u64,
        summary_offset_start: u64,
        crc_matches: Option<bool>,
        intact: bool,
    ) -> Vec<SummaryProblem> {
        let base = self.base;
        let relative = |absolute: u64| absolute.saturating_sub(base);
        let walked = self.summary_start(footer_at);
        let has_summary = !self.records.is_empty();
        if self.data_end.is_none() && summary_start != 0 {
            let detail = format!("the footer's summary start is {summary_start}, but no data end record precedes it");
            self.problem(footer_at, detail);
        } else if (has_summary || summary_start != 0) && base.checked_add(summary_start) != Some(walked) {
            let detail = format!(
                "the footer's summary start is {summary_start}, but the summary section starts at offset {}",
                relative(walked)
            );
            self.problem(footer_at, detail);
        }
        let first_group = self.records.iter().find(|(_, o)| **o == op::SUMMARY_OFFSET).map_or(footer_at, |(a, _)| *a);
        if summary_offset_start != 0 && base.checked_add(summary_offset_start) != Some(first_group) {
            let detail = format!(
                "the footer's summary offset start is {summary_offset_start}, but the summary offset records start at offset {}",
                relative(first_group)
            );
            self.problem(footer_at, detail);
        }
        if crc_matches == Some(false) {
            self.problem(footer_at, "the footer's summary CRC does not match the summary section".into());
        }
        for g in std::mem::take(&mut self.groups) {
            let start = base.checked_add(g.start);
            let end = start.and_then(|s| s.checked_add(g.len));
            // An empty group (some writers list one) need only lie within the summary.
            let empty_within = g.len == 0 && start.is_some_and(|s| (walked..=footer_at).contains(&s));
            let starts_group = empty_within || start.is_some_and(|s| self.records.get(&s) == Some(&g.opcode));
            let ends_at_record = end.is_some_and(|e| e == footer_at || self.records.contains_key(&e));
            if !starts_group || !ends_at_record {
                let detail = format!(
                    "summary offset record: a group of {}s at offset {} of {} bytes, which is not where they are",
                    record_name(g.opcode),
                    g.start,
                    g.len
                );
                self.problem(g.at, detail);
            }
        }
        if self.chunk_indexes > 0 {
            let unindexed: Vec<u64> = self.chunks.keys().filter(|c| !self.indexed.contains(c)).copied().collect();
            if let Some(first) = unindexed.first() {
                let detail = format!(
                    "{} chunk(s) of the data section are in no chunk index (indexed readers skip their messages), the first at byte {first}",
                    unindexed.len()
                );
                self.problem(footer_at, detail);
            }
        }
        if let (Some((at, messages, chunks, metadata)), true) = (self.statistics, intact) {
            let counts = [
                ("messages", messages, self.messages),
                ("chunks", chunks.into(), self.chunks.len() as u64),
                ("metadata records", metadata.into(), self.metadata.len() as u64),
            ];
            for (what, stated, found) in counts {
                if stated != found {
                    self.problem(at, format!("statistics record: {stated} {what}, but the data section holds {found}"));
                }
            }
        }
        self.problems
    }
}

/// A map of `u16` keys to `u64` values (a chunk index's message index offsets).
fn int_map(f: &mut Fields, what: &str) -> Result<BTreeMap<u16, u64>, String> {
    let len = f.u32(what)?;
    let mut map = Fields::new(f.bytes(len.into(), what)?);
    let mut out = BTreeMap::new();
    while map.left() > 0 {
        let key = map.u16(what)?;
        let value = map.u64(what)?;
        out.insert(key, value);
    }
    Ok(out)
}

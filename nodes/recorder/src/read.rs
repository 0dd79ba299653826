//! Streaming a recording record by record, one chunk in memory at a time, trusting no length
//! read from the file.
//!
//! The MCAP framing (the magic, then records of `opcode: u8, length: u64 LE, content`) and the
//! records this project uses are parsed here rather than by the `mcap` crate's readers: those add
//! and allocate whatever a damaged length says (the magic followed by junk made them overflow or
//! ask for exabytes). Here every length is checked, with checked arithmetic, against the bytes
//! left (in the file, the record, the chunk) and against a cap ([`MAX_RECORD_LEN`],
//! [`MAX_CHUNK_LEN`]); memory follows the bytes actually there, never a length field; a chunk
//! is used only when its CRC (when it has one) checks out. A damaged file is an
//! [`Error::Damaged`] naming the file, the byte offset and what is wrong.
//!
//! In lenient mode ([`ReadOptions::lenient`], what `recover` and `info` use) damage is not an
//! error: the damaged record is skipped whole and reading resumes at the next intact record,
//! found by scanning forward for a plausible opcode and length whose content parses (a chunk
//! whose CRC checks out), as `mcap recover` does. What was skipped is kept in
//! [`RecordingReader::damage`] and, per topic, in [`RecordingReader::skipped`] (counted from the
//! message indexes that follow a skipped chunk).
//!
//! The file is read to its physical end: bytes after a recording's closing magic are damage,
//! unless another recording starts there (`cat a.mcap b.mcap`), which a lenient reader reads too
//! ([`RecordingReader::recordings`]) and a strict one refuses. The summary section is checked,
//! not used ([`RecordingReader::summary_problems`]).

use crate::fields::{record_name, Fields};
use crate::summary::{SummaryCheck, SummaryProblem};
use crate::{Error, FrameKind, Result, MESSAGE_ENCODING, META_TYPE, META_WIRE_VERSION};
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::fmt;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The longest record accepted (1 GiB; a chunk of this project holds about 1 MiB).
pub const MAX_RECORD_LEN: u64 = 1 << 30;
/// The largest uncompressed chunk accepted (1 GiB).
pub const MAX_CHUNK_LEN: u64 = 1 << 30;
/// The longest record other than a chunk that a forward scan for an intact record considers.
const MAX_SCANNED_RECORD_LEN: u64 = 16 << 20;
/// The profile `RecordingWriter` writes: in such a file an unknown opcode is damage.
const OWN_PROFILE: &str = "deep-contact";
/// The read buffer over the file.
const READ_BUFFER_LEN: usize = 1 << 16;

/// MCAP opcodes (the `mcap` crate's `records::op`, under their names in the specification).
mod op {
    pub use mcap::records::op::*;
    /// Opcodes from here to 0xff are left to a writer's own records.
    pub const FIRST_PRIVATE: u8 = 0x80;
}

/// Bytes of the magic at each end of a file.
const MAGIC_LEN: u64 = mcap::MAGIC.len() as u64;
/// Bytes of a record's header: `opcode: u8, length: u64` (the length of the content after it).
const RECORD_HEADER_LEN: u64 = 9;
/// Bytes of a data end record's content: `data_section_crc: u32`.
const DATA_END_LEN: u64 = 4;
/// Bytes of a footer record's content: `summary_start: u64, summary_offset_start: u64,
/// summary_crc: u32`.
const FOOTER_LEN: u64 = 20;
/// Bytes of the footer record that its CRC covers after the summary: its header,
/// `summary_start` and `summary_offset_start` (all but the CRC itself).
const FOOTER_CRC_LEN: u64 = RECORD_HEADER_LEN + FOOTER_LEN - 4;
/// Bytes of a message record's fields before its data ([`MessageHeader`]).
const MESSAGE_HEADER_LEN: u64 = 22;
/// Bytes of a message index record's fields before its entries ([`MessageIndexHeader`]).
const MESSAGE_INDEX_HEADER_LEN: u64 = 6;
/// Bytes of a message index entry: `log_time: u64, offset: u64`.
const MESSAGE_INDEX_ENTRY_LEN: u32 = 16;
/// The shortest content of a header, channel, schema or metadata record (that of a header or a
/// metadata record holding two empty strings).
const MIN_DESCRIPTIVE_LEN: u64 = 8;

/// A channel of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Channel {
    pub id: u16,
    pub topic: String,
    pub encoding: String,
    pub metadata: BTreeMap<String, String>,
    /// The frame type; `None` for a channel this project did not write (not `cbor`, no known type).
    pub kind: Option<FrameKind>,
}

/// A message: its channel, times (ns since the epoch) and CBOR payload.
#[derive(Debug, Clone)]
pub struct Message {
    pub channel: Arc<Channel>,
    pub sequence: u32,
    pub log_time: u64,
    pub publish_time: u64,
    pub data: Vec<u8>,
}

/// What a recording's data section holds, in file order.
#[derive(Debug, Clone)]
pub enum Item {
    Channel(Arc<Channel>),
    Message(Message),
    Metadata(mcap::records::Metadata),
    /// An intact chunk was read: its sizes and compression (before the messages it holds).
    Chunk {
        compression: String,
        compressed: u64,
        uncompressed: u64,
    },
}

/// How to read a file.
#[derive(Debug, Clone, Copy, Default)]
pub struct ReadOptions {
    /// Accept a channel whose wire version differs from this build's (recovery copies bytes only).
    pub any_wire_version: bool,
    /// Skip damage and resume at the next intact record instead of stopping with an error
    /// (see [`RecordingReader::damage`]).
    pub lenient: bool,
}

/// A damaged region that a lenient reader skipped.
#[derive(Debug, Clone, PartialEq)]
pub struct Damage {
    /// Byte offset of the damaged record (of the end of the file for a file without a footer).
    pub offset: u64,
    /// The opcode the damaged record claimed (`None`: the file ended inside a record header).
    pub opcode: Option<u8>,
    /// What is wrong.
    pub detail: String,
    /// Where reading resumed (the next intact record); `None` when nothing intact followed.
    pub resumed_at: Option<u64>,
    /// Messages the skipped region held, per topic, as far as the message indexes after it tell.
    pub messages: BTreeMap<String, u64>,
}

impl Damage {
    /// What kind of record was damaged, in words.
    pub fn what(&self) -> &'static str {
        self.opcode.map_or("record header", record_name)
    }

    /// Whether the damaged record was (or may have been: its opcode is lost) a chunk.
    pub fn may_be_chunk(&self) -> bool {
        // At byte 0 only the magic can be damaged.
        self.offset > 0 && self.opcode.is_none_or(|o| o == op::CHUNK || !is_known(o))
    }

    /// The strict reader's error for this damage.
    pub fn to_error(&self, path: &Path) -> Error {
        Error::Damaged { path: path.to_path_buf(), offset: self.offset, detail: self.detail.clone() }
    }

    /// Bytes skipped, given the file's size.
    pub fn skipped_bytes(&self, file_size: u64) -> u64 {
        self.resumed_at.unwrap_or(file_size).saturating_sub(self.offset)
    }
}

impl fmt::Display for Damage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "at byte {}: {}", self.offset, self.detail)?;
        match self.resumed_at {
            Some(at) => write!(f, "; resumed at byte {at} ({} bytes skipped)", at.saturating_sub(self.offset))?,
            None => write!(f, "; nothing intact after it")?,
        }
        if !self.messages.is_empty() {
            let n: u64 = self.messages.values().sum();
            let per: Vec<String> = self.messages.iter().map(|(t, n)| format!("{t} {n}")).collect();
            write!(f, "; {n} messages lost ({})", per.join(", "))?;
        }
        Ok(())
    }
}

/// What [`RecordingReader::from_source`] reads from: a file, or bytes in memory.
pub trait Source: Read + Seek + Send + Sync {}
impl<S: Read + Seek + Send + Sync> Source for S {}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// In the data section.
    Data,
    /// After the data end record: only the footer is read.
    Summary,
    Done,
}

/// A record that does not parse: where, which, and why.
#[derive(Debug)]
struct Fault {
    offset: u64,
    opcode: Option<u8>,
    detail: String,
}

/// Why reading a record stopped: damage (skipped in lenient mode) or an error that ends reading.
enum Stop {
    Fault(Fault),
    Error(Error),
}

/// A channel record as stored.
#[derive(Debug, Clone)]
struct RawChannel {
    id: u16,
    topic: String,
    encoding: String,
    metadata: BTreeMap<String, String>,
}

/// A record's header.
#[derive(Debug, Clone, Copy)]
struct RecordHeader {
    opcode: u8,
    length: u64,
}

impl RecordHeader {
    fn parse(bytes: &[u8; RECORD_HEADER_LEN as usize]) -> RecordHeader {
        let [opcode, length @ ..] = *bytes;
        RecordHeader { opcode, length: u64::from_le_bytes(length) }
    }
}

/// A message record's fields before its data.
#[derive(Debug, Clone, Copy)]
struct MessageHeader {
    channel_id: u16,
    sequence: u32,
    log_time: u64,
    publish_time: u64,
}

/// A message index record's fields before its entries.
struct MessageIndexHeader {
    channel_id: u16,
    /// Bytes of the entries that follow.
    records_len: u32,
}

impl MessageIndexHeader {
    fn read(f: &mut Fields) -> Result<MessageIndexHeader, String> {
        Ok(MessageIndexHeader { channel_id: f.u16("the channel id")?, records_len: f.u32("the index entries")? })
    }
}

/// A message index record: the channel and how many messages of it the chunk before holds.
struct MessageIndex {
    channel_id: u16,
    entries: u64,
}

/// A chunk record's fields before its compressed records.
struct ChunkHeader {
    uncompressed_size: u64,
    /// CRC-32 of the decompressed records; 0: none.
    uncompressed_crc: u32,
    compression: String,
    compressed_size: u64,
}

impl ChunkHeader {
    fn read(f: &mut Fields) -> Result<ChunkHeader, String> {
        let _message_start_time = f.u64("the start time")?;
        let _message_end_time = f.u64("the end time")?;
        Ok(ChunkHeader {
            uncompressed_size: f.u64("the uncompressed size")?,
            uncompressed_crc: f.u32("the CRC")?,
            compression: f.string("the compression")?,
            compressed_size: f.u64("the compressed size")?,
        })
    }
}

/// A footer record's fields.
struct Footer {
    summary_start: u64,
    summary_offset_start: u64,
    /// CRC-32 of the summary section and the footer's fields before it; 0: none.
    summary_crc: u32,
}

/// A record inside a chunk that this reader uses.
enum Inner {
    Channel(RawChannel),
    Message(MessageHeader, Vec<u8>),
}

/// A chunk that decompressed, checked out and parsed.
struct ParsedChunk {
    header: ChunkHeader,
    records: Vec<Inner>,
}

/// Reads a recording from start to end with bounded memory: records are read one at a time (a
/// chunk is decompressed whole, one at a time). Every error names the file.
pub struct RecordingReader {
    path: PathBuf,
    source: BufReader<Box<dyn Source>>,
    size: u64,
    /// Where the source's read position is (`u64::MAX`: unknown, after a failed seek).
    at: u64,
    /// Start of the next record.
    pos: u64,
    state: State,
    pending: VecDeque<Item>,
    channels: HashMap<u16, Arc<Channel>>,
    options: ReadOptions,
    /// The header names another writer's profile: unknown opcodes are extensions, not damage.
    foreign: bool,
    damage: Vec<Damage>,
    skipped: BTreeMap<String, u64>,
    /// The message indexes being read belong to a skipped chunk: they count lost messages.
    counting_skipped: bool,
    /// The summary section's channels (lenient mode: for messages whose declaration was lost).
    summary_channels: Option<HashMap<u16, RawChannel>>,
    /// The channels the writer repeated outside the chunks ([`crate::CHANNELS_METADATA`]), for
    /// the same use in a file without a summary (a killed recording).
    repeated_channels: HashMap<u16, RawChannel>,
    /// The current recording's data section as walked, to check its summary against.
    summary: SummaryCheck,
    /// What is wrong with the summary sections read so far.
    summary_problems: Vec<SummaryProblem>,
    /// Where each recording after the first starts (files concatenated; lenient mode).
    recordings: Vec<u64>,
    /// Reading is just past a recording's closing magic: only another recording may follow.
    after_end: bool,
    /// Where the last MCAP magic read ends (a header record belongs there).
    magic_end: Option<u64>,
    /// A header record was read: another one starts another recording.
    header_seen: bool,
}

impl RecordingReader {
    /// Opens `path` for strict reading, checking the MCAP magic.
    pub fn open(path: &Path) -> Result<RecordingReader> {
        Self::open_with(path, ReadOptions::default())
    }

    /// Only a regular file is opened: a folder, a FIFO, a device (`/dev/zero`) or a socket is
    /// refused by its kind ([`Error::NotMcap`]) before anything is read.
    pub fn open_with(path: &Path, options: ReadOptions) -> Result<RecordingReader> {
        let file = match runtime::files::open_regular(path, "recording") {
            Ok(file) => file,
            Err(runtime::files::UserFileError::NotRegular { kind, .. }) => {
                return Err(Error::NotMcap { path: path.to_path_buf(), detail: kind.into() })
            }
            Err(e) => return Err(Error::Io { path: path.to_path_buf(), source: e.into() }),
        };
        Self::from_source(path, file, options)
    }

    /// Reads `source` (a file, `std::io::Cursor` over bytes in memory ...); `name` is the path that
    /// errors name.
    pub fn from_source(
        name: &Path,
        mut source: impl Source + 'static,
        options: ReadOptions,
    ) -> Result<RecordingReader> {
        let io = |source| Error::Io { path: name.to_path_buf(), source };
        let size = source.seek(SeekFrom::End(0)).map_err(io)?;
        source.seek(SeekFrom::Start(0)).map_err(io)?;
        let mut reader = RecordingReader {
            path: name.to_path_buf(),
            source: BufReader::with_capacity(READ_BUFFER_LEN, Box::new(source)),
            size,
            at: 0,
            pos: 0,
            state: State::Data,
            pending: VecDeque::new(),
            channels: HashMap::new(),
            options,
            foreign: false,
            damage: Vec::new(),
            skipped: BTreeMap::new(),
            counting_skipped: false,
            summary_channels: None,
            repeated_channels: HashMap::new(),
            summary: SummaryCheck::new(0),
            summary_problems: Vec::new(),
            recordings: Vec::new(),
            after_end: false,
            magic_end: None,
            header_seen: false,
        };
        reader.start()?;
        Ok(reader)
    }

    /// Checks the magic; a lenient reader looks past a damaged one for the first intact record.
    fn start(&mut self) -> Result<()> {
        let n = self.size.min(MAGIC_LEN) as usize;
        let mut magic = vec![0u8; n];
        self.read_at(0, &mut magic).map_err(|e| self.io(e))?;
        if magic == mcap::MAGIC {
            self.pos = MAGIC_LEN;
            self.magic_end = Some(MAGIC_LEN);
            return Ok(());
        }
        let detail = format!("the first {n} bytes are not the MCAP magic");
        if self.options.lenient {
            if let Some(at) = self.resync(0).map_err(|e| self.io(e))? {
                self.note_damage(Fault { offset: 0, opcode: None, detail }, Some(at));
                self.pos = at;
                return Ok(());
            }
        }
        Err(Error::NotMcap { path: self.path.clone(), detail })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Size of the file in bytes.
    pub fn size(&self) -> u64 {
        self.size
    }

    /// The channels seen so far, by id.
    pub fn channels(&self) -> &HashMap<u16, Arc<Channel>> {
        &self.channels
    }

    /// Bytes of the file read so far (the start of the next record).
    pub fn consumed(&self) -> u64 {
        self.pos
    }

    /// The damaged regions skipped so far (lenient mode), in file order.
    pub fn damage(&self) -> &[Damage] {
        &self.damage
    }

    /// Messages known to be lost in skipped regions, per topic (or `channel N (undeclared)` for
    /// messages whose channel declaration was lost), so far.
    pub fn skipped(&self) -> &BTreeMap<String, u64> {
        &self.skipped
    }

    /// What is wrong with the summary sections read so far (footer offsets, chunk indexes,
    /// statistics ...: what indexed readers go by), in file order. Not an error of the reader:
    /// the data section is read whole either way.
    pub fn summary_problems(&self) -> &[SummaryProblem] {
        &self.summary_problems
    }

    /// Where each recording after the first starts (its MCAP magic, or its header record when
    /// the magic was lost): files concatenated, as `cat a.mcap b.mcap` makes. A lenient reader
    /// reads them all; a strict one stops with an error where the second starts.
    pub fn recordings(&self) -> &[u64] {
        &self.recordings
    }

    /// The next item of the data section; `None` after the footer. After an error it returns `None`.
    pub fn next_item(&mut self) -> Option<Result<Item>> {
        loop {
            if let Some(item) = self.pending.pop_front() {
                return Some(Ok(item));
            }
            if self.state == State::Done {
                return None;
            }
            if let Err(e) = self.fill() {
                self.state = State::Done;
                self.pending.clear();
                return Some(Err(e));
            }
        }
    }

    /// The next message (channels and metadata are taken in on the way).
    pub fn next_message(&mut self) -> Option<Result<Message>> {
        loop {
            match self.next_item()? {
                Ok(Item::Message(m)) => return Some(Ok(m)),
                Ok(_) => continue,
                Err(e) => return Some(Err(e)),
            }
        }
    }

    /// Reads records until at least one item is pending or the file ended.
    fn fill(&mut self) -> Result<()> {
        while self.pending.is_empty() && self.state != State::Done {
            match self.step() {
                Ok(()) => {}
                Err(Stop::Error(e)) => return Err(e),
                Err(Stop::Fault(fault)) if !self.options.lenient => {
                    return Err(Error::Damaged { path: self.path.clone(), offset: fault.offset, detail: fault.detail })
                }
                Err(Stop::Fault(fault)) => self.skip_damage(fault)?,
            }
        }
        Ok(())
    }

    /// Skips a damaged record: resumes at the next intact one, or ends.
    fn skip_damage(&mut self, fault: Fault) -> Result<()> {
        let resumed = if self.state == State::Data && fault.offset < self.size {
            self.resync(fault.offset + 1).map_err(|e| self.io(e))?
        } else {
            None
        };
        // The message indexes after a skipped chunk (or after a record whose opcode is lost)
        // say what it held.
        self.counting_skipped = !matches!(fault.opcode, Some(o) if o != op::CHUNK && is_known(o));
        self.note_damage(fault, resumed);
        match resumed {
            Some(at) => self.pos = at,
            None => self.state = State::Done,
        }
        Ok(())
    }

    fn note_damage(&mut self, fault: Fault, resumed_at: Option<u64>) {
        let damage = Damage {
            offset: fault.offset,
            opcode: fault.opcode,
            detail: fault.detail,
            resumed_at,
            messages: BTreeMap::new(),
        };
        tracing::warn!(path = %self.path.display(), "skipped damage: {damage}");
        self.damage.push(damage);
    }

    fn io(&self, source: std::io::Error) -> Error {
        Error::Io { path: self.path.clone(), source }
    }

    /// Reads and takes in the record at `pos`.
    fn step(&mut self) -> Result<(), Stop> {
        let offset = self.pos;
        let left = self.size.saturating_sub(offset);
        let fault = |opcode, detail: String| Stop::Fault(Fault { offset, opcode, detail });
        // The record header, or as much of it as the file holds, read once: it may be a magic.
        let mut head = [0u8; RECORD_HEADER_LEN as usize];
        let head_len = left.min(RECORD_HEADER_LEN) as usize;
        self.read_at(offset, &mut head[..head_len]).map_err(|e| Stop::Error(self.io(e)))?;
        let is_magic = head[..head_len].starts_with(mcap::MAGIC);
        if std::mem::take(&mut self.after_end) && !is_magic {
            let detail =
                format!("{left} bytes after the recording's closing magic, and they are not another recording");
            return Err(fault(None, detail));
        }
        if is_magic {
            return self.start_recording(offset);
        }
        if left == 0 {
            let detail = "the file ends here without a footer (its writer did not finish)".to_string();
            return Err(fault(None, detail));
        }
        if left < RECORD_HEADER_LEN {
            return Err(fault(None, format!("the file ends inside a record header ({left} bytes left)")));
        }
        let RecordHeader { opcode, length: len } = RecordHeader::parse(&head);
        check_len(opcode, len, left - RECORD_HEADER_LEN).map_err(|d| fault(Some(opcode), d))?;
        let body_at = offset + RECORD_HEADER_LEN;
        let end = body_at + len; // <= size, checked above
        if self.state == State::Summary && opcode != op::FOOTER {
            // The summary repeats what the data section holds: only its indexes are read, to
            // check them against what the data section held.
            let mut body = Vec::new();
            let readable = SummaryCheck::reads(opcode) && len <= MAX_SCANNED_RECORD_LEN;
            if readable {
                body.resize(len as usize, 0);
                self.read_at(body_at, &mut body).map_err(|e| Stop::Error(self.io(e)))?;
            }
            self.summary.summary_record(offset, opcode, readable.then_some(&body[..]));
            self.pos = end;
            return Ok(());
        }
        let mut body = vec![0u8; len as usize];
        self.read_at(body_at, &mut body).map_err(|e| Stop::Error(self.io(e)))?;
        self.take(offset, opcode, &body)?;
        self.pos = end;
        if opcode == op::FOOTER {
            self.check_end_magic(end)?;
            // Past the closing magic: the end of the file, or another recording (or junk).
            self.pos = end + MAGIC_LEN;
            self.state = if self.pos == self.size { State::Done } else { State::Data };
            self.after_end = self.state == State::Data;
        }
        Ok(())
    }

    /// Whether the MCAP magic is at `offset`.
    fn magic_at(&mut self, offset: u64) -> std::io::Result<bool> {
        if self.size.saturating_sub(offset) < MAGIC_LEN {
            return Ok(false);
        }
        let mut magic = [0u8; MAGIC_LEN as usize];
        self.read_at(offset, &mut magic)?;
        Ok(magic == *mcap::MAGIC)
    }

    /// Another recording starts at `offset` (its magic there, or its header record when the magic
    /// was lost): a lenient reader reads it as well and notes where it starts; for a strict one it
    /// is damage.
    fn new_recording(&mut self, offset: u64) -> Result<(), Stop> {
        if !self.options.lenient {
            let detail = "another MCAP recording starts here (files concatenated?): readers that go by the \
                          summary see only one of them; `dc-record recover IN OUT` keeps both"
                .to_string();
            return Err(Stop::Fault(Fault { offset, opcode: None, detail }));
        }
        tracing::warn!(path = %self.path.display(), "another recording starts at byte {offset}");
        self.recordings.push(offset);
        self.summary = SummaryCheck::new(offset);
        self.state = State::Data;
        Ok(())
    }

    /// The MCAP magic at `offset`, where a record was expected: another recording starts.
    fn start_recording(&mut self, offset: u64) -> Result<(), Stop> {
        self.new_recording(offset)?;
        self.pos = offset + MAGIC_LEN;
        self.magic_end = Some(self.pos);
        Ok(())
    }

    /// The footer at `offset`: its offsets and CRC checked against the summary as walked.
    fn take_footer(&mut self, offset: u64, footer: Footer) -> Result<(), Stop> {
        let crc_matches = match footer.summary_crc {
            0 => None,
            stored => {
                let from = self.summary.summary_start(offset);
                let to = offset + FOOTER_CRC_LEN;
                Some(self.crc_between(from, to).map_err(|e| Stop::Error(self.io(e)))? == stored)
            }
        };
        let base = self.summary.base();
        let intact = !self.damage.iter().any(|d| d.offset >= base);
        let check = std::mem::replace(&mut self.summary, SummaryCheck::new(offset));
        let problems = check.footer(offset, footer.summary_start, footer.summary_offset_start, crc_matches, intact);
        for p in &problems {
            tracing::warn!(path = %self.path.display(), "summary section: {p}");
        }
        self.summary_problems.extend(problems);
        Ok(())
    }

    /// CRC-32 of the bytes `from..to` of the file (within it: callers check), read in pieces.
    fn crc_between(&mut self, from: u64, to: u64) -> std::io::Result<u32> {
        let mut hasher = crc32fast::Hasher::new();
        let mut buf = vec![0u8; READ_BUFFER_LEN.min(to.saturating_sub(from) as usize)];
        let mut at = from;
        while at < to {
            let n = (to - at).min(buf.len() as u64) as usize;
            self.read_at(at, &mut buf[..n])?;
            hasher.update(&buf[..n]);
            at += n as u64;
        }
        Ok(hasher.finalize())
    }

    fn check_end_magic(&mut self, at: u64) -> Result<(), Stop> {
        let fault = |detail: String| Stop::Fault(Fault { offset: at, opcode: None, detail });
        if self.size - at < MAGIC_LEN {
            return Err(fault(format!(
                "the file ends {} bytes after its footer, before the closing magic",
                self.size - at
            )));
        }
        if !self.magic_at(at).map_err(|e| Stop::Error(self.io(e)))? {
            return Err(fault("no MCAP magic after the footer".into()));
        }
        Ok(())
    }

    /// Takes in one record of the data section.
    fn take(&mut self, offset: u64, opcode: u8, body: &[u8]) -> Result<(), Stop> {
        let fault = |detail: String| {
            Stop::Fault(Fault { offset, opcode: Some(opcode), detail: format!("{}: {detail}", record_name(opcode)) })
        };
        if opcode != op::MESSAGE_INDEX {
            self.counting_skipped = false;
        }
        match opcode {
            op::HEADER => self.take_header(offset, parse_header(body).map_err(fault)?)?,
            op::CHUNK => {
                let chunk = parse_chunk(body).map_err(fault)?;
                let h = &chunk.header;
                let record_len = RECORD_HEADER_LEN + body.len() as u64;
                self.summary.chunk(offset, record_len, &h.compression, h.compressed_size, h.uncompressed_size);
                self.take_chunk(offset, chunk)?
            }
            op::CHANNEL => self.add_channel(parse_channel(body).map_err(fault)?)?,
            op::MESSAGE => {
                let (header, data) = parse_message(body).map_err(fault)?;
                self.add_message(offset, header, data.to_vec())?;
            }
            op::SCHEMA => parse_schema(body).map_err(fault)?,
            op::METADATA => {
                let metadata = parse_metadata(body).map_err(fault)?;
                self.summary.metadata(offset, RECORD_HEADER_LEN + body.len() as u64, &metadata.name);
                self.take_metadata(metadata)
            }
            op::MESSAGE_INDEX => {
                let index = parse_message_index(body).map_err(fault)?;
                self.summary.message_index(offset, index.channel_id);
                self.take_message_index(index)
            }
            op::DATA_END => {
                parse_data_end(body).map_err(fault)?;
                self.summary.data_end(offset + RECORD_HEADER_LEN + DATA_END_LEN);
                self.state = State::Summary;
            }
            op::FOOTER => self.take_footer(offset, parse_footer(body).map_err(fault)?)?,
            op::ATTACHMENT
            | op::ATTACHMENT_INDEX
            | op::CHUNK_INDEX
            | op::STATISTICS
            | op::METADATA_INDEX
            | op::SUMMARY_OFFSET => {}
            other if other >= op::FIRST_PRIVATE && self.foreign => {} // another writer's extension
            other => {
                return Err(fault(format!("0x{other:02x} is no MCAP opcode (this file's writer uses none of its own)")))
            }
        }
        Ok(())
    }

    /// A header record: whose profile the file has. A second one, not right after a magic, starts
    /// another recording whose magic was lost.
    fn take_header(&mut self, offset: u64, header: mcap::records::Header) -> Result<(), Stop> {
        if self.header_seen && self.magic_end != Some(offset) {
            self.new_recording(offset)?;
        }
        self.header_seen = true;
        self.foreign = header.profile != OWN_PROFILE;
        Ok(())
    }

    /// An intact chunk: its sizes, then the channels and messages it holds.
    fn take_chunk(&mut self, offset: u64, chunk: ParsedChunk) -> Result<(), Stop> {
        let ChunkHeader { compression, compressed_size, uncompressed_size, .. } = chunk.header;
        self.pending.push_back(Item::Chunk {
            compression,
            compressed: compressed_size,
            uncompressed: uncompressed_size,
        });
        for record in chunk.records {
            match record {
                Inner::Channel(c) => self.add_channel(c)?,
                Inner::Message(header, data) => self.add_message(offset, header, data)?,
            }
        }
        Ok(())
    }

    /// A metadata record: the recording's metadata, or the writer's repetition of its channels.
    fn take_metadata(&mut self, metadata: mcap::records::Metadata) {
        if metadata.name == crate::CHANNELS_METADATA {
            // The format's own bookkeeping, not the recording's metadata.
            self.repeated_channels.extend(repeated_channels(&metadata.metadata));
        } else {
            self.pending.push_back(Item::Metadata(metadata));
        }
    }

    /// A message index record: after a skipped chunk, it counts the messages lost.
    fn take_message_index(&mut self, index: MessageIndex) {
        if !self.counting_skipped {
            return;
        }
        let topic = self.topic_name(index.channel_id);
        *self.skipped.entry(topic.clone()).or_default() += index.entries;
        if let Some(last) = self.damage.last_mut() {
            *last.messages.entry(topic).or_default() += index.entries;
        }
    }

    /// The topic of a channel id for reports.
    fn topic_name(&mut self, id: u16) -> String {
        if let Some(c) = self.channels.get(&id) {
            return c.topic.clone();
        }
        match self.summary_channel(id) {
            Some(c) => c.topic,
            None => format!("channel {id} (undeclared)"),
        }
    }

    fn add_channel(&mut self, c: RawChannel) -> Result<(), Stop> {
        let channel = self.channel(c).map_err(Stop::Error)?;
        if self.channels.get(&channel.id).is_none_or(|old| **old != *channel) {
            self.channels.insert(channel.id, channel.clone());
            self.pending.push_back(Item::Channel(channel));
        }
        Ok(())
    }

    fn add_message(&mut self, offset: u64, header: MessageHeader, data: Vec<u8>) -> Result<(), Stop> {
        let id = header.channel_id;
        if !self.channels.contains_key(&id) {
            if !self.options.lenient {
                let detail = format!("a message on channel {id} that was never declared");
                return Err(Stop::Fault(Fault { offset, opcode: Some(op::MESSAGE), detail }));
            }
            // Its declaration was in a skipped region: the summary or the writer's repetition
            // outside the chunks may still have it.
            match self.summary_channel(id).or_else(|| self.repeated_channels.get(&id).cloned()) {
                Some(c) => self.add_channel(c)?,
                None => {
                    *self.skipped.entry(format!("channel {id} (undeclared)")).or_default() += 1;
                    return Ok(());
                }
            }
        }
        let channel = self.channels[&id].clone();
        self.summary.message();
        self.pending.push_back(Item::Message(Message {
            channel,
            sequence: header.sequence,
            log_time: header.log_time,
            publish_time: header.publish_time,
            data,
        }));
        Ok(())
    }

    fn channel(&self, c: RawChannel) -> Result<Arc<Channel>> {
        let kind = if c.encoding == MESSAGE_ENCODING {
            c.metadata
                .get(META_TYPE)
                .and_then(|t| FrameKind::from_type_name(t))
                .or_else(|| FrameKind::of_topic(&c.topic))
        } else {
            None
        };
        if kind.is_some() && !self.options.any_wire_version {
            if let Some(v) = c.metadata.get(META_WIRE_VERSION) {
                if !v.parse::<u32>().is_ok_and(|v| (msgs::OLDEST_WIRE_VERSION..=msgs::WIRE_VERSION).contains(&v)) {
                    return Err(Error::WireVersion {
                        path: self.path.clone(),
                        topic: c.topic.clone(),
                        found: v.clone(),
                        expected: msgs::WIRE_VERSION,
                    });
                }
            }
        }
        Ok(Arc::new(Channel { id: c.id, topic: c.topic, encoding: c.encoding, metadata: c.metadata, kind }))
    }

    /// A channel of the summary section (read once, best effort; lenient mode only).
    fn summary_channel(&mut self, id: u16) -> Option<RawChannel> {
        if !self.options.lenient {
            return None;
        }
        if self.summary_channels.is_none() {
            let channels = self.read_summary_channels().unwrap_or_default();
            self.summary_channels = Some(channels);
        }
        self.summary_channels.as_ref().and_then(|c| c.get(&id).cloned())
    }

    /// The channel records of an intact summary section, found through the footer.
    fn read_summary_channels(&mut self) -> std::io::Result<HashMap<u16, RawChannel>> {
        const FOOTER_RECORD_LEN: u64 = RECORD_HEADER_LEN + FOOTER_LEN;
        let mut out = HashMap::new();
        // The footer record, then the closing magic.
        let Some(footer_at) = self.size.checked_sub(FOOTER_RECORD_LEN + MAGIC_LEN) else { return Ok(out) };
        let mut tail = [0u8; (FOOTER_RECORD_LEN + MAGIC_LEN) as usize];
        self.read_at(footer_at, &mut tail)?;
        let (head, rest) = tail.split_first_chunk().expect("a record header");
        let (body, magic) = rest.split_at(FOOTER_LEN as usize);
        let head = RecordHeader::parse(head);
        let is_footer = head.opcode == op::FOOTER && head.length == FOOTER_LEN && magic == mcap::MAGIC;
        let Some(footer) = parse_footer(body).ok().filter(|_| is_footer) else { return Ok(out) };
        let mut at = footer.summary_start;
        if at < MAGIC_LEN || at > footer_at {
            return Ok(out);
        }
        while at + RECORD_HEADER_LEN <= footer_at {
            let head = self.read_record_header(at)?;
            let body_at = at + RECORD_HEADER_LEN;
            if head.length > footer_at - body_at || head.length > MAX_SCANNED_RECORD_LEN {
                break;
            }
            if head.opcode == op::CHANNEL {
                let mut body = vec![0u8; head.length as usize];
                self.read_at(body_at, &mut body)?;
                if let Ok(c) = parse_channel(&body) {
                    out.insert(c.id, c);
                }
            }
            at = body_at + head.length;
        }
        Ok(out)
    }

    /// Reads the record header at `offset` (within the file: callers check).
    fn read_record_header(&mut self, offset: u64) -> std::io::Result<RecordHeader> {
        let mut head = [0u8; RECORD_HEADER_LEN as usize];
        self.read_at(offset, &mut head)?;
        Ok(RecordHeader::parse(&head))
    }

    /// Reads `buf.len()` bytes at `offset` (within the file: callers check).
    fn read_at(&mut self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
        if offset != self.at {
            let moved = i64::try_from(offset as i128 - self.at as i128).ok().filter(|_| self.at != u64::MAX);
            self.at = u64::MAX;
            match moved {
                Some(delta) => self.source.seek_relative(delta)?,
                None => {
                    self.source.seek(SeekFrom::Start(offset))?;
                }
            }
        }
        self.at = u64::MAX;
        self.source.read_exact(buf)?;
        self.at = offset + buf.len() as u64;
        Ok(())
    }

    /// The offset of the first intact record at or after `from`, scanning forward: a plausible
    /// opcode and length (cheap checks on a window of the file), then the whole record parsed (a
    /// chunk decompressed and its CRC checked).
    fn resync(&mut self, from: u64) -> std::io::Result<Option<u64>> {
        const WINDOW: u64 = 1 << 16;
        // Bytes a cheap check may look at past a candidate's offset.
        const LOOKAHEAD: u64 = 128;
        let mut window: Vec<u8> = Vec::new();
        let mut window_start = from;
        let mut p = from;
        while p.saturating_add(RECORD_HEADER_LEN) <= self.size {
            let want = LOOKAHEAD.min(self.size - p);
            if p < window_start || p + want > window_start + window.len() as u64 {
                let n = WINDOW.min(self.size - p) as usize;
                window.resize(n, 0);
                self.read_at(p, &mut window)?;
                window_start = p;
            }
            let w = &window[(p - window_start) as usize..];
            if self.plausible(p, w) && self.intact(p)? {
                return Ok(Some(p));
            }
            p += 1;
        }
        Ok(None)
    }

    /// Cheap checks of a candidate record at `p` whose first bytes are `w` (at least 128, or up
    /// to the end of the file).
    fn plausible(&self, p: u64, w: &[u8]) -> bool {
        let RecordHeader { opcode, length: len } = RecordHeader::parse(w.first_chunk().expect("a record header"));
        let left = self.size - p - RECORD_HEADER_LEN;
        if len > left || len > MAX_RECORD_LEN {
            return false;
        }
        let small = len <= MAX_SCANNED_RECORD_LEN;
        // The fields of the content that are in `w` (it may end before the record does).
        let mut content = Fields::new(&w[RECORD_HEADER_LEN as usize..]);
        match opcode {
            op::CHUNK => match ChunkHeader::read(&mut content) {
                Ok(chunk) => {
                    let header_len = content.position() as u64;
                    matches!(chunk.compression.as_str(), "" | "zstd" | "lz4")
                        && len.checked_sub(header_len).is_some_and(|rest| chunk.compressed_size <= rest)
                        && chunk.uncompressed_size <= MAX_CHUNK_LEN
                }
                Err(_) => false,
            },
            op::MESSAGE_INDEX => {
                len >= MESSAGE_INDEX_HEADER_LEN
                    && small
                    && MessageIndexHeader::read(&mut content).is_ok_and(|h| {
                        u64::from(h.records_len) == len - MESSAGE_INDEX_HEADER_LEN
                            && h.records_len % MESSAGE_INDEX_ENTRY_LEN == 0
                    })
            }
            op::DATA_END => len == DATA_END_LEN,
            op::FOOTER => len == FOOTER_LEN && left >= FOOTER_LEN + MAGIC_LEN,
            op::MESSAGE => {
                len >= MESSAGE_HEADER_LEN && content.u16("the channel id").is_ok_and(|id| self.knows_channel(id))
            }
            op::HEADER | op::CHANNEL | op::SCHEMA | op::METADATA => len >= MIN_DESCRIPTIVE_LEN && small,
            _ => false,
        }
    }

    /// Whether channel `id` was declared so far, in the summary or in the writer's repetition.
    fn knows_channel(&self, id: u16) -> bool {
        self.channels.contains_key(&id)
            || self.summary_channels.as_ref().is_some_and(|c| c.contains_key(&id))
            || self.repeated_channels.contains_key(&id)
    }

    /// Whether the record at `p` (plausible) parses whole; a record with no CRC or little
    /// structure must also be followed by a plausible record header (or the end of the file).
    fn intact(&mut self, p: u64) -> std::io::Result<bool> {
        let RecordHeader { opcode, length: len } = self.read_record_header(p)?;
        let body_at = p + RECORD_HEADER_LEN;
        let end = body_at + len;
        if opcode == op::FOOTER {
            return self.magic_at(end);
        }
        let mut body = vec![0u8; len as usize];
        self.read_at(body_at, &mut body)?;
        let parses = match opcode {
            op::CHUNK => match parse_chunk(&body) {
                // A chunk with a CRC that checks out stands on its own.
                Ok(chunk) if chunk.header.uncompressed_crc != 0 => return Ok(true),
                Ok(_) => true,
                Err(_) => false,
            },
            op::HEADER => parse_header(&body).is_ok(),
            op::CHANNEL => parse_channel(&body).is_ok(),
            op::SCHEMA => parse_schema(&body).is_ok(),
            op::METADATA => parse_metadata(&body).is_ok(),
            op::MESSAGE_INDEX => parse_message_index(&body).is_ok(),
            _ => true,
        };
        if !parses {
            return Ok(false);
        }
        if end == self.size {
            return Ok(true);
        }
        if self.size - end < RECORD_HEADER_LEN {
            return Ok(false);
        }
        let next = self.read_record_header(end)?;
        Ok(is_known(next.opcode) && next.opcode != 0 && next.length <= self.size - end - RECORD_HEADER_LEN)
    }
}

impl Iterator for RecordingReader {
    type Item = Result<Item>;
    fn next(&mut self) -> Option<Result<Item>> {
        self.next_item()
    }
}

/// An opcode of the MCAP specification.
fn is_known(opcode: u8) -> bool {
    (op::HEADER..=op::DATA_END).contains(&opcode)
}

/// A record's length against the bytes after its header and the cap.
fn check_len(opcode: u8, len: u64, left: u64) -> Result<(), String> {
    let what = record_name(opcode);
    if len > left {
        return Err(format!(
            "a {what} (opcode 0x{opcode:02x}) of {len} bytes, but the file has only {left} bytes after its header"
        ));
    }
    if len > MAX_RECORD_LEN {
        return Err(format!("a {what} of {len} bytes, more than the {MAX_RECORD_LEN} a record may hold"));
    }
    Ok(())
}

fn parse_header(body: &[u8]) -> Result<mcap::records::Header, String> {
    let mut f = Fields::new(body);
    let profile = f.string("the profile")?;
    let library = f.string("the library")?;
    f.end("header")?;
    Ok(mcap::records::Header { profile, library })
}

fn parse_channel(body: &[u8]) -> Result<RawChannel, String> {
    let mut f = Fields::new(body);
    let id = f.u16("the channel id")?;
    let _schema = f.u16("the schema id")?;
    let topic = f.string("the topic")?;
    let encoding = f.string("the message encoding")?;
    let metadata = f.string_map("the channel metadata")?;
    f.end("channel")?;
    Ok(RawChannel { id, topic, encoding, metadata })
}

fn parse_schema(body: &[u8]) -> Result<(), String> {
    let mut f = Fields::new(body);
    f.u16("the schema id")?;
    f.string("the schema name")?;
    f.string("the schema encoding")?;
    let len = f.u32("the schema data")?;
    f.bytes(len.into(), "the schema data")?;
    f.end("schema")
}

fn parse_message(body: &[u8]) -> Result<(MessageHeader, &[u8]), String> {
    let mut f = Fields::new(body);
    let header = MessageHeader {
        channel_id: f.u16("the channel id")?,
        sequence: f.u32("the sequence")?,
        log_time: f.u64("the log time")?,
        publish_time: f.u64("the publish time")?,
    };
    Ok((header, f.rest()))
}

/// The channels of a [`crate::CHANNELS_METADATA`] record; entries without a topic and an
/// encoding, or with an id that is not a number, are left out.
fn repeated_channels(record: &BTreeMap<String, String>) -> HashMap<u16, RawChannel> {
    let mut out: HashMap<u16, RawChannel> = HashMap::new();
    let mut complete: HashMap<u16, [bool; 2]> = HashMap::new();
    for (key, value) in record {
        let Some((id, field)) = key.split_once('/') else { continue };
        let Ok(id) = id.parse::<u16>() else { continue };
        let c = out.entry(id).or_insert_with(|| RawChannel {
            id,
            topic: String::new(),
            encoding: String::new(),
            metadata: BTreeMap::new(),
        });
        let seen = complete.entry(id).or_default();
        match field {
            "topic" => (c.topic, seen[0]) = (value.clone(), true),
            "encoding" => (c.encoding, seen[1]) = (value.clone(), true),
            _ => {
                if let Some(k) = field.strip_prefix("meta/") {
                    c.metadata.insert(k.to_string(), value.clone());
                }
            }
        }
    }
    out.retain(|id, _| complete.get(id) == Some(&[true, true]));
    out
}

fn parse_metadata(body: &[u8]) -> Result<mcap::records::Metadata, String> {
    let mut f = Fields::new(body);
    let name = f.string("the metadata name")?;
    let metadata = f.string_map("the metadata")?;
    f.end("metadata")?;
    Ok(mcap::records::Metadata { name, metadata })
}

fn parse_message_index(body: &[u8]) -> Result<MessageIndex, String> {
    let mut f = Fields::new(body);
    let MessageIndexHeader { channel_id, records_len: len } = MessageIndexHeader::read(&mut f)?;
    f.bytes(len.into(), "the index entries")?;
    f.end("message index")?;
    if len % MESSAGE_INDEX_ENTRY_LEN != 0 {
        return Err(format!("index entries of {len} bytes, not a multiple of {MESSAGE_INDEX_ENTRY_LEN}"));
    }
    Ok(MessageIndex { channel_id, entries: u64::from(len / MESSAGE_INDEX_ENTRY_LEN) })
}

fn parse_data_end(body: &[u8]) -> Result<(), String> {
    exact_len(body, DATA_END_LEN)
}

fn parse_footer(body: &[u8]) -> Result<Footer, String> {
    exact_len(body, FOOTER_LEN)?;
    let mut f = Fields::new(body);
    let summary_start = f.u64("the summary start")?;
    let summary_offset_start = f.u64("the summary offset start")?;
    let summary_crc = f.u32("the summary CRC")?;
    Ok(Footer { summary_start, summary_offset_start, summary_crc })
}

/// A record of fixed length: exactly `len` bytes.
fn exact_len(body: &[u8], len: u64) -> Result<(), String> {
    match body.len() as u64 {
        n if n == len => Ok(()),
        n => Err(format!("{n} bytes ({len} expected)")),
    }
}

/// A chunk record: header, decompressed records (size and CRC checked), parsed.
fn parse_chunk(body: &[u8]) -> Result<ParsedChunk, String> {
    let mut f = Fields::new(body);
    let header = ChunkHeader::read(&mut f)?;
    // Padding after the compressed records is allowed.
    let data = f.bytes(header.compressed_size, "the compressed records")?;
    let uncompressed = header.uncompressed_size;
    if uncompressed > MAX_CHUNK_LEN {
        return Err(format!(
            "an uncompressed size of {uncompressed} bytes, more than the {MAX_CHUNK_LEN} a chunk may hold"
        ));
    }
    let records = decompress(&header.compression, data, uncompressed)?;
    let crc = header.uncompressed_crc;
    if crc != 0 {
        let computed = crc32fast::hash(&records);
        if computed != crc {
            return Err(format!(
                "CRC mismatch (stored {crc:08x}, computed {computed:08x} over the decompressed records)"
            ));
        }
    }
    Ok(ParsedChunk { header, records: parse_chunk_records(&records)? })
}

/// The records of a decompressed chunk.
fn parse_chunk_records(records: &[u8]) -> Result<Vec<Inner>, String> {
    let mut f = Fields::new(records);
    let mut out = Vec::new();
    while f.left() > 0 {
        let at = f.position();
        let in_chunk = |e: String| format!("in the record at byte {at} of the decompressed chunk: {e}");
        let opcode = f.array::<1>("a record's opcode").map_err(in_chunk)?[0];
        let len = f.u64("a record's length").map_err(in_chunk)?;
        let body = f.bytes(len, "a record").map_err(in_chunk)?;
        match opcode {
            op::CHANNEL => out.push(Inner::Channel(parse_channel(body).map_err(in_chunk)?)),
            op::MESSAGE => {
                let (header, data) = parse_message(body).map_err(in_chunk)?;
                out.push(Inner::Message(header, data.to_vec()));
            }
            op::SCHEMA => parse_schema(body).map_err(in_chunk)?,
            other => return Err(in_chunk(format!("a {} (opcode 0x{other:02x}) in a chunk", record_name(other)))),
        }
    }
    Ok(out)
}

/// Decompresses a chunk's records, to exactly `size` bytes (memory follows the bytes produced,
/// not `size`).
fn decompress(compression: &str, data: &[u8], size: u64) -> Result<Vec<u8>, String> {
    // Reserved ahead: as if compressed to a quarter, up to 16 MiB; more grows as bytes arrive.
    let mut out = Vec::with_capacity(size.min(data.len() as u64 * 4).min(16 << 20) as usize);
    let limit = size.saturating_add(1);
    let read = match compression {
        "" => {
            out.extend_from_slice(data);
            Ok(data.len())
        }
        "zstd" => zstd::stream::read::Decoder::with_buffer(data).and_then(|d| d.take(limit).read_to_end(&mut out)),
        "lz4" => lz4::Decoder::new(data).and_then(|d| d.take(limit).read_to_end(&mut out)),
        other => return Err(format!("unknown compression `{}`", other.escape_debug())),
    };
    read.map_err(|e| format!("the {compression} records do not decompress: {e}"))?;
    if out.len() as u64 != size {
        let n = if out.len() as u64 > size { format!("more than {size}") } else { out.len().to_string() };
        return Err(format!("the records decompress to {n} bytes, the chunk header says {size}"));
    }
    Ok(out)
}

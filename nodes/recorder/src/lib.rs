//! Deep Contact recordings: MCAP files holding a graph's frames exactly as they travel on zenoh
//! (CBOR `{v, h, i}`, message encoding `cbor`, no schema), one channel per topic.
//!
//! - [`write::RecordingWriter`]: what `dc-record` writes with: zstd chunks written whole (a killed
//!   writer leaves only complete chunks behind), channel metadata with the frame type and wire
//!   version, run metadata as MCAP metadata records.
//! - [`read::RecordingReader`]: streams a file record by record with bounded memory (one chunk at a
//!   time), trusts no length in the file, checks the magic, every chunk's CRC and every channel's
//!   wire version, and names the file and the byte in every error; leniently, it skips damaged
//!   chunks and resumes at the next intact record.
//! - [`join::Steps`]: what the trainer reads: a recording (one file or a folder of files) as steps
//!   joined per (run, simulation, step): bodies + contacts (+ solver statistics).
//! - [`info::Info`] (`dc-record info`) and [`recover::recover`] (`dc-record recover`: every intact
//!   chunk, with a report per topic of what was kept and skipped, into a new file that replaces
//!   the output only when complete and is never the input under another name).
//! - [`summary`]: the summary section (footer offsets, chunk indexes, statistics) checked against
//!   the data section as the reader walks it; what follows a footer (another recording, junk) is
//!   read too, never ignored.
//! - [`bench`]: the recorder's end-of-run counts and a recording's missing steps, for
//!   `dc-record bench` (a 10,000-body simulator recorded live: drops, MB/s, msgs/s, CPU time).
//!
//! Compression: the `mcap` crate (0.24) sets one compression per writer, not per channel or chunk
//! (no setter after `create`; see [`write::RecordingWriter`] for what per-channel compression would
//! take), so every chunk is zstd (float grids compress less, but still gain from zstd's entropy
//! stage).

pub mod bench;
mod fields;
pub mod info;
pub mod join;
pub mod read;
pub mod recover;
pub mod summary;
pub mod write;

pub use info::Info;
pub use join::{Step, Steps};
/// The frame kinds live in the contract crate (`msgs::topics`).
pub use msgs::{FrameKind, HasStep};
pub use read::{Item, Message, RecordingReader};
pub use write::{now_ns, utc_stamp, utc_text, RecordingWriter};

use std::path::PathBuf;

/// Message encoding of every channel the recorder writes.
pub const MESSAGE_ENCODING: &str = "cbor";
/// Channel metadata key: the frame type ([`FrameKind::type_name`]).
pub const META_TYPE: &str = "type";
/// Channel metadata key: the wire version of the CBOR frames ([`msgs::WIRE_VERSION`]).
pub const META_WIRE_VERSION: &str = "wire_version";
/// Name of the metadata record that repeats every channel declaration outside the chunks, after
/// each new channel and at every flush. MCAP declares a channel once, inside the chunk where it
/// first appears; a killed recording has no summary to repeat it, so damage to that one chunk
/// would lose every later message of the channel. Keys: `<id>/topic`, `<id>/encoding` and
/// `<id>/meta/<key>` for each key of the channel's metadata. Readers take it in silently.
pub const CHANNELS_METADATA: &str = "dc.channels";

/// Why a recording could not be read or written; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path}: not an MCAP file ({detail})")]
    NotMcap { path: PathBuf, detail: String },
    #[error("{path}: damaged or truncated MCAP file at byte {offset}: {detail} (a recorder killed mid-run leaves such a file; `dc-record recover IN OUT` rescues its intact chunks)")]
    Damaged { path: PathBuf, offset: u64, detail: String },
    #[error("{path}: topic `{topic}` was recorded with wire version {found}; this build reads version {expected}")]
    WireVersion { path: PathBuf, topic: String, found: String, expected: u32 },
    #[error("{path}: MCAP writer: {source}")]
    Write { path: PathBuf, source: mcap::McapError },
    /// The operating system refused a write (`No space left on device` ...): the writer stops
    /// there, and every later call returns the same error; the file keeps every chunk flushed
    /// before it (`dc-record recover` rescues them).
    #[error("{error} writing {path}")]
    WriteIo { path: PathBuf, error: std::io::Error },
    #[error("{path}: nothing recovered: {detail}")]
    NothingRecovered { path: PathBuf, detail: String },
    #[error("{path}: no .mcap recordings there")]
    NoRecordings { path: PathBuf },
    /// `recover` was asked to write over the file it reads.
    #[error("{output} is the same file as the input {input} (a hard link, a symlink or another spelling of it): recover would overwrite what it reads; choose another output")]
    SameFile { input: PathBuf, output: PathBuf },
    /// A new recording was asked for at a path that already holds a file.
    #[error("{path} already exists: a recording is never written over an existing file (it may be a finished recording, or a killed one waiting for `dc-record recover`); choose another path, remove it, or pass `--overwrite`")]
    Exists { path: PathBuf },
    /// More than one recording in one file (`cat a.mcap b.mcap > c.mcap`).
    #[error("{path}: {recordings} recordings concatenated in one file (the second starts at byte {second}): readers that go by the summary see only one; `dc-record recover IN OUT` writes them as one")]
    Concatenated { path: PathBuf, recordings: usize, second: u64 },
    /// The summary section does not match the data section (see [`summary::SummaryProblem`]).
    #[error("{path}: bad summary section at byte {offset}: {detail}{more} (indexed MCAP readers refuse the file or lose messages; `dc-record recover IN OUT` writes a new summary)")]
    BadSummary { path: PathBuf, offset: u64, detail: String, more: String },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

/// The `.mcap` files a path names: the file itself, or a folder's `*.mcap` files sorted by name.
pub fn recording_files(path: &std::path::Path) -> Result<Vec<PathBuf>> {
    let io = |source| Error::Io { path: path.to_path_buf(), source };
    if !path.is_dir() {
        std::fs::metadata(path).map_err(io)?;
        return Ok(vec![path.to_path_buf()]);
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(io)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(Error::NoRecordings { path: path.to_path_buf() });
    }
    Ok(files)
}

//! Writing recordings.

use crate::{Error, FrameKind, Result, CHANNELS_METADATA, MESSAGE_ENCODING, META_TYPE, META_WIRE_VERSION};
use runtime::files::Replacement;
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// Target uncompressed size of a chunk; a chunk is also closed by every [`RecordingWriter::flush`].
pub const CHUNK_SIZE: u64 = 1 << 20;

/// An MCAP file being written: one `cbor` channel per topic, zstd chunks.
///
/// Chunks are built in memory and written whole (`disable_seeking`), so a writer killed at any
/// moment leaves a file whose chunks are all complete but perhaps the last one.
///
/// A write the operating system refuses (a full disk ...) stops the writer: that call returns
/// [`Error::WriteIo`] naming the OS error and the file, every later call returns the same error
/// without touching the file again, and dropping the writer neither panics nor writes; the file
/// keeps every chunk flushed before the failure (`recover` restores them).
///
/// Why every chunk is zstd, although the issue asked for lz4 or none on float grids: the MCAP
/// format stores the compression per chunk, but `mcap` 0.24's `Writer` takes it once, from the
/// `WriteOptions` consumed by `create`, and reads that private copy each time it starts a chunk
/// (`start_chunk` -> `ChunkWriter::new(.., self.options.compression, ..)`); there is no setter, and
/// a `flush` (which ends a chunk) does not change it. A second `Writer` on the same file cannot
/// share the summary, chunk indexes and channel ids. So per-channel compression needs either a
/// small patch of the crate (a `set_compression` taking effect at the next chunk, plus routing
/// grid channels into chunks of their own by flushing when the class changes) or our own chunk
/// writer; neither is worth it while grids are a minor share of a recording: zstd still gains on
/// them (sparse impulse grids are mostly zeros), and its cost shows in `dc-record bench` as
/// recorder CPU time well under the wall time.
pub struct RecordingWriter {
    path: PathBuf,
    writer: Option<mcap::Writer<Sink>>,
    /// The first I/O error of the output, shared with the [`Sink`] under the MCAP writer.
    failed: Arc<Mutex<Option<std::io::Error>>>,
    /// The output file, for `sync_all` at the end (none for another kind of output).
    file: Option<File>,
    /// The file is written under a temporary name, renamed over the path by `finish` (see
    /// [`RecordingWriter::create_replacing`]).
    replacement: Option<Replacement>,
    channels: HashMap<String, u16>,
    /// Every channel as declared (id -> topic, encoding, metadata), repeated in
    /// [`CHANNELS_METADATA`] records.
    declared: BTreeMap<u16, (String, String, BTreeMap<String, String>)>,
    /// A channel was declared since the last repetition: repeat before the next message.
    repeat_pending: bool,
    sequences: HashMap<u16, u32>,
    messages: u64,
}

/// How many numbered names [`RecordingWriter::create_numbered`] tries before it gives up.
pub const NUMBERED_TRIES: u32 = 999;

impl RecordingWriter {
    /// Creates `path` (and its folder), truncating a file already there.
    pub fn create(path: &Path) -> Result<RecordingWriter> {
        let file = Self::open(path, std::fs::OpenOptions::new().write(true).create(true).truncate(true))?;
        Self::to_file(path, file, None)
    }

    /// Creates `path` (and its folder) only if nothing is there ([`Error::Exists`] otherwise):
    /// the check and the creation are one step, so two recorders cannot both take one path.
    pub fn create_new(path: &Path) -> Result<RecordingWriter> {
        let file = Self::open(path, std::fs::OpenOptions::new().write(true).create_new(true))?;
        Self::to_file(path, file, None)
    }

    /// Creates `dir/<stem>.mcap`, or `<stem>-2.mcap`, `<stem>-3.mcap`, ... when another
    /// recorder (of this graph or another, started in the same second) took the name first; each
    /// try is [`RecordingWriter::create_new`], so two recorders never share a file.
    pub fn create_numbered(dir: &Path, stem: &str) -> Result<RecordingWriter> {
        for n in 1..=NUMBERED_TRIES {
            let name = if n == 1 { format!("{stem}.mcap") } else { format!("{stem}-{n}.mcap") };
            match Self::create_new(&dir.join(name)) {
                Err(Error::Exists { .. }) => continue,
                other => return other,
            }
        }
        Err(Error::Exists { path: dir.join(format!("{stem}-{NUMBERED_TRIES}.mcap")) })
    }

    fn open(path: &Path, options: &std::fs::OpenOptions) -> Result<File> {
        let io = |source| Error::Io { path: path.to_path_buf(), source };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
        options.open(path).map_err(|source| match source.kind() {
            std::io::ErrorKind::AlreadyExists => Error::Exists { path: path.to_path_buf() },
            _ => io(source),
        })
    }

    /// Writes a new file for `path` under a temporary name in the same folder, renamed over `path`
    /// by [`RecordingWriter::finish`]: until then `path` keeps what it held (or stays absent), and
    /// a writer dropped unfinished, or a failed `finish`, removes the temporary file.
    pub fn create_replacing(path: &Path) -> Result<RecordingWriter> {
        let (replacement, file) =
            Replacement::create(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        Self::to_file(path, file, Some(replacement))
    }

    /// Writes to `file`, opened for `path` (synced by `finish`, then `replacement` committed).
    fn to_file(path: &Path, file: File, replacement: Option<Replacement>) -> Result<RecordingWriter> {
        let sync = file.try_clone().map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        let mut w = Self::start(path, Box::new(file), Some(sync))?;
        w.replacement = replacement;
        Ok(w)
    }

    /// Writes to `out` (a pipe, a buffer, a test's failing writer ...); `name` is the path that
    /// errors name.
    pub fn to_output(name: &Path, out: impl Write + Send + 'static) -> Result<RecordingWriter> {
        Self::start(name, Box::new(out), None)
    }

    fn start(path: &Path, out: Box<dyn Write + Send>, file: Option<File>) -> Result<RecordingWriter> {
        let options = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .chunk_size(Some(CHUNK_SIZE))
            .disable_seeking(true)
            .profile("deep-contact")
            .library(concat!("dc-record ", env!("CARGO_PKG_VERSION"), " (mcap-rs 0.24)"));
        let failed = Arc::new(Mutex::new(None));
        let sink = Sink { out: Some(BufWriter::with_capacity(1 << 20, out)), position: 0, failed: failed.clone() };
        let mut w = RecordingWriter {
            path: path.to_path_buf(),
            writer: None,
            failed,
            file,
            replacement: None,
            channels: HashMap::new(),
            declared: BTreeMap::new(),
            repeat_pending: false,
            sequences: HashMap::new(),
            messages: 0,
        };
        w.writer = Some(options.create(sink).map_err(|e| w.err(e))?);
        Ok(w)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Messages written so far.
    pub fn messages(&self) -> u64 {
        self.messages
    }

    /// A copy of the output's first I/O error, if one happened.
    fn first_error(&self) -> Option<std::io::Error> {
        self.failed.lock().unwrap_or_else(|e| e.into_inner()).as_ref().map(copy_io_error)
    }

    /// Whether a write failed (every later call fails the same way).
    pub fn has_failed(&self) -> bool {
        self.failed.lock().unwrap_or_else(|e| e.into_inner()).is_some()
    }

    /// An error of the MCAP writer, named after the output's first I/O error when there was one.
    fn err(&self, source: mcap::McapError) -> Error {
        match (self.first_error(), source) {
            (Some(first), _) => Error::WriteIo { path: self.path.clone(), error: first },
            (None, mcap::McapError::Io(error)) => Error::WriteIo { path: self.path.clone(), error },
            (None, source) => Error::Write { path: self.path.clone(), source },
        }
    }

    /// The MCAP writer, or the first I/O error once the output failed: nothing more reaches it.
    fn writer(&mut self) -> Result<&mut mcap::Writer<Sink>> {
        if let Some(first) = self.first_error() {
            return Err(Error::WriteIo { path: self.path.clone(), error: first });
        }
        Ok(self.writer.as_mut().expect("the writer lives until finish()"))
    }

    /// Adds the channel of `topic` (once): encoding `cbor`, metadata with the frame type and the
    /// wire version.
    pub fn add_channel(&mut self, topic: &str, kind: FrameKind) -> Result<u16> {
        if let Some(&id) = self.channels.get(topic) {
            return Ok(id);
        }
        let (header, item) = kind.parts();
        let metadata = BTreeMap::from([
            (META_TYPE.to_string(), kind.type_name().to_string()),
            (META_WIRE_VERSION.to_string(), msgs::WIRE_VERSION.to_string()),
            ("header".to_string(), header.to_string()),
            ("item".to_string(), item.to_string()),
        ]);
        self.add_raw_channel(topic, MESSAGE_ENCODING, &metadata)
    }

    /// Adds a channel with the given encoding and metadata as found in another file (recovery).
    pub fn add_raw_channel(&mut self, topic: &str, encoding: &str, metadata: &BTreeMap<String, String>) -> Result<u16> {
        let id = self.writer()?.add_channel(0, topic, encoding, metadata).map_err(|e| self.err(e))?;
        self.channels.insert(topic.to_string(), id);
        let declaration = (topic.to_string(), encoding.to_string(), metadata.clone());
        if self.declared.insert(id, declaration.clone()) != Some(declaration) {
            self.repeat_pending = true;
        }
        Ok(id)
    }

    /// Writes the [`CHANNELS_METADATA`] record of every channel declared so far (which ends the
    /// chunk holding the new declarations: they are said again outside any chunk).
    fn repeat_channels(&mut self) -> Result<()> {
        self.repeat_pending = false;
        let mut record = BTreeMap::new();
        for (id, (topic, encoding, metadata)) in &self.declared {
            record.insert(format!("{id}/topic"), topic.clone());
            record.insert(format!("{id}/encoding"), encoding.clone());
            for (k, v) in metadata {
                record.insert(format!("{id}/meta/{k}"), v.clone());
            }
        }
        self.write_metadata(CHANNELS_METADATA, record)
    }

    /// Writes one CBOR frame of `topic` (its channel is added if needed). Times in ns since the epoch.
    pub fn write(&mut self, topic: &str, kind: FrameKind, log_time: u64, publish_time: u64, data: &[u8]) -> Result<()> {
        let channel_id = self.add_channel(topic, kind)?;
        self.write_to_channel(channel_id, log_time, publish_time, data)
    }

    /// Writes one message to a channel added before.
    pub fn write_to_channel(&mut self, channel_id: u16, log_time: u64, publish_time: u64, data: &[u8]) -> Result<()> {
        if self.repeat_pending {
            self.repeat_channels()?;
        }
        let seq = self.sequences.entry(channel_id).or_insert(0);
        *seq = seq.wrapping_add(1);
        let header = mcap::records::MessageHeader { channel_id, sequence: *seq, log_time, publish_time };
        self.writer()?.write_to_known_channel(&header, data).map_err(|e| self.err(e))?;
        self.messages += 1;
        Ok(())
    }

    /// Writes a metadata record (run parameters, git revision ...).
    pub fn write_metadata(&mut self, name: &str, metadata: BTreeMap<String, String>) -> Result<()> {
        let record = mcap::records::Metadata { name: name.to_string(), metadata };
        self.writer()?.write_metadata(&record).map_err(|e| self.err(e))
    }

    /// Closes the current chunk, repeats the channel declarations after it, and pushes everything
    /// to the operating system: a kill after this loses nothing written before it.
    pub fn flush(&mut self) -> Result<()> {
        if !self.declared.is_empty() {
            self.repeat_channels()?;
        }
        self.writer()?.flush().map_err(|e| self.err(e))
    }

    /// Writes the summary (indexes, statistics) and the footer; returns the messages written.
    pub fn finish(mut self) -> Result<u64> {
        self.writer()?.finish().map_err(|e| self.err(e))?;
        let writer = self.writer.take().expect("the writer lives until finish()");
        let mut sink = writer.into_inner();
        sink.flush().map_err(|error| Error::WriteIo { path: self.path.clone(), error })?;
        if let Some(file) = &self.file {
            file.sync_all().map_err(|error| Error::WriteIo { path: self.path.clone(), error })?;
        }
        if let Some(replacement) = self.replacement.take() {
            replacement.commit().map_err(|source| Error::Io { path: self.path.clone(), source })?;
        }
        Ok(self.messages)
    }
}

/// Writes `bytes` as the new content of `path` through a [`Replacement`].
pub fn replace_file(path: &Path, bytes: &[u8]) -> Result<()> {
    runtime::files::replace_file(path, bytes).map_err(|error| Error::WriteIo { path: path.to_path_buf(), error })
}

impl Drop for RecordingWriter {
    fn drop(&mut self) {
        let Some(mut w) = self.writer.take() else { return };
        if self.has_failed() {
            // The error was returned already; the file stays as the last write left it.
            return;
        }
        // An unfinished writer (an error path elsewhere): finish it here and only log a failure.
        if let Err(e) = w.finish() {
            tracing::error!("could not finish the recording: {}", self.err(e));
        }
    }
}

/// The output under the MCAP writer: counts its position itself (the writer asks for it at every
/// chunk; a `BufWriter<File>` would flush to answer, and an error there left `mcap` 0.24's writer
/// without its output, to panic later), and remembers the first I/O error, after which nothing
/// reaches the output again, not even the buffer's flush on drop: the file keeps what was written
/// before the failure.
struct Sink {
    out: Option<BufWriter<Box<dyn Write + Send>>>,
    position: u64,
    failed: Arc<Mutex<Option<std::io::Error>>>,
}

impl Sink {
    fn run<T>(
        &mut self,
        op: impl FnOnce(&mut BufWriter<Box<dyn Write + Send>>) -> std::io::Result<T>,
    ) -> std::io::Result<T> {
        let mut failed = self.failed.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(first) = failed.as_ref() {
            return Err(copy_io_error(first));
        }
        let out = self.out.as_mut().expect("the output lives until drop");
        op(out).inspect_err(|e| {
            *failed = Some(copy_io_error(e));
            // Drop what is still buffered: nothing more reaches the output.
            if let Some(out) = self.out.take() {
                let _ = out.into_parts();
            }
        })
    }
}

impl Write for Sink {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.run(|out| out.write(buf))?;
        self.position += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.run(|out| out.flush())
    }
}

impl Seek for Sink {
    /// Only tells the position: with `disable_seeking` the MCAP writer builds each chunk in memory.
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        match pos {
            SeekFrom::Current(0) | SeekFrom::End(0) => Ok(self.position),
            SeekFrom::Start(p) if p == self.position => Ok(self.position),
            _ => Err(std::io::Error::new(std::io::ErrorKind::Unsupported, "the recording output does not seek")),
        }
    }
}

/// `std::io::Error` is not `Clone`: the same OS error, or the same kind and message.
fn copy_io_error(e: &std::io::Error) -> std::io::Error {
    match e.raw_os_error() {
        Some(code) => std::io::Error::from_raw_os_error(code),
        None => std::io::Error::new(e.kind(), e.to_string()),
    }
}

/// `YYYYMMDDTHHMMSSZ` in UTC: the time in recordings' default names.
pub fn utc_stamp(t: std::time::SystemTime) -> String {
    let secs = t.duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0) as i64;
    let (y, m, d, hh, mm, ss) = civil_utc(secs);
    format!("{y:04}{m:02}{d:02}T{hh:02}{mm:02}{ss:02}Z")
}

/// A time in ns since the epoch as people read it: `2026-12-06 03:24:40.123 UTC`.
pub fn utc_text(ns: u64) -> String {
    let (y, m, d, hh, mm, ss) = civil_utc((ns / 1_000_000_000) as i64);
    format!("{y:04}-{m:02}-{d:02} {hh:02}:{mm:02}:{ss:02}.{:03} UTC", ns % 1_000_000_000 / 1_000_000)
}

/// Year, month, day, hour, minute, second of `secs` since 1970-01-01 UTC.
fn civil_utc(secs: i64) -> (i64, i64, i64, i64, i64, i64) {
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d, rem / 3600, rem % 3600 / 60, rem % 60)
}

/// Now, in nanoseconds since the Unix epoch: a message's log time.
pub fn now_ns() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    #[test]
    fn times_are_written_as_people_read_them() {
        // 2026-12-06 03:24:40.123 UTC, a leap year's end and the epoch itself.
        assert_eq!(super::utc_text(1_796_527_480_123_456_789), "2026-12-06 03:24:40.123 UTC");
        assert_eq!(super::utc_text(1_704_067_199_999_000_000), "2023-12-31 23:59:59.999 UTC");
        assert_eq!(super::utc_text(0), "1970-01-01 00:00:00.000 UTC");
        let t = std::time::UNIX_EPOCH + std::time::Duration::from_secs(1_796_527_480);
        assert_eq!(super::utc_stamp(t), "20261206T032440Z");
    }
}

//! `dc-record recover`: rewrites a recording whose writer died (no summary, no footer, perhaps a
//! torn last chunk) or whose bytes were damaged into a valid indexed file with every message of
//! every intact chunk: a damaged chunk is skipped and reading resumes at the next intact record.

use crate::read::{Damage, Item, ReadOptions, RecordingReader};
use crate::summary::SummaryProblem;
use crate::write::RecordingWriter;
use crate::{Error, Result};
use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::path::Path;

/// What [`recover`] rescued and what it had to leave.
#[derive(Debug, Clone, Default)]
pub struct Recovered {
    /// Messages kept (all topics).
    pub messages: u64,
    pub channels: u64,
    pub metadata: u64,
    /// Messages kept, per topic.
    pub kept: BTreeMap<String, u64>,
    /// Messages lost in skipped chunks, per topic, as far as the message indexes after them tell
    /// (a torn last chunk has none), and messages whose channel declaration was lost.
    pub skipped: BTreeMap<String, u64>,
    /// The damaged regions skipped, in file order; empty for an intact input.
    pub damage: Vec<Damage>,
    /// Bytes of the input read (its size, unless an error stopped the copy).
    pub bytes_read: u64,
    /// Size of the input in bytes.
    pub input_size: u64,
    /// Where each recording after the first starts in the input (files concatenated): all of
    /// them are copied, into one recording.
    pub recordings: Vec<u64>,
    /// What was wrong with the input's summary section (the output has a new one).
    pub summary_problems: Vec<SummaryProblem>,
}

impl Recovered {
    /// Whether the input was a sound recording: no damage, one recording, a sound summary.
    pub fn input_was_sound(&self) -> bool {
        self.damage.is_empty() && self.recordings.is_empty() && self.summary_problems.is_empty()
    }

    /// Damaged chunks (and torn records, or records whose opcode was lost) that were skipped.
    pub fn skipped_chunks(&self) -> usize {
        self.damage.iter().filter(|d| d.may_be_chunk() && d.skipped_bytes(self.input_size) > 0).count()
    }
}

impl fmt::Display for Recovered {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let topics: std::collections::BTreeSet<&String> = self.kept.keys().chain(self.skipped.keys()).collect();
        for topic in topics {
            let kept = self.kept.get(topic).copied().unwrap_or(0);
            match self.skipped.get(topic) {
                Some(n) => writeln!(f, "  {topic}: kept {kept}, skipped {n}")?,
                None => writeln!(f, "  {topic}: kept {kept}")?,
            }
        }
        for d in &self.damage {
            writeln!(f, "  skipped {d}")?;
        }
        for at in &self.recordings {
            writeln!(f, "  another recording starts at byte {at} of the input (files concatenated): kept too")?;
        }
        for p in &self.summary_problems {
            writeln!(f, "  the input's summary section {p}: the output has a new one")?;
        }
        Ok(())
    }
}

/// Copies every channel, metadata record and message of the intact parts of `input` (of every
/// recording in it, when files were concatenated) into a new file `output`, which gets a summary,
/// indexes and a footer. A file that is not MCAP at all, or a damaged one of which nothing could
/// be kept, is an error. The output is written under a temporary name and renamed over `output`
/// when complete: an error leaves `output` as it was. An output that is the input under another
/// name (a hard link, a symlink ...) is refused before anything is written.
pub fn recover(input: &Path, output: &Path) -> Result<Recovered> {
    recover_with_progress(input, output, &mut |_, _| {})
}

/// [`recover`], calling `progress(bytes read, input size)` as it goes.
pub fn recover_with_progress(input: &Path, output: &Path, progress: &mut dyn FnMut(u64, u64)) -> Result<Recovered> {
    let output_meta = std::fs::metadata(output).ok();
    refuse_same_file(input, output, output_meta.as_ref())?;
    let reader = RecordingReader::open_with(input, ReadOptions { any_wire_version: true, lenient: true })?;
    // A device or a pipe (`/dev/null`, `/dev/stdout`) is written to; a file is replaced.
    let writer = match output_meta {
        Some(m) if !m.is_file() && !m.is_dir() => RecordingWriter::create(output)?,
        _ => RecordingWriter::create_replacing(output)?,
    };
    recover_into_with(reader, writer, progress)
}

/// [`Error::SameFile`] when `output` exists (`output_meta`) and is the same file as `input` (same
/// device and inode, whatever the paths: hard links, symlinks, `./a` and `a`).
fn refuse_same_file(input: &Path, output: &Path, output_meta: Option<&std::fs::Metadata>) -> Result<()> {
    use std::os::unix::fs::MetadataExt;
    let input_meta = std::fs::metadata(input).map_err(|source| Error::Io { path: input.to_path_buf(), source })?;
    let Some(output_meta) = output_meta else { return Ok(()) };
    if (input_meta.dev(), input_meta.ino()) == (output_meta.dev(), output_meta.ino()) {
        return Err(Error::SameFile { input: input.to_path_buf(), output: output.to_path_buf() });
    }
    Ok(())
}

/// [`recover`] from a reader (best opened lenient, with any wire version) into a writer.
pub fn recover_into(reader: RecordingReader, writer: RecordingWriter) -> Result<Recovered> {
    recover_into_with(reader, writer, &mut |_, _| {})
}

/// [`recover_into`], calling `progress(bytes read, input size)` after each record.
pub fn recover_into_with(
    mut reader: RecordingReader,
    mut writer: RecordingWriter,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<Recovered> {
    let mut ids: HashMap<u16, u16> = HashMap::new();
    let mut out = Recovered { input_size: reader.size(), ..Default::default() };
    while let Some(item) = reader.next_item() {
        progress(reader.consumed(), out.input_size);
        match item {
            Ok(Item::Channel(c)) => {
                let id = writer.add_raw_channel(&c.topic, &c.encoding, &c.metadata)?;
                if ids.insert(c.id, id).is_none() {
                    out.channels += 1;
                }
            }
            Ok(Item::Message(m)) => {
                let id = ids[&m.channel.id];
                writer.write_to_channel(id, m.log_time, m.publish_time, &m.data)?;
                out.messages += 1;
                *out.kept.entry(m.channel.topic.clone()).or_default() += 1;
            }
            Ok(Item::Metadata(m)) => {
                writer.write_metadata(&m.name, m.metadata)?;
                out.metadata += 1;
            }
            Ok(Item::Chunk { .. }) => {}
            // A strict reader's damage ends the copy; a lenient one reports it below.
            Err(Error::Damaged { offset, detail, .. }) => {
                out.damage.push(Damage { offset, opcode: None, detail, resumed_at: None, messages: BTreeMap::new() });
                break;
            }
            Err(e) => return Err(e),
        }
    }
    out.damage.splice(0..0, reader.damage().iter().cloned());
    out.skipped = reader.skipped().clone();
    out.recordings = reader.recordings().to_vec();
    out.summary_problems = reader.summary_problems().to_vec();
    out.bytes_read = reader.consumed();
    if out.messages == 0 && !out.damage.is_empty() {
        return Err(Error::NothingRecovered {
            path: reader.path().to_path_buf(),
            detail: format!("no intact message in {} bytes; {}", out.input_size, out.damage[0]),
        });
    }
    writer.finish()?;
    Ok(out)
}

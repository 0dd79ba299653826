//! `dc-record recover`: rewrites a recording whose writer died (no summary, no footer, perhaps a
//! torn last chunk) into a valid indexed file with every complete message.

use crate::read::{Item, ReadOptions, RecordingReader};
use crate::write::RecordingWriter;
use crate::{Error, Result};
use std::collections::HashMap;
use std::path::Path;

/// What [`recover`] rescued.
#[derive(Debug, Clone, Default)]
pub struct Recovered {
    pub messages: u64,
    pub channels: u64,
    pub metadata: u64,
    /// Why reading stopped before a footer (the damage), `None` for an intact input.
    pub damage: Option<String>,
    /// Bytes of the input that were read up to the damage (or the whole file).
    pub bytes_read: u64,
}

/// Copies every channel, metadata record and message of `input` up to the first damage into a new
/// file `output`, which gets a summary, indexes and a footer. A file that is not MCAP at all is an
/// error; damage after the magic is not.
pub fn recover(input: &Path, output: &Path) -> Result<Recovered> {
    if input.canonicalize().ok().is_some_and(|i| output.canonicalize().ok() == Some(i)) {
        return Err(Error::Io {
            path: output.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::AlreadyExists, "recover would overwrite its input"),
        });
    }
    let mut reader = RecordingReader::open_with(input, ReadOptions { any_wire_version: true })?;
    let mut writer = RecordingWriter::create(output)?;
    let mut ids: HashMap<u16, u16> = HashMap::new();
    let mut out = Recovered::default();
    while let Some(item) = reader.next_item() {
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
            }
            Ok(Item::Metadata(m)) => {
                writer.write_metadata(&m.name, m.metadata)?;
                out.metadata += 1;
            }
            Ok(Item::Chunk { .. }) => {}
            Err(e @ Error::Damaged { .. }) => {
                out.damage = Some(e.to_string());
                break;
            }
            Err(e) => return Err(e),
        }
    }
    out.bytes_read = reader.consumed();
    writer.finish()?;
    Ok(out)
}

//! Streaming a recording record by record, one chunk in memory at a time.

use crate::{Error, FrameKind, Result, MESSAGE_ENCODING, META_TYPE, META_WIRE_VERSION};
use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;

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
    /// A chunk was read: its sizes and compression (before the messages it holds).
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
}

/// Reads a recording from start to end with bounded memory: the raw file is read in pieces and
/// one chunk at a time is decompressed. Every error names the file.
pub struct RecordingReader {
    path: PathBuf,
    file: File,
    reader: LinearReader,
    pending: VecDeque<Item>,
    channels: HashMap<u16, Arc<Channel>>,
    options: ReadOptions,
    in_summary: bool,
    done: bool,
    /// Bytes of the file consumed so far (for reports on damaged files).
    consumed: u64,
}

impl RecordingReader {
    /// Opens `path`, checking the MCAP magic.
    pub fn open(path: &Path) -> Result<RecordingReader> {
        Self::open_with(path, ReadOptions::default())
    }

    pub fn open_with(path: &Path, options: ReadOptions) -> Result<RecordingReader> {
        let io = |source| Error::Io { path: path.to_path_buf(), source };
        let mut file = File::open(path).map_err(io)?;
        if file.metadata().map_err(io)?.is_dir() {
            return Err(Error::NotMcap { path: path.to_path_buf(), detail: "a folder".into() });
        }
        let mut magic = [0u8; 8];
        let n = read_full(&mut file, &mut magic).map_err(io)?;
        if n < 8 || &magic[..] != mcap::MAGIC {
            return Err(Error::NotMcap {
                path: path.to_path_buf(),
                detail: format!("the first {n} bytes are not the MCAP magic"),
            });
        }
        let file = File::open(path).map_err(io)?;
        let reader = LinearReader::new_with_options(LinearReaderOptions::default().with_emit_chunks(true));
        Ok(RecordingReader {
            path: path.to_path_buf(),
            file,
            reader,
            pending: VecDeque::new(),
            channels: HashMap::new(),
            options,
            in_summary: false,
            done: false,
            consumed: 0,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The channels seen so far, by id.
    pub fn channels(&self) -> &HashMap<u16, Arc<Channel>> {
        &self.channels
    }

    /// Bytes of the file read so far.
    pub fn consumed(&self) -> u64 {
        self.consumed
    }

    fn damaged(&self, detail: impl std::fmt::Display) -> Error {
        damaged(&self.path, self.consumed, detail)
    }

    /// The next item of the data section; `None` after the footer. After an error it returns `None`.
    pub fn next_item(&mut self) -> Option<Result<Item>> {
        loop {
            if let Some(item) = self.pending.pop_front() {
                return Some(Ok(item));
            }
            if self.done {
                return None;
            }
            match self.fill() {
                Ok(()) => {}
                Err(e) => {
                    self.done = true;
                    self.pending.clear();
                    return Some(Err(e));
                }
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

    /// Reads the file until at least one item is pending or the file ended.
    fn fill(&mut self) -> Result<()> {
        loop {
            // Fields, not methods, while the reader's event borrows it.
            let record = match self.reader.next_event() {
                None => {
                    self.done = true;
                    return Ok(());
                }
                Some(Err(e)) => return Err(damaged(&self.path, self.consumed, e)),
                Some(Ok(LinearReadEvent::ReadRequest(need))) => {
                    let buf = self.reader.insert(need.max(1 << 16));
                    let n = self.file.read(buf).map_err(|source| Error::Io { path: self.path.clone(), source })?;
                    self.reader.notify_read(n);
                    self.consumed += n as u64;
                    continue;
                }
                Some(Ok(LinearReadEvent::Record { opcode, data })) => {
                    mcap::parse_record(opcode, data).map(|r| r.into_owned())
                }
            };
            let record = record.map_err(|e| damaged(&self.path, self.consumed, e))?;
            self.take(record)?;
            if !self.pending.is_empty() {
                return Ok(());
            }
        }
    }

    fn take(&mut self, record: Record<'static>) -> Result<()> {
        if self.in_summary {
            return Ok(());
        }
        match record {
            Record::Chunk { header, data } => {
                self.pending.push_back(Item::Chunk {
                    compression: header.compression.clone(),
                    compressed: header.compressed_size,
                    uncompressed: header.uncompressed_size,
                });
                let chunk = mcap::read::ChunkReader::new(header, &data).map_err(|e| self.damaged(e))?;
                for record in chunk {
                    let record = record.map_err(|e| self.damaged(format!("in a chunk: {e}")))?;
                    self.take(record.into_owned())?;
                }
            }
            Record::Channel(c) => {
                let channel = self.channel(c)?;
                if self.channels.get(&channel.id).is_none_or(|old| **old != *channel) {
                    self.channels.insert(channel.id, channel.clone());
                    self.pending.push_back(Item::Channel(channel));
                }
            }
            Record::Message { header, data } => {
                let Some(channel) = self.channels.get(&header.channel_id).cloned() else {
                    return Err(
                        self.damaged(format!("a message on channel {} that was never declared", header.channel_id))
                    );
                };
                self.pending.push_back(Item::Message(Message {
                    channel,
                    sequence: header.sequence,
                    log_time: header.log_time,
                    publish_time: header.publish_time,
                    data: data.into_owned(),
                }));
            }
            Record::Metadata(m) => self.pending.push_back(Item::Metadata(m)),
            Record::DataEnd(_) => self.in_summary = true,
            _ => {}
        }
        Ok(())
    }

    fn channel(&self, c: mcap::records::Channel) -> Result<Arc<Channel>> {
        let kind = if c.message_encoding == MESSAGE_ENCODING {
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
        Ok(Arc::new(Channel { id: c.id, topic: c.topic, encoding: c.message_encoding, metadata: c.metadata, kind }))
    }
}

impl Iterator for RecordingReader {
    type Item = Result<Item>;
    fn next(&mut self) -> Option<Result<Item>> {
        self.next_item()
    }
}

fn read_full(file: &mut File, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match file.read(&mut buf[n..])? {
            0 => break,
            k => n += k,
        }
    }
    Ok(n)
}

fn damaged(path: &Path, consumed: u64, detail: impl std::fmt::Display) -> Error {
    Error::Damaged { path: path.to_path_buf(), detail: format!("{detail} (after reading {consumed} bytes)") }
}

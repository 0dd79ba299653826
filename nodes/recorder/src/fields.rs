//! Reading an MCAP record's fields without trusting a length, and the records' names for
//! messages: what the reader and the summary check share.

use std::collections::BTreeMap;

/// The name of a record of `opcode` in the MCAP specification, for messages.
pub(crate) fn record_name(opcode: u8) -> &'static str {
    match opcode {
        mcap::records::op::HEADER => "header record",
        mcap::records::op::FOOTER => "footer record",
        mcap::records::op::SCHEMA => "schema record",
        mcap::records::op::CHANNEL => "channel record",
        mcap::records::op::MESSAGE => "message record",
        mcap::records::op::CHUNK => "chunk",
        mcap::records::op::MESSAGE_INDEX => "message index record",
        mcap::records::op::CHUNK_INDEX => "chunk index record",
        mcap::records::op::ATTACHMENT => "attachment record",
        mcap::records::op::ATTACHMENT_INDEX => "attachment index record",
        mcap::records::op::STATISTICS => "statistics record",
        mcap::records::op::METADATA => "metadata record",
        mcap::records::op::METADATA_INDEX => "metadata index record",
        mcap::records::op::SUMMARY_OFFSET => "summary offset record",
        mcap::records::op::DATA_END => "data end record",
        _ => "record of unknown opcode",
    }
}

/// Reads the fields of one record (or chunk), every length checked against what is left.
pub(crate) struct Fields<'a> {
    data: &'a [u8],
    at: usize,
}

impl<'a> Fields<'a> {
    pub(crate) fn new(data: &'a [u8]) -> Fields<'a> {
        Fields { data, at: 0 }
    }

    /// The bytes read so far.
    pub(crate) fn position(&self) -> usize {
        self.at
    }

    pub(crate) fn left(&self) -> usize {
        self.data.len() - self.at
    }

    /// The bytes not read yet.
    pub(crate) fn rest(&self) -> &'a [u8] {
        &self.data[self.at..]
    }

    pub(crate) fn bytes(&mut self, n: u64, what: &str) -> Result<&'a [u8], String> {
        match usize::try_from(n).ok().filter(|&n| n <= self.left()) {
            Some(n) => {
                let out = &self.data[self.at..self.at + n];
                self.at += n;
                Ok(out)
            }
            None => Err(format!(
                "{what} of {n} bytes at byte {} of the record, which has only {} left",
                self.at,
                self.left()
            )),
        }
    }

    pub(crate) fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], String> {
        Ok(self.bytes(N as u64, what)?.try_into().expect("N bytes"))
    }

    pub(crate) fn u16(&mut self, what: &str) -> Result<u16, String> {
        Ok(u16::from_le_bytes(self.array(what)?))
    }

    pub(crate) fn u32(&mut self, what: &str) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }

    pub(crate) fn u64(&mut self, what: &str) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.array(what)?))
    }

    pub(crate) fn string(&mut self, what: &str) -> Result<String, String> {
        let len = self.u32(what)?;
        let bytes = self.bytes(len.into(), what)?;
        String::from_utf8(bytes.to_vec()).map_err(|_| format!("{what} is not UTF-8"))
    }

    pub(crate) fn string_map(&mut self, what: &str) -> Result<BTreeMap<String, String>, String> {
        let len = self.u32(what)?;
        let mut map = Fields::new(self.bytes(len.into(), what)?);
        let mut out = BTreeMap::new();
        while map.left() > 0 {
            let key = map.string("a metadata key")?;
            let value = map.string("a metadata value")?;
            if out.insert(key, value).is_some() {
                return Err(format!("{what} repeats a key"));
            }
        }
        Ok(out)
    }

    pub(crate) fn end(&self, what: &str) -> Result<(), String> {
        match self.left() {
            0 => Ok(()),
            n => Err(format!("{n} bytes left over after the {what}")),
        }
    }
}

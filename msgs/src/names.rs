//! How names and ids travel in self-describing formats.
//!
//! - A [`Name16`](crate::Name16) (model names, grid channels) is a text string in CBOR frames and
//!   recordings, so that any reader sees `"unet"`, not `[117, 110, 101, 116, 0, ...]`. Frames
//!   written before (wire version 1) carried the 16 bytes as an array of integers: still read.
//! - A `u64` id (`run_id`) is a text string in JSON and CSV: ids from the clock exceed 2^53, which
//!   a JavaScript number (a Foxglove panel) silently rounds. Integers are still read.

use crate::{name16, name16_str, Name16};
use serde::de::{self, SeqAccess, Visitor};
use serde::{Deserializer, Serializer};
use std::fmt;

/// Accepts a name as text, bytes, or a sequence of byte values.
struct NameVisitor;

impl<'de> Visitor<'de> for NameVisitor {
    type Value = Name16;
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a name (text of at most 16 bytes, or 16 byte values)")
    }
    fn visit_str<E: de::Error>(self, v: &str) -> Result<Name16, E> {
        if v.len() > 16 {
            return Err(E::custom(format!("name `{v}` is longer than 16 bytes")));
        }
        Ok(name16(v))
    }
    fn visit_bytes<E: de::Error>(self, v: &[u8]) -> Result<Name16, E> {
        let mut out = [0u8; 16];
        if v.len() > 16 {
            return Err(E::invalid_length(v.len(), &self));
        }
        out[..v.len()].copy_from_slice(v);
        Ok(out)
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Name16, A::Error> {
        let mut out = [0u8; 16];
        let mut i = 0;
        while let Some(b) = seq.next_element::<u8>()? {
            if i == 16 {
                return Err(de::Error::invalid_length(17, &self));
            }
            out[i] = b;
            i += 1;
        }
        Ok(out)
    }
}

/// One [`Name16`] as text.
pub mod text {
    use super::*;

    pub fn serialize<S: Serializer>(n: &Name16, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(name16_str(n))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Name16, D::Error> {
        d.deserialize_any(NameVisitor)
    }
}

/// A fixed array of [`Name16`] as an array of text strings.
pub mod text_array {
    use super::*;

    struct Any(Name16);
    impl<'de> serde::Deserialize<'de> for Any {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Any, D::Error> {
            d.deserialize_any(NameVisitor).map(Any)
        }
    }

    pub fn serialize<S: Serializer, const N: usize>(names: &[Name16; N], s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(names.iter().map(name16_str))
    }

    pub fn deserialize<'de, D: Deserializer<'de>, const N: usize>(d: D) -> Result<[Name16; N], D::Error> {
        struct ArrayVisitor<const N: usize>;
        impl<'de, const N: usize> Visitor<'de> for ArrayVisitor<N> {
            type Value = [Name16; N];
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                write!(f, "an array of at most {N} names")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<[Name16; N], A::Error> {
                let mut out = [[0u8; 16]; N];
                let mut i = 0;
                while let Some(Any(n)) = seq.next_element::<Any>()? {
                    if i == N {
                        return Err(de::Error::invalid_length(N + 1, &self));
                    }
                    out[i] = n;
                    i += 1;
                }
                Ok(out)
            }
        }
        d.deserialize_seq(ArrayVisitor::<N>)
    }
}

/// A `u64` id as a decimal text string (integers are read too).
pub mod id_text {
    use super::*;

    pub fn serialize<S: Serializer>(id: &u64, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(id)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<u64, D::Error> {
        struct IdVisitor;
        impl Visitor<'_> for IdVisitor {
            type Value = u64;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("an id (decimal text or an unsigned integer)")
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<u64, E> {
                Ok(v)
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<u64, E> {
                u64::try_from(v).map_err(|_| E::custom(format!("negative id {v}")))
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<u64, E> {
                v.parse().map_err(|_| E::custom(format!("`{v}` is not an id")))
            }
        }
        d.deserialize_any(IdVisitor)
    }
}

#[cfg(test)]
mod tests {
    use crate::*;
    use serde::Serialize;

    fn stats_header() -> SolveStatsHeader {
        SolveStatsHeader {
            step: StepHeader { run_id: 5, simulation: 1, step: 2 },
            model: name16("unet"),
            used_model: name16("builtin"),
            sweeps: 12,
            ..SolveStatsHeader::default()
        }
    }

    /// The CBOR value of a frame's header, as an independent reader sees it.
    fn header_value(bytes: &[u8]) -> ciborium::Value {
        let v: ciborium::Value = ciborium::from_reader(bytes).unwrap();
        v.as_map().unwrap().iter().find(|(k, _)| k.as_text() == Some("h")).unwrap().1.clone()
    }

    fn field<'a>(map: &'a ciborium::Value, name: &str) -> &'a ciborium::Value {
        &map.as_map().unwrap().iter().find(|(k, _)| k.as_text() == Some(name)).unwrap().1
    }

    #[test]
    fn names_are_text_on_the_wire() {
        let f = SolveStats::new(stats_header(), vec![1.0]);
        let h = header_value(&encode(&f).unwrap());
        assert_eq!(field(&h, "model").as_text(), Some("unet"));
        assert_eq!(field(&h, "used_model").as_text(), Some("builtin"));
        let g = Grid::zeros(StepHeader::default(), [0.0; 2], 1.0, 1, 1, &["normal", "tangent"]);
        let h = header_value(&encode(&g).unwrap());
        let names: Vec<&str> =
            field(&h, "channel_names").as_array().unwrap().iter().map(|v| v.as_text().unwrap()).collect();
        assert_eq!(names[..3], ["normal", "tangent", ""]);
    }

    #[test]
    fn version_1_frames_with_byte_array_names_still_decode() {
        // The layout of wire version 1: names as arrays of 16 integers.
        #[derive(Serialize)]
        struct OldStats {
            step: StepHeader,
            model: Name16,
            used_model: Name16,
        }
        let h = stats_header();
        // Today's header as a CBOR map, its name fields replaced by the old byte arrays.
        let mut full = ciborium::Value::serialized(&h).unwrap();
        let old = OldStats { step: h.step, model: h.model, used_model: h.used_model };
        let old_value = ciborium::Value::serialized(&old).unwrap();
        for (k, v) in full.as_map_mut().unwrap().iter_mut() {
            if let Some(ov) = old_value.as_map().unwrap().iter().find(|(ok, _)| ok == k) {
                *v = ov.1.clone();
            }
        }
        assert!(field(&full, "model").is_array(), "the old layout has byte arrays");
        let mut bytes = Vec::new();
        let wire = ciborium::Value::Map(vec![
            (ciborium::Value::Text("v".into()), ciborium::Value::Integer(1.into())),
            (ciborium::Value::Text("h".into()), full),
            (ciborium::Value::Text("i".into()), ciborium::Value::Bytes(vec![0, 0, 128, 63])),
        ]);
        ciborium::into_writer(&wire, &mut bytes).unwrap();
        let back: SolveStats = decode(&bytes).unwrap();
        assert_eq!(back.header, h);
        assert_eq!(back.items, [1.0]);
    }

    #[test]
    fn a_name_longer_than_16_bytes_is_refused() {
        let mut v = ciborium::Value::serialized(&stats_header()).unwrap();
        for (k, val) in v.as_map_mut().unwrap().iter_mut() {
            if k.as_text() == Some("model") {
                *val = ciborium::Value::Text("a-name-of-more-than-sixteen".into());
            }
        }
        assert!(v.deserialized::<SolveStatsHeader>().is_err());
    }
}

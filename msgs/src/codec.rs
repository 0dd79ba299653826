//! CBOR encoding of [`Frame`]s: `{ "v": version, "h": header, "i": bytes }`.
//!
//! Items travel as one CBOR byte string holding the packed little-endian elements. Decoding checks
//! the version, that the byte length is a whole number of elements, and copies into an aligned
//! `Vec` (a byte string inside a CBOR buffer has no alignment guarantee).

use crate::{Frame, FrameHeader, FrameItem};
use serde::{Deserialize, Serialize};

/// Version of the wire format; bumped when a layout changes. Version 2 writes names
/// (model, channels) as text strings; version 1 frames (names as byte arrays) are still read.
/// Version 3 appends the contact height to [`crate::ProblemContact`] (76 bytes); older frames
/// hold its first 72 bytes and read with height 0.
pub const WIRE_VERSION: u32 = 3;

/// The bytes an item of type `T` took in a frame of wire version `v`, where an older layout is a
/// prefix of today's (fields appended at the end); `None`: today's size.
fn legacy_item_size<T: 'static>(v: u32) -> Option<usize> {
    (v < 3 && std::any::TypeId::of::<T>() == std::any::TypeId::of::<crate::ProblemContact>()).then_some(72)
}
/// The oldest version still read.
pub const OLDEST_WIRE_VERSION: u32 = 1;

/// Why a payload could not be decoded.
#[derive(Debug, thiserror::Error)]
pub enum CodecError {
    #[error("not a valid CBOR frame: {0}")]
    Cbor(String),
    #[error("wire version {found} is not supported (expected {expected})")]
    Version { found: u32, expected: u32 },
    #[error("item bytes ({bytes}) are not a whole number of {item_size}-byte `{item_type}` elements")]
    Length { bytes: usize, item_size: usize, item_type: &'static str },
    #[error("a frame of {bytes} bytes is larger than any topic carries ({max} bytes)")]
    TooLarge { bytes: usize, max: usize },
    #[error("could not encode frame: {0}")]
    Encode(String),
}

#[derive(Serialize)]
struct WireOut<'a, H> {
    v: u32,
    h: &'a H,
    #[serde(with = "serde_bytes")]
    i: &'a [u8],
}

#[derive(Deserialize)]
struct WireIn<H> {
    v: u32,
    h: H,
    #[serde(with = "serde_bytes")]
    i: Vec<u8>,
}

/// Header only, to peek at a payload without copying its items.
#[derive(Deserialize)]
struct WireHeader<H> {
    v: u32,
    h: H,
}

/// Encodes a header and items into `out` (cleared first), reusing its allocation.
pub fn encode_into<H: FrameHeader, T: FrameItem>(header: &H, items: &[T], out: &mut Vec<u8>) -> Result<(), CodecError> {
    out.clear();
    let wire = WireOut { v: WIRE_VERSION, h: header, i: bytemuck::cast_slice(items) };
    ciborium::into_writer(&wire, out).map_err(|e| CodecError::Encode(e.to_string()))
}

/// Encodes a frame as CBOR bytes.
pub fn encode<H: FrameHeader, T: FrameItem>(frame: &Frame<H, T>) -> Result<Vec<u8>, CodecError> {
    let mut out = Vec::with_capacity(64 + std::mem::size_of_val(frame.items.as_slice()));
    encode_into(&frame.header, &frame.items, &mut out)?;
    Ok(out)
}

/// Decodes CBOR bytes into a frame, checking version and item length.
pub fn decode<H: FrameHeader, T: FrameItem>(bytes: &[u8]) -> Result<Frame<H, T>, CodecError> {
    if bytes.len() > MAX_FRAME_BYTES {
        return Err(CodecError::TooLarge { bytes: bytes.len(), max: MAX_FRAME_BYTES });
    }
    let mut rest = bytes;
    if let Some((header, len)) = envelope::<H, T>(&mut rest) {
        if let Some(items) = rest.get(..len) {
            return Ok(Frame { header, items: bytemuck::pod_collect_to_vec(items) });
        }
    }
    decode_any(bytes)
}

/// The largest frame a reader accepts, in bytes: items a frame claims beyond it are refused
/// before anything is allocated, whatever the bytes present (1,000,000 bodies are 48 MB).
pub const MAX_FRAME_BYTES: usize = 256 << 20;

/// Decodes a frame from a payload of `total` bytes read in pieces (a zenoh sample's slices),
/// copying its items once, straight into their aligned vector. `None` when the payload is not
/// laid out as [`encode`] writes frames (or is not valid), and before allocating anything when
/// its items claim more bytes than the payload has left or than [`MAX_FRAME_BYTES`]: a peer's
/// length is never trusted. [`decode`] the whole bytes then, which reads any valid frame and
/// says what is wrong with an invalid one.
pub fn decode_reader<H: FrameHeader, T: FrameItem>(reader: impl std::io::Read, total: usize) -> Option<Frame<H, T>> {
    let mut counted = Counted { inner: reader, read: 0 };
    let (header, len) = envelope::<H, T>(&mut counted)?;
    let left = total.checked_sub(counted.read)?;
    (len <= left && len <= MAX_FRAME_BYTES).then_some(())?;
    let mut items = vec![T::zeroed(); len / std::mem::size_of::<T>()];
    counted.inner.read_exact(bytemuck::cast_slice_mut(&mut items)).ok()?;
    Some(Frame { header, items })
}

/// A reader that counts the bytes read through it.
struct Counted<R> {
    inner: R,
    read: usize,
}

impl<R: std::io::Read> std::io::Read for Counted<R> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(out)?;
        self.read += n;
        Ok(n)
    }
}

/// The header of a frame laid out as [`encode`] writes it (a map of `v`, `h`, `i` in this
/// order, today's wire version, the items a definite-length byte string of whole items), and the
/// items' byte length; the reader is left at the first item byte. `None` for anything else.
/// Without it a frame's items were copied three times (CBOR reader, growing vector, aligned
/// vector), each into fresh pages: most of a large frame's time over zenoh.
fn envelope<H: FrameHeader, T: FrameItem>(mut r: impl std::io::Read) -> Option<(H, usize)> {
    let r = &mut r;
    (byte(r)? == 0xa3).then_some(())?;
    key(r, b'v')?;
    let v = byte(r)?;
    (v >> 5 == 0 && argument(r, v)? == WIRE_VERSION as u64).then_some(())?;
    key(r, b'h')?;
    let header: H = ciborium::from_reader(&mut *r).ok()?;
    key(r, b'i')?;
    let head = byte(r)?;
    (head >> 5 == 2).then_some(())?;
    let len = usize::try_from(argument(r, head)?).ok()?;
    let size = std::mem::size_of::<T>();
    (size > 0 && len.is_multiple_of(size)).then_some((header, len))
}

fn byte(r: &mut impl std::io::Read) -> Option<u8> {
    let mut b = [0u8; 1];
    r.read_exact(&mut b).ok().map(|()| b[0])
}

/// The argument of the CBOR head whose first byte is `first` (an unsigned integer's value, a
/// byte string's length); `None` for an indefinite length.
fn argument(r: &mut impl std::io::Read, first: u8) -> Option<u64> {
    let n = match first & 0x1f {
        a @ 0..=23 => return Some(a as u64),
        24 => 1,
        25 => 2,
        26 => 4,
        27 => 8,
        _ => return None,
    };
    let mut b = [0u8; 8];
    r.read_exact(&mut b[8 - n..]).ok()?;
    Some(u64::from_be_bytes(b))
}

/// A one-letter text string key.
fn key(r: &mut impl std::io::Read, k: u8) -> Option<()> {
    (byte(r)? == 0x61 && byte(r)? == k).then_some(())
}

/// Decodes any valid CBOR frame (keys in any order, byte strings in pieces, older versions).
fn decode_any<H: FrameHeader, T: FrameItem>(bytes: &[u8]) -> Result<Frame<H, T>, CodecError> {
    let wire: WireIn<H> = ciborium::from_reader(bytes).map_err(|e| CodecError::Cbor(e.to_string()))?;
    check_version(wire.v)?;
    let size = legacy_item_size::<T>(wire.v).unwrap_or(std::mem::size_of::<T>());
    if size == 0 || !wire.i.len().is_multiple_of(size) {
        return Err(CodecError::Length { bytes: wire.i.len(), item_size: size, item_type: std::any::type_name::<T>() });
    }
    if size != std::mem::size_of::<T>() {
        // An older, shorter layout: each item's bytes are the start of today's, the rest zero.
        let items = wire
            .i
            .chunks_exact(size)
            .map(|old| {
                let mut item = T::zeroed();
                bytemuck::bytes_of_mut(&mut item)[..size].copy_from_slice(old);
                item
            })
            .collect();
        return Ok(Frame { header: wire.h, items });
    }
    let items: Vec<T> = bytemuck::pod_collect_to_vec(&wire.i);
    Ok(Frame { header: wire.h, items })
}

/// Decodes only the header of a CBOR frame.
pub fn decode_header<H: FrameHeader>(bytes: &[u8]) -> Result<H, CodecError> {
    let wire: WireHeader<H> = ciborium::from_reader(bytes).map_err(|e| CodecError::Cbor(e.to_string()))?;
    check_version(wire.v)?;
    Ok(wire.h)
}

fn check_version(v: u32) -> Result<(), CodecError> {
    if !(OLDEST_WIRE_VERSION..=WIRE_VERSION).contains(&v) {
        return Err(CodecError::Version { found: v, expected: WIRE_VERSION });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::*;

    #[test]
    fn contacts_round_trip_bit_identical() {
        let c = ProblemContact { body_a: 1, body_b: 2, age: 3, reference: [f32::NAN, -0.0], ..Default::default() };
        let h = ProblemHeader { bodies: 3, tolerance: 1e-4, max_sweeps: 1000, ..Default::default() };
        let f = ProblemContacts::new(h, vec![c; 5]);
        let back: ProblemContacts = crate::decode(&crate::encode(&f).unwrap()).unwrap();
        assert_eq!(back.header, f.header);
        assert_eq!(bytemuck::cast_slice::<_, u8>(&back.items), bytemuck::cast_slice::<_, u8>(&f.items));
    }

    #[test]
    fn problem_contacts_of_wire_version_2_read_with_height_zero() {
        // A version-2 frame: 72-byte contacts (no height).
        let c =
            ProblemContact { body_a: 1, body_b: 2, age: 3, previous: [0.5, -0.25], height: 7.0, ..Default::default() };
        let old: Vec<u8> = [c, c].iter().flat_map(|c| bytemuck::bytes_of(c)[..72].to_vec()).collect();
        #[derive(Serialize)]
        struct Old<'a> {
            v: u32,
            h: ProblemHeader,
            #[serde(with = "serde_bytes")]
            i: &'a [u8],
        }
        let mut bytes = Vec::new();
        ciborium::into_writer(&Old { v: 2, h: ProblemHeader::default(), i: &old }, &mut bytes).unwrap();
        let frame: ProblemContacts = decode(&bytes).unwrap();
        assert_eq!(frame.items, vec![ProblemContact { height: 0.0, ..c }; 2]);
        // Today's frames keep the height; a version-3 frame of 72-byte items is refused.
        let now: ProblemContacts = decode(&encode(&Frame::new(ProblemHeader::default(), vec![c])).unwrap()).unwrap();
        assert_eq!(now.items, vec![c]);
        let mut bytes = Vec::new();
        ciborium::into_writer(&Old { v: 3, h: ProblemHeader::default(), i: &old }, &mut bytes).unwrap();
        assert!(decode::<ProblemHeader, ProblemContact>(&bytes).unwrap_err().to_string().contains("76"));
    }

    fn bodies(n: usize) -> Bodies {
        let items = (0..n)
            .map(|i| Body {
                id: i as u32,
                shape: Shape::Ball as u32,
                size: [0.5, 0.5],
                mass: 1.0,
                inertia: 0.125,
                x: i as f32 * 0.25,
                y: -(i as f32),
                angle: 0.1,
                vx: f32::MIN_POSITIVE,
                vy: -0.0,
                omega: f32::NAN,
            })
            .collect();
        Frame::new(StepHeader { run_id: 7, simulation: 3, step: 42 }, items)
    }

    fn bits(b: &[Body]) -> &[u8] {
        bytemuck::cast_slice(b)
    }

    #[test]
    fn bodies_round_trip_bit_identical() {
        let f = bodies(1000);
        let back: Bodies = decode(&encode(&f).unwrap()).unwrap();
        assert_eq!(back.header, f.header);
        // NaN and -0.0 must survive: compare bits, not values.
        assert_eq!(bits(&back.items), bits(&f.items));
    }

    #[test]
    fn items_travel_as_one_byte_string() {
        let f = bodies(100);
        let bytes = encode(&f).unwrap();
        // Packed bytes plus a small envelope; per-field CBOR would be several times larger.
        assert!(bytes.len() < 100 * 48 + 128, "{} bytes", bytes.len());
    }

    #[test]
    fn grid_and_control_round_trip() {
        let mut g = Grid::zeros(StepHeader::default(), [1.0, 2.0], 0.125, 5, 4, &["vx", "vy"]);
        g.items.iter_mut().enumerate().for_each(|(i, v)| *v = i as f32);
        let back: Grid = decode(&encode(&g).unwrap()).unwrap();
        assert_eq!(back, g);
        let c = ControlMsg::simple(StepHeader::default(), ControlKind::RunEnd, 3);
        let back: ControlMsg = decode(&encode(&c).unwrap()).unwrap();
        assert_eq!(back, c);
        assert_eq!(back.header.kind(), Some(ControlKind::RunEnd));
    }

    #[test]
    fn truncated_payload_is_an_error_not_a_panic() {
        let bytes = encode(&bodies(10)).unwrap();
        for cut in [0, 1, 5, bytes.len() / 2, bytes.len() - 1] {
            assert!(decode::<StepHeader, Body>(&bytes[..cut]).is_err(), "cut at {cut}");
        }
    }

    #[test]
    fn garbage_payload_is_an_error() {
        let garbage: Vec<u8> = (0..200u32).map(|i| (i * 37 % 251) as u8).collect();
        assert!(matches!(decode::<StepHeader, Body>(&garbage), Err(CodecError::Cbor(_))));
    }

    #[test]
    fn item_length_must_be_whole_elements() {
        #[derive(Serialize)]
        struct Bad<'a> {
            v: u32,
            h: StepHeader,
            #[serde(with = "serde_bytes")]
            i: &'a [u8],
        }
        let mut bytes = Vec::new();
        ciborium::into_writer(&Bad { v: WIRE_VERSION, h: StepHeader::default(), i: &[0u8; 50] }, &mut bytes).unwrap();
        let err = decode::<StepHeader, Body>(&bytes).unwrap_err();
        assert!(matches!(err, CodecError::Length { bytes: 50, item_size: 48, .. }), "{err}");
    }

    #[test]
    fn wrong_version_is_refused() {
        let mut bytes = Vec::new();
        ciborium::into_writer(&WireOut { v: 99, h: &StepHeader::default(), i: &[] }, &mut bytes).unwrap();
        assert!(matches!(decode::<StepHeader, Body>(&bytes), Err(CodecError::Version { found: 99, .. })));
        assert!(decode_header::<StepHeader>(&bytes).is_err());
    }

    /// A reader that hands out at most `piece` bytes a call, as a payload in fragments does.
    struct Pieces<'a> {
        bytes: &'a [u8],
        piece: usize,
    }

    impl std::io::Read for Pieces<'_> {
        fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
            let n = out.len().min(self.piece).min(self.bytes.len());
            out[..n].copy_from_slice(&self.bytes[..n]);
            self.bytes = &self.bytes[n..];
            Ok(n)
        }
    }

    #[test]
    fn frames_read_in_pieces_equal_the_general_decoders() {
        let f = bodies(1000);
        let mut g = Grid::zeros(StepHeader { run_id: 1, simulation: 2, step: 3 }, [1.0, 2.0], 0.125, 64, 64, &["vx"]);
        g.items.iter_mut().enumerate().for_each(|(i, v)| *v = -(i as f32));
        let (fb, gb) = (encode(&f).unwrap(), encode(&g).unwrap());
        for piece in [1, 7, 4096, usize::MAX] {
            let back: Bodies = decode_reader(Pieces { bytes: &fb, piece }, fb.len()).expect("encode's layout");
            assert_eq!(back.header, f.header);
            assert_eq!(bits(&back.items), bits(&f.items));
            let back: Grid = decode_reader(Pieces { bytes: &gb, piece }, gb.len()).expect("encode's layout");
            assert_eq!(back, g);
        }
        // The slice decoder's fast path and the general decoder agree bit for bit.
        assert_eq!(
            bits(&decode::<StepHeader, Body>(&fb).unwrap().items),
            bits(&decode_any::<StepHeader, Body>(&fb).unwrap().items)
        );
        assert_eq!(decode::<GridHeader, f32>(&gb).unwrap(), decode_any(&gb).unwrap());
        // An empty frame.
        let empty = Frame::new(StepHeader::default(), Vec::<Body>::new());
        assert_eq!(
            decode_reader::<StepHeader, Body>(encode(&empty).unwrap().as_slice(), encode(&empty).unwrap().len()),
            Some(empty)
        );
    }

    #[test]
    fn other_valid_layouts_leave_the_fast_path_and_still_decode() {
        let f = bodies(10);
        let items: &[u8] = bytemuck::cast_slice(&f.items);
        // Keys in another order (as another writer may put them).
        #[derive(Serialize)]
        struct Reordered<'a> {
            #[serde(with = "serde_bytes")]
            i: &'a [u8],
            h: StepHeader,
            v: u32,
        }
        let mut reordered = Vec::new();
        ciborium::into_writer(&Reordered { i: items, h: f.header, v: WIRE_VERSION }, &mut reordered).unwrap();
        // The items as an indefinite-length byte string in two chunks (0x5f ... 0xff).
        let mut chunked = encode(&Frame::new(f.header, Vec::<Body>::new())).unwrap();
        chunked.truncate(chunked.len() - 1); // drop the empty byte string's head (0x40)
        chunked.push(0x5f);
        for half in items.chunks(items.len() / 2) {
            chunked.push(0x59);
            chunked.extend_from_slice(&(half.len() as u16).to_be_bytes());
            chunked.extend_from_slice(half);
        }
        chunked.push(0xff);
        for bytes in [&reordered, &chunked] {
            assert!(decode_reader::<StepHeader, Body>(bytes.as_slice(), bytes.len()).is_none());
            let back: Bodies = decode(bytes).unwrap();
            assert_eq!(back.header, f.header);
            assert_eq!(bits(&back.items), bits(&f.items));
        }
    }

    #[test]
    fn invalid_payloads_leave_the_fast_path_with_the_general_decoders_error() {
        let bytes = encode(&bodies(10)).unwrap();
        for cut in [0, 1, 5, 30, bytes.len() - 1] {
            assert!(decode_reader::<StepHeader, Body>(&bytes[..cut], cut).is_none(), "cut at {cut}");
        }
        // A frame of contacts read as bodies: 76-byte items are not whole 48-byte bodies.
        let contacts =
            encode(&ProblemContacts::new(ProblemHeader::default(), vec![ProblemContact::default(); 3])).unwrap();
        assert!(decode_reader::<ProblemHeader, Body>(contacts.as_slice(), contacts.len()).is_none());
        assert!(matches!(decode::<ProblemHeader, Body>(&contacts), Err(CodecError::Length { .. })));
        // Another wire version goes the general way (and is refused there).
        let mut future = bytes.clone();
        future[3] = 0x09;
        assert!(decode_reader::<StepHeader, Body>(future.as_slice(), future.len()).is_none());
        assert!(matches!(decode::<StepHeader, Body>(&future), Err(CodecError::Version { found: 9, .. })));
    }

    #[test]
    fn an_items_length_beyond_the_bytes_present_is_refused_before_allocating() {
        // The forged control frame of the probe: items claiming 2^40 bytes, padded to 300 kB.
        let mut forged = encode(&Frame::new(Control::default(), Vec::<u8>::new())).unwrap();
        forged.truncate(forged.len() - 1); // the empty byte string's head (0x40)
        forged.push(0x5b); // a byte string with an 8-byte length
        forged.extend_from_slice(&(1u64 << 40).to_be_bytes());
        forged.resize(300_000, 0);
        for piece in [1, 4096, usize::MAX] {
            assert!(decode_reader::<Control, u8>(Pieces { bytes: &forged, piece }, forged.len()).is_none());
        }
        assert!(decode::<Control, u8>(&forged).is_err());
        // A payload that says it is longer than it is (a lying `total`) still stops at the bytes.
        let ok = encode(&bodies(10)).unwrap();
        assert!(decode_reader::<StepHeader, Body>(&ok[..ok.len() - 48], ok.len()).is_none());
        assert!(decode_reader::<StepHeader, Body>(&ok[..], ok.len() - 1).is_none());
    }
}

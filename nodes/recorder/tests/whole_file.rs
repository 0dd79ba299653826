//! What lies around a recording's records: which file `recover` writes (never its input, under
//! any name; never a half-written output), what follows the footer (another recording appended,
//! junk), and the summary section that indexed readers go by (footer offsets, chunk indexes).
//! Each case is checked through the library and through `dc-record` as a user types it.

mod common;

use common::*;
use recorder::read::ReadOptions;
use recorder::recover::recover;
use recorder::Info;
use std::path::{Path, PathBuf};
use std::process::Output;

const LENIENT: ReadOptions = ReadOptions { any_wire_version: false, lenient: true };
const FOOTER: u8 = mcap::records::op::FOOTER;
const CHUNK_INDEX: u8 = mcap::records::op::CHUNK_INDEX;

/// `dc-record ARGS...`, its output captured.
fn dc_record(args: &[&Path]) -> Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_dc-record")).args(args).output().unwrap()
}

/// What `dc-record` printed, both streams.
fn printed(out: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr))
}

/// The names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    names
}

/// Adds `delta` to the little-endian `u64` at `at`.
fn add_u64(bytes: &mut [u8], at: usize, delta: i64) {
    let v = u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
    bytes[at..at + 8].copy_from_slice(&v.wrapping_add_signed(delta).to_le_bytes());
}

/// The footer record of an intact file, its summary CRC zeroed (no CRC: only the other checks
/// of the summary can catch what a test damages).
fn footer_without_crc(bytes: &mut [u8]) -> RecordAt {
    let footer = *records(bytes).last().unwrap();
    assert_eq!(footer.opcode, FOOTER);
    bytes[footer.offset + 9 + 16..footer.offset + 9 + 20].fill(0);
    footer
}

/// `bytes` written as `name` in `dir`.
fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let file = dir.join(name);
    std::fs::write(&file, bytes).unwrap();
    file
}

#[test]
fn recover_refuses_an_output_that_is_its_input_under_another_name() {
    // The issue's case: a hard link as the output truncated the input ("failed to fill whole
    // buffer"); the check compared paths. A file larger than the reader's 64 KiB buffer.
    let dir = scratch("same-file");
    let input = dir.join("a.mcap");
    let total = chunked_fixture(&input, 1, 4, 300, 20);
    let original = std::fs::read(&input).unwrap();
    assert!(original.len() > 1 << 16, "{} bytes", original.len());
    let hard = dir.join("hard.mcap");
    std::fs::hard_link(&input, &hard).unwrap();
    let soft = dir.join("soft.mcap");
    std::os::unix::fs::symlink(&input, &soft).unwrap();
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    let outputs = [hard.clone(), soft, dir.join(".").join("a.mcap"), dir.join("sub/../a.mcap")];
    for output in &outputs {
        let e = recover(&input, output).expect_err("recover over its own input");
        let text = e.to_string();
        assert!(text.contains(&*input.to_string_lossy()) && text.contains(&*output.to_string_lossy()), "{text}");
        assert!(text.contains("same file"), "{text}");
        assert!(std::fs::read(&input).unwrap() == original, "{}: the input changed", output.display());
    }
    // The input named by the link, the output by its own name.
    assert!(recover(&hard, &input).is_err());
    let out = dc_record(&[Path::new("recover"), &input, &hard]);
    assert!(!out.status.success(), "{}", printed(&out));
    assert!(printed(&out).contains("same file"), "{}", printed(&out));
    assert!(std::fs::read(&input).unwrap() == original, "dc-record recover changed its input");
    assert_eq!(Info::read(&input).unwrap().messages, total);
}

#[test]
fn a_failed_recover_leaves_the_existing_output_as_it_was() {
    let dir = scratch("failed-recover");
    let output = dir.join("out.mcap");
    fixture(&output, 1, 1, 3);
    let before = std::fs::read(&output).unwrap();
    let junk = write(&dir, "junk.mcap", &[mcap::MAGIC, &b"junk".repeat(50)[..]].concat());
    recover(&junk, &output).expect_err("nothing to recover");
    assert!(std::fs::read(&output).ok() == Some(before.clone()), "the output was truncated or removed");
    let out = dc_record(&[Path::new("recover"), &junk, &output]);
    assert!(!out.status.success(), "{}", printed(&out));
    assert!(std::fs::read(&output).ok() == Some(before), "dc-record recover truncated or removed the output");
    assert_eq!(names(&dir), ["junk.mcap", "out.mcap"], "a temporary file was left behind");
    // A recover that succeeds replaces the output whole.
    let input = dir.join("in.mcap");
    let total = fixture(&input, 2, 2, 5);
    assert_eq!(recover(&input, &output).unwrap().messages, total);
    assert_eq!(Info::read(&output).unwrap().messages, total);
    assert_eq!(names(&dir), ["in.mcap", "junk.mcap", "out.mcap"]);
}

#[test]
fn concatenated_recordings_are_reported_by_info_and_all_kept_by_recover() {
    // `cat a.mcap b.mcap > c.mcap`: recover said the input was intact and dropped b's messages;
    // info exited 0.
    let dir = scratch("concatenated");
    let (a, b) = (dir.join("a.mcap"), dir.join("b.mcap"));
    let in_a = chunked_fixture(&a, 1, 2, 30, 10);
    let in_b = chunked_fixture(&b, 2, 1, 40, 10);
    let a_bytes = std::fs::read(&a).unwrap();
    let second = a_bytes.len();
    let c = write(&dir, "c.mcap", &[a_bytes, std::fs::read(&b).unwrap()].concat());

    // A strict reader stops where the second recording starts.
    let e = Info::read(&c).expect_err("two recordings in one file");
    assert!(e.to_string().contains(&format!("at byte {second}")), "{e}");
    assert!(e.to_string().contains("another MCAP recording"), "{e}");
    // A lenient one reads both and says where the second starts; `dc-record info` fails.
    let info = Info::read_with(&c, LENIENT).unwrap();
    assert_eq!(info.messages, in_a + in_b);
    assert_eq!(info.simulations.len(), 3);
    assert!(info.to_string().contains(&format!("another recording starts at byte {second}")), "{info}");
    let out = dc_record(&[Path::new("info"), &c]);
    assert!(!out.status.success(), "{}", printed(&out));
    assert!(printed(&out).contains("2 recordings concatenated"), "{}", printed(&out));

    // recover keeps both, in one recording, and says so.
    let r = recover(&c, &dir.join("out.mcap")).unwrap();
    assert_eq!(r.messages, in_a + in_b, "{r}");
    assert!(r.to_string().contains(&format!("another recording starts at byte {second}")), "{r}");
    let back = Info::read(&dir.join("out.mcap")).unwrap();
    assert_eq!((back.messages, back.simulations.len()), (in_a + in_b, 3));

    // A killed recording with another appended: every intact chunk of both.
    let a_bytes = std::fs::read(&a).unwrap();
    let killed = &a_bytes[..data_end(&a_bytes)];
    let joined = write(&dir, "killed-then-b.mcap", &[killed, &std::fs::read(&b).unwrap()].concat());
    let r = recover(&joined, &dir.join("out2.mcap")).unwrap();
    assert_eq!(r.messages, in_a + in_b, "{r}");
    assert!(r.to_string().contains(&format!("another recording starts at byte {}", killed.len())), "{r}");
}

#[test]
fn junk_after_the_closing_magic_is_reported_not_ignored() {
    let dir = scratch("trailing");
    let good = dir.join("good.mcap");
    let total = fixture(&good, 1, 2, 5);
    let size = std::fs::metadata(&good).unwrap().len();
    let bad = write(&dir, "bad.mcap", &[std::fs::read(&good).unwrap(), b"trailing junk".to_vec()].concat());
    let e = Info::read(&bad).expect_err("bytes after the end");
    assert!(e.to_string().contains(&format!("at byte {size}")), "{e}");
    let out = dc_record(&[Path::new("info"), &bad]);
    assert!(!out.status.success(), "{}", printed(&out));
    assert!(printed(&out).contains("after the recording's closing magic"), "{}", printed(&out));
    let r = recover(&bad, &dir.join("out.mcap")).unwrap();
    assert_eq!(r.messages, total);
    assert_eq!(r.damage.len(), 1, "{r}");
    assert_eq!(r.damage[0].offset, size, "{r}");
}

#[test]
fn info_reports_a_footer_whose_summary_offsets_are_wrong() {
    let dir = scratch("bad-footer");
    let good = dir.join("good.mcap");
    fixture(&good, 1, 2, 5);
    let out = dc_record(&[Path::new("info"), &good]);
    assert!(out.status.success(), "{}", printed(&out));
    for (field, name) in [(0, "summary start"), (8, "summary offset start")] {
        let mut bytes = std::fs::read(&good).unwrap();
        let footer = footer_without_crc(&mut bytes);
        add_u64(&mut bytes, footer.offset + 9 + field, -9);
        let bad = write(&dir, &format!("bad-{field}.mcap"), &bytes);
        let info = Info::read(&bad).unwrap();
        assert!(info.to_string().contains(&format!("the footer's {name} is")), "{name}: {info}");
        let out = dc_record(&[Path::new("info"), &bad]);
        assert_eq!(out.status.code(), Some(1), "{name}: {}", printed(&out));
        assert!(printed(&out).contains(&format!("bad summary section at byte {}", footer.offset)), "{}", printed(&out));
    }
}

#[test]
fn info_reports_chunk_indexes_that_do_not_match_their_chunk() {
    let dir = scratch("bad-chunk-index");
    let good = dir.join("good.mcap");
    chunked_fixture(&good, 1, 2, 100, 20);
    let original = std::fs::read(&good).unwrap();
    let indexes: Vec<RecordAt> = records(&original).into_iter().filter(|r| r.opcode == CHUNK_INDEX).collect();
    assert!(indexes.len() >= 10, "{} chunk indexes", indexes.len());
    let index = indexes[3];
    // Fields: start and end time, chunk start offset, chunk length.
    for (field, delta, what) in [(16, 1, "no intact chunk"), (16, -1, "no intact chunk"), (24, 7, "chunk length")] {
        let mut bytes = original.clone();
        footer_without_crc(&mut bytes);
        add_u64(&mut bytes, index.offset + 9 + field, delta);
        let bad = write(&dir, &format!("bad-{field}-{delta}.mcap"), &bytes);
        let info = Info::read(&bad).unwrap();
        let text = info.to_string();
        assert!(
            text.contains(&format!("at byte {}: chunk index record", index.offset)) && text.contains(what),
            "{text}"
        );
        let out = dc_record(&[Path::new("info"), &bad]);
        assert_eq!(out.status.code(), Some(1), "{}", printed(&out));
        // recover writes a new summary: its output is sound.
        let fixed = dir.join("fixed.mcap");
        let r = recover(&bad, &fixed).unwrap();
        assert!(r.to_string().contains("the output has a new one"), "{r}");
        assert!(dc_record(&[Path::new("info"), &fixed]).status.success());
    }
}

#[test]
fn a_flipped_byte_in_the_summary_fails_its_crc() {
    let dir = scratch("summary-crc");
    let good = dir.join("good.mcap");
    fixture(&good, 1, 2, 5);
    let mut bytes = std::fs::read(&good).unwrap();
    let statistics = records(&bytes).into_iter().find(|r| r.opcode == mcap::records::op::STATISTICS).unwrap();
    bytes[statistics.offset + 9 + 12] ^= 0x01; // in the channel count: no other check reads it
    let bad = write(&dir, "bad.mcap", &bytes);
    let info = Info::read(&bad).unwrap();
    assert!(info.to_string().contains("summary CRC does not match"), "{info}");
    assert_eq!(dc_record(&[Path::new("info"), &bad]).status.code(), Some(1));
}

//! Damaged recordings: the readers never trust a length (an error naming the file and the byte,
//! never a panic or a huge allocation), and `recover` skips a damaged chunk and resumes at the
//! next intact record.

mod common;

use common::*;
use recorder::read::{ReadOptions, RecordingReader};
use recorder::recover::recover;
use recorder::{Error, Info, Steps};
use std::path::Path;

const LENIENT: ReadOptions = ReadOptions { any_wire_version: false, lenient: true };

/// Every message of `file` read strictly, or the error.
fn strict_messages(file: &Path) -> Result<u64, Error> {
    let mut reader = RecordingReader::open(file)?;
    let mut n = 0;
    while let Some(m) = reader.next_message() {
        m?;
        n += 1;
    }
    Ok(n)
}

#[test]
fn junk_after_the_magic_is_an_error_naming_the_file_and_the_byte() {
    let dir = scratch("junk");
    let magic = mcap::MAGIC.to_vec();
    let huge =
        |opcode: u8, len: u64| [magic.clone(), vec![opcode], len.to_le_bytes().to_vec(), b"junk".repeat(10)].concat();
    // A header record whose profile string claims 4 GiB.
    let mut long_string = magic.clone();
    long_string.push(0x01);
    long_string.extend(12u64.to_le_bytes());
    long_string.extend(u32::MAX.to_le_bytes());
    long_string.extend([0u8; 8]);
    let cases = [
        ("random", [magic.clone(), (0..200u32).map(|i| (i * 131 % 251) as u8 ^ 0x5a).collect()].concat()),
        ("max-length", huge(0x01, u64::MAX)),
        ("overflowing-length", huge(0x06, u64::MAX - 4)),
        ("exabyte-chunk", huge(0x06, 1 << 60)),
        ("long-string", long_string),
        ("magic-only", magic.clone()),
        ("torn-header", [magic.clone(), vec![0x01, 3, 0]].concat()),
    ];
    for (name, bytes) in cases {
        let file = dir.join(format!("{name}.mcap"));
        std::fs::write(&file, &bytes).unwrap();
        let shown = file.display().to_string();
        let e = Info::read(&file).unwrap_err();
        assert!(matches!(e, Error::Damaged { offset: 8.., .. }), "{name}: {e}");
        assert!(e.to_string().contains(&shown) && e.to_string().contains("at byte"), "{name}: {e}");
        let e = strict_messages(&file).unwrap_err();
        assert!(e.to_string().contains(&shown), "{name}: {e}");
        let e = Steps::open(&file).unwrap().find_map(Result::err).expect("an error");
        assert!(e.to_string().contains(&shown), "{name}: {e}");
        // Nothing to keep: an error, and no output left behind.
        let out = dir.join(format!("{name}-recovered.mcap"));
        let e = recover(&file, &out).unwrap_err();
        assert!(matches!(e, Error::NothingRecovered { .. }), "{name}: {e}");
        assert!(e.to_string().contains(&shown), "{name}: {e}");
        assert!(!out.exists(), "{name}");
    }
}

#[test]
fn a_strict_reader_names_the_damaged_chunk_and_why() {
    let dir = scratch("strict-damage");
    let good = dir.join("good.mcap");
    chunked_fixture(&good, 1, 2, 100, 20);
    let mut bytes = std::fs::read(&good).unwrap();
    let (chunk, _) = chunks(&bytes)[3];
    bytes[chunk.end() - 10] ^= 0x10; // in the compressed records
    let bad = dir.join("bad.mcap");
    std::fs::write(&bad, &bytes).unwrap();
    for e in [Info::read(&bad).unwrap_err(), strict_messages(&bad).unwrap_err()] {
        match &e {
            Error::Damaged { offset, detail, .. } => {
                assert_eq!(*offset, chunk.offset as u64, "{e}");
                assert!(detail.contains("chunk"), "{e}");
            }
            other => panic!("not a damage error: {other}"),
        }
        assert!(e.to_string().contains("bad.mcap"), "{e}");
    }
}

#[test]
fn one_flipped_byte_in_chunk_3_loses_only_chunk_3() {
    // The case: 606 messages, a byte of chunk 3 flipped; recover kept 49 and threw away
    // the intact chunks after it.
    let dir = scratch("flip-one");
    let good = dir.join("good.mcap");
    let total = chunked_fixture(&good, 1, 2, 100, 20);
    assert_eq!(total, 606);
    let mut bytes = std::fs::read(&good).unwrap();
    let all = chunks(&bytes);
    assert!(all.len() >= 10, "{} chunks", all.len());
    let (chunk, in_chunk) = all[3];
    bytes[chunk.offset + 9 + chunk.len / 2] ^= 0x01;
    let bad = dir.join("bad.mcap");
    std::fs::write(&bad, &bytes).unwrap();

    let r = recover(&bad, &dir.join("recovered.mcap")).unwrap();
    eprintln!("kept {} of {total} messages; chunk 3 held {in_chunk}\n{r}", r.messages);
    assert_eq!(r.messages, total - in_chunk);
    assert_eq!(r.damage.len(), 1, "{r}");
    assert_eq!(r.damage[0].offset, chunk.offset as u64);
    assert_eq!(r.damage[0].resumed_at, Some(chunk.end() as u64), "{r}");
    // What was skipped, per topic, from the chunk's message indexes: 20 steps of 3 topics.
    assert_eq!(r.skipped.values().sum::<u64>(), in_chunk, "{r}");
    assert_eq!(r.skipped.get("bodies"), Some(&20), "{r}");
    assert_eq!(r.kept["bodies"] + r.skipped["bodies"], 200, "{r}");
    assert_eq!(Info::read(&dir.join("recovered.mcap")).unwrap().messages, total - in_chunk);

    // Lenient info counts the same and lists the damage; strict info refuses.
    let info = Info::read_with(&bad, LENIENT).unwrap();
    assert_eq!(info.messages, total - in_chunk);
    assert_eq!(info.damage, r.damage);
    assert!(info.to_string().contains(&format!("at byte {}", chunk.offset)), "{info}");
    assert!(Info::read(&bad).is_err());
}

#[test]
fn a_flipped_byte_loses_at_most_its_chunk_wherever_it_is() {
    // Every chunk of a finished file and of the same file cut where a killed writer's ends (no
    // summary), a byte flipped in its length, its header or its records.
    let dir = scratch("flip-each");
    let good = dir.join("good.mcap");
    let total = chunked_fixture(&good, 1, 2, 100, 20);
    let bytes = std::fs::read(&good).unwrap();
    let killed = &bytes[..data_end(&bytes)];
    for (label, original) in [("finished", &bytes[..]), ("killed", killed)] {
        for (i, (chunk, in_chunk)) in chunks(original).into_iter().enumerate() {
            for at in [chunk.offset + 3, chunk.offset + 9 + 20, chunk.offset + 9 + chunk.len / 3, chunk.end() - 1] {
                let mut damaged = original.to_vec();
                damaged[at] ^= 0x40;
                let file = dir.join(format!("{label}-{i}-{at}.mcap"));
                std::fs::write(&file, &damaged).unwrap();
                let r = recover(&file, &dir.join("out.mcap")).unwrap();
                assert!(
                    r.messages >= total - in_chunk,
                    "{label} chunk {i}, byte {at}: kept {} of {total} ({in_chunk} in the chunk)\n{r}",
                    r.messages
                );
                assert!(r.messages <= total);
                assert!(!r.damage.is_empty());
            }
        }
    }
}

#[test]
fn many_flipped_bytes_keep_every_chunk_they_missed() {
    // The 50 flipped bytes: recovered 0 and exited 0.
    let dir = scratch("flip-many");
    let good = dir.join("good.mcap");
    let total = chunked_fixture(&good, 1, 2, 100, 20);
    let mut bytes = std::fs::read(&good).unwrap();
    let all = chunks(&bytes);
    // 50 bytes in chunks 2, 5 and 8 (the records of each, past their headers).
    let mut lost = 0;
    for &i in &[2usize, 5, 8] {
        let (chunk, n) = all[i];
        lost += n;
        for k in 0..17 {
            bytes[chunk.offset + 60 + k * (chunk.len - 60) / 17] ^= 0xff;
        }
    }
    let bad = dir.join("bad.mcap");
    std::fs::write(&bad, &bytes).unwrap();
    let r = recover(&bad, &dir.join("out.mcap")).unwrap();
    eprintln!("kept {} of {total}\n{r}", r.messages);
    assert_eq!(r.messages, total - lost);
    assert_eq!(r.skipped_chunks(), 3, "{r}");
    assert_eq!(r.skipped.values().sum::<u64>(), lost);
}

#[test]
fn a_damaged_magic_is_looked_past_by_recover() {
    let dir = scratch("magic");
    let good = dir.join("good.mcap");
    let total = fixture(&good, 1, 2, 5);
    let mut bytes = std::fs::read(&good).unwrap();
    bytes[2] = b'X';
    let bad = dir.join("bad.mcap");
    std::fs::write(&bad, &bytes).unwrap();
    assert!(matches!(Info::read(&bad).unwrap_err(), Error::NotMcap { .. }));
    let r = recover(&bad, &dir.join("out.mcap")).unwrap();
    assert_eq!(r.messages, total);
    assert_eq!(r.damage.len(), 1);
    assert_eq!(r.damage[0].resumed_at, Some(8));
    assert_eq!(r.skipped_chunks(), 0);
}

#[test]
fn a_lost_channel_declaration_is_taken_from_the_summary_or_the_repetition() {
    // The chunks that declare the channels (the first ones, before any message) and the first
    // chunk of messages are damaged; a finished file's summary repeats the declarations, and so
    // do the writer's `dc.channels` records between chunks, which a killed file still has.
    let dir = scratch("lost-channels");
    let good = dir.join("good.mcap");
    let total = chunked_fixture(&good, 1, 2, 100, 20);
    let mut bytes = std::fs::read(&good).unwrap();
    let all = chunks(&bytes);
    let declaring = all.iter().take_while(|(_, n)| *n == 0).count();
    assert!(declaring >= 1, "the channels are declared before any message");
    let (first_messages, in_first) = all[declaring];
    for (chunk, _) in &all[..=declaring] {
        bytes[chunk.end() - 5] ^= 0x01;
    }
    assert_eq!(first_messages.offset, all[declaring].0.offset);
    let bad = dir.join("bad.mcap");
    std::fs::write(&bad, &bytes).unwrap();
    let r = recover(&bad, &dir.join("out.mcap")).unwrap();
    assert_eq!(r.messages, total - in_first, "{r}");
    assert_eq!(r.channels, 4, "{r}");

    let killed = dir.join("killed.mcap");
    let killed_bytes = bytes[..data_end(&bytes)].to_vec();
    std::fs::write(&killed, &killed_bytes).unwrap();
    let r = recover(&killed, &dir.join("out2.mcap")).unwrap();
    assert_eq!(r.messages, total - in_first, "{r}");
    assert_eq!(r.channels, 4, "{r}");

    // Without the repetition (its records renamed, framing intact) every message is lost — the
    // damaged chunk's by its message index, the rest as undeclared — and counted per channel id.
    let mut hidden = killed_bytes.clone();
    let name = recorder::CHANNELS_METADATA.as_bytes();
    let mut renamed = 0;
    for at in 0..hidden.len() - name.len() {
        if &hidden[at..at + name.len()] == name {
            hidden[at + name.len() - 1] = b'X';
            renamed += 1;
        }
    }
    assert!(renamed > declaring, "a repetition after each declaration and at each flush: {renamed}");
    let hidden_file = dir.join("hidden.mcap");
    std::fs::write(&hidden_file, &hidden).unwrap();
    let e = recover(&hidden_file, &dir.join("out3.mcap")).unwrap_err();
    assert!(matches!(e, Error::NothingRecovered { .. }), "{e}");
    let mut reader = RecordingReader::open_with(&hidden_file, LENIENT).unwrap();
    while reader.next_item().is_some() {}
    assert_eq!(reader.skipped().values().sum::<u64>(), total, "{:?}", reader.skipped());
    assert!(reader.skipped().keys().all(|k| k.contains("undeclared")), "{:?}", reader.skipped());
}

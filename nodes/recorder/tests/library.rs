//! The reading library, `info` and `recover` on recordings written without a bus.

mod common;

use common::*;
use msgs::StepHeader;
use recorder::{Error, FrameKind, Info, RecordingWriter, Steps};
use std::collections::BTreeMap;

#[test]
fn steps_are_joined_per_run_simulation_and_step_in_order() {
    let dir = scratch("join");
    let file = dir.join("a.mcap");
    fixture(&file, 7, 2, 5);
    let steps: Vec<_> = Steps::open(&file).unwrap().collect::<Result<_, _>>().unwrap();
    assert_eq!(steps.len(), 10);
    for (i, s) in steps.iter().enumerate() {
        let key = StepHeader { run_id: 7, simulation: i as u32 / 5, step: i as u32 % 5 };
        assert_eq!(s.key, key);
        assert_eq!(s.bodies, bodies(key, 4));
        assert_eq!(s.contacts, contacts(key, key.step as usize % 3));
        assert_eq!(s.stats.as_ref(), Some(&stats(key)));
    }
}

#[test]
fn a_folder_of_recordings_is_read_file_by_file_in_name_order() {
    let dir = scratch("folder");
    fixture(&dir.join("run-2.mcap"), 2, 1, 3);
    fixture(&dir.join("run-1.mcap"), 1, 1, 3);
    std::fs::write(dir.join("notes.txt"), "not a recording").unwrap();
    let keys: Vec<_> = Steps::open(&dir).unwrap().map(|s| s.unwrap().key).collect();
    let runs: Vec<u64> = keys.iter().map(|k| k.run_id).collect();
    assert_eq!(runs, [1, 1, 1, 2, 2, 2]);
}

#[test]
fn a_step_missing_its_contacts_is_skipped_and_counted() {
    let dir = scratch("incomplete");
    let file = dir.join("a.mcap");
    let mut w = RecordingWriter::create(&file).unwrap();
    for step in 0..4 {
        let s = StepHeader { run_id: 1, simulation: 0, step };
        w.write("bodies", FrameKind::Bodies, 1, 1, &msgs::encode(&bodies(s, 2)).unwrap()).unwrap();
        if step != 1 {
            w.write("contacts", FrameKind::Contacts, 1, 1, &msgs::encode(&contacts(s, 1)).unwrap()).unwrap();
        }
    }
    // An undecodable payload on a known topic is skipped too.
    w.write("bodies", FrameKind::Bodies, 1, 1, b"garbage").unwrap();
    w.finish().unwrap();
    let mut it = Steps::open(&file).unwrap().with_window(2);
    let got: Vec<u32> = it.by_ref().map(|s| s.unwrap().key.step).collect();
    assert_eq!(got, [0, 2, 3]);
    assert_eq!(it.incomplete(), 1);
    assert_eq!(it.undecodable(), 1);
}

#[test]
fn info_reports_topics_counts_steps_and_compression() {
    let dir = scratch("info");
    let file = dir.join("a.mcap");
    let n = fixture(&file, 3, 2, 6);
    let info = Info::read(&file).unwrap();
    assert_eq!(info.messages, n);
    assert_eq!(info.topics["bodies"].messages, 12);
    assert_eq!(info.topics["bodies"].type_name, "dc::Bodies");
    assert_eq!(info.topics["control"].messages, 2 + 2 * 2);
    assert_eq!(info.simulations.len(), 2);
    let r = info.simulations[&(3, 1)];
    assert_eq!((r.first, r.last, r.steps), (0, 5, 6));
    assert!(info.compressions.contains("zstd"), "{:?}", info.compressions);
    assert!(info.compression_ratio() > 1.0, "{}", info.compression_ratio());
    let (a, b) = info.time_range.unwrap();
    assert!(b > a);
    let text = info.to_string();
    assert!(text.contains("Topic: bodies") && text.contains("run 3 simulation 1: steps 0..=5"), "{text}");
    // The run's parameters are not in this fixture, but channel metadata is.
    assert_eq!(info.undecodable(), 0);
}

/// Writes a run flushed at every simulation end, then keeps writing without a flush and "dies":
/// returns (file bytes after each flush, messages after each flush, the full unfinished bytes).
fn killed_writer(file: &std::path::Path) -> (Vec<u64>, Vec<u64>, Vec<u8>) {
    let mut w = RecordingWriter::create(file).unwrap();
    let mut sizes = Vec::new();
    let mut counts = Vec::new();
    write_run(&mut w, 5, 3, 20, |w, _| {
        sizes.push(std::fs::metadata(w.path()).unwrap().len());
        counts.push(w.messages());
    });
    // More messages that are never flushed: a chunk only partly on disk at most.
    let s = StepHeader { run_id: 5, simulation: 9, step: 0 };
    for _ in 0..100 {
        w.write("bodies", FrameKind::Bodies, 9, 9, &msgs::encode(&bodies(s, 5)).unwrap()).unwrap();
    }
    let bytes = std::fs::read(file).unwrap();
    w.finish().unwrap(); // the test cuts copies of the unfinished bytes instead
    (sizes, counts, bytes)
}

#[test]
fn recover_keeps_every_message_written_before_the_last_flush() {
    let dir = scratch("recover");
    let (sizes, counts, bytes) = killed_writer(&dir.join("full.mcap"));
    // Cut at a flush, just after one (a torn chunk), and midway through the chunk written
    // between two flushes.
    let torn_chunk = chunks(&bytes).into_iter().map(|(c, _)| c).find(|c| c.offset as u64 >= sizes[0]).unwrap();
    let cuts = [
        (sizes[2] as usize, counts[2]),
        (sizes[1] as usize + 37, counts[1]),
        (torn_chunk.offset + torn_chunk.len / 2, counts[0]),
        (bytes.len(), counts[2]),
    ];
    for (cut, expected) in cuts {
        let torn = dir.join(format!("torn-{cut}.mcap"));
        std::fs::write(&torn, &bytes[..cut.min(bytes.len())]).unwrap();
        let err = Info::read(&torn).unwrap_err();
        assert!(matches!(err, Error::Damaged { .. }), "{err}");
        assert!(err.to_string().contains(&torn.display().to_string()), "{err}");

        let out = dir.join(format!("recovered-{cut}.mcap"));
        let r = recorder::recover::recover(&torn, &out).unwrap();
        assert_eq!(r.messages, expected, "cut at {cut} of {}", bytes.len());
        assert!(!r.damage.is_empty());
        // The result is an indexed file: summary with statistics and chunk indexes.
        let data = std::fs::read(&out).unwrap();
        let summary = mcap::Summary::read(&data).unwrap().expect("a summary section");
        assert_eq!(summary.stats.as_ref().unwrap().message_count, expected);
        assert!(!summary.chunk_indexes.is_empty());
        assert_eq!(summary.channels.len(), 4);
        assert_eq!(Info::read(&out).unwrap().messages, expected);
    }
}

#[test]
fn non_mcap_empty_and_missing_files_are_refused_naming_the_file() {
    let dir = scratch("bad");
    let text = dir.join("notes.mcap");
    std::fs::write(&text, "hello, I am not a recording at all").unwrap();
    let empty = dir.join("empty.mcap");
    std::fs::write(&empty, "").unwrap();
    for f in [&text, &empty] {
        let e = Info::read(f).unwrap_err();
        assert!(matches!(e, Error::NotMcap { .. }), "{e}");
        assert!(e.to_string().contains(&f.display().to_string()), "{e}");
        assert!(recorder::recover::recover(f, &dir.join("out.mcap")).is_err());
    }
    let e = Info::read(&dir.join("missing.mcap")).unwrap_err();
    assert!(matches!(e, Error::Io { .. }) && e.to_string().contains("missing.mcap"), "{e}");
}

/// A device, a FIFO or a folder named as a recording is refused by its kind, before anything is
/// read: `/dev/zero` never ends, and opening a FIFO waits for a writer that never comes.
#[test]
fn devices_fifos_and_folders_are_refused_by_their_kind() {
    let dir = scratch("kinds");
    let fifo = dir.join("pipe.mcap");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let started = std::time::Instant::now();
    for (path, kind) in [
        (std::path::Path::new("/dev/zero"), "a character device"),
        (fifo.as_path(), "a FIFO (named pipe)"),
        (dir.as_path(), "a directory"),
    ] {
        for e in [Info::read(path).unwrap_err(), recorder::RecordingReader::open(path).err().expect("refused")] {
            assert!(matches!(&e, Error::NotMcap { detail, .. } if detail == kind), "{e}");
            assert!(e.to_string().starts_with(&format!("{}: not an MCAP file ({kind})", path.display())), "{e}");
        }
    }
    assert!(started.elapsed() < std::time::Duration::from_secs(5), "{:?}", started.elapsed());
}

#[test]
fn an_unknown_wire_version_is_refused_naming_the_file_and_topic() {
    let dir = scratch("version");
    let file = dir.join("future.mcap");
    let mut w = RecordingWriter::create(&file).unwrap();
    let meta = BTreeMap::from([
        ("type".to_string(), "dc::Bodies".to_string()),
        ("wire_version".to_string(), "99".to_string()),
    ]);
    let id = w.add_raw_channel("bodies", "cbor", &meta).unwrap();
    w.write_to_channel(id, 1, 1, b"whatever").unwrap();
    w.finish().unwrap();
    let e = Info::read(&file).unwrap_err();
    assert!(matches!(e, Error::WireVersion { .. }), "{e}");
    let text = e.to_string();
    assert!(text.contains("future.mcap") && text.contains("bodies") && text.contains("99"), "{text}");
    let e = Steps::open(&file).unwrap().next().unwrap().unwrap_err();
    assert!(matches!(e, Error::WireVersion { .. }), "{e}");
}

#[test]
fn recorders_started_in_the_same_second_take_numbered_names_never_an_error() {
    // `dc record -a` twice within a second (and the graph's recorder beside them): one stem,
    // three files, none written over.
    let dir = scratch("numbered");
    let stem = "attached-ns-20261204T101010Z";
    let writers: Vec<RecordingWriter> = (0..3).map(|_| RecordingWriter::create_numbered(&dir, stem).unwrap()).collect();
    let names: Vec<String> =
        writers.iter().map(|w| w.path().file_name().unwrap().to_string_lossy().into_owned()).collect();
    assert_eq!(names, [format!("{stem}.mcap"), format!("{stem}-2.mcap"), format!("{stem}-3.mcap")]);
    for w in writers {
        w.finish().unwrap();
    }
    // A name given by the user is still never taken over.
    let given = dir.join(format!("{stem}.mcap"));
    assert!(matches!(RecordingWriter::create_new(&given), Err(Error::Exists { .. })));
}

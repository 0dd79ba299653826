//! A writer whose disk fills up: the OS error and the file are named, once; nothing panics; the
//! file keeps every chunk flushed before the failure and `recover` restores them.

mod common;

use common::*;
use msgs::StepHeader;
use recorder::{Error, FrameKind, RecordingWriter};
use std::io::Write;
use std::process::Command;
use std::sync::{Arc, Mutex};

const ENOSPC: &str = "No space left on device";

/// An output that takes `room` bytes (kept in `bytes`), then fails like a full disk.
#[derive(Clone)]
struct FillingDisk {
    bytes: Arc<Mutex<Vec<u8>>>,
    room: usize,
    /// Write calls after the disk was full.
    refused: Arc<Mutex<u64>>,
}

impl Write for FillingDisk {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let mut bytes = self.bytes.lock().unwrap();
        let n = buf.len().min(self.room - bytes.len());
        if n == 0 && !buf.is_empty() {
            *self.refused.lock().unwrap() += 1;
            return Err(std::io::Error::from_raw_os_error(libc::ENOSPC));
        }
        bytes.extend_from_slice(&buf[..n]);
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[test]
fn a_full_disk_is_named_once_and_recover_restores_the_last_flushed_chunk() {
    let dir = scratch("disk-full");
    let name = dir.join("run.mcap");
    let disk = FillingDisk { bytes: Arc::default(), room: 40_000, refused: Arc::default() };
    let mut w = RecordingWriter::to_output(&name, disk.clone()).unwrap();
    for (topic, kind) in [("control", FrameKind::Control), ("bodies", FrameKind::Bodies)] {
        w.add_channel(topic, kind).unwrap();
    }
    // Chunks of 10 steps until the disk is full; the messages on disk at each good flush.
    let mut flushed = 0;
    let mut first_error = None;
    'steps: for step in 0..10_000u32 {
        let s = StepHeader { run_id: 1, simulation: 0, step };
        let frame = msgs::encode(&bodies(s, 20)).unwrap();
        let result = w.write("bodies", FrameKind::Bodies, u64::from(step), 0, &frame);
        let result = result.and_then(|()| if step % 10 == 9 { w.flush() } else { Ok(()) });
        match result {
            Ok(()) if step % 10 == 9 => flushed = w.messages(),
            Ok(()) => {}
            Err(e) => {
                first_error = Some(e);
                break 'steps;
            }
        }
    }
    let e = first_error.expect("the disk filled up");
    assert!(matches!(e, Error::WriteIo { .. }), "{e}");
    let text = e.to_string();
    assert!(text.contains(ENOSPC) && text.contains(&name.display().to_string()), "{text}");
    assert!(flushed > 0);
    // Every later call fails the same way without touching the output again.
    let refused = *disk.refused.lock().unwrap();
    for _ in 0..100 {
        let again = w.write("control", FrameKind::Control, 0, 0, b"x").unwrap_err();
        assert_eq!(again.to_string(), text);
    }
    assert_eq!(w.flush().unwrap_err().to_string(), text);
    assert_eq!(w.finish().unwrap_err().to_string(), text);
    assert_eq!(*disk.refused.lock().unwrap(), refused, "the output was written to after it failed");

    // What reached the disk: every chunk flushed before the failure, then a torn one.
    let on_disk = dir.join("on-disk.mcap");
    std::fs::write(&on_disk, &*disk.bytes.lock().unwrap()).unwrap();
    let r = recorder::recover::recover(&on_disk, &dir.join("recovered.mcap")).unwrap();
    eprintln!("flushed {flushed} messages before the disk filled; recovered {}\n{r}", r.messages);
    assert_eq!(r.messages, flushed);
}

#[cfg(target_os = "linux")]
#[test]
fn writing_to_dev_full_fails_with_enospc_naming_the_file() {
    // /dev/full: every write is refused with ENOSPC, no root needed.
    let full = std::path::Path::new("/dev/full");
    let mut w = RecordingWriter::create(full).unwrap();
    let s = StepHeader { run_id: 1, simulation: 0, step: 0 };
    w.write("bodies", FrameKind::Bodies, 1, 1, &msgs::encode(&bodies(s, 4)).unwrap()).unwrap();
    let e = w.flush().unwrap_err();
    assert!(e.to_string().contains(ENOSPC) && e.to_string().contains("/dev/full"), "{e}");
    drop(w); // no panic in a destructor

    let dir = scratch("dev-full");
    let good = dir.join("good.mcap");
    fixture(&good, 1, 2, 5);
    let e = recorder::recover::recover(&good, full).unwrap_err();
    assert_eq!(e.to_string(), format!("{ENOSPC} (os error 28) writing /dev/full"));
}

#[cfg(target_os = "linux")]
#[test]
fn dc_record_recover_onto_a_full_disk_exits_with_one_clear_error() {
    // It ended with `unreachable: self.writer should never be None`, a panic in a destructor and
    // an abort, leaving a 0-byte file.
    let dir = scratch("recover-full");
    let good = dir.join("good.mcap");
    chunked_fixture(&good, 1, 2, 100, 20);
    let out =
        Command::new(env!("CARGO_BIN_EXE_dc-record")).arg("recover").arg(&good).arg("/dev/full").output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert_eq!(stderr.matches(ENOSPC).count(), 1, "{stderr}");
    assert!(stderr.contains("writing /dev/full"), "{stderr}");
    assert!(!stderr.contains("panicked") && !stderr.contains("unreachable"), "{stderr}");
}

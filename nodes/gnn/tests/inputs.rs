//! Untrusted input at `dc-gnn` (issue #40): a model path that is a device, a FIFO or a folder is
//! refused by its kind before anything is read (`dc-gnn info /dev/zero` used to grow without
//! end), and a network's shape flags are bounded when parsed.

use std::ffi::OsStr;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn dc_gnn(args: &[&OsStr], validate: bool) -> Output {
    let mut command = Command::new(env!("CARGO_BIN_EXE_dc-gnn"));
    command.args(args).env_remove("DC_BUS").env_remove("DC_LAUNCHED");
    match validate {
        true => command.env("DC_VALIDATE", "1"),
        false => command.env_remove("DC_VALIDATE"),
    };
    command.output().expect("run dc-gnn")
}

#[test]
fn model_paths_that_are_not_regular_files_are_refused_naming_them() {
    let dir = std::env::temp_dir().join(format!("dc-gnn-inputs-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let fifo = dir.join("pipe.dcg");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let huge = dir.join("huge.dcg");
    std::fs::File::create(&huge).unwrap().set_len(3 << 30).unwrap();
    let started = Instant::now();
    for (path, why) in [
        (std::path::Path::new("/dev/zero"), "is a character device, not a model file"),
        (fifo.as_path(), "is a FIFO (named pipe), not a model file"),
        (dir.as_path(), "is a directory, not a model file"),
        (huge.as_path(), "is 3 GiB, larger than any model file (at most 256 MiB)"),
    ] {
        let expected = format!("{}: {why}", path.display());
        // `info` and `upgrade`: an error (status 1).
        for sub in ["info", "upgrade"] {
            let out = dc_gnn(&[OsStr::new(sub), path.as_os_str()], false);
            let err = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(1), "{sub} {}: {err}", path.display());
            assert!(err.contains(&expected), "{sub}: {err}");
        }
        // The node's `--model`: refused by the parameter check, under the launcher's too.
        for validate in [false, true] {
            let out = dc_gnn(&[OsStr::new("--model"), path.as_os_str()], validate);
            let err = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(2), "--model {}: {err}", path.display());
            assert!(err.contains(&expected), "--model: {err}");
        }
    }
    assert!(started.elapsed() < Duration::from_secs(20), "{:?}", started.elapsed());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn network_shape_flags_out_of_range_are_refused_by_name() {
    for (flag, value) in [("--hidden", "0"), ("--hidden", "1025"), ("--hidden", "-1"), ("--rounds", "65")] {
        let arg = format!("{flag}={value}");
        let out = dc_gnn(&[OsStr::new("init"), OsStr::new("--out"), OsStr::new("m.dcg"), OsStr::new(&arg)], false);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{arg}: {err}");
        assert!(err.contains(flag), "{arg}: {err}");
    }
}

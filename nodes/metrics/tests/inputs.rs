//! Untrusted input (issue #40): a `--from-steps` path that is not a regular file is refused by
//! its kind before it is read, and numbers outside a flag's range are refused when the flags are
//! parsed (exit status 2, the flag named).

use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn dc_metrics(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_dc-metrics"))
        .args(args)
        .env_remove("DC_VALIDATE")
        .env_remove("DC_BUS")
        .env_remove("DC_LAUNCHED")
        .output()
        .expect("run dc-metrics")
}

#[test]
fn a_steps_file_that_is_a_device_a_fifo_or_a_folder_is_refused_by_its_kind() {
    let dir = std::env::temp_dir().join(format!("dc-metrics-inputs-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let fifo = dir.join("steps.csv");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let started = Instant::now();
    for (path, why) in [
        (Path::new("/dev/zero"), "is a character device, not a steps file"),
        (fifo.as_path(), "is a FIFO (named pipe), not a steps file"),
        (dir.as_path(), "is a directory, not a steps file"),
    ] {
        let e = metrics::report::aggregate_steps(path, 0.1, Some(&[])).expect_err("refused").to_string();
        assert_eq!(e, format!("{}: {why}", path.display()));
        let out = dc_metrics(&["--from-steps", path.to_str().unwrap(), "--out", dir.join("report").to_str().unwrap()]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains(&format!("{}: {why}", path.display())), "{err}");
    }
    assert!(started.elapsed() < Duration::from_secs(20), "{:?}", started.elapsed());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_settle_speed_that_is_not_a_positive_finite_speed_is_refused_by_name() {
    for value in ["nan", "-1", "0", "inf", "1e308", "fast"] {
        let out = dc_metrics(&[&format!("--settle-speed={value}")]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "--settle-speed={value}: {err}");
        assert!(err.contains("--settle-speed"), "--settle-speed={value}: {err}");
    }
    // A good value parses (the launcher's check: parse only, then exit 0).
    let out = Command::new(env!("CARGO_BIN_EXE_dc-metrics"))
        .arg("--settle-speed=0.2")
        .env("DC_VALIDATE", "1")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

//! A recording is readable from Python with the PyPI `mcap` and `cbor2` packages (what a notebook
//! or a Python trainer uses). Skipped, saying so, where those packages are not installed.

mod common;

use common::*;
use std::process::Command;

#[test]
fn python_reads_topics_counts_and_cbor_fields() {
    let have = Command::new("python3").args(["-c", "import mcap, cbor2"]).output();
    if !have.as_ref().is_ok_and(|o| o.status.success()) {
        let why = "python3 with `mcap` and `cbor2` is not available (pip install mcap cbor2)";
        // CI installs them: there a missing package fails the test instead of passing it.
        assert!(std::env::var("DC_REQUIRE_ALL").map_or(true, |v| v != "1"), "{why} (DC_REQUIRE_ALL=1)");
        eprintln!("SKIPPED python_reads_topics_counts_and_cbor_fields: {why}");
        return;
    }
    let dir = scratch("python");
    let file = dir.join("a.mcap");
    fixture(&file, 11, 2, 4);
    // Bodies 0 and 1 of the first frame: see `common::bodies` (x = step + id * 0.5; a non-zero
    // field, so a reader that returns zeros cannot pass).
    let expected = serde_json::json!({
        "counts": { "bodies": 8, "contacts": 8, "stats/solve": 8, "control": 6 },
        "first_body": { "run_id": 11, "simulation": 0, "step": 0, "n": 4, "x0": 0.0, "x1": 0.5 },
        // Names are text, and a run start's details are a CBOR map, for any reader.
        "stats_model": "builtin",
        "run_start": { "model": "builtin", "steps": 4, "seeds": [0, 1] },
        "wire_version": msgs::WIRE_VERSION,
    });
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/read_with_python.py");
    let out = Command::new("python3").arg(script).arg(&file).arg(expected.to_string()).output().unwrap();
    assert!(out.status.success(), "{}\n{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
}

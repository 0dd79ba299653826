//! The Python solver probes (`experiments/python/`) on a real recording: the small labelled run
//! the product's Python reader test records (`deep_contact::record_labelled_problems`), re-solved
//! by each probe. Skipped, saying why, where python3 or the PyPI packages
//! (`python/requirements.txt`) are missing, except under `DC_REQUIRE_ALL=1` (CI).

use deep_contact::{have_python, python, record_labelled_problems, text};
use std::path::PathBuf;
use std::sync::OnceLock;

/// One recording for both probes (recorded by the first test that needs it).
fn recording() -> &'static PathBuf {
    static FILE: OnceLock<PathBuf> = OnceLock::new();
    FILE.get_or_init(|| record_labelled_problems("python-probes").0)
}

/// The probe's table (stdout) for `args` after the recording; fails on a failed probe.
fn probe(script: &str, args: &[&str]) -> String {
    let file = recording().to_str().expect("UTF-8 scratch path").to_string();
    let out = python(script, &[&[file.as_str()], args].concat());
    assert!(out.status.success(), "{}", text(&out));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The line of `table` for variant `name`.
fn row<'a>(table: &'a str, name: &str) -> &'a str {
    table.lines().find(|l| l.starts_with(name)).unwrap_or_else(|| panic!("no {name}:\n{table}"))
}

#[test]
fn headroom_probe_needs_almost_no_sweeps_from_the_recorded_reference() {
    if !have_python("headroom probe", "numpy, mcap, cbor2") {
        return;
    }
    // The probe re-solves late problems: from the recorded reference it takes about one sweep.
    let table = probe("experiments/python/probe_headroom.py", &["--from-step", "40", "--every", "10", "--limit", "2"]);
    let ratio = |name: &str| -> f64 {
        row(&table, name).split_whitespace().last().unwrap().trim_end_matches('x').parse().unwrap()
    };
    assert_eq!(ratio("builtin"), 1.0, "{table}");
    assert!(ratio("reference") < 0.2, "the exact solution needs almost no sweeps:\n{table}");
}

#[test]
fn active_set_probe_solves_from_the_true_active_set_in_about_one_sweep() {
    if !have_python("active-set probe", "numpy, mcap, cbor2") {
        return;
    }
    // With compliant contacts the linear solution on the exact solution's own active set is that
    // solution: about one sweep.
    let table = probe("experiments/python/probe_active_set.py", &["--from-step", "40", "--limit", "2"]);
    let sweeps = |name: &str| -> u64 { row(&table, name).split_whitespace().nth(1).unwrap().parse().unwrap() };
    assert!(sweeps("true-set") <= 2 * 2 && sweeps("builtin") > sweeps("true-set"), "{table}");
}

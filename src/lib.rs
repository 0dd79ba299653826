//! Support for the end-to-end tests in `tests/`: where the built binaries are, unique bus
//! namespaces, and launch files written to temporary folders.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The cargo target folder holding the binaries (`target/debug`), found from the test executable.
/// The shipped demo U-Net model, by absolute path (a launch file's relative paths resolve against
/// the file's own folder, and the tests write theirs in scratch folders).
pub const UNET_DEMO: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/models/unet-demo.dcu");

pub fn bin_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    // target/debug/deps/<test> -> target/debug
    exe.parent().and_then(Path::parent).expect("target dir").to_path_buf()
}

/// Path of a workspace binary such as `dc` or `dc-sim`.
pub fn bin(name: &str) -> PathBuf {
    let p = bin_dir().join(name);
    assert!(p.is_file(), "{} is not built (run `cargo build --workspace --bins` first)", p.display());
    p
}

/// A namespace no other test (or test run) uses, so graphs can run side by side.
pub fn unique_namespace(test: &str) -> String {
    use std::sync::atomic::{AtomicU32, Ordering};
    static N: AtomicU32 = AtomicU32::new(0);
    // Process ids recycle (pid_max is 32768 here): the clock keeps earlier runs' leftovers apart.
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
    format!("t{}-{}-{nanos}-{test}", std::process::id(), N.fetch_add(1, Ordering::SeqCst))
}

/// A scratch folder under the target dir, removed and re-created.
pub fn scratch_dir(test: &str) -> PathBuf {
    let d = bin_dir().join("e2e-scratch").join(unique_namespace(test));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("create scratch dir");
    d
}

/// Writes `text` as a launch file and runs `dc launch` on it (plus `extra` arguments).
pub fn launch(test: &str, text: &str, extra: &[&str]) -> (PathBuf, Output) {
    let dir = scratch_dir(test);
    let file = dir.join("graph.toml");
    std::fs::write(&file, text).expect("write launch file");
    let out = Command::new(bin("dc"))
        .arg("launch")
        .arg(&file)
        .args(["--namespace", &unique_namespace(test)])
        .args(extra)
        .output()
        .expect("run dc");
    (file, out)
}

/// Whether `test` must skip because a prerequisite of this machine is missing (`why`): says so on
/// stderr and returns true, except under `DC_REQUIRE_ALL=1` (CI, which installs every
/// prerequisite), where a missing prerequisite fails the test instead of passing it silently.
pub fn skip_for_missing(test: &str, why: &str) -> bool {
    if std::env::var("DC_REQUIRE_ALL").is_ok_and(|v| v == "1") {
        panic!("{test}: a prerequisite is missing under DC_REQUIRE_ALL=1: {why}");
    }
    eprintln!("SKIPPED {test}: {why}");
    true
}

/// The repository's root folder (this package's): where `python/`, `launch/` and `experiments/` lie.
pub fn repo_root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Runs `python3 SCRIPT ARGS`, the script's path relative to the repository root.
pub fn python(script: &str, args: &[&str]) -> Output {
    Command::new("python3").arg(repo_root().join(script)).args(args).output().expect("run python3")
}

/// Whether python3 imports `modules`; else skips (or fails under DC_REQUIRE_ALL=1).
pub fn have_python(test: &str, modules: &str) -> bool {
    let ok = Command::new("python3").args(["-c", &format!("import {modules}")]).output();
    ok.is_ok_and(|o| o.status.success())
        || !skip_for_missing(test, &format!("python3 cannot import {modules} (pip install -r python/requirements.txt)"))
}

/// Records a small real run for the Python readers: `dc-sim` (builtin, seeds 3..5, 60 steps, 30
/// balls) publishing every step's problem labelled to 2e-6, and `dc-record` writing every topic
/// the step join and the probes read. Returns the recording and the launcher's (successful) output.
pub fn record_labelled_problems(test: &str) -> (PathBuf, Output) {
    let dir = scratch_dir(test);
    let file = dir.join("run.mcap");
    let graph = dir.join("graph.toml");
    std::fs::write(
        &graph,
        format!(
            r#"
[[nodes]]
name = "recorder"
binary = "dc-record"
daemon = true
params = {{ out = "{}", topics = "bodies,contacts,problem/bodies,problem/contacts,stats/solve,control" }}

[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ model = "builtin", seeds = "3..5", steps = 60, n = 30, publish-problem = true, label-tolerance = 2e-6 }}
"#,
            file.display()
        ),
    )
    .expect("write launch file");
    let out = Command::new(bin("dc"))
        .args(["launch"])
        .arg(&graph)
        .args(["--namespace", &unique_namespace(test)])
        .output()
        .expect("run dc");
    assert!(out.status.success(), "{}", text(&out));
    (file, out)
}

/// stdout and stderr of a finished command, for assertion messages.
pub fn text(out: &Output) -> String {
    format!(
        "status: {}\n--- stdout\n{}\n--- stderr\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// The named `columns` of every row of a metrics report's `steps.csv`, in file order.
pub fn report_columns(dir: &Path, columns: &[&str]) -> Vec<Vec<String>> {
    let file = dir.join("steps.csv");
    let text = std::fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let at: Vec<usize> = columns
        .iter()
        .map(|name| header.iter().position(|h| h == name).unwrap_or_else(|| panic!("no column {name}")))
        .collect();
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            at.iter().map(|&i| f[i].to_string()).collect()
        })
        .collect()
}

/// Per-step rows of a metrics report (`steps.csv`): `(simulation, step) -> (sweeps, fallback,
/// used model)`.
pub fn report_steps(dir: &Path) -> std::collections::BTreeMap<(u32, u32), (u32, bool, String)> {
    report_columns(dir, &["simulation", "step", "sweeps", "fallback", "used_model"])
        .into_iter()
        .map(|f| {
            ((f[0].parse().unwrap(), f[1].parse().unwrap()), (f[2].parse().unwrap(), f[3] == "true", f[4].clone()))
        })
        .collect()
}

/// A report folder's tables (every `*.csv`, by file name) without what measures wall time (the
/// `*_us`, `*_ms`, `* us` and `* ms` columns) or names a process (`run_id`): what two runs of the same seeds and
/// settings must agree on, cell for cell, wherever and however split they ran.
pub fn report_figures(dir: &Path) -> std::collections::BTreeMap<String, Vec<Vec<String>>> {
    let mut tables = std::collections::BTreeMap::new();
    for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = entry.expect("read report folder").path();
        if path.extension().is_none_or(|e| e != "csv") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let mut rows = text.lines().map(csv_cells);
        let header = rows.next().unwrap_or_default();
        let kept: Vec<usize> = (0..header.len())
            .filter(|&i| {
                let name = header[i].as_str();
                let timed = ["_us", "_ms", " us", " ms"].iter().any(|unit| name.ends_with(unit));
                !(timed || name == "run_id")
            })
            .collect();
        let pick = |row: Vec<String>| kept.iter().map(|&i| row.get(i).cloned().unwrap_or_default()).collect();
        let mut table = vec![pick(header.clone())];
        table.extend(rows.map(pick));
        tables.insert(path.file_name().unwrap().to_string_lossy().into_owned(), table);
    }
    tables
}

/// One CSV line's cells (quoted cells may hold commas and doubled quotes).
fn csv_cells(line: &str) -> Vec<String> {
    let (mut cells, mut cell, mut quoted) = (Vec::new(), String::new(), false);
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '"' if quoted && chars.peek() == Some(&'"') => {
                cell.push('"');
                chars.next();
            }
            '"' => quoted = !quoted,
            ',' if !quoted => cells.push(std::mem::take(&mut cell)),
            c => cell.push(c),
        }
    }
    cells.push(cell);
    cells
}

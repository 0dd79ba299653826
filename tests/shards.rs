//! A run split into shards (`dc eval --shard I/N`) and merged (`dc report merge`) gives the report
//! of the same run on one host, figure for figure; every way a set of shards cannot make that
//! report is refused, naming the shard, the setting or the seeds, with nothing written.

use deep_contact::{bin, report_figures, scratch_dir, text};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The run every shard test splits: two models, four seeds, small but long enough for the balls to
/// land and pile (thousands of sweeps: the tables compare something).
const RUN: &[&str] = &["--models", "builtin,copy", "--seeds", "0..4", "--steps", "150", "--n", "30", "--threads", "1"];

fn dc(args: &[&str]) -> Output {
    Command::new(bin("dc")).args(args).output().expect("run dc")
}

fn eval_into(out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["eval"];
    args.extend_from_slice(RUN);
    args.extend_from_slice(extra);
    args.extend(["--out", out.to_str().unwrap()]);
    dc(&args)
}

fn merge(dirs: &[&Path], out: &Path) -> Output {
    let mut args = vec!["report".to_string(), "merge".to_string()];
    args.extend(dirs.iter().map(|d| d.display().to_string()));
    args.extend(["--out".to_string(), out.display().to_string()]);
    Command::new(bin("dc")).args(&args).output().expect("run dc report merge")
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        if entry.file_type().unwrap().is_file() {
            std::fs::copy(entry.path(), to.join(entry.file_name())).unwrap();
        }
    }
}

/// Rewrites one shard.json with `edit` applied to its JSON.
fn edit_manifest(dir: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let path = dir.join("shard.json");
    let mut value: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut value);
    std::fs::write(&path, serde_json::to_string_pretty(&value).unwrap()).unwrap();
}

/// Asserts the merge of `dirs` fails saying every one of `says`, and writes nothing.
fn refused(dirs: &[&Path], scratch: &Path, case: &str, says: &[&str]) {
    let out = scratch.join(format!("refused-{case}"));
    let o = merge(dirs, &out);
    let t = text(&o);
    assert!(!o.status.success(), "{case}: the merge should be refused:\n{t}");
    for s in says {
        assert!(t.contains(s), "{case}: the refusal should say `{s}`:\n{t}");
    }
    assert!(!out.exists(), "{case}: a refused merge wrote {}", out.display());
}

#[test]
fn two_shards_merge_into_the_report_of_the_run_on_one_host() {
    let scratch = scratch_dir("shards");
    let one = scratch.join("one");
    let o = eval_into(&one, &[]);
    assert!(o.status.success(), "one-host run:\n{}", text(&o));
    let shards: Vec<PathBuf> = (0..2).map(|i| scratch.join(format!("shard-{i}"))).collect();
    // Shard 1 first: the merge orders shards by index, not by when or in which order they ran.
    for i in [1, 0] {
        let o = eval_into(&shards[i], &["--shard", &format!("{i}/2")]);
        assert!(o.status.success(), "shard {i}/2:\n{}", text(&o));
        let manifest = std::fs::read_to_string(shards[i].join("shard.json")).unwrap();
        assert!(manifest.contains("\"state\": \"complete\""), "shard {i} finished:\n{manifest}");
    }
    // Each shard's own report holds only its own seeds.
    let shard0 = std::fs::read_to_string(shards[0].join("steps.csv")).unwrap();
    let sims: std::collections::BTreeSet<&str> = shard0.lines().skip(1).filter_map(|l| l.split(',').nth(1)).collect();
    assert_eq!(sims.into_iter().collect::<Vec<_>>(), ["0", "1"], "shard 0 of 2 of seeds 0..4 ran seeds 0 and 1");

    let sweeps: u64 = std::fs::read_to_string(one.join("steps.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(7).unwrap().parse::<u64>().unwrap())
        .sum();
    assert!(sweeps > 1000, "the run piles balls up ({sweeps} sweeps): the comparison below is not of empty tables");
    let merged = scratch.join("merged");
    let o = merge(&[&shards[1], &shards[0]], &merged);
    assert!(o.status.success(), "merge:\n{}", text(&o));
    let figures = report_figures(&one);
    assert!(figures.len() >= 4, "the one-host report's tables: {:?}", figures.keys().collect::<Vec<_>>());
    let merged_figures = report_figures(&merged);
    assert_eq!(merged_figures.keys().collect::<Vec<_>>(), figures.keys().collect::<Vec<_>>(), "the same tables");
    for (file, rows) in &figures {
        assert_eq!(&merged_figures[file], rows, "{file}: the merged report differs from the one-host run's");
    }
    let title = |dir: &Path| {
        let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
        html.split("<title>").nth(1).and_then(|t| t.split("</title>").next()).map(str::to_string)
    };
    assert_eq!(title(&merged), title(&one), "the merged report is titled as the whole run");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(merged.join("merged.json")).unwrap()).unwrap();
    let merged_shards = summary["shards"].as_array().unwrap();
    assert_eq!(merged_shards.len(), 2);
    assert_eq!(merged_shards[0]["seeds"], "0..2");
    assert_eq!(merged_shards[1]["seeds"], "2..4");

    // What cannot be merged, each refused with nothing written.
    refused(&[&shards[0]], &scratch, "missing", &["missing shard 1/2", "seeds 2..4"]);
    let copy = scratch.join("copy-of-0");
    copy_dir(&shards[0], &copy);
    refused(&[&shards[0], &copy, &shards[1]], &scratch, "overlap", &["overlap", "shard 0/2"]);

    let other_steps = scratch.join("other-steps");
    copy_dir(&shards[1], &other_steps);
    edit_manifest(&other_steps, |m| m["settings"]["steps"] = "151".into());
    refused(&[&shards[0], &other_steps], &scratch, "setting", &["setting `steps`", "`150`", "`151`"]);

    let other_build = scratch.join("other-build");
    copy_dir(&shards[1], &other_build);
    edit_manifest(&other_build, |m| m["build"]["dc-sim sha256"] = "0".repeat(64).into());
    refused(&[&shards[0], &other_build], &scratch, "build", &["build `dc-sim sha256`"]);

    // A shard killed half way keeps the manifest it wrote before its work: running.
    let died = scratch.join("died");
    copy_dir(&shards[1], &died);
    edit_manifest(&died, |m| {
        m["state"] = "running".into();
        m.as_object_mut().unwrap().remove("finished_unix");
    });
    refused(&[&shards[0], &died], &scratch, "running", &["never finished", "seeds 2..4"]);

    let failed = scratch.join("failed");
    copy_dir(&shards[1], &failed);
    edit_manifest(&failed, |m| {
        m["state"] = "failed".into();
        m["why"] = "node sim-0 exited with status 1".into();
    });
    refused(&[&shards[0], &failed], &scratch, "failed", &["failed", "node sim-0 exited"]);

    let cut = scratch.join("cut");
    copy_dir(&shards[1], &cut);
    let records = std::fs::read(cut.join("records.cbor")).unwrap();
    std::fs::write(cut.join("records.cbor"), &records[..records.len() / 2]).unwrap();
    refused(&[&shards[0], &cut], &scratch, "cut-records", &["records.cbor", "corrupt or cut short"]);

    let no_records = scratch.join("no-records");
    copy_dir(&shards[1], &no_records);
    std::fs::remove_file(no_records.join("records.cbor")).unwrap();
    refused(&[&shards[0], &no_records], &scratch, "no-records", &["records.cbor"]);

    let garbled = scratch.join("garbled");
    copy_dir(&shards[1], &garbled);
    std::fs::write(garbled.join("shard.json"), "{\"format\": 1, \"shard\": ").unwrap();
    refused(&[&shards[0], &garbled], &scratch, "garbled-manifest", &["shard.json"]);

    refused(&[&shards[0], &one], &scratch, "not-a-shard", &["no shard.json", "one"]);

    let o = merge(&[&shards[0], &shards[1]], &shards[0]);
    assert!(!o.status.success() && text(&o).contains("one of the shard folders"), "{}", text(&o));
}

#[test]
fn impossible_shards_are_refused_naming_the_flag() {
    let scratch = scratch_dir("bad-shards");
    for (shard, says) in [
        ("3/2", "index 3"),
        ("0/0", "at least 1"),
        ("a/2", "I/N"),
        ("2", "I/N"),
        // More shards than seeds: a shard with nothing to run is refused, not an empty report.
        ("0/6", "no seeds"),
    ] {
        let out = scratch.join(shard.replace('/', "-"));
        let o = eval_into(&out, &["--shard", shard]);
        let t = text(&o);
        assert!(!o.status.success(), "--shard {shard} should be refused:\n{t}");
        assert!(
            t.contains("--shard") && t.contains(says),
            "--shard {shard}: the error should name the flag and say `{says}`:\n{t}"
        );
        assert!(!out.join("shard.json").exists(), "--shard {shard}: refused, yet a manifest was written");
    }
}

/// A recording graph split by `dc launch --shard`: each shard records its part of the seeds into
/// a file of its own, and a graph without seeds is refused naming the flag.
#[test]
fn a_launch_file_runs_its_part_of_the_seeds_with_its_own_recording() {
    let graph = r#"
[[nodes]]
name = "recorder"
binary = "dc-record"
daemon = true
params = { out = "run.mcap", topics = "bodies,contacts,stats/solve,control" }

[[nodes]]
name = "sim"
binary = "dc-sim"
params = { model = "builtin", seeds = "0..5", steps = 6, n = 20 }
"#;
    let mut simulations = Vec::new();
    for i in 0..2 {
        let (file, o) = deep_contact::launch("launch-shard", graph, &["--shard", &format!("{i}/2")]);
        assert!(o.status.success(), "shard {i}/2:\n{}", text(&o));
        let said = String::from_utf8_lossy(&o.stdout).to_string();
        assert!(said.contains(&format!("shard {i}/2: sim: seeds 0..5 -> ")), "{said}");
        let dir = file.parent().unwrap();
        assert!(!dir.join("run.mcap").exists(), "shard {i} wrote the unsharded file");
        let recording = dir.join(format!("run.shard-{i}-of-2.mcap"));
        let info = recorder::Info::read(&recording).unwrap_or_else(|e| panic!("{}: {e}", recording.display()));
        let seeds: Vec<u32> = info.simulations.keys().map(|(_, sim)| *sim).collect();
        simulations.push(seeds);
    }
    assert_eq!(simulations, [vec![0, 1], vec![2, 3, 4]], "contiguous blocks, every seed once");

    let unseeded = graph.replace("seeds = \"0..5\", ", "");
    let (_, o) = deep_contact::launch("launch-shard-none", &unseeded, &["--shard", "0/2"]);
    assert!(
        !o.status.success() && text(&o).contains("--shard 0/2: no node") && text(&o).contains("seeds"),
        "{}",
        text(&o)
    );
    let (_, o) = deep_contact::launch("launch-shard-many", graph, &["--shard", "0/6"]);
    assert!(!o.status.success() && text(&o).contains("has no seeds"), "{}", text(&o));
}

/// `dc study ARGS [--shard I/N] --out OUT`.
fn study_into(args: &[&str], out: &Path, shard: Option<&str>) -> Output {
    let mut all = vec!["study"];
    all.extend_from_slice(args);
    if let Some(shard) = shard {
        all.extend(["--shard", shard]);
    }
    all.extend(["--out", out.to_str().unwrap()]);
    dc(&all)
}

/// A study run on one host and in two shards, merged: returns (one-host folder, merged folder).
fn study_both_ways(test: &str, args: &[&str]) -> (PathBuf, PathBuf, PathBuf) {
    let scratch = scratch_dir(test);
    let one = scratch.join("one");
    let o = study_into(args, &one, None);
    assert!(o.status.success(), "one-host study:\n{}", text(&o));
    let shards: Vec<PathBuf> = (0..2).map(|i| scratch.join(format!("shard-{i}"))).collect();
    for (i, dir) in shards.iter().enumerate() {
        let o = study_into(args, dir, Some(&format!("{i}/2")));
        assert!(o.status.success(), "shard {i}/2:\n{}", text(&o));
    }
    let merged = scratch.join("merged");
    let o = merge(&[&shards[1], &shards[0]], &merged);
    assert!(o.status.success(), "merge:\n{}", text(&o));
    (one, merged, scratch)
}

/// The sections of a study's markdown report whose heading contains one of `headings`.
fn sections(dir: &Path, file: &str, headings: &[&str]) -> Vec<String> {
    let md = std::fs::read_to_string(dir.join(file)).unwrap();
    let found: Vec<String> = md
        .split("\n## ")
        .filter(|s| headings.iter().any(|h| s.lines().next().unwrap_or("").contains(h)))
        .map(str::to_string)
        .collect();
    assert!(!found.is_empty(), "{file} has no section {headings:?}:\n{md}");
    found
}

#[test]
fn a_solvers_study_in_shards_merges_into_the_one_host_study() {
    let args = [
        "solvers",
        "pgs,nncg:1.2/down",
        "--seeds",
        "0..4",
        "--steps",
        "120",
        "--n",
        "30",
        "--threads",
        "1",
        "--whole-runs",
    ];
    let (one, merged, scratch) = study_both_ways("study-solvers-shards", &args);
    let (a, b) = (report_figures(&one), report_figures(&merged));
    assert_eq!(a.keys().collect::<Vec<_>>(), ["solver-steps.csv"]);
    assert!(a["solver-steps.csv"].len() == 481, "4 seeds x 120 steps and a header: {}", a["solver-steps.csv"].len());
    assert_eq!(a, b, "every step's figures, but the timings");
    // The whole runs' sweeps, the ratios of sweeps, the capped steps and the worst seed (the
    // columns not measured in seconds).
    let whole = |dir: &Path| -> Vec<Vec<String>> {
        let section = sections(dir, "solvers.md", &["Whole runs"]).remove(0);
        section
            .lines()
            .filter(|l| l.starts_with("| ") && !l.starts_with("| solver"))
            .map(|l| {
                let cells: Vec<&str> = l.split('|').map(str::trim).collect();
                [1, 2, 3, 6, 7].iter().map(|&i| cells[i].to_string()).collect()
            })
            .collect()
    };
    assert_eq!(whole(&one).len(), 2, "a row per solver");
    assert_eq!(whole(&merged), whole(&one), "the whole runs' sweeps");
    let summary = std::fs::read_to_string(merged.join("merged.json")).unwrap();
    assert!(summary.contains("\"command\": \"dc study solvers\""), "{summary}");

    // The chooser is trained once, on one host: not with --shard.
    let o = study_into(&[&args[..], &["--train-seeds", "1000..1002"]].concat(), &scratch.join("chooser"), Some("0/2"));
    assert!(!o.status.success() && text(&o).contains("--shard with --train-seeds"), "{}", text(&o));
    // A study's shard and an evaluation's shard are not one run.
    let eval_shard = scratch.join("eval-shard");
    let o = eval_into(&eval_shard, &["--shard", "1/2"]);
    assert!(o.status.success(), "{}", text(&o));
    refused(
        &[&scratch.join("shard-0"), &eval_shard],
        &scratch,
        "study-and-eval",
        &["the command", "dc study solvers", "dc eval"],
    );
    // A shard of another setting, named.
    let other = scratch.join("other");
    let mut changed = args.to_vec();
    changed[5] = "121";
    let o = study_into(&changed, &other, Some("1/2"));
    assert!(o.status.success(), "{}", text(&o));
    refused(&[&scratch.join("shard-0"), &other], &scratch, "study-setting", &["setting `steps`", "`120`", "`121`"]);
}

#[test]
fn a_budget_study_in_shards_merges_into_the_one_host_study() {
    let args = [
        "budget",
        "4,8",
        "--models",
        "none,builtin,blend:0.5",
        "--error-split",
        "--seeds",
        "0..4",
        "--steps",
        "100",
        "--n",
        "30",
        "--threads",
        "1",
    ];
    let (one, merged, scratch) = study_both_ways("study-budget-shards", &args);
    let (a, b) = (report_figures(&one), report_figures(&merged));
    assert_eq!(a.keys().collect::<Vec<_>>(), ["budget-steps.csv"]);
    assert_eq!(a, b, "every run's steps, but the timings");
    // The error split (summed over seeds) and the pile against the reference: no timings there.
    let headings = ["which part of builtin's error", "The pile against the reference"];
    assert_eq!(sections(&merged, "budget.md", &headings), sections(&one, "budget.md", &headings));

    // A shard whose results were cut short is refused, naming the file.
    let cut = scratch.join("cut");
    copy_dir(&scratch.join("shard-1"), &cut);
    let data = std::fs::read(cut.join("study.cbor")).unwrap();
    std::fs::write(cut.join("study.cbor"), &data[..data.len() / 3]).unwrap();
    refused(&[&scratch.join("shard-0"), &cut], &scratch, "study-cut", &["study.cbor", "corrupt or cut short"]);
}

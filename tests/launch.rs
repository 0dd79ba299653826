//! `dc launch` as users meet it: malformed launch files are refused before anything starts, with
//! file, line and what is wrong; a node that fails stops the graph, and no process is left behind.

use deep_contact::{bin, launch, scratch_dir, text, unique_namespace};
use std::io::Read;
use std::os::unix::process::ExitStatusExt;
use std::process::{Command, ExitStatus, Output, Stdio};
use std::time::{Duration, Instant};

fn refused(test: &str, graph: &str) -> String {
    let (file, out) = launch(test, graph, &[]);
    assert!(!out.status.success(), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(stderr.contains(&file.display().to_string()), "error must name the file:\n{stderr}");
    // Refused before start: no node output at all.
    assert!(!String::from_utf8_lossy(&out.stdout).contains('['), "{}", text(&out));
    stderr
}

#[test]
fn syntax_error_is_reported_with_its_line() {
    let err = refused("syntax", "[graph]\nname = \"x\"\n\n[[nodes]]\nname = \"a\"\nbinary = \n");
    assert!(err.contains("graph.toml:6:"), "{err}");
}

#[test]
fn unknown_node_binary_is_refused() {
    let err = refused("binary", "[[nodes]]\nname = \"a\"\nbinary = \"dc-does-not-exist\"\n");
    assert!(err.contains("graph.toml:3: node `a`: unknown node binary `dc-does-not-exist`"), "{err}");
}

#[test]
fn unknown_host_is_refused() {
    let err = refused(
        "host",
        "[hosts.a]\n[hosts.b]\n[[nodes]]\nname = \"x\"\nbinary = \"dc-bench-bus\"\nhost = \"c\"\nparams = { role = \"sink\" }\n",
    );
    assert!(err.contains("graph.toml:6: node `x`: unknown host `c`"), "{err}");
}

#[test]
fn duplicate_node_name_is_refused() {
    let node = "[[nodes]]\nname = \"x\"\nbinary = \"dc-bench-bus\"\nparams = { role = \"sink\" }\n";
    let err = refused("duplicate", &format!("{node}{node}"));
    assert!(err.contains("graph.toml:6: duplicate node name `x` (first defined on line 1)"), "{err}");
}

#[test]
fn missing_and_unknown_parameters_are_refused() {
    let err = refused(
        "params",
        "[[nodes]]\nname = \"no-role\"\nbinary = \"dc-bench-bus\"\n\n[[nodes]]\nname = \"typo\"\nbinary = \"dc-bench-bus\"\nparams = { role = \"sink\", cuont = 3 }\n",
    );
    assert!(err.contains("graph.toml:1: node `no-role` (dc-bench-bus): bad parameters"), "{err}");
    assert!(err.contains("--role"), "{err}");
    assert!(err.contains("graph.toml:5: node `typo` (dc-bench-bus): bad parameters"), "{err}");
    assert!(err.contains("--cuont"), "{err}");
}

#[test]
fn a_graph_of_only_daemons_is_refused() {
    let err = refused(
        "daemons",
        "[[nodes]]\nname = \"rec\"\nbinary = \"dc-record\"\ndaemon = true\nparams = { out = \"x.mcap\" }\n",
    );
    assert!(err.contains("every node is a daemon"), "{err}");
}

#[test]
fn parameters_that_would_fail_later_are_refused_before_start() {
    // Each parses, but would make no grid (or an enormous one) once the run starts.
    let err = refused(
        "sph-params",
        "[[nodes]]\nname = \"zero\"\nbinary = \"dc-sph\"\nparams = { res = 0 }\n\n\
         [[nodes]]\nname = \"huge\"\nbinary = \"dc-sph\"\nparams = { bounds = \"0,0,1e9,1e9\" }\n\n\
         [[nodes]]\nname = \"fine\"\nbinary = \"dc-sph\"\nparams = { res = 1e-4 }\n\n\
         [[nodes]]\nname = \"narrow\"\nbinary = \"dc-sph\"\nparams = { h = 0.01 }\n",
    );
    for (line, node, what) in [
        (1, "zero", "grid spacing (res) must be > 0"),
        (6, "huge", "above the limit 4096 x 4096"),
        (11, "fine", "needs 150002 nodes"),
        (16, "narrow", "below half the grid spacing"),
    ] {
        assert!(err.contains(&format!("graph.toml:{line}: node `{node}` (dc-sph): bad parameters")), "{node}: {err}");
        assert!(err.contains(what), "{node}: {what}:\n{err}");
    }
}

/// Runs `dc launch` on `graph` like [`launch`], but fails the test (killing the launcher) if it
/// has not ended within `limit`: a graph that never stops must not hang the suite.
fn launch_within(test: &str, graph: &str, limit: Duration) -> Output {
    let dir = scratch_dir(test);
    let file = dir.join("graph.toml");
    std::fs::write(&file, graph).unwrap();
    let mut child = Command::new(bin("dc"))
        .arg("launch")
        .arg(&file)
        .args(["--namespace", &unique_namespace(test)])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run dc");
    let drain = |mut pipe: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut bytes = Vec::new();
            let _ = pipe.read_to_end(&mut bytes);
            bytes
        })
    };
    let stdout = drain(Box::new(child.stdout.take().unwrap()));
    let stderr = drain(Box::new(child.stderr.take().unwrap()));
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break Some(status);
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let out = Output {
        status: status.unwrap_or_else(|| ExitStatus::from_raw(9)),
        stdout: stdout.join().unwrap(),
        stderr: stderr.join().unwrap(),
    };
    assert!(status.is_some(), "{test}: the graph did not end within {limit:?}:\n{}", text(&out));
    out
}

fn pids_with(marker: &str) -> Vec<String> {
    let out = std::process::Command::new("pgrep").args(["-f", marker]).output().expect("pgrep");
    String::from_utf8_lossy(&out.stdout).lines().map(str::to_string).collect()
}

#[test]
fn a_failing_node_stops_the_graph_and_leaves_no_orphans() {
    // `doomed` waits 1 s for frames that never come and fails; `bystander` would wait a minute.
    let marker = format!("bystander-{}", std::process::id());
    let graph = format!(
        r#"
[[nodes]]
name = "bystander"
binary = "dc-bench-bus"
params = {{ role = "sink", timeout-s = 60, label = "{marker}" }}

[[nodes]]
name = "doomed"
binary = "dc-bench-bus"
params = {{ role = "sink", kind = "grid", timeout-s = 1 }}
"#
    );
    let (_, out) = launch("failing", &graph, &[]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("node `doomed` exited with exit status 1"), "{stderr}");
    assert!(stderr.contains("lost frames"), "the node's own error is forwarded:\n{stderr}");
    // ... and quoted in the launcher's final error, said once (no `Caused by:` repeat).
    let last = stderr.lines().find(|l| l.starts_with("dc: error: node `doomed` exited")).expect("final error");
    assert!(last.contains("exit status 1: error: ") && last.contains("lost frames"), "{last}");
    assert!(!stderr.contains("Caused by"), "{stderr}");
    // The bystander was stopped (it says so), not left to time out and fail a minute later.
    assert!(stderr.contains("stopped before all frames arrived"), "the bystander was not stopped:\n{stderr}");
    assert!(!stderr.contains("node `bystander` exited"), "{stderr}");
    assert!(pids_with(&marker).is_empty(), "orphan processes remain: {:?}", pids_with(&marker));
}

#[test]
fn a_node_failing_past_its_restart_bound_stops_the_graph() {
    // `flaky` fails every time it runs (it waits 0.3 s for frames that never come) and may be
    // restarted twice; `patient` would wait a minute.
    let marker = format!("patient-{}", std::process::id());
    let graph = format!(
        r#"
[[nodes]]
name = "patient"
binary = "dc-bench-bus"
params = {{ role = "sink", timeout-s = 60, label = "{marker}" }}

[[nodes]]
name = "flaky"
binary = "dc-bench-bus"
on_failure = "restart"
max_restarts = 2
params = {{ role = "sink", kind = "grid", timeout-s = 0.3 }}
"#
    );
    let out = launch_within("restarts", &graph, Duration::from_secs(120));
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    // Started once and restarted twice, then no more.
    assert_eq!(stderr.matches("[dc] node `flaky` started (pid").count(), 3, "{stderr}");
    for attempt in 1..=2 {
        let line = format!("[dc] node `flaky` exited with exit status 1: restarting it ({attempt} of at most 2)");
        assert!(stderr.contains(&line), "no restart {attempt}:\n{stderr}");
    }
    assert!(!stderr.contains("restarting it (3 of"), "{stderr}");
    assert!(
        stderr.contains("[dc] node `flaky` exited with exit status 1 after 2 restarts: stopping the graph"),
        "{stderr}"
    );
    let last = stderr.lines().find(|l| l.starts_with("dc: error: ")).expect("final error");
    assert!(
        last.starts_with(
            "dc: error: node `flaky` exited with exit status 1 after 2 restarts (its bound): stopping the graph"
        ) && last.contains("lost frames"),
        "{last}"
    );
    // The rest of the graph was stopped, not left to fail on its own.
    assert!(stderr.contains("stopped before all frames arrived"), "`patient` was not stopped:\n{stderr}");
    assert!(!stderr.contains("node `patient` exited with exit status 1"), "{stderr}");
    assert!(pids_with(&marker).is_empty(), "orphan processes remain: {:?}", pids_with(&marker));
}

#[test]
fn dry_run_and_list_show_the_graph_without_starting_it() {
    let graph = "[topics]\n\"bench/bodies\" = \"zenoh\"\n\
                 [[nodes]]\nname = \"s\"\nbinary = \"dc-bench-bus\"\nparams = { role = \"sink\" }\n\
                 [[nodes]]\nname = \"src\"\nbinary = \"dc-bench-bus\"\nparams = { role = \"source\" }\n";
    let (file, out) = launch("dry", graph, &["--dry-run"]);
    assert!(out.status.success(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("s: ") && stdout.contains("--role=sink"), "{stdout}");
    // The ports come from the node binaries; the forced topic travels over zenoh.
    assert!(stdout.contains("publishes -; subscribes bench/bodies"), "{stdout}");
    let route = stdout.lines().find(|l| l.trim_start().starts_with("bench/bodies")).unwrap_or_default();
    assert!(route.contains("src -> s") && route.contains("[zenoh on local]"), "{stdout}");
    let list = std::process::Command::new(deep_contact::bin("dc")).arg("list").arg(&file).output().unwrap();
    assert!(list.status.success(), "{}", text(&list));
}

/// The program `dc` runs for `binary` when none of that name is beside it: the first on PATH.
fn on_path(binary: &str) -> std::path::PathBuf {
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path).map(|d| d.join(binary)).find(|p| p.is_file()).expect("on PATH")
}

/// `dc list` ran what a launch file named: `env -S "sh -c ..."` ran a command from a file that
/// was only being read. Neither `dc list` nor `dc launch --dry-run` runs a program that is not
/// one of dc's node binaries; the error names the line, the node, the program and `--trust`.
#[test]
fn list_and_dry_run_run_no_program_a_file_names_unless_trusted() {
    let dir = scratch_dir("untrusted");
    let marker = dir.join("ran");
    let graph = format!(
        "[[nodes]]\nname = \"sneaky\"\nbinary = \"env\"\nparams = {{ split-string = \"sh -c 'touch {}'\" }}\n",
        marker.display()
    );
    let file = dir.join("graph.toml");
    std::fs::write(&file, &graph).unwrap();
    let list = Command::new(bin("dc")).arg("list").arg(&file).output().unwrap();
    let (_, dry) = launch("untrusted-dry", &graph, &["--dry-run"]);
    let refusal = format!(
        "graph.toml:1: node `sneaky` (env): not run: `{}` is not one of dc's node binaries",
        on_path("env").display()
    );
    for out in [&list, &dry] {
        assert_eq!(out.status.code(), Some(1), "{}", text(out));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(&refusal) && err.contains("--trust"), "{err}");
        assert!(!marker.exists(), "the file's command ran:\n{}", text(out));
    }
}

/// A node that never answered its check hung `dc list` for good. Named like one of dc's nodes
/// but not beside dc, it is refused; trusted, its check has a time limit (`DC_CHECK_TIMEOUT`
/// here, 20 s by default), past which its process group is killed and `dc list` fails.
#[test]
fn a_check_that_never_ends_fails_list_within_its_time_limit() {
    use std::os::unix::fs::PermissionsExt;
    let dir = scratch_dir("check-timeout");
    let script = dir.join("dc-sleepy");
    std::fs::write(&script, "#!/bin/sh\nsleep 1000\n").unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    let file = dir.join("graph.toml");
    std::fs::write(&file, format!("[[nodes]]\nname = \"sleepy\"\nbinary = \"{}\"\n", script.display())).unwrap();
    let list = |extra: &[&str]| {
        Command::new(bin("dc")).arg("list").arg(&file).args(extra).env("DC_CHECK_TIMEOUT", "1").output().unwrap()
    };
    let out = list(&[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(err.contains(&format!("`{}` is not one of dc's node binaries", script.display())), "{err}");
    assert!(err.contains("--trust"), "{err}");

    let started = Instant::now();
    let out = list(&["--trust"]);
    assert!(started.elapsed() < Duration::from_secs(15), "took {:?}", started.elapsed());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(err.contains("graph.toml:1: node `sleepy`") && err.contains("did not end within 1 s"), "{err}");
    // Its whole process group went: the shell running the script, and its `sleep`.
    std::thread::sleep(Duration::from_millis(200));
    let script = script.display().to_string();
    assert!(pids_with(&script).is_empty(), "the check is still running: {:?}", pids_with(&script));
}

/// Each graph left its namespace's lock file in $TMPDIR/dc-graphs, one more per `dc eval`: the
/// launcher removes it when the graph ends, after success as after a failure.
#[test]
fn a_graph_leaves_no_lock_file_when_it_ends() {
    let lock = |ns: &str| std::env::temp_dir().join("dc-graphs").join(format!("{ns}@local.lock"));
    let pair = "[[nodes]]\nname = \"sink\"\nbinary = \"dc-bench-bus\"\nparams = { role = \"sink\", count = 10 }\n\
                [[nodes]]\nname = \"source\"\nbinary = \"dc-bench-bus\"\nparams = { role = \"source\", count = 10 }\n";
    let doomed =
        "[[nodes]]\nname = \"doomed\"\nbinary = \"dc-bench-bus\"\nparams = { role = \"sink\", kind = \"grid\", timeout-s = 0.3 }\n";
    for (test, graph, succeeds) in [("lock-ok", pair, true), ("lock-failed", doomed, false)] {
        let file = scratch_dir(test).join("graph.toml");
        std::fs::write(&file, graph).unwrap();
        let namespace = unique_namespace(test);
        let out = Command::new(bin("dc")).arg("launch").arg(&file).args(["--namespace", &namespace]).output().unwrap();
        assert_eq!(out.status.success(), succeeds, "{test}: {}", text(&out));
        assert!(!lock(&namespace).exists(), "{test}: {} left behind", lock(&namespace).display());
    }
}

#[test]
fn dc_record_forwards_to_the_recorder_and_names_a_bad_file() {
    let readme = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md");
    let out =
        std::process::Command::new(deep_contact::bin("dc")).args(["record", "info"]).arg(&readme).output().unwrap();
    assert!(!out.status.success(), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("README.md: not an MCAP file"), "{stderr}");
}

#[test]
fn eval_feeds_the_unet_the_grids_its_model_file_asks_for_and_refuses_a_non_model() {
    let dc = deep_contact::bin("dc");
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = std::process::Command::new(&dc)
        .current_dir(root)
        .args(["eval", "--models", "grid,unet", "--seeds", "0..2", "--dry-run"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let sph = stdout.lines().find(|l| l.trim_start().starts_with("sph")).expect("an sph node");
    // The demo model is temporal, padded to 128, preserving transfer at the thesis's spacing.
    for arg in ["--temporal", "--pad-to=128", "--res=0.125", "--mode=preserving"] {
        assert!(sph.contains(arg), "{sph}");
    }
    assert!(stdout.contains("dc-unet --model=") && stdout.contains("models/unet-demo.dcu"), "{stdout}");

    let out = std::process::Command::new(&dc)
        .current_dir(root)
        .args(["eval", "--models", "unet", "--unet-model", "README.md", "--seeds", "0..2", "--dry-run"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("README.md") && stderr.contains("not a Deep Contact U-Net model"), "{stderr}");
}

#[test]
fn eval_starts_the_gnn_node_for_gnn_node_and_asks_for_its_model() {
    let dc = |args: &[&str]| Command::new(bin("dc")).args(args).output().unwrap();
    let out = dc(&["eval", "--models", "gnn-node", "--seeds", "0..1", "--dry-run"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("needs --gnn-model"), "{}", text(&out));
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/models/gnn.dcg");
    let out = dc(&["eval", "--models", "gnn-node", "--seeds", "0..1", "--gnn-model", model, "--dry-run"]);
    let listed = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", text(&out));
    // The node serves the simulator's problems; the simulator reads its answers.
    assert!(listed.contains("publishes warm/gnn; subscribes control, problem/bodies, problem/contacts"), "{listed}");
    assert!(listed.contains("warm/gnn") && listed.contains("sim-0 -> "), "{listed}");
}

#[test]
fn a_daemon_finishes_its_backlog_before_the_daemon_that_records_it_stops() {
    // The simulator outruns an SPH node on a fine grid (back-pressure holds it a queue ahead), so
    // when it ends, steps are still queued at SPH. The launcher stops producers before their
    // readers and SPH turns what it holds into grids: the recording has every step's grid.
    let dir = scratch_dir("daemon-backlog");
    let recordings = dir.join("rec");
    let graph = format!(
        "[[nodes]]\nname = \"sim\"\nbinary = \"dc-sim\"\nparams = {{ models = \"builtin\", seeds = \"0\", steps = 60 }}\n\n\
         [[nodes]]\nname = \"sph\"\nbinary = \"dc-sph\"\ndaemon = true\nparams = {{ res = 0.04 }}\n\n\
         [[nodes]]\nname = \"recorder\"\nbinary = \"dc-record\"\ndaemon = true\n\
         params = {{ dir = \"{}\", topics = \"bodies,grid/contacts\" }}\n",
        recordings.display()
    );
    let out = launch_within("daemon-backlog", &graph, Duration::from_secs(120));
    assert!(out.status.success(), "{}", text(&out));
    let (mut bodies, mut grids) = (std::collections::BTreeSet::new(), std::collections::BTreeSet::new());
    for file in recorder::recording_files(&recordings).unwrap() {
        let mut reader = recorder::RecordingReader::open(&file).unwrap();
        while let Some(m) = reader.next_message() {
            let m = m.unwrap();
            match m.channel.topic.as_str() {
                "bodies" => bodies.insert(msgs::decode::<msgs::StepHeader, msgs::Body>(&m.data).unwrap().header.step),
                "grid/contacts" => {
                    grids.insert(msgs::decode::<msgs::GridHeader, f32>(&m.data).unwrap().header.step.step)
                }
                other => panic!("unexpected topic {other}"),
            };
        }
    }
    assert_eq!(bodies.len(), 60, "{}", text(&out));
    assert_eq!(grids, bodies, "steps recorded without their grid:\n{}", text(&out));
}

/// `dc` under an address-space limit (its nodes inherit it), so that a bound that regresses fails
/// the test with an allocation abort instead of exhausting the machine.
fn dc_limited(args: &[&str]) -> Output {
    Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 8000000; exec \"$0\" \"$@\"")
        .arg(bin("dc"))
        .args(args)
        .output()
        .expect("run dc")
}

#[test]
fn counts_and_sizes_beyond_their_bounds_are_refused_by_the_check() {
    let dir = scratch_dir("bounds");
    let file = dir.join("graph.toml");
    std::fs::write(
        &file,
        "[[nodes]]\nname = \"many\"\nbinary = \"dc-sim\"\nparams = { seeds = \"0..4294967296\" }\n\n\
         [[nodes]]\nname = \"wide\"\nbinary = \"dc-sim\"\nparams = { side = 1e12 }\n\n\
         [[nodes]]\nname = \"crowd\"\nbinary = \"dc-sim\"\nparams = { n = 100000000 }\n",
    )
    .unwrap();
    let out = dc_limited(&["launch", file.to_str().unwrap(), "--dry-run"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    for (line, node, what) in [
        (1, "many", "invalid parameter `seeds` = 0..4294967296: `0..4294967296`: more than 100000 seeds"),
        (6, "wide", "invalid parameter `side` = 1000000000000: at most 4096"),
        (11, "crowd", "invalid parameter `n` = 100000000: at most 1000000 bodies"),
    ] {
        assert!(
            err.contains(&format!("graph.toml:{line}: node `{node}` (dc-sim): bad parameters: {what}")),
            "{node}:\n{err}"
        );
    }
    assert!(!err.contains("panicked") && !err.contains("backtrace") && !err.contains("crashed"), "{err}");
}

#[test]
fn eval_refuses_an_unwritable_out_folder_before_any_node_starts() {
    let dir = scratch_dir("eval-out");
    let file = dir.join("not-a-folder");
    std::fs::write(&file, "x").unwrap();
    // Root may write anywhere: a path below a regular file is what cannot be created.
    let out_dir = file.join("report");
    let started = Instant::now();
    let args = "eval --models none --seeds 0 --steps 1 --n 20 --out";
    let out = dc_limited(&args.split(' ').chain([out_dir.to_str().unwrap()]).collect::<Vec<_>>());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    assert!(err.contains("--out") && err.contains(&format!("cannot create the folder {}", out_dir.display())), "{err}");
    // Refused before start: no node ran, so no node output and no run summary.
    assert!(!String::from_utf8_lossy(&out.stdout).contains('['), "{}", text(&out));
    assert!(!err.contains("[sim-0]") && !err.contains("[metrics]"), "{err}");
    assert!(started.elapsed() < Duration::from_secs(30), "took {:?}", started.elapsed());
}

/// Eight simulators at once (`--jobs 8`, one model each): nine writers of `control` with the
/// launcher, more than the eight an iceoryx2 service was once made for ("ExceedsMaxSupported
/// Publishers" at start, after the check had passed). Every model's run reaches the report.
#[test]
fn eval_runs_eight_simulators_at_once() {
    let dir = scratch_dir("eval-jobs-8");
    let out_dir = dir.join("report");
    let models = "builtin,none,copy,extrapolate,blend:0.5,noise:1,cg:10,continue";
    let out = Command::new(bin("dc"))
        .args(["eval", "--models", models, "--jobs", "8", "--seeds", "0..1", "--steps", "60", "--n", "30", "--out"])
        .arg(&out_dir)
        .output()
        .expect("run dc");
    assert!(out.status.success(), "{}", text(&out));
    let summary = std::fs::read_to_string(out_dir.join("summary.csv")).unwrap();
    let rows: Vec<Vec<&str>> = summary.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 8, "{summary}");
    for model in models.split(',') {
        // A model named without its parameter is reported with the default one (`continue:1`).
        let row = rows.iter().find(|r| r[0] == model || r[0].starts_with(&format!("{model}:")));
        let row = row.unwrap_or_else(|| panic!("{model} missing: {summary}"));
        assert_eq!((row[1], row[2]), ("1", "60"), "{model}: one simulation of 60 steps");
        assert!(row[3].parse::<u64>().unwrap() > 0, "{model} solved nothing: {summary}");
    }
    // Without a terminal the log is short: a line per model as its run ends, the result
    // table, the report's path (plus what nodes warn of); not every node's log.
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(stdout.lines().count() + stderr.lines().count() <= 40, "{}", text(&out));
    for model in ["builtin", "none", "copy", "extrapolate", "blend:0.5", "noise:1", "cg:10", "continue"] {
        assert!(stdout.lines().any(|l| l.contains(&format!("] model {model}"))), "{model}: {stdout}");
    }
    assert_eq!(stdout.lines().filter(|l| l.starts_with("| ") && !l.starts_with("| model")).count(), 8, "{stdout}");
    assert!(stdout.contains("evaluation report: "), "{stdout}");
}

#[test]
fn eval_at_budgets_runs_every_model_at_each_and_tabulates_their_accuracy() {
    let dir = scratch_dir("eval-budget");
    let out_dir = dir.join("report");
    // grid is served by the SPH node: the error split measures served models too.
    let args = "eval --models builtin,none,grid --seeds 0..2 --steps 60 --n 30 --budget 2,8 --error-split --out";
    let out = Command::new(bin("dc"))
        .args(args.split(' ').chain([out_dir.to_str().unwrap(), "--", "--solver", "pgs"]))
        .output()
        .expect("run dc");
    assert!(out.status.success(), "{}", text(&out));
    for k in [2u32, 8] {
        let steps = std::fs::read_to_string(out_dir.join(format!("budget-{k}/steps.csv"))).unwrap();
        let header: Vec<&str> = steps.lines().next().unwrap().split(',').collect();
        let column =
            |name: &str| header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("{name} in {header:?}"));
        let (sweeps, natural, contacts) = (column("sweeps"), column("natural_max"), column("contacts"));
        let (split_contacts, split_budget) = (column("split_contacts"), column("split_budget"));
        let rows: Vec<Vec<String>> =
            steps.lines().skip(1).map(|l| l.split(',').map(str::to_string).collect()).collect();
        assert_eq!(rows.len(), 3 * 2 * 60, "three models, two seeds, 60 steps");
        // Every step with contacts split over all of them, at the budget.
        for r in &rows {
            assert_eq!(r[split_contacts], r[contacts], "{r:?}");
            assert_eq!(r[split_budget], if r[contacts] == "0" { "0".to_string() } else { k.to_string() }, "{r:?}");
        }
        // Exactly k sweeps, fewer only where the natural residual already met the tolerance.
        for r in &rows {
            let s: u32 = r[sweeps].parse().unwrap();
            let n: f32 = r[natural].parse().unwrap();
            assert!(s == k || (s < k && n <= 1e-4), "budget {k}: {r:?}");
        }
        assert!(rows.iter().any(|r| r[sweeps] == k.to_string() && r[contacts] != "0"), "budget {k} used");
    }
    let table = std::fs::read_to_string(out_dir.join("budgets.md")).unwrap();
    assert!(table.contains("| builtin | 2 |") && table.contains("| builtin | 8 | "), "{table}");
    assert!(table.contains("| none | 2 |") && table.contains("| none | 8 |"), "{table}");
    // builtin sits on its own curve at its own budget, and buys nothing there: 1.00x its time.
    assert!(
        table.lines().any(|l| l.starts_with("| builtin | 8 |")
            && l.split('|').nth(3).unwrap().trim() == "1.00x"
            && l.split('|').nth(5).unwrap().trim() == "8.0"),
        "{table}"
    );
    // Which part of builtin's error each removes: builtin none; from a zero start the budget's
    // sweeps leave more than from builtin's.
    let split = table.split("Which part of builtin's warm-start error").nth(1).unwrap_or_else(|| panic!("{table}"));
    let row = |model: &str, k: u32| {
        let prefix = format!("| {model} | {k} | ");
        let line = split.lines().find(|l| l.starts_with(&prefix)).unwrap_or_else(|| panic!("{prefix}: {split}"));
        line.split('|').map(|c| c.trim().to_string()).filter(|c| !c.is_empty()).collect::<Vec<_>>()
    };
    let figure = |cell: &str| cell.parse::<f64>().unwrap_or_else(|_| panic!("{cell}: {split}"));
    for k in [2, 8] {
        let builtin = row("builtin", k);
        assert_eq!((builtin[2].as_str(), builtin[3].as_str()), ("0%", "0%"), "{split}");
        assert_eq!(builtin[4], builtin[5], "{split}");
        assert_eq!(builtin[6], builtin[7], "{split}");
        let none = row("none", k);
        assert!(figure(&none[4]) > figure(&none[5]), "{split}");
        assert_eq!(row("grid", k).len(), 8, "{split}");
    }
    let report = std::fs::read_to_string(out_dir.join("budget-8/summary.md")).unwrap();
    assert!(
        report.contains("## Which part of builtin's error each model removes") && report.contains("| grid |"),
        "{report}"
    );
}

/// `dc topic list --namespace NS` against a running graph: each topic the simulator and the
/// recorder use, with its frame kind and its writers and readers as they are (control: the
/// simulator and the launcher); a namespace with no graph says so and exits 1.
#[test]
fn topic_list_shows_a_running_graphs_topics_with_their_writers_and_readers() {
    let dir = scratch_dir("topic-list");
    let namespace = unique_namespace("topic-list");
    let file = dir.join("graph.toml");
    let recording = dir.join("run.mcap");
    std::fs::write(
        &file,
        format!(
            "[graph]\nname = \"topics\"\n[[nodes]]\nname = \"recorder\"\nbinary = \"dc-record\"\ndaemon = true\n\
             params = {{ out = \"{}\", topics = \"control,bodies,stats/solve\" }}\n\
             [[nodes]]\nname = \"sim\"\nbinary = \"dc-sim\"\nparams = {{ seeds = \"0..1\", steps = 1000000, model = \"builtin\", n = 20 }}\n",
            recording.display()
        ),
    )
    .unwrap();
    let mut graph = Command::new(bin("dc"))
        .arg("launch")
        .arg(&file)
        .args(["--namespace", &namespace])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let list = || Command::new(bin("dc")).args(["topic", "list", "--namespace", &namespace]).output().unwrap();
    let started = std::time::Instant::now();
    let listed = loop {
        let out = list();
        let stdout = String::from_utf8_lossy(&out.stdout).to_string();
        // Up once the recorder reads bodies and both writers of control (the simulator's and the
        // launcher's) have registered: under load they show up one after the other.
        let has = |row: [&str; 5]| stdout.lines().any(|l| l.split_whitespace().collect::<Vec<_>>()[1..] == row);
        if out.status.success()
            && has(["bodies", "Bodies", "1", "1", "reliable"])
            && has(["control", "Control", "2", "2", "reliable"])
        {
            break stdout;
        }
        assert!(
            started.elapsed() < std::time::Duration::from_secs(60),
            "the graph's topics never showed: {}",
            text(&out)
        );
        std::thread::sleep(std::time::Duration::from_millis(200));
    };
    let _ = Command::new("kill").arg("-INT").arg(graph.id().to_string()).status();
    graph.wait().unwrap();
    let rows: Vec<Vec<&str>> = listed.lines().skip(1).map(|l| l.split_whitespace().collect()).collect();
    let row = |topic: &str| rows.iter().find(|r| r[1] == topic).unwrap_or_else(|| panic!("{topic} missing:\n{listed}"));
    assert!(rows.iter().all(|r| r[0] == namespace), "{listed}");
    assert_eq!(row("contacts")[2..5], ["Contacts", "1", "0"], "written by the simulator, read by nobody:\n{listed}");
    assert_eq!(
        row("control")[2..5],
        ["Control", "2", "2"],
        "the simulator and the launcher write, the recorder and the simulator (a shutdown from outside) read:\n{listed}"
    );
    assert_eq!(row("stats/solve")[2..5], ["SolveStats", "1", "1"], "{listed}");

    let none = Command::new(bin("dc")).args(["topic", "list", "--namespace", "no-graph-here"]).output().unwrap();
    assert_eq!(none.status.code(), Some(1), "{}", text(&none));
    assert!(
        String::from_utf8_lossy(&none.stderr).contains("no topics alive in namespace `no-graph-here`"),
        "{}",
        text(&none)
    );
}

#[test]
fn a_launcher_whose_stdout_closes_keeps_supervising_its_graph() {
    // `dc launch g.toml | head -1`: the reader goes away after the first line; the launcher must
    // not die of the broken pipe (it took its nodes and the recording with it).
    let dir = scratch_dir("closed-stdout");
    let recording = dir.join("all.mcap");
    let graph = format!(
        "[[nodes]]\nname = \"recorder\"\nbinary = \"dc-record\"\ndaemon = true\nparams = {{ out = \"{}\", topics = \"stats/solve\" }}\n\n\
         [[nodes]]\nname = \"sim\"\nbinary = \"dc-sim\"\nparams = {{ models = \"builtin,none,copy,bad\", seeds = \"0..2\", steps = 60, n = 30, \"step-period\" = \"2ms\" }}\n",
        recording.display()
    );
    let file = dir.join("graph.toml");
    std::fs::write(&file, graph).unwrap();
    let mut child = Command::new(bin("dc"))
        .arg("launch")
        .arg(&file)
        .args(["--namespace", &unique_namespace("closed-stdout")])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run dc");
    let mut stdout = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut first = String::new();
    std::io::BufRead::read_line(&mut stdout, &mut first).unwrap();
    drop(stdout);
    let stderr = child.stderr.take().unwrap();
    let log = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = std::io::BufReader::new(stderr).read_to_string(&mut s);
        s
    });
    let started = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        assert!(started.elapsed() < Duration::from_secs(120), "the graph did not end");
        std::thread::sleep(Duration::from_millis(50));
    };
    let log = log.join().unwrap();
    assert!(status.success(), "{status}: {first}\n{log}");
    assert!(!log.contains("panicked"), "{log}");
    // Every run's every step reached the recording: 4 models x 2 seeds x 60 steps.
    let info = recorder::Info::read(&recording).unwrap();
    let solves = info.topics.get("stats/solve").map(|t| t.messages).unwrap_or(0);
    assert_eq!(solves, 4 * 2 * 60, "{log}");
}

/// `dc` from any folder: the defaults name the shipped files, and a launch file's relative paths
/// are its own (`[graph] root`, from the file's folder), not the current folder's.
#[test]
fn eval_and_launch_dry_runs_work_from_any_folder() {
    let elsewhere = scratch_dir("any-folder");
    let repo = deep_contact::repo_root().canonicalize().unwrap();
    for folder in [std::path::Path::new("/"), elsewhere.as_path()] {
        let dc = |args: &[&str]| Command::new(bin("dc")).current_dir(folder).args(args).output().unwrap();
        let out = dc(&["eval", "--dry-run", "--seeds", "0..2"]);
        assert!(out.status.success(), "dc eval --dry-run from {}: {}", folder.display(), text(&out));
        assert!(String::from_utf8_lossy(&out.stdout).contains("dc-unet --model="), "{}", text(&out));
        for (file, host) in [("launch/unet-loop.toml", None), ("launch/two-hosts.toml", Some("sim-box"))] {
            let file = repo.join(file);
            let mut args = vec!["launch", file.to_str().unwrap(), "--dry-run"];
            args.extend(host.iter().flat_map(|h| ["--host", *h]));
            let out = dc(&args);
            assert!(out.status.success(), "{args:?} from {}: {}", folder.display(), text(&out));
            let stdout = String::from_utf8_lossy(&out.stdout);
            assert!(stdout.contains(&format!("nodes run in {}", repo.display())), "{stdout}");
        }
    }
}

/// A host checks the files of its own nodes only: the model on the other host need not exist
/// here, a missing one on this host is named, and a relative one is the launch file's.
#[test]
fn each_host_checks_only_its_own_nodes_files() {
    let dir = scratch_dir("own-host-files");
    let file = dir.join("two.toml");
    let write = |model: &str| {
        let text = format!(
            "[hosts.sim-box]\naddress = \"127.0.0.1\"\nzenoh_port = 7447\n\n\
             [hosts.gpu-box]\naddress = \"127.0.0.2\"\nzenoh_port = 7447\n\n\
             [[nodes]]\nname = \"sim\"\nbinary = \"dc-sim\"\nhost = \"sim-box\"\n\
             params = {{ models = \"builtin\", seeds = \"0..1\", steps = 5 }}\n\n\
             [[nodes]]\nname = \"unet\"\nbinary = \"dc-unet\"\nhost = \"gpu-box\"\ndaemon = true\n\
             params = {{ model = \"{model}\" }}\n\n\
             [[nodes]]\nname = \"metrics\"\nbinary = \"dc-metrics\"\nhost = \"gpu-box\"\n\
             params = {{ runs = 1, out = \"report\" }}\n"
        );
        std::fs::write(&file, text).unwrap();
    };
    let dry_run = |host: &str| {
        Command::new(bin("dc"))
            .current_dir("/")
            .arg("launch")
            .arg(&file)
            .args(["--host", host, "--dry-run"])
            .output()
            .unwrap()
    };
    write("missing.dcu");
    let out = dry_run("sim-box");
    assert!(out.status.success(), "the sim host must not need the other host's model: {}", text(&out));
    let out = dry_run("gpu-box");
    assert!(!out.status.success(), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("node `unet`") && stderr.contains("missing.dcu"), "{stderr}");
    // Beside the launch file, named relatively: found from any folder.
    std::fs::copy(deep_contact::UNET_DEMO, dir.join("demo.dcu")).unwrap();
    write("demo.dcu");
    let out = dry_run("gpu-box");
    assert!(out.status.success(), "{}", text(&out));
}

#[test]
fn dc_says_its_version() {
    let out = Command::new(bin("dc")).arg("--version").output().unwrap();
    assert!(out.status.success(), "{}", text(&out));
    assert_eq!(String::from_utf8_lossy(&out.stdout).trim(), format!("dc {}", env!("CARGO_PKG_VERSION")));
}

/// A node that never gets ready (a server stuck importing, a model that loads forever): the
/// launcher says whom it waits for, and past `--ready-timeout` stops the graph naming it.
#[test]
fn a_node_that_never_gets_ready_is_named_and_the_wait_is_bounded() {
    use std::os::unix::fs::PermissionsExt;
    let dir = scratch_dir("never-ready");
    // Answers the checks as a node would, then never says it is ready.
    let script = dir.join("stall.sh");
    std::fs::write(
        &script,
        "#!/bin/sh\n[ \"$DC_VALIDATE\" = 1 ] && exit 0\n\
         [ \"$DC_DESCRIBE\" = 1 ] && { printf '\\036dc-ports {\"publishes\":[],\"subscribes\":[]}\\n'; exit 0; }\n\
         exec sleep 60\n",
    )
    .unwrap();
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    let file = dir.join("graph.toml");
    std::fs::write(&file, "[[nodes]]\nname = \"stuck\"\nbinary = \"./stall.sh\"\n").unwrap();
    let started = Instant::now();
    let out = Command::new(bin("dc"))
        .current_dir("/")
        .arg("launch")
        .arg(&file)
        .args(["--trust", "--ready-timeout", "7s", "--namespace", &unique_namespace("never-ready")])
        .output()
        .unwrap();
    assert!(!out.status.success(), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("waiting for node `stuck` to be ready"), "{stderr}");
    assert!(stderr.contains("node `stuck` not ready within 7 s"), "{stderr}");
    assert!(started.elapsed() < Duration::from_secs(30), "the wait is bounded: {:?}", started.elapsed());
}

#[test]
fn dc_writes_shell_completions() {
    for (shell, marker) in [("bash", "_dc()"), ("zsh", "#compdef dc")] {
        let out = Command::new(bin("dc")).args(["completions", shell]).output().unwrap();
        assert!(out.status.success(), "{}", text(&out));
        let script = String::from_utf8_lossy(&out.stdout);
        assert!(
            script.contains(marker) && script.contains("eval") && script.contains("topic"),
            "{shell}: {script:.300}"
        );
    }
}

//! How long `dc-sim` waits for a warm-start producer that never answers: a U-Net node whose input
//! grids never come (no SPH node in the graph). In lockstep the first step waits
//! `--lockstep-timeout`, then the producer counts as lost and every later step waits only
//! `--resume-patience` before it falls back; the run ends instead of hanging.
//!
//! Times are only bounded from below (a step cannot fall back before its wait is over) or against
//! the options' defaults with a wide margin: the test stays honest on a loaded machine.

use deep_contact::{launch, scratch_dir, text, UNET_DEMO};
use msgs::SolveStatsHeader;

/// Steps of the run: step 0 needs no grid (step k starts from the grid made of step k - 1), step 1
/// waits the lockstep timeout, step 2 the patience.
const STEPS: u32 = 3;
/// `--lockstep-timeout`: far below its 30 s default.
const LOCKSTEP_TIMEOUT_S: f64 = 1.0;
/// `--resume-patience`: above its 2 s default, so only the option explains waits this long.
const PATIENCE_S: f64 = 2.5;

/// `waited=1.006103778s` (a `Duration` as `Debug` prints it) in a log line, in seconds.
fn waited_secs(line: &str) -> f64 {
    let v = line.split_whitespace().find_map(|t| t.strip_prefix("waited=")).expect("a waited= field");
    let (number, scale) = if let Some(ms) = v.strip_suffix("ms") {
        (ms, 1e-3)
    } else if let Some(us) = v.strip_suffix("µs") {
        (us, 1e-6)
    } else {
        (v.strip_suffix('s').expect("a duration"), 1.0)
    };
    number.parse::<f64>().expect("a number") * scale
}

#[test]
fn a_producer_that_never_answers_costs_one_lockstep_timeout_then_the_patience_per_step() {
    let rec = scratch_dir("grid-waits-rec").join("stats.mcap");
    let graph = format!(
        r#"
[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ model = "unet", seeds = "0", steps = {STEPS}, n = 20, deadline = "none", lockstep-timeout = "{LOCKSTEP_TIMEOUT_S}s", resume-patience = "{PATIENCE_S}s" }}

[[nodes]]
name = "unet"
binary = "dc-unet"
daemon = true
params = {{ model = "{UNET_DEMO}" }}

[[nodes]]
name = "rec"
binary = "dc-record"
daemon = true
params = {{ out = "{}", topics = "stats/solve" }}
"#,
        rec.display()
    );
    let (_, out) = launch("grid-waits", &graph, &[]);
    let report = text(&out);
    assert!(out.status.success(), "{report}");
    let stderr = String::from_utf8_lossy(&out.stderr);

    // The producer counted as lost once, after waiting the lockstep timeout (not its 30 s
    // default); later steps did not wait for it again (they would each say so).
    let lost: Vec<&str> = stderr.lines().filter(|l| l.contains("within --lockstep-timeout")).collect();
    assert_eq!(lost.len(), 1, "{report}");
    let waited = waited_secs(lost[0]);
    assert!((LOCKSTEP_TIMEOUT_S..10.0).contains(&waited), "waited {waited} s for the first grid: {}", lost[0]);

    // Per step, as the simulator published it: every step that asked for a grid fell back to its
    // built-in warm start; the first waited the lockstep timeout, each later one the patience.
    let mut reader = recorder::RecordingReader::open(&rec).expect("the recording");
    let mut steps = Vec::new();
    while let Some(m) = reader.next_message() {
        let m = m.expect("an intact recording");
        let s: SolveStatsHeader = msgs::decode_header(&m.data).unwrap();
        steps.push((
            s.step.step,
            s.fallback,
            msgs::name16_str(&s.used_model).to_string(),
            s.warm_start_us as f64 * 1e-6,
        ));
    }
    eprintln!("steps (step, fallback, used, warm-start secs): {steps:?}");
    assert_eq!(steps.iter().map(|s| s.0).collect::<Vec<_>>(), (0..STEPS).collect::<Vec<_>>(), "{report}");
    for (step, fallback, used, secs) in &steps[1..] {
        assert!(*fallback == 1 && used == "builtin", "step {step}: fallback {fallback}, used {used}");
        let least = if *step == 1 { LOCKSTEP_TIMEOUT_S } else { PATIENCE_S };
        assert!(*secs >= least * 0.99, "step {step} waited {secs:.3} s, less than {least} s");
    }
}

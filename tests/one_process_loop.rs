//! The closed loop in one process (`dc-loop-bench`, the simulator's own run loop with SPH and the
//! U-Net called in turn) and the same loop as graphs over iceoryx2 and zenoh (`dc bench loop`)
//! solve exactly the same steps: the same total sweeps, from the typed run summaries.

use deep_contact::{bin, text};
use std::process::Command;

#[test]
fn one_process_and_graphs_solve_the_same_steps() {
    let out = Command::new(bin("dc"))
        .args(["bench", "loop", "--seeds", "0", "--steps", "80", "--n", "20", "--repeat", "1"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("run dc bench loop");
    assert!(out.status.success(), "{}", text(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    // Each variant's row: name, steps/s, loop s, total sweeps, fallbacks.
    let sweeps: Vec<u64> = ["one process (no bus)", "graph, iceoryx2 (one host)", "graph, every topic over zenoh"]
        .iter()
        .map(|variant| {
            let row = stdout
                .lines()
                .find(|l| l.starts_with(variant))
                .unwrap_or_else(|| panic!("no `{variant}` row\n{}", text(&out)));
            let cols: Vec<&str> = row[variant.len()..].split_whitespace().collect();
            assert_eq!(cols.len(), 4, "{row}");
            assert_eq!(cols[3], "0", "no fallbacks in lockstep: {row}");
            cols[2].parse().unwrap()
        })
        .collect();
    assert!(sweeps[0] > 0, "{}", text(&out));
    assert_eq!(sweeps, vec![sweeps[0]; 3], "{}", text(&out));
    assert!(
        stdout.contains("same total sweeps in every variant (lockstep solves the same problems): true"),
        "{}",
        text(&out)
    );
}

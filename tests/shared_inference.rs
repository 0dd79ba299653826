//! Several simulators feeding one inference node: two `dc-sim` processes with different seed
//! ranges share one SPH node and one `dc-unet`, which batches grids that wait together; each
//! simulator takes only the replies for its own simulations, in lockstep.

use deep_contact::{launch, report_steps, text, UNET_DEMO};

#[test]
fn two_simulators_share_one_unet_and_each_gets_its_own_replies() {
    let dir = deep_contact::scratch_dir("shared-unet");
    let report = dir.join("report");
    let sim = |name: &str, seeds: &str, run: u32| {
        format!(
            "[[nodes]]\nname = \"{name}\"\nbinary = \"dc-sim\"\nparams = {{ models = \"unet\", seeds = \"{seeds}\", steps = 40, n = 40, deadline = \"none\", run-id = {run} }}\n"
        )
    };
    let graph = format!(
        "{}{}
[[nodes]]
name = \"sph\"
binary = \"dc-sph\"
daemon = true
params = {{ mode = \"preserving\", temporal = true, pad-to = 128 }}

[[nodes]]
name = \"unet\"
binary = \"dc-unet\"
daemon = true
params = {{ model = \"{UNET_DEMO}\" }}

[[nodes]]
name = \"metrics\"
binary = \"dc-metrics\"
params = {{ runs = 2, out = \"{}\" }}
",
        sim("sim-a", "0..2", 11),
        sim("sim-b", "2..4", 12),
        report.display()
    );
    let (_, out) = launch("shared-unet", &graph, &[]);
    let log = text(&out);
    assert!(out.status.success(), "{log}");
    let steps = report_steps(&report);
    assert_eq!(steps.len(), 4 * 40, "4 simulations x 40 steps: {log}");
    assert!(
        steps.values().all(|(_, fallback, used)| !fallback && used == "unet"),
        "every step used the U-Net's reply for its own simulation (lockstep, no fallback)"
    );
    // The node served both simulators: more predictions than batches means grids of the two
    // waited together and went through the network in one batch.
    let done = log.lines().find(|l| l.contains("dc-unet done")).unwrap_or_else(|| panic!("no dc-unet summary: {log}"));
    let field = |name: &str| -> u64 {
        let at = done.find(&format!("{name}=")).unwrap_or_else(|| panic!("no {name} in `{done}`")) + name.len() + 1;
        done[at..].split(|c: char| !c.is_ascii_digit()).next().unwrap().parse().unwrap()
    };
    let (predicted, batches) = (field("predicted"), field("batches"));
    assert!(predicted > 0 && batches < predicted, "no batching across simulators: {done}");
}

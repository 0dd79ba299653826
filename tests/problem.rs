//! The contact problem on the bus: a simulator run with `--publish-problem` publishes each step's
//! velocity problem, a recorder keeps it, and re-solving every recorded problem from the warm
//! start the run used (builtin's: the previous step's impulses) takes exactly the sweeps the run
//! reported, with the same residual after every sweep. With `--label-tolerance` the problems
//! carry a reference solution from which the solve is over at once.

use deep_contact::{bin, launch, scratch_dir, text};

#[test]
fn recorded_problems_resolve_to_the_recorded_sweeps() {
    let dir = scratch_dir("problem");
    let file = record_problems(&dir, "", 150);
    let resolved = resolve_every_step(&file, 0.0, 1.0);
    assert_eq!(resolved.steps, 150);
    let (with_contacts, total_sweeps, old_contacts) = (resolved.with_contacts, resolved.sweeps, resolved.old_contacts);
    assert!(with_contacts > 50 && total_sweeps > 1000, "{with_contacts} steps with contacts, {total_sweeps} sweeps");
    assert!(old_contacts > 1000, "{old_contacts} contacts at least two steps old");

    // The network trains end to end on the recording, and with --save-candidates every epoch's
    // network is written beside the chosen one, as a model file `dc-gnn` reads.
    let model = dir.join("net.dcg");
    let trained = std::process::Command::new(bin("dc-gnn-train"))
        .args(["--data", &file.display().to_string(), "--validation", &file.display().to_string()])
        .args(["--out", &model.display().to_string(), "--method", "backprop", "--epochs", "2", "--save-candidates"])
        .output()
        .unwrap();
    assert!(trained.status.success(), "{}", text(&trained));
    for path in [model.clone(), dir.join("net.epoch1.dcg"), dir.join("net.epoch2.dcg")] {
        let info = std::process::Command::new(bin("dc-gnn")).arg("info").arg(&path).output().unwrap();
        assert!(info.status.success(), "{}: {}", path.display(), text(&info));
    }
    // `--data` repeated trains on every recording given (here the same one twice: twice the
    // steps), and the model file says which.
    let training_steps = |out: &std::process::Output| -> usize {
        let text = text(out);
        let line = text.lines().find(|l| l.contains("training steps")).unwrap_or_else(|| panic!("{text}"));
        line.split_whitespace().nth(1).and_then(|n| n.parse().ok()).unwrap_or_else(|| panic!("{line}"))
    };
    let twice = std::process::Command::new(bin("dc-gnn-train"))
        .args(["--data", &file.display().to_string(), "--data", &file.display().to_string()])
        .args(["--validation", &file.display().to_string(), "--out", &dir.join("twice.dcg").display().to_string()])
        .args(["--method", "backprop", "--epochs", "1", "--hidden", "8", "--rounds", "1"])
        .output()
        .unwrap();
    assert!(twice.status.success(), "{}", text(&twice));
    assert_eq!(training_steps(&twice), 2 * training_steps(&trained));
    let info = std::process::Command::new(bin("dc-gnn")).arg("info").arg(dir.join("twice.dcg")).output().unwrap();
    let shown = format!("{} + {}", file.display(), file.display());
    assert!(text(&info).contains(&shown), "{}", text(&info));
}

/// Records `steps` steps of builtin on seed 3 with labelled problems (`extra`: more sim params).
fn record_problems(dir: &std::path::Path, extra: &str, steps: u32) -> std::path::PathBuf {
    let file = dir.join("problem.mcap");
    let graph = format!(
        r#"
[graph]
name = "problem"

[[nodes]]
name = "recorder"
binary = "dc-record"
daemon = true
params = {{ out = "{}" }}

[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ model = "builtin", seeds = "3", steps = {steps}, n = 40, publish-problem = true, label-tolerance = 1e-6{extra} }}
"#,
        file.display()
    );
    let (_, out) = launch("problem", &graph, &[]);
    assert!(out.status.success(), "{}", text(&out));
    file
}

struct Resolved {
    steps: usize,
    with_contacts: usize,
    sweeps: u64,
    old_contacts: u64,
}

/// Re-solves every recorded problem from builtin's warm start with its own stopping rule and
/// checks the sweeps, residuals and impulses against the recorded ones, and the reference.
fn resolve_every_step(file: &std::path::Path, compliance: f32, relaxation: f32) -> Resolved {
    let mut r = Resolved { steps: 0, with_contacts: 0, sweeps: 0, old_contacts: 0 };
    for step in recorder::Steps::open(file).expect("the recording") {
        let step = step.expect("a complete step");
        let stats = step.stats.as_ref().expect("statistics");
        let (bodies, contacts) = step.problem.as_ref().expect("the step's problem");
        assert_eq!(contacts.header.step, step.key);
        assert_eq!(contacts.header.bodies as usize, bodies.items.len());
        assert_eq!(contacts.items.len(), stats.header.contacts as usize);
        assert_eq!(contacts.header.compliance, compliance);
        assert_eq!(contacts.header.relaxation, relaxation);
        let problem = sim::problem::Problem {
            header: contacts.header,
            bodies: bodies.items.clone(),
            contacts: contacts.items.clone(),
        };
        let warm = sim::problem::builtin_warm_start(&problem.contacts);
        let mut solver_bodies = sim::problem::bodies_of(&problem.bodies);
        let mut solver = sim::ContactSolver::new();
        let report = solver.solve(
            &sim::problem::rows_of(&problem.contacts, problem.params().friction),
            &mut solver_bodies,
            &warm,
            &problem.params(),
        );
        assert_eq!(report.sweeps, stats.header.sweeps, "step {:?}", step.key);
        assert_eq!(solver.residuals(), &stats.items[..], "step {:?}: residuals differ", step.key);
        // The final impulses are the recorded contacts' (same order: sorted by key).
        for (l, c) in solver.impulses().iter().zip(&step.contacts.items) {
            assert_eq!((l.normal, l.tangent), (c.normal_impulse, c.tangent_impulse), "step {:?}", step.key);
        }
        if !problem.contacts.is_empty() {
            r.with_contacts += 1;
            let reference = problem.reference().expect("labelled");
            assert!(contacts.header.reference_sweeps > 0 && contacts.header.reference_tolerance == 1e-6);
            let (from_reference, _) = problem.solve(&reference);
            assert!(
                from_reference.sweeps <= 5,
                "step {:?}: {} sweeps from the reference",
                step.key,
                from_reference.sweeps
            );
            // A new contact has no previous impulse; one that persisted two steps has both.
            for c in &problem.contacts {
                if c.age == 0 {
                    assert_eq!(c.previous, [0.0; 2], "step {:?}", step.key);
                }
                r.old_contacts += (c.age >= 2) as u64;
            }
        }
        r.sweeps += report.sweeps as u64;
        r.steps += 1;
    }
    r
}

#[test]
fn compliant_relaxed_problems_carry_their_solver_and_resolve_to_the_recorded_sweeps() {
    let dir = scratch_dir("problem-compliant");
    let file = record_problems(&dir, ", compliance = 0.05, relaxation = 1.3", 80);
    let resolved = resolve_every_step(&file, 0.05, 1.3);
    assert_eq!(resolved.steps, 80);
    assert!(resolved.with_contacts > 20, "{} steps with contacts", resolved.with_contacts);
}

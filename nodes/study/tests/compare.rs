//! The solver study on the same states: the menu re-solves the trajectory's own states bit for
//! bit, and the learned per-step choice learns which setting a feature favours.

use sim::{SceneConfig, SolveParams, SolverSetting, StopRule, WorldParams};
use study::compare::{self, CompareSpec, SolverChooser};

fn natural(setting: &str, tolerance: f32) -> WorldParams {
    let solve = SolveParams { tolerance, stop: StopRule::Natural, ..Default::default() };
    WorldParams { solve: solve.with_setting(setting.parse().unwrap()), ..Default::default() }
}

/// The default scene for 120 steps, every step compared, the trajectory the menu's first
/// setting's (natural residual 1e-4).
fn every_step(menu: &[&str]) -> CompareSpec {
    CompareSpec {
        scene: SceneConfig::default(),
        params: natural(menu[0], 1e-4),
        steps: 120,
        menu: menu.iter().map(|s| s.parse().unwrap()).collect(),
        sampling: compare::Sampling::EVERY_STEP,
    }
}

#[test]
fn the_menu_on_the_trajectory_solvers_own_states_repeats_its_sweeps() {
    // The trajectory's own solver re-solving its own states from the same warm start must take
    // exactly the sweeps the run took: the comparison is on the same states, bit for bit.
    let spec = every_step(&["pgs", "sor:1.4/down", "nncg"]);
    let steps = compare::same_states(&spec, &[40, 41], |_| ()).unwrap();
    assert_eq!(steps.len(), 240);
    let run = compare::whole_run(&spec, &[40, 41], compare::Choice::Fixed(spec.menu[0]), |_| ()).unwrap();
    assert_eq!(run.sweeps, steps.iter().map(|s| s.solves[0].sweeps as u64).sum::<u64>());
    let rows = compare::same_states_table(&spec.menu, &steps, None);
    let ceiling = &rows[spec.menu.len()];
    assert!(rows[..spec.menu.len()].iter().all(|r| ceiling.sweeps <= r.sweeps), "{rows:?}");
    assert!(steps.iter().all(|s| s.solves.iter().all(|m| !m.converged || m.natural_max <= 1e-4)));
    assert!(compare::markdown(&rows).contains("hindsight best"));
}

#[test]
fn the_chooser_learns_which_setting_a_feature_favours() {
    // Two settings; the first is cheap when the pile is high (feature 2), the second otherwise.
    let menu: Vec<SolverSetting> = vec!["pgs".parse().unwrap(), "sor:1.4".parse().unwrap()];
    let solve = |sweeps| sim::world::MenuSolve {
        sweeps,
        converged: true,
        us: sweeps as f32,
        natural_max: 0.0,
        natural_rms: 0.0,
        ..Default::default()
    };
    let steps: Vec<compare::ComparedStep> = (0..200)
        .map(|i| {
            let height = (i % 10) as f64;
            let mut features = compare::StepFeatures::default();
            features.0[2] = height;
            features.0[0] = (i % 7) as f64; // noise the regression must ignore
            let (a, b) = if height >= 5.0 { (10, 40) } else { (40, 10) };
            compare::ComparedStep {
                seed: 1000,
                step: i,
                features,
                features_us: 0.0,
                contacts: 10,
                kinetic_energy: 0.0,
                solves: vec![solve(a), solve(b)],
            }
        })
        .collect();
    let chooser = SolverChooser::fit(&menu, &steps).unwrap();
    for s in &steps {
        let want = if s.features.0[2] >= 5.0 { 0 } else { 1 };
        // The boundary steps (height 4 and 5) may go either way for a linear fit.
        if !(4.0..=5.0).contains(&s.features.0[2]) {
            assert_eq!(chooser.choose(&s.features), want, "{:?}", s.features);
        }
    }
    assert!(SolverChooser::fit(&menu, &steps[..5]).unwrap_err().to_string().contains("training steps"));
}

#[test]
fn a_sampled_comparison_solves_the_same_states_on_the_sampled_steps_only() {
    // The trajectory runs every step whatever is compared: the sampled steps' solves are the
    // full comparison's on those steps, sweep for sweep and bit for bit in the residual.
    let full = every_step(&["nncg:1.2/down", "pgs"]);
    let sampled = CompareSpec { sampling: compare::Sampling { from: 50, every: 10 }, ..full.clone() };
    let all = compare::same_states(&full, &[42], |_| ()).unwrap();
    let some = compare::same_states(&sampled, &[42], |_| ()).unwrap();
    assert_eq!(some.iter().map(|s| s.step).collect::<Vec<_>>(), vec![50, 60, 70, 80, 90, 100, 110]);
    for s in &some {
        let same = &all[s.step as usize];
        assert_eq!(
            (s.contacts, s.kinetic_energy, s.features),
            (same.contacts, same.kinetic_energy, same.features),
            "step {}",
            s.step
        );
        for (a, b) in s.solves.iter().zip(&same.solves) {
            assert_eq!((a.sweeps, a.natural_max, a.natural_rms), (b.sweeps, b.natural_max, b.natural_rms));
        }
    }
    assert!(compare::settling(&some, 120).contains("(7 compared steps)"), "{}", compare::settling(&some, 120));
}

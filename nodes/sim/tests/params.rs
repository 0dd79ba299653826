//! Bad parameters give clear errors, in the library and at the binary.

use sim::{ModelKind, SceneConfig, SceneKind, SimError, SolveParams, World, WorldParams};
use std::process::Command;

#[test]
fn library_rejects_bad_parameters_with_clear_errors() {
    assert_eq!(
        "washing".parse::<SceneKind>().unwrap_err().to_string(),
        "unknown scene `washing` (known: ball-box, drum, mixed)"
    );
    assert!("oracle".parse::<ModelKind>().unwrap_err().to_string().starts_with("unknown warm-start model `oracle`"));
    let e = World::new(
        &SceneConfig::default(),
        WorldParams {
            solve: SolveParams { tolerance: 0.0, max_sweeps: 10, ..Default::default() },
            ..Default::default()
        },
    )
    .err()
    .unwrap();
    assert!(matches!(e, SimError::InvalidParameter { name: "tolerance", .. }), "{e}");
    assert_eq!(e.to_string(), "invalid parameter `tolerance` = 0: must be > 0");
    let soft = SolveParams { compliance: -1.0, ..Default::default() };
    let e = World::new(&SceneConfig::default(), WorldParams { solve: soft, ..Default::default() }).err().unwrap();
    assert_eq!(e.to_string(), "invalid parameter `compliance` = -1: must be in [0, 10]");
    let sor = SolveParams { relaxation: 2.5, ..Default::default() };
    let e = World::new(&SceneConfig::default(), WorldParams { solve: sor, ..Default::default() }).err().unwrap();
    assert_eq!(e.to_string(), "invalid parameter `relaxation` = 2.5: must be in (0, 2)");
    // An infinite slop would let every overlap stay (the position pass does nothing).
    let position = sim::PositionParams { slop: f32::INFINITY, ..Default::default() };
    let e = World::new(&SceneConfig::default(), WorldParams { position, ..Default::default() }).err().unwrap();
    assert!(e.to_string().contains("slop finite"), "{e}");
    let e = World::new(&SceneConfig { n: 1000, side: Some(15.0), ..Default::default() }, WorldParams::default())
        .err()
        .unwrap();
    assert!(matches!(e, SimError::SceneTooDense(_)), "{e}");
}

/// `dc-sim` under an address-space limit, so that a bound that regresses fails a test with an
/// allocation abort instead of exhausting the machine.
fn dc_sim(args: &[&str]) -> (i32, String) {
    let out = Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 4000000; exec \"$0\" \"$@\"")
        .arg(env!("CARGO_BIN_EXE_dc-sim"))
        .args(args)
        .env_remove("DC_BUS")
        .env_remove("DC_LAUNCHED")
        .env_remove("DC_VALIDATE")
        .output()
        .expect("run dc-sim");
    (out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stderr).into_owned())
}

#[test]
fn binary_rejects_bad_parameters_with_clear_errors() {
    let (code, err) = dc_sim(&["--scene", "washing"]);
    assert_ne!(code, 0);
    assert!(err.contains("unknown scene `washing`"), "{err}");

    let (code, err) = dc_sim(&["--model", "oracle"]);
    assert_ne!(code, 0);
    assert!(err.contains("unknown warm-start model `oracle`"), "{err}");

    let (code, err) = dc_sim(&["--tolerance", "0"]);
    assert_ne!(code, 0);
    assert!(err.contains("--tolerance") && err.contains("> 0"), "{err}");

    for bad in ["--compliance=-0.1", "--compliance=nan", "--compliance=11"] {
        let (code, err) = dc_sim(&[bad]);
        assert_ne!(code, 0);
        assert!(err.contains("--compliance") && err.contains("[0, 10]"), "{bad}: {err}");
    }
    for bad in ["--relaxation=0", "--relaxation=2", "--relaxation=inf"] {
        let (code, err) = dc_sim(&[bad]);
        assert_ne!(code, 0);
        assert!(err.contains("--relaxation") && err.contains("(0, 2)"), "{bad}: {err}");
    }

    for (bad, says) in [
        ("--solver=sor:2", "out of range"),
        ("--solver=jacobi", "unknown method `jacobi`"),
        ("--solver=nncg:-1", "out of range"),
        ("--order=up", "unknown row order `up`"),
        ("--stop=tight", "unknown stopping rule `tight`"),
    ] {
        let (code, err) = dc_sim(&[bad]);
        assert_ne!(code, 0);
        assert!(err.contains(says), "{bad}: {err}");
    }
    let (code, err) = dc_sim(&["--solver", "nncg", "--relaxation", "1.2"]);
    assert_ne!(code, 0);
    assert!(err.contains("--relaxation") && err.contains("--solver"), "{err}");

    let (code, err) = dc_sim(&["--n", "1000", "--side", "15"]);
    assert_ne!(code, 0);
    assert!(err.contains("scene too dense"), "{err}");

    let (code, err) = dc_sim(&["--seeds", "5..2"]);
    assert_ne!(code, 0);
    assert!(err.contains("seeds"), "{err}");
}

#[test]
fn binary_refuses_counts_and_sizes_beyond_their_bounds_without_allocating() {
    for (args, wants) in [
        (&["--seeds", "0..400000000"][..], &["seeds", "0..400000000", "more than 100000 seeds"][..]),
        (&["--seeds", "0..4294967296"], &["seeds", "more than 100000 seeds"]),
        (&["--simulations", "1000000000"], &["--simulations", "1000000000", "100000"]),
        (&["--seed", "4294967295", "--simulations", "2"], &["--seed", "4294967295"]),
        (&["--n", "100000000"], &["`n` = 100000000", "at most 1000000"]),
        (&["--side", "1e6"], &["`side` = 1000000", "at most 4096"]),
        (&["--side", "1e12"], &["`side` = 1000000000000", "at most 4096"]),
        (&["--steps", "4000000000"], &["`steps` = 4000000000", "at most 1000000"]),
    ] {
        let (code, err) = dc_sim(args);
        assert_eq!(code, 2, "{args:?}: {err}");
        for want in wants {
            assert!(err.contains(want), "{args:?}: no `{want}` in\n{err}");
        }
        assert!(!err.contains("panicked") && !err.contains("backtrace"), "{args:?}: {err}");
    }
}

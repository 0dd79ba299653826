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
            solve: SolveParams { tolerance: 0.0, max_sweeps: 10, compliance: 0.0, relaxation: 1.0 },
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
    let e = World::new(&SceneConfig { n: 1000, side: Some(15.0), ..Default::default() }, WorldParams::default())
        .err()
        .unwrap();
    assert!(matches!(e, SimError::SceneTooDense(_)), "{e}");
}

fn dc_sim(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_dc-sim"))
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

    let (code, err) = dc_sim(&["--n", "1000", "--side", "15"]);
    assert_ne!(code, 0);
    assert!(err.contains("scene too dense"), "{err}");

    let (code, err) = dc_sim(&["--seeds", "5..2"]);
    assert_ne!(code, 0);
    assert!(err.contains("seeds"), "{err}");
}

//! Numbers outside a flag's range are refused when the flags are parsed (issue #40): exit status
//! 2 and a message naming the flag, before any recording is read.

use std::process::Command;

#[test]
fn numeric_flags_out_of_range_are_refused_by_name() {
    let cases: &[(&str, &[&str])] = &[
        ("--lr", &["nan", "-1", "0", "inf", "1e308"]),
        ("--power", &["nan", "-1", "0", "inf", "1e308"]),
        ("--approach-weight", &["nan", "-1", "0", "inf", "1e308"]),
        ("--ridge", &["nan", "-1", "1e-3,inf", "1e308"]),
        ("--sweeps", &["-1", "1001"]),
        ("--epochs", &["-1", "100001"]),
        ("--hidden", &["0", "1025", "-1"]),
        ("--rounds", &["65", "-1"]),
    ];
    for (flag, values) in cases {
        for value in *values {
            let out = Command::new(env!("CARGO_BIN_EXE_dc-gnn-train"))
                .args(["--data", "train.mcap", "--validation", "validation.mcap", "--out", "m.dcg"])
                .arg(format!("{flag}={value}"))
                .env_remove("DC_VALIDATE")
                .env_remove("DC_BUS")
                .env_remove("DC_LAUNCHED")
                .output()
                .expect("run dc-gnn-train");
            let err = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(2), "{flag}={value}: {err}");
            assert!(err.contains(flag), "{flag}={value}: {err}");
        }
    }
}

//! Numbers outside a flag's range are refused when the flags are parsed (issue #40): exit status
//! 2 and a message naming the flag, before any port is created.

use std::process::Command;

#[test]
fn numeric_flags_out_of_range_are_refused_by_name() {
    let cases: &[(&str, &[&str])] = &[
        ("--timeout-s", &["nan", "-1", "0", "inf", "1e308"]),
        ("--n", &["0", "-1", "1000001", "1e308"]),
        ("--create-delay-ms", &["-1", "3600001", "nan"]),
        ("--start-delay-ms", &["-1", "3600001", "nan"]),
    ];
    for (flag, values) in cases {
        for value in *values {
            let out = Command::new(env!("CARGO_BIN_EXE_dc-bench-bus"))
                .args(["--role", "sink", &format!("{flag}={value}")])
                .env_remove("DC_VALIDATE")
                .env_remove("DC_BUS")
                .env_remove("DC_LAUNCHED")
                .output()
                .expect("run dc-bench-bus");
            let err = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(2), "{flag}={value}: {err}");
            assert!(err.contains(flag), "{flag}={value}: {err}");
        }
    }
    // Values in range parse (the launcher's check: parse only, then exit 0).
    let out = Command::new(env!("CARGO_BIN_EXE_dc-bench-bus"))
        .args(["--role", "sink", "--timeout-s=0.5", "--n=1000000"])
        .env("DC_VALIDATE", "1")
        .output()
        .expect("run dc-bench-bus");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

//! Numbers outside a flag's range are refused when the flags are parsed (issue #40): exit status
//! 2 and a message naming the flag, before the server starts.

use std::process::{Command, Output};

const DC_FOXGLOVE: &str = env!("CARGO_BIN_EXE_dc-foxglove");

fn dc_foxglove(args: &[&str], validate: bool) -> Output {
    let mut command = Command::new(DC_FOXGLOVE);
    command.args(args).env_remove("DC_BUS").env_remove("DC_LAUNCHED");
    match validate {
        true => command.env("DC_VALIDATE", "1"),
        false => command.env_remove("DC_VALIDATE"),
    };
    command.output().expect("run dc-foxglove")
}

#[test]
fn numeric_flags_out_of_range_are_refused_by_name() {
    let cases: &[(&str, &[&str])] = &[
        ("--max-hz", &["nan", "-1", "inf", "1e308", "10001"]),
        ("--plot-hz", &["nan", "-1", "inf", "1e308", "10001"]),
        ("--impulse-scale", &["nan", "-1", "0", "inf", "1e308"]),
        ("--max-arrow", &["nan", "-1", "0", "inf", "1e308"]),
        ("--backlog", &["0", "-1", "65537"]),
    ];
    for (flag, values) in cases {
        for value in *values {
            for validate in [false, true] {
                let out = dc_foxglove(&[&format!("{flag}={value}")], validate);
                let err = String::from_utf8_lossy(&out.stderr);
                assert_eq!(out.status.code(), Some(2), "{flag}={value}: {err}");
                assert!(err.contains(flag), "{flag}={value}: {err}");
            }
        }
    }
    // `viz` draws with the same style flags.
    let out = dc_foxglove(&["viz", "in.mcap", "out.mcap", "--impulse-scale=nan"], false);
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    // The documented values parse, 0 (unlimited) included.
    let out = dc_foxglove(&["--max-hz=0", "--plot-hz=10000", "--impulse-scale=0.5", "--max-arrow=3"], true);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

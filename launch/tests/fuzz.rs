//! Seeded fuzzing of the launch-file parser: the repository's launch files, mutated at the byte
//! and the line level (flips, junk, truncation, lines dropped, repeated or swapped, values
//! replaced by hostile ones), parsed again. Nothing may panic; a bad file is an error that names
//! the file. `DC_FUZZ_CASES` / `DC_FUZZ_SEED` change the run.

use launch::graph::{Graph, GraphError};

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn env_or(name: &str, default: u64) -> u64 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// Values a careless or hostile file might hold.
const HOSTILE: &[&str] = &[
    "\"\"",
    "0",
    "-1",
    "65536",
    "99999999999999999999999",
    "1e400",
    "nan",
    "inf",
    "true",
    "[]",
    "{}",
    "\"../../../../etc/passwd\"",
    "\"{host}{host}\"",
    "\"dc-sim\"",
    "\"\u{1F600}\"",
    "\"a\\u0000b\"",
    "[[1, 2], \"x\"]",
    "{ role = { nested = true } }",
];

fn mutate(rng: &mut Rng, text: &str) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    for _ in 0..1 + rng.below(3) {
        if lines.is_empty() {
            break;
        }
        let i = rng.below(lines.len());
        match rng.below(8) {
            0 => {
                lines.remove(i);
            }
            1 => {
                let l = lines[i].clone();
                lines.insert(i, l);
            }
            2 => {
                let j = rng.below(lines.len());
                lines.swap(i, j);
            }
            3 => {
                if let Some((key, _)) = lines[i].split_once('=') {
                    lines[i] = format!("{key}= {}", HOSTILE[rng.below(HOSTILE.len())]);
                }
            }
            4 => lines.insert(
                i,
                ["[[nodes]]", "[graph]", "[hosts.x]", "[security]", "[qos]", "[topics]"][rng.below(6)].into(),
            ),
            5 => {
                let cut = rng.below(lines[i].len() + 1);
                let cut = (0..=cut).rev().find(|&c| lines[i].is_char_boundary(c)).unwrap_or(0);
                lines[i].truncate(cut);
            }
            _ => {
                // Byte-level damage (possibly invalid UTF-8, read lossily as a user's editor would).
                let mut b = lines[i].clone().into_bytes();
                let at = rng.below(b.len() + 1);
                b.insert(at, rng.next() as u8);
                lines[i] = String::from_utf8_lossy(&b).into_owned();
            }
        }
    }
    lines.join("\n")
}

#[test]
fn mutated_launch_files_never_panic_and_errors_name_the_file() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let corpus: Vec<(String, String)> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml") && p.file_name().is_some_and(|n| n != "Cargo.toml"))
        .map(|p| (p.display().to_string(), std::fs::read_to_string(&p).unwrap()))
        .collect();
    assert!(corpus.len() >= 5, "the repository's launch files: {corpus:?}");
    // The node binaries (target/debug, beside this test's deps/ folder) on PATH, so intact files
    // parse and mutations exercise the accepting paths too, not only "unknown binary".
    let bins = std::env::current_exe().unwrap().parent().and_then(|d| d.parent()).unwrap().to_path_buf();
    let path = std::env::var_os("PATH").unwrap_or_default();
    let joined = std::env::join_paths(std::iter::once(bins).chain(std::env::split_paths(&path))).unwrap();
    std::env::set_var("PATH", joined);
    let intact = corpus.iter().filter(|(f, t)| Graph::parse(f, t).is_ok()).count();
    let cases = env_or("DC_FUZZ_CASES", 10_000);
    let mut rng = Rng(env_or("DC_FUZZ_SEED", 0x1a0c_4f11) | 1);
    let (mut refused, start) = (0u64, std::time::Instant::now());
    for _ in 0..cases {
        let (file, text) = &corpus[rng.below(corpus.len())];
        let mutated = mutate(&mut rng, text);
        if let Err(e) = Graph::parse(file, &mutated) {
            refused += 1;
            let message = e.to_string();
            assert!(matches!(e, GraphError::Invalid { .. }), "a parse problem, not an I/O one: {message}");
            assert!(message.contains(file.as_str()), "an error must name the file: {message}\n---\n{mutated}");
        }
    }
    eprintln!(
        "{cases} mutated launch files ({intact} of {} intact ones parse) in {:.1?}: {refused} refused with an \
         error naming the file, {} accepted",
        corpus.len(),
        start.elapsed(),
        cases - refused
    );
}

//! The numpy sampler rebuilds the original Python code's initial worlds exactly.
//!
//! Fixtures: `tests/fixtures/numpy_seed_<S>.txt`, written by `gen_numpy_fixtures.py` from
//! `/work/shared/reference/genworld_numpy.py` (numpy legacy `RandomState`).

use sim::scene::{BodyKind, ShapeSpec};
use sim::{SamplerKind, Scene, SceneConfig};

fn fixture(seed: u64) -> Vec<[f32; 2]> {
    let path = format!("{}/tests/fixtures/numpy_seed_{seed}.txt", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let mut it = l.split_whitespace().map(|v| v.parse::<f32>().unwrap());
            [it.next().unwrap(), it.next().unwrap()]
        })
        .collect()
}

#[test]
fn numpy_sampler_reproduces_the_reference_worlds_bit_for_bit() {
    for seed in [0u64, 1, 2, 7, 29] {
        let expected = fixture(seed);
        assert_eq!(expected.len(), 100, "seed {seed}: fixture length");
        let scene = Scene::build(&SceneConfig { seed, sampler: SamplerKind::Numpy, ..Default::default() }).unwrap();
        let balls: Vec<_> = scene.bodies.iter().filter(|b| b.kind == BodyKind::Dynamic).collect();
        assert_eq!(balls.len(), 100);
        for (i, (b, e)) in balls.iter().zip(&expected).enumerate() {
            assert_eq!(b.shape, ShapeSpec::Ball { radius: 0.5 });
            assert!(
                b.position[0].to_bits() == e[0].to_bits() && b.position[1].to_bits() == e[1].to_bits(),
                "seed {seed}, ball {i}: got {:?}, numpy {:?}",
                b.position,
                e
            );
        }
    }
}

#[test]
fn native_sampler_differs_from_numpy_but_has_the_same_spread() {
    let numpy = Scene::build(&SceneConfig { sampler: SamplerKind::Numpy, ..Default::default() }).unwrap();
    let native = Scene::build(&SceneConfig::default()).unwrap();
    assert_ne!(numpy.bodies[0].position, native.bodies[0].position);
    // Same distribution: centroid near the box centre for both.
    for scene in [&numpy, &native] {
        let (sx, sy) = scene.bodies[..100].iter().fold((0.0, 0.0), |(x, y), b| (x + b.position[0], y + b.position[1]));
        assert!((sx / 100.0 - 7.5).abs() < 1.0 && (sy / 100.0 - 7.5).abs() < 1.0, "centroid {sx} {sy}");
    }
}

//! Receivers deep in umbra (issue 69): under a target error, a receiver whose every direction
//! of the light's cone is proven at least `-ln(2 E)` deep (a cone march over the trilinear
//! field, `light/umbra.rs`) is answered `T = U / 2 +- U / 2` without sampling. Against 4096
//! directions: every such answer is within its bound; receivers near the cloud's edge, where
//! part of the cone leaves the density, are sampled or bounded, never beyond; nearest lookups
//! prove nothing.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use umbra::input::{Source, SourceOptions};
use umbra::request::{EstimatorOptions, LightOptions, QueryRequest};
use umbra::Interp;

use crate::vdb_writer::{Grid, Leaf, VdbFile};

/// A 16^3 box of density 2 (unit voxels), with one empty `8^3` leaf's worth of hole in a
/// corner: 32 optical depths across, so its core is deep umbra for any target.
fn dense_box(dir: &Path) -> PathBuf {
    let mut leaves = Vec::new();
    for i in [0, 8] {
        for j in [0, 8] {
            for k in [0, 8] {
                if [i, j, k] != [8, 8, 8] {
                    leaves.push(Leaf::filled([i, j, k], 2.0));
                }
            }
        }
    }
    let p = dir.join("dense.vdb");
    VdbFile::new(vec![Grid::fog("density", leaves)]).write(&p);
    p
}

/// `(T, std_err, directions)` at `at` toward a sun along `dir` `angle` degrees across.
fn query(file: &Path, at: [f64; 3], interp: Interp, samples: Option<u32>) -> (f64, f64, usize) {
    let r = QueryRequest {
        at: Some(at),
        light: LightOptions {
            light_dir: Some([0.2, -1.0, 0.1]),
            light_angle: Some(6.0),
            light_samples: samples,
            ..LightOptions::default()
        },
        estimator: EstimatorOptions {
            seed: 3,
            ..EstimatorOptions::default()
        },
        ..QueryRequest::new(Source::new(
            file,
            SourceOptions {
                interp,
                ..SourceOptions::default()
            },
        ))
    };
    let a = crate::common::one_answer(&r);
    (
        a.estimate.value[0],
        a.estimate.std_err[0],
        a.light_samples.unwrap(),
    )
}

#[test]
fn receivers_proven_in_umbra_are_within_their_bound_of_4096_directions() {
    let dir = tempfile::tempdir().unwrap();
    let file = dense_box(dir.path());
    let (mut umbral, mut sampled, mut edge_umbral) = (0, 0, 0);
    // Across the box at three heights: the core, the faces the cone leaves by, the hole.
    for y in [1.0, 6.0, 12.5] {
        for x in [-0.6, 0.4, 3.0, 7.5, 11.0, 14.6, 15.6] {
            for z in [0.3, 7.5, 12.0] {
                let at = [x, y, z];
                let (t, se, dirs) = query(&file, at, Interp::Trilinear, None);
                let (r, r_se, _) = query(&file, at, Interp::Trilinear, Some(4096));
                // An error bar of 0 only for a cone proven clear (the hole's).
                assert!((0.0..=1.0).contains(&t), "{at:?}: {t}");
                assert!(se > 0.0 || (t == 1.0 && dirs == 0), "{at:?}: {t} +- {se}");
                if dirs == 0 && t < 1.0 {
                    // In umbra: T = U / 2 +- U / 2, a bound at most the target, never beyond.
                    assert_eq!(t, se, "{at:?}");
                    assert!(se <= 5e-3, "{at:?}: bar {se}");
                    assert!(
                        (t - r).abs() <= se + 4.0 * r_se,
                        "{at:?}: {t} +- {se} vs {r}"
                    );
                    umbral += 1;
                } else if dirs > 0 {
                    sampled += 1;
                }
            }
        }
    }
    // 25 voxels below the box, across the shadow of its edge: the cone's edge directions
    // pass beside the box where its centre ray is deep (the bound must grow with the cone).
    for k in 0..40 {
        let at = [2.0 + 0.2 * f64::from(k), -25.0, 7.5];
        let (t, se, dirs) = query(&file, at, Interp::Trilinear, None);
        let (r, r_se, _) = query(&file, at, Interp::Trilinear, Some(4096));
        eprintln!("{at:?}: {t:.6} +- {se:.1e} ({dirs}) vs {r:.6} +- {r_se:.1e}");
        // (The sampled ones at the umbra's edge, T ~ 1e-4 from 64 directions, are the
        // heavy-tailed case docs/lights.md names: their bars are not asserted here.)
        if dirs == 0 && t < 1.0 {
            assert_eq!(t, se, "{at:?}");
            assert!(
                (t - r).abs() <= se + 4.0 * r_se,
                "{at:?}: {t} +- {se} vs {r}"
            );
            edge_umbral += 1;
        }
    }
    assert!(edge_umbral >= 5, "{edge_umbral} in umbra below the box");
    eprintln!("{umbral} receivers proven in umbra, {sampled} sampled");
    assert!(umbral >= 20, "{umbral} in umbra");
    assert!(sampled >= 10, "{sampled} sampled");
    // The core under nearest lookups: nothing is proven, every receiver is sampled.
    let (t, se, dirs) = query(&file, [7.5, 6.0, 7.5], Interp::Nearest, None);
    assert!(dirs >= 64 && se > 0.0, "{t} +- {se} ({dirs})");
}

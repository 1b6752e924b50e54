//! Which HDDA granularity should the null-collision estimators use by default? Coarser segments
//! cost less traversal but carry looser majorants, so each sample takes more null collisions
//! (lookups) and, for ratio-type estimators, has more variance. This measures both over many
//! rays and prints, per estimator and granularity, the time per ray, lookups per ray, the mean
//! squared error against exact regular tracking, and the efficiency `1 / (MSE x time)`
//! relative to leaf granularity (> 1: better than leaf).
//!
//! ```sh
//! cargo run --release --ignore-rust-version --example granularity -- [FILE] [SCALE] [RAYS] [REPS]
//! ```
//! Defaults: `../shared/corpus/gen/cloud_fbm.vdb`, scale 5, 4000 rays, 3 repetitions (median
//! time). Rays join two uniform points of the grid's world box, extended to cross it (the
//! shadow-ray mix of a light outside the cloud); one thread, 1 sample per ray, seeds fixed.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use rand::{Rng, SeedableRng};
use std::time::Instant;
use umbra::estimate::{estimate, Estimator, Options};
use umbra::internals::traverse::Granularity;
use umbra::{Interp, Ray, Volume};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let file = args
        .get(1)
        .cloned()
        .unwrap_or_else(|| "../shared/corpus/gen/cloud_fbm.vdb".into());
    let scale: f64 = args.get(2).map_or(5.0, |s| s.parse().unwrap());
    let n_rays: usize = args.get(3).map_or(4000, |s| s.parse().unwrap());
    let reps: usize = args.get(4).map_or(3, |s| s.parse().unwrap());
    let vol = Volume::load(&file, "density", scale).unwrap();
    let vb = vol.value_box().expect("grid has values");
    let corners: Vec<[f64; 3]> = (0..8)
        .map(|c| {
            let p = [0, 1, 2].map(|a| {
                if c >> a & 1 == 1 {
                    vb[1][a] as f64 + 1.0
                } else {
                    vb[0][a] as f64
                }
            });
            vol.to_world(p).to_array()
        })
        .collect();
    let lo = [0, 1, 2].map(|a| corners.iter().map(|p| p[a]).fold(f64::INFINITY, f64::min));
    let hi = [0, 1, 2].map(|a| {
        corners
            .iter()
            .map(|p| p[a])
            .fold(f64::NEG_INFINITY, f64::max)
    });
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    let rays: Vec<Ray> = (0..n_rays)
        .map(|_| {
            let mut p = || [0, 1, 2].map(|a| rng.gen_range(lo[a]..hi[a]));
            let (a, b) = (p(), p());
            let d = [0, 1, 2].map(|k| b[k] - a[k]);
            Ray::between(
                [0, 1, 2].map(|k| a[k] - 2.0 * d[k]),
                [0, 1, 2].map(|k| a[k] + 3.0 * d[k]),
            )
            .unwrap()
        })
        .collect();
    let base = Options {
        interp: Interp::Trilinear,
        ..Options::default()
    };
    let exact: Vec<f64> = rays
        .iter()
        .enumerate()
        .map(|(i, r)| {
            estimate(&vol, r, i as u64, &Estimator::REGULAR, &base)
                .unwrap()
                .value
        })
        .collect();
    let mean_t = exact.iter().sum::<f64>() / exact.len() as f64;
    println!(
        "{file}: {n_rays} rays, scale {scale}, mean T {mean_t:.4}, 1 thread, 1 spp, median of {reps}"
    );
    println!();
    println!("| estimator | granularity | us / ray | lookups / ray | segments / ray | MSE | efficiency vs leaf |");
    println!("|---|---|---|---|---|---|---|");
    let estimators = [
        "ratio",
        "residual-ratio",
        "track-length",
        "next-flight",
        "decomposition",
        "unbiased-raymarch",
    ];
    let grans = [
        ("leaf", Granularity::Leaf, false),
        ("lower", Granularity::Lower, false),
        ("upper", Granularity::Upper, false),
        ("global majorant", Granularity::Leaf, true),
    ];
    for name in estimators {
        let est = Estimator::from_name(name).unwrap();
        let mut leaf_eff = None;
        for (gname, g, global) in grans {
            let opts = Options {
                granularity: g,
                global_majorant: global,
                ..base
            };
            let mut times = Vec::new();
            let (mut se, mut lookups, mut segs) = (0.0, 0u64, 0u64);
            for rep in 0..reps {
                let t = Instant::now();
                let (mut e2, mut l, mut s) = (0.0, 0u64, 0u64);
                for (i, r) in rays.iter().enumerate() {
                    let id = (rep * n_rays + i) as u64;
                    let e = estimate(&vol, r, id, &est, &opts).unwrap();
                    e2 += (e.value - exact[i]).powi(2);
                    l += e.lookups;
                    s += e.segments;
                }
                times.push(t.elapsed().as_secs_f64());
                se += e2;
                lookups += l;
                segs += s;
            }
            times.sort_by(f64::total_cmp);
            let per_ray = times[reps / 2] / n_rays as f64;
            let total = (reps * n_rays) as f64;
            let mse = se / total;
            let eff = 1.0 / (mse * per_ray);
            let rel = eff / *leaf_eff.get_or_insert(eff);
            println!(
                "| {name} | {gname} | {:.2} | {:.1} | {:.1} | {mse:.3e} | {rel:.2} |",
                per_ray * 1e6,
                lookups as f64 / total,
                segs as f64 / total
            );
        }
    }
}

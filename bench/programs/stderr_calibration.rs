//! Are the reported standard errors honest? Draws random segments through a real smoke
//! (fixed seed), runs every stochastic estimator of the registry at a few sample counts and
//! density scales, and prints per estimator the fraction of rows further than 3 and 4
//! `std_err` from the exact `T` (regular tracking), the rows whose `std_err` is 0 although
//! `|T - exact| > 1e-6`, and the RMS of `z = (T - exact) / std_err` over the rows with a
//! non-zero error bar (near 1: calibrated; well below 1: inflated error bars). A normal tail
//! puts 0.27 % beyond 3 and 0.006 % beyond 4 standard errors.
//!
//! ```sh
//! cargo run --release --ignore-rust-version --example stderr_calibration -- [FILE] [GRID] [RAYS] [SCALES] [SAMPLES]
//! ```
//! Defaults: `../shared/corpus/real/openvdb_smoke1_houdini_v222.vdb`, `density`, 1000 rays,
//! scales `0.05,2`, samples `4,64`. Segments join two uniform points of the grid's value box
//! (seed 46); ray `i` has ray id `i`, estimator seed 7. Markdown on stdout.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use rayon::prelude::*;
use umbra::estimate::{estimate, Estimator, Options, REGISTRY};
use umbra::internals::rng::Rng;
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

/// `n` segments between uniform points of the value box (world space), seeded.
fn segments(vol: &Volume, n: usize) -> Vec<Ray> {
    let [lo, hi] = vol.value_box().expect("a grid with values");
    let mut rng = Rng::new(46, 0, 0);
    let mut point = || {
        let p: [f64; 3] =
            std::array::from_fn(|a| lo[a] as f64 + rng.uniform() * (hi[a] - lo[a]) as f64);
        vol.to_world(p).to_array()
    };
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        if let Ok(r) = Ray::between(point(), point()) {
            out.push(r);
        }
    }
    out
}

fn list<T: std::str::FromStr>(s: Option<&String>, default: &str) -> Vec<T>
where
    T::Err: std::fmt::Debug,
{
    s.map_or(default, |s| s.as_str())
        .split(',')
        .map(|x| x.parse().unwrap())
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let file = args
        .get(1)
        .cloned()
        .unwrap_or_else(|| "../shared/corpus/real/openvdb_smoke1_houdini_v222.vdb".into());
    let grid = args.get(2).cloned().unwrap_or_else(|| "density".into());
    let n_rays: usize = args.get(3).map_or(1000, |s| s.parse().unwrap());
    let scales: Vec<f64> = list(args.get(4), "0.05,2");
    let spps: Vec<u32> = list(args.get(5), "4,64");
    println!("`{file}` grid `{grid}`, {n_rays} segments (seed 46), estimator seed 7\n");
    println!(
        "| scale | estimator | spp | mean T | beyond 3 se | beyond 4 se | se 0, wrong | rms z |"
    );
    println!("|---:|---|---:|---:|---:|---:|---:|---:|");
    for &scale in &scales {
        let vol = Volume::load(&file, &grid, scale).unwrap();
        let rays = segments(&vol, n_rays);
        let exact: Vec<f64> = rays
            .par_iter()
            .map(|r| {
                optical_depth(&vol, r, Interp::Trilinear)
                    .unwrap()
                    .transmittance()
            })
            .collect();
        let mean_t = exact.iter().sum::<f64>() / exact.len() as f64;
        for spec in REGISTRY.iter().filter(|s| !s.deterministic) {
            let est = Estimator::from_name(spec.name).unwrap();
            for &spp in &spps {
                let opts = Options {
                    samples: spp,
                    seed: 7,
                    ..Options::default()
                };
                let rows: Vec<(f64, f64)> = rays
                    .par_iter()
                    .enumerate()
                    .map(|(i, r)| {
                        let e = estimate(&vol, r, i as u64, &est, &opts).unwrap();
                        (e.value - exact[i], e.std_err)
                    })
                    .collect();
                let n = rows.len() as f64;
                let beyond = |k: f64| rows.iter().filter(|(d, s)| d.abs() > k * s).count();
                let wrong_zero = rows
                    .iter()
                    .filter(|(d, s)| *s == 0.0 && d.abs() > 1e-6)
                    .count();
                let z: Vec<f64> = rows
                    .iter()
                    .filter(|(_, s)| *s > 0.0)
                    .map(|(d, s)| d / s)
                    .collect();
                let rms = (z.iter().map(|z| z * z).sum::<f64>() / z.len().max(1) as f64).sqrt();
                println!(
                    "| {scale} | {} | {spp} | {mean_t:.3} | {:.1} % | {:.1} % | {wrong_zero} | {rms:.2} |",
                    spec.name,
                    100.0 * beyond(3.0) as f64 / n,
                    100.0 * beyond(4.0) as f64 / n,
                );
            }
        }
    }
}

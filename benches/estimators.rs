//! Every estimator per ray on the sample cloud (`data/cloud.vdb`, density scale 4, trilinear,
//! leaf majorants, 1 sample per ray), the rays grouped by their exact optical depth: thin
//! (`tau < 0.5`), medium (`0.5 <= tau < 2`) and thick (`tau >= 2`), 48 rays each. Criterion
//! reports rays/s per estimator and group. Printed once, before the timings: mean lookups per
//! ray against the cost model of `../shared/research/estimators.md` section 7 (majorant optical
//! depth `taubar` for the null-collision family, `ceil(L / step)` per sampled segment for ray
//! marching, voxel reads for regular tracking), and the RMSE of the 1-sample estimates.
//! Run: `cargo bench --ignore-rust-version --bench estimators`.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rand::{Rng, SeedableRng};
use std::hint::black_box;
use std::ops::ControlFlow;
use std::path::PathBuf;
use std::time::Duration;
use umbra::estimate::{estimate, Estimator, Options};
use umbra::internals::traverse::{walk, Granularity};
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

const SCALE: f64 = 4.0;
const PER_GROUP: usize = 48;
const GROUPS: [(&str, f64, f64); 3] = [
    ("thin", 0.0, 0.5),
    ("medium", 0.5, 2.0),
    ("thick", 2.0, f64::INFINITY),
];

/// Random chords of the cloud's box, sorted into the optical-depth groups until each is full.
fn grouped_rays(vol: &Volume) -> Vec<Vec<(Ray, f64)>> {
    let [lo, hi] = vol.value_box().unwrap();
    let (lo, hi) = (
        vol.to_world(lo.map(|c| c as f64)),
        vol.to_world(hi.map(|c| c as f64)),
    );
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let mut groups = vec![Vec::new(); GROUPS.len()];
    for _ in 0..200_000 {
        if groups.iter().all(|g: &Vec<_>| g.len() == PER_GROUP) {
            break;
        }
        let mut p = || [0, 1, 2].map(|a| rng.gen_range(lo[a].min(hi[a])..lo[a].max(hi[a])));
        let (a, b) = (p(), p());
        let d = [0, 1, 2].map(|k| b[k] - a[k]);
        let ray = Ray::between(
            [0, 1, 2].map(|k| a[k] - 2.0 * d[k]),
            [0, 1, 2].map(|k| a[k] + 3.0 * d[k]),
        )
        .unwrap();
        let tau = optical_depth(vol, &ray, Interp::Trilinear).unwrap().tau;
        if tau <= 1e-6 {
            continue;
        }
        let g = GROUPS
            .iter()
            .position(|&(_, a, b)| tau >= a && tau < b)
            .unwrap();
        if groups[g].len() < PER_GROUP {
            groups[g].push((ray, tau));
        }
    }
    groups
}

/// Cost-model lookups per ray (see the module docs) and what the model claims: `=` exact
/// expectation, `<=` upper bound, `n/a` no simple closed form.
fn theory(vol: &Volume, est: &Estimator, ray: &Ray) -> (f64, &'static str) {
    // taubar: the majorant optical depth of the sampled segments.
    let taubar = || {
        let mut t = 0.0;
        walk(vol, ray, Interp::Trilinear, Granularity::Leaf, |s| {
            if !s.is_constant() {
                t += s.mu_maj * s.length();
            }
            ControlFlow::Continue(())
        });
        t
    };
    match est.name() {
        "regular" => (
            optical_depth(vol, ray, Interp::Trilinear).unwrap().lookups as f64,
            "= reads (8 + 4/cell)",
        ),
        "riemann" | "mc" | "jittered" => {
            let step = est.param("step").unwrap();
            let vox = vol.to_index_dir(ray.direction());
            let per_world = (vox[0] * vox[0] + vox[1] * vox[1] + vox[2] * vox[2]).sqrt();
            let mut n = 0.0;
            walk(vol, ray, Interp::Trilinear, Granularity::Leaf, |s| {
                if !s.is_constant() {
                    n += (s.length() * per_world / step).ceil().max(1.0);
                }
                ControlFlow::Continue(())
            });
            (n, "= sum ceil(L/h)")
        }
        // E = taubar, less where the weight reaches 0 (mu = mu_maj) and the walk stops.
        "ratio" | "residual-ratio" | "residual-ratio-midpoint" | "next-flight" => {
            (taubar(), "E <= taubar")
        }
        "track-length" | "collision" | "decomposition" => (taubar(), "E <= taubar"),
        "jackknife" => (2.0 * est.param("points").unwrap(), "= 2 x points"),
        _ => (f64::NAN, "n/a"),
    }
}

fn bench_estimators(c: &mut Criterion) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb");
    let vol = Volume::load(&path, "density", SCALE).unwrap();
    let groups = grouped_rays(&vol);
    let opts = Options {
        samples: 1,
        ..Options::default()
    };
    let ests: Vec<Estimator> = umbra::estimate::names()
        .map(|n| Estimator::from_name(n).unwrap())
        .collect();
    eprintln!(
        "estimators on data/cloud.vdb (scale {SCALE}, trilinear, leaf majorants, 1 sample/ray)"
    );
    eprintln!(
        "{:<18} {:<7} {:>5} {:>10} {:>10} {:<22} {:>10}",
        "estimator", "group", "rays", "lookups", "model", "(model is)", "rmse"
    );
    for est in &ests {
        for (g, rays) in groups.iter().enumerate() {
            let (mut look, mut model, mut se, mut what) = (0.0, 0.0, 0.0, "");
            for (i, (r, tau)) in rays.iter().enumerate() {
                let e = estimate(&vol, r, i as u64, est, &opts).unwrap();
                look += e.lookups as f64;
                let (m, w) = theory(&vol, est, r);
                (model, what) = (model + m, w);
                se += (e.value - (-tau).exp()).powi(2);
            }
            let n = rays.len().max(1) as f64;
            eprintln!(
                "{:<18} {:<7} {:>5} {:>10.1} {:>10.1} {:<22} {:>10.2e}",
                est.name(),
                GROUPS[g].0,
                rays.len(),
                look / n,
                model / n,
                what,
                (se / n).sqrt()
            );
        }
    }
    let mut group = c.benchmark_group("estimator_per_ray");
    group
        .sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2));
    for est in &ests {
        for (g, rays) in groups.iter().enumerate() {
            if rays.is_empty() {
                continue;
            }
            group.throughput(Throughput::Elements(rays.len() as u64));
            group.bench_function(format!("{}/{}", est.name(), GROUPS[g].0), |b| {
                b.iter(|| {
                    let mut s = 0.0;
                    for (i, (r, _)) in rays.iter().enumerate() {
                        s += estimate(&vol, r, i as u64, est, &opts).unwrap().value;
                    }
                    black_box(s)
                });
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_estimators);
criterion_main!(benches);

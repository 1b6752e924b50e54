//! Null-collision maps swept block by block against the exact optical depth: unbiased within
//! their standard errors, the same bits whatever the bands or threads.

use super::super::tests::{cameras, run_bands, tiles_and_shells};
use super::*;
use crate::bake::camera::Camera;
use crate::volume::Volume;

/// The flight the sweep renders for estimator `name` at `spp` samples.
fn flight_of(name: &str, spp: u32) -> Flight {
    let est = Estimator::with_params(name, &[]).expect("estimator");
    let opts = Options {
        samples: spp,
        seed: 11,
        ..Options::default()
    };
    flights(&BakeSettings::new(est, opts)).expect("a flight")
}

/// The sweep's estimates of every pixel, `stride` a pixel (sample-major, then the full ray and
/// each slice), bands of `rows` rows one after the other; `None` when the sweep declines.
fn estimates(
    vol: &Volume,
    camera: &Camera,
    f: Flight,
    depths: &[f64],
    rows: u32,
) -> Option<Vec<f64>> {
    let planned = Sweep::new(vol, camera, rows, depths)
        .expect("plan")
        .expect("frame");
    let sweep = planned.marching(None, Some(f))?;
    let buf = run_bands(&sweep, camera, rows);
    assert!(!sweep.capped.load(Ordering::Relaxed));
    Some(buf)
}

/// Groups of pixels (`n mod GROUPS`) whose summed errors the t statistic compares.
const GROUPS: usize = 16;

/// The map's summed errors against the exact `T` (the full ray, and the slice at `depth`) in
/// [`GROUPS`] interleaved groups of pixels: `S_g = sum (mean_p - T_p)` over pixels
/// `p = g mod GROUPS`. Each has mean 0 for an unbiased estimator, and the groups are
/// independent (pixels draw from streams of their own). Returns them and the pixels whose
/// estimates vary.
fn group_errors(
    vol: &Volume,
    camera: &Camera,
    f: Flight,
    depth: f64,
    what: &str,
) -> ([[f64; GROUPS]; 2], usize) {
    let buf = estimates(vol, camera, f, &[depth], 16).expect("swept");
    let (samples, per) = (f.samples(), 2);
    let stride = samples * per;
    let mut sums = [[0.0f64; GROUPS]; 2];
    let mut varied = 0;
    for n in 0..camera.pixels() as usize {
        let (i, j) = (n as u32 % camera.width, n as u32 / camera.width);
        let ray = camera.pixel_ray(i, j).expect("ray");
        for (k, slot_ray) in [ray, ray.with_range(0.0, depth).expect("range")]
            .iter()
            .enumerate()
        {
            let tau = crate::regular::optical_depth(vol, slot_ray, Interp::Trilinear).expect("tau");
            let exact = (-tau.tau).exp();
            let x: Vec<f64> = (0..samples)
                .map(|s| buf[n * stride + s * per + k])
                .collect();
            assert!(
                x.iter().all(|v| v.is_finite()),
                "{what}: pixel ({i}, {j}) slot {k}: {x:?}"
            );
            let mean = x.iter().sum::<f64>() / samples as f64;
            sums[k][n % GROUPS] += mean - exact;
            if k == 0 && x.iter().any(|&v| v != x[0]) {
                varied += 1;
            }
        }
    }
    (sums, varied)
}

/// Student's `t` of independent zero-mean errors: `mean(S) / (sd(S) / sqrt(n))`, `n - 1`
/// degrees of freedom; 0 when every error is 0 (nothing sampled).
fn student_t(s: &[f64]) -> f64 {
    let n = s.len() as f64;
    let mean = s.iter().sum::<f64>() / n;
    let sd = (s.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    if s.iter().all(|x| x.abs() <= 1e-12) {
        0.0
    } else {
        mean / (sd / n.sqrt())
    }
}

const ESTIMATORS: [&str; 5] = [
    "ratio",
    "residual-ratio",
    "residual-ratio-midpoint",
    "track-length",
    "decomposition",
];

/// Every swept null-collision estimator is unbiased: the pixels' errors against the exact `T`
/// (full rays and a depth slice), summed in 16 groups a view over 4 views, pass a t test at
/// `|t| <= 5.5` (63 degrees of freedom: `P(|t| > 5.5) < 1e-6`). Per-pixel standard errors are
/// not used: a pixel whose rare large weights its samples missed would make them worthless.
/// A bias of 1 % in the ratio weights fails it (`t` about 8 on the clouds). Corpus
/// clouds and smokes, extreme media (NaN/Inf voxels, optical depth 1e6: its high-contrast
/// blocks go to the ray path), a rotated transform, tiles and shells; both projections.
#[test]
fn flights_are_unbiased() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus");
    // (file, scale, resolution, samples): the clouds get the most pixels and samples (a bias
    // of 1 % in the weights shows there), the optical depth 1e6 file the fewest (ratio
    // trackers spend about 1e5 lookups a ray on it, as on the ray path).
    let mut vols = Vec::new();
    for (file, scale, res, spp) in [
        ("gen/cloud_fbm.vdb", 5.0, 64, 128),
        ("gen/extreme_nan_inf.vdb", 3.0, 24, 32),
        ("gen/extreme_thick_1e6.vdb", 3.0, 8, 4),
        ("gen/xform_affine_rotated.vdb", 3.0, 24, 32),
        ("real/openvdb_smoke1_houdini_v222.vdb", 0.3, 48, 64),
    ] {
        let vol = Volume::load(root.join(file), "density", scale).expect(file);
        vols.push((file, vol, res, spp));
    }
    vols.push(("tiles and shells", tiles_and_shells(), 24, 32));
    let mut checked = 0;
    for (file, vol, res, spp) in &vols {
        let views = cameras(vol, *res);
        for name in ESTIMATORS {
            // The groups of 4 views: 64 independent errors a slot.
            let mut errors = [Vec::new(), Vec::new()];
            let mut varied = 0;
            for (view, camera) in views.iter().take(4) {
                let depth = 0.5 * (camera.t_near + camera.t_max);
                let what = format!("{file} {view} {name}");
                let (sums, v) = group_errors(vol, camera, flight_of(name, *spp), depth, &what);
                for k in 0..2 {
                    errors[k].extend_from_slice(&sums[k]);
                }
                varied += v;
            }
            let t = errors.map(|e| student_t(&e));
            assert!(t.iter().all(|t| t.abs() <= 5.5), "{file} {name}: t {t:?}");
            assert!(varied > 0, "{file} {name}: nothing sampled");
            checked += 1;
        }
    }
    assert_eq!(checked, 6 * ESTIMATORS.len());
}

/// A flight map is the same, bit for bit, whatever the bands and the threads that run them:
/// a chord's streams depend on its block, its ray id and the sample alone, and each pixel's
/// factors are multiplied in piece order.
#[test]
fn flights_do_not_depend_on_bands_or_threads() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/gen/cloud_fbm.vdb");
    let vol = Volume::load(&path, "density", 5.0).expect("cloud");
    let (_, camera) = cameras(&vol, 40).swap_remove(1);
    let depth = 0.5 * (camera.t_near + camera.t_max);
    for name in ["residual-ratio", "track-length"] {
        let f = flight_of(name, 8);
        let a = estimates(&vol, &camera, f, &[depth], 16).expect("swept");
        let b = estimates(&vol, &camera, f, &[depth], 7).expect("swept");
        assert!(
            a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
            "{name}"
        );
        let mut s = BakeSettings::new(f.est, f.opts);
        s.depths = crate::bake::map::Depths::At(vec![depth]);
        let render = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            pool.install(|| super::super::render(&vol, &camera, &s, &[depth], 16, &|_| {}))
                .expect("render")
                .expect("swept")
        };
        let (one, two) = (render(1), render(2));
        assert!(one.stats.sweep);
        assert_eq!(one.t, two.t, "{name}");
        assert_eq!(one.slices, two.slices, "{name}");
    }
}

/// A map whose samples would pass the collision budget is declined (the ray path caps them
/// where they stand); the same map with the default budget is swept.
#[test]
fn a_capped_flight_map_goes_by_rays() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/gen/cloud_fbm.vdb");
    let vol = Volume::load(&path, "density", 5.0).expect("cloud");
    let (_, camera) = cameras(&vol, 32).swap_remove(0);
    let f = flight_of("ratio", 4);
    let mut s = BakeSettings::new(f.est, f.opts);
    let swept = super::super::render(&vol, &camera, &s, &[], 16, &|_| {}).expect("render");
    assert!(swept.is_some());
    s.options.max_collisions = 2;
    let capped = super::super::render(&vol, &camera, &s, &[], 16, &|_| {}).expect("render");
    assert!(capped.is_none());
}

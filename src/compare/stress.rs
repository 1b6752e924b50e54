//! The stress catalogue: stiff and extreme media on which every estimator must return a finite
//! answer in range (or, for the signed estimators, finite), reach `T = 0` exactly where the
//! optical depth underflows, and never hang (a collision cap, counted). Each case is built in
//! memory except the half-float one, which reads `data/cloud_half.vdb` when present.

use super::random_rays;
use crate::estimate::{estimate, Estimator, Options};
use crate::ray::Ray;
use crate::regular::optical_depth;
use crate::tree::TreeBuilder;
use crate::volume::{Interp, Volume};
use serde::Serialize;
use std::time::Instant;

/// One case of the catalogue.
#[derive(Debug)]
pub struct Case {
    /// Short name.
    pub name: &'static str,
    /// What it stresses.
    pub what: &'static str,
    /// The medium.
    pub volume: Volume,
    /// Rays to trace.
    pub rays: Vec<Ray>,
}

fn map(voxel: f64, t: [f64; 3]) -> [[f64; 4]; 3] {
    [
        [voxel, 0.0, 0.0, t[0]],
        [0.0, voxel, 0.0, t[1]],
        [0.0, 0.0, voxel, t[2]],
    ]
}

fn smooth(i: i32, j: i32, k: i32) -> f32 {
    let (x, y, z) = (f64::from(i), f64::from(j), f64::from(k));
    (1.0 + 0.8 * (0.3 * x).sin() * (0.2 * y).cos() * (0.25 * z + 1.0).sin()) as f32
}

fn block(n: i32, f: impl Fn(i32, i32, i32) -> f32) -> TreeBuilder {
    let mut b = TreeBuilder::new(0.0);
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                b.set([i, j, k], f(i, j, k));
            }
        }
    }
    b
}

fn case(
    name: &'static str,
    what: &'static str,
    b: &TreeBuilder,
    voxel: f64,
    t: [f64; 3],
    scale: f64,
    rays: usize,
) -> crate::error::Result<Case> {
    let volume = Volume::from_tree(name.into(), b.build(), map(voxel, t), scale)?;
    let rays = random_rays(&volume, rays, 17);
    Ok(Case {
        name,
        what,
        volume,
        rays,
    })
}

/// Build the catalogue with `rays` random rays per case (plus hand-placed rays where the case
/// is about geometry).
///
/// # Errors
/// None expected (the media are fixed); a volume constructor's error is passed on.
pub fn catalogue(rays: usize) -> crate::error::Result<Vec<Case>> {
    let mut out = Vec::new();
    let smooth16 = block(16, smooth);
    // Optical depth along a ray through 16 voxels of ~1: ~16 * voxel * scale.
    out.push(case(
        "tau-1e-8",
        "optical depth ~1e-8 along a ray",
        &smooth16,
        1.0,
        [0.0; 3],
        1e-9,
        rays,
    )?);
    out.push(case(
        "tau-1e5",
        "optical depth ~1e5 along a ray (T underflows to 0)",
        &smooth16,
        1.0,
        [0.0; 3],
        1e4,
        rays,
    )?);
    out.push(case(
        "densities-1e-8-and-1e6",
        "densities 1e-8 and 1e6 in one grid, in alternating 4^3 blocks",
        &block(16, |i, j, k| {
            if (i / 4 + j / 4 + k / 4) % 2 == 0 {
                1e-8
            } else {
                1e6
            }
        }),
        0.01,
        [0.0; 3],
        1e-4,
        rays,
    )?);
    let mut spike = block(16, |_, _, _| 1e-3);
    spike.set([8, 8, 8], 1e6);
    out.push(case(
        "spike-1e6",
        "a single 1e6 voxel in a near-empty (1e-3) region",
        &spike,
        1.0,
        [0.0; 3],
        1.0,
        rays,
    )?);
    let mut ratio = block(16, |_, _, _| 1e-6);
    for l in 0..2 {
        for m in 0..2 {
            for n in 0..2 {
                ratio.set([3 + 8 * l, 3 + 8 * m, 3 + 8 * n], 1.0);
            }
        }
    }
    out.push(case(
        "majorant-ratio-1e6",
        "majorant / density up to 1e6 in every leaf",
        &ratio,
        1.0,
        [0.0; 3],
        1.0,
        rays,
    )?);
    let mut bad = block(16, smooth);
    bad.set([4, 4, 4], f32::NAN)
        .set([5, 9, 2], -3.0)
        .set([12, 12, 12], f32::INFINITY)
        .set([6, 6, 6], f32::NEG_INFINITY);
    let mut c = case(
        "nan-inf-negative",
        "NaN, -Inf, negative (set to 0) and +Inf (opaque) voxels",
        &bad,
        1.0,
        [0.0; 3],
        0.2,
        rays,
    )?;
    if let Ok(r) = Ray::between([12.0, 12.0, -5.0], [12.0, 12.0, 20.0]) {
        c.rays.push(r);
    }
    out.push(c);
    let half = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cloud_half.vdb");
    if let Ok(volume) = Volume::load(&half, "density", 2.0) {
        let rays = random_rays(&volume, rays, 17);
        out.push(Case {
            name: "half-float",
            what: "data/cloud_half.vdb (16-bit values on disk)",
            volume,
            rays,
        });
    }
    // Rays along axes, grazing leaf faces, starting exactly on voxel and leaf boundaries.
    let mut c = case(
        "axis-grazing",
        "axis-aligned rays on voxel/leaf faces and starting on boundaries",
        &smooth16,
        1.0,
        [0.0; 3],
        0.3,
        0,
    )?;
    for (o, e) in [
        ([-2.0, 8.0, 8.0], [20.0, 8.0, 8.0]),
        ([-0.5, 7.5, 7.5], [20.0, 7.5, 7.5]),
        ([8.0, -0.5, 3.0], [8.0, 16.5, 3.0]),
        ([7.5, 7.5, -1.0], [7.5, 7.5, 30.0]),
        ([0.0, 0.0, 0.0], [15.0, 15.0, 15.0]),
        ([15.5, 15.5, 15.5], [-0.5, -0.5, -0.5]),
        ([8.0, 8.0, 8.0], [8.0, 8.0, 8.0]),
    ] {
        if let Ok(r) = Ray::between(o, e) {
            c.rays.push(r);
        }
    }
    out.push(c);
    out.push(case(
        "far-coordinates",
        "world coordinates near 1e6",
        &smooth16,
        1.0,
        [1.0e6, -1.0e6, 1.0e6],
        0.3,
        rays,
    )?);
    out.push(case(
        "voxel-1e-6",
        "voxel size 1e-6 world units",
        &smooth16,
        1e-6,
        [0.0; 3],
        3e5,
        rays,
    )?);
    out.push(case(
        "voxel-1e3",
        "voxel size 1e3 world units",
        &smooth16,
        1e3,
        [0.0; 3],
        3e-4,
        rays,
    )?);
    let mut empty = case(
        "empty",
        "a grid with no values (T = 1)",
        &TreeBuilder::new(0.0),
        1.0,
        [0.0; 3],
        1.0,
        0,
    )?;
    if let Ok(r) = Ray::between([-1.0, 0.0, 0.0], [5.0, 2.0, 1.0]) {
        empty.rays.push(r);
    }
    out.push(empty);
    let mut tiles = TreeBuilder::new(0.0);
    tiles
        .tile([0, 0, 0], 7, 0.5)
        .tile([128, 0, 0], 3, 2.0)
        .tile([136, 8, 0], 3, 1.0);
    out.push(case(
        "tiles-only",
        "128^3 and 8^3 tiles, no leaves",
        &tiles,
        0.05,
        [0.0; 3],
        1.0,
        rays,
    )?);
    Ok(out)
}

/// Result of one estimator on one case.
#[derive(Debug, Clone, Serialize)]
pub struct StressRow {
    /// Case name.
    pub case: String,
    /// Estimator name (with its variant).
    pub estimator: String,
    /// Rays traced.
    pub rays: usize,
    /// Largest exact optical depth over the rays.
    pub max_tau: f64,
    /// Largest |T_estimate - T_exact|.
    pub max_error: f64,
    /// Estimates that were NaN or infinite.
    pub non_finite: u64,
    /// Estimates outside [0, 1] (allowed only for signed estimators).
    pub out_of_range: u64,
    /// Rays with tau so large that exp(-tau) underflows whose exact T was not exactly 0.
    pub underflow_violations: u64,
    /// Samples stopped by the collision cap.
    pub capped: u64,
    /// Wall time for all rays, seconds.
    pub seconds: f64,
    /// Whether the estimator may return values outside [0, 1].
    pub signed: bool,
}

/// Every estimator variant the stress suite runs.
#[must_use]
pub fn stress_estimators() -> Vec<(String, Estimator)> {
    crate::estimate::REGISTRY
        .iter()
        .map(|spec| {
            let e = spec.default_estimator();
            // A kernel of 0.05 world units: the stress media have unit voxels.
            let e = e.set("kernel", 0.05).unwrap_or(e);
            (spec.name.to_string(), e)
        })
        .collect()
}

/// Run every estimator on every case with `samples` samples per ray.
#[must_use]
pub fn run(cases: &[Case], samples: u32, max_collisions: u64) -> Vec<StressRow> {
    let mut rows = Vec::new();
    for c in cases {
        let exact: Vec<(f64, f64)> = c
            .rays
            .iter()
            .map(|r| {
                optical_depth(&c.volume, r, Interp::Trilinear)
                    .map_or((f64::NAN, f64::NAN), |od| (od.tau, od.transmittance()))
            })
            .collect();
        let max_tau = exact.iter().fold(0.0f64, |m, e| m.max(e.0));
        for (name, est) in stress_estimators() {
            let opts = Options {
                samples,
                seed: 3,
                max_collisions,
                interp: Interp::Trilinear,
                ..Options::default()
            };
            let t0 = Instant::now();
            let signed = est.may_leave_unit_interval();
            let mut row = StressRow {
                case: c.name.into(),
                estimator: name,
                rays: c.rays.len(),
                max_tau,
                max_error: 0.0,
                non_finite: 0,
                out_of_range: 0,
                underflow_violations: 0,
                capped: 0,
                seconds: 0.0,
                signed,
            };
            for (i, (r, &(tau, t))) in c.rays.iter().zip(&exact).enumerate() {
                let Ok(e) = estimate(&c.volume, r, i as u64, &est, &opts) else {
                    row.non_finite += 1;
                    continue;
                };
                if !e.value.is_finite() || !e.std_err.is_finite() {
                    row.non_finite += 1;
                }
                if !(0.0..=1.0).contains(&e.value) {
                    row.out_of_range += 1;
                }
                if tau > 800.0 && t != 0.0 {
                    row.underflow_violations += 1;
                }
                row.capped += e.capped;
                row.max_error = row.max_error.max((e.value - t).abs());
            }
            row.seconds = t0.elapsed().as_secs_f64();
            rows.push(row);
        }
    }
    rows
}

/// The stability table in markdown.
#[must_use]
pub fn markdown(cases: &[Case], rows: &[StressRow], samples: u32) -> String {
    let mut s = String::from("# Stability on stiff and extreme media\n\n");
    s.push_str(&format!("{samples} samples per ray; trilinear lookups; exact = regular tracking.\n\n| case | what |\n|---|---|\n"));
    for c in cases {
        s.push_str(&format!("| {} | {} |\n", c.name, c.what));
    }
    s.push_str("\n| case | estimator | rays | max tau | max abs error | non-finite | outside [0,1] | underflow misses | capped | seconds |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for r in rows {
        let range = if r.signed {
            format!("{} (signed)", r.out_of_range)
        } else {
            r.out_of_range.to_string()
        };
        s.push_str(&format!(
            "| {} | {} | {} | {:.3e} | {:.2e} | {} | {} | {} | {} | {:.3} |\n",
            r.case,
            r.estimator,
            r.rays,
            r.max_tau,
            r.max_error,
            r.non_finite,
            range,
            r.underflow_violations,
            r.capped,
            r.seconds
        ));
    }
    s
}

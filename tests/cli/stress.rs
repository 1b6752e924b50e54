//! The stress catalogue (`umbra compare --stress`): every estimator on stiff and extreme media
//! returns finite answers, in [0, 1] unless documented as signed, exactly 0 where the optical
//! depth underflows, and stops at the collision cap instead of hanging. The references are
//! independent of the code under test: regular tracking is checked on every case against a
//! brute-force quadrature written here (5-point Gauss-Legendre between the integer planes the
//! ray crosses, values from the tree's point sampler: exact for the piecewise-cubic trilinear
//! field), and against closed forms on constant media with optical depths from 1e-8 to 1e5,
//! where the unbiased estimators must also agree within a few standard errors. Also:
//! `umbra compare` writes well-formed reports in which exact tracking has zero error and the
//! stochastic estimators' error falls with budget.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::Command;
use umbra::compare::stress::{catalogue, run};
use umbra::estimate::{estimate, Estimator, Kind, Options, REGISTRY};
use umbra::internals::tree::{Accessor, TreeBuilder};
use umbra::{Interp, Ray, Volume};

/// Brute-force trilinear optical depth of `r` through `v`, independent of umbra's traversal and
/// regular tracking: the index-space line is cut at every integer plane it crosses inside the
/// grid's value box (grown by 2 voxels; the background is 0 outside it in these media), and
/// each piece, where the trilinear field is a cubic in `t`, is integrated by 5-point
/// Gauss-Legendre (exact to degree 9) of the trilinear interpolation, in f64, of the 8 voxel
/// values `Accessor::value` returns around each point.
fn brute_tau(v: &Volume, r: &Ray) -> f64 {
    let Some([lo, hi]) = v.value_box() else {
        return 0.0;
    };
    let q = v.to_index(r.origin()).to_array();
    let d = v.to_index_dir(r.direction()).to_array();
    // Independent slab clip to [lo - 2, hi + 2].
    let (mut t0, mut t1) = (r.t_min(), r.t_max());
    for a in 0..3 {
        let (l, h) = ((lo[a] - 2) as f64, (hi[a] + 2) as f64);
        if d[a] == 0.0 {
            if q[a] < l || q[a] > h {
                return 0.0;
            }
            continue;
        }
        let (u, w) = ((l - q[a]) / d[a], (h - q[a]) / d[a]);
        t0 = t0.max(u.min(w));
        t1 = t1.min(u.max(w));
    }
    if t0.partial_cmp(&t1) != Some(std::cmp::Ordering::Less) {
        return 0.0;
    }
    let mut cuts = vec![t0, t1];
    for a in 0..3 {
        if d[a] == 0.0 {
            continue;
        }
        let (p0, p1) = (q[a] + d[a] * t0, q[a] + d[a] * t1);
        let (a0, a1) = (p0.min(p1).ceil() as i64, p0.max(p1).floor() as i64);
        for k in a0..=a1 {
            let t = (k as f64 - q[a]) / d[a];
            if t > t0 && t < t1 {
                cuts.push(t);
            }
        }
    }
    cuts.sort_by(f64::total_cmp);
    let x = [
        0.0,
        -0.538_469_310_105_683_1,
        0.538_469_310_105_683_1,
        -0.906_179_845_938_664,
        0.906_179_845_938_664,
    ];
    let w = [
        0.568_888_888_888_888_9,
        0.478_628_670_499_366_5,
        0.478_628_670_499_366_5,
        0.236_926_885_056_189_1,
        0.236_926_885_056_189_1,
    ];
    let mut acc = Accessor::new(v.tree());
    let mut s = 0.0;
    for c in cuts.windows(2) {
        let (m, h) = (0.5 * (c[0] + c[1]), 0.5 * (c[1] - c[0]));
        if h <= 0.0 {
            continue;
        }
        for g in 0..5 {
            let t = m + h * x[g];
            let p = [0, 1, 2].map(|k| q[k] + d[k] * t);
            let i = p.map(|c| c.floor());
            let f = [0, 1, 2].map(|k| p[k] - i[k]);
            let mut val = 0.0;
            for n in 0..8 {
                let o = [n >> 2 & 1, n >> 1 & 1, n & 1];
                let ijk = [0, 1, 2].map(|k| i[k] as i32 + o[k]);
                let wt: f64 = (0..3)
                    .map(|k| if o[k] == 1 { f[k] } else { 1.0 - f[k] })
                    .product();
                let x = f64::from(acc.value(ijk));
                if wt != 0.0 {
                    val += wt * x;
                }
            }
            s += h * w[g] * val;
        }
    }
    if v.density_scale() == 0.0 {
        return 0.0;
    }
    s * v.density_scale()
}

#[test]
fn regular_tracking_matches_an_independent_quadrature_on_every_stress_case() {
    let cases = catalogue(24).unwrap();
    let mut checked = 0;
    for c in &cases {
        for (i, r) in c.rays.iter().enumerate() {
            let e = estimate(
                &c.volume,
                r,
                i as u64,
                &Estimator::REGULAR,
                &Options::default(),
            )
            .unwrap();
            let tau = e.tau.unwrap();
            let want = brute_tau(&c.volume, r);
            if !want.is_finite() {
                // Through an opaque (+inf) voxel: the quadrature sees inf (or inf * 0).
                assert_eq!(tau, f64::INFINITY, "{} ray {i}", c.name);
                continue;
            }
            assert!(
                (tau - want).abs() <= 1e-9 * want.abs() + 1e-300,
                "{} ray {i}: regular {tau:e} vs quadrature {want:e}",
                c.name
            );
            checked += 1;
        }
    }
    assert!(checked > 200, "{checked} rays checked");
}

/// A constant cube of `n^3` voxels of density `c` (voxel `h`, scale `s`): along an
/// axis-parallel line through the interior, nearest lookups see `c` over `n` voxels
/// (`[-1/2, n - 1/2)`), trilinear ones `c` over `[0, n - 1]` plus two linear ramps of half a
/// voxel each: `tau = n c h s` either way, in closed form.
fn constant_cube(n: i32, c: f32, h: f64, s: f64) -> Volume {
    let mut b = TreeBuilder::new(0.0);
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                b.set([i, j, k], c);
            }
        }
    }
    let m = [[h, 0.0, 0.0, 3.0], [0.0, h, 0.0, -2.0], [0.0, 0.0, h, 1.0]];
    Volume::from_tree("cube".into(), b.build(), m, s).unwrap()
}

#[test]
fn closed_form_optical_depths_from_1e_minus_8_to_1e5() {
    let n = 16;
    for (c, s, h) in [
        (1.0f32, 1e-9, 0.5),
        (0.25, 0.3, 1e-6),
        (2.0, 0.05, 2.0),
        (4.0, 1e4, 0.1),
        (1.0, 6250.0, 1.0),
    ] {
        let vol = constant_cube(n, c, h, s);
        let tau = f64::from(n) * f64::from(c) * h * s;
        // Axis-parallel rays through voxel centres of the interior, from outside to outside.
        let w = |i: f64, j: f64, k: f64| [3.0 + i * h, -2.0 + j * h, 1.0 + k * h];
        let rays = [
            Ray::between(w(-3.0, 7.0, 8.0), w(20.0, 7.0, 8.0)).unwrap(),
            Ray::between(w(5.0, 21.0, 9.0), w(5.0, -4.0, 9.0)).unwrap(),
            Ray::between(w(6.0, 6.0, -2.5), w(6.0, 6.0, 18.0)).unwrap(),
        ];
        for interp in [Interp::Nearest, Interp::Trilinear] {
            let opts = Options {
                interp,
                samples: 400,
                seed: 11,
                ..Options::default()
            };
            for (i, r) in rays.iter().enumerate() {
                let e = estimate(&vol, r, i as u64, &Estimator::REGULAR, &opts).unwrap();
                let got = e.tau.unwrap();
                assert!(
                    (got - tau).abs() <= 1e-10 * tau,
                    "c {c} s {s} {interp:?} ray {i}: tau {got:e} vs closed form {tau:e}"
                );
                assert_eq!(e.value, (-tau).exp());
                // Unbiased estimators agree within 5 standard errors plus the rule-of-three
                // bound 3 / n on an event that n samples all missed (a binary estimator on a
                // ray with tau 1e-8 reads exactly 1 with standard error 0).
                for spec in REGISTRY.iter().filter(|s| s.kind != Kind::Biased) {
                    let est = spec.default_estimator();
                    let e = estimate(&vol, r, i as u64, &est, &opts).unwrap();
                    let t = (-tau).exp();
                    assert!(
                        (e.value - t).abs() <= 5.0 * e.std_err + 3.0 / f64::from(e.samples),
                        "{} c {c} s {s} {interp:?} ray {i}: {} +- {} vs {t:e}",
                        spec.name,
                        e.value,
                        e.std_err
                    );
                    assert_eq!(e.capped, 0);
                    assert_eq!(e.majorant_violations, 0);
                }
            }
        }
    }
}

#[test]
fn every_estimator_is_sound_on_every_stress_case() {
    let cases = catalogue(12).unwrap();
    assert!(cases.len() >= 12, "catalogue has {} cases", cases.len());
    let rows = run(&cases, 4, 5_000_000);
    let mut bad = Vec::new();
    for r in &rows {
        if r.non_finite > 0
            || (!r.signed && r.out_of_range > 0)
            || r.underflow_violations > 0
            || r.capped > 0
        {
            bad.push(format!("{r:?}"));
        }
    }
    let thick = rows
        .iter()
        .find(|r| r.case == "tau-1e5" && r.estimator == "regular")
        .unwrap();
    // max_error is against regular tracking itself (see the quadrature test for regular's own
    // check); here only the magnitude of the case matters.
    assert!(thick.max_tau > 1e4, "{thick:?}");
    let thin = rows
        .iter()
        .find(|r| r.case == "tau-1e-8" && r.estimator == "regular")
        .unwrap();
    assert!(thin.max_tau < 1e-6 && thin.max_tau > 1e-10, "{thin:?}");
    eprintln!(
        "{} (case, estimator) rows on {} cases",
        rows.len(),
        cases.len()
    );
    assert!(
        bad.is_empty(),
        "{} rows violate the stress properties:\n{}",
        bad.len(),
        bad.join("\n")
    );
}

#[test]
fn opaque_voxels_give_exactly_zero_and_infinite_tau() {
    let cases = catalogue(0).unwrap();
    let c = cases.iter().find(|c| c.name == "nan-inf-negative").unwrap();
    let r = Ray::between([12.0, 12.0, -5.0], [12.0, 12.0, 20.0]).unwrap();
    let e = estimate(&c.volume, &r, 0, &Estimator::REGULAR, &Options::default()).unwrap();
    assert_eq!(e.value, 0.0);
    assert_eq!(e.tau, Some(f64::INFINITY));
    assert_eq!(c.volume.sanitized().nan, 1);
    assert_eq!(c.volume.sanitized().negative, 2);
}

#[test]
fn the_collision_cap_stops_a_sample_and_is_counted() {
    let cases = catalogue(4).unwrap();
    let c = cases.iter().find(|c| c.name == "tau-1e5").unwrap();
    let opts = Options {
        samples: 3,
        max_collisions: 10,
        ..Options::default()
    };
    let e = estimate(
        &c.volume,
        &c.rays[0],
        0,
        &Estimator::from_name("ratio").unwrap(),
        &opts,
    )
    .unwrap();
    assert_eq!(e.capped, 3, "{e:?}");
    assert!(e.value.is_finite());
}

/// A sample stopped by the collision cap finishes its ray with the exact optical depth of the
/// rest. On a dense blob (exact T below 1e-7) every null-collision estimator stopped after a
/// few collisions answers T <= 0.01, never "no attenuation". On a blob of exact T = 0.1 with a
/// budget of one collision (nearly every sample capped) the unbiased trackers stay unbiased
/// (the closed-form rest is the walk's conditional mean): within 4 standard errors of the
/// exact T.
#[test]
fn a_capped_sample_finishes_its_ray_with_the_exact_rest() {
    let id = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
    ];
    let tree = || {
        let mut b = TreeBuilder::new(0.0);
        for i in 0..22 {
            for j in 0..22 {
                for k in 0..22 {
                    let r2 = (i - 11) * (i - 11) + (j - 11) * (j - 11) + (k - 11) * (k - 11);
                    b.set([i, j, k], (-f64::from(r2) / 30.0).exp() as f32);
                }
            }
        }
        b.build()
    };
    let ray = Ray::between([0.0, 0.0, 0.0], [21.0, 21.0, 21.0]).unwrap();
    let tau = |v: &Volume| {
        estimate(v, &ray, 0, &Estimator::REGULAR, &Options::default())
            .unwrap()
            .tau
            .unwrap()
    };
    let dense = Volume::from_tree("dense".into(), tree(), id, 1e12).unwrap();
    let unit = Volume::from_tree("unit".into(), tree(), id, 1.0).unwrap();
    let scale = 10f64.ln() / tau(&unit);
    let mid = Volume::from_tree("mid".into(), tree(), id, scale).unwrap();
    let t_mid = (-tau(&mid)).exp();
    assert!((t_mid - 0.1).abs() < 1e-6, "{t_mid}");
    for name in [
        "track-length",
        "collision",
        "ratio",
        "residual-ratio",
        "residual-ratio-midpoint",
        "next-flight",
        "decomposition",
    ] {
        let est = Estimator::from_name(name).unwrap();
        let opts = Options {
            samples: 16,
            max_collisions: 3,
            ..Options::default()
        };
        let e = estimate(&dense, &ray, 7, &est, &opts).unwrap();
        assert!(
            e.value <= 0.01,
            "{name}: dense blob gives T = {} ({e:?})",
            e.value
        );
        let opts = Options {
            samples: 4000,
            max_collisions: 1,
            ..Options::default()
        };
        let e = estimate(&mid, &ray, 7, &est, &opts).unwrap();
        assert!(
            e.capped > 400,
            "{name}: only {} of 4000 samples capped",
            e.capped
        );
        let err = (e.value - t_mid).abs();
        if est.kind() == Kind::Biased {
            assert!(err < 0.05, "{name}: T = {} (exact {t_mid})", e.value);
        } else {
            assert!(
                err < 4.0 * e.std_err,
                "{name}: T = {} +- {} (exact {t_mid}, {} capped)",
                e.value,
                e.std_err,
                e.capped
            );
        }
    }
}

#[test]
fn compare_writes_four_well_formed_reports() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cmp");
    let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb");
    let status = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args([
            "compare",
            data.to_str().unwrap(),
            "--grid",
            "density",
            "--density-scale",
            "2",
        ])
        .args([
            "--rays",
            "48",
            "--repeats",
            "1",
            "--quiet",
            "-o",
            out.to_str().unwrap(),
        ])
        .args(["--estimators", "regular,ratio,jittered,unbiased-raymarch"])
        .arg("--global-baseline")
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    let csv = std::fs::read_to_string(out.join("report.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    for col in [
        "estimator",
        "budget",
        "rmse",
        "bias",
        "variance",
        "max_error",
        "seconds",
        "lookups",
        "efficiency",
    ] {
        assert!(header.contains(&col), "missing column {col}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let rows = json["rows"].as_array().unwrap();
    assert_eq!(rows.len(), csv.lines().count() - 1);
    let rmse = |est: &str| -> Vec<f64> {
        rows.iter()
            .filter(|r| r["estimator"] == est)
            .map(|r| r["rmse"].as_f64().unwrap())
            .collect()
    };
    let mut ran: Vec<&str> = rows
        .iter()
        .filter_map(|r| r["estimator"].as_str())
        .collect();
    ran.dedup();
    assert_eq!(
        ran,
        [
            "regular",
            "ratio",
            "jittered",
            "unbiased-raymarch",
            "ratio-global-majorant"
        ],
        "exactly the estimators asked for, then the baseline"
    );
    assert_eq!(rmse("regular"), vec![0.0]);
    for est in [
        "ratio",
        "jittered",
        "unbiased-raymarch",
        "ratio-global-majorant",
    ] {
        let r = rmse(est);
        assert_eq!(r.len(), 4, "{est}");
        assert!(
            r[3] < 0.5 * r[0],
            "{est}: RMSE did not fall with budget: {r:?}"
        );
    }
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("| estimator | budget | RMSE") && md.contains("**"));
    let svg = std::fs::read_to_string(out.join("error_vs_time.svg")).unwrap();
    assert!(
        svg.starts_with("<svg")
            && svg.contains("unbiased-raymarch")
            && svg.trim_end().ends_with("</svg>")
    );
    assert!(json["meta"]["machine"].as_str().unwrap().contains("cores"));
}

/// `--estimators a,b` runs exactly a and b; `all` runs every registered estimator (no
/// baseline unless asked for).
#[test]
fn compare_runs_exactly_the_estimators_asked_for() {
    let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb");
    let run = |which: &str| -> Vec<String> {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("cmp");
        let o = Command::new(env!("CARGO_BIN_EXE_umbra"))
            .args([
                "compare",
                data.to_str().unwrap(),
                "--rays",
                "6",
                "--repeats",
                "1",
            ])
            .args(["-q", "-o", out.to_str().unwrap(), "--estimators", which])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap())
                .unwrap();
        let mut names: Vec<String> = json["rows"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r["estimator"].as_str().unwrap().to_string())
            .collect();
        names.dedup();
        names
    };
    assert_eq!(
        run("residual-ratio-midpoint,riemann"),
        ["residual-ratio-midpoint", "riemann"]
    );
    let all: Vec<String> = umbra::estimate::names().map(String::from).collect();
    assert_eq!(run("all"), all);
}

//! The stress catalogue (`umbra compare --stress`): every estimator on stiff and extreme media
//! returns finite answers, in [0, 1] unless documented as signed, exactly 0 where the optical
//! depth underflows, and stops at the collision cap instead of hanging. Also: `umbra compare`
//! writes well-formed reports in which exact tracking has zero error and the stochastic
//! estimators' error falls with budget.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::Command;
use umbra::compare::stress::{catalogue, run};
use umbra::estimate::{estimate, Estimator, Options};
use umbra::Ray;

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
    assert!(thick.max_tau > 1e4 && thick.max_error == 0.0, "{thick:?}");
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

//! `QueryRequest::run`, the one entry point of a query, against answers computed without it:
//! exact regular tracking on the volume loaded by hand, and `scene::estimate` ray by ray with
//! the ray ids a file of rays numbers its rows with.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;
use umbra::input::{Source, SourceOptions};
use umbra::request::{EstimatorOptions, QueryOutcome, QueryRequest, RayAnswers, RayRow};
use umbra::{Interp, Light, Ray, Volume};

fn cloud() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb")
}

fn rays(r: &QueryRequest) -> RayAnswers {
    match r.run(&mut |_| {}).unwrap() {
        QueryOutcome::Rays(a) => a,
        QueryOutcome::Points(_) => panic!("a ray query answered points"),
    }
}

/// The exact transmittance along `ray` through the sample cloud (regular tracking, trilinear).
fn exact(ray: &Ray) -> f64 {
    let vol = Volume::load(cloud(), "density", 1.0).unwrap();
    let tau = umbra::regular::optical_depth(&vol, ray, Interp::Trilinear)
        .unwrap()
        .tau;
    (-tau).exp()
}

/// Equal to the rounding of the batch kernel (queries go through `scene::estimate_many`,
/// whose lanes sum the optical depth in another order than the scalar walk).
fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-7 * b.abs().max(1e-12)
}

#[test]
fn a_segment_is_the_exact_answer() {
    let (from, to) = ([-3.0, 1.5, 0.0], [3.0, 1.5, 0.0]);
    let r = QueryRequest {
        from: Some(from),
        to: Some(to),
        ..QueryRequest::new(Source::new(cloud(), SourceOptions::default()))
    };
    let a = rays(&r);
    assert_eq!(
        (a.estimator.as_str(), a.interp),
        ("regular", Interp::Trilinear)
    );
    let [one] = a.answers.as_slice() else {
        panic!("{} answers", a.answers.len())
    };
    assert_eq!(one.line, None);
    let got = one.result.as_ref().unwrap();
    let want = exact(&Ray::between(from, to).unwrap());
    assert!(want < 0.99, "the segment crosses the cloud: T = {want}");
    assert!(
        close(got.estimate.value[0], want),
        "{} vs {want}",
        got.estimate.value[0]
    );
    // Loaded lazily or whole, the answer is the same, bit for bit.
    let eager = rays(&QueryRequest {
        load: umbra::request::LoadMode::Eager,
        ..r.clone()
    });
    let e = eager.answers[0].result.as_ref().unwrap();
    assert_eq!(
        e.estimate.value[0].to_bits(),
        got.estimate.value[0].to_bits()
    );
}

#[test]
fn a_file_of_rays_keeps_its_bad_rows_and_numbers_its_ray_ids() {
    let segs = [
        ([-3.0, 1.5, 0.0], [3.0, 1.5, 0.0]),
        ([-3.0, 1.0, 0.5], [3.0, 2.0, -0.5]),
    ];
    let rows = vec![
        RayRow {
            line: 2,
            ray: Ok(Ray::between(segs[0].0, segs[0].1).unwrap()),
        },
        RayRow {
            line: 3,
            ray: Err("expected 6 fields, got 1".into()),
        },
        RayRow {
            line: 4,
            ray: Ok(Ray::between(segs[1].0, segs[1].1).unwrap()),
        },
    ];
    let estimator = EstimatorOptions {
        estimator: "ratio".into(),
        samples: 16,
        seed: 7,
        ..EstimatorOptions::default()
    };
    let r = QueryRequest {
        rays: Some(rows.clone()),
        ray_id: 100,
        estimator: estimator.clone(),
        ..QueryRequest::new(Source::new(cloud(), SourceOptions::default()))
    };
    let a = rays(&r);
    assert_eq!(a.estimator, "ratio");
    let lines: Vec<Option<usize>> = a.answers.iter().map(|x| x.line).collect();
    assert_eq!(lines, [Some(2), Some(3), Some(4)]);
    assert_eq!(
        a.answers[1].result.as_ref().unwrap_err(),
        "expected 6 fields, got 1"
    );
    // Row n has ray id ray_id + n (the bad row counts): each answer is scene::estimate's for
    // that ray and id.
    let scene = Source::new(cloud(), SourceOptions::default())
        .load()
        .unwrap();
    let (est, opts) = estimator
        .resolve(&Default::default(), Interp::Trilinear)
        .unwrap();
    for (n, row) in rows.iter().enumerate() {
        let Ok(ray) = &row.ray else { continue };
        let want = umbra::scene::estimate(&scene, ray, 100 + n as u64, &est, &opts).unwrap();
        let got = &a.answers[n].result.as_ref().unwrap().estimate;
        assert_eq!(got.value[0].to_bits(), want.value[0].to_bits(), "row {n}");
        assert_eq!(
            got.std_err[0].to_bits(),
            want.std_err[0].to_bits(),
            "row {n}"
        );
        // A stochastic answer near the exact one (16 samples: within 5 standard errors).
        let t = exact(ray);
        assert!(
            (got.value[0] - t).abs() <= 5.0 * got.std_err[0] + 1e-3,
            "row {n}"
        );
    }
}

#[test]
fn a_stage_point_toward_the_stage_light() {
    let dir = tempfile::tempdir().unwrap();
    let stage = dir.path().join("shot.usda");
    // A sun turned 90 degrees about Y: it travels along its world -Z axis, here -X; its
    // angle authored 0 (a point sun), then left to the schema's fallback (0.53 degrees).
    let write = |angle: &str| {
        let text = format!(
        "#usda 1.0\n\ndef Volume \"cloud\"\n{{\n    rel field:density = </cloud/density>\n\n    \
         def OpenVDBAsset \"density\"\n    {{\n        asset filePath = @{}@\n        \
         token fieldName = \"density\"\n    }}\n}}\n\n\
         def DistantLight \"sun\"\n{{\n    {angle}\n    double3 xformOp:rotateXYZ = (0, 90, 0)\n    \
         uniform token[] xformOpOrder = [\"xformOp:rotateXYZ\"]\n}}\n",
            cloud().display()
        );
        std::fs::write(&stage, text).unwrap();
    };
    write("float inputs:angle = 0");
    let at = [-2.0, 1.5, 0.0];
    let a = rays(&QueryRequest {
        at: Some(at),
        ..QueryRequest::new(Source::new(&stage, SourceOptions::default()))
    });
    let got = a.answers[0].result.as_ref().unwrap();
    // Independently: the shot's light, and the ray from the point against its direction
    // through the cloud loaded from its own file.
    let shot = umbra::usd::lights_at(&stage, None).unwrap();
    let (_, emitter) = shot.light(Some("sun")).unwrap();
    let umbra::usd::Emitter::Directional { dir: d, .. } = emitter else {
        panic!("the sun is directional")
    };
    assert!((d[0] + 1.0).abs() < 1e-9 && d[1].abs() < 1e-9, "{d:?}");
    let scene = Source::new(cloud(), SourceOptions::default())
        .load()
        .unwrap();
    let ray = Light::Directional { dir: d }
        .ray_from_scene(&scene, at)
        .unwrap();
    let want = exact(&ray);
    assert!(want < 0.99, "the ray crosses the cloud: T = {want}");
    assert!(
        close(got.estimate.value[0], want),
        "{} vs {want}",
        got.estimate.value[0]
    );
    // The same light given by its direction: the same answer.
    let toward = |angle: Option<f64>| {
        let given = rays(&QueryRequest {
            at: Some(at),
            light: umbra::request::LightOptions {
                light_dir: Some(d),
                light_angle: angle,
                ..umbra::request::LightOptions::default()
            },
            ..QueryRequest::new(Source::new(&stage, SourceOptions::default()))
        });
        given.answers[0].result.clone().unwrap()
    };
    let g = toward(None);
    assert_eq!(
        g.estimate.value[0].to_bits(),
        got.estimate.value[0].to_bits()
    );
    // Unauthored, the angle is the schema's 0.53 degrees (a float), as renderers apply it:
    // the sun's disc, the same answer as the direction with that angle, bit for bit.
    write("");
    let soft = rays(&QueryRequest {
        at: Some(at),
        ..QueryRequest::new(Source::new(&stage, SourceOptions::default()))
    });
    let soft = soft.answers[0].result.as_ref().unwrap();
    assert!(
        soft.light_samples.is_some_and(|n| n >= 64),
        "{:?}",
        soft.light_samples
    );
    let g = toward(Some(f64::from(0.53_f32)));
    assert_eq!(
        g.estimate.value[0].to_bits(),
        soft.estimate.value[0].to_bits()
    );
    assert_eq!(
        g.estimate.std_err[0].to_bits(),
        soft.estimate.std_err[0].to_bits()
    );
}

#[test]
fn what_is_asked_is_checked_by_name() {
    let e = QueryRequest {
        from: Some([0.0; 3]),
        ..QueryRequest::new(Source::new(cloud(), SourceOptions::default()))
    }
    .check()
    .unwrap_err();
    assert_eq!(
        e.to_string(),
        "from and to go together (a segment from one point to the other)"
    );
    assert!(matches!(e, umbra::Error::Conflict { ref names, .. } if names == &["from", "to"]));
    let e = QueryRequest::new(Source::new(cloud(), SourceOptions::default()))
        .check()
        .unwrap_err();
    assert!(
        e.to_string().starts_with("give exactly one of from/to"),
        "{e}"
    );
    let e = QueryRequest {
        positions: Some("/World/points".into()),
        ..QueryRequest::new(Source::new(cloud(), SourceOptions::default()))
    }
    .check()
    .unwrap_err();
    assert!(
        matches!(e, umbra::Error::InvalidArgument { ref name, .. } if name == "positions"),
        "{e}"
    );
}

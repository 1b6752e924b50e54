//! The library enforces its own invariants: every public constructor validates, invalid input
//! is a typed error (never a hang, a NaN or a silently wrong answer), and the estimator
//! registry round-trips through every place a name appears (library, CLI JSON, EXR header).
//! Struct literals that would bypass the checks do not compile (`compile_fail` doc tests on
//! `Ray` and `Volume`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;
use std::process::Command;
use umbra::bake::{bake, BakeSettings, Camera, Depths, Projection, View};
use umbra::batch::{panic_message, parse_job, BatchError};
use umbra::estimate::{estimate, names, Estimator, Kind, Options, REGISTRY};
use umbra::internals::tree::TreeBuilder;
use umbra::{Error, Ray, Volume};

const UNIT: [[f64; 4]; 3] = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
];

fn slab() -> Volume {
    let mut b = TreeBuilder::new(0.0);
    for i in 0..16 {
        for j in 0..4 {
            b.set(
                [i, j, 0],
                0.5 + 0.1 * f32::from(u8::try_from(i % 3).unwrap()),
            );
        }
    }
    Volume::from_tree("slab".into(), b.build(), UNIT, 1.0).unwrap()
}

fn invalid_arg(e: Error) -> String {
    match e {
        Error::InvalidArgument { name, .. } => name,
        other => panic!("expected InvalidArgument, got {other:?}"),
    }
}

#[test]
fn marching_steps_out_of_range_are_errors_not_hangs() {
    for bad in [0.0, -1.0, 1e-300, 1e-9, f64::NAN, f64::INFINITY, 1e7] {
        for name in ["riemann", "mc", "jittered"] {
            let e = Estimator::with_params(name, &[("step", bad)]);
            assert_eq!(invalid_arg(e.unwrap_err()), "step", "{name} step {bad}");
        }
    }
    let e = Estimator::from_name("riemann").unwrap();
    assert!(e.set("step", 0.0).is_err());
    assert_eq!(
        e.param("step"),
        Some(1.0),
        "a failed set leaves the value alone"
    );
    assert!(Estimator::with_params("jackknife", &[("points", 2.5)]).is_err());
    assert!(Estimator::with_params("jackknife", &[("points", 0.0)]).is_err());
    assert!(Estimator::with_params("collision", &[("kernel", -0.1)]).is_err());
    // A parameter the estimator does not have is an error, not silently ignored.
    assert_eq!(
        invalid_arg(Estimator::with_params("ratio", &[("step", 1.0)]).unwrap_err()),
        "step"
    );
    assert_eq!(
        invalid_arg(Estimator::from_name("magic").unwrap_err()),
        "estimator"
    );
}

#[test]
fn the_registry_round_trips_every_name_and_parameter() {
    assert_eq!(names().count(), REGISTRY.len());
    for spec in REGISTRY {
        let e = Estimator::from_name(spec.name).unwrap();
        assert_eq!(e.name(), spec.name);
        assert_eq!(Estimator::from_name(e.name()).unwrap(), e);
        assert_eq!(e.kind(), spec.kind);
        assert_eq!(e.is_unbiased(), spec.kind != Kind::Biased);
        assert_eq!(e.may_leave_unit_interval(), spec.kind == Kind::Signed);
        for p in spec.params {
            assert_eq!(e.param(p.name), Some(p.default));
            // Every value of the compare ladder, and the range ends, are valid and read back.
            for v in p.ladder.iter().copied().chain([p.min, p.max]) {
                let f = e.set(p.name, v).unwrap();
                assert_eq!(f.param(p.name), Some(v));
                let again = Estimator::with_params(f.name(), &[(p.name, v)]).unwrap();
                assert_eq!(again, f);
            }
        }
        // The serialised form (the EXR umbra:estimator_params attribute) names it exactly.
        let json = serde_json::to_value(e).unwrap();
        assert_eq!(json["name"], spec.name);
        assert_eq!(json.as_object().unwrap().len(), 1 + spec.params.len());
    }
    assert!(names().any(|n| n == "residual-ratio-midpoint"));
    assert_eq!(Estimator::default(), Estimator::REGULAR);
}

#[test]
fn query_reports_back_exactly_the_name_it_was_given() {
    let data = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb");
    for name in names() {
        let o = Command::new(env!("CARGO_BIN_EXE_umbra"))
            .args([
                "query",
                data.to_str().unwrap(),
                "--from",
                "-2,0,0",
                "--to",
                "2,0.5,0",
            ])
            .args(["--estimator", name, "--samples", "4", "--json"])
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["estimator"], name);
    }
    let o = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(["estimators", "--json"])
        .output()
        .unwrap();
    assert!(o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let list = v.as_array().unwrap();
    assert_eq!(list.len(), REGISTRY.len());
    for (entry, spec) in list.iter().zip(REGISTRY) {
        assert_eq!(entry["name"], spec.name);
        assert_eq!(entry["kind"], spec.kind.as_str());
        assert_eq!(entry["params"].as_array().unwrap().len(), spec.params.len());
        for (p, q) in entry["params"].as_array().unwrap().iter().zip(spec.params) {
            assert_eq!(p["name"], q.name);
            assert_eq!(p["default"].as_f64(), Some(q.default));
            assert_eq!(p["min"].as_f64(), Some(q.min));
            assert_eq!(p["max"].as_f64(), Some(q.max));
        }
    }
}

#[test]
fn rays_validate_on_every_constructor() {
    assert!(
        Ray::new([0.0; 3], [0.0; 3], 0.0, 1.0).is_err(),
        "zero direction"
    );
    assert!(
        Ray::new([0.0; 3], [1.0, 0.0, 0.0], 2.0, 1.0).is_err(),
        "t_min > t_max"
    );
    assert!(
        Ray::new([0.0; 3], [1.0, 0.0, 0.0], -1.0, 1.0).is_err(),
        "negative t_min"
    );
    assert!(Ray::new([f64::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], 0.0, 1.0).is_err());
    assert!(Ray::new([0.0; 3], [f64::INFINITY, 0.0, 0.0], 0.0, 1.0).is_err());
    assert!(Ray::new([0.0; 3], [1.0, 0.0, 0.0], 0.0, f64::NAN).is_err());
    let r = Ray::new([0.0; 3], [0.0, 3.0, 4.0], 0.0, 1.0).unwrap();
    assert_eq!(r.direction().to_array(), [0.0, 0.6, 0.8], "normalised");
    assert!(r.with_range(1.0, 0.5).is_err());
    assert!(Ray::between([0.0; 3], [f64::NAN, 0.0, 0.0]).is_err());
}

#[test]
fn volumes_validate_scale_and_transform() {
    let tree = || TreeBuilder::new(0.0).build();
    for s in [-1.0, f64::NAN, f64::INFINITY] {
        let e = Volume::from_tree("v".into(), tree(), UNIT, s).unwrap_err();
        assert_eq!(invalid_arg(e), "density-scale");
    }
    let mut flat = UNIT;
    flat[1][1] = 0.0;
    let e = Volume::from_tree("v".into(), tree(), flat, 1.0).unwrap_err();
    assert_eq!(invalid_arg(e), "transform");
    let mut tiny = UNIT;
    tiny[0][0] = 5e-324;
    assert!(Volume::from_tree("v".into(), tree(), tiny, 1.0).is_err());
    let mut nan = UNIT;
    nan[2][3] = f64::NAN;
    assert!(Volume::from_tree("v".into(), tree(), nan, 1.0).is_err());
    let v = slab();
    assert!(v.clone().with_density_scale(-2.0).is_err());
    assert_eq!(v.with_density_scale(3.0).unwrap().density_scale(), 3.0);
}

#[test]
fn estimate_refuses_invalid_options() {
    let v = slab();
    let r = Ray::between([-1.0, 1.0, 0.0], [17.0, 1.0, 0.0]).unwrap();
    let ratio = Estimator::from_name("ratio").unwrap();
    let zero = Options {
        samples: 0,
        ..Options::default()
    };
    assert_eq!(
        invalid_arg(estimate(&v, &r, 0, &ratio, &zero).unwrap_err()),
        "samples"
    );
    let no_cap = Options {
        max_collisions: 0,
        ..Options::default()
    };
    assert!(estimate(&v, &r, 0, &ratio, &no_cap).is_err());
    let ok = estimate(&v, &r, 0, &ratio, &Options::default()).unwrap();
    assert_eq!(ok.majorant_violations, 0);
}

#[test]
fn bake_settings_and_cameras_validate() {
    let v = slab();
    let view = View {
        projection: Projection::Ortho,
        light_dir: Some([0.0, 0.0, -1.0]),
        light_pos: None,
        fov_deg: None,
        res: Some(umbra::bake::Resolution::Exact(8, 8)),
        up: None,
        frame_box: None,
    };
    let cam = Camera::frame(&view, &v.box_corners().unwrap()).unwrap();
    let base = BakeSettings::new(Estimator::REGULAR, Options::default());
    let cases: Vec<(BakeSettings, &str)> = vec![
        (
            BakeSettings {
                options: Options {
                    samples: 0,
                    ..Options::default()
                },
                ..base.clone()
            },
            "samples",
        ),
        (
            BakeSettings {
                target_error: Some(-1.0),
                ..base.clone()
            },
            "target-error",
        ),
        (
            BakeSettings {
                target_error: Some(f64::NAN),
                ..base.clone()
            },
            "target-error",
        ),
        (
            BakeSettings {
                max_spp: 0,
                ..base.clone()
            },
            "max-spp",
        ),
        (
            BakeSettings {
                depths: Depths::Slices(0),
                ..base.clone()
            },
            "slices",
        ),
        (
            BakeSettings {
                depths: Depths::At(vec![2.0, 1.0]),
                ..base.clone()
            },
            "depths",
        ),
    ];
    for (s, name) in cases {
        let e = bake(&v, &cam, &s, &|_| {}).unwrap_err();
        assert_eq!(invalid_arg(e), name);
    }
    let corners = v.box_corners().unwrap();
    for bad in [
        View {
            light_dir: Some([0.0; 3]),
            ..view
        },
        View {
            light_dir: Some([f64::NAN, 0.0, 1.0]),
            ..view
        },
        View {
            res: Some(umbra::bake::Resolution::Exact(0, 8)),
            ..view
        },
        View {
            light_dir: None,
            ..view
        },
        View {
            projection: Projection::Perspective,
            light_pos: Some([8.0, 2.0, 30.0]),
            fov_deg: Some(0.0),
            ..view
        },
        View {
            projection: Projection::Perspective,
            light_pos: Some([8.0, 2.0, 30.0]),
            fov_deg: Some(180.0),
            ..view
        },
    ] {
        assert!(Camera::frame(&bad, &corners).is_err(), "{bad:?}");
    }
}

#[test]
fn batch_errors_are_typed_and_panics_keep_their_message() {
    let path = std::path::Path::new("/tmp/job.toml");
    let e = parse_job(path, "output = 1").unwrap_err();
    assert!(matches!(e, BatchError::Syntax { .. }), "{e:?}");
    let text = r#"
        output = "o_{light}.exr"
        [[inputs]]
        file = "a.vdb"
        [[lights]]
        name = "sun"
        dir = [0, -1, 0]
        [bake]
        estimator = "riemann"
        step = 0
    "#;
    match parse_job(path, text).unwrap_err() {
        BatchError::Invalid { key, .. } => assert_eq!(key, "bake.step"),
        other => panic!("{other:?}"),
    }
    let ok = parse_job(path, &text.replace("step = 0", "step = 0.5\nslices = 2")).unwrap();
    let task = ok.bake_job(&ok.tasks[0], 1).unwrap();
    assert_eq!(task.settings.estimator.param("step"), Some(0.5));
    assert_eq!(task.settings.depths, Depths::Slices(2));
    let p = std::panic::catch_unwind(|| panic!("boom {}", 42)).unwrap_err();
    assert_eq!(panic_message(p.as_ref()), "boom 42");
    let q = std::panic::catch_unwind(|| panic!("static")).unwrap_err();
    assert_eq!(panic_message(q.as_ref()), "static");
}

#[test]
fn cameras_rebuild_from_their_spec_and_refuse_bad_ones() {
    let v = slab();
    let corners = v.box_corners().unwrap();
    for view in [
        View {
            projection: Projection::Ortho,
            light_dir: Some([0.3, -1.0, 0.2]),
            light_pos: None,
            fov_deg: None,
            res: Some(umbra::bake::Resolution::Exact(9, 7)),
            up: None,
            frame_box: None,
        },
        View {
            projection: Projection::Perspective,
            light_dir: None,
            light_pos: Some([8.0, 30.0, 5.0]),
            fov_deg: None,
            res: Some(umbra::bake::Resolution::Exact(9, 7)),
            up: None,
            frame_box: None,
        },
    ] {
        let cam = Camera::frame(&view, &corners).unwrap();
        let again = Camera::from_spec(&cam.spec()).unwrap();
        assert_eq!(again.spec(), cam.spec());
        for (i, j) in [(0, 0), (8, 6), (4, 3)] {
            let (a, b) = (cam.pixel_ray(i, j).unwrap(), again.pixel_ray(i, j).unwrap());
            assert!((a.direction() - b.direction()).length() < 1e-12);
            assert!((a.origin() - b.origin()).length() < 1e-12);
        }
        for k in 0..3 {
            assert!(
                (cam.forward()[k] - again.forward()[k]).abs() < 1e-9,
                "{view:?}"
            );
        }
        let mut bad = cam.spec();
        bad.step_y = bad.step_x;
        assert!(Camera::from_spec(&bad).is_err(), "parallel steps");
        let mut bad = cam.spec();
        bad.step_x = [0.0; 3];
        assert!(Camera::from_spec(&bad).is_err(), "zero step");
        let mut bad = cam.spec();
        bad.t_max = f64::NAN;
        assert!(Camera::from_spec(&bad).is_err(), "NaN t_max");
        let mut bad = cam.spec();
        bad.width = 0;
        assert!(Camera::from_spec(&bad).is_err(), "no pixels");
    }
}

/// Hostile job files are refused with the key named, never a panic, an overflow or a hang.
#[test]
fn hostile_job_files_are_refused_by_key() {
    let path = std::path::Path::new("/tmp/job.toml");
    let job = |output: &str, input: &str, lights: &str| {
        format!("output = \"{output}\"\n[[inputs]]\n{input}\n{lights}\n")
    };
    let sun = "[[lights]]\nname = \"sun\"\ndir = [0, -1, 0]";
    let two =
        "[[lights]]\nname = \"a\"\ndir = [0, -1, 0]\n[[lights]]\nname = \"b\"\ndir = [1, -1, 0]";
    let hashes = format!(
        "pattern = \"c.{}.vdb\"\nframes = [1, 2]",
        "#".repeat(65_536)
    );
    let cases: Vec<(String, &str)> = vec![
        (
            job(
                "o.{frame:065536}.exr",
                "pattern = \"c.####.vdb\"\nframes = [1, 2]",
                sun,
            ),
            "output",
        ),
        (
            job(
                "o.exr",
                "pattern = \"c.$F999999999.vdb\"\nframes = [1, 2]",
                sun,
            ),
            "inputs[0].pattern",
        ),
        (job("o.{frame}.exr", &hashes, sun), "inputs[0].pattern"),
        (
            job(
                "o.{frame}.exr",
                "pattern = \"c.####.vdb\"\nframes = [0, 9223372036854775807]",
                sun,
            ),
            "inputs[0].frames",
        ),
        (
            job("out2/{light}/../{stem}.exr", "file = \"c.vdb\"", two),
            "output",
        ),
        (
            job(
                "o_{light}.exr",
                "file = \"c.vdb\"",
                "[[lights]]\nname = \"..\"\ndir = [0, -1, 0]",
            ),
            "lights[0].name",
        ),
        (
            job(
                "o_{light}.exr",
                "file = \"c.vdb\"",
                "[[lights]]\nname = \"a\\u001b[2J\"\ndir = [0, -1, 0]",
            ),
            "lights[0].name",
        ),
    ];
    for (text, key) in cases {
        match parse_job(path, &text) {
            Err(BatchError::Invalid { key: k, .. }) => assert_eq!(k, key, "{text}"),
            other => panic!("{key}: {other:?}"),
        }
    }
    // Frames up to i64::MAX expand without overflowing the counter.
    let near_max = job(
        "o.{frame}.exr",
        "pattern = \"c.####.vdb\"\nframes = [9223372036854775800, 9223372036854775807]\nstep = 3",
        sun,
    );
    let j = parse_job(path, &near_max).unwrap();
    let frames: Vec<i64> = j.tasks.iter().filter_map(|t| t.frame).collect();
    assert_eq!(
        frames,
        [
            9223372036854775800,
            9223372036854775803,
            9223372036854775806
        ]
    );
}

fn reason_of(e: Error) -> (String, String) {
    match e {
        Error::InvalidArgument { name, reason } => (name, reason),
        other => panic!("expected InvalidArgument, got {other:?}"),
    }
}

/// The work budget refuses, before tracing, what no job needs, naming the option and the
/// largest accepted value; the values at the budget itself are accepted.
#[test]
fn work_budget_refuses_with_the_largest_accepted_value() {
    use umbra::estimate::budget::{
        check_job, check_ray, MAX_LOOKUPS_PER_RAY, MAX_SAMPLES_PER_JOB, MAX_SAMPLES_PER_RAY,
    };
    let v = slab();
    let ratio = Estimator::from_name("ratio").unwrap();
    let ray = Ray::between([0.0, 0.5, 0.5], [16.0, 0.5, 0.5]).unwrap();
    // Samples per ray: through estimate() itself (so every caller gets it).
    for samples in [MAX_SAMPLES_PER_RAY + 1, u32::MAX] {
        let opts = Options {
            samples,
            ..Options::default()
        };
        let (name, reason) = reason_of(estimate(&v, &ray, 0, &ratio, &opts).unwrap_err());
        assert_eq!(name, "samples");
        assert!(reason.contains("at most 16777216"), "{reason}");
    }
    assert!(check_ray(&v, &ratio, MAX_SAMPLES_PER_RAY).is_ok());
    // Samples per job: a 4096^2 map at 4096 spp is the budget; one more sample is not.
    let pixels = 4096 * 4096;
    assert!(check_job(&v, &ratio, pixels, MAX_SAMPLES_PER_JOB / pixels, "spp").is_ok());
    let (name, reason) = reason_of(check_job(&v, &ratio, pixels, 4097, "spp").unwrap_err());
    assert_eq!(name, "spp");
    assert!(reason.contains("at most 4096 samples per ray"), "{reason}");
    // Deterministic estimators are charged one sample whatever --samples says.
    assert!(check_job(&v, &Estimator::REGULAR, pixels, 1 << 24, "spp").is_ok());
    // Marching: the slab's leaves span 16 x 8 x 8 voxels (reach: their diagonal), so a 0.001-voxel step
    // costs ~1.7e4 lookups per sample: 2^24 samples of it are over the per-ray budget, and
    // the suggested step is accepted.
    let jit = Estimator::with_params("jittered", &[("step", 0.001)]).unwrap();
    let reach = v.data_reach();
    assert!(reach > 16.0 && reach < 25.0, "reach {reach}");
    let (name, reason) = reason_of(check_ray(&v, &jit, MAX_SAMPLES_PER_RAY).unwrap_err());
    assert_eq!(name, "step");
    let at_least: f64 = reason
        .rsplit("at least ")
        .next()
        .and_then(|r| r.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no step in {reason}"));
    let ok = Estimator::with_params("jittered", &[("step", at_least)]).unwrap();
    assert!(check_ray(&v, &ok, MAX_SAMPLES_PER_RAY).is_ok(), "{reason}");
    assert!(f64::from(MAX_SAMPLES_PER_RAY) * (reach / at_least) <= MAX_LOOKUPS_PER_RAY * 1.01);
    // A bake applies it up front (adaptive: max-spp is what a pixel may take).
    let view = View {
        projection: Projection::Ortho,
        light_dir: Some([0.0, 0.0, -1.0]),
        light_pos: None,
        fov_deg: None,
        res: Some(umbra::bake::Resolution::Exact(4096, 4096)),
        up: None,
        frame_box: None,
    };
    let cam = Camera::frame(&view, &v.box_corners().unwrap()).unwrap();
    let s = BakeSettings {
        target_error: Some(1e-3),
        max_spp: 1 << 20,
        ..BakeSettings::new(ratio, Options::default())
    };
    let started = std::time::Instant::now();
    let (name, reason) = reason_of(bake(&v, &cam, &s, &|_| {}).unwrap_err());
    assert_eq!(name, "max-spp");
    assert!(reason.contains("at most 4096"), "{reason}");
    assert!(started.elapsed().as_secs() < 5, "refused before tracing");
}

/// A far-apart sparse grid is charged for its data, not for the index space between.
#[test]
fn data_reach_counts_nodes_not_empty_space() {
    let mut b = TreeBuilder::new(0.0);
    b.set([i32::MIN, i32::MIN, i32::MIN], 1.0);
    b.set([i32::MAX, i32::MAX, i32::MAX], 1.0);
    let v = Volume::from_tree("far".into(), b.build(), UNIT, 1.0).unwrap();
    // Two leaves: 2 x sqrt(3) x (8 + 2) voxels, not the 7.4e9-voxel diagonal.
    assert!(
        (v.data_reach() - 20.0 * 3f64.sqrt()).abs() < 1e-9,
        "{}",
        v.data_reach()
    );
    let empty =
        Volume::from_tree("empty".into(), TreeBuilder::new(0.0).build(), UNIT, 1.0).unwrap();
    assert_eq!(empty.data_reach(), 0.0);
}

//! Lights with extent at many receivers (issue 60): every point of a stage's points prim
//! (`QueryRequest::positions`) toward the stage light with `light-angle` or `light-radius`.
//! Each point's answer is the one `query --at` gives at that point with ray id `i` (the
//! point's index), bit for bit, whatever the thread count; zero extent is the point light's
//! answer exactly; a light of the wrong kind for the key is refused by name; extreme lights
//! (one direction per replicate, a 179.9 degree sun, a sphere of radius 1e300, a receiver
//! inside the sphere) are answered, never a panic.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use umbra::input::{Source, SourceOptions};
use umbra::internals::points::PointAnswers;
use umbra::request::{EstimatorOptions, LightOptions, QueryOutcome, QueryRequest};
use umbra::Error;

fn cloud() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb")
}

/// Receivers around the cloud: in the penumbra under it, inside it, beside it.
const POINTS: [[f64; 3]; 5] = [
    [1.9, -1.0, 0.3],
    [-2.0, 1.5, 0.3],
    [0.0, 0.0, 0.0],
    [-1.4, 1.5, 0.3],
    [9.0, 9.0, 9.0],
];

/// A stage: the cloud, a points prim holding [`POINTS`] and `light` (a UsdLux prim's text).
fn stage(dir: &Path, light: &str) -> PathBuf {
    let pts: Vec<String> = POINTS
        .iter()
        .map(|p| format!("({}, {}, {})", p[0], p[1], p[2]))
        .collect();
    let text = format!(
        "#usda 1.0\n\ndef Volume \"cloud\"\n{{\n    rel field:density = </cloud/density>\n\n    \
         def OpenVDBAsset \"density\"\n    {{\n        asset filePath = @{}@\n        \
         token fieldName = \"density\"\n    }}\n}}\n\n\
         def Points \"pts\"\n{{\n    point3f[] points = [{}]\n}}\n\n{light}\n",
        cloud().display(),
        pts.join(", ")
    );
    let p = dir.join("shot.usda");
    std::fs::write(&p, text).unwrap();
    p
}

/// A sun travelling along -Y (its -Z turned by -90 degrees about X).
const SUN: &str = "def DistantLight \"sun\"\n{\n    double3 xformOp:rotateXYZ = (-90, 0, 0)\n    \
                   uniform token[] xformOpOrder = [\"xformOp:rotateXYZ\"]\n}";
/// The sun traced as a point by the stage itself (its angle authored 0).
const SUN_POINT: &str = "def DistantLight \"sun\"\n{\n    float inputs:angle = 0\n    \
                         double3 xformOp:rotateXYZ = (-90, 0, 0)\n    \
                         uniform token[] xformOpOrder = [\"xformOp:rotateXYZ\"]\n}";
/// The sphere light traced as a point by the stage itself (its radius authored 0).
const LAMP_POINT: &str = "def SphereLight \"lamp\"\n{\n    float inputs:radius = 0\n    \
                          double3 xformOp:translate = (0, 6, 0)\n    \
                          uniform token[] xformOpOrder = [\"xformOp:translate\"]\n}";
/// A sphere light at (0, 6, 0).
const LAMP: &str = "def SphereLight \"lamp\"\n{\n    double3 xformOp:translate = (0, 6, 0)\n    \
                    uniform token[] xformOpOrder = [\"xformOp:translate\"]\n}";

fn read() -> SourceOptions {
    SourceOptions {
        density_scale: 4.0,
        ..SourceOptions::default()
    }
}

fn extent(angle: Option<f64>, radius: Option<f64>, samples: Option<u32>) -> LightOptions {
    LightOptions {
        light_angle: angle,
        light_radius: radius,
        light_samples: samples,
        ..LightOptions::default()
    }
}

fn positions(stage: &Path, light: LightOptions, est: &str, threads: usize) -> PointAnswers {
    let r = QueryRequest {
        positions: Some("/pts".into()),
        light,
        estimator: EstimatorOptions {
            estimator: est.into(),
            samples: 2,
            seed: 7,
            ..EstimatorOptions::default()
        },
        threads,
        ..QueryRequest::new(Source::new(stage, read()))
    };
    match r.run(&mut |_| {}).unwrap() {
        QueryOutcome::Points(p) => p.answers,
        QueryOutcome::Rays(_) => panic!("a positions query answered rays"),
    }
}

/// `query --at` at `at` toward the stage light (or `given`'s light) with ray id `id`:
/// `(T, std_err, light_samples)`.
fn at(stage: &Path, at: [f64; 3], light: LightOptions, est: &str, id: u64) -> (f64, f64, usize) {
    let r = QueryRequest {
        at: Some(at),
        light,
        ray_id: id,
        estimator: EstimatorOptions {
            estimator: est.into(),
            samples: 2,
            seed: 7,
            ..EstimatorOptions::default()
        },
        ..QueryRequest::new(Source::new(stage, read()))
    };
    let a = crate::common::one_answer(&r);
    (
        a.estimate.value[0],
        a.estimate.std_err[0],
        a.light_samples.unwrap(),
    )
}

#[test]
fn each_point_is_query_at_that_point_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    for (light, keys) in [
        (SUN, extent(Some(8.0), None, Some(64))),
        (LAMP, extent(None, Some(1.0), Some(64))),
    ] {
        let shot = stage(dir.path(), light);
        for est in ["regular", "ratio"] {
            let all = positions(&shot, keys.clone(), est, 0);
            assert_eq!(all.light_samples, Some(64));
            let f = &all.frames[0];
            assert_eq!(f.transmittance.len(), POINTS.len());
            // The points as the stage holds them (point3f: f32 positions).
            for (i, p) in f.positions.iter().enumerate() {
                let (t, e, _) = at(&shot, *p, keys.clone(), est, i as u64);
                assert_eq!(
                    (t.to_bits(), e.to_bits()),
                    (f.transmittance[i].to_bits(), f.std_err[i].to_bits()),
                    "{light} {est} point {i}"
                );
            }
            // The penumbra point is soft: between 0 and 1, with an error bar.
            assert!(f.std_err[0] > 0.0 && f.transmittance[0] < 1.0, "{f:?}");
            // The same answers whatever the thread count.
            assert_eq!(positions(&shot, keys.clone(), est, 1), all, "{light} {est}");
        }
    }
    // Toward the stage sun given by its direction: the same answers (no shadow links here).
    let shot = stage(dir.path(), SUN);
    let all = positions(&shot, extent(Some(8.0), None, Some(64)), "regular", 2);
    let sun = umbra::usd::lights_at(&shot, None).unwrap();
    let (_, e) = sun.light(None).unwrap();
    let dir_ = umbra::Light::from(e).direction().unwrap();
    let given = LightOptions {
        light_dir: Some(dir_),
        ..extent(Some(8.0), None, Some(64))
    };
    let (t, _, _) = at(&shot, all.frames[0].positions[0], given, "regular", 0);
    assert_eq!(t.to_bits(), all.frames[0].transmittance[0].to_bits());
}

/// Zero extent from the flags is the stage light authored as a point, exactly; without a
/// flag the stage light's own extent applies (the fallbacks: a sun 0.53 degrees across, a
/// sphere of radius 0.5), as for a query at a point.
#[test]
fn zero_extent_is_the_point_lights_answer_exactly() {
    let dir = tempfile::tempdir().unwrap();
    for (light, point, zero) in [
        (SUN, SUN_POINT, extent(Some(0.0), None, Some(64))),
        (LAMP, LAMP_POINT, extent(None, Some(0.0), None)),
    ] {
        let hard = positions(
            &stage(dir.path(), point),
            LightOptions::default(),
            "regular",
            0,
        );
        assert_eq!(hard.light_samples, None);
        assert_eq!(hard.frames[0].sampled, None);
        let shot = stage(dir.path(), light);
        assert_eq!(positions(&shot, zero, "regular", 0), hard, "{light}");
        // The stage's own extent, and each point as a query at it toward the stage light.
        let own = positions(&shot, LightOptions::default(), "regular", 0);
        assert_eq!(own.light_samples, Some(16384), "{light}");
        assert!(own.frames[0].std_err[0] > 0.0, "{light}");
        let f = &own.frames[0];
        for (i, p) in f.positions.iter().enumerate() {
            let (t, e, _) = at(&shot, *p, LightOptions::default(), "regular", i as u64);
            assert_eq!((t, e), (f.transmittance[i], f.std_err[i]), "{light} {i}");
        }
    }
}

#[test]
fn a_key_for_the_other_kind_of_light_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    for (light, keys, name) in [
        (SUN, extent(None, Some(1.0), None), "light-radius"),
        (LAMP, extent(Some(2.0), None, None), "light-angle"),
    ] {
        let shot = stage(dir.path(), light);
        let r = QueryRequest {
            positions: Some("/pts".into()),
            light: keys.clone(),
            ..QueryRequest::new(Source::new(&shot, read()))
        };
        let e = r.run(&mut |_| {}).unwrap_err().error;
        assert!(
            matches!(&e, Error::InvalidArgument { name: n, .. } if n == name),
            "{light}: {e}"
        );
        // The same at a point toward the stage light.
        let r = QueryRequest {
            at: Some(POINTS[0]),
            light: keys,
            ..QueryRequest::new(Source::new(&shot, read()))
        };
        let e = r.run(&mut |_| {}).unwrap_err().error;
        assert!(
            matches!(&e, Error::InvalidArgument { name: n, .. } if n == name),
            "{light}: {e}"
        );
    }
    // Bad values before the stage is read: by name.
    let shot = stage(dir.path(), SUN);
    for (keys, name) in [
        (extent(Some(-1.0), None, None), "light-angle"),
        (extent(Some(f64::NAN), None, None), "light-angle"),
        (extent(Some(180.0), None, None), "light-angle"),
        (extent(None, Some(f64::INFINITY), None), "light-radius"),
        (extent(Some(1.0), None, Some(0)), "light-samples"),
    ] {
        let r = QueryRequest {
            positions: Some("/pts".into()),
            light: keys,
            ..QueryRequest::new(Source::new(&shot, read()))
        };
        let e = r.check().unwrap_err();
        assert!(
            matches!(&e, Error::InvalidArgument { name: n, .. } if n == name),
            "{name}: {e}"
        );
    }
    // Directions without an extent: the stage light's own (the sun's 0.53 degree fallback).
    let a = positions(&shot, extent(None, None, Some(64)), "regular", 0);
    assert_eq!(a.light_samples, Some(64));
    let e = QueryRequest {
        positions: Some("/pts".into()),
        light: extent(Some(1.0), Some(1.0), None),
        ..QueryRequest::new(Source::new(&shot, read()))
    }
    .check()
    .unwrap_err();
    assert!(matches!(e, Error::Conflict { .. }), "{e}");
}

#[test]
fn extreme_lights_are_answered() {
    let dir = tempfile::tempdir().unwrap();
    let sun = stage(dir.path(), SUN);
    for keys in [
        extent(Some(8.0), None, Some(64)),
        extent(Some(179.9), None, Some(64)),
        extent(Some(1e-9), None, Some(64)),
    ] {
        let a = positions(&sun, keys.clone(), "regular", 0);
        for (t, e) in a.frames[0].transmittance.iter().zip(&a.frames[0].std_err) {
            assert!(
                (0.0..=1.0).contains(t) && e.is_finite() && *e >= 0.0,
                "{keys:?}: {a:?}"
            );
        }
    }
    // The far receiver under a narrow sun: its cone misses the cloud, T = 1 unsampled.
    let a = positions(&sun, extent(Some(1.0), None, Some(64)), "regular", 0);
    let f = &a.frames[0];
    assert_eq!((f.transmittance[4], f.std_err[4]), (1.0, 0.0));
    // And one near receiver whose cone passes between the cloud's voxels is proven clear too.
    assert_eq!(f.sampled, Some(POINTS.len() - 2));
    let lamp = stage(dir.path(), LAMP);
    for keys in [
        // Every receiver inside the sphere.
        extent(None, Some(20.0), Some(64)),
        extent(None, Some(1e300), Some(64)),
        extent(None, Some(1.0), Some(64)),
    ] {
        let a = positions(&lamp, keys.clone(), "regular", 0);
        for (t, e) in a.frames[0].transmittance.iter().zip(&a.frames[0].std_err) {
            assert!((0.0..=1.0).contains(t) && e.is_finite(), "{keys:?}: {a:?}");
        }
    }
}

/// A transmittance volume toward a sun with an angle: voxel `k` in output order holds
/// `query --at` at its centre with ray id `k`, rounded to f32, bit for bit; zero extent
/// holds the point light's values.
#[test]
fn a_voxel_holds_query_at_its_centre() {
    use umbra::request::{BakeOptions, BakePlan, BakeRequest};
    let plan = |keys: LightOptions| {
        let r = BakeRequest {
            input: cloud(),
            output: "t.vdb".into(),
            options: BakeOptions {
                light: LightOptions {
                    light_dir: Some([0.3, -1.0, 0.2]),
                    ..keys
                },
                source: read(),
                ..BakeOptions::default()
            },
        };
        let BakePlan::Volume(job) = r.plan().unwrap() else {
            panic!("a .vdb output is a transmittance volume")
        };
        job
    };
    let soft = plan(extent(Some(8.0), None, Some(64)));
    let vol = soft.load().unwrap();
    let (leaves, stats) = soft.leaves(&vol, &|_| {}).unwrap();
    assert_eq!(stats.light_samples, Some(64));
    assert_eq!(stats.sampled_fraction, Some(1.0));
    let mut k = 0u64;
    let mut checked = 0;
    for l in &leaves {
        for n in 0..512usize {
            if l.active[n / 64] >> (n % 64) & 1 == 0 {
                continue;
            }
            if k.is_multiple_of(4099) {
                let ijk = [
                    l.origin[0] + (n >> 6) as i32,
                    l.origin[1] + ((n >> 3) & 7) as i32,
                    l.origin[2] + (n & 7) as i32,
                ];
                let c = vol.to_world(glam::DVec3::from_array(ijk.map(f64::from)));
                let keys = LightOptions {
                    light_dir: Some([0.3, -1.0, 0.2]),
                    ..extent(Some(8.0), None, Some(64))
                };
                let r = QueryRequest {
                    at: Some(c.to_array()),
                    light: keys,
                    ray_id: k,
                    ..QueryRequest::new(Source::new(cloud(), read()))
                };
                let QueryOutcome::Rays(a) = r.run(&mut |_| {}).unwrap() else {
                    panic!("rays")
                };
                let t = a.answers[0].result.as_ref().unwrap().estimate.value[0];
                assert_eq!(
                    (t as f32).to_bits(),
                    l.values[n].to_bits(),
                    "voxel {k} {ijk:?}"
                );
                checked += 1;
            }
            k += 1;
        }
    }
    assert!(checked > 30, "{checked}");
    // Zero extent: the point light's job, values and all.
    let hard = plan(LightOptions::default());
    let zero = plan(extent(Some(0.0), None, Some(64)));
    assert_eq!(zero.soft, None);
    let (h, _) = hard.leaves(&vol, &|_| {}).unwrap();
    let (z, zs) = zero.leaves(&vol, &|_| {}).unwrap();
    assert!(h.iter().zip(&z).all(|(a, b)| a.values == b.values));
    assert_eq!(zs.light_samples, None);
}

/// A soft transmittance volume with a stochastic estimator: the same values on one thread and
/// on two (each voxel keyed by its ray id alone).
#[test]
fn a_soft_volume_ignores_the_thread_count() {
    use umbra::request::{BakeOptions, BakePlan, BakeRequest};
    let job = |threads: usize| {
        let r = BakeRequest {
            input: cloud(),
            output: "t.vdb".into(),
            options: BakeOptions {
                light: LightOptions {
                    light_pos: Some([0.0, 6.0, 0.0]),
                    ..extent(None, Some(1.0), Some(64))
                },
                source: read(),
                estimator: EstimatorOptions {
                    estimator: "ratio".into(),
                    samples: 2,
                    seed: 9,
                    ..EstimatorOptions::default()
                },
                threads,
                ..BakeOptions::default()
            },
        };
        let BakePlan::Volume(job) = r.plan().unwrap() else {
            panic!("a .vdb output is a transmittance volume")
        };
        job
    };
    let (one, two) = (job(1), job(2));
    let vol = one.load().unwrap();
    let (a, sa) = one.leaves(&vol, &|_| {}).unwrap();
    let (b, sb) = two.leaves(&vol, &|_| {}).unwrap();
    assert!(a.iter().zip(&b).all(|(x, y)| x.values == y.values));
    assert_eq!(sa.std_err_max, sb.std_err_max);
    assert!(sa.std_err_max.unwrap() > 0.0);
}

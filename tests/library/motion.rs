//! Motion blur (`Volume::with_motion`): a constant velocity is a translation, so the blurred
//! answer is the shutter mean of exact answers of the shifted volume; zero velocity and a
//! zero shutter give the still answer bit for bit; unbiased estimators land within a few
//! standard errors and never meet a majorant violation although the density crosses blocks;
//! `regular` is refused.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use glam::DVec3;
use umbra::estimate::{estimate, Estimator, Options};
use umbra::internals::tree::{Tree, TreeBuilder};
use umbra::regular::optical_depth;
use umbra::volume::{MotionSpec, VelocityField};
use umbra::{Interp, Ray, Volume};

const VOXEL: f64 = 0.5;

fn rows(shift: [f64; 3]) -> [[f64; 4]; 3] {
    [
        [VOXEL, 0.0, 0.0, shift[0]],
        [0.0, VOXEL, 0.0, shift[1]],
        [0.0, 0.0, VOXEL, shift[2]],
    ]
}

/// A Gaussian puff of radius ~5 voxels at voxel (20, 22, 18), with a denser core off centre.
fn puff() -> Tree {
    let mut b = TreeBuilder::new(0.0);
    for x in 0..44 {
        for y in 0..44 {
            for z in 0..40 {
                let r2 = ((x - 20) * (x - 20) + (y - 22) * (y - 22) + (z - 18) * (z - 18)) as f32;
                let core = ((x - 23) * (x - 23) + (y - 20) * (y - 20) + (z - 18) * (z - 18)) as f32;
                let v = 1.5 * (-r2 / 50.0).exp() + 3.0 * (-core / 6.0).exp();
                if v > 1e-4 {
                    b.set([x, y, z], v);
                }
            }
        }
    }
    b.build()
}

fn volume(shift: [f64; 3]) -> Volume {
    Volume::from_tree("density".into(), puff(), rows(shift), 0.12).unwrap()
}

/// A velocity of `v` world units per second everywhere (the background of three empty trees).
fn constant(v: [f32; 3]) -> VelocityField {
    let comps = v.map(|c| TreeBuilder::new(c).build());
    VelocityField::new("vel".into(), comps, rows([0.0; 3]), false, false).unwrap()
}

fn rays() -> Vec<Ray> {
    let c = DVec3::new(10.5, 10.7, 9.0);
    [
        DVec3::new(0.0, 1.0, 0.0),
        DVec3::new(0.0, 0.2, 1.0),
        DVec3::new(1.0, 0.0, 0.0),
        DVec3::new(0.7, 0.5, -0.4),
    ]
    .iter()
    .enumerate()
    .map(|(i, d)| {
        let d = d.normalize();
        let o = c + DVec3::new(0.4 * i as f64 - 0.6, 0.3, -0.5) - d * 30.0;
        Ray::new(o, d, 0.0, 60.0).unwrap()
    })
    .collect()
}

/// The shutter mean of exact transmittance through the volume translated by `v t / F`:
/// 400 midpoints of the shutter (the answer is smooth in `t`).
fn translated_mean(ray: &Ray, v: [f64; 3], spec: &MotionSpec) -> f64 {
    let n = 400;
    (0..n)
        .map(|i| {
            let t = spec.time_at((i as f64 + 0.5) / n as f64);
            let k = spec.displacement_per_velocity(t);
            let moved = volume(v.map(|c| c * k));
            optical_depth(&moved, ray, Interp::Trilinear)
                .unwrap()
                .transmittance()
        })
        .sum::<f64>()
        / n as f64
}

fn opts(samples: u32) -> Options {
    Options {
        interp: Interp::Trilinear,
        samples,
        seed: 7,
        ..Options::default()
    }
}

#[test]
fn a_constant_velocity_is_a_translation() {
    // 120 world units per second over a shutter of [-0.5, 0.75] frames at 24 fps: the puff
    // moves from -2.5 to +3.75 world units along x (-5 to +7.5 voxels), across blocks.
    let v = [120.0, 30.0, 0.0];
    let spec = MotionSpec::new([-0.5, 0.75], 24.0, 1.0, 64).unwrap();
    let vol = volume([0.0; 3])
        .with_motion(spec, constant(v.map(|c| c as f32)))
        .unwrap();
    let still = volume([0.0; 3]);
    let mut moved_somewhere = false;
    for (i, ray) in rays().iter().enumerate() {
        let want = translated_mean(ray, v, &spec);
        let still_t = optical_depth(&still, ray, Interp::Trilinear)
            .unwrap()
            .transmittance();
        moved_somewhere |= (want - still_t).abs() > 0.05;
        eprintln!("ray {i}: blurred {want} still {still_t}");
        let riemann = Estimator::with_params("riemann", &[("step", 0.25)]).unwrap();
        let e = estimate(&vol, ray, i as u64, &riemann, &opts(1)).unwrap();
        assert!(
            (e.value - want).abs() < 2e-3,
            "riemann ray {i}: {} vs {want} (still {still_t})",
            e.value
        );
        for name in [
            "ratio",
            "track-length",
            "residual-ratio",
            "next-flight",
            "decomposition",
            "unbiased-raymarch",
        ] {
            let est = Estimator::from_name(name).unwrap();
            let e = estimate(&vol, ray, i as u64, &est, &opts(4000)).unwrap();
            assert_eq!(e.majorant_violations, 0, "{name} ray {i}");
            assert!(
                (e.value - want).abs() < 4.0 * e.std_err + 1e-6,
                "{name} ray {i}: {} +- {} vs {want}",
                e.value,
                e.std_err
            );
        }
        for name in ["mc", "jittered"] {
            let est = Estimator::with_params(name, &[("step", 0.25)]).unwrap();
            // Biased upward by Jensen's inequality: a few 1e-3 at this step.
            let e = estimate(&vol, ray, i as u64, &est, &opts(64)).unwrap();
            assert!(
                (e.value - want).abs() < 4.0 * e.std_err + 3e-3,
                "{name} ray {i}: {} +- {} vs {want}",
                e.value,
                e.std_err
            );
        }
    }
    assert!(moved_somewhere, "the test must blur something");
}

#[test]
fn zero_velocity_or_a_zero_shutter_is_the_still_answer() {
    let still = volume([0.0; 3]);
    let zero_v = volume([0.0; 3])
        .with_motion(
            MotionSpec::new([-0.5, 0.5], 24.0, 1.0, 8).unwrap(),
            constant([0.0; 3]),
        )
        .unwrap();
    let zero_shutter = volume([0.0; 3])
        .with_motion(
            MotionSpec::new([0.0, 0.0], 24.0, 1.0, 8).unwrap(),
            constant([40.0, 0.0, 0.0]),
        )
        .unwrap();
    for (i, ray) in rays().iter().enumerate() {
        for name in ["riemann", "ratio", "residual-ratio"] {
            let est = Estimator::from_name(name).unwrap();
            let a = estimate(&still, ray, i as u64, &est, &opts(64)).unwrap();
            for vol in [&zero_v, &zero_shutter] {
                let b = estimate(vol, ray, i as u64, &est, &opts(64)).unwrap();
                assert_eq!(a.value.to_bits(), b.value.to_bits(), "{name} ray {i}");
            }
        }
    }
}

#[test]
fn regular_is_refused_with_a_velocity() {
    let vol = volume([0.0; 3])
        .with_motion(
            MotionSpec::new([0.0, 1.0], 24.0, 1.0, 8).unwrap(),
            constant([10.0, 0.0, 0.0]),
        )
        .unwrap();
    let err = estimate(&vol, &rays()[0], 0, &Estimator::REGULAR, &opts(1)).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("estimator") && msg.contains("riemann"),
        "{msg}"
    );
}

#[test]
fn a_swirl_moves_density_across_blocks_without_majorant_violations() {
    // Rotation about the z axis through the puff's centre: v = w (-(y - cy), x - cx, 0),
    // sampled per voxel, so the density near the rim moves several voxels over the shutter.
    let (cx, cy) = (20.0f32, 22.0f32);
    let w = 2.0f32;
    let comps: [Tree; 3] = [0, 1, 2].map(|k| {
        let mut b = TreeBuilder::new(0.0);
        for x in -8..52 {
            for y in -8..52 {
                for z in 0..40 {
                    let (px, py) = (x as f32 * VOXEL as f32, y as f32 * VOXEL as f32);
                    let (ox, oy) = (cx * VOXEL as f32, cy * VOXEL as f32);
                    let v = match k {
                        0 => -w * (py - oy),
                        1 => w * (px - ox),
                        _ => 0.0,
                    };
                    b.set([x, y, z], v * 24.0 / 4.0);
                }
            }
        }
        b.build()
    });
    let field = VelocityField::new("vel".into(), comps, rows([0.0; 3]), false, false).unwrap();
    let spec = MotionSpec::new([-1.0, 1.0], 24.0, 1.0, 32).unwrap();
    let vol = volume([0.0; 3]).with_motion(spec, field).unwrap();
    let riemann = Estimator::with_params("riemann", &[("step", 0.125)]).unwrap();
    for (i, ray) in rays().iter().enumerate() {
        let reference = estimate(&vol, ray, i as u64, &riemann, &opts(1)).unwrap();
        for name in ["ratio", "track-length", "next-flight", "decomposition"] {
            let est = Estimator::from_name(name).unwrap();
            let e = estimate(&vol, ray, 100 + i as u64, &est, &opts(3000)).unwrap();
            assert_eq!(e.majorant_violations, 0, "{name} ray {i}");
            assert!(
                (e.value - reference.value).abs() < 4.0 * e.std_err + 3e-3,
                "{name} ray {i}: {} +- {} vs {}",
                e.value,
                e.std_err,
                reference.value
            );
        }
    }
}

/// Swirling and staggered velocity files written by OpenVDB against the independent NumPy
/// march of `tests/motion/make_reference.py` (module docs there): `riemann` at a tenth of a
/// voxel with 64 stratified times within 2e-3, ratio tracking within four standard errors,
/// no majorant violation; the still answers differ from the blurred ones by far more.
#[test]
fn swirling_and_staggered_files_match_an_independent_numpy_march() {
    if !crate::common::oracle_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let script =
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/motion/make_reference.py");
    let o = std::process::Command::new("/usr/bin/python3")
        .arg(script)
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let reference: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("reference.json")).unwrap())
            .unwrap();
    let num = |v: &serde_json::Value| v.as_f64().unwrap();
    let shutter = reference["shutter"].as_array().unwrap();
    let spec = MotionSpec::new(
        [num(&shutter[0]), num(&shutter[1])],
        num(&reference["fps"]),
        num(&reference["scale"]),
        64,
    )
    .unwrap();
    let request = umbra::internals::motion::MotionRequest {
        velocity: "vel".into(),
        spec,
        file: None,
        fps_given: true,
    };
    let riemann = Estimator::with_params("riemann", &[("step", 0.1)]).unwrap();
    let ratio = Estimator::from_name("ratio").unwrap();
    let mut blur_seen = 0.0f64;
    for (name, rays) in reference["files"].as_object().unwrap() {
        let path = dir.path().join(name);
        let field = request.field(&path).unwrap();
        assert_eq!(field.is_staggered(), name == "staggered.vdb");
        let mut lookup = field.lookup();
        for p in reference["probes"].as_array().unwrap() {
            let p: Vec<f64> = p.as_array().unwrap().iter().map(num).collect();
            let got = lookup.at(DVec3::new(p[0], p[1], p[2]));
            let want = DVec3::new(p[3], p[4], p[5]);
            assert!(
                (got - want).length() < 1e-3 * want.length().max(1.0),
                "{name}: velocity {got} vs analytic {want}"
            );
        }
        let vol = Volume::load(&path, "density", num(&reference["density_scale"]))
            .unwrap()
            .with_motion(spec, field)
            .unwrap();
        for (i, r) in rays.as_array().unwrap().iter().enumerate() {
            let v3 = |k: &str| {
                let a = r[k].as_array().unwrap();
                DVec3::new(num(&a[0]), num(&a[1]), num(&a[2]))
            };
            let ray = Ray::new(v3("origin"), v3("dir"), 0.0, num(&r["length"])).unwrap();
            let want = num(&r["T"]);
            blur_seen = blur_seen.max((want - num(&r["still"])).abs());
            let e = estimate(&vol, &ray, i as u64, &riemann, &opts(1)).unwrap();
            assert!(
                (e.value - want).abs() < 2e-3,
                "{name} ray {i}: riemann {} vs numpy {want}",
                e.value
            );
            let e = estimate(&vol, &ray, i as u64, &ratio, &opts(20_000)).unwrap();
            assert_eq!(e.majorant_violations, 0, "{name} ray {i}");
            assert!(
                (e.value - want).abs() < 4.0 * e.std_err + 1e-3,
                "{name} ray {i}: ratio {} +- {} vs numpy {want}",
                e.value,
                e.std_err
            );
        }
    }
    assert!(blur_seen > 0.05, "the reference must blur: {blur_seen}");
}

#[test]
fn non_finite_velocities_are_zeroed_counted_and_warned_about() {
    let mut b = TreeBuilder::new(0.0);
    b.set([20, 22, 18], f32::NAN)
        .set([21, 22, 18], f32::INFINITY);
    let x = b.build();
    let comps = [
        x,
        TreeBuilder::new(0.0).build(),
        TreeBuilder::new(0.0).build(),
    ];
    let field = VelocityField::new("vel".into(), comps, rows([0.0; 3]), false, false);
    // The components must share a topology: the x component has a leaf the others lack.
    assert!(field.unwrap_err().to_string().contains("topology"));
    let mut b = TreeBuilder::new(0.0);
    b.set([20, 22, 18], f32::NAN)
        .set([21, 22, 18], f32::INFINITY);
    let t = b.build();
    let field = VelocityField::new(
        "vel".into(),
        [t.clone(), t.clone(), t],
        rows([0.0; 3]),
        false,
        false,
    )
    .unwrap();
    let vol = volume([0.0; 3])
        .with_motion(MotionSpec::new([-1.0, 1.0], 24.0, 1.0, 4).unwrap(), field)
        .unwrap();
    let w = umbra::bake::velocity_warnings(&vol)
        .into_iter()
        .next()
        .unwrap();
    assert_eq!(
        w.to_string(),
        "velocity grid 'vel': 6 NaN or infinite components read as 0"
    );
    let e = estimate(
        &vol,
        &rays()[0],
        0,
        &Estimator::from_name("ratio").unwrap(),
        &opts(8),
    );
    assert!(e.unwrap().value.is_finite());
}

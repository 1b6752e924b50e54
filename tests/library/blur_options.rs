//! Every option under blur is honoured or refused by name (issue 58): the blurred bounds carry
//! a minorant, so `residual-ratio` and `decomposition` keep their control (they no longer
//! answer bit for bit as `ratio` and `track-length`, and residual ratio tracking takes fewer
//! lookups inside a dense moving box), `global_majorant` swaps the per-block bounds for one, and both
//! stay within a few standard errors of the translated truth; a coarser granularity and time
//! samples for a null-collision estimator are refused.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use glam::DVec3;
use umbra::estimate::{estimate, Estimator, Options};
use umbra::internals::tree::TreeBuilder;
use umbra::regular::optical_depth;
use umbra::volume::{MotionSpec, VelocityField};
use umbra::{Interp, Ray, Volume};

const VOXEL: f64 = 0.5;

fn rows() -> [[f64; 4]; 3] {
    [
        [VOXEL, 0.0, 0.0, 0.0],
        [0.0, VOXEL, 0.0, 0.0],
        [0.0, 0.0, VOXEL, 0.0],
    ]
}

/// A 40^3 box of density 1 to 1.5 (a gentle ripple): its inner blocks keep a minorant near 1
/// however the box moves within the reach.
fn dense_box() -> Volume {
    let mut b = TreeBuilder::new(0.0);
    for x in 0..40 {
        for y in 0..40 {
            for z in 0..40 {
                let v = 1.0 + 0.25 * (1.0 + (0.4 * f64::from(x + 2 * y - z)).sin());
                b.set([x, y, z], v as f32);
            }
        }
    }
    Volume::from_tree("density".into(), b.build(), rows(), 0.06).unwrap()
}

fn constant(v: [f32; 3]) -> VelocityField {
    let comps = v.map(|c| TreeBuilder::new(c).build());
    VelocityField::new("vel".into(), comps, rows(), false, false).unwrap()
}

/// The shutter mean of exact T through the box translated by `v t / F` (the ray translated
/// back), 400 midpoints of the shutter.
fn truth(still: &Volume, r: &Ray, v: DVec3, spec: &MotionSpec) -> f64 {
    let n = 400;
    (0..n)
        .map(|i| {
            let t = spec.time_at((f64::from(i) + 0.5) / f64::from(n));
            let o = r.origin() - v * spec.displacement_per_velocity(t);
            let moved = Ray::new(o.to_array(), r.direction().to_array(), r.t_min(), r.t_max());
            optical_depth(still, &moved.unwrap(), Interp::Trilinear)
                .unwrap()
                .transmittance()
        })
        .sum::<f64>()
        / f64::from(n)
}

#[test]
fn minorant_controls_and_the_global_majorant_hold_under_blur() {
    // 24 units/s over [-0.5, 0.5] frames at 24 fps: the box moves 1 unit (2 voxels).
    let v = DVec3::new(24.0, 0.0, 12.0);
    let spec = MotionSpec::new([-0.5, 0.5], 24.0, 1.0, 8).unwrap();
    let still = dense_box();
    let vol = dense_box()
        .with_motion(spec, constant(v.as_vec3().to_array()))
        .unwrap();
    let rays: Vec<Ray> = (0..6)
        .map(|i| {
            let f = f64::from(i);
            let a = DVec3::new(-3.0, 4.0 + 2.0 * f, 5.0 + f);
            let b = DVec3::new(23.0, 14.0 - f, 9.0 + 0.5 * f);
            Ray::between(a.to_array(), b.to_array()).unwrap()
        })
        .collect();
    let opts = |global| Options {
        interp: Interp::Trilinear,
        samples: 4000,
        seed: 11,
        global_majorant: global,
        ..Options::default()
    };
    let (mut residual_lookups, mut ratio_lookups) = (0u64, 0u64);
    for (i, r) in rays.iter().enumerate() {
        let want = truth(&still, r, v, &spec);
        assert!(want > 0.01 && want < 0.9, "ray {i}: T {want} tests little");
        let mut by_name = std::collections::HashMap::new();
        for global in [false, true] {
            for name in ["ratio", "residual-ratio", "track-length", "decomposition"] {
                let est = Estimator::from_name(name).unwrap();
                let e = estimate(&vol, r, i as u64, &est, &opts(global)).unwrap();
                assert_eq!(e.majorant_violations, 0, "{name} global {global} ray {i}");
                assert!(
                    (e.value - want).abs() < 4.0 * e.std_err,
                    "{name} global {global} ray {i}: {} +- {} vs {want}",
                    e.value,
                    e.std_err
                );
                by_name.insert((name, global), e);
            }
        }
        let get = |n, g| &by_name[&(n, g)];
        assert_ne!(
            get("residual-ratio", false).value,
            get("ratio", false).value
        );
        assert_ne!(
            get("decomposition", false).value,
            get("track-length", false).value
        );
        // One bound for the whole grid: one segment, another answer.
        let (g, b) = (get("ratio", true), get("ratio", false));
        assert_ne!(g.value, b.value, "ray {i}");
        assert!(g.segments == 1 && b.segments > 1, "ray {i}: {g:?} {b:?}");
        residual_lookups += get("residual-ratio", false).lookups;
        ratio_lookups += get("ratio", false).lookups;
    }
    // The minorant is taken in closed form: residual ratio tracking walks only the residual.
    assert!(
        10 * residual_lookups < 8 * ratio_lookups,
        "residual-ratio {residual_lookups} vs ratio {ratio_lookups}"
    );
}

#[test]
fn options_that_blur_cannot_take_are_refused_by_name() {
    let with = |json: &str| {
        let o = umbra::request::TraceOptions::from_json(json).unwrap();
        o.estimator.motion(&o.source).map(|_| ())
    };
    let name = |r: Result<(), umbra::Error>| match r {
        Err(umbra::Error::InvalidArgument { name, .. }) => name,
        other => panic!("{other:?}"),
    };
    assert_eq!(
        name(with(
            r#"{"velocity": "vel", "estimator": "ratio", "granularity": "lower"}"#
        )),
        "granularity"
    );
    assert_eq!(
        name(with(
            r#"{"velocity": "vel", "estimator": "ratio", "time_samples": 4}"#
        )),
        "time-samples"
    );
    assert!(with(r#"{"velocity": "vel", "estimator": "jittered", "time_samples": 4}"#).is_ok());
    assert!(with(r#"{"velocity": "vel", "estimator": "ratio", "global_majorant": true}"#).is_ok());
    // The refusal of `regular` names estimators that exist.
    let Err(umbra::Error::InvalidArgument { reason, .. }) = with(r#"{"velocity": "vel"}"#) else {
        panic!("regular must be refused");
    };
    let list = reason.split('(').nth(2).unwrap_or_default();
    let names: Vec<&str> = umbra::estimate::REGISTRY.iter().map(|s| s.name).collect();
    for word in list.split(':').next().unwrap_or_default().split(", ") {
        assert!(
            names.contains(&word),
            "'{word}' in {reason:?} is not an estimator"
        );
    }
}

//! Motion-blurred `riemann` maps in object order (`bake::trace::sweep::blur`) against the ray
//! path they replace: the same midpoints read the same way, so every pixel's `T` and error bar
//! agree to the order of the sums (T to 2 f32 ulps, the error bar to 1e-9 relative); the same
//! bits on 1 and 2 threads; a block moved too far for a window (reads through the accessors)
//! and one shutter time (unknown error bar) alike; maps the sweep does not take go by rays.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::bake_support::ortho;
use umbra::bake::{bake, BakeSettings, Camera, Depths, Map, Order, Projection, View};
use umbra::estimate::{Estimator, Options};
use umbra::internals::tree::{Tree, TreeBuilder};
use umbra::volume::{MotionSpec, VelocityField};
use umbra::Volume;

const VOXEL: f64 = 0.5;

fn rows() -> [[f64; 4]; 3] {
    [
        [VOXEL, 0.0, 0.0, 0.3],
        [0.0, VOXEL, 0.0, -1.1],
        [0.0, 0.0, VOXEL, 0.7],
    ]
}

/// A puff with a dense core and a hard-edged block, over several leaves.
fn density() -> Tree {
    let mut b = TreeBuilder::new(0.0);
    for x in 0..40 {
        for y in 0..44 {
            for z in 0..36 {
                let r2 = ((x - 20) * (x - 20) + (y - 22) * (y - 22) + (z - 18) * (z - 18)) as f32;
                let mut v = 1.5 * (-r2 / 60.0).exp();
                if (26..32).contains(&x) && (14..22).contains(&y) && (10..20).contains(&z) {
                    v += 2.0;
                }
                if v > 1e-4 {
                    b.set([x, y, z], v);
                }
            }
        }
    }
    b.build()
}

/// A swirl about z with an updraft, `spin` radians per second, per voxel of a grid that
/// covers the density and more; cell-centred or staggered.
fn swirl(spin: f32, staggered: bool) -> VelocityField {
    let comps: [Tree; 3] = [0, 1, 2].map(|k| {
        let mut b = TreeBuilder::new(0.0);
        for x in -8..48 {
            for y in -8..52 {
                for z in -4..40 {
                    let (px, py) = ((x - 20) as f32 * 0.5, (y - 22) as f32 * 0.5);
                    let v = match k {
                        0 => -spin * py,
                        1 => spin * px,
                        _ => 9.0,
                    };
                    b.set([x, y, z], v);
                }
            }
        }
        b.build()
    });
    VelocityField::new("vel".into(), comps, rows(), staggered, false).unwrap()
}

fn moving(spin: f32, staggered: bool, times: u32) -> Volume {
    let spec = MotionSpec::new([-0.5, 0.75], 24.0, 1.0, times).unwrap();
    Volume::from_tree("density".into(), density(), rows(), 0.3)
        .unwrap()
        .with_motion(spec, swirl(spin, staggered))
        .unwrap()
}

fn riemann(step: f64, order: Order, threads: usize) -> BakeSettings {
    BakeSettings {
        order,
        threads,
        std_err: true,
        ..BakeSettings::new(
            Estimator::with_params("riemann", &[("step", step)]).unwrap(),
            Options {
                seed: 17,
                ..Options::default()
            },
        )
    }
}

fn cameras(vol: &Volume) -> Vec<Camera> {
    let corners = vol.box_corners().unwrap();
    let mut out = Vec::new();
    for dir in [[0.3, -1.0, 0.45], [0.0, 0.0, -1.0], [-1.0, 0.2, 0.1]] {
        out.push(Camera::frame(&ortho(dir, 72, 60), &corners).unwrap());
    }
    let persp = View {
        projection: Projection::Perspective,
        light_dir: Some([0.4, -0.8, -0.3]),
        light_pos: Some([3.0, 40.0, 25.0]),
        fov_deg: None,
        res: Some(umbra::bake::Resolution::Exact(64, 48)),
        up: None,
        frame_box: None,
    };
    out.push(Camera::frame(&persp, &corners).unwrap());
    out
}

/// The sweep's map against the ray path's, pixel by pixel; the largest `|dT|`.
fn agree(a: &Map, r: &Map, what: &str) -> f32 {
    assert!(a.stats.sweep && !r.stats.sweep, "{what}: not swept");
    assert_eq!(a.stats.lookups, r.stats.lookups, "{what}: lookups");
    let (ea, er) = (a.std_err.as_ref().unwrap(), r.std_err.as_ref().unwrap());
    let mut worst = 0.0f32;
    for n in 0..a.t.len() {
        let d = (a.t[n] - r.t[n]).abs();
        assert!(
            d <= 2.0 * f32::EPSILON,
            "{what} pixel {n}: T {} vs {}",
            a.t[n],
            r.t[n]
        );
        worst = worst.max(d);
        let (x, y) = (ea[n], er[n]);
        assert!(
            (x.is_nan() && y.is_nan()) || (x - y).abs() <= 1e-6 * y.abs() + 1e-12,
            "{what} pixel {n}: std_err {x} vs {y}"
        );
    }
    worst
}

#[test]
fn blurred_riemann_maps_match_the_ray_path() {
    let mut dark = 0usize;
    for (spin, staggered, times, step) in [
        (3.0, false, 8, 1.0),
        (3.0, true, 4, 0.5),
        (5.0, false, 1, 0.75),
        // Density moved tens of voxels: windows too large, reads through the accessors.
        (90.0, false, 3, 1.0),
    ] {
        let vol = moving(spin, staggered, times);
        for (c, cam) in cameras(&vol).iter().enumerate() {
            let what = format!("spin {spin} staggered {staggered} times {times} camera {c}");
            let a = bake(&vol, cam, &riemann(step, Order::Auto, 2), &|_| {}).unwrap();
            let r = bake(&vol, cam, &riemann(step, Order::Rays, 2), &|_| {}).unwrap();
            agree(&a, &r, &what);
            dark += a.t.iter().filter(|&&t| t < 0.7).count();
            if times == 1 {
                assert!(
                    a.std_err.as_ref().unwrap().iter().any(|e| e.is_nan()),
                    "{what}"
                );
                // Some error bar unknown: the largest is unknown too, on both paths.
                assert!(
                    a.stats.max_std_err.is_nan() && r.stats.max_std_err.is_nan(),
                    "{what}"
                );
            } else {
                assert!(a.stats.max_std_err > 0.0, "{what}");
            }
            let one = bake(&vol, cam, &riemann(step, Order::Auto, 1), &|_| {}).unwrap();
            assert!(
                one.t
                    .iter()
                    .zip(&a.t)
                    .all(|(x, y)| x.to_bits() == y.to_bits()),
                "{what}: 1 and 2 threads differ"
            );
        }
    }
    assert!(
        dark > 1000,
        "the views must see the cloud: {dark} dark pixels"
    );
}

#[test]
fn blurred_maps_the_sweep_does_not_take_go_by_rays() {
    let vol = moving(3.0, false, 4);
    let cam = &cameras(&vol)[0];
    let slices = BakeSettings {
        depths: Depths::Slices(3),
        ..riemann(1.0, Order::Auto, 2)
    };
    assert!(!bake(&vol, cam, &slices, &|_| {}).unwrap().stats.sweep);
    let ratio = BakeSettings::new(Estimator::from_name("ratio").unwrap(), Options::default());
    assert!(!bake(&vol, cam, &ratio, &|_| {}).unwrap().stats.sweep);
    let global = riemann(1.0, Order::Auto, 2);
    let global = BakeSettings {
        options: Options {
            global_majorant: true,
            ..global.options
        },
        ..global
    };
    assert!(!bake(&vol, cam, &global, &|_| {}).unwrap().stats.sweep);
}

//! Exact regular tracking and the HDDA against analytic answers and brute force.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use proptest::prelude::*;
use std::ops::ControlFlow;
use umbra::internals::traverse::{dda, walk, Cells, Granularity, Segment};
use umbra::internals::tree::{Accessor, TreeBuilder};
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

fn scale_map(s: f64, t: [f64; 3]) -> [[f64; 4]; 3] {
    [
        [s, 0.0, 0.0, t[0]],
        [0.0, s, 0.0, t[1]],
        [0.0, 0.0, s, t[2]],
    ]
}

fn vol(b: &TreeBuilder, voxel: f64, scale: f64) -> Volume {
    Volume::from_tree("t".into(), b.build(), scale_map(voxel, [0.0; 3]), scale).unwrap()
}

fn tau(v: &Volume, r: &Ray, i: Interp) -> f64 {
    optical_depth(v, r, i).unwrap().tau
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-300) || (a - b).abs() < 1e-12
}

#[test]
fn homogeneous_box_axis_and_oblique() {
    // A 128^3 tile of value 2 at voxel size 0.1, mu = 0.5 * value: mu = 1 per world unit.
    let mut b = TreeBuilder::new(0.0);
    b.tile([0, 0, 0], 7, 2.0);
    let v = vol(&b, 0.1, 0.5);
    let r = Ray::between([-1.0, 6.4, 6.4], [20.0, 6.4, 6.4]).unwrap();
    // Nearest: voxels 0..127 own index x in [-0.5, 127.5): 12.8 world units.
    assert!(close(tau(&v, &r, Interp::Nearest), 12.8, 1e-12));
    // Trilinear: 127 interior + two unit ramps of mean 1 -> 256 value-units -> 12.8.
    assert!(close(tau(&v, &r, Interp::Trilinear), 12.8, 1e-12));
    // Oblique ray entirely inside the nearest region: tau = length.
    let r = Ray::between([1.0, 1.0, 1.0], [10.0, 7.0, 4.0]).unwrap();
    let len = (81.0f64 + 36.0 + 9.0).sqrt();
    assert!(close(tau(&v, &r, Interp::Nearest), len, 1e-12));
    assert!(close(tau(&v, &r, Interp::Trilinear), len, 1e-12));
    assert!(close(
        optical_depth(&v, &r, Interp::Nearest)
            .unwrap()
            .transmittance(),
        (-len).exp(),
        1e-12
    ));
    // A constant tile costs no lookups.
    assert_eq!(optical_depth(&v, &r, Interp::Nearest).unwrap().lookups, 0);
}

#[test]
fn two_voxel_step_nearest_and_trilinear() {
    let mut b = TreeBuilder::new(0.0);
    b.set([0, 0, 0], 1.0).set([1, 0, 0], 3.0);
    let v = vol(&b, 1.0, 1.0);
    let r = Ray::between([-5.0, 0.0, 0.0], [5.0, 0.0, 0.0]).unwrap();
    assert!(close(tau(&v, &r, Interp::Nearest), 4.0, 1e-12));
    // Piecewise linear 0 -> 1 -> 3 -> 0 over [-1, 2]: 0.5 + 2 + 1.5.
    assert!(close(tau(&v, &r, Interp::Trilinear), 4.0, 1e-12));
    // Reversed direction gives the same answer.
    let r = Ray::between([5.0, 0.0, 0.0], [-5.0, 0.0, 0.0]).unwrap();
    assert!(close(tau(&v, &r, Interp::Nearest), 4.0, 1e-12));
    assert!(close(tau(&v, &r, Interp::Trilinear), 4.0, 1e-12));
    // Half-way up the step: y = 0.25 lies in the same voxel row for nearest.
    let r = Ray::between([-5.0, 0.25, 0.0], [5.0, 0.25, 0.0]).unwrap();
    assert!(close(tau(&v, &r, Interp::Nearest), 4.0, 1e-12));
    assert!(close(tau(&v, &r, Interp::Trilinear), 3.0, 1e-12));
}

#[test]
fn linear_ramp_is_integrated_exactly_by_trilinear() {
    // v = 1 + 0.5 i over a 40^3 block; an interior oblique ray sees the linear field exactly.
    let mut b = TreeBuilder::new(0.0);
    for i in 0..40 {
        for j in 0..40 {
            for k in 0..40 {
                b.set([i, j, k], 1.0 + 0.5 * i as f32);
            }
        }
    }
    let v = vol(&b, 1.0, 1.0);
    let (a, e) = ([3.3, 4.1, 5.7], [30.2, 28.9, 33.3]);
    let r = Ray::between(a, e).unwrap();
    let len = r.t_max();
    let expect = len * (1.0 + 0.5 * 0.5 * (a[0] + e[0]));
    assert!(
        close(tau(&v, &r, Interp::Trilinear), expect, 1e-10),
        "{} vs {expect}",
        tau(&v, &r, Interp::Trilinear)
    );
}

#[test]
fn tile_only_region_and_nonzero_background() {
    let mut b = TreeBuilder::new(0.1);
    b.tile([8, 8, 8], 3, 1.0);
    let v = vol(&b, 1.0, 2.0);
    let r = Ray::between([0.0, 10.0, 10.0], [30.0, 10.0, 10.0]).unwrap();
    // 8 voxels of 1 and 22 units of background 0.1, all times scale 2.
    let bg = f64::from(0.1f32);
    let expect = 2.0 * (8.0 + bg * 22.0);
    let got = tau(&v, &r, Interp::Nearest);
    assert!(close(got, expect, 1e-12), "{got} vs {expect}");
    // Trilinear: ramps of half-height over one unit on each side -> same integral.
    assert!(close(tau(&v, &r, Interp::Trilinear), expect, 1e-12));
    // A ray that misses everything sees only the background.
    let r = Ray::between([0.0, 100.0, 0.0], [0.0, 100.0, 7.0]).unwrap();
    assert!(close(tau(&v, &r, Interp::Nearest), 2.0 * bg * 7.0, 1e-12));
    // Zero-length segment: T = 1 exactly.
    let r = Ray::between([10.0, 10.0, 10.0], [10.0, 10.0, 10.0]).unwrap();
    assert_eq!(
        optical_depth(&v, &r, Interp::Trilinear)
            .unwrap()
            .transmittance(),
        1.0
    );
}

#[test]
fn ray_on_a_negative_tie_plane_reads_what_point_sampler_reads() {
    // PointSampler rounds -2.5 to -3 (ties away from zero).
    let mut b = TreeBuilder::new(0.0);
    b.set([0, -3, 0], 1.0).set([0, -2, 0], 5.0);
    let v = vol(&b, 1.0, 1.0);
    let r = Ray::between([-4.0, -2.5, 0.0], [4.0, -2.5, 0.0]).unwrap();
    assert!(close(tau(&v, &r, Interp::Nearest), 1.0, 1e-12));
}

#[test]
fn huge_coordinates_and_rays_along_axes() {
    let mut b = TreeBuilder::new(0.0);
    let c = 1_500_000;
    b.set([c, -c, c], 2.0).set([c + 1, -c, c], 2.0);
    let v = vol(&b, 1.0, 1.0);
    let p = [c as f64, -c as f64, c as f64];
    let r = Ray::new([p[0] - 10.0, p[1], p[2]], [1.0, 0.0, -0.0], 0.0, 30.0).unwrap();
    assert!(close(tau(&v, &r, Interp::Nearest), 4.0, 1e-12));
    assert!(close(tau(&v, &r, Interp::Trilinear), 4.0, 1e-12));
    let r = Ray::new(
        [p[0], p[1] - 3.0, p[2]],
        [0.0, 1.0, 0.0],
        0.0,
        f64::INFINITY,
    )
    .unwrap();
    assert!(close(tau(&v, &r, Interp::Nearest), 2.0, 1e-12));
}

// ---- brute-force references, independent of the HDDA ----

/// Nearest: sum value * length over the unit cells of the whole ray, point lookups at the
/// middle of each piece.
fn brute_nearest(v: &Volume, r: &Ray) -> f64 {
    let q = v.to_index(r.origin()).to_array().map(|c| c + 0.5);
    let d = v.to_index_dir(r.direction()).to_array();
    let mut acc = Accessor::new(v.tree());
    let mut s = 0.0;
    let cells = Cells {
        size: 1.0,
        lo: [-1 << 40; 3],
        hi: [1 << 40; 3],
    };
    let _ = dda(q, d, (r.t_min(), r.t_max()), &cells, |_, a, b| {
        let m = 0.5 * (a + b);
        let p = [0, 1, 2].map(|k| v.to_index(r.origin()).to_array()[k] + d[k] * m);
        s += f64::from(acc.nearest(p)) * (b - a);
        ControlFlow::Continue(())
    });
    s * v.density_scale()
}

/// Trilinear: 5-point Gauss-Legendre per unit cell with OpenVDB-style BoxSampler lookups.
fn brute_trilinear(v: &Volume, r: &Ray) -> f64 {
    let o = v.to_index(r.origin()).to_array();
    let d = v.to_index_dir(r.direction()).to_array();
    let mut acc = Accessor::new(v.tree());
    let x = [
        0.0,
        -0.538_469_310_105_683,
        0.538_469_310_105_683,
        -0.906_179_845_938_664,
        0.906_179_845_938_664,
    ];
    let w = [
        0.568_888_888_888_889,
        0.478_628_670_499_366,
        0.478_628_670_499_366,
        0.236_926_885_056_189,
        0.236_926_885_056_189,
    ];
    let mut s = 0.0;
    let cells = Cells {
        size: 1.0,
        lo: [-1 << 40; 3],
        hi: [1 << 40; 3],
    };
    let _ = dda(o, d, (r.t_min(), r.t_max()), &cells, |_, a, b| {
        let (m, h) = (0.5 * (a + b), 0.5 * (b - a));
        for i in 0..5 {
            let t = m + h * x[i];
            let p = [0, 1, 2].map(|k| o[k] + d[k] * t);
            s += h * w[i] * f64::from(acc.trilinear(p));
        }
        ControlFlow::Continue(())
    });
    s * v.density_scale()
}

#[derive(Debug, Clone)]
struct Scene {
    bg: f32,
    voxels: Vec<([i32; 3], f32)>,
    tile: Option<([i32; 3], f32)>,
    origin: [f64; 3],
    dir: [f64; 3],
    len: f64,
}

fn scene() -> impl Strategy<Value = Scene> {
    (
        prop_oneof![Just(0.0f32), Just(0.3f32)],
        prop::collection::vec(([-20i32..20, -20i32..20, -20i32..20], 0.0f32..5.0), 1..60),
        prop::option::of(([-24i32..24, -24i32..24, -24i32..24], 0.0f32..3.0)),
        [-30.0f64..30.0, -30.0f64..30.0, -30.0f64..30.0],
        [-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0],
        0.0f64..90.0,
    )
        .prop_filter("direction", |s| {
            s.4.iter().map(|v| v * v).sum::<f64>() > 1e-3
        })
        .prop_map(|(bg, voxels, tile, origin, dir, len)| Scene {
            bg,
            voxels,
            tile,
            origin,
            dir,
            len,
        })
}

fn build(s: &Scene) -> Volume {
    let mut b = TreeBuilder::new(s.bg);
    if let Some((o, v)) = s.tile {
        b.tile(o, 3, v);
    }
    for &(ijk, v) in &s.voxels {
        b.set(ijk, v);
    }
    Volume::from_tree("p".into(), b.build(), scale_map(0.7, [0.3, -0.2, 0.1]), 1.3).unwrap()
}

fn check_segments(
    v: &Volume,
    r: &Ray,
    interp: Interp,
    gran: Granularity,
) -> Result<(), TestCaseError> {
    let mut segs: Vec<Segment> = Vec::new();
    let w = walk(v, r, interp, gran, |s| {
        segs.push(s);
        ControlFlow::Continue(())
    });
    let mut prev = r.t_min();
    let mut acc = Accessor::new(v.tree());
    let o = v.to_index(r.origin()).to_array();
    let d = v.to_index_dir(r.direction()).to_array();
    let mu = |acc: &mut Accessor<'_>, t: f64| {
        let p = [0, 1, 2].map(|k| o[k] + d[k] * t);
        let x = match interp {
            Interp::Nearest => acc.nearest(p),
            Interp::Trilinear => acc.trilinear(p),
        };
        v.density_scale() * f64::from(x)
    };
    let mu_bg = v.mu_background();
    for s in &segs {
        prop_assert!(
            s.t_min >= prev && s.t_max > s.t_min && s.t_max <= r.t_max(),
            "order {s:?} after {prev}"
        );
        // Gap before this segment has the background density.
        for k in 1..4 {
            let t = prev + (s.t_min - prev) * f64::from(k) / 4.0;
            if s.t_min - prev > 1e-9 {
                prop_assert!(
                    close(mu(&mut acc, t), mu_bg, 1e-6),
                    "gap at t={t} mu={} bg={mu_bg}",
                    mu(&mut acc, t)
                );
            }
        }
        for k in 0..8 {
            let t = s.t_min + (s.t_max - s.t_min) * (f64::from(k) + 0.5) / 8.0;
            let m = mu(&mut acc, t);
            let tol = 1e-6 * s.mu_maj.abs().max(1e-6);
            prop_assert!(
                m >= s.mu_min - tol && m <= s.mu_maj + tol,
                "mu {m} at {t} outside {s:?}"
            );
        }
        prev = s.t_max;
    }
    let covered: f64 = segs.iter().map(Segment::length).sum();
    prop_assert!(close(covered, w.covered, 1e-12));
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, .. ProptestConfig::default() })]

    #[test]
    fn hdda_segments_are_ordered_bounded_and_tau_matches_brute_force(s in scene()) {
        let v = build(&s);
        let r = Ray::new(s.origin, s.dir, 0.0, s.len).unwrap();
        for interp in [Interp::Nearest, Interp::Trilinear] {
            for gran in [Granularity::Leaf, Granularity::Lower, Granularity::Upper] {
                check_segments(&v, &r, interp, gran)?;
            }
        }
        let (n, bn) = (tau(&v, &r, Interp::Nearest), brute_nearest(&v, &r));
        prop_assert!(close(n, bn, 1e-9), "nearest {n} vs brute {bn}");
        let (t, bt) = (tau(&v, &r, Interp::Trilinear), brute_trilinear(&v, &r));
        prop_assert!(close(t, bt, 1e-6), "trilinear {t} vs brute {bt}");
    }
}

/// Optical depth and a few sampled estimators along `+z` through a full leaf of ones at `o`
/// (plus, optionally, a second leaf at the opposite corner of the `i32` range, which a wrapped
/// or clamped coordinate would read).
fn edge_leaf_tau(o: [i32; 3], opposite: bool, interp: Interp) -> f64 {
    let mut b = TreeBuilder::new(0.0);
    for x in 0..8 {
        for y in 0..8 {
            for z in 0..8 {
                b.set([o[0] + x, o[1] + y, o[2] + z], 1.0);
                if opposite {
                    b.set([i32::MAX - x, i32::MAX - y, i32::MAX - z], 1.0);
                }
            }
        }
    }
    let m = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
    ];
    let vol = Volume::from_tree("edge".into(), b.build(), m, 1.0).unwrap();
    let c = [
        f64::from(o[0]) + 3.3,
        f64::from(o[1]) + 4.1,
        f64::from(o[2]) - 5.0,
    ];
    let ray = Ray::new(c, [0.0, 0.0, 1.0], 0.0, 20.0).unwrap();
    optical_depth(&vol, &ray, interp).unwrap().tau
}

/// A leaf at the minimum `i32` corner integrates exactly like the same leaf at the origin:
/// trilinear lookups there read one voxel below the range, which is background (it used to be
/// dropped with its root cell, giving 7.5 instead of 8, or to wrap to the far corner).
#[test]
fn leaves_at_the_edges_of_the_i32_range_integrate_like_at_the_origin() {
    for interp in [Interp::Nearest, Interp::Trilinear] {
        let at_origin = edge_leaf_tau([0; 3], false, interp);
        assert!((at_origin - 8.0).abs() < 1e-12, "{interp:?}: {at_origin}");
        for (o, opposite) in [
            ([i32::MIN; 3], false),
            ([i32::MIN; 3], true),
            ([i32::MAX - 7; 3], false),
            ([i32::MIN, 0, i32::MAX - 7], false),
        ] {
            let tau = edge_leaf_tau(o, opposite, interp);
            assert!(
                (tau - at_origin).abs() < 1e-9,
                "{interp:?} leaf at {o:?} (opposite corner filled: {opposite}): {tau} vs {at_origin}"
            );
        }
    }
}

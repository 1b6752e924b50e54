//! Baked maps read back from the EXR (exr crate) against exact answers: an analytic box medium
//! pixel by pixel (ortho and perspective, with a non-zero background), the sample cloud against
//! exact regular tracking, depth slices, adaptive sampling, thread-count determinism, the
//! standard matrices, and the object-order sweep against the ray path.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::bake_support;

use bake_support::{box_volume, ortho, prov, read_exr, regular, Exr};
use glam::DVec3;
use std::path::Path;
use umbra::bake::{bake, write_exr, BakeSettings, Camera, Depths, Map, Order, Projection, View};
use umbra::estimate::{Estimator, Options};
use umbra::internals::ray::clip_box;
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

fn bake_to(dir: &Path, name: &str, vol: &Volume, cam: &Camera, s: &BakeSettings) -> (Map, Exr) {
    let map = bake(vol, cam, s, &|_| {}).unwrap();
    let p = dir.join(name);
    write_exr(&p, &map, &prov(vol), false).unwrap();
    let exr = read_exr(&p);
    (map, exr)
}

/// Exact tau of a ray through the box medium: mu_bg (t_max - L) + mu L, L the chord.
fn box_tau(vol: &Volume, r: &Ray) -> f64 {
    let chord = clip_box(
        vol.to_index(r.origin()),
        vol.to_index_dir(r.direction()),
        [-0.5; 3],
        [127.5; 3],
    )
    .map_or(0.0, |(a, b)| (b.min(r.t_max()) - a.max(r.t_min())).max(0.0));
    0.125 * (r.t_max() - r.t_min() - chord) + chord
}

#[test]
fn analytic_box_ortho_and_perspective_pixel_by_pixel() {
    let dir = tempfile::tempdir().unwrap();
    let vol = box_volume();
    let corners = vol.box_corners().unwrap();
    let persp = View {
        projection: Projection::Perspective,
        light_dir: None,
        light_pos: Some([9.0, 14.0, -6.0]),
        fov_deg: None,
        res: Some(umbra::bake::Resolution::Exact(40, 30)),
        up: None,
        frame_box: None,
    };
    for (n, view) in [ortho([0.3, -1.0, 0.45], 64, 48), persp].iter().enumerate() {
        let cam = Camera::frame(view, &corners).unwrap();
        let (map, exr) = bake_to(
            dir.path(),
            &format!("box{n}.exr"),
            &vol,
            &cam,
            &regular(Interp::Nearest),
        );
        assert_eq!(
            (exr.w, exr.h),
            (cam.width() as usize, cam.height() as usize)
        );
        let t = &exr.ch["T"];
        let (mut worst, mut inside) = (0.0f64, 0);
        for j in 0..exr.h {
            for i in 0..exr.w {
                let r = exr.ray(i, j);
                let tau = box_tau(&vol, &r);
                inside += usize::from(tau > 0.125 * r.t_max() + 1e-9);
                let d = (f64::from(t[j * exr.w + i]) - (-tau).exp()).abs();
                worst = worst.max(d);
                assert!(
                    d < 2e-6,
                    "{view:?} pixel ({i},{j}): {} vs {}",
                    t[j * exr.w + i],
                    (-tau).exp()
                );
            }
        }
        // The box is framed: most pixels see it, and the border pixels only see background.
        assert!(inside > exr.w * exr.h / 4, "{inside} pixels hit the box");
        assert_eq!(map.t, *t);
        eprintln!("{:?}: worst |T - exact| = {worst:.2e}", cam.kind());
    }
}

#[test]
fn cloud_map_matches_exact_regular_tracking_per_pixel() {
    let dir = tempfile::tempdir().unwrap();
    let vol = Volume::load("data/cloud.vdb", "density", 2.0).unwrap();
    let cam = Camera::frame(
        &ortho([-1.0, -1.0, 0.3], 48, 40),
        &vol.box_corners().unwrap(),
    )
    .unwrap();
    let (_, exr) = bake_to(
        dir.path(),
        "cloud.exr",
        &vol,
        &cam,
        &regular(Interp::Trilinear),
    );
    let t = &exr.ch["T"];
    let mut worst = 0.0f64;
    for j in 0..exr.h {
        for i in 0..exr.w {
            let od = optical_depth(&vol, &exr.ray(i, j), Interp::Trilinear).unwrap();
            let want = od.transmittance() as f32;
            worst = worst.max(f64::from((t[j * exr.w + i] - want).abs()));
        }
    }
    assert!(worst <= 1e-6, "worst {worst}");
    let min = t.iter().copied().fold(1.0f32, f32::min);
    assert!(
        min < 0.1,
        "the cloud should cast a dark shadow, min T = {min}"
    );
}

#[test]
fn slices_are_prefix_transmittances() {
    let dir = tempfile::tempdir().unwrap();
    let vol = Volume::load("data/cloud.vdb", "density", 1.0).unwrap();
    let cam = Camera::frame(
        &ortho([0.2, -1.0, 0.1], 24, 20),
        &vol.box_corners().unwrap(),
    )
    .unwrap();
    let s = BakeSettings {
        depths: Depths::Slices(4),
        ..regular(Interp::Trilinear)
    };
    let (map, exr) = bake_to(dir.path(), "slices.exr", &vol, &cam, &s);
    assert_eq!(map.depths.len(), 4);
    assert!((map.depths[3] - cam.t_max()).abs() < 1e-12);
    for (k, &d) in map.depths.iter().enumerate() {
        assert_eq!(exr.f64(&format!("depth.{k:02}")), d);
        let ch = &exr.ch[&format!("slice{k:02}.T")];
        for j in 0..exr.h {
            for i in 0..exr.w {
                let r = exr.ray(i, j).with_range(0.0, d).unwrap();
                let want = optical_depth(&vol, &r, Interp::Trilinear)
                    .unwrap()
                    .transmittance();
                let got = f64::from(ch[j * exr.w + i]);
                assert!(
                    (got - want).abs() < 1e-6,
                    "slice {k} ({i},{j}): {got} vs {want}"
                );
                if k > 0 {
                    let prev = exr.ch[&format!("slice{:02}.T", k - 1)][j * exr.w + i];
                    assert!(got <= f64::from(prev) + 1e-7);
                }
            }
        }
    }
    // The deepest slice is the full T.
    let full = &exr.ch["T"];
    let last = &exr.ch["slice03.T"];
    assert!(full.iter().zip(last).all(|(a, b)| (a - b).abs() < 1e-6));
}

#[test]
fn adaptive_sampling_reaches_the_target_error_and_stays_unbiased() {
    let dir = tempfile::tempdir().unwrap();
    let vol = Volume::load("data/cloud.vdb", "density", 1.0).unwrap();
    let cam = Camera::frame(
        &ortho([0.0, -1.0, 0.0], 16, 16),
        &vol.box_corners().unwrap(),
    )
    .unwrap();
    let s = BakeSettings {
        target_error: Some(0.02),
        std_err: true,
        ..BakeSettings::new(
            Estimator::from_name("ratio").unwrap(),
            Options {
                samples: 8,
                seed: 3,
                ..Options::default()
            },
        )
    };
    let (map, exr) = bake_to(dir.path(), "adaptive.exr", &vol, &cam, &s);
    assert_eq!(map.stats.unconverged, 0);
    let (t, e) = (&exr.ch["T"], &exr.ch["T.stderr"]);
    assert!(e.iter().all(|&x| x <= 0.02));
    assert!(
        map.stats.samples > 8 * map.stats.rays,
        "no pixel needed more samples?"
    );
    // Sequential stopping on a sample variance is slightly optimistic on heavy-tailed pixels,
    // so allow a tenth of the target on top of 4 standard errors, and 2 outliers in 256.
    let (mut far, mut sum_diff, mut sum_var) = (0, 0.0, 0.0);
    for j in 0..exr.h {
        for i in 0..exr.w {
            let exact = optical_depth(&vol, &exr.ray(i, j), Interp::Trilinear)
                .unwrap()
                .transmittance();
            let n = j * exr.w + i;
            let (diff, err) = (f64::from(t[n]) - exact, f64::from(e[n]));
            sum_diff += diff;
            sum_var += err * err;
            if diff.abs() > 4.0 * err + 0.002 {
                eprintln!("({i},{j}) T {} exact {exact} stderr {err}", t[n]);
                far += 1;
            }
        }
    }
    assert!(
        sum_diff.abs() < 4.0 * sum_var.sqrt(),
        "mean bias {sum_diff} vs {}",
        sum_var.sqrt()
    );
    assert!(
        far <= 2,
        "{far} of 256 pixels further than 4 std_err from exact"
    );
}

#[test]
fn one_and_two_threads_write_identical_files() {
    let dir = tempfile::tempdir().unwrap();
    let vol = Volume::load("data/cloud.vdb", "density", 1.5).unwrap();
    let cam = Camera::frame(
        &ortho([-1.0, -0.5, 0.2], 40, 33),
        &vol.box_corners().unwrap(),
    )
    .unwrap();
    for est in [Estimator::REGULAR, Estimator::from_name("ratio").unwrap()] {
        let mut files = Vec::new();
        for threads in [1, 2, 0] {
            let s = BakeSettings {
                threads,
                target_error: Some(0.05),
                std_err: true,
                depths: Depths::At(vec![1.0, 2.5]),
                ..BakeSettings::new(
                    est,
                    Options {
                        samples: 4,
                        seed: 11,
                        ..Options::default()
                    },
                )
            };
            let p = dir.path().join(format!("{}-{threads}.exr", est.name()));
            let map = bake(&vol, &cam, &s, &|_| {}).unwrap();
            let s0 = BakeSettings { threads: 1, ..s };
            write_exr(
                &p,
                &Map {
                    settings: s0,
                    ..map
                },
                &prov(&vol),
                false,
            )
            .unwrap();
            files.push(std::fs::read(&p).unwrap());
            eprintln!("{threads}: {:?}", read_exr(&p).ch["T"][..4].to_vec());
        }
        assert!(
            files.windows(2).all(|w| w[0] == w[1]),
            "{} differs across threads",
            est.name()
        );
    }
}

#[test]
fn standard_matrices_map_pixel_rays_to_their_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let vol = box_volume();
    let corners = vol.box_corners().unwrap();
    let persp = View {
        projection: Projection::Perspective,
        light_dir: Some([-0.5, -1.0, 0.7]),
        light_pos: Some([9.0, 14.0, -6.0]),
        fov_deg: Some(50.0),
        res: Some(umbra::bake::Resolution::Exact(20, 12)),
        up: None,
        frame_box: None,
    };
    for (n, view) in [ortho([1.0, 0.2, -0.3], 20, 12), persp].iter().enumerate() {
        let cam = Camera::frame(view, &corners).unwrap();
        let (_, exr) = bake_to(
            dir.path(),
            &format!("m{n}.exr"),
            &vol,
            &cam,
            &regular(Interp::Nearest),
        );
        let ndc = exr.attrs.world_to_normalized_device.unwrap();
        let w2c = exr.attrs.world_to_camera.unwrap();
        for (i, j) in [(0, 0), (19, 0), (0, 11), (7, 5), (19, 11)] {
            let r = exr.ray(i, j);
            let p = r.at(0.6 * r.t_max());
            // Row-vector convention: [x y z 1] * M.
            let mul = |m: &[f32; 16], c: usize| {
                (0..4)
                    .map(|k| [p[0], p[1], p[2], 1.0][k] * f64::from(m[4 * k + c]))
                    .sum::<f64>()
            };
            let w = mul(&ndc, 3);
            let (x, y) = (mul(&ndc, 0) / w, mul(&ndc, 1) / w);
            assert!(
                (x - (i as f64 + 0.5) / 20.0).abs() < 1e-4,
                "{n} ({i},{j}) x {x}"
            );
            assert!(
                (y - (j as f64 + 0.5) / 12.0).abs() < 1e-4,
                "{n} ({i},{j}) y {y}"
            );
            assert!(mul(&w2c, 2) > 0.0, "camera z is forward");
        }
    }
}

/// The object-order sweep (what `Order::Auto` picks for an exact map) against the ray path on
/// the sample cloud and a corpus cloud, several directions, orthographic and perspective: every
/// pixel's T within 5e-7 (the sweep's optical depth is within ~1e-6 relative; T is f32), depth
/// slices (evenly spaced and explicit, one past the volume) likewise, the same bytes on 1 and 2
/// threads; a light inside the box leaves the map to the ray path (bit-identical).
#[test]
fn sweep_matches_the_ray_path_and_the_thread_count() {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/gen/cloud_fbm.vdb");
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb");
    for (path, scale) in [(data, 4.0), (corpus, 5.0)] {
        let vol = Volume::load(&path, "density", scale).unwrap();
        let corners = vol.box_corners().unwrap();
        let (lo, hi) = corners.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(a, b), &c| (a.min(c), b.max(c)),
        );
        let centre = 0.5 * (lo + hi);
        let mut cams = Vec::new();
        for dir in [[0.6, -0.35, -1.0], [0.0, -1.0, 0.0], [-1.0, 0.5, 0.25]] {
            cams.push((dir, Camera::frame(&ortho(dir, 96, 80), &corners).unwrap()));
            let pos = centre - DVec3::from(dir).normalize() * 1.5 * (hi - lo).length();
            let persp = View {
                projection: Projection::Perspective,
                light_dir: Some(dir),
                light_pos: Some(pos.to_array()),
                fov_deg: None,
                res: Some(umbra::bake::Resolution::Exact(80, 64)),
                up: None,
                frame_box: None,
            };
            cams.push((dir, Camera::frame(&persp, &corners).unwrap()));
        }
        for (dir, cam) in cams {
            let auto = BakeSettings {
                threads: 2,
                ..regular(Interp::Trilinear)
            };
            let rays = BakeSettings {
                order: Order::Rays,
                ..auto.clone()
            };
            let a = bake(&vol, &cam, &auto, &|_| {}).unwrap();
            let r = bake(&vol, &cam, &rays, &|_| {}).unwrap();
            let worst =
                a.t.iter()
                    .zip(&r.t)
                    .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
            assert!(worst <= 5e-7, "{path:?} {dir:?}: |dT| up to {worst}");
            assert!(
                r.t.iter().any(|&t| t < 0.9),
                "{path:?} {dir:?}: the view misses the cloud"
            );
            // Depth slices: each block's chord split at the slice depths it straddles.
            for depths in [Depths::Slices(5), Depths::At(vec![0.5, 2.0, 2.25, 40.0])] {
                let sa = BakeSettings {
                    depths: depths.clone(),
                    ..auto.clone()
                };
                let sr = BakeSettings {
                    depths: depths.clone(),
                    ..rays.clone()
                };
                let a = bake(&vol, &cam, &sa, &|_| {}).unwrap();
                let r = bake(&vol, &cam, &sr, &|_| {}).unwrap();
                assert!(a.stats.sweep && !r.stats.sweep);
                assert_eq!(
                    (a.depths.len(), a.slices.len()),
                    (r.depths.len(), r.slices.len())
                );
                assert_eq!(a.depths, r.depths);
                for (k, (x, y)) in a.slices.iter().zip(&r.slices).enumerate() {
                    let worst = x
                        .iter()
                        .zip(y)
                        .fold(0.0f32, |m, (p, q)| m.max((p - q).abs()));
                    assert!(
                        worst <= 5e-7,
                        "{path:?} {dir:?} {depths:?} slice {k}: {worst}"
                    );
                }
                assert_eq!(a.t, bake(&vol, &cam, &auto, &|_| {}).unwrap().t);
            }
            let one = BakeSettings {
                threads: 1,
                ..auto.clone()
            };
            let a1 = bake(&vol, &cam, &one, &|_| {}).unwrap();
            assert!(
                a1.t.iter()
                    .zip(&a.t)
                    .all(|(x, y)| x.to_bits() == y.to_bits()),
                "{path:?} {dir:?}: 1 and 2 threads differ"
            );
        }
        let inside = View {
            projection: Projection::Perspective,
            light_dir: Some([0.0, -1.0, 0.0]),
            light_pos: Some(centre.to_array()),
            fov_deg: Some(90.0),
            res: Some(umbra::bake::Resolution::Exact(48, 48)),
            up: None,
            frame_box: None,
        };
        let cam = Camera::frame(&inside, &corners).unwrap();
        let rays = BakeSettings {
            order: Order::Rays,
            ..regular(Interp::Trilinear)
        };
        let a = bake(&vol, &cam, &regular(Interp::Trilinear), &|_| {}).unwrap();
        let r = bake(&vol, &cam, &rays, &|_| {}).unwrap();
        assert!(a.stats.sweep, "{path:?}: a light inside the box is swept");
        let worst =
            a.t.iter()
                .zip(&r.t)
                .fold(0.0f32, |m, (p, q)| m.max((p - q).abs()));
        assert!(
            worst <= 1e-6,
            "{path:?}: a light inside the box, sweep against rays: {worst}"
        );
    }
}

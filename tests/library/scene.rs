//! Scenes (several volumes, weighted grids, RGB extinction, solids) against exact answers:
//! exact optical depth is the sum of each volume's, every unbiased estimator is within 4
//! standard errors of it per channel, maps of scenes equal their rays.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[allow(unused_imports)]
use crate::common;

use std::path::{Path, PathBuf};
use umbra::bake::{bake_scene, BakeSettings, Camera, Order, Projection, Resolution, View};
use umbra::estimate::{estimate, ColourWalk, Estimator, Kind, Options, REGISTRY};
use umbra::input::SourceOptions;
use umbra::regular::optical_depth;
use umbra::scene::{self, Scene};
use umbra::{Interp, Ray, Volume};

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

const SHIFT: [f64; 16] = [
    1.0, 0.0, 0.0, 0.4, 0.0, 1.0, 0.0, -0.3, 0.0, 0.0, 1.0, 0.2, 0.0, 0.0, 0.0, 1.0,
];

fn shift() -> umbra::internals::xform::Xform {
    umbra::internals::xform::Xform::from_row_major(&SHIFT).unwrap()
}

/// The sample cloud twice: as it is, and shifted at half density; `sigma` per volume.
fn two_clouds(dir: &Path, sigma: Option<([f64; 3], [f64; 3])>) -> PathBuf {
    let cloud = data("cloud.vdb");
    let colour = |s: Option<[f64; 3]>| {
        s.map_or(String::new(), |s| {
            format!("sigma_t = [{}, {}, {}]\n", s[0], s[1], s[2])
        })
    };
    let x: Vec<String> = SHIFT.iter().map(|v| format!("{v:?}")).collect();
    let text = format!(
        "[[volume]]\nfile = {:?}\ngrid = \"density\"\n{}\n[[volume]]\nfile = \"cloud.vdb\"\n\
         density_scale = 0.5\nxform = [{}]\n{}",
        cloud.display().to_string(),
        colour(sigma.map(|s| s.0)),
        x.join(", "),
        colour(sigma.map(|s| s.1)),
    );
    std::fs::copy(&cloud, dir.join("cloud.vdb")).unwrap();
    write(dir, "two.toml", &text)
}

/// The two volumes of [`two_clouds`], loaded on their own.
fn two_volumes() -> (Volume, Volume) {
    let a = Volume::load(data("cloud.vdb"), "density", 1.0).unwrap();
    let b = Volume::load(data("cloud.vdb"), "density", 0.5)
        .unwrap()
        .with_xform(&shift())
        .unwrap();
    (a, b)
}

/// Rays through the cloud's box from all sides (fixed, deterministic).
fn rays(n: usize) -> Vec<Ray> {
    (0..n)
        .map(|i| {
            let a = i as f64 * 2.399_963;
            let h = (i as f64 / n as f64) * 1.6 - 0.8;
            let from = [2.5 * a.cos(), h, 2.5 * a.sin()];
            let to = [-2.0 * (a + 0.7).cos(), 0.4 - h, -2.0 * (a + 0.7).sin()];
            Ray::between(from, to).unwrap()
        })
        .collect()
}

#[test]
fn a_two_volume_scene_is_the_sum_of_the_volumes_exact_depths() {
    let dir = tempfile::tempdir().unwrap();
    let scene = umbra::input::Source::new(two_clouds(dir.path(), None), SourceOptions::default())
        .load()
        .unwrap();
    assert_eq!(scene.fogs().len(), 2);
    assert_eq!(scene.channels(), 1);
    let (a, b) = two_volumes();
    let mut informative = 0;
    for (i, r) in rays(64).iter().enumerate() {
        let ta = optical_depth(&a, r, Interp::Trilinear).unwrap().tau;
        let tb = optical_depth(&b, r, Interp::Trilinear).unwrap().tau;
        let e = scene::estimate(
            &scene,
            r,
            i as u64,
            &Estimator::REGULAR,
            &Options::default(),
        )
        .unwrap();
        let tau = e.tau.unwrap()[0];
        assert!(
            (tau - (ta + tb)).abs() <= 1e-12 * (ta + tb),
            "ray {i}: {tau} vs {ta} + {tb}"
        );
        assert_eq!(e.value[0], (-tau).exp());
        if ta > 0.05 && tb > 0.05 {
            informative += 1;
        }
    }
    assert!(informative > 10, "{informative} rays cross both volumes");
}

#[test]
fn a_scene_of_one_grey_volume_is_the_volume() {
    let vol = Volume::load(data("cloud.vdb"), "density", 1.0).unwrap();
    let scene = Scene::from_volume(vol.clone());
    let ratio = Estimator::from_name("ratio").unwrap();
    let opts = Options {
        samples: 16,
        seed: 3,
        ..Options::default()
    };
    for (i, r) in rays(16).iter().enumerate() {
        for est in [&Estimator::REGULAR, &ratio] {
            let a = estimate(&vol, r, i as u64, est, &opts).unwrap();
            let b = scene::estimate(&scene, r, i as u64, est, &opts).unwrap();
            assert_eq!(b.channel(0), a);
        }
    }
}

#[test]
fn weighted_grids_add_with_their_weights() {
    let Some(dir) = common::corpus_dir() else {
        return;
    };
    let file = dir.join("real/blender_smoke_fluid_data_0050.vdb");
    let tmp = tempfile::tempdir().unwrap();
    let scene_path = write(
        tmp.path(),
        "fire.toml",
        &format!(
            "[[volume]]\nfile = {:?}\ngrids = [\"density\", \"flame\"]\nweights = [1.0, 0.5]\n\
             density_scale = 20.0\n",
            file.display().to_string()
        ),
    );
    let scene = umbra::input::Source::new(&scene_path, SourceOptions::default())
        .load()
        .unwrap();
    let d = Volume::load(&file, "density", 20.0).unwrap();
    let f = Volume::load(&file, "flame", 10.0).unwrap();
    let c = d.box_corners().unwrap();
    let (lo, hi) = (c[0], c[7]);
    let mut both = 0;
    for i in 0..40 {
        let u = (i as f64 + 0.5) / 40.0;
        let from = lo + (hi - lo) * glam::DVec3::new(u, 0.0, 0.5 + 0.3 * (u - 0.5));
        let to = lo + (hi - lo) * glam::DVec3::new(1.0 - u, 1.0, 0.5);
        let r = Ray::between(from, to).unwrap();
        let td = optical_depth(&d, &r, Interp::Trilinear).unwrap().tau;
        let tf = optical_depth(&f, &r, Interp::Trilinear).unwrap().tau;
        let e = scene::estimate(&scene, &r, 0, &Estimator::REGULAR, &Options::default()).unwrap();
        let tau = e.tau.unwrap()[0];
        assert!(
            (tau - (td + tf)).abs() <= 1e-12 * (td + tf) + 1e-300,
            "{tau} {td} {tf}"
        );
        if td > 1e-3 && tf > 1e-3 {
            both += 1;
        }
    }
    assert!(both > 5, "{both} rays see density and flame");
}

#[test]
fn rgb_exact_is_sigma_times_tau_per_channel() {
    let dir = tempfile::tempdir().unwrap();
    let s1 = [0.5, 1.0, 2.0];
    let s2 = [2.0, 1.0, 0.25];
    let path = two_clouds(dir.path(), Some((s1, s2)));
    let scene = umbra::input::Source::new(&path, SourceOptions::default())
        .load()
        .unwrap();
    assert_eq!(scene.channels(), 3);
    let (a, b) = two_volumes();
    for (i, r) in rays(32).iter().enumerate() {
        let ta = optical_depth(&a, r, Interp::Trilinear).unwrap().tau;
        let tb = optical_depth(&b, r, Interp::Trilinear).unwrap().tau;
        let e = scene::estimate(
            &scene,
            r,
            i as u64,
            &Estimator::REGULAR,
            &Options::default(),
        )
        .unwrap();
        for c in 0..3 {
            let want = s1[c] * ta + s2[c] * tb;
            let got = e.tau.unwrap()[c];
            assert!((got - want).abs() <= 1e-12 * want, "ray {i} channel {c}");
            assert_eq!(e.value[c], (-got).exp());
        }
    }
    // --sigma-t on the command line multiplies each volume's colour.
    let tinted = umbra::input::Source::new(
        &path,
        SourceOptions {
            sigma_t: Some([1.0, 2.0, 0.5]),
            ..SourceOptions::default()
        },
    )
    .load()
    .unwrap();
    let r = &rays(1)[0];
    let e0 = scene::estimate(&scene, r, 0, &Estimator::REGULAR, &Options::default()).unwrap();
    let e1 = scene::estimate(&tinted, r, 0, &Estimator::REGULAR, &Options::default()).unwrap();
    for (c, k) in [1.0, 2.0, 0.5].iter().enumerate() {
        let (t0, t1) = (e0.tau.unwrap()[c], e1.tau.unwrap()[c]);
        assert!((t1 - k * t0).abs() <= 1e-12 * t1.abs().max(1e-300));
    }
}

/// Every estimator the registry calls unbiased (signed ones included), at its defaults.
fn unbiased() -> Vec<Estimator> {
    REGISTRY
        .iter()
        .filter(|s| matches!(s.kind, Kind::Unbiased | Kind::Signed))
        .map(|s| Estimator::from_name(s.name).unwrap())
        .collect()
}

/// Check every unbiased estimator against exact on `scene`, per channel, with `walk`.
fn check_unbiased(scene: &Scene, what: &str, walk: ColourWalk) {
    let n = 3000;
    let mut failures = Vec::new();
    let (mut checks, mut informative) = (0, 0);
    let ests = unbiased();
    assert!(ests.len() >= 6, "{} unbiased estimators", ests.len());
    for est in &ests {
        let opts = Options {
            samples: n,
            seed: 77,
            colour_walk: walk,
            ..Options::default()
        };
        for (i, r) in rays(10).iter().enumerate() {
            let exact = scene::estimate(scene, r, i as u64, &Estimator::REGULAR, &opts).unwrap();
            let e = scene::estimate(scene, r, i as u64, est, &opts).unwrap();
            assert_eq!(e.capped, 0);
            assert_eq!(e.majorant_violations, 0, "{} ray {i}", est.name());
            for c in 0..scene.channels() {
                let t = exact.value[c];
                let se = if e.std_err[c] > 0.0 {
                    e.std_err[c]
                } else {
                    (t * (1.0 - t) / f64::from(n)).sqrt().max(1e-12)
                };
                checks += 1;
                if se < 0.1 * t && t < 0.95 {
                    informative += 1;
                }
                if (e.value[c] - t).abs() > 4.0 * se {
                    failures.push(format!(
                        "{what} {walk:?} {} ray {i} channel {c}: {} vs exact {t} (se {se:.2e}, {:.1} se)",
                        est.name(),
                        e.value[c],
                        (e.value[c] - t).abs() / se
                    ));
                }
            }
        }
    }
    eprintln!("{what} {walk:?}: {checks} checks, {informative} informative");
    assert!(
        informative * 2 > checks,
        "{informative} of {checks} informative"
    );
    // 4 sigma: about 6e-5 of checks fail by chance; allow none at these counts.
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn unbiased_estimators_on_a_two_volume_scene_match_exact() {
    let dir = tempfile::tempdir().unwrap();
    let scene = umbra::input::Source::new(two_clouds(dir.path(), None), SourceOptions::default())
        .load()
        .unwrap();
    check_unbiased(&scene, "grey scene", ColourWalk::Auto);
}

#[test]
fn unbiased_estimators_on_rgb_match_exact_per_channel() {
    let dir = tempfile::tempdir().unwrap();
    let path = two_clouds(dir.path(), Some(([0.3, 1.0, 2.5], [1.5, 0.7, 0.1])));
    let scene = umbra::input::Source::new(&path, SourceOptions::default())
        .load()
        .unwrap();
    // One volume in colour (the command line's --sigma-t on a .vdb).
    let one = umbra::input::Source::new(
        data("cloud.vdb"),
        SourceOptions {
            sigma_t: Some([0.25, 1.0, 3.0]),
            ..SourceOptions::default()
        },
    )
    .load()
    .unwrap();
    // Both walks, whatever `auto` picks for each estimator: the shared walk (one majorant for
    // every channel) and split walks (per-channel majorants).
    for walk in [ColourWalk::Shared, ColourWalk::Split] {
        check_unbiased(&scene, "RGB scene", walk);
        check_unbiased(&one, "RGB volume", walk);
    }
}

#[test]
fn a_split_walk_is_the_single_channel_estimator_on_its_own_majorants() {
    let tinted = |sigma: [f64; 3], density_scale: f64| {
        umbra::input::Source::new(
            data("cloud.vdb"),
            SourceOptions {
                sigma_t: Some(sigma),
                density_scale,
                ..SourceOptions::default()
            },
        )
        .load()
        .unwrap()
    };
    let rgb = tinted([1.0; 3], 1.0);
    for spec in REGISTRY.iter().filter(|s| !s.deterministic) {
        let est = Estimator::from_name(spec.name).unwrap();
        let opts = |walk| Options {
            samples: 16,
            seed: 9,
            colour_walk: walk,
            ..Options::default()
        };
        for (i, r) in rays(6).iter().enumerate() {
            let id = i as u64;
            let g = scene::estimate(&rgb, r, id, &est, &opts(ColourWalk::Shared)).unwrap();
            let c = scene::estimate(&rgb, r, id, &est, &opts(ColourWalk::Split)).unwrap();
            // Equal channels: the shared walk looks up once for all three; split walks are
            // each the same single-channel walk from the same stream, three times the lookups.
            assert_eq!(c.value, [g.value[0]; 3], "{} ray {i}", spec.name);
            assert_eq!(c.lookups, 3 * g.lookups, "{} ray {i}", spec.name);
        }
    }
    // A weak channel walks at its own rate: with blue and green at a tenth of red, the split
    // delta tracker looks the medium up far less often than the shared one, whose weak
    // channels sample at red's majorant once red's walk has stopped.
    let red = tinted([1.0, 0.1, 0.1], 4.0);
    let est = Estimator::from_name("track-length").unwrap();
    let lookups = |walk| {
        let opts = Options {
            samples: 64,
            seed: 3,
            colour_walk: walk,
            ..Options::default()
        };
        rays(12)
            .iter()
            .enumerate()
            .map(|(i, r)| {
                scene::estimate(&red, r, i as u64, &est, &opts)
                    .unwrap()
                    .lookups
            })
            .sum::<u64>()
    };
    let (shared, split) = (lookups(ColourWalk::Shared), lookups(ColourWalk::Split));
    assert!(
        (split as f64) < 0.8 * shared as f64,
        "split {split} lookups, shared {shared}"
    );
    // `auto` is the registry's choice at this spread (0.1): split for the delta tracker.
    assert_eq!(
        ColourWalk::Auto.resolve(&est, 0.1),
        ColourWalk::Split,
        "track-length at spread 0.1"
    );
    assert_eq!(lookups(ColourWalk::Auto), split);
}

#[test]
fn the_shared_walk_looks_the_medium_up_once_for_all_channels() {
    let grey = umbra::input::Source::new(data("cloud.vdb"), SourceOptions::default())
        .load()
        .unwrap();
    let rgb = umbra::input::Source::new(
        data("cloud.vdb"),
        SourceOptions {
            sigma_t: Some([1.0, 1.0, 1.0]),
            ..SourceOptions::default()
        },
    )
    .load()
    .unwrap();
    let ratio = Estimator::from_name("ratio").unwrap();
    let opts = Options {
        samples: 200,
        seed: 5,
        colour_walk: ColourWalk::Shared,
        ..Options::default()
    };
    for (i, r) in rays(8).iter().enumerate() {
        let g = scene::estimate(&grey, r, i as u64, &ratio, &opts).unwrap();
        let c = scene::estimate(&rgb, r, i as u64, &ratio, &opts).unwrap();
        // Same walk, same numbers: three equal channels for the cost of one.
        assert_eq!(c.value, [g.value[0]; 3]);
        assert_eq!(c.lookups, g.lookups, "ray {i}");
    }
}

fn camera(scene: &Scene, res: u32) -> Camera {
    let view = View {
        projection: Projection::Ortho,
        light_dir: Some([-0.3, -1.0, 0.2]),
        res: Some(Resolution::Exact(res, res)),
        ..View::default()
    };
    Camera::frame(&view, &scene.box_corners().unwrap()).unwrap()
}

#[test]
fn scene_maps_sweep_equals_rays_and_colour_is_per_channel() {
    let dir = tempfile::tempdir().unwrap();
    let s1 = [0.5, 1.0, 2.0];
    let path = two_clouds(dir.path(), Some((s1, s1)));
    let rgb = umbra::input::Source::new(&path, SourceOptions::default())
        .load()
        .unwrap();
    let cam = camera(&rgb, 48);
    let mut s = BakeSettings::new(Estimator::REGULAR, Options::default());
    s.depths = umbra::bake::Depths::Slices(3);
    let swept = bake_scene(&rgb, &cam, &s, &|_| {}).unwrap();
    assert!(swept.stats.sweep);
    assert_eq!(swept.channels(), 3);
    s.order = Order::Rays;
    let traced = bake_scene(&rgb, &cam, &s, &|_| {}).unwrap();
    assert!(!traced.stats.sweep);
    let mut dark = 0;
    for c in 0..3 {
        let (a, _, sa) = swept.channel(c);
        let (b, _, sb) = traced.channel(c);
        for (x, y) in a
            .iter()
            .zip(b)
            .chain(sa.iter().flatten().zip(sb.iter().flatten()))
        {
            assert!((x - y).abs() <= 2e-6, "channel {c}: {x} vs {y}");
        }
        dark += a.iter().filter(|t| **t < 0.5).count();
    }
    assert!(dark > 100, "{dark} dark pixels");
    // Grey: T_c = T_grey^sigma_c for a uniformly tinted scene.
    let grey = umbra::input::Source::new(two_clouds(dir.path(), None), SourceOptions::default())
        .load()
        .unwrap();
    s.order = Order::Auto;
    let g = bake_scene(&grey, &cam, &s, &|_| {}).unwrap();
    for (c, sigma) in s1.iter().enumerate() {
        let (t, _, _) = swept.channel(c);
        for (x, y) in t.iter().zip(&g.t) {
            let want = f64::from(*y).powf(*sigma);
            assert!((f64::from(*x) - want).abs() <= 1e-5, "{x} vs {want}");
        }
    }
}

#[test]
fn stochastic_scene_maps_are_the_per_pixel_estimates() {
    let dir = tempfile::tempdir().unwrap();
    let path = two_clouds(dir.path(), Some(([0.5, 1.0, 2.0], [1.0, 1.0, 1.0])));
    let rgb = umbra::input::Source::new(&path, SourceOptions::default())
        .load()
        .unwrap();
    let cam = camera(&rgb, 16);
    let est = Estimator::from_name("ratio").unwrap();
    let opts = Options {
        samples: 8,
        seed: 9,
        ..Options::default()
    };
    let mut s = BakeSettings::new(est, opts);
    s.std_err = true;
    let one = BakeSettings {
        threads: 1,
        ..s.clone()
    };
    let map = bake_scene(&rgb, &cam, &s, &|_| {}).unwrap();
    let map1 = bake_scene(&rgb, &cam, &one, &|_| {}).unwrap();
    for c in 0..3 {
        assert_eq!(
            map.channel(c).0,
            map1.channel(c).0,
            "thread count changed channel {c}"
        );
    }
    for j in 0..16 {
        for i in 0..16 {
            let ray = cam.pixel_ray(i, j).unwrap();
            let p = u64::from(j * 16 + i);
            let e = scene::estimate(&rgb, &ray, p, &est, &opts).unwrap();
            for c in 0..3 {
                let (t, err, _) = map.channel(c);
                assert_eq!(t[p as usize], e.value[c] as f32);
                assert_eq!(err.unwrap()[p as usize], e.std_err[c] as f32);
            }
        }
    }
}

#[test]
fn malformed_scenes_name_the_file_and_the_entry() {
    let dir = tempfile::tempdir().unwrap();
    let cloud = data("cloud.vdb").display().to_string();
    let cases = [
        ("[[volume]]\nfile = \"nope.vdb\"\n", "nope.vdb"),
        ("[[volume]]\nfile = 3\n", "line 2"),
        ("[[volume]]\nfil = \"a.vdb\"\n", "unknown field"),
        ("volume = []\n", "no [[volume]]"),
        (
            &format!("[[volume]]\nfile = {cloud:?}\ngrids = [\"density\"]\nweights = [1, 2]\n"),
            "volume[0]",
        ),
        (
            &format!("[[volume]]\nfile = {cloud:?}\nsigma_t = [1, -1, 1]\n"),
            "sigma_t",
        ),
        (
            &format!("[[volume]]\nfile = {cloud:?}\nkind = \"smoke\"\n"),
            "kind",
        ),
        (
            &format!("[[volume]]\nfile = {cloud:?}\nkind = \"solid\"\nsigma_t = 2\n"),
            "no meaning for a solid",
        ),
        (
            &format!("[[volume]]\nfile = {cloud:?}\ngrid = \"nope\"\n"),
            "no grid named 'nope'",
        ),
        (
            &format!("[[volume]]\nfile = {cloud:?}\nxform = [1, 2, 3]\n"),
            "volume[0]",
        ),
    ];
    for (i, (text, want)) in cases.iter().enumerate() {
        let p = write(dir.path(), &format!("bad{i}.toml"), text);
        let e = umbra::input::Source::new(&p, SourceOptions::default())
            .load()
            .unwrap_err()
            .to_string();
        assert!(e.contains(want), "case {i}: {e}");
        if !want.contains("nope") {
            assert!(e.contains(&format!("bad{i}.toml")), "case {i}: {e}");
        }
    }
}

#[test]
fn scene_boxes_from_topology_equal_the_loaded_boxes() {
    let dir = tempfile::tempdir().unwrap();
    let path = two_clouds(dir.path(), None);
    let loaded = umbra::input::Source::new(&path, SourceOptions::default())
        .load()
        .unwrap()
        .box_corners()
        .unwrap();
    let read = umbra::input::Source::new(&path, SourceOptions::default())
        .box_corners()
        .unwrap();
    assert_eq!(loaded.len(), 16);
    for (a, b) in loaded.iter().zip(&read) {
        assert!((*a - *b).length() < 1e-12, "{a} vs {b}");
    }
}

#[test]
fn a_solid_in_a_scene_casts_the_analytic_shadow() {
    let Some(corpus) = common::corpus_dir() else {
        return;
    };
    // createLevelSetSphere(radius=1.0, center=(0.1,-0.2,0.3), voxelSize=0.02), scaled by 0.35
    // and moved up by 0.1: centre c, radius 0.35, voxel 0.007.
    let dir = tempfile::tempdir().unwrap();
    let cloud = data("cloud.vdb").display().to_string();
    let sphere = corpus.join("gen/sphere_levelset.vdb").display().to_string();
    let solid = format!(
        "[[volume]]\nfile = {sphere:?}\ngrid = \"ls_sphere\"\nkind = \"solid\"\n\
         xform = [0.35, 0, 0, 0, 0, 0.35, 0, 0.1, 0, 0, 0.35, 0, 0, 0, 0, 1]\n"
    );
    let fog = format!("[[volume]]\nfile = {cloud:?}\nsigma_t = [0.6, 0.9, 1.3]\n");
    let with = umbra::input::Source::new(
        write(dir.path(), "with.toml", &format!("{fog}\n{solid}")),
        SourceOptions::default(),
    )
    .load()
    .unwrap();
    let without = umbra::input::Source::new(
        write(dir.path(), "without.toml", &fog),
        SourceOptions::default(),
    )
    .load()
    .unwrap();
    let c = glam::DVec3::new(0.035, -0.07 + 0.1, 0.105);
    let (r, voxel) = (0.35, 0.007);
    let cam = camera(&with, 160);
    let s = BakeSettings::new(Estimator::REGULAR, Options::default());
    let a = bake_scene(&with, &cam, &s, &|_| {}).unwrap();
    let b = bake_scene(&without, &cam, &s, &|_| {}).unwrap();
    let (mut inside, mut outside) = (0, 0);
    for j in 0..cam.height() {
        for i in 0..cam.width() {
            let ray = cam.pixel_ray(i, j).unwrap();
            let to_c = c - ray.origin();
            let miss = (to_c - ray.direction() * to_c.dot(ray.direction())).length();
            let n = (j * cam.width() + i) as usize;
            for ch in 0..3 {
                let (ta, tb) = (a.channel(ch).0[n], b.channel(ch).0[n]);
                if miss < r - 1.5 * voxel {
                    assert_eq!(ta, 0.0, "pixel ({i}, {j}) passes {miss} from the centre");
                    inside += 1;
                } else if miss > r + 1.5 * voxel {
                    assert_eq!(ta, tb, "pixel ({i}, {j}) misses the sphere");
                    outside += 1;
                }
            }
        }
    }
    // The shadow's area against the disc's: pi r^2 / pixel area.
    let px = cam.step_x().iter().map(|v| v * v).sum::<f64>().sqrt();
    let disc = std::f64::consts::PI * r * r / (px * px);
    let dark = a.t.iter().filter(|t| **t == 0.0).count() as f64;
    assert!(
        (dark - disc).abs() < 0.05 * disc,
        "{dark} dark pixels, disc {disc}"
    );
    assert!(inside > 300 && outside > 3000, "{inside} {outside}");
    // Queries: through the sphere T = 0 with the hit distance; a point inside it is dark.
    let ray = Ray::between(c - glam::DVec3::X * 2.0, c + glam::DVec3::X * 2.0).unwrap();
    let e = scene::estimate(&with, &ray, 0, &Estimator::REGULAR, &Options::default()).unwrap();
    assert_eq!(e.value, [0.0; 3]);
    assert!((e.hit.unwrap() - (2.0 - r)).abs() < voxel, "{:?}", e.hit);
}

fn umbra() -> assert_cmd::Command {
    assert_cmd::Command::cargo_bin("umbra").unwrap()
}

#[test]
fn the_cli_bakes_and_queries_scenes_in_colour() {
    let dir = tempfile::tempdir().unwrap();
    let path = two_clouds(dir.path(), Some(([0.5, 1.0, 2.0], [0.5, 1.0, 2.0])));
    let out = dir.path().join("rgb.exr");
    let o = umbra()
        .arg("bake")
        .arg(&path)
        .args([
            "--light-dir=-1,-1,0",
            "--res",
            "40x30",
            "--stderr",
            "--slices",
            "1",
        ])
        .args(["--estimator", "ratio", "--spp", "4", "--json", "-q", "-o"])
        .arg(&out)
        .assert()
        .success();
    let v: serde_json::Value = serde_json::from_slice(&o.get_output().stdout).unwrap();
    assert_eq!(
        v["channels"],
        serde_json::json!([
            "R",
            "R.stderr",
            "slice00.R",
            "G",
            "G.stderr",
            "slice00.G",
            "B",
            "B.stderr",
            "slice00.B"
        ])
    );
    assert_eq!(v["grid"], "density+density");
    match std::process::Command::new("iinfo")
        .arg("-v")
        .arg(&out)
        .output()
    {
        Ok(o) => {
            let text = String::from_utf8_lossy(&o.stdout);
            assert!(text.contains("9 channel, float openexr"), "{text}");
            assert!(text.contains("channel list: R, G, B, B.stderr, G.stderr, R.stderr, slice00.R, slice00.G, slice00.B"), "{text}");
            assert!(text.contains("umbra:grid: \"density+density\""), "{text}");
        }
        Err(_) => assert!(
            std::env::var("UMBRA_SKIP_OIIO").as_deref() == Ok("1"),
            "iinfo (Debian openimageio-tools) is not installed; set UMBRA_SKIP_OIIO=1 to skip"
        ),
    }
    // query --json: T and tau per channel, equal to the library's (`estimate_many`, what every
    // query of the CLI and the Python module goes through).
    let o = umbra()
        .arg("query")
        .arg(&path)
        .args(["--from", "-2,0,0", "--to", "2,0.5,0", "--json"])
        .assert()
        .success();
    let v: serde_json::Value = serde_json::from_slice(&o.get_output().stdout).unwrap();
    let scene = umbra::input::Source::new(&path, SourceOptions::default())
        .load()
        .unwrap();
    let r = Ray::between([-2.0, 0.0, 0.0], [2.0, 0.5, 0.0]).unwrap();
    let e = scene::estimate_many(&scene, &[r], &[0], &Estimator::REGULAR, &Options::default())
        .pop()
        .unwrap()
        .unwrap();
    for c in 0..3 {
        assert_eq!(v["T"][c].as_f64().unwrap(), e.value[c]);
        assert_eq!(v["tau"][c].as_f64().unwrap(), e.tau.unwrap()[c]);
    }
    // --sigma-t on a .vdb; a bad one is a usage error naming the flag.
    umbra()
        .args([
            "query",
            "data/cloud.vdb",
            "--from",
            "-2,0,0",
            "--to",
            "2,0.5,0",
        ])
        .args(["--sigma-t", "1,2,3", "--json"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .assert()
        .success();
    let o = umbra()
        .args([
            "query",
            "data/cloud.vdb",
            "--from",
            "-2,0,0",
            "--to",
            "2,0.5,0",
        ])
        .args(["--sigma-t", "1,-2,3"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .assert()
        .code(1);
    let err = String::from_utf8_lossy(&o.get_output().stderr);
    assert!(err.contains("sigma-t"), "{err}");
    // compare refuses a scene, saying why.
    let o = umbra()
        .arg("compare")
        .arg(&path)
        .arg("-o")
        .arg(dir.path().join("cmp"))
        .assert()
        .code(1);
    assert!(!dir.path().join("cmp").exists());
    let err = String::from_utf8_lossy(&o.get_output().stderr);
    assert!(err.contains("scenes (.toml) are traced by query"), "{err}");
}

#[test]
fn the_cli_traces_a_level_set_as_a_solid_only_when_asked() {
    let Some(corpus) = common::corpus_dir() else {
        return;
    };
    let ls = corpus.join("gen/sphere_levelset.vdb");
    let args = [
        "--grid",
        "ls_sphere",
        "--from",
        "-2,-0.2,0.3",
        "--to",
        "2,-0.2,0.3",
    ];
    let o = umbra().arg("query").arg(&ls).args(args).assert().code(1);
    let err = String::from_utf8_lossy(&o.get_output().stderr);
    assert!(err.contains("level set"), "{err}");
    let o = umbra()
        .arg("query")
        .arg(&ls)
        .args(args)
        .args(["--levelset", "solid", "--json"])
        .assert()
        .success();
    let v: serde_json::Value = serde_json::from_slice(&o.get_output().stdout).unwrap();
    assert_eq!(v["T"], 0.0);
    // Centre (0.1, -0.2, 0.3), radius 1: entered at x = -0.9, 1.1 from the start.
    let hit = v["solid_hit"].as_f64().unwrap();
    assert!((hit - 1.1).abs() < 0.02, "{hit}");
}

#[test]
fn batch_jobs_take_colour_and_scene_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let path = two_clouds(dir.path(), None);
    let job = dir.path().join("job.toml");
    std::fs::write(
        &job,
        format!(
            "output = \"{}/{{stem}}_{{light}}.exr\"\n[[inputs]]\nfile = {:?}\n\
             [[lights]]\nname = \"sun\"\ndir = [-1, -1, 0]\n[bake]\nres = 24\n\
             sigma_t = [0.5, 1, 2]\n",
            dir.path().display(),
            path.display().to_string()
        ),
    )
    .unwrap();
    umbra().arg("batch").arg(&job).arg("-q").assert().success();
    let out = dir.path().join("two_sun.exr");
    assert!(out.exists());
    // The same map as bake with --sigma-t.
    let bake_out = dir.path().join("bake.exr");
    umbra()
        .arg("bake")
        .arg(&path)
        .args([
            "--light-dir=-1,-1,0",
            "--res",
            "24",
            "--sigma-t",
            "0.5,1,2",
            "-q",
            "-o",
        ])
        .arg(&bake_out)
        .assert()
        .success();
    let a = exr::prelude::read_all_flat_layers_from_file(&out).unwrap();
    let b = exr::prelude::read_all_flat_layers_from_file(&bake_out).unwrap();
    let names = |i: &exr::prelude::FlatImage| -> Vec<String> {
        i.layer_data[0]
            .channel_data
            .list
            .iter()
            .map(|c| c.name.to_string())
            .collect()
    };
    assert_eq!(names(&a), ["B", "G", "R"]);
    for (x, y) in a.layer_data[0]
        .channel_data
        .list
        .iter()
        .zip(&b.layer_data[0].channel_data.list)
    {
        assert_eq!(x.sample_data, y.sample_data);
    }
    // A bad key value is named.
    std::fs::write(
        &job,
        std::fs::read_to_string(&job).unwrap() + "levelset = \"maybe\"\n",
    )
    .unwrap();
    let o = umbra().arg("batch").arg(&job).arg("-q").assert().code(1);
    let err = String::from_utf8_lossy(&o.get_output().stderr);
    assert!(err.contains("bake.levelset"), "{err}");
}

/// `scene::estimate_many` (what `query --rays` and Python's array queries call) against
/// `scene::estimate` ray by ray: exact trilinear answers within `2e-6 tau + 1e-7` (the kernel's
/// f32 positions; `regular::batch`'s unit test holds the general bound `1e-6 tau + 1e-7 M`)
/// on one grey volume, a two-volume scene and an RGB one; stochastic and nearest answers bit
/// for bit (they still go ray by ray, with the ids given).
#[test]
fn a_batch_of_rays_answers_as_each_ray_alone() {
    let dir = tempfile::tempdir().unwrap();
    let grey = umbra::input::Source::new(data("cloud.vdb"), SourceOptions::default())
        .load()
        .unwrap();
    let two = umbra::input::Source::new(two_clouds(dir.path(), None), SourceOptions::default())
        .load()
        .unwrap();
    let sub = tempfile::tempdir().unwrap();
    let rgb = umbra::input::Source::new(
        two_clouds(sub.path(), Some(([0.5, 1.0, 2.0], [2.0, 1.0, 0.25]))),
        SourceOptions::default(),
    )
    .load()
    .unwrap();
    let rays = rays(300);
    for (what, s) in [("grey", &grey), ("two", &two), ("rgb", &rgb)] {
        let ids: Vec<u64> = (0..rays.len() as u64).map(|i| 7 + i).collect();
        let exact = scene::estimate_many(s, &rays, &ids, &Estimator::REGULAR, &Options::default());
        let mut crossed = 0;
        for (i, (r, got)) in rays.iter().zip(&exact).enumerate() {
            let got = got.as_ref().unwrap();
            let want =
                scene::estimate(s, r, 7 + i as u64, &Estimator::REGULAR, &Options::default())
                    .unwrap();
            assert_eq!(got.channels, want.channels);
            for c in 0..3 {
                let (g, w) = (got.tau.unwrap()[c], want.tau.unwrap()[c]);
                assert!(
                    (g - w).abs() <= 2e-6 * w + 1e-7,
                    "{what} ray {i} channel {c}: {g} vs {w}"
                );
                assert_eq!(got.value[c], (-g).exp());
            }
            assert_eq!(got.segments, want.segments, "{what} ray {i}");
            crossed += usize::from(want.tau.unwrap()[0] > 0.05);
        }
        assert!(crossed > 100, "{what}: {crossed} rays cross the cloud");
        for (name, interp) in [("ratio", Interp::Trilinear), ("regular", Interp::Nearest)] {
            let est = Estimator::from_name(name).unwrap();
            let opts = Options {
                samples: 4,
                interp,
                ..Options::default()
            };
            let many = scene::estimate_many(s, &rays[..40], &ids[..40], &est, &opts);
            for (i, (r, got)) in rays.iter().zip(&many).enumerate() {
                let want = scene::estimate(s, r, 7 + i as u64, &est, &opts).unwrap();
                assert_eq!(*got.as_ref().unwrap(), want, "{what} {name} ray {i}");
            }
        }
    }
}

/// The segment the colour-walk queries trace.
const SEGMENT: [&str; 4] = ["--from", "-2,0,0", "--to", "2,0.5,0"];

#[test]
fn the_colour_walk_is_asked_for_on_every_front_end() {
    let dir = tempfile::tempdir().unwrap();
    let cloud = data("cloud.vdb");
    let split = |samples| Options {
        samples,
        seed: 0,
        colour_walk: ColourWalk::Split,
        ..Options::default()
    };
    // bake: the walk is in --json and in the EXR header of a stochastic colour map.
    let out = dir.path().join("split.exr");
    let o = umbra()
        .arg("bake")
        .arg(&cloud)
        .args([
            "--light-dir=0,-1,0",
            "--res",
            "24",
            "--sigma-t",
            "1,0.1,0.1",
        ])
        .args(["--estimator", "track-length", "--spp", "4"])
        .args(["--colour-walk", "split", "--json", "-q", "-o"])
        .arg(&out)
        .assert()
        .success();
    let v: serde_json::Value = serde_json::from_slice(&o.get_output().stdout).unwrap();
    assert_eq!(v["colour_walk"], "split");
    if let Ok(o) = std::process::Command::new("iinfo")
        .arg("-v")
        .arg(&out)
        .output()
    {
        let text = String::from_utf8_lossy(&o.stdout);
        assert!(text.contains("umbra:colour_walk: \"split\""), "{text}");
    }
    // query: the library's split estimate, number for number.
    let o = umbra()
        .arg("query")
        .arg(&cloud)
        .args(SEGMENT)
        .args(["--sigma-t", "1,0.1,0.1"])
        .args(["--estimator", "track-length", "--spp", "256"])
        .args(["--colour-walk", "split", "--json"])
        .assert()
        .success();
    let v: serde_json::Value = serde_json::from_slice(&o.get_output().stdout).unwrap();
    let scene = umbra::input::Source::new(
        &cloud,
        SourceOptions {
            sigma_t: Some([1.0, 0.1, 0.1]),
            ..SourceOptions::default()
        },
    )
    .load()
    .unwrap();
    let r = Ray::between([-2.0, 0.0, 0.0], [2.0, 0.5, 0.0]).unwrap();
    let est = Estimator::from_name("track-length").unwrap();
    let e = scene::estimate(&scene, &r, 0, &est, &split(256)).unwrap();
    let shared = Options {
        colour_walk: ColourWalk::Shared,
        ..split(256)
    };
    let s = scene::estimate(&scene, &r, 0, &est, &shared).unwrap();
    assert_ne!(e.value, s.value, "the walks differ on this ray");
    for c in 0..3 {
        assert_eq!(v["T"][c].as_f64().unwrap(), e.value[c]);
    }
    // A walk that is not one is a usage error naming the flag.
    let o = umbra()
        .arg("query")
        .arg(&cloud)
        .args(SEGMENT)
        .args(["--colour-walk", "both"])
        .assert()
        .code(2);
    let err = String::from_utf8_lossy(&o.get_output().stderr).to_string();
    assert!(err.contains("--colour-walk"), "{err}");
    // Job files take the key (the schema names it).
    let o = umbra().args(["batch", "--schema"]).assert().success();
    let schema = String::from_utf8_lossy(&o.get_output().stdout).to_string();
    assert!(schema.contains("colour_walk"), "schema without colour_walk");
    // compare --sigma-t: both walks of every estimator on the same rays.
    let report = dir.path().join("colour");
    umbra()
        .arg("compare")
        .arg(&cloud)
        .args([
            "--sigma-t",
            "1,0.1,0.1",
            "--density-scale",
            "4",
            "--rays",
            "48",
        ])
        .args([
            "--repeats",
            "1",
            "--estimators",
            "riemann,track-length,ratio",
            "-q",
            "-o",
        ])
        .arg(&report)
        .assert()
        .success();
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(report.join("colour.json")).unwrap())
            .unwrap();
    let rows = v["rows"].as_array().unwrap();
    assert_eq!(
        rows.len(),
        2 * (4 + 4 + 4),
        "three ladders of four, two walks each"
    );
    for pair in rows.chunks(2) {
        assert_eq!(pair[0]["walk"], "shared");
        assert_eq!(pair[1]["walk"], "split");
        assert_eq!(pair[0]["budget"], pair[1]["budget"]);
        if pair[0]["estimator"] == "riemann" {
            // Marching points do not depend on the majorant: the same numbers, a third of
            // the lookups (one lookup serves three channels in the shared walk).
            assert_eq!(pair[0]["rmse"], pair[1]["rmse"]);
            let (a, b) = (pair[0]["lookups"].as_u64(), pair[1]["lookups"].as_u64());
            assert_eq!(3 * a.unwrap(), b.unwrap());
        }
    }
    let verdicts = v["verdicts"].as_array().unwrap();
    let auto: Vec<&str> = verdicts
        .iter()
        .map(|x| x["auto"].as_str().unwrap())
        .collect();
    assert_eq!(auto, ["shared", "split", "shared"]);
    let md = std::fs::read_to_string(report.join("colour.md")).unwrap();
    assert!(md.contains("| track-length |"), "{md}");
    let svg = std::fs::read_to_string(report.join("colour_walks.svg")).unwrap();
    for name in ["riemann", "track-length", "ratio", "auto takes split here"] {
        assert!(svg.contains(name), "the plot has no '{name}'");
    }
}

//! Maps toward a light with extent (issue 60): each texel is `T_L` at its receiver on the
//! texel's ray, which must be exactly what `query --at` answers at that point with the texel's
//! ray id (the same directions, the same estimates), for a sun and a sphere light, flat,
//! sliced and omni maps; zero extent gives today's bytes; the header says the receiver;
//! the same map whatever the thread count; bad values are refused by name; a thin dense slab
//! near a sphere light gives slices whose `T_L` rises with depth.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::bake_support::read_exr;
use crate::vdb_writer::{Grid, Leaf, VdbFile};
use glam::DVec3;
use std::path::{Path, PathBuf};
use umbra::bake::{BakeReport, Map, Omni, Resolution};
use umbra::input::{Source, SourceOptions};
use umbra::request::{
    BakeOptions, BakeOutcome, BakeRequest, LightOptions, QueryOutcome, QueryRequest,
};
use umbra::Error;

fn cloud() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb")
}

fn sun(angle: f64) -> LightOptions {
    LightOptions {
        light_dir: Some([-0.3, -1.0, 0.2]),
        light_angle: Some(angle),
        light_samples: Some(64),
        ..LightOptions::default()
    }
}

fn sphere(pos: [f64; 3], radius: f64) -> LightOptions {
    LightOptions {
        light_pos: Some(pos),
        light_radius: Some(radius),
        light_samples: Some(64),
        ..LightOptions::default()
    }
}

fn options(light: LightOptions, res: u32) -> BakeOptions {
    BakeOptions {
        source: SourceOptions {
            density_scale: 4.0,
            ..SourceOptions::default()
        },
        light,
        res: Some(Resolution::LongSide(res)),
        stderr: true,
        force: true,
        ..BakeOptions::default()
    }
}

fn bake(input: &Path, out: &Path, options: BakeOptions) -> BakeReport {
    let req = BakeRequest {
        input: input.to_path_buf(),
        output: out.to_path_buf(),
        options,
    };
    match req.run(&umbra::progress::Silent).unwrap() {
        BakeOutcome::Map { report, .. } => *report,
        BakeOutcome::Volume { .. } => panic!("a map came back a volume"),
    }
}

fn plan_error(options: BakeOptions, out: &str) -> Error {
    BakeRequest {
        input: cloud(),
        output: out.into(),
        options,
    }
    .plan()
    .unwrap_err()
}

/// `query --at at --ray-id id` toward `light` on `input`, as the map's options read it.
fn query(input: &Path, o: &BakeOptions, at: DVec3, id: u64) -> (f64, f64) {
    let r = QueryRequest {
        at: Some(at.to_array()),
        light: o.light.clone(),
        ray_id: id,
        estimator: o.estimator.clone(),
        ..QueryRequest::new(Source::new(input, o.source.clone()))
    };
    let QueryOutcome::Rays(a) = r.run(&mut |_| {}).unwrap() else {
        panic!("a ray query answered points")
    };
    let e = a.answers[0].result.clone().unwrap().estimate;
    (e.value[0], e.std_err[0])
}

/// Every `step`-th texel of `map` against the query at its receiver `at(ray)`, channel
/// `image` (the map's `T` or a slice) with ray id `id(p)`: bit for bit as f32 (T and, where
/// the light was sampled, std_err). Returns the texels strictly inside a penumbra or shadow.
fn texels_are_queries(
    input: &Path,
    o: &BakeOptions,
    map: &Map,
    image: &[f32],
    at: impl Fn(&umbra::Ray) -> DVec3,
    id: impl Fn(u64) -> u64,
    step: usize,
) -> usize {
    let (w, n) = (map.camera.width() as usize, image.len());
    let mut inside = 0;
    for p in (0..n).step_by(step) {
        let ray = map
            .camera
            .pixel_ray((p % w) as u32, (p / w) as u32)
            .unwrap();
        let (t, err) = query(input, o, at(&ray), id(p as u64));
        assert_eq!(image[p], t as f32, "texel {p}: map {} query {t}", image[p]);
        if image[p] < 1.0 {
            let e = map.std_err.as_ref().unwrap()[p];
            assert_eq!(e, err as f32, "texel {p}: std_err map {e} query {err}");
        }
        inside += usize::from(image[p] > 0.02 && image[p] < 0.98);
    }
    inside
}

#[test]
fn a_texel_is_the_query_at_its_receiver_depth() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("soft.exr");
    for light in [sun(8.0), sphere([0.5, 6.0, -0.3], 1.0)] {
        let o = BakeOptions {
            receiver_depth: Some(if light.light_dir.is_some() { 4.0 } else { 6.5 }),
            ..options(light, 20)
        };
        let r = bake(&cloud(), &out, o.clone());
        let d = o.receiver_depth.unwrap();
        let inside = texels_are_queries(&cloud(), &o, &r.map, &r.map.t, |ray| ray.at(d), |p| p, 3);
        assert!(inside >= 5, "only {inside} texels in a penumbra or shadow");
        let [sampled, all] = r.map.stats.light_sampled.unwrap();
        assert!(
            sampled > 0 && sampled <= all && all == r.map.camera.pixels(),
            "{sampled}/{all}"
        );
    }
}

/// Receivers answered without sampling (the map's `T = 1` with `std_err = 0`) are provably
/// unoccluded: the query at each answers exactly 1, for a sun and a sphere light. And some
/// receivers were sampled, some not (the test looks at both kinds).
#[test]
fn unsampled_receivers_are_unoccluded() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("soft.exr");
    for light in [sun(8.0), sphere([0.5, 6.0, -0.3], 1.0)] {
        let o = BakeOptions {
            receiver_depth: Some(if light.light_dir.is_some() { 4.0 } else { 6.5 }),
            ..options(light, 24)
        };
        let r = bake(&cloud(), &out, o.clone());
        let d = o.receiver_depth.unwrap();
        let err = r.map.std_err.as_ref().unwrap();
        let w = r.map.camera.width() as usize;
        let mut unsampled = 0;
        for p in (0..r.map.t.len()).filter(|&p| err[p] == 0.0) {
            assert_eq!(r.map.t[p], 1.0, "texel {p}");
            let ray = r
                .map
                .camera
                .pixel_ray((p % w) as u32, (p / w) as u32)
                .unwrap();
            let (t, _) = query(&cloud(), &o, ray.at(d), p as u64);
            assert_eq!(t, 1.0, "texel {p}: unsampled but the query answers {t}");
            unsampled += 1;
        }
        let [sampled, all] = r.map.stats.light_sampled.unwrap();
        assert_eq!(all - sampled, unsampled as u64);
        assert!(unsampled > 0 && sampled > 0, "{sampled} of {all} sampled");
    }
}

/// The default receiver, where the texel's ray leaves the volume box: against the query at
/// the exit computed here from the box's world corners (a plain slab clip of an axis-aligned
/// box), within 4 std_err (the exit may differ in its last bits).
#[test]
fn a_texel_is_the_query_where_its_ray_leaves_the_box() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("soft.exr");
    let o = options(sun(8.0), 16);
    let r = bake(&cloud(), &out, o.clone());
    let scene = Source::new(cloud(), o.source.clone()).load().unwrap();
    let c = scene.box_corners().unwrap();
    let lo = c.iter().fold(DVec3::INFINITY, |a, b| a.min(*b));
    let hi = c.iter().fold(DVec3::NEG_INFINITY, |a, b| a.max(*b));
    let w = r.map.camera.width();
    let mut checked = 0;
    for p in (0..r.map.t.len()).step_by(5) {
        let ray = r.map.camera.pixel_ray(p as u32 % w, p as u32 / w).unwrap();
        let (o_, d) = (ray.origin(), ray.direction());
        let t1 = (0..3)
            .map(|a| {
                let (t0, t1) = ((lo[a] - o_[a]) / d[a], (hi[a] - o_[a]) / d[a]);
                t0.max(t1)
            })
            .fold(f64::INFINITY, f64::min);
        let t_in = (0..3)
            .map(|a| {
                let (t0, t1) = ((lo[a] - o_[a]) / d[a], (hi[a] - o_[a]) / d[a]);
                t0.min(t1)
            })
            .fold(f64::NEG_INFINITY, f64::max);
        if t_in > t1 {
            continue;
        }
        let (t, err) = query(&cloud(), &o, ray.at(t1), p as u64);
        let e = f64::from(r.map.std_err.as_ref().unwrap()[p]);
        let diff = (f64::from(r.map.t[p]) - t).abs();
        assert!(
            diff <= 4.0 * e.max(err) + 1e-6,
            "texel {p}: {} vs {t}",
            r.map.t[p]
        );
        checked += 1;
    }
    assert!(checked > 10, "{checked}");
    let exr = read_exr(&out);
    assert_eq!(exr.text("receiver"), "box exit");
}

#[test]
fn slices_are_the_query_at_their_depths() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("soft.exr");
    let o = BakeOptions {
        depths: Some(vec![2.0, 3.0]),
        ..options(sun(6.0), 12)
    };
    let r = bake(&cloud(), &out, o.clone());
    let n = r.map.camera.pixels();
    for (k, d) in [2.0, 3.0].into_iter().enumerate() {
        let img = &r.map.slices[k];
        let id = |p: u64| (64 + k as u64) * n + p;
        // A slice has no std_err channel: compare T alone (texels_are_queries reads the
        // map's std_err only below 1 and only for the main image).
        let w = r.map.camera.width() as usize;
        for p in (0..img.len()).step_by(4) {
            let ray = r
                .map
                .camera
                .pixel_ray((p % w) as u32, (p / w) as u32)
                .unwrap();
            let (t, _) = query(&cloud(), &o, ray.at(d), id(p as u64));
            assert_eq!(img[p], t as f32, "slice {k} texel {p}");
        }
    }
}

#[test]
fn zero_extent_is_todays_map_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let hard = dir.path().join("hard.exr");
    let zero = dir.path().join("zero.exr");
    for light in [
        LightOptions {
            light_dir: Some([-0.3, -1.0, 0.2]),
            ..LightOptions::default()
        },
        LightOptions {
            light_pos: Some([0.5, 6.0, -0.3]),
            ..LightOptions::default()
        },
    ] {
        let mut soft = light.clone();
        if soft.light_dir.is_some() {
            soft.light_angle = Some(0.0);
        } else {
            soft.light_radius = Some(0.0);
        }
        soft.light_samples = Some(64);
        bake(&cloud(), &hard, options(light, 24));
        bake(&cloud(), &zero, options(soft, 24));
        assert_eq!(std::fs::read(&hard).unwrap(), std::fs::read(&zero).unwrap());
        let exr = read_exr(&zero);
        assert!(!exr
            .attrs
            .other
            .contains_key(&exr::meta::attribute::Text::from("umbra:receiver")));
    }
}

#[test]
fn the_header_says_the_receiver_and_the_light() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("soft.exr");
    let o = BakeOptions {
        receiver_depth: Some(2.5),
        ..options(sun(4.0), 10)
    };
    let r = bake(&cloud(), &out, o);
    let exr = read_exr(&out);
    assert_eq!(exr.text("receiver"), "depth 2.5");
    assert_eq!(exr.text("light_extent"), "sun 4 degrees across");
    let [sampled, all] = r.map.stats.light_sampled.unwrap();
    let f = exr.f64("light_sampled_fraction");
    assert_eq!(f, sampled as f64 / all as f64);
    assert!(f > 0.0 && f <= 1.0, "{f}");
    assert!(matches!(
        exr.attr("light_samples"),
        exr::meta::attribute::AttributeValue::I32(64)
    ));
    // The summary (bake --json, Python's dict) says the same, and is not rebuilt into a map.
    let summary = umbra::bake::MapSummary::new(&r.map, &r.provenance);
    let light = summary.light.clone().unwrap();
    assert_eq!(
        (light.receiver.as_str(), light.extent.as_str()),
        ("depth 2.5", "sun 4 degrees across")
    );
    assert_eq!([light.sampled, light.receivers], [sampled, all]);
    let e = summary
        .to_map(r.map.t.clone(), r.map.std_err.clone(), None)
        .unwrap_err();
    assert!(e.to_string().contains("light with extent"), "{e}");
}

#[test]
fn the_same_map_whatever_the_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let maps: Vec<(Vec<f32>, Vec<f32>)> = [1, 2]
        .into_iter()
        .map(|threads| {
            let out = dir.path().join(format!("t{threads}.exr"));
            let o = BakeOptions {
                threads,
                ..options(sphere([0.5, 6.0, -0.3], 1.0), 14)
            };
            let m = bake(&cloud(), &out, o).map;
            (m.t, m.std_err.unwrap())
        })
        .collect();
    assert_eq!(maps[0], maps[1]);
}

#[test]
fn an_omni_map_is_the_query_at_its_receivers() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("omni.exr");
    let o = BakeOptions {
        omni: Some(Omni::Cube),
        receiver_depth: Some(2.5),
        res: Some(Resolution::LongSide(6)),
        ..options(sphere([0.3, 0.4, 0.1], 0.5), 6)
    };
    let r = bake(&cloud(), &out, o.clone());
    assert_eq!(r.map.t.len(), 6 * 36);
    let inside = texels_are_queries(&cloud(), &o, &r.map, &r.map.t, |ray| ray.at(2.5), |p| p, 2);
    assert!(inside >= 5, "{inside}");
}

#[test]
fn bad_values_are_refused_by_name() {
    let name = |e: Error| match e {
        Error::InvalidArgument { name, .. } => name,
        other => panic!("{other}"),
    };
    for d in [-1.0, f64::NAN, f64::INFINITY] {
        let o = BakeOptions {
            receiver_depth: Some(d),
            ..options(sun(4.0), 8)
        };
        assert_eq!(name(plan_error(o, "m.exr")), "receiver-depth", "{d}");
    }
    // No light with extent: nothing to place.
    for light in [
        LightOptions {
            light_dir: Some([0.0, -1.0, 0.0]),
            ..LightOptions::default()
        },
        sun(0.0),
    ] {
        let o = BakeOptions {
            receiver_depth: Some(1.0),
            ..options(light, 8)
        };
        assert_eq!(name(plan_error(o, "m.exr")), "receiver-depth");
    }
    // A transmittance volume takes a light with extent, and refuses a bad one by name.
    assert_eq!(
        name(plan_error(
            BakeOptions {
                light: sun(200.0),
                ..BakeOptions::default()
            },
            "t.vdb"
        )),
        "light-angle"
    );
    // A deep map stores T_L as it is: no fit, so no deep-error.
    let o = BakeOptions {
        deep: true,
        deep_error: Some(0.01),
        stderr: false,
        ..options(sun(4.0), 8)
    };
    assert_eq!(name(plan_error(o, "m.exr")), "deep-error");
    // Fixed-size formats bound their error by monotonicity, which T_L(z) need not have.
    let dir = tempfile::tempdir().unwrap();
    for format in ["fourier:7", "moments:4", "avsm:8"] {
        let req = BakeRequest {
            input: cloud(),
            output: dir.path().join("deep.exr"),
            options: BakeOptions {
                deep_format: Some(format.into()),
                stderr: false,
                ..options(sun(4.0), 8)
            },
        };
        let e = req.run(&umbra::progress::Silent).unwrap_err().error;
        assert_eq!(name(e), "deep-format", "{format}");
    }
}

/// The slab of [`a_slab_near_a_sphere_light_gives_a_rising_profile`] and its light.
fn slab(dir: &Path) -> (PathBuf, BakeOptions) {
    let slab = dir.join("slab.vdb");
    // A faint leaf 200 below (optical depth 8e-4 at most) makes the box, and the deep
    // map's receivers, reach down there.
    let leaves = [[0, 0, 0], [8, 0, 0], [0, 0, 8], [8, 0, 8]]
        .into_iter()
        .map(|o| Leaf::filled(o, 2.0))
        .chain([Leaf::filled([8, -200, 8], 1e-4)])
        .collect();
    VdbFile::new(vec![Grid::fog("density", leaves)]).write(&slab);
    let light = LightOptions {
        light_samples: Some(256),
        ..sphere([8.0, 40.0, 8.0], 20.0)
    };
    let o = BakeOptions {
        source: SourceOptions::default(),
        res: Some(Resolution::LongSide(5)),
        ..options(light, 5)
    };
    (slab, o)
}

/// A deep map toward the slab's sphere light, read back by OpenImageIO (`oiiotool
/// --dumpdata`): its samples are those the flat map's slices at the same depths call for
/// (`A = 1 - T_k / T_(k-1)` between receivers, so compositing gives `T_L` at each), and the
/// centre texel's `T_L` rises with depth (some sample has a negative alpha).
#[test]
fn a_deep_map_stores_a_rising_profile_as_it_is() {
    let dir = tempfile::tempdir().unwrap();
    let (slab, o) = slab(dir.path());
    let deep = dir.path().join("deep.exr");
    let r = bake(
        &slab,
        &deep,
        BakeOptions {
            deep: true,
            stderr: false,
            ..o.clone()
        },
    );
    let camera = r.map.camera;
    let depths = umbra::bake::soft_deep_depths(&camera);
    assert_eq!(depths.len(), umbra::bake::SOFT_DEEP_DEPTHS + 1);
    let flat = bake(
        &slab,
        &dir.path().join("flat.exr"),
        BakeOptions {
            depths: Some(depths.clone()),
            ..o
        },
    )
    .map;
    let (w, h) = (camera.width() as usize, camera.height() as usize);
    let Some(pixels) = crate::common::deep_dump(&deep, w, h) else {
        return;
    };
    let mut negative = 0;
    for (p, samples) in pixels.iter().enumerate() {
        // The samples the slices call for: A = 1 - T_k / T_(k-1) between receivers, from 0.
        let mut want = Vec::new();
        let (mut z0, mut t0) = (0.0f64, 1.0f64);
        for (k, &z) in depths.iter().enumerate() {
            let t = f64::from(flat.slices[k][p]);
            let a = 1.0 - t / t0;
            if a != 0.0 {
                want.push([a as f32, z0 as f32, z as f32]);
            }
            (z0, t0) = (z, t);
        }
        assert_eq!(samples.len(), want.len(), "texel {p}");
        for (s, w) in samples.iter().zip(&want) {
            let v = |c: &str| s.iter().find(|(n, _)| n == c).unwrap().1;
            let got = [v("A"), v("Z"), v("ZBack")];
            for (g, w) in got.iter().zip(w) {
                // oiiotool prints about 6 significant digits.
                assert!(
                    (g - w).abs() <= 1e-5 * w.abs() + 1e-6,
                    "texel {p}: {got:?} vs {w:?}"
                );
            }
            negative += usize::from(got[0] < 0.0);
        }
    }
    assert!(negative > 0, "no rising sample");
    let centre = (h / 2) * w + w / 2;
    let profile: Vec<f32> = flat.slices.iter().map(|s| s[centre]).collect();
    assert!(
        profile.windows(2).any(|p| p[1] > p[0] + 0.05),
        "{profile:?}"
    );
}

/// A 16 x 8 x 16 slab of density 2 (unit voxels, y in [0, 8]) under a sphere light of radius
/// 20 centred 40 above it: just below the slab it hides the whole light, far below it hides a
/// small part, so `T_L` along the ray through the slab's centre rises with depth.
#[test]
fn a_slab_near_a_sphere_light_gives_a_rising_profile() {
    let dir = tempfile::tempdir().unwrap();
    let (slab, o) = slab(dir.path());
    let out = dir.path().join("slab.exr");
    // Depths from the light's centre down its central ray (the slab spans 32..40): just
    // below it, then 40, 80, 160 and 360 below.
    let depths = vec![41.0, 80.0, 120.0, 200.0, 400.0];
    let o = BakeOptions {
        depths: Some(depths.clone()),
        ..o
    };
    let r = bake(&slab, &out, o);
    let (w, h) = (
        r.map.camera.width() as usize,
        r.map.camera.height() as usize,
    );
    let centre = (h / 2) * w + w / 2;
    let profile: Vec<f32> = r.map.slices.iter().map(|s| s[centre]).collect();
    assert!(profile[0] < 0.05, "{profile:?}");
    assert!(profile.windows(2).all(|p| p[1] > p[0]), "{profile:?}");
    assert!(profile[4] > 0.5, "{profile:?}");
}

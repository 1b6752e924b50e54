//! Fixed-size deep maps (`bake --deep-format`, `Product::Fixed`) on the corpus's extreme media
//! (optical depth 1e6 and 1e-8, NaN/Inf and negative voxels, a level set as a solid), read back
//! with the exr crate: every texel's reconstruction is in `[0, 1]` and never grows with depth at
//! 200 depths, and the header's error bound holds at 24 depths against the exact `T` of regular
//! tracking on the texel's ray cut at that depth (`umbra::regular::optical_depth`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use exr::prelude::*;
use std::path::{Path, PathBuf};
use umbra::bake::{BakeJob, BakeSettings, DeepFormat, Product, Projection, Resolution, View};
use umbra::estimate::{Estimator, Options};
use umbra::Volume;

const FORMATS: [&str; 4] = ["fourier:9", "moments:4", "moments:6", "avsm:6"];

fn corpus(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus/gen")
        .join(name)
}

fn job(input: &Path, out: PathBuf, format: DeepFormat, solid: bool) -> BakeJob {
    BakeJob {
        source: umbra::input::Source::new(
            input.to_path_buf(),
            umbra::input::SourceOptions {
                grid: if solid {
                    "ls_sphere".into()
                } else {
                    "density".into()
                },
                density_scale: 1.0,
                levelset: (solid).then_some(umbra::input::LevelSet::Solid),
                ..umbra::input::SourceOptions::default()
            },
        ),
        view: View {
            projection: Projection::Ortho,
            light_dir: Some([0.3, -1.0, 0.2]),
            res: Some(Resolution::Exact(20, 18)),
            ..View::default()
        },
        camera: None,
        settings: BakeSettings::new(Estimator::REGULAR, Options::default()),
        output: out,
        preview: None,
        overwrite: true,
        max_memory: None,
        layout: umbra::bake::ExrLayout::default(),
        product: Product::Fixed { format },
        key: None,
    }
}

/// A written map's channels (name, values) and its `umbra:*` f32/f64 attributes.
type Read = (
    Vec<(String, Vec<f32>)>,
    std::collections::HashMap<String, f64>,
);

/// Every channel of the written map by name, and its `umbra:*` f32/f64 attributes.
fn read(path: &Path) -> Read {
    let img = read_all_flat_layers_from_file(path).unwrap();
    let layer = &img.layer_data[0];
    let chans = layer
        .channel_data
        .list
        .iter()
        .map(|c| {
            let v: Vec<f32> = c.sample_data.values_as_f32().collect();
            (c.name.to_string(), v)
        })
        .collect();
    let attrs = layer
        .attributes
        .other
        .iter()
        .filter_map(|(k, v)| match v {
            exr::meta::attribute::AttributeValue::F32(x) => Some((k.to_string(), f64::from(*x))),
            exr::meta::attribute::AttributeValue::F64(x) => Some((k.to_string(), *x)),
            _ => None,
        })
        .collect();
    (chans, attrs)
}

/// Every texel's stored values, in the order of the format's channel names (`deep.<name>`).
fn texels(format: DeepFormat, chans: &[(String, Vec<f32>)]) -> Vec<Vec<f32>> {
    let cols: Vec<&Vec<f32>> = format
        .channel_names()
        .iter()
        .map(|n| {
            &chans
                .iter()
                .find(|(c, _)| *c == format!("deep.{n}"))
                .unwrap()
                .1
        })
        .collect();
    (0..cols[0].len())
        .map(|p| cols.iter().map(|v| v[p]).collect())
        .collect()
}

/// The texel's T in [0, 1] and never growing (beyond 1e-12) at 201 depths.
fn monotone_and_bounded(format: DeepFormat, c: &[f32], what: &str) {
    let mut prev = 1.0f64;
    for k in 0..=200 {
        let t = format.transmittance(c, f64::from(k) / 200.0);
        assert!((0.0..=1.0).contains(&t), "{what}: T = {t}");
        assert!(t <= prev + 1e-12, "{what}: T grows to {t}");
        prev = t;
    }
}

#[test]
fn extreme_media_give_monotone_bounded_texels_within_the_reported_error() {
    let files = [
        ("extreme_thick_1e6.vdb", false),
        ("extreme_tiny_1e-8.vdb", false),
        ("extreme_nan_inf.vdb", false),
        ("extreme_negative.vdb", false),
        ("sphere_levelset.vdb", true),
    ];
    let dir = tempfile::tempdir().unwrap();
    for (name, solid) in files {
        let input = corpus(name);
        for f in FORMATS {
            let format: DeepFormat = f.parse().unwrap();
            let out = dir.path().join("m.exr");
            let j = job(&input, out.clone(), format, solid);
            let report = j.run(&|_| {}).unwrap();
            let stats = report.fixed.unwrap();
            let (chans, attrs) = read(&out);
            let bound = attrs["umbra:deep_max_error"];
            assert!(
                bound >= stats.max_error && bound <= 1.0,
                "{name} {f}: {bound}"
            );
            let (near, far) = (attrs["umbra:deep_near"], attrs["umbra:deep_far"]);
            let texels = texels(format, &chans);
            let cam = &report.map.camera;
            let vol = (!solid).then(|| Volume::load(&input, "density", 1.0).unwrap());
            for (p, c) in texels.iter().enumerate() {
                monotone_and_bounded(format, c, &format!("{name} {f} texel {p}"));
                // The bound against exact regular tracking (fog volumes; the level set is a
                // solid, whose first hit the deep profile holds).
                let Some(vol) = vol.as_ref() else {
                    continue;
                };
                let (i, jj) = (
                    (p % cam.width() as usize) as u32,
                    (p / cam.width() as usize) as u32,
                );
                let ray = cam.pixel_ray(i, jj).unwrap();
                for k in 0..24 {
                    let z = near + (far - near) * (f64::from(k) + 0.5) / 24.0;
                    let cut = ray.with_range(ray.t_min(), z).unwrap();
                    let exact = umbra::regular::optical_depth(vol, &cut, umbra::Interp::Trilinear)
                        .unwrap()
                        .transmittance();
                    let got = format.transmittance(c, (z - near) / (far - near));
                    assert!(
                        (got - exact).abs() <= bound + 1e-6,
                        "{name} {f} texel {p} depth {z}: {got} vs exact {exact} (bound {bound})"
                    );
                }
            }
        }
    }
}

#[test]
fn the_stress_catalogue_gives_monotone_bounded_texels() {
    // Every medium of `compare --stress` (densities 1e-8 to 1e6, spikes, majorant ratios of
    // 1e6, NaN/-Inf/negative/+Inf voxels, half floats, huge coordinates, tiny and huge voxels,
    // tiles only), baked in every format seen from above: each texel's T in [0, 1] and never
    // growing at 200 depths, the header's bound finite and at most 1.
    let dir = tempfile::tempdir().unwrap();
    let mut baked = 0;
    for case in umbra::compare::stress::catalogue(1).unwrap() {
        let scene = umbra::scene::Scene::from_volume(case.volume);
        let Ok(corners) = scene.box_corners() else {
            continue; // the empty grid frames nothing
        };
        let view = View {
            projection: Projection::Ortho,
            light_dir: Some([0.3, -1.0, 0.2]),
            res: Some(Resolution::Exact(12, 12)),
            ..View::default()
        };
        let camera = umbra::bake::Camera::frame(&view, &corners).unwrap();
        for f in FORMATS {
            let format: DeepFormat = f.parse().unwrap();
            let out = dir.path().join("s.exr");
            let mut j = job(&corpus("extreme_tiny_1e-8.vdb"), out.clone(), format, false);
            j.view = view;
            let report = j.run_loaded(&scene, camera, &|_| {}).unwrap();
            let stats = report.fixed.unwrap();
            assert!(
                stats.max_error.is_finite() && stats.max_error <= 1.0,
                "{}",
                case.name
            );
            let (chans, _) = read(&out);
            let texels = texels(format, &chans);
            for (p, c) in texels.iter().enumerate() {
                assert!(c.iter().all(|v| v.is_finite()), "{} {f}: {c:?}", case.name);
                monotone_and_bounded(format, c, &format!("{} {f} texel {p}", case.name));
            }
            baked += 1;
        }
    }
    assert!(baked >= 10 * FORMATS.len(), "{baked} maps");
}

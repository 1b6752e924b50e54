//! Deep shadow maps (`bake --deep`, `Product::Deep`), read back by OpenImageIO: every sample of
//! every pixel as `oiiotool --dumpdata` prints it, interpreted as OpenEXR's "Interpreting
//! OpenEXR Deep Pixels" defines volumetric samples (alpha grows exponentially across `[Z,
//! ZBack]`, samples composited front to back; the formula is written out here, not taken from
//! umbra), gives `T(z)` within the bound `E` of the exact prefix transmittance
//! `exp(-tau(0, z))` (regular tracking on the pixel's ray cut at `z`) at many depths of every
//! pixel; `oiiotool --flatten` composites the samples to the full-depth `1 - T`. Without
//! oiiotool the tests fail unless `UMBRA_SKIP_OIIO=1`.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use umbra::bake::{
    BakeJob, BakeReport, BakeSettings, Depths, Product, Projection, Resolution, View,
};
use umbra::estimate::{Estimator, Options};
use umbra::{Interp, Volume};

fn cloud() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb")
}

fn job(out: PathBuf, est: Estimator, interp: Interp, product: Product) -> BakeJob {
    BakeJob {
        source: umbra::input::Source::new(
            cloud(),
            umbra::input::SourceOptions {
                grid: "density".into(),
                density_scale: 4.0,
                ..umbra::input::SourceOptions::default()
            },
        ),
        view: View {
            projection: Projection::Ortho,
            light_dir: Some([0.3, -1.0, 0.2]),
            res: Some(Resolution::Exact(40, 36)),
            ..View::default()
        },
        camera: None,
        settings: BakeSettings::new(
            est,
            Options {
                samples: 16,
                seed: 3,
                interp,
                ..Options::default()
            },
        ),
        output: out,
        preview: None,
        overwrite: false,
        max_memory: None,
        layout: umbra::bake::ExrLayout::default(),
        product,
        key: None,
    }
}

fn oiiotool(args: &[&str]) -> Option<String> {
    common::oiio_tool("oiiotool", args)
}

/// One deep sample as read back: channel name to value.
type Sample = BTreeMap<String, f64>;

/// Every pixel's samples, row-major, from `oiiotool --dumpdata`.
fn dump(path: &Path, w: usize, h: usize) -> Option<Vec<Vec<Sample>>> {
    Some(
        common::deep_dump(path, w, h)?
            .into_iter()
            .map(|px| {
                px.into_iter()
                    .map(|s| s.into_iter().map(|(c, v)| (c, f64::from(v))).collect())
                    .collect()
            })
            .collect(),
    )
}

/// `T(z)` of channel `alpha` (`A`, `R`, `G` or `B`) of a pixel's samples, as OpenEXR defines
/// volumetric samples: a sample `[Z, ZBack]` of alpha `a` lets `(1 - a)^((z - Z) / (ZBack - Z))`
/// through up to depth `z` inside it, all of `1 - a` behind it; a point sample (`Z = ZBack`)
/// acts at `Z`.
fn t_at(samples: &[Sample], alpha: &str, z: f64) -> f64 {
    let mut t = 1.0;
    for s in samples {
        let (z0, z1, a) = (s["Z"], s["ZBack"], s[alpha]);
        if z >= z1 {
            t *= 1.0 - a;
        } else if z > z0 {
            t *= (1.0 - a).powf((z - z0) / (z1 - z0));
        }
    }
    t
}

/// Sorted, non-overlapping, alphas in `[0, 1]`.
fn check_order(samples: &[Sample], channels: &[&str]) {
    for s in samples {
        assert!(s["Z"] <= s["ZBack"], "{s:?}");
        for c in channels {
            assert!((0.0..=1.0).contains(&s[*c]), "{s:?}");
        }
    }
    for w in samples.windows(2) {
        assert!(w[0]["ZBack"] <= w[1]["Z"], "{w:?}");
    }
}

/// Bake, read back, and compare every pixel at many depths with the exact prefix
/// transmittance `exp(-sigma_c tau(0, z))`. Returns the largest error seen and the report.
fn check_exact(
    dir: &Path,
    name: &str,
    interp: Interp,
    e: f64,
    sigma: Option<[f64; 3]>,
) -> Option<(f64, BakeReport)> {
    let out = dir.join(name);
    let mut j = job(
        out.clone(),
        Estimator::REGULAR,
        interp,
        Product::Deep { max_error: e },
    );
    j.source.options_mut().sigma_t = sigma;
    if name.starts_with("persp") {
        // A pinhole light outside the box, aimed at it.
        j.view = View {
            projection: Projection::Perspective,
            light_pos: Some([4.0, 10.0, 3.0]),
            res: Some(Resolution::Exact(36, 32)),
            ..View::default()
        };
    }
    let report = j.run(&|_| {}).unwrap();
    let cam = report.map.camera;
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let pixels = dump(&out, w, h)?;
    let vol = Volume::load(cloud(), "density", 4.0).unwrap();
    // Per-channel alphas (OpenEXR's AR, AG, AB) for colour, A of the mean optical depth.
    let channels: Vec<(&str, f64)> = match sigma {
        None => vec![("A", 1.0)],
        Some(s) => vec![
            ("A", (s[0] + s[1] + s[2]) / 3.0),
            ("AR", s[0]),
            ("AG", s[1]),
            ("AB", s[2]),
        ],
    };
    let names: Vec<&str> = channels.iter().map(|c| c.0).collect();
    let mut worst = 0.0f64;
    let stats = report.deep.unwrap();
    let mut samples = 0u64;
    for j in 0..h {
        for i in 0..w {
            let px = &pixels[j * w + i];
            samples += px.len() as u64;
            check_order(px, &names);
            let ray = cam.pixel_ray(i as u32, j as u32).unwrap();
            let full = umbra::regular::optical_depth(&vol, &ray, interp)
                .unwrap()
                .tau;
            if full == 0.0 {
                assert!(px.is_empty(), "pixel ({i}, {j}) meets nothing: no samples");
            }
            // Evenly spaced depths plus every sample boundary and its neighbourhood.
            let mut depths: Vec<f64> = (0..=48)
                .map(|k| ray.t_max() * f64::from(k) / 48.0)
                .collect();
            for s in px {
                for z in [s["Z"], s["ZBack"]] {
                    depths.extend([z, z * (1.0 - 1e-6), z * (1.0 + 1e-6)]);
                }
                depths.push(0.5 * (s["Z"] + s["ZBack"]));
            }
            for z in depths
                .into_iter()
                .filter(|z| (0.0..=ray.t_max()).contains(z))
            {
                let tau =
                    umbra::regular::optical_depth(&vol, &ray.with_range(0.0, z).unwrap(), interp)
                        .unwrap()
                        .tau;
                for (c, s) in &channels {
                    let exact = (-s * tau).exp();
                    let got = t_at(px, c, z);
                    let err = (got - exact).abs();
                    worst = worst.max(err);
                    assert!(
                        err <= e,
                        "{name} pixel ({i}, {j}) {c} at z = {z}: {got} vs exact {exact}"
                    );
                }
            }
        }
    }
    assert_eq!(samples, stats.samples);
    // OpenImageIO's own compositing: the flattened alpha is 1 - T over the whole ray (OIIO
    // composites AR/AG/AB as colours, so only A is checked this way).
    let flat = dir.join(format!("{name}.flat.exr"));
    oiiotool(&[
        out.to_str().unwrap(),
        "--flatten",
        "-o",
        flat.to_str().unwrap(),
    ])?;
    let img = exr::prelude::read_all_flat_layers_from_file(&flat).unwrap();
    let layer = &img.layer_data[0];
    // A colour map's flattening is left out: with AR/AG/AB present OIIO composites A
    // its own way (not the product of 1 - A the file's samples give).
    let flat_channels = if sigma.is_none() {
        &channels[..1]
    } else {
        &channels[..0]
    };
    for (c, s) in flat_channels {
        let ch = layer
            .channel_data
            .list
            .iter()
            .find(|ch| ch.name.to_string() == *c)
            .unwrap();
        for (p, a) in ch.sample_data.values_as_f32().enumerate() {
            let ray = cam.pixel_ray((p % w) as u32, (p / w) as u32).unwrap();
            let tau = umbra::regular::optical_depth(&vol, &ray, interp)
                .unwrap()
                .tau;
            let exact = (-s * tau).exp();
            assert!(
                (1.0 - f64::from(a) - exact).abs() <= e,
                "{name} flattened pixel {p} {c}: {} vs {exact}",
                1.0 - a
            );
        }
    }
    Some((worst, report))
}

#[test]
fn exact_deep_maps_hold_the_bound_at_every_depth() {
    let dir = tempfile::tempdir().unwrap();
    for (name, interp, e) in [
        ("tri.exr", Interp::Trilinear, 0.002),
        ("tri_loose.exr", Interp::Trilinear, 0.02),
        ("near.exr", Interp::Nearest, 0.002),
        ("persp.exr", Interp::Trilinear, 0.002),
    ] {
        let Some((worst, report)) = check_exact(dir.path(), name, interp, e, None) else {
            return;
        };
        let d = report.deep.unwrap();
        println!(
            "{name}: E {e}, worst {worst:.2e}, {:.2} samples/pixel, {:.1} breakpoints/pixel",
            d.mean_samples(),
            d.breakpoints as f64 / d.pixels as f64
        );
        // The bound is used, not met trivially by sampling everything.
        assert!(worst > e / 20.0, "{name}: worst error {worst}");
        assert!(d.mean_samples() < d.breakpoints as f64 / d.pixels as f64 / 2.0);
        assert!(d.empty_pixels > 0 && d.empty_pixels < d.pixels);
        assert_eq!(d.coarse_cells, 0);
    }
}

#[test]
fn colour_deep_maps_fit_every_channel() {
    let dir = tempfile::tempdir().unwrap();
    let Some((_, report)) = check_exact(
        dir.path(),
        "rgb.exr",
        Interp::Trilinear,
        0.002,
        Some([1.0, 0.5, 0.25]),
    ) else {
        return;
    };
    let info = oiiotool(&["--info", "-v", dir.path().join("rgb.exr").to_str().unwrap()]).unwrap();
    assert!(
        info.contains("channel list: A, AR, AG, AB, Z, ZBack"),
        "{info}"
    );
    // The camera travels with the deep map, as with a flat one.
    for attr in [
        "worldToCamera",
        "worldToNDC",
        "umbra:camera_origin",
        "umbra:camera_step_x",
        "umbra:camera_direction",
        "umbra:camera_t_max",
        "umbra:deep_error: 0.002",
        "umbra:sigma_t",
    ] {
        assert!(info.contains(attr), "{attr} missing: {info}");
    }
    assert!(report.deep.unwrap().samples > 0);
}

#[test]
fn looser_bounds_take_fewer_samples() {
    let dir = tempfile::tempdir().unwrap();
    let mut last = u64::MAX;
    for e in [0.0005, 0.002, 0.01, 0.05] {
        let r = job(
            dir.path().join(format!("e{e}.exr")),
            Estimator::REGULAR,
            Interp::Trilinear,
            Product::Deep { max_error: e },
        )
        .run(&|_| {})
        .unwrap();
        let n = r.deep.unwrap().samples;
        assert!(n < last, "E {e}: {n} samples, {last} at the tighter bound");
        last = n;
    }
}

/// A stochastic estimator's deep map is the deep function of its estimate: at each of the 64
/// depths it equals (within E) the running minimum of the flat map's `--slices 64` channels,
/// which use the same ray ids.
#[test]
fn stochastic_deep_maps_follow_their_slices() {
    let dir = tempfile::tempdir().unwrap();
    let ratio = Estimator::from_name("ratio").unwrap();
    let e = 0.002;
    let out = dir.path().join("ratio.exr");
    let report = job(
        out.clone(),
        ratio,
        Interp::Trilinear,
        Product::Deep { max_error: e },
    )
    .run(&|_| {})
    .unwrap();
    let mut flat = job(
        dir.path().join("ratio_flat.exr"),
        ratio,
        Interp::Trilinear,
        Product::Map,
    );
    flat.settings.depths = Depths::Slices(64);
    let flat = flat.run(&|_| {}).unwrap().map;
    let cam = report.map.camera;
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let Some(pixels) = dump(&out, w, h) else {
        return;
    };
    assert_eq!(flat.depths.len(), 64);
    for (p, px) in pixels.iter().enumerate() {
        let mut running = 1.0f64;
        for (k, z) in flat.depths.iter().enumerate() {
            running = running.min(f64::from(flat.slices[k][p]).clamp(0.0, 1.0));
            // The file holds f32 depths: the slice depth as the file can name it.
            let got = t_at(px, "A", f64::from(*z as f32));
            assert!(
                (got - running).abs() <= e,
                "pixel {p} depth {k}: deep {got} vs slice {running}"
            );
        }
    }
    assert!(report.map.slices.is_empty() && report.map.depths.is_empty());
}

#[test]
fn deep_maps_refuse_flat_only_options() {
    let dir = tempfile::tempdir().unwrap();
    let deep = Product::Deep { max_error: 0.002 };
    let base = || {
        job(
            dir.path().join("x.exr"),
            Estimator::REGULAR,
            Interp::Trilinear,
            deep,
        )
    };
    let mut cases: Vec<(&str, BakeJob)> = Vec::new();
    let mut j = base();
    j.layout.tile = Some(32);
    cases.push(("tile", j));
    let mut j = base();
    j.settings.depths = Depths::Slices(4);
    cases.push(("slices", j));
    let mut j = base();
    j.settings.std_err = true;
    cases.push(("stderr", j));
    let mut j = base();
    j.max_memory = Some(1 << 30);
    cases.push(("max-memory", j));
    for e in [0.0, 1.0, -0.1, f64::NAN] {
        let mut j = base();
        j.product = Product::Deep { max_error: e };
        cases.push(("deep-error", j));
    }
    for (flag, j) in cases {
        match j.run(&|_| {}) {
            Err(umbra::Error::InvalidArgument { name, .. }) => assert_eq!(name, flag),
            other => panic!("{flag}: {other:?}"),
        }
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

/// A scene (two tinted fog volumes and a solid sphere, `examples/scene/shot.toml`): every
/// channel's `T(z)` within E of the exact scene transmittance over `[0, z]` (regular tracking
/// in each volume, zero past the sphere), the sphere a point sample of alpha 1 where the ray
/// meets it. Depths within an f32 step of a point sample are the file's resolution there
/// and are left out.
#[test]
fn scene_deep_maps_hold_the_bound_and_stop_at_solids() {
    let dir = tempfile::tempdir().unwrap();
    let shot = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/scene/shot.toml");
    if !shot
        .with_file_name("../../../shared/corpus/gen/sphere_levelset.vdb")
        .exists()
    {
        assert!(
            std::env::var_os("CI").is_none(),
            "../shared/corpus is needed under CI"
        );
        return;
    }
    let e = 0.002;
    let out = dir.path().join("scene.exr");
    let mut j = job(
        out.clone(),
        Estimator::REGULAR,
        Interp::Trilinear,
        Product::Deep { max_error: e },
    );
    j.source = umbra::input::Source::new(
        &shot,
        umbra::input::SourceOptions {
            density_scale: 3.0,
            ..j.source.options().clone()
        },
    );
    j.view.light_dir = Some([-0.4, -1.0, -0.3]);
    let report = j.run(&|_| {}).unwrap();
    let scene = j.source.load().unwrap();
    let cam = report.map.camera;
    let (w, h) = (cam.width() as usize, cam.height() as usize);
    let Some(pixels) = dump(&out, w, h) else {
        return;
    };
    let opts = Options {
        interp: Interp::Trilinear,
        ..Options::default()
    };
    let (mut opaque, mut checked) = (0, 0);
    for jj in 0..h {
        for i in 0..w {
            let px = &pixels[jj * w + i];
            check_order(px, &["A", "AR", "AG", "AB"]);
            let points: Vec<f64> = px
                .iter()
                .filter(|s| s["Z"] == s["ZBack"])
                .map(|s| s["Z"])
                .collect();
            opaque += points.len();
            let ray = cam.pixel_ray(i as u32, jj as u32).unwrap();
            for k in 0..=32 {
                let z = ray.t_max() * f64::from(k) / 32.0;
                if points
                    .iter()
                    .any(|p| (z - p).abs() <= 4.0 * f64::from(f32::EPSILON) * p.abs())
                {
                    continue;
                }
                let est = umbra::scene::estimate(
                    &scene,
                    &ray.with_range(0.0, z).unwrap(),
                    0,
                    &Estimator::REGULAR,
                    &opts,
                )
                .unwrap();
                let tau = est.tau.unwrap();
                let mean = (tau[0] + tau[1] + tau[2]) / 3.0;
                for (c, t) in [("AR", tau[0]), ("AG", tau[1]), ("AB", tau[2]), ("A", mean)] {
                    let exact = (-t).exp();
                    let got = t_at(px, c, z);
                    assert!(
                        (got - exact).abs() <= e,
                        "pixel ({i}, {jj}) {c} at z = {z}: {got} vs exact {exact}"
                    );
                }
                checked += 1;
            }
        }
    }
    // The sphere's shadow is in the map, as point samples of alpha 1.
    assert!(opaque >= 5, "{opaque} opaque samples");
    assert!(checked > w * h * 30);
    for px in &pixels {
        for s in px.iter().filter(|s| s["Z"] == s["ZBack"]) {
            assert_eq!((s["A"], s["AR"], s["AG"], s["AB"]), (1.0, 1.0, 1.0, 1.0));
        }
    }
}

/// The CLI: `--deep-error` needs `--deep` (usage, exit 2); a bad bound is a one-line error
/// (exit 1); `--json` carries the deep counts.
#[test]
fn cli_deep_flags() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("d.exr");
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_umbra"))
            .arg("bake")
            .arg(cloud())
            .args(["--light-dir=0.3,-1,0.2", "--res", "32", "-o"])
            .arg(&out)
            .args(args)
            .output()
            .unwrap()
    };
    // The library refuses it, naming the flag (a job says `bake.deep_error`, Python
    // `deep_error`).
    let o = run(&["--deep-error", "0.01"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("'--deep-error': applies to deep maps"));
    let bad = run(&["--deep", "--deep-error", "1.5"]);
    assert_eq!(bad.status.code(), Some(1));
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.starts_with("umbra: error:") && err.contains("--deep-error"),
        "{err}"
    );
    assert!(!out.exists());
    let ok = run(&["--deep", "--json", "--quiet"]);
    assert!(ok.status.success());
    let j: serde_json::Value = serde_json::from_slice(&ok.stdout).unwrap();
    assert_eq!(j["deep"]["max_error"], 0.002);
    assert!(j["deep"]["samples"].as_u64().unwrap() > 0);
    assert!(out.exists());
}

/// A batch job's `deep = true` / `deep_error` bakes the CLI's deep map (same samples; the
/// files differ only in the provenance a batch task records), and `deep_error` without
/// `deep` is refused naming the key.
#[test]
fn batch_jobs_write_deep_maps() {
    let dir = tempfile::tempdir().unwrap();
    let job = |extra: &str| {
        let p = dir.path().join("job.toml");
        std::fs::write(
            &p,
            format!(
                "output = \"{}/{{stem}}_{{light}}.exr\"\n[[inputs]]\nfile = {:?}\n\
                 [[lights]]\nname = \"sun\"\ndir = [0.3, -1, 0.2]\n[bake]\nres = [40, 30]\n\
                 density_scale = 4\n{extra}\n",
                dir.path().display(),
                cloud().display().to_string()
            ),
        )
        .unwrap();
        Command::new(env!("CARGO_BIN_EXE_umbra"))
            .args(["batch", p.to_str().unwrap(), "-q", "--force"])
            .output()
            .unwrap()
    };
    let bad = job("deep_error = 0.01");
    assert_eq!(bad.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("bake.deep_error"));
    let o = job("deep = true\ndeep_error = 0.01");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cli = dir.path().join("cli.exr");
    let c = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .arg("bake")
        .arg(cloud())
        .args([
            "--light-dir=0.3,-1,0.2",
            "--res",
            "40x30",
            "--density-scale",
            "4",
        ])
        .args(["--deep", "--deep-error", "0.01", "-q", "-o"])
        .arg(&cli)
        .output()
        .unwrap();
    assert!(c.status.success());
    let Some(a) = dump(&dir.path().join("cloud_sun.exr"), 40, 30) else {
        return;
    };
    let b = dump(&cli, 40, 30).unwrap();
    assert_eq!(a, b);
    assert!(a.iter().map(Vec::len).sum::<usize>() > 0);
}

/// `BakeJob::run_loaded` (the scene borrowed, as the Python module keeps it) writes the same
/// deep and flat files as `run`.
#[test]
fn run_loaded_writes_what_run_writes() {
    let dir = tempfile::tempdir().unwrap();
    for product in [Product::Deep { max_error: 0.005 }, Product::Map] {
        let a = dir.path().join("a.exr");
        let b = dir.path().join("b.exr");
        let j = job(a.clone(), Estimator::REGULAR, Interp::Trilinear, product);
        let ra = j.run(&|_| {}).unwrap();
        let jb = BakeJob {
            output: b.clone(),
            ..j.clone()
        };
        let (scene, camera) = jb.prepare().unwrap();
        let rb = jb.run_loaded(&scene, camera, &|_| {}).unwrap();
        assert_eq!(
            std::fs::read(&a).unwrap(),
            std::fs::read(&b).unwrap(),
            "{product:?}"
        );
        assert_eq!(ra.deep.map(|d| d.samples), rb.deep.map(|d| d.samples));
        std::fs::remove_file(&a).unwrap();
        std::fs::remove_file(&b).unwrap();
    }
}

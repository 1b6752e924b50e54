//! Blurred maps in parts under a memory budget (`--max-memory` with a velocity): runs of image
//! rows on the ray path, each decoding the density leaves within the reach of the blocks its
//! rays cross, all sharing blurred bounds built from per-leaf ranges. Every `riemann` pixel must
//! be the whole bake's, bit for bit, for cell-centred and staggered velocities, a huge reach and
//! depth slices; a `ratio` pixel within its error bars (a whole bake's null collisions walk the
//! bounds per shutter interval, which a bake in parts does not build); a budget below the least
//! part is refused naming the flag.

use std::path::{Path, PathBuf};
use umbra::estimate::{Estimator, Options};

/// The moving cloud of `tests/motion/make_moving_cloud.py` (pyopenvdb) with `args`.
fn moving_cloud(dir: &Path, name: &str, args: &[&str]) -> PathBuf {
    let out = dir.join(name);
    let script =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/motion/make_moving_cloud.py");
    let o = std::process::Command::new("/usr/bin/python3")
        .arg(&script)
        .arg(&out)
        .args(args)
        .output()
        .expect("python3-openvdb (Debian) makes the test cache");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    out
}

/// A blurred map of `path` by `estimator` (2 samples, seed 7, the standard error and 2 slices).
fn job(
    path: &Path,
    out: PathBuf,
    estimator: &str,
    max_memory: Option<u64>,
) -> umbra::bake::BakeJob {
    use umbra::bake::{BakeJob, BakeSettings, Depths, Projection, Resolution, View};
    let options = Options {
        samples: 2,
        seed: 7,
        ..Options::default()
    };
    let mut settings = BakeSettings::new(Estimator::from_name(estimator).unwrap(), options);
    settings.depths = Depths::Slices(2);
    settings.std_err = true;
    BakeJob {
        source: umbra::input::Source::new(
            path.to_path_buf(),
            umbra::input::SourceOptions {
                grid: "density".into(),
                density_scale: 4.0,
                velocity: Some("vel".into()),
                time_samples: Some(3),
                ..umbra::input::SourceOptions::default()
            },
        ),
        view: View {
            projection: Projection::Ortho,
            light_dir: Some([0.3, -1.0, 0.2]),
            light_pos: None,
            fov_deg: None,
            res: Some(Resolution::Exact(120, 90)),
            up: None,
            frame_box: None,
        },
        camera: None,
        settings,
        output: out,
        preview: None,
        overwrite: true,
        max_memory,
        layout: umbra::bake::ExrLayout::default(),
        product: umbra::bake::Product::Map,
        key: None,
    }
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Whole and in parts, the same map: T, standard error, slices, lookups and the EXR's bytes.
/// With `light_pos`, a pinhole there (its rays start far outside the blurred bounds).
fn parts_equal_whole(dir: &Path, path: &Path, estimator: &str, light_pos: Option<[f64; 3]>) {
    let what = format!("{} {estimator} {light_pos:?}", path.display());
    let job = |out: &str, max_memory| {
        let mut j = job(path, dir.join(out), estimator, max_memory);
        if let Some(p) = light_pos {
            j.view.projection = umbra::bake::Projection::Perspective;
            j.view.light_pos = Some(p);
            j.view.light_dir = None;
        }
        j
    };
    let whole = job("whole.exr", None).run(&|_| {}).unwrap();
    assert_eq!(whole.map.stats.parts, 0, "{what}");
    let least = crate::lazy::least_budget(&job("p.exr", None));
    let r = job("parts.exr", Some(least + (2 << 20)))
        .run(&|_| {})
        .unwrap();
    assert!(
        r.map.stats.parts >= 2,
        "{what}: {} parts",
        r.map.stats.parts
    );
    assert!(!r.map.stats.sweep, "{what}");
    assert_eq!(r.map.stats.majorant_violations, 0, "{what}");
    if estimator != "riemann" {
        // A whole bake's null collisions walk the bounds per interval of the shutter, which
        // need every voxel at once; a bake in parts walks the whole shutter's (as valid, looser):
        // other walks, the same expectation. Every pixel within its error bars.
        let (ea, eb) = (
            r.map.std_err.as_ref().unwrap(),
            whole.map.std_err.as_ref().unwrap(),
        );
        let mut beyond = 0;
        for n in 0..r.map.t.len() {
            let d = f64::from((r.map.t[n] - whole.map.t[n]).abs());
            let s = f64::from(ea[n]).hypot(f64::from(eb[n]));
            assert!(
                d <= 6.0 * s + 1e-6,
                "{what} pixel {n}: {d} vs error bar {s}"
            );
            beyond += usize::from(d > 3.0 * s + 1e-6);
        }
        assert!(
            beyond * 100 < r.map.t.len(),
            "{what}: {beyond} pixels beyond 3 sigma"
        );
        assert!(
            whole.map.t.iter().any(|&t| t > 0.05 && t < 0.95),
            "{what}: nothing to compare"
        );
        return;
    }
    assert_eq!(bits(&r.map.t), bits(&whole.map.t), "{what}");
    assert_eq!(
        bits(r.map.std_err.as_ref().unwrap()),
        bits(whole.map.std_err.as_ref().unwrap()),
        "{what}"
    );
    assert_eq!(r.map.slices.len(), 2, "{what}");
    for (a, b) in r.map.slices.iter().zip(&whole.map.slices) {
        assert_eq!(bits(a), bits(b), "{what} slices");
    }
    assert_eq!(r.map.stats.lookups, whole.map.stats.lookups, "{what}");
    assert_eq!(r.map.stats.majorant_violations, 0, "{what}");
    // The map blurs: somewhere it is neither empty nor opaque.
    assert!(
        whole.map.t.iter().any(|&t| t > 0.05 && t < 0.95),
        "{what}: nothing to compare"
    );
    let a = std::fs::read(dir.join("whole.exr")).unwrap();
    let b = std::fs::read(dir.join("parts.exr")).unwrap();
    assert!(a == b, "{what}: the EXR files differ");
}

#[test]
fn blurred_maps_in_parts_equal_whole_bakes_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let centred = moving_cloud(dir.path(), "centred.vdb", &["--copies", "3", "2", "2"]);
    let staggered = moving_cloud(
        dir.path(),
        "staggered.vdb",
        &["--copies", "3", "2", "2", "--staggered"],
    );
    for path in [&centred, &staggered] {
        for estimator in ["riemann", "ratio"] {
            parts_equal_whole(dir.path(), path, estimator, None);
        }
    }
    // A pinhole far outside the cache.
    parts_equal_whole(dir.path(), &centred, "riemann", Some([30.0, 40.0, 25.0]));
}

/// A velocity that moves density ~80 voxels over the shutter (its reach crosses lower nodes):
/// each run loads far more leaves than its rays cross, and still equals the whole bake.
#[test]
fn a_huge_reach_in_parts_equals_the_whole_bake() {
    let dir = tempfile::tempdir().unwrap();
    let fast = moving_cloud(
        dir.path(),
        "fast.vdb",
        &[
            "--copies",
            "3",
            "2",
            "2",
            "--speed",
            "20",
            "--vel-voxel",
            "0.4",
        ],
    );
    parts_equal_whole(dir.path(), &fast, "ratio", None);
    parts_equal_whole(dir.path(), &fast, "ratio", Some([-20.0, 30.0, -15.0]));
}

/// The least budget of a blurred bake in parts is refused by name below it, and it is less than
/// what the whole grid with its velocity needs.
#[test]
fn a_budget_below_the_least_part_of_a_blurred_map_names_the_flag() {
    let dir = tempfile::tempdir().unwrap();
    let path = moving_cloud(dir.path(), "m.vdb", &["--copies", "3", "2", "2"]);
    let mut j = job(&path, dir.path().join("o.exr"), "riemann", Some(1 << 20));
    let Err(umbra::Error::InvalidArgument { name, reason }) = j.plan_bounded() else {
        panic!("1 MiB must be refused");
    };
    assert_eq!(name, "max-memory");
    let mib = |after: &str| -> f64 {
        let s = reason.split(after).nth(1).unwrap();
        s.split(' ').next().unwrap().parse().unwrap()
    };
    let (least, whole) = (mib("at least "), mib("the image need "));
    assert!(least < whole, "{reason}");
    // Just above the least, the plan goes in parts.
    j.max_memory = Some(((least + 1.0) * f64::from(1 << 20)) as u64);
    assert!(j.plan_bounded().unwrap().is_some());
}

//! Object transforms (`--xform`, `Volume::with_xform`): a rigid motion of both the volume and
//! the segment leaves T unchanged, a uniform scale by `s` multiplies the optical depth by `s`,
//! the map of a moved volume equals the unmoved one's, the EXR records the matrix, and bad
//! matrices are refused naming the flag.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::bake_support;

use assert_cmd::Command;
use bake_support::read_exr;
use glam::{DMat3, DVec3};
use std::path::Path;
use umbra::internals::xform::Xform;
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

/// Rotation by `angle` about `axis`, then a translation; scaled by `s`.
fn motion(axis: [f64; 3], angle: f64, t: [f64; 3], s: f64) -> Xform {
    let m = DMat3::from_axis_angle(DVec3::from(axis).normalize(), angle) * s;
    Xform::new([
        [m.x_axis.x, m.y_axis.x, m.z_axis.x, t[0]],
        [m.x_axis.y, m.y_axis.y, m.z_axis.y, t[1]],
        [m.x_axis.z, m.y_axis.z, m.z_axis.z, t[2]],
        [0.0, 0.0, 0.0, 1.0],
    ])
    .unwrap()
}

fn tau(vol: &Volume, a: DVec3, b: DVec3, interp: Interp) -> f64 {
    let d = b - a;
    let ray = Ray::new(a, d, 0.0, d.length()).unwrap();
    optical_depth(vol, &ray, interp).unwrap().tau
}

#[test]
fn rigid_motions_leave_optical_depth_unchanged_and_scales_scale_it() {
    let path = Path::new("data/cloud.vdb");
    let vol = Volume::load(path, "density", 2.0).unwrap();
    let segments = [
        ([-3.0, 1.5, 0.2], [3.0, 1.4, -0.1]),
        ([0.0, -1.0, 0.0], [0.1, 4.0, 0.3]),
        ([-2.0, 3.0, -2.0], [2.0, 0.0, 2.0]),
    ];
    let mut seen = 0.0;
    for (x, s) in [
        (motion([0.3, 1.0, -0.2], 0.7, [5.0, -2.0, 11.0], 1.0), 1.0),
        (motion([1.0, 0.0, 0.0], -2.1, [-100.0, 3.0, 0.5], 1.0), 1.0),
        (motion([0.0, 0.0, 1.0], 0.0, [0.0; 3], 2.5), 2.5),
        (motion([1.0, 2.0, 3.0], 1.3, [7.0, 7.0, -7.0], 0.4), 0.4),
    ] {
        let moved = Volume::load(path, "density", 2.0)
            .unwrap()
            .with_xform(&x)
            .unwrap();
        assert_eq!(moved.xform(), Some(x));
        for interp in [Interp::Trilinear, Interp::Nearest] {
            for (a, b) in segments {
                let (a, b) = (DVec3::from(a), DVec3::from(b));
                let want = tau(&vol, a, b, interp) * s;
                let got = tau(&moved, x.point(a), x.point(b), interp);
                assert!(
                    (got - want).abs() <= 1e-9 * want.max(1.0),
                    "{x:?} {interp:?}: {got} vs {want}"
                );
                seen += want;
            }
        }
        // The moved box is the image of the box.
        let corners = vol.box_corners().unwrap();
        for (c, m) in corners.iter().zip(moved.box_corners().unwrap()) {
            assert!((x.point(*c) - m).length() < 1e-9 * (1.0 + m.length()));
        }
    }
    assert!(seen > 1.0, "the segments miss the cloud");
    // Transforms compose: a then b is b a.
    let (a, b) = (
        motion([0.0, 1.0, 0.0], 0.5, [1.0, 0.0, 0.0], 1.0),
        motion([1.0, 0.0, 0.0], 0.25, [0.0, 2.0, 0.0], 1.0),
    );
    let twice = vol.clone().with_xform(&a).unwrap().with_xform(&b).unwrap();
    let p = DVec3::new(0.3, 1.2, -0.4);
    let composed = twice.xform().unwrap().point(p);
    assert!((composed - b.point(a.point(p))).length() < 1e-12);
}

#[test]
fn bad_matrices_are_refused() {
    let e = Xform::from_row_major(&[1.0; 15]).unwrap_err().to_string();
    assert!(e.contains("15 numbers"), "{e}");
    let mut m = Xform::IDENTITY.rows();
    m[3] = [0.0, 0.0, 1.0, 1.0];
    assert!(Xform::new(m)
        .unwrap_err()
        .to_string()
        .contains("not 0,0,0,1"));
    m = Xform::IDENTITY.rows();
    m[2] = [0.0, 0.0, 0.0, 1.0];
    assert!(Xform::new(m).unwrap_err().to_string().contains("singular"));
    m = Xform::IDENTITY.rows();
    m[0][0] = f64::NAN;
    assert!(Xform::new(m).is_err());
    // A uniform scale of 1e-200 flattens nothing: it is refused for its size, not as
    // singular; a tiny but invertible one (1e-90) is taken.
    let tiny = |s: f64| {
        let mut m = Xform::IDENTITY.rows();
        for (a, row) in m.iter_mut().take(3).enumerate() {
            row[a] = s;
        }
        Xform::new(m)
    };
    let e = tiny(1e-200).unwrap_err().to_string();
    assert!(!e.contains("singular") && e.contains("1e-200"), "{e}");
    assert!(tiny(1e-90).is_ok());
    // A scale that takes the voxels past what umbra traces (1e-30 to 1e30 world units):
    // refused on the volume, naming the flag.
    let huge = motion([0.0, 0.0, 1.0], 0.0, [0.0; 3], 1e33);
    let vol = Volume::load("data/cloud.vdb", "density", 1.0).unwrap();
    match vol.with_xform(&huge) {
        Ok(_) => panic!("a 1e33 scale was accepted"),
        Err(e) => assert!(e.to_string().contains("'xform'"), "{e}"),
    }
}

fn umbra() -> Command {
    Command::cargo_bin("umbra").unwrap()
}

fn csv(v: &[f64]) -> String {
    v.iter()
        .map(|c| format!("{c:?}"))
        .collect::<Vec<_>>()
        .join(",")
}

#[test]
fn cli_query_bake_and_compare_take_xform() {
    let x = motion([0.2, 1.0, 0.1], 0.9, [3.0, -1.0, 20.0], 1.0);
    let flat: Vec<f64> = x.rows().iter().flatten().copied().collect();
    let (a, b) = (DVec3::new(-3.0, 1.5, 0.2), DVec3::new(3.0, 1.4, -0.1));
    let query = |extra: &[String]| -> serde_json::Value {
        let o = umbra()
            .args(["query", "data/cloud.vdb", "--json"])
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let plain = query(&[
        format!("--from={}", csv(&a.to_array())),
        format!("--to={}", csv(&b.to_array())),
    ]);
    let moved = query(&[
        format!("--from={}", csv(&x.point(a).to_array())),
        format!("--to={}", csv(&x.point(b).to_array())),
        format!("--xform={}", csv(&flat)),
    ]);
    let (t0, t1) = (plain["T"].as_f64().unwrap(), moved["T"].as_f64().unwrap());
    assert!(t0 < 0.99 && (t0 - t1).abs() < 1e-9, "{t0} vs {t1}");
    // Bake: a translated volume framed on its moved box gives the same map; the header keeps
    // the matrix.
    let dir = tempfile::tempdir().unwrap();
    let shift = Xform::new([
        [1.0, 0.0, 0.0, 10.0],
        [0.0, 1.0, 0.0, -4.0],
        [0.0, 0.0, 1.0, 2.5],
        [0.0, 0.0, 0.0, 1.0],
    ])
    .unwrap();
    let shift_csv = csv(&shift.rows().iter().flatten().copied().collect::<Vec<_>>());
    let bake = |name: &str, extra: &[&str]| {
        let p = dir.path().join(name);
        umbra()
            .args([
                "bake",
                "data/cloud.vdb",
                "--light-dir=-1,-1,0",
                "--res",
                "40x30",
                "-q",
            ])
            .args(extra)
            .arg("-o")
            .arg(&p)
            .assert()
            .success();
        read_exr(&p)
    };
    let m0 = bake("plain.exr", &[]);
    let m1 = bake("moved.exr", &[&format!("--xform={shift_csv}")]);
    let worst = m0.ch["T"]
        .iter()
        .zip(&m1.ch["T"])
        .fold(0.0f32, |m, (p, q)| m.max((p - q).abs()));
    assert!(worst < 1e-5, "moved map differs by {worst}");
    assert_eq!(m1.text("xform"), shift_csv);
    let o = umbra()
        .args([
            "bake",
            "data/cloud.vdb",
            "--light-dir=-1,-1,0",
            "--res",
            "8",
            "-q",
            "--json",
        ])
        .arg(format!("--xform={shift_csv}"))
        .arg("-o")
        .arg(dir.path().join("j.exr"))
        .output()
        .unwrap();
    let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(summary["xform"], serde_json::json!(shift.rows()));
    let o0 = m0.v3d("camera_origin");
    let o1 = m1.v3d("camera_origin");
    assert!((o1[0] - o0[0] - 10.0).abs() < 1e-9 && (o1[1] - o0[1] + 4.0).abs() < 1e-9);
    // Compare runs on the placed volume.
    let out = dir.path().join("cmp");
    umbra()
        .args([
            "compare",
            "data/cloud.vdb",
            "--rays",
            "16",
            "--estimators",
            "ratio",
            "-q",
        ])
        .arg(format!("--xform={shift_csv}"))
        .arg("-o")
        .arg(&out)
        .assert()
        .success();
    assert!(out.join("report.json").exists());
    // Bad matrices: a usage error naming the flag.
    for bad in ["1,2,3", "1,0,0,0,0,1,0,0,0,0,0,0,0,0,0,1", "a,b"] {
        let o = umbra()
            .args(["query", "data/cloud.vdb", "--from=0,0,0", "--to=1,1,1"])
            .arg(format!("--xform={bad}"))
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{bad}");
        assert!(
            String::from_utf8_lossy(&o.stderr).contains("--xform"),
            "{bad}"
        );
    }
}

//! Camera control (issue 17): `--up` against hand-computed bases, `--frame-box` maps whose box
//! corners land on the image border (the depth still covering the volume), `--camera` reuse of
//! an earlier map's camera from its EXR header or its `--json` summary (the same camera
//! attributes, byte for byte; `--res` keeps the window), and the errors.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::bake_support;

use assert_cmd::Command;
use bake_support::read_exr;
use glam::DVec3;
use std::path::Path;
use umbra::bake::{read_camera, world_box_corners, Camera, Projection, Resolution, View};

fn close(a: [f64; 3], b: [f64; 3]) -> bool {
    (0..3).all(|k| (a[k] - b[k]).abs() < 1e-12)
}

/// A unit box from the origin: the volume every camera here frames.
fn unit_box() -> [DVec3; 8] {
    world_box_corners([[0.0; 3], [1.0; 3]])
}

#[test]
fn up_gives_the_hand_computed_basis() {
    // A sun travelling along +Y over a Z-up scene with --up 0,0,1: r = f x a = (1, 0, 0),
    // u = r x f = (0, 0, 1). Without --up the reference axis is +Y, parallel to the light, so
    // the default's fallback (-Z) applies: r = (0,1,0) x (0,0,-1) = (-1, 0, 0), u = (0, 0, -1),
    // the upside-down, mirrored map the issue describes.
    let view = |up| View {
        light_dir: Some([0.0, 1.0, 0.0]),
        res: Some(Resolution::Exact(20, 10)),
        up,
        ..View::default()
    };
    let z_up = Camera::frame(&view(Some([0.0, 0.0, 1.0])), &unit_box()).unwrap();
    assert!(close(z_up.right(), [1.0, 0.0, 0.0]), "{:?}", z_up.right());
    assert!(close(z_up.up(), [0.0, 0.0, 1.0]), "{:?}", z_up.up());
    let default = Camera::frame(&view(None), &unit_box()).unwrap();
    assert!(close(default.right(), [-1.0, 0.0, 0.0]));
    assert!(close(default.up(), [0.0, 0.0, -1.0]));
    // A light down -Z with X up: r = (0,0,-1) x (1,0,0) = (0, -1, 0), u = r x f = (1, 0, 0).
    let top = View {
        light_dir: Some([0.0, 0.0, -1.0]),
        up: Some([2.0, 0.0, 0.0]), // any length
        ..View::default()
    };
    let c = Camera::frame(&top, &unit_box()).unwrap();
    assert!(close(c.right(), [0.0, -1.0, 0.0]) && close(c.up(), [1.0, 0.0, 0.0]));
    // An up with a component along the light: only its part across the light counts.
    let tilted = View {
        up: Some([2.0, 0.0, 5.0]),
        ..top
    };
    assert!(close(
        Camera::frame(&tilted, &unit_box()).unwrap().up(),
        c.up()
    ));
    // Up parallel to the light: the default rule (here +Y, so r = (-1, 0, 0), u = (0, 1, 0)).
    let parallel = View {
        up: Some([0.0, 0.0, 3.0]),
        ..top
    };
    let p = Camera::frame(&parallel, &unit_box()).unwrap();
    let none = Camera::frame(&View { up: None, ..top }, &unit_box()).unwrap();
    assert_eq!(p, none);
    assert!(close(p.up(), [0.0, 1.0, 0.0]));
    // Perspective: the same basis rule about the aim.
    let persp = View {
        projection: Projection::Perspective,
        light_pos: Some([0.5, -4.0, 0.5]),
        up: Some([0.0, 0.0, 1.0]),
        ..View::default()
    };
    let c = Camera::frame(&persp, &unit_box()).unwrap();
    assert!(close(c.forward(), [0.0, 1.0, 0.0]));
    assert!(close(c.right(), [1.0, 0.0, 0.0]) && close(c.up(), [0.0, 0.0, 1.0]));
    // A higher point is on an earlier row (row 0 at the top).
    let row = |cam: &Camera, p: [f64; 3]| {
        let o = DVec3::from(cam.origin());
        (DVec3::from(p) - o).dot(DVec3::from(cam.step_y())) / cam.pixel_size().powi(2)
    };
    let ortho = Camera::frame(&view(Some([0.0, 0.0, 1.0])), &unit_box()).unwrap();
    assert!(row(&ortho, [0.5, 0.5, 0.9]) < row(&ortho, [0.5, 0.5, 0.1]));
    // A zero up is an error naming the flag.
    let e = Camera::frame(
        &View {
            up: Some([0.0; 3]),
            ..top
        },
        &unit_box(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("'up'"), "{e}");
}

/// Column and row of world point `p` on an ortho camera (pixel centres at whole numbers).
fn pixel(c: &Camera, p: DVec3) -> (f64, f64) {
    let v = p - DVec3::from(c.origin());
    let s2 = c.pixel_size().powi(2);
    (
        v.dot(DVec3::from(c.step_x())) / s2,
        v.dot(DVec3::from(c.step_y())) / s2,
    )
}

#[test]
fn frame_box_corners_land_on_the_image_border() {
    let volume = world_box_corners([[-3.0, -3.0, -3.0], [3.0, 3.0, 3.0]]);
    let fb = [[0.5, -1.0, 0.25], [2.5, 0.0, 1.0]];
    for (dir, res) in [
        ([0.0, 0.0, -1.0], Resolution::Exact(200, 100)),
        ([0.6, -0.35, -1.0], Resolution::LongSide(300)),
        ([-1.0, 0.2, 0.1], Resolution::LongSide(257)),
    ] {
        let view = View {
            light_dir: Some(dir),
            res: Some(res),
            frame_box: Some(fb),
            ..View::default()
        };
        let c = Camera::frame(&view, &volume).unwrap();
        let (w, h) = (f64::from(c.width()), f64::from(c.height()));
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for p in world_box_corners(fb) {
            let (x, y) = pixel(&c, p);
            (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
        }
        // The binding axis spans the image exactly, edge to edge (pixel edges at -0.5 and
        // N - 0.5); the other fits inside, centred, within the rounding of its pixel count.
        let tight =
            |lo: f64, hi: f64, n: f64| (lo + 0.5).abs() < 1e-9 && (hi - n + 0.5).abs() < 1e-9;
        let inside = |lo: f64, hi: f64, n: f64| {
            lo >= -0.5 - 1e-9 && hi <= n - 0.5 + 1e-9 && ((lo + 0.5) - (n - 0.5 - hi)).abs() < 1e-9
        };
        assert!(
            (tight(x0, x1, w) && inside(y0, y1, h)) || (tight(y0, y1, h) && inside(x0, x1, w)),
            "{dir:?}: x {x0}..{x1} of {w}, y {y0}..{y1} of {h}"
        );
        if matches!(res, Resolution::LongSide(_)) {
            // The short side is rounded: its border is within half a pixel of the box.
            assert!((x0 + 0.5).abs() < 0.5 + 1e-9 && (y0 + 0.5).abs() < 0.5 + 1e-9);
        }
        // The rays still cross the whole volume in depth.
        let f = DVec3::from(c.direction());
        for p in volume {
            let z = (p - DVec3::from(c.origin())).dot(f);
            assert!(z >= -1e-9 && z <= c.t_max() + 1e-9, "{dir:?}: depth {z}");
        }
    }
    // An empty or inverted box is an error naming the flag.
    let e = Camera::frame(
        &View {
            light_dir: Some([0.0, 0.0, -1.0]),
            frame_box: Some([[0.0; 3], [1.0, 0.0, 1.0]]),
            ..View::default()
        },
        &volume,
    )
    .unwrap_err();
    assert!(e.to_string().contains("'frame-box'"), "{e}");
}

#[test]
fn with_resolution_keeps_the_window() {
    for projection in [Projection::Ortho, Projection::Perspective] {
        let view = View {
            projection,
            light_dir: Some([0.3, -1.0, 0.2]),
            light_pos: (projection == Projection::Perspective).then_some([-1.0, 6.0, -0.5]),
            res: Some(Resolution::Exact(40, 30)),
            ..View::default()
        };
        let c = Camera::frame(&view, &unit_box()).unwrap();
        assert_eq!(c.with_resolution(Resolution::Exact(40, 30)).unwrap(), c);
        // Twice the pixels: pixel (2i + 0.5, 2j + 0.5) of the new map is pixel (i, j) of the
        // old one, so the old pixel (0, 0)'s ray is the new pixels' (0.5, 0.5).
        let d = c.with_resolution(Resolution::LongSide(80)).unwrap();
        assert_eq!((d.width(), d.height()), (80, 60));
        assert!((d.pixel_size() * 2.0 - c.pixel_size()).abs() < 1e-15);
        let v = DVec3::from_array;
        let half = (v(d.step_x()) + v(d.step_y())) * 0.5;
        let (old, new) = match projection {
            Projection::Ortho => (v(c.origin()), v(d.origin()) + half),
            Projection::Perspective => (v(c.direction()), v(d.direction()) + half),
            other => panic!("{other:?} is not framed here"),
        };
        assert!(
            (old - new).length() < 1e-12,
            "{projection:?}: {old} vs {new}"
        );
        // Another aspect: square pixels, the old window centred inside.
        let e = c.with_resolution(Resolution::Exact(30, 30)).unwrap();
        assert!((e.pixel_size() - 40.0 * c.pixel_size() / 30.0).abs() < 1e-15);
    }
}

fn umbra() -> Command {
    Command::cargo_bin("umbra").unwrap()
}

fn camera_attrs(p: &Path) -> Vec<String> {
    let e = read_exr(p);
    let mut v: Vec<String> = e
        .attrs
        .other
        .iter()
        .filter(|(k, _)| k.to_string().starts_with("umbra:camera_"))
        .map(|(k, a)| format!("{k} {a:?}"))
        .collect();
    v.sort();
    v.push(format!("{:?}", e.attrs.world_to_camera));
    v.push(format!("{:?}", e.attrs.world_to_normalized_device));
    v.push(format!("{}x{}", e.w, e.h));
    v
}

#[test]
fn camera_reuse_from_exr_and_json_is_exact() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (k, light) in [["--light-dir=-1,-1,0.3"], ["--light-pos=4,5,-3"]]
        .iter()
        .enumerate()
    {
        let first = d.join(format!("first{k}.exr"));
        let json = d.join(format!("first{k}.json"));
        let o = umbra()
            .args([
                "bake",
                "data/cloud.vdb",
                "--res",
                "48x40",
                "--up",
                "0.2,0.1,1",
                "--json",
                "-q",
            ])
            .args(light.iter())
            .arg("-o")
            .arg(&first)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::write(&json, &o.stdout).unwrap();
        let want = camera_attrs(&first);
        for src in [&first, &json] {
            let again = d.join("again.exr");
            umbra()
                .args(["bake", "data/cloud.vdb", "--force", "-q", "--camera"])
                .arg(src)
                .arg("-o")
                .arg(&again)
                .assert()
                .success();
            assert_eq!(camera_attrs(&again), want, "{src:?}");
            // The same camera on the same volume: the same T.
            assert_eq!(
                read_exr(&again).ch["T"],
                read_exr(&first).ch["T"],
                "{src:?}"
            );
        }
        // The library reads the same camera from both.
        let a = read_camera(&first, None).unwrap();
        assert_eq!(a, read_camera(&json, None).unwrap());
        // A bare camera object: its size from --res (required), its steps as they are.
        let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let bare = d.join("bare.json");
        std::fs::write(&bare, summary["camera"].to_string()).unwrap();
        assert_eq!(
            read_camera(&bare, Some(Resolution::Exact(48, 40))).unwrap(),
            a
        );
        let e = read_camera(&bare, None).unwrap_err().to_string();
        assert!(e.contains("--res WxH"), "{e}");
        // --res: the same window at another size.
        let big = d.join("big.exr");
        umbra()
            .args([
                "bake",
                "data/cloud.vdb",
                "-q",
                "--force",
                "--res",
                "96",
                "--camera",
            ])
            .arg(&first)
            .arg("-o")
            .arg(&big)
            .assert()
            .success();
        let b = read_exr(&big);
        assert_eq!((b.w, b.h), (96, 80));
    }
    // Errors: one line naming the file or the flag, nothing written.
    let out = d.join("never.exr");
    for (args, code, needle) in [
        (vec!["--camera", "missing.exr"], 1, "missing.exr"),
        (vec!["--camera", "data/cloud.vdb"], 1, "'--camera'"),
        (
            vec!["--camera", "x.exr", "--light-dir=1,0,0"],
            1,
            "'--light-dir': a reused camera fixes the whole view",
        ),
        (vec!["--light-dir=1,0,0", "--up", "0,0,0"], 1, "'--up'"),
        (
            vec!["--light-dir=1,0,0", "--frame-box", "0,0,0,1,1"],
            2,
            "--frame-box",
        ),
        (
            vec!["--light-dir=1,0,0", "--frame-box", "0,0,0,1,0,1"],
            1,
            "'--frame-box'",
        ),
    ] {
        let o = umbra()
            .args(["bake", "data/cloud.vdb", "-q", "-o"])
            .arg(&out)
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(code), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!out.exists());
    }
}

/// The volume box read from the header and topology alone equals the loaded volume's, on the
/// corpus (tiles at every level, instanced grids, rotated and scaled transforms).
#[test]
fn box_from_topology_equals_the_loaded_box() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus");
    let mut checked = 0;
    for dir in ["gen", "real"] {
        let Ok(entries) = std::fs::read_dir(root.join(dir)) else {
            continue;
        };
        let mut files: Vec<_> = entries.flatten().map(|e| e.path()).collect();
        files.sort();
        for path in files
            .iter()
            .filter(|p| p.extension().is_some_and(|e| e == "vdb"))
        {
            let Ok(archive) = umbra::internals::vdb::open(path) else {
                continue;
            };
            for gd in &archive.grids {
                let Ok(vol) = umbra::Volume::load(path, &gd.display_name, 1.0) else {
                    continue;
                };
                let read = umbra::Volume::read_box_corners(path, &gd.display_name).unwrap();
                assert_eq!(read, vol.box_corners().ok(), "{path:?} {}", gd.display_name);
                checked += 1;
            }
        }
    }
    assert!(
        checked >= 20,
        "only {checked} grids: is ../shared/corpus there?"
    );
}

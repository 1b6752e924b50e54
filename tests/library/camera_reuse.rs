//! A reused camera never drops density. A sequence bakes frame 1, then later frames through
//! frame 1's camera (`--camera a.exr`, Python `camera=`, a library `Camera`): where a later
//! frame reaches further toward or away from the light than frame 1, the map must still give,
//! at every pixel, the `T` a fresh bake with the same projection gives; where it reaches outside
//! the camera's window, the bake warns how far (stderr and `--json`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::bake_support;
use crate::vdb_writer;

use bake_support::read_exr;
use std::path::{Path, PathBuf};
use umbra::bake::{
    BakeJob, BakeSettings, Camera, Depths, ExrLayout, Order, Product, Projection, Resolution, View,
    Warning,
};
use umbra::estimate::{Estimator, Options};
use umbra::glam::DVec3;
use umbra::scene::Scene;
use umbra::{Interp, Volume};
use vdb_writer::{Grid, Leaf, Map, VdbFile};

/// Voxel size of every frame.
const VOXEL: f64 = 0.1;

/// The leaf origins of frame `n`: frame 0 is a 32^3 block of leaves; frame 1 adds leaves above
/// it (toward a light shining down -Y), below it, and beside it along +X (outside a window
/// framed on frame 0); frame 2 only reaches further up.
fn frame_leaves(n: usize) -> Vec<[i32; 3]> {
    let mut o = Vec::new();
    for x in 0..4 {
        for y in 0..4 {
            for z in 0..4 {
                o.push([8 * x, 8 * y, 8 * z]);
            }
        }
    }
    if n >= 1 {
        for x in 0..4 {
            for z in 0..4 {
                o.push([8 * x, 40, 8 * z]);
                o.push([8 * x, 48, 8 * z]);
                if n == 1 {
                    o.push([8 * x, -16, 8 * z]);
                }
            }
        }
    }
    if n == 1 {
        for y in 0..4 {
            o.push([32, 8 * y, 8]);
        }
    }
    o
}

/// A smooth density, different in every voxel.
fn density(p: [i32; 3]) -> f64 {
    let [x, y, z] = p.map(f64::from);
    0.6 + 0.4 * (0.31 * x + 0.17 * y).sin() * (0.23 * z - 0.11 * y).cos()
}

fn frame_volume(n: usize) -> Volume {
    let mut b = umbra::internals::tree::TreeBuilder::new(0.0);
    for o in frame_leaves(n) {
        for i in 0..8 {
            for j in 0..8 {
                for k in 0..8 {
                    let p = [o[0] + i, o[1] + j, o[2] + k];
                    b.set(p, density(p) as f32);
                }
            }
        }
    }
    let m = [
        [VOXEL, 0.0, 0.0, 0.0],
        [0.0, VOXEL, 0.0, 0.0],
        [0.0, 0.0, VOXEL, 0.0],
    ];
    Volume::from_tree("density".into(), b.build(), m, 1.0).unwrap()
}

fn write_frame(dir: &Path, n: usize) -> PathBuf {
    let leaves = frame_leaves(n)
        .into_iter()
        .map(|o| {
            Leaf::from_fn(o, |ijk| {
                density([
                    o[0] + ijk[0] as i32,
                    o[1] + ijk[1] as i32,
                    o[2] + ijk[2] as i32,
                ])
            })
        })
        .collect();
    let path = dir.join(format!("frame{n}.vdb"));
    VdbFile::new(vec![
        Grid::fog("density", leaves).with_map(Map::UniformScale(VOXEL))
    ])
    .write(&path);
    path
}

fn job(view: View, settings: BakeSettings) -> BakeJob {
    BakeJob {
        source: umbra::input::Source::new(
            "frame.vdb",
            umbra::input::SourceOptions {
                grid: "density".into(),
                density_scale: 1.0,
                ..umbra::input::SourceOptions::default()
            },
        ),
        view,
        camera: None,
        settings,
        output: "unused.exr".into(),
        preview: None,
        overwrite: true,
        layout: ExrLayout::default(),
        max_memory: None,
        product: Product::Map,
        key: None,
    }
}

fn settings(interp: Interp, order: Order) -> BakeSettings {
    BakeSettings {
        order,
        ..BakeSettings::new(
            Estimator::REGULAR,
            Options {
                interp,
                ..Options::default()
            },
        )
    }
}

/// The box the sequence is framed on: frame 0's middle, in world units.
const FRAME_BOX: [[f64; 3]; 2] = [[0.4, 0.4, 0.4], [2.8, 2.8, 2.8]];

fn ortho_view(frame_box: Option<[[f64; 3]; 2]>) -> View {
    View {
        projection: Projection::Ortho,
        light_dir: Some([0.05, -1.0, 0.02]),
        res: Some(Resolution::Exact(48, 40)),
        frame_box,
        ..View::default()
    }
}

fn perspective_view(fov: Option<f64>) -> View {
    View {
        projection: Projection::Perspective,
        light_pos: Some([1.6, 9.0, 1.7]),
        light_dir: Some([0.0, -1.0, 0.0]),
        fov_deg: fov,
        res: Some(Resolution::Exact(40, 40)),
        ..View::default()
    }
}

fn worst(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| f64::from((x - y).abs()) / f64::from(x.max(*y)).max(1e-3))
        .fold(0.0, f64::max)
}

/// Frames 1 and 2 through frame 0's camera equal fresh bakes with the same projection at
/// every pixel (ortho: framed on the same box; perspective: the same field of view), for the
/// sweep, the ray path and nearest lookups. Before the fix, frame 1 dropped what lay above
/// frame 0's image plane and below its `t_max`.
#[test]
fn reused_cameras_give_the_fresh_bake_with_the_same_projection() {
    let frames: Vec<Scene> = (0..3)
        .map(|n| Scene::from_volume(frame_volume(n)))
        .collect();
    let mut compared = 0;
    for (kind, first, fresh_view) in [
        (
            "ortho",
            ortho_view(Some(FRAME_BOX)),
            ortho_view(Some(FRAME_BOX)),
        ),
        (
            "perspective",
            perspective_view(Some(40.0)),
            perspective_view(Some(40.0)),
        ),
    ] {
        let camera = Camera::frame(&first, &frames[0].box_corners().unwrap()).unwrap();
        for (interp, order) in [
            (Interp::Trilinear, Order::Auto),
            (Interp::Trilinear, Order::Rays),
            (Interp::Nearest, Order::Auto),
        ] {
            for (n, frame) in frames.iter().enumerate().skip(1) {
                let s = settings(interp, order);
                // What `--camera a.exr` runs: no framing request, the camera as given.
                let reused = job(View::default(), s.clone())
                    .bake_in_memory(frame, camera, &|_| {})
                    .unwrap();
                let fresh_camera =
                    Camera::frame(&fresh_view, &frame.box_corners().unwrap()).unwrap();
                let fresh = job(fresh_view, s)
                    .bake_in_memory(frame, fresh_camera, &|_| {})
                    .unwrap();
                let (a, b) = (&reused.map.t, &fresh.map.t);
                assert_eq!(a.len(), b.len());
                let w = worst(a, b);
                assert!(
                    w < 2e-5,
                    "{kind} frame {n} {interp:?} {order:?}: reused camera differs from the \
                     fresh bake by {w:.3e} (relative T)"
                );
                // The window never moves: the same pixel lines.
                let (rc, fc) = (reused.map.camera, fresh.map.camera);
                assert_eq!((rc.width(), rc.height()), (fc.width(), fc.height()));
                for (x, y) in [(rc.step_x(), fc.step_x()), (rc.step_y(), fc.step_y())] {
                    assert!((0..3).all(|k| (x[k] - y[k]).abs() < 1e-12), "{x:?} {y:?}");
                }
                compared += a.len();
            }
        }
        // Reused on the frame it was framed on, the camera comes back bit for bit.
        let same = job(View::default(), settings(Interp::Trilinear, Order::Auto))
            .bake_in_memory(&frames[0], camera, &|_| {})
            .unwrap();
        assert_eq!(same.map.camera, camera, "{kind}");
    }
    assert!(compared > 10_000, "{compared}");
}

/// Slices at explicit depths stay at the world points asked for when the ray start moves back:
/// a slice at the far end of frame 0's range holds, in frame 1, the density frame 1 added
/// before frame 0's image plane (it is part of every slice), and equals the fresh bake's slice
/// at the same world depth.
#[test]
fn explicit_depths_stay_at_their_world_points() {
    let f0 = Scene::from_volume(frame_volume(0));
    let f1 = Scene::from_volume(frame_volume(1));
    let view = ortho_view(Some(FRAME_BOX));
    let camera = Camera::frame(&view, &f0.box_corners().unwrap()).unwrap();
    let depth = 0.5 * camera.t_max();
    let s = BakeSettings {
        depths: Depths::At(vec![depth]),
        ..settings(Interp::Trilinear, Order::Auto)
    };
    let reused = job(View::default(), s.clone())
        .bake_in_memory(&f1, camera, &|_| {})
        .unwrap();
    let fresh_camera = Camera::frame(&view, &f1.box_corners().unwrap()).unwrap();
    // The same world depth, measured from the fresh camera's ray start.
    let f = DVec3::from_array(camera.forward());
    let shift =
        (DVec3::from_array(camera.origin()) - DVec3::from_array(fresh_camera.origin())).dot(f);
    assert!(
        shift > 1.0,
        "frame 1 reaches {shift} before frame 0's plane"
    );
    let fresh = job(
        view,
        BakeSettings {
            depths: Depths::At(vec![depth + shift]),
            ..s
        },
    )
    .bake_in_memory(&f1, fresh_camera, &|_| {})
    .unwrap();
    let w = worst(&reused.map.slices[0], &fresh.map.slices[0]);
    assert!(w < 2e-5, "slice differs by {w:.3e}");
    assert!((reused.map.depths[0] - (depth + shift)).abs() < 1e-9 * depth);
    // The slice is not the frame-0 slice: frame 1's density above the old plane is in it.
    let old = job(View::default(), s)
        .bake_in_memory(&f0, camera, &|_| {})
        .unwrap();
    assert!(worst(&reused.map.slices[0], &old.map.slices[0]) > 0.05);
}

/// Where a later frame reaches outside the reused camera's window the bake says how far, in
/// pixels and world units; a frame inside the window gets no such warning.
#[test]
fn volumes_outside_a_reused_window_are_warned_about() {
    let f0 = Scene::from_volume(frame_volume(0));
    let f2 = Scene::from_volume(frame_volume(2));
    let f1 = Scene::from_volume(frame_volume(1));
    // A sun straight down: growth along the light stays inside the window.
    let down = View {
        light_dir: Some([0.0, -1.0, 0.0]),
        ..ortho_view(None)
    };
    let camera = Camera::frame(&down, &f0.box_corners().unwrap()).unwrap();
    let s = settings(Interp::Trilinear, Order::Auto);
    let warn = |scene: &Scene| {
        job(View::default(), s.clone())
            .bake_in_memory(scene, camera, &|_| {})
            .unwrap()
            .warnings
            .into_iter()
            .find_map(|w| match w {
                Warning::OutsideCamera { pixels, world } => Some((pixels, world)),
                _ => None,
            })
    };
    // Frame 2 grows only along the light: still inside the window.
    assert_eq!(warn(&f0), None);
    assert_eq!(warn(&f2), None);
    // Frame 1 reaches 8 voxels further along +X (the map's right), beyond frame 0's box.
    let (pixels, world) = warn(&f1).expect("frame 1 reaches outside");
    let right = DVec3::from_array(camera.right());
    let reach = |sc: &Scene| {
        sc.box_corners()
            .unwrap()
            .iter()
            .map(|c| c.dot(right))
            .fold(f64::NEG_INFINITY, f64::max)
    };
    // The window's right edge: half a pixel right of the last column's centre.
    let edge = DVec3::from_array(camera.origin()).dot(right)
        + (f64::from(camera.width()) - 0.5) * camera.pixel_size();
    assert!(edge >= reach(&f0) - 1e-9);
    let want = reach(&f1) - edge;
    assert!(want > 0.3, "{want}");
    assert!((world - want).abs() < 1e-6, "{world} vs {want}");
    assert!((pixels * camera.pixel_size() - world).abs() < 1e-9);
}

/// The issue's commands: `bake FRAME1 --frame-box B -o a.exr`, then `bake FRAME2 --camera
/// a.exr` equals `bake FRAME2 --frame-box B` at every pixel, and `--json` carries the warning.
#[test]
fn the_cli_sequence_of_the_issue() {
    let dir = tempfile::tempdir().unwrap();
    let (f0, f1) = (write_frame(dir.path(), 0), write_frame(dir.path(), 1));
    let b = "0.4,0.4,0.4,2.8,2.8,2.8";
    let bake = |input: &Path, out: &str, extra: &[&str]| {
        let o = assert_cmd::Command::cargo_bin("umbra")
            .unwrap()
            .arg("bake")
            .arg(input)
            .args(["-q", "--json", "--res", "48x40", "-o"])
            .arg(dir.path().join(out))
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let json: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        (
            read_exr(&dir.path().join(out)),
            json,
            String::from_utf8_lossy(&o.stderr).to_string(),
        )
    };
    let light = "--light-dir=0.05,-1,0.02";
    let (_, j0, _) = bake(&f0, "a.exr", &[light, "--frame-box", b]);
    assert!(
        j0["warnings"].as_array().is_none_or(|w| w.is_empty()),
        "{j0}"
    );
    let a = dir.path().join("a.exr");
    let (reused, json, stderr) = bake(&f1, "b.exr", &["--camera", a.to_str().unwrap()]);
    let (fresh, _, _) = bake(&f1, "c.exr", &[light, "--frame-box", b]);
    let w = worst(&reused.ch["T"], &fresh.ch["T"]);
    assert!(
        w < 2e-5,
        "reused camera differs from the fresh bake by {w:.3e}"
    );
    let warns = json["warnings"].as_array().expect("warnings");
    let outside = warns
        .iter()
        .find(|w| w["kind"] == "outside-camera")
        .unwrap_or_else(|| panic!("{json}"));
    assert!(outside["pixels"].as_f64().unwrap() > 1.0, "{outside}");
    assert!(outside["world"].as_f64().unwrap() > 0.0, "{outside}");
    assert!(stderr.contains("outside the camera's window"), "{stderr}");
}

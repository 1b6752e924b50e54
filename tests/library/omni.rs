//! Omnidirectional maps around a point light (`--omni cube|latlong`): every texel, the poles
//! and seams and the cube's edges included, equals the exact optical depth from the light
//! along that texel's direction, the directions written here from OpenEXR's `ImfEnvmap`
//! (`LatLongMap::direction`, `CubeMap::direction` of the face position `pixelPosition` maps
//! to the texel), for a light inside the sample cloud (also exactly on a lattice corner),
//! inside a two-volume scene and outside the box. The cube goes through the exact sweep (six
//! pinholes at the light, inside the volume), the latlong map through rays.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use glam::DVec3;
use std::path::PathBuf;
use umbra::bake::{bake_scene, BakeSettings, Camera, Map, Projection, Resolution, View};
use umbra::estimate::{Estimator, Options};
use umbra::input::SourceOptions;
use umbra::regular::optical_depth;
use umbra::scene::Scene;
use umbra::{Interp, Ray, Volume};

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
}

/// `LatLongMap::direction` at integer pixel `(x, y)` of a `w x h` map.
fn latlong(w: u32, h: u32, x: u32, y: u32) -> DVec3 {
    let pi = std::f64::consts::PI;
    let lat = -pi * (f64::from(y) / f64::from(h - 1) - 0.5);
    let lon = -2.0 * pi * (f64::from(x) / f64::from(w - 1) - 0.5);
    DVec3::new(lon.sin() * lat.cos(), lat.sin(), lon.cos() * lat.cos())
}

/// `CubeMap::direction(face, pif)` where `pixelPosition(face, pif)` is texel `(x, y)` of an
/// `n x 6n` map (faces +X, -X, +Y, -Y, +Z, -Z top to bottom).
fn cube(n: u32, x: u32, y: u32) -> DVec3 {
    let face = y / n;
    let m = f64::from(n - 1);
    // The face's data window is [0, m] x [face n, face n + m].
    let (px, py) = (f64::from(x), f64::from(y % n));
    let pif = match face {
        0 => (m - py, px),
        1 => (m - py, m - px),
        2 => (px, m - py),
        3 => (px, py),
        4 => (m - px, m - py),
        _ => (px, m - py),
    };
    let (a, b) = (pif.0 / m * 2.0 - 1.0, pif.1 / m * 2.0 - 1.0);
    match face {
        0 => DVec3::new(1.0, a, b),
        1 => DVec3::new(-1.0, a, b),
        2 => DVec3::new(a, 1.0, b),
        3 => DVec3::new(a, -1.0, b),
        4 => DVec3::new(a, b, 1.0),
        _ => DVec3::new(a, b, -1.0),
    }
}

fn exact() -> BakeSettings {
    BakeSettings::new(Estimator::REGULAR, Options::default())
}

fn omni(scene: &Scene, kind: Projection, light: DVec3, n: u32) -> Map {
    let view = View {
        projection: kind,
        light_pos: Some(light.to_array()),
        res: Some(Resolution::LongSide(n)),
        ..View::default()
    };
    let camera = Camera::frame(&view, &scene.box_corners().unwrap()).unwrap();
    bake_scene(scene, &camera, &exact(), &|_| {}).unwrap()
}

/// Every texel of `map` against the exact T along its direction from the light, summed over
/// the volumes; returns how many texels were in shadow (T < 0.999) so a test knows it looked
/// at the medium.
fn check(map: &Map, vols: &[&Volume], light: DVec3) -> usize {
    let c = &map.camera;
    let (w, h) = (c.width(), c.height());
    let mut shaded = 0;
    for y in 0..h {
        for x in 0..w {
            let d = match c.kind() {
                Projection::Cube => cube(w, x, y),
                _ => latlong(w, h, x, y),
            };
            let ray = Ray::new(light, d, 0.0, c.t_max()).unwrap();
            let tau: f64 = vols
                .iter()
                .map(|v| optical_depth(v, &ray, Interp::Trilinear).unwrap().tau)
                .sum();
            let want = (-tau).exp();
            let got = f64::from(map.t[(y * w + x) as usize]);
            assert!(
                (got - want).abs() <= 1e-6,
                "{:?} texel ({x}, {y}) looking {d:?}: {got} against exact {want}",
                c.kind()
            );
            shaded += usize::from(want < 0.999);
        }
    }
    shaded
}

#[test]
fn a_light_inside_the_cloud_sees_every_direction_exactly() {
    let vol = Volume::load(data("cloud.vdb"), "density", 1.0).unwrap();
    let scene = Scene::from_volume(vol.clone());
    let [lo, hi] = vol.value_box().unwrap();
    let mid = |k: usize| ((lo[k] + hi[k]) / 2) as f64;
    // Off the lattice, and exactly on a lattice corner (integer index coordinates: every
    // direction along an axis runs in a voxel plane).
    let lights = [
        vol.to_world(DVec3::new(mid(0) + 0.37, mid(1) + 0.21, mid(2) - 0.44)),
        vol.to_world(DVec3::new(mid(0), mid(1), mid(2))),
    ];
    for light in lights {
        let cube_map = omni(&scene, Projection::Cube, light, 17);
        assert!(cube_map.stats.sweep, "the cube is swept face by face");
        assert!(check(&cube_map, &[&vol], light) > 100);
        let ll = omni(&scene, Projection::LatLong, light, 15);
        assert!(check(&ll, &[&vol], light) > 100);
    }
}

#[test]
fn a_light_outside_the_box_and_inside_a_scene() {
    let vol = Volume::load(data("cloud.vdb"), "density", 1.0).unwrap();
    let corners = vol.box_corners().unwrap();
    let far = corners[7] + DVec3::new(0.8, 0.5, 0.3);
    let scene = Scene::from_volume(vol.clone());
    for kind in [Projection::Cube, Projection::LatLong] {
        let map = omni(&scene, kind, far, 12);
        assert!(check(&map, &[&vol], far) > 3);
    }
    // Two volumes: the cloud and a shifted copy at half density.
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(data("cloud.vdb"), dir.path().join("cloud.vdb")).unwrap();
    let toml = dir.path().join("two.toml");
    std::fs::write(
        &toml,
        "[[volume]]\nfile = \"cloud.vdb\"\n[[volume]]\nfile = \"cloud.vdb\"\ndensity_scale = \
         0.5\nxform = [1, 0, 0, 0.4, 0, 1, 0, -0.3, 0, 0, 1, 0.2, 0, 0, 0, 1]\n",
    )
    .unwrap();
    let two = umbra::input::Source::new(&toml, SourceOptions::default())
        .load()
        .unwrap();
    let shifted = Volume::load(data("cloud.vdb"), "density", 0.5)
        .unwrap()
        .with_xform(
            &umbra::internals::xform::Xform::from_row_major(&[
                1.0, 0.0, 0.0, 0.4, 0.0, 1.0, 0.0, -0.3, 0.0, 0.0, 1.0, 0.2, 0.0, 0.0, 0.0, 1.0,
            ])
            .unwrap(),
        )
        .unwrap();
    // The cloud's box centre: inside both volumes' boxes.
    let light = (corners[0] + corners[7]) * 0.5;
    for kind in [Projection::Cube, Projection::LatLong] {
        let map = omni(&two, kind, light, 11);
        assert!(check(&map, &[&vol, &shifted], light) > 50);
    }
}

#[test]
fn omni_options_are_checked_and_sizes_follow_the_layout() {
    let vol = Volume::load(data("cloud.vdb"), "density", 1.0).unwrap();
    let corners = vol.box_corners().unwrap();
    let view = |kind, res| View {
        projection: kind,
        light_pos: Some([0.0, 1.5, 0.0]),
        res,
        ..View::default()
    };
    let c = Camera::frame(&view(Projection::Cube, None), &corners).unwrap();
    assert_eq!((c.width(), c.height()), (512, 3072));
    let c = Camera::frame(
        &view(Projection::LatLong, Some(Resolution::LongSide(64))),
        &corners,
    )
    .unwrap();
    assert_eq!((c.width(), c.height()), (128, 64));
    let bad = Camera::frame(
        &view(Projection::Cube, Some(Resolution::Exact(64, 64))),
        &corners,
    );
    assert!(format!("{:?}", bad.unwrap_err()).contains("res"));
    let aimed = View {
        light_dir: Some([0.0, -1.0, 0.0]),
        ..view(Projection::Cube, None)
    };
    assert!(format!("{:?}", Camera::frame(&aimed, &corners).unwrap_err()).contains("light-dir"));
}

//! The sweep against the ray path: the optical depth of every pixel, in f64.

use super::rays::Layout;
use super::*;
use crate::bake::camera::Projection;
use crate::bake::{Resolution, View};
use crate::estimate::Estimator;
use crate::traverse::lookup_ray;
use crate::traverse::Granularity;
use crate::tree::TreeBuilder;
use glam::DVec3;
use std::ops::ControlFlow;

/// The sweep's optical depth of every pixel (bands run one after the other).
fn sweep_taus(vol: &Volume, camera: &Camera) -> Vec<f64> {
    let rows = 16;
    let sweep = Sweep::new(vol, camera, rows, &[])
        .expect("plan")
        .expect("frame");
    let mut tau = vec![0.0; camera.pixels() as usize];
    for (b, chunk) in tau
        .chunks_mut(rows as usize * camera.width as usize)
        .enumerate()
    {
        sweep.band(b, chunk, &mut 0).expect("band");
    }
    tau
}

/// Every pixel's optical depth by the ray path, against the sweep's. The kernel's positions carry
/// an error of about `2^-23` voxels, which moves a cell's integral by `|grad f| 2^-23 h`: so the
/// bound is `1e-6 tau + 1e-7 M`, `M` the majorant optical depth (the integral of each leaf's
/// largest corner value) that bounds `|grad f|` summed along the ray. Returns the largest
/// relative difference over pixels with `tau >= 1e-3` and how many pixels saw any optical depth.
fn check(vol: &Volume, camera: &Camera, what: &str) -> (f64, usize) {
    let got = sweep_taus(vol, camera);
    let mut worst = 0.0f64;
    let mut hit = 0;
    for j in 0..camera.height {
        for i in 0..camera.width {
            let ray = camera.pixel_ray(i, j).expect("ray");
            let want = crate::regular::optical_depth(vol, &ray, Interp::Trilinear)
                .expect("tau")
                .tau;
            let g = got[(j * camera.width + i) as usize];
            if want.is_infinite() || g.is_infinite() {
                assert_eq!(g, want, "{what}: pixel ({i}, {j})");
                continue;
            }
            let mut maj = 0.0;
            crate::traverse::walk(vol, &ray, Interp::Trilinear, Granularity::Leaf, |s| {
                maj += s.mu_maj.abs() * s.length();
                ControlFlow::Continue(())
            });
            let err = (g - want).abs();
            assert!(
                err <= 1e-6 * want.abs() + 1e-7 * maj,
                "{what}: pixel ({i}, {j}): sweep {g} rays {want} majorant {maj}"
            );
            hit += usize::from(want > 0.0);
            if want >= 1e-3 {
                worst = worst.max(err / want);
            }
        }
    }
    (worst, hit)
}

pub(super) fn ortho(vol: &Volume, dir: [f64; 3], res: u32) -> Camera {
    let view = View {
        projection: Projection::Ortho,
        light_dir: Some(dir),
        light_pos: None,
        fov_deg: None,
        res: Some(Resolution::Exact(res, res)),
        up: None,
        frame_box: None,
    };
    Camera::frame(&view, &vol.box_corners().expect("box")).expect("camera")
}

/// A perspective camera from a light outside the box, looking along `dir` at its centre from
/// twice its diagonal away.
pub(super) fn persp(vol: &Volume, dir: [f64; 3], res: u32) -> Camera {
    let corners = vol.box_corners().expect("box");
    let (lo, hi) = corners.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(a, b), &c| (a.min(c), b.max(c)),
    );
    let d = DVec3::from(dir).normalize();
    let pos = 0.5 * (lo + hi) - d * 2.0 * (hi - lo).length();
    let view = View {
        projection: Projection::Perspective,
        light_dir: Some(dir),
        light_pos: Some(pos.to_array()),
        fov_deg: None,
        res: Some(Resolution::Exact(res, res)),
        up: None,
        frame_box: None,
    };
    Camera::frame(&view, &corners).expect("camera")
}

/// Both projections of each direction.
pub(super) fn cameras(vol: &Volume, res: u32) -> Vec<(String, Camera)> {
    DIRS.iter()
        .flat_map(|&dir| {
            [
                (format!("ortho {dir:?}"), ortho(vol, dir, res)),
                (format!("perspective {dir:?}"), persp(vol, dir, res)),
            ]
        })
        .collect()
}

const DIRS: [[f64; 3]; 4] = [
    [0.6, -0.35, -1.0],
    [0.0, 0.0, -1.0],
    [1.0, 1.0, 1.0],
    [-0.2, 1.0, 0.05],
];

#[test]
fn corpus_maps_match_the_ray_path() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus");
    let files = [
        ("gen/cloud_fbm.vdb", "density"),
        ("gen/tiles_mixed.vdb", "density"),
        ("gen/tiles_constant_box.vdb", "density"),
        ("gen/tiles_root_level.vdb", "density"),
        ("gen/fog_nonzero_background.vdb", "density"),
        ("gen/extreme_nan_inf.vdb", "density"),
        ("gen/extreme_thick_1e6.vdb", "density"),
        ("gen/extreme_tiny_1e-8.vdb", "density"),
        ("gen/negative_coords.vdb", "density"),
        ("gen/xform_affine_rotated.vdb", "density"),
        ("gen/xform_scale_nonuniform.vdb", "density"),
        ("real/openvdb_smoke1_houdini_v222.vdb", "density"),
        ("real/blender_smoke_fluid_data_0050.vdb", "density"),
    ];
    let mut checked = 0;
    for (file, grid) in files {
        let path = root.join(file);
        if !path.exists() {
            continue;
        }
        let vol = Volume::load(&path, grid, 3.0).expect(file);
        let mut seen = 0;
        for (what, camera) in cameras(&vol, 48) {
            let (worst, hit) = check(&vol, &camera, &format!("{file} {what}"));
            seen += hit;
            // Clouds and real smokes: within 2e-6 relative wherever tau >= 1e-3 (measured:
            // cloud_fbm 1.7e-7, the Houdini smoke 1.1e-6 at the edge of a plume).
            if file.contains("cloud") || file.starts_with("real/") {
                assert!(worst <= 2e-6, "{file} {what}: {worst}");
            }
            eprintln!("{file} {what}: worst relative {worst:.2e}");
            checked += 1;
        }
        assert!(seen > 0, "{file}: no pixel saw the volume");
    }
    assert!(
        checked >= 80,
        "only {checked} views checked: is ../shared/corpus there?"
    );
}

/// Tiles at every level (root 4096^3, upper 128^3, lower 8^3), a non-zero background, values the
/// f32 kernel must not take (infinite, huge, subnormal), leaves next to tiles on every side.
#[test]
fn synthetic_trees_match_the_ray_path() {
    let m = [
        [0.5, 0.0, 0.0, 0.0],
        [0.0, 0.5, 0.0, 0.0],
        [0.0, 0.0, 0.5, 0.0],
    ];
    let fill = |b: &mut TreeBuilder, o: [i32; 3], n: i32, f: &dyn Fn(i32) -> f32| {
        for k in 0..n * n * n {
            let p = [o[0] + k % n, o[1] + (k / n) % n, o[2] + k / (n * n)];
            b.set(p, f(k));
        }
    };
    let mut cases: Vec<(&str, TreeBuilder)> = Vec::new();
    // Leaves around a lower-level tile and an upper-level tile, data on every side.
    let mut b = TreeBuilder::new(0.0);
    b.tile([8, 8, 8], 3, 1.5);
    b.tile([128, 0, 0], 7, 0.75);
    fill(&mut b, [0, 0, 0], 20, &|k| (k % 7) as f32 * 0.3);
    fill(&mut b, [120, 4, 4], 12, &|k| (k % 5) as f32 * 0.5);
    fill(&mut b, [256, 3, 3], 6, &|k| (k % 3) as f32);
    cases.push(("tiles", b));
    // A non-zero background around leaves.
    let mut b = TreeBuilder::new(0.2);
    fill(&mut b, [-12, -5, 3], 17, &|k| (k % 11) as f32 * 0.1);
    cases.push(("background", b));
    // Data on the - faces of a lower node: the shell blocks before it read it.
    let mut b = TreeBuilder::new(0.0);
    fill(&mut b, [128, 128, 128], 3, &|k| 1.0 + k as f32);
    fill(&mut b, [0, 0, 0], 2, &|k| k as f32);
    cases.push(("shells", b));
    // A root tile beside data.
    let mut b = TreeBuilder::new(0.0);
    b.tile([4096, 0, 0], 12, 0.001);
    fill(&mut b, [4090, 5, 5], 9, &|k| (k % 4) as f32);
    cases.push(("root tile", b));
    // Values the kernel leaves to the f64 path.
    let mut b = TreeBuilder::new(0.0);
    fill(&mut b, [0, 0, 0], 10, &|k| match k % 9 {
        0 => f32::INFINITY,
        1 => 1e30,
        2 => 1e-39,
        _ => 0.5,
    });
    fill(&mut b, [40, 0, 0], 10, &|k| {
        if k % 2 == 0 {
            1e-39
        } else {
            0.0
        }
    });
    fill(&mut b, [0, 40, 0], 10, &|k| {
        if k % 3 == 0 {
            3e37
        } else {
            1.0
        }
    });
    cases.push(("extreme", b));
    for (name, b) in cases {
        let vol = Volume::from_tree(name.into(), b.build(), m, 0.7).expect(name);
        let mut seen = 0;
        for (what, camera) in cameras(&vol, 40) {
            seen += check(&vol, &camera, &format!("{name} {what}")).1;
        }
        assert!(seen > 0, "{name}: no pixel saw the volume");
    }
}

/// Every pixel outside a piece's footprint misses the block, for parallel rays (and their row
/// spans) and through a pinhole; [`RowClip::at`] agrees with the independent slab test.
#[test]
fn footprints_cover_what_the_rays_cross() {
    let mut b = TreeBuilder::new(0.0);
    for k in 0..64 {
        b.set([k, k / 2, 3], 1.0);
    }
    let vol = Volume::from_tree(
        "f".into(),
        b.build(),
        [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
        ],
        1.0,
    )
    .expect("volume");
    for camera in [
        ortho(&vol, [0.3, 0.2, -1.0], 64),
        persp(&vol, [0.3, 0.2, -1.0], 64),
    ] {
        let rays = Rays::new(&vol, &camera).expect("rays").expect("frame");
        let pieces = pieces(&vol, &rays, true);
        assert!(pieces.len() > 8);
        for p in pieces {
            let (lo, hi) = rays.clipped(p.origin, 8).expect("inside the clip box");
            for j in 0..camera.height {
                for i in 0..camera.width {
                    let inside = (p.rect[0]..=p.rect[1]).contains(&i)
                        && (p.rect[2]..=p.rect[3]).contains(&j);
                    // The independent slab test, on the block clipped to the walk's box.
                    let ray = camera.pixel_ray(i, j).expect("ray");
                    let (q, d) = lookup_ray(&vol, &ray, Interp::Trilinear);
                    let hit = crate::ray::clip_box(q, d, lo, hi)
                        .is_some_and(|(a, b)| a.max(rays.t_min) < b.min(rays.t_max));
                    let mut in_span = true;
                    if let Layout::Parallel(par) = &rays.layout {
                        let row = rays.row_clip(par, j, p.origin, 8);
                        let span = row.span([0, camera.width - 1]);
                        in_span = span.is_some_and(|[a, b]| (a..=b).contains(&i));
                        assert_eq!(row.at(i).is_some(), hit, "{p:?} at ({i}, {j})");
                    }
                    if !(inside && in_span) {
                        assert!(!hit, "{p:?} misses ({i}, {j})");
                    }
                }
            }
        }
    }
}

/// A light inside the volume's box (framed with a field of view, looking along each axis and
/// obliquely) has blocks beside and behind it: those that reach behind the pinhole's plane get
/// footprints running to the image's edge, and every pixel still equals the ray path. The
/// light also sits exactly on a lattice corner of the grid.
#[test]
fn a_light_inside_the_box_is_swept_exactly() {
    let fbm =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/gen/cloud_fbm.vdb");
    let vol = Volume::load(&fbm, "density", 5.0).expect("cloud_fbm");
    let corners = vol.box_corners().expect("box");
    let centre = corners.iter().fold(DVec3::ZERO, |a, &c| a + c) / 8.0;
    let lattice = vol.to_world(vol.to_index(centre).round());
    for light in [centre, lattice] {
        for dir in [[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.3, -0.8, 0.5]] {
            let view = View {
                projection: Projection::Perspective,
                light_dir: Some(dir),
                light_pos: Some(light.to_array()),
                fov_deg: Some(100.0),
                res: Some(Resolution::Exact(24, 20)),
                up: None,
                frame_box: None,
            };
            let camera = Camera::frame(&view, &corners).expect("camera");
            assert!(Sweep::new(&vol, &camera, 16, &[]).expect("plan").is_some());
            let (_, hit) = check(&vol, &camera, &format!("inside {light} looking {dir:?}"));
            assert!(hit > 300, "{hit}");
        }
    }
}

/// Slices: pixel `n`'s slice `k` is the optical depth of `[0, t_k]`, including a depth inside
/// the volume, one before it and one past it, with and without the rest walk (a non-zero
/// background).
#[test]
fn slices_match_prefix_optical_depths() {
    let mut cases = Vec::new();
    let mut b = TreeBuilder::new(0.2);
    for k in 0..17 * 17 * 17 {
        b.set(
            [k % 17 - 12, (k / 17) % 17 - 5, k / 289 + 3],
            (k % 11) as f32 * 0.1,
        );
    }
    let m = [
        [0.5, 0.0, 0.0, 0.0],
        [0.0, 0.5, 0.0, 0.0],
        [0.0, 0.0, 0.5, 0.0],
    ];
    cases.push(Volume::from_tree("bg".into(), b.build(), m, 0.7).expect("bg"));
    let fbm =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/gen/cloud_fbm.vdb");
    cases.push(Volume::load(&fbm, "density", 5.0).expect("cloud_fbm"));
    for (vol, camera) in cases
        .iter()
        .flat_map(|v| [(v, ortho(v, DIRS[0], 32)), (v, persp(v, DIRS[0], 32))])
    {
        let mid = 0.5 * (camera.t_near + camera.t_max);
        let depths = [0.25 * camera.t_near, mid, mid + 0.01, 2.0 * camera.t_max];
        let rows = 16;
        let sweep = Sweep::new(vol, &camera, rows, &depths)
            .expect("plan")
            .expect("frame");
        let s = sweep.stride();
        let buf = run_bands(&sweep, &camera, rows);
        let mut straddled = 0;
        for n in 0..camera.pixels() as usize {
            let (i, j) = (n as u32 % camera.width, n as u32 / camera.width);
            let ray = camera.pixel_ray(i, j).expect("ray");
            for (k, &t) in depths.iter().enumerate() {
                let seg = ray.with_range(0.0, t).expect("range");
                let want = crate::regular::optical_depth(vol, &seg, Interp::Trilinear)
                    .expect("tau")
                    .tau;
                let got = buf[n * s + 1 + k];
                assert!(
                    (got - want).abs() <= 1e-6 * want + 1e-7,
                    "{}: pixel {n} slice {k}: {got} vs {want}",
                    vol.name()
                );
                straddled += usize::from(k == 1 && want > 0.0 && want < buf[n * s] * 0.99);
            }
        }
        assert!(
            straddled > 10,
            "{}: the middle slice cut too few rays",
            vol.name()
        );
    }
}

/// The march the sweep renders for estimator `name` at `step` voxels, `spp` samples.
fn march_of(name: &str, step: f64, spp: u32) -> March {
    let est = Estimator::with_params(name, &[("step", step)]).expect("estimator");
    let opts = crate::estimate::Options {
        samples: spp,
        seed: 7,
        ..crate::estimate::Options::default()
    };
    marches(&BakeSettings::new(est, opts)).expect("a march")
}

/// The sweep's march `m` of every pixel and slice against the ray path's estimate of the same
/// ray (the pixel's ray id, slice `k`'s `(64 + k) npix + p`): the same points, so within the
/// kernel's f32 positions, in `T` (`1e-6 (1 + tau) + 1e-7 M`, `M` the majorant optical depth,
/// as [`check`]). Returns how many pixels saw the volume, or `None` when the sweep declines.
fn check_march(
    vol: &Volume,
    camera: &Camera,
    m: March,
    depths: &[f64],
    what: &str,
) -> Option<usize> {
    let rows = 16;
    let planned = Sweep::new(vol, camera, rows, depths)
        .expect("plan")
        .expect("frame");
    let rest = planned.rest_needed;
    let Some(sweep) = planned.marching(Some(m), None) else {
        assert!(
            rest,
            "{what}: a march declined without extinction above lower nodes"
        );
        return None;
    };
    let (stride, samples) = (sweep.stride(), sweep.samples());
    let per = stride / samples;
    let buf = run_bands(&sweep, camera, rows);
    let (est, opts) = m.estimator();
    let npix = camera.pixels();
    let mut hit = 0;
    for n in 0..npix as usize {
        let (i, j) = (n as u32 % camera.width, n as u32 / camera.width);
        let ray = camera.pixel_ray(i, j).expect("ray");
        let mut maj = 0.0;
        crate::traverse::walk(vol, &ray, Interp::Trilinear, Granularity::Leaf, |s| {
            maj += s.mu_maj.abs() * s.length();
            ControlFlow::Continue(())
        });
        let ends = std::iter::once(None).chain(depths.iter().map(Some));
        for (k, end) in ends.enumerate() {
            let (r, id) = match end {
                Some(&t) => (
                    ray.with_range(0.0, t).expect("range"),
                    (64 + k as u64 - 1) * npix + n as u64,
                ),
                None => (ray, n as u64),
            };
            let e = crate::estimate::estimate(vol, &r, id, &est, &opts).expect("estimate");
            let want = e.value;
            let mut err = vec![0.0f32; 1];
            let mut t = [0.0f32];
            let est_of = &buf[n * stride..(n + 1) * stride];
            let got = finish_samples(camera, 0, est_of, (per, samples), None, &mut t, &mut err)
                .map(|slices| {
                    if k == 0 {
                        f64::from(t[0])
                    } else {
                        f64::from(slices[k - 1])
                    }
                })
                .expect("finite");
            let tol = 1e-6 * (1.0 - want.ln()) + 1e-7 * maj + 1e-7;
            assert!(
                (got - want).abs() <= tol,
                "{what}: pixel ({i}, {j}) slot {k}: sweep T {got} rays {want} majorant {maj}"
            );
            if k == 0 && samples > 1 {
                let err = f64::from(err[0]);
                assert!(
                    (err - e.std_err).abs() <= 2.0 * tol,
                    "{what}: pixel ({i}, {j}): std err {err} vs {}",
                    e.std_err
                );
            }
            hit += usize::from(k == 0 && want < 1.0);
        }
    }
    Some(hit)
}

/// A synthetic tree: leaves around 8^3 tiles inside a lower node (the walk splits their chords
/// into halo cells and a constant inner box) and data on the - faces of another lower node
/// (shell blocks before it, outside every lower node).
pub(super) fn tiles_and_shells() -> Volume {
    let mut b = TreeBuilder::new(0.0);
    b.tile([8, 8, 8], 3, 1.5);
    b.tile([24, 8, 8], 3, 0.0);
    for k in 0..20 * 20 * 20 {
        b.set([k % 20, (k / 20) % 20, k / 400], (k % 7) as f32 * 0.3);
    }
    for k in 0..27 {
        b.set(
            [128 + k % 3, 128 + (k / 3) % 3, 128 + k / 9],
            1.0 + k as f32,
        );
    }
    let m = [
        [0.5, 0.0, 0.0, 0.0],
        [0.0, 0.5, 0.0, 0.0],
        [0.0, 0.0, 0.5, 0.0],
    ];
    Volume::from_tree("tiles".into(), b.build(), m, 0.8).expect("volume")
}

/// Riemann maps swept block by block take the ray path's points: corpus clouds and smokes,
/// extreme media, both projections, steps on and off the voxel grid, slices.
#[test]
fn marches_match_the_ray_path() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus");
    let files = [
        ("gen/cloud_fbm.vdb", 5.0),
        ("gen/tiles_mixed.vdb", 3.0),
        ("gen/extreme_nan_inf.vdb", 3.0),
        ("gen/extreme_thick_1e6.vdb", 3.0),
        ("gen/xform_affine_rotated.vdb", 3.0),
        ("real/openvdb_smoke1_houdini_v222.vdb", 0.3),
    ];
    let mut checked = 0;
    for (file, scale) in files {
        let vol = Volume::load(root.join(file), "density", scale).expect(file);
        for (what, camera) in cameras(&vol, 40) {
            let mid = 0.5 * (camera.t_near + camera.t_max);
            for step in [1.0, 0.37, 2.0] {
                let what = format!("{file} {what} step {step}");
                let m = march_of("riemann", step, 1);
                if let Some(hit) = check_march(&vol, &camera, m, &[mid], &what) {
                    assert!(hit > 0, "{what}: no pixel saw the volume");
                    checked += 1;
                }
            }
        }
    }
    // Every file but the one with tiles above lower nodes (which goes by rays).
    assert_eq!(checked, 5 * 8 * 3);
    let vol = tiles_and_shells();
    for (what, camera) in cameras(&vol, 48) {
        let mid = 0.5 * (camera.t_near + camera.t_max);
        for step in [1.0, 0.5] {
            let what = format!("tiles and shells {what} step {step}");
            let m = march_of("riemann", step, 1);
            let hit = check_march(&vol, &camera, m, &[mid], &what).expect("swept");
            assert!(hit > 20, "{what}: {hit}");
        }
    }
}

/// Every band of `sweep` (planned for `camera` in bands of `rows` rows), one after the other:
/// the image's buffer, [`Sweep::stride`] values a pixel.
pub(super) fn run_bands(sweep: &Sweep<'_>, camera: &Camera, rows: u32) -> Vec<f64> {
    let stride = sweep.stride();
    let mut buf = vec![0.0; camera.pixels() as usize * stride];
    for (b, chunk) in buf
        .chunks_mut(rows as usize * camera.width as usize * stride)
        .enumerate()
    {
        sweep.band(b, chunk, &mut 0).expect("band");
    }
    buf
}

/// The sweep's march `m` of every pixel (`stride` values each: its estimates, each the full
/// ray then its slices at `depths`) and that stride, or `None` when the sweep declines.
fn march_buf(vol: &Volume, camera: &Camera, m: March, depths: &[f64]) -> Option<(Vec<f64>, usize)> {
    let rows = 16;
    let sweep = Sweep::new(vol, camera, rows, depths)
        .expect("plan")
        .expect("frame")
        .marching(Some(m), None)?;
    Some((run_bands(&sweep, camera, rows), sweep.stride()))
}

/// A Riemann map without slices (a leaf's chords on parallel rays staged straight into the
/// kernel's batches, `MarchBand::piece_chords`; through a pinhole staged chord by chord) has
/// the very bits of the full depth of the same map with a slice (every chord through the
/// estimates of `Sweep::jobs`): corpus files with leaves and tiles, both projections, steps on
/// and off the voxel grid.
#[test]
fn a_riemann_map_without_slices_is_bit_for_bit_its_full_depth_with_slices() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus");
    let mut vols: Vec<(String, Volume)> = [
        ("gen/cloud_fbm.vdb", 5.0),
        ("gen/tiles_mixed.vdb", 3.0),
        ("real/openvdb_smoke1_houdini_v222.vdb", 0.3),
    ]
    .into_iter()
    .map(|(file, scale)| {
        let vol = Volume::load(root.join(file), "density", scale).expect(file);
        (file.to_string(), vol)
    })
    .collect();
    vols.push(("tiles and shells".into(), tiles_and_shells()));
    let mut checked = 0;
    for (file, vol) in &vols {
        for (what, camera) in cameras(vol, 40) {
            let mid = 0.5 * (camera.t_near + camera.t_max);
            for step in [1.0, 0.37] {
                let what = format!("{file} {what} step {step}");
                let m = march_of("riemann", step, 1);
                let Some((plain, one)) = march_buf(vol, &camera, m, &[]) else {
                    continue;
                };
                let (sliced, two) = march_buf(vol, &camera, m, &[mid]).expect("swept");
                assert_eq!((one, two), (1, 2), "{what}");
                let mut seen = 0;
                for (n, &tau) in plain.iter().enumerate() {
                    assert_eq!(
                        tau.to_bits(),
                        sliced[2 * n].to_bits(),
                        "{what}: pixel {n}: {tau} without slices, {} with",
                        sliced[2 * n]
                    );
                    seen += usize::from(tau > 0.0);
                }
                assert!(seen > 20, "{what}: {seen} pixels saw the volume");
                checked += 1;
            }
        }
    }
    // Every volume but the one with extinction above lower nodes (which goes by rays).
    assert!(checked >= 3 * 8 * 2, "{checked}");
}

/// Jittered and Monte Carlo maps swept block by block draw the ray path's points (each chord's
/// stream forked by its block): several samples per pixel, slices with their own streams,
/// both projections, tiles.
#[test]
fn random_marches_match_the_ray_path() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus");
    let mut checked = 0;
    for (file, scale) in [
        ("gen/cloud_fbm.vdb", 5.0),
        ("gen/extreme_thick_1e6.vdb", 3.0),
    ] {
        let vol = Volume::load(root.join(file), "density", scale).expect(file);
        for (what, camera) in cameras(&vol, 24).into_iter().take(4) {
            let mid = 0.5 * (camera.t_near + camera.t_max);
            for (name, step, spp) in [("jittered", 1.0, 3), ("mc", 0.7, 2), ("jittered", 2.0, 1)] {
                let what = format!("{file} {what} {name} step {step} spp {spp}");
                let m = march_of(name, step, spp);
                let hit = check_march(&vol, &camera, m, &[mid], &what).expect("swept");
                assert!(hit > 0, "{what}");
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 2 * 4 * 3);
}

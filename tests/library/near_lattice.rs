//! Exact answers on rays that lie on, along and a hair off lattice planes and axes, against the
//! independent OpenVDB oracle (`../shared/tools/oracle.py`). Random rays never find these: a
//! line whose direction has a component of 1e-17 .. 1e-9 crosses a plane it nearly lies in at a
//! `t` that rounding decides, and the walk used to stop there, dropping up to a whole tile.
//!
//! The grids (`tests/near_lattice/make_grids.py`, written by pyopenvdb) hold one layered fog
//! (leaves, 8^3 and 128^3 tiles) under an axis-aligned, a rotated and a sheared map; the rays
//! run along index axes from starts on cell faces, tie planes and voxel centres with
//! perpendicular drifts of 0 and +-1e-17 .. +-1e-9, mapped to world by OpenVDB. Corpus files
//! with real variation add the same kind of rays for trilinear lookups. Needs Debian's
//! `python3-openvdb`; `UMBRA_SKIP_ORACLE=1` skips on machines without it.
//!
//! Beyond queries, the same lines are checked through every exact product that walks them:
//! maps (the object-order sweep and the ray path), deep-map profiles and transmittance volumes.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use common::oracle_available;
use std::path::{Path, PathBuf};
use std::process::Command;
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

const SCALE: f64 = 0.5;

fn shared() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared")
}

/// A world segment and whether its nearest answer is well defined (trilinear always is).
struct Seg {
    a: [f64; 3],
    b: [f64; 3],
    nearest: bool,
}

fn parse_rays(text: &str) -> Vec<Seg> {
    text.lines()
        .map(|l| {
            let (nums, tag) = l.split_once('#').unwrap_or((l, "both"));
            let v: Vec<f64> = nums
                .split_whitespace()
                .map(|x| x.parse().unwrap())
                .collect();
            Seg {
                a: [v[0], v[1], v[2]],
                b: [v[3], v[4], v[5]],
                nearest: tag.trim() == "both",
            }
        })
        .collect()
}

/// The oracle's `(tau_nearest, tau_trilinear)` for every segment: the vectorised path for all
/// of them, and the scalar reference path (pyopenvdb's accessor) on every `stride`-th one,
/// which must agree with the vectorised answer.
fn oracle(vdb: &Path, segs: &[Seg], dir: &Path, stride: usize) -> Vec<(f64, f64)> {
    let run = |segs: Vec<&Seg>, vector: bool, tag: &str| -> Vec<(f64, f64)> {
        let rays = dir.join(format!("{tag}.txt"));
        let out = dir.join(format!("{tag}.csv"));
        let txt: String = segs
            .iter()
            .map(|s| {
                format!(
                    "{:?} {:?} {:?} {:?} {:?} {:?}\n",
                    s.a[0], s.a[1], s.a[2], s.b[0], s.b[1], s.b[2]
                )
            })
            .collect();
        std::fs::write(&rays, txt).unwrap();
        let mut cmd = Command::new("/usr/bin/python3");
        cmd.arg(shared().join("tools/oracle.py"))
            .args(["rays", vdb.to_str().unwrap(), "--grid", "density"])
            .args(["--scale", &SCALE.to_string()])
            .args([
                "--rays",
                rays.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ]);
        if vector {
            cmd.arg("--vector");
        }
        let o = cmd.output().unwrap();
        assert!(
            o.status.success(),
            "oracle failed on {}: {}",
            vdb.display(),
            String::from_utf8_lossy(&o.stderr)
        );
        std::fs::read_to_string(&out)
            .unwrap()
            .lines()
            .skip(1)
            .map(|l| {
                let c: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
                (c[2], c[4])
            })
            .collect()
    };
    let all = run(segs.iter().collect(), true, "vector");
    let picked: Vec<&Seg> = segs.iter().step_by(stride).collect();
    let scalar = run(picked, false, "scalar");
    for (k, s) in scalar.iter().enumerate() {
        let v = all[k * stride];
        // Nearest answers on tie planes are either column's: compared only where defined.
        let mut pairs = vec![(s.1, v.1)];
        if segs[k * stride].nearest {
            pairs.push((s.0, v.0));
        }
        for (x, y) in pairs {
            assert!(
                close(x, y),
                "the oracle's two paths disagree on ray {}: {x} vs {y}",
                k * stride
            );
        }
    }
    all
}

fn close(got: f64, want: f64) -> bool {
    (got - want).abs() <= 1e-6 * want.abs() + 1e-12
}

/// umbra's exact tau on every segment against the oracle's; returns the mismatches.
fn compare(name: &str, vol: &Volume, segs: &[Seg], want: &[(f64, f64)]) -> (usize, Vec<String>) {
    let mut bad = Vec::new();
    let mut n = 0;
    for (s, w) in segs.iter().zip(want) {
        let r = Ray::between(s.a, s.b).unwrap();
        let mut cases = vec![(Interp::Trilinear, w.1)];
        if s.nearest {
            cases.push((Interp::Nearest, w.0));
        }
        for (interp, want) in cases {
            let got = optical_depth(vol, &r, interp).unwrap().tau;
            n += 1;
            if !close(got, want) {
                bad.push(format!(
                    "{name} {interp:?} {:?} -> {:?}: umbra tau {got}, OpenVDB {want}",
                    s.a, s.b
                ));
            }
        }
    }
    (n, bad)
}

fn generated(dir: &Path) {
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/near_lattice/make_grids.py");
    let o = Command::new("/usr/bin/python3")
        .arg(script)
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "make_grids.py: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn queries_on_near_lattice_rays_match_the_openvdb_oracle() {
    if !oracle_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    generated(dir.path());
    let mut failures = Vec::new();
    let mut compared = 0;
    for map in ["scale", "rotated", "sheared"] {
        let vdb = dir.path().join(format!("layered_{map}.vdb"));
        let text = std::fs::read_to_string(dir.path().join(format!("layered_{map}.rays"))).unwrap();
        let segs = parse_rays(&text);
        assert!(segs.len() > 2000, "{} rays", segs.len());
        let want = oracle(&vdb, &segs, dir.path(), 9);
        let vol = Volume::load(&vdb, "density", SCALE).unwrap();
        let (n, bad) = compare(map, &vol, &segs, &want);
        compared += n;
        failures.extend(bad);
    }
    assert!(compared > 8000, "{compared}");
    assert!(
        failures.is_empty(),
        "{} of {compared} near-lattice answers differ from OpenVDB's:\n{}",
        failures.len(),
        failures[..failures.len().min(30)].join("\n")
    );
}

/// Corpus grids with real variation (leaves, tiles of every level, a rotated map): rays along
/// index axes from the grid's lattice planes with the same drifts, trilinear.
#[test]
fn corpus_grids_on_near_lattice_rays_match_the_openvdb_oracle() {
    if !oracle_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    let mut compared = 0;
    for file in ["gen/tiles_mixed.vdb", "gen/xform_affine_rotated.vdb"] {
        let path = shared().join("corpus").join(file);
        let vol = Volume::load(&path, "density", SCALE).unwrap();
        let segs = corpus_rays(&vol);
        let want = oracle(&path, &segs, dir.path(), 7);
        let (n, bad) = compare(file, &vol, &segs, &want);
        compared += n;
        failures.extend(bad);
    }
    assert!(compared >= 400, "{compared}");
    assert!(
        failures.is_empty(),
        "{} of {compared} near-lattice answers differ from OpenVDB's:\n{}",
        failures.len(),
        failures[..failures.len().min(30)].join("\n")
    );
}

/// Index-space lines along each axis through the grid's index box, laterally on integer
/// planes (leaf faces among them) and half-integers, with drifts 0 and +-1e-17 .. +-1e-9,
/// mapped to world with the volume's transform.
fn corpus_rays(vol: &Volume) -> Vec<Seg> {
    let [lo, hi] = vol.value_box().unwrap();
    let (lo, hi) = (lo.map(|c| c as f64), hi.map(|c| c as f64));
    let drifts = [0.0, 1e-17, -1e-15, 1e-13, -1e-11, 1e-9];
    let mut out = Vec::new();
    for axis in 0..3 {
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        let lateral = |a: usize| {
            let m = (0.5 * (lo[a] + hi[a])).floor();
            let eight = (m / 8.0).floor() * 8.0;
            [lo[a], eight, eight + 0.5, m + 3.0, hi[a], hi[a] + 1.0]
        };
        for (pb, pc) in lateral(b).into_iter().zip(lateral(c).into_iter().rev()) {
            for drift in drifts {
                for sign in [1.0, -1.0] {
                    let mut p = [0.0; 3];
                    p[axis] = if sign > 0.0 {
                        lo[axis] - 3.0
                    } else {
                        hi[axis] + 3.0
                    };
                    (p[b], p[c]) = (pb, pc);
                    let len = hi[axis] - lo[axis] + 6.0;
                    let mut q = p;
                    q[axis] += sign * len;
                    q[b] += drift * len;
                    q[c] -= 0.6 * drift * len;
                    out.push(Seg {
                        a: vol.to_world(p).to_array(),
                        b: vol.to_world(q).to_array(),
                        nearest: false,
                    });
                }
            }
        }
    }
    out
}

/// The world images of the index axes of `vol` (columns of its linear part).
fn index_axes(vol: &Volume) -> [umbra::glam::DVec3; 3] {
    let o = vol.to_world(umbra::glam::DVec3::ZERO);
    [
        umbra::glam::DVec3::X,
        umbra::glam::DVec3::Y,
        umbra::glam::DVec3::Z,
    ]
    .map(|a| vol.to_world(a) - o)
}

/// Exact maps of suns straight down an index axis with drifts 0 .. 1e-9 (what a light
/// direction out of a rotated transform gives), pixels on lattice planes and tie planes: the
/// sweep and the ray path give, at every pixel, the exact optical depth of that pixel's ray
/// (the one the query test proves against OpenVDB), in both interpolations; deep-map profiles
/// end at it; transmittance volumes of the same suns hold it at every voxel.
#[test]
fn maps_profiles_and_transmittance_volumes_on_near_lattice_rays_are_exact() {
    if !oracle_available() {
        return;
    }
    use umbra::bake::{BakeSettings, Camera, CameraSpec, Order, Projection};
    use umbra::estimate::{Estimator, Options};
    let dir = tempfile::tempdir().unwrap();
    generated(dir.path());
    let mut checked = 0u64;
    let mut bad = Vec::new();
    for map in ["scale", "rotated"] {
        let vdb = dir.path().join(format!("layered_{map}.vdb"));
        let vol = Volume::load(&vdb, "density", SCALE).unwrap();
        let [ei, ej, ek] = index_axes(&vol);
        for drift in [0.0, 1e-17, -1e-15, 1e-13, -1e-11, 1e-9] {
            // Down index k, drifting along i and j; pixels every half voxel from i = j = 124.
            let d = -ek + ei * drift - ej * (0.6 * drift);
            let origin = vol.to_world(umbra::glam::DVec3::new(124.0, 124.0, 230.0));
            let spec = CameraSpec {
                kind: Projection::Ortho,
                width: 40,
                height: 24,
                origin: origin.to_array(),
                step_x: (ei * 0.5).to_array(),
                step_y: (ej * -0.5).to_array(),
                direction: d.normalize().to_array(),
                t_max: 250.0 * ek.length(),
            };
            let camera = Camera::from_spec(&spec).unwrap();
            for interp in [Interp::Trilinear, Interp::Nearest] {
                for order in [Order::Auto, Order::Rays] {
                    let opts = Options {
                        interp,
                        ..Options::default()
                    };
                    let settings = BakeSettings {
                        order,
                        ..BakeSettings::new(Estimator::REGULAR, opts)
                    };
                    let m = umbra::bake::bake(&vol, &camera, &settings, &|_| {}).unwrap();
                    for j in 0..camera.height() {
                        for i in 0..camera.width() {
                            let r = camera.pixel_ray(i, j).unwrap();
                            let want = optical_depth(&vol, &r, interp).unwrap().transmittance();
                            let got = f64::from(m.t[(j * camera.width() + i) as usize]);
                            checked += 1;
                            if (got - want).abs() > 2e-6 * want.max(1e-3) {
                                bad.push(format!(
                                    "{map} map drift {drift:e} {interp:?} {order:?} pixel ({i}, {j}): T {got} vs {want}"
                                ));
                            }
                        }
                    }
                }
                // Profiles of the same rays end at the same optical depth.
                for (i, j) in [(0, 0), (7, 3), (15, 15), (33, 20)] {
                    let r = camera.pixel_ray(i, j).unwrap();
                    let want = optical_depth(&vol, &r, interp).unwrap().tau;
                    let p = umbra::regular::optical_depth_profile(&vol, &r, interp, 1e-4).unwrap();
                    let got = p.at(r.t_max());
                    checked += 1;
                    if (got - want).abs() > 1e-9 * want.max(1.0) {
                        bad.push(format!(
                            "{map} profile drift {drift:e} {interp:?} pixel ({i}, {j}): tau {got} vs {want}"
                        ));
                    }
                }
            }
            // A transmittance volume lit by the same sun (from above: toward -k).
            let light = umbra::Light::Directional { dir: d.to_array() };
            let (leaves, _) = umbra::bake::transmittance_leaves(
                &vol,
                &light,
                &Estimator::REGULAR,
                &Options::default(),
                0,
                &|_| {},
            )
            .unwrap();
            for leaf in leaves.iter().step_by(37) {
                for n in (0..512).step_by(61) {
                    if leaf.active[n / 64] >> (n % 64) & 1 == 0 {
                        continue;
                    }
                    let ijk = [n >> 6, (n >> 3) & 7, n & 7];
                    let p = umbra::glam::DVec3::from_array(
                        [0, 1, 2].map(|a| f64::from(leaf.origin[a]) + ijk[a] as f64),
                    );
                    let at = vol.to_world(p).to_array();
                    let r = light.ray_from(&vol, at).unwrap();
                    let want = optical_depth(&vol, &r, Interp::Trilinear)
                        .unwrap()
                        .transmittance();
                    let got = f64::from(leaf.values[n]);
                    checked += 1;
                    if (got - want).abs() > 2e-6 * want.max(1e-3) {
                        bad.push(format!(
                            "{map} transmittance volume drift {drift:e} voxel {p}: T {got} vs {want}"
                        ));
                    }
                }
            }
        }
    }
    assert!(checked > 20_000, "{checked}");
    assert!(
        bad.is_empty(),
        "{} of {checked} differ:\n{}",
        bad.len(),
        bad[..bad.len().min(30)].join("\n")
    );
}

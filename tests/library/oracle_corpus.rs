//! Exact regular tracking against the independent OpenVDB oracle (`../shared/tools/oracle.py`,
//! pyopenvdb accessor + exact per-cell integration) on corpus files: tau must agree to 1e-6
//! relative for nearest and trilinear lookups. Needs Debian's `python3-openvdb`
//! (`.ci/run` installs it); set `UMBRA_SKIP_ORACLE=1` to skip on machines without it.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use common::oracle_available;
use rand::{Rng, SeedableRng};
use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::Command;
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

const CASES: &[(&str, &str, f64)] = &[
    ("gen/puff_blosc.vdb", "density", 20.0),
    ("gen/cloud_fbm_half.vdb", "density", 5.0),
    ("gen/tiles_mixed.vdb", "density", 3.0),
    ("gen/fog_nonzero_background.vdb", "density", 4.0),
    ("gen/xform_affine_rotated.vdb", "density", 10.0),
    ("gen/xform_scale_nonuniform.vdb", "density", 10.0),
    ("gen/negative_coords.vdb", "density", 10.0),
    ("gen/sphere_fog.vdb", "density", 2.0),
    ("real/openvdb_smoke1_houdini_v222.vdb", "density", 0.5),
];

#[test]
fn exact_regular_tracking_matches_the_openvdb_oracle() {
    let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared");
    if !oracle_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(2026);
    let mut compared = 0;
    let mut failures = Vec::new();
    let mut worst = 0.0f64;
    let mut worst_any = 0.0f64;
    for &(file, grid, scale) in CASES {
        let path = shared.join("corpus").join(file);
        let vol = Volume::load(&path, grid, scale).unwrap();
        let info =
            umbra::info::FileInfo::from_archive(&umbra::internals::vdb::open(&path).unwrap());
        let g = info.grids.iter().find(|g| g.name == grid).unwrap();
        let [lo, hi] = g.world_bbox.unwrap();
        // Segments between random points of the bbox grown by 20%, plus axis-aligned ones.
        let mut rays = Vec::new();
        let pick = |rng: &mut rand_pcg::Pcg64| {
            [0, 1, 2].map(|a| {
                let (l, h) = (lo[a], hi[a]);
                let m = 0.2 * (h - l);
                rng.gen_range(l - m..h + m)
            })
        };
        for i in 0..24 {
            let a = pick(&mut rng);
            let mut b = pick(&mut rng);
            if i % 6 == 0 {
                b = [a[0], a[1], b[2]]; // parallel to z
            }
            rays.push((a, b));
        }
        let mut txt = String::new();
        for (a, b) in &rays {
            writeln!(txt, "{} {} {} {} {} {}", a[0], a[1], a[2], b[0], b[1], b[2]).unwrap();
        }
        let rays_path = dir.path().join("rays.txt");
        let out_path = dir.path().join("out.csv");
        std::fs::write(&rays_path, txt).unwrap();
        let status = Command::new("/usr/bin/python3")
            .arg(shared.join("tools/oracle.py"))
            .args([
                "rays",
                path.to_str().unwrap(),
                "--grid",
                grid,
                "--scale",
                &scale.to_string(),
            ])
            .args([
                "--rays",
                rays_path.to_str().unwrap(),
                "--out",
                out_path.to_str().unwrap(),
            ])
            .output()
            .unwrap();
        assert!(
            status.status.success(),
            "oracle failed on {file}: {}",
            String::from_utf8_lossy(&status.stderr)
        );
        let csv = std::fs::read_to_string(&out_path).unwrap();
        for (line, (a, b)) in csv.lines().skip(1).zip(&rays) {
            let cols: Vec<f64> = line.split(',').map(|c| c.parse().unwrap()).collect();
            let r = Ray::between(*a, *b).unwrap();
            for (interp, want) in [(Interp::Nearest, cols[2]), (Interp::Trilinear, cols[4])] {
                let got = optical_depth(&vol, &r, interp).unwrap().tau;
                let diff = (got - want).abs();
                let err = diff / want.abs().max(1e-300);
                worst = worst.max(if diff > 1e-12 { err } else { 0.0 });
                worst_any = worst_any.max(if want > 0.0 { err } else { 0.0 });
                if err > 1e-6 && diff > 1e-12 {
                    failures.push(format!(
                        "{file} {interp:?} {a:?}->{b:?}: umbra {got} oracle {want} (rel {err:.2e})"
                    ));
                }
                compared += 1;
            }
        }
    }
    eprintln!(
        "oracle: {compared} tau values on {} files, worst relative difference {worst_any:.2e} ({worst:.2e} where the difference exceeds 1e-12)",
        CASES.len()
    );
    assert!(compared >= CASES.len() * 48);
    assert!(
        failures.is_empty(),
        "{} mismatches:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

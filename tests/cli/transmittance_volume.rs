//! Transmittance volumes (`umbra bake ... -o NAME.vdb`), read back by real OpenVDB: pyopenvdb
//! (Debian's `/usr/bin/python3`) lists every active voxel of the written grid, which must be
//! exactly the density's active voxels (active tiles included) with the density's transform,
//! background 1; every value equals the exact transmittance from the voxel centre toward the
//! light (regular tracking on the ray `Light::ray_from` makes), and a sample of them equals the
//! independent OpenVDB oracle (`../shared/tools/oracle.py`) on the same segments; `vdb_print`
//! lists the grid. Without pyopenvdb / vdb_print the tests fail under `CI`, else skip.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;
use umbra::{Interp, Light, Volume};

fn umbra_bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_umbra"))
}

fn cloud() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb")
}

/// Whether a tool is there; under `CI` a missing one fails the test.
fn have(what: &str, ok: bool) -> bool {
    if !ok {
        assert!(
            std::env::var_os("CI").is_none(),
            "{what} is needed under CI"
        );
        eprintln!("skipping: {what} is missing");
    }
    ok
}

fn pyopenvdb() -> bool {
    let ok = Command::new("/usr/bin/python3")
        .args(["-c", "import pyopenvdb"])
        .output()
        .is_ok_and(|o| o.status.success());
    have("pyopenvdb (/usr/bin/python3, Debian python3-openvdb)", ok)
}

/// What pyopenvdb reads: the written grid's active voxels `(i, j, k, value)`, its
/// background, name and `indexToWorld` of 4 points, and whether every voxel is active in the
/// density grid, whose active voxel count (tiles expanded) is given too.
struct ReadBack {
    voxels: Vec<([i32; 3], f64)>,
    background: f64,
    name: String,
    index_to_world: Vec<[f64; 3]>,
    density_count: u64,
    all_on_in_density: bool,
}

fn read_back(vdb: &Path, grid: &str, density: &Path) -> ReadBack {
    let script = r#"
import sys, json, pyopenvdb as vdb
out, grid, dens = sys.argv[1], sys.argv[2], sys.argv[3]
g = vdb.read(out, grid)
d = vdb.read(dens, 'density')
acc = d.getConstAccessor()
vox = []
on = True
for it in g.citerOnValues():
    lo, hi = it.min, it.max
    for i in range(lo[0], hi[0] + 1):
        for j in range(lo[1], hi[1] + 1):
            for k in range(lo[2], hi[2] + 1):
                vox.append([i, j, k, float(it.value) if (lo == hi) else float(g.getConstAccessor().getValue((i, j, k)))])
                on = on and acc.isValueOn((i, j, k))
pts = [g.transform.indexToWorld(p) for p in [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]]
print(json.dumps({"voxels": vox, "background": g.background, "name": g.name,
                  "index_to_world": [list(p) for p in pts],
                  "density_count": d.activeVoxelCount(), "all_on": on}))
"#;
    let o = Command::new("/usr/bin/python3")
        .args(["-c", script])
        .args([vdb.to_str().unwrap(), grid, density.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "pyopenvdb: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let f = |x: &serde_json::Value| x.as_f64().unwrap();
    ReadBack {
        voxels: v["voxels"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| {
                let e = e.as_array().unwrap();
                ([0, 1, 2].map(|a| e[a].as_i64().unwrap() as i32), f(&e[3]))
            })
            .collect(),
        background: f(&v["background"]),
        name: v["name"].as_str().unwrap().to_string(),
        index_to_world: v["index_to_world"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| [0, 1, 2].map(|a| f(&p[a])))
            .collect(),
        density_count: v["density_count"].as_u64().unwrap(),
        all_on_in_density: v["all_on"].as_bool().unwrap(),
    }
}

/// Bake a transmittance volume with the CLI; its `--json` report.
fn bake(out: &Path, args: &[&str]) -> serde_json::Value {
    let o = umbra_bin()
        .arg("bake")
        .arg(cloud())
        .args(args)
        .args(["-o", out.to_str().unwrap(), "--json", "--quiet"])
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "umbra bake {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_slice(&o.stdout).unwrap()
}

/// The exact transmittance of voxel `ijk` toward `light` in `vol`.
fn exact(vol: &Volume, light: &Light, ijk: [i32; 3], interp: Interp) -> f64 {
    let p = vol.to_world(glam::DVec3::from_array(ijk.map(f64::from)));
    let ray = light.ray_from(vol, p.to_array()).unwrap();
    umbra::regular::optical_depth(vol, &ray, interp)
        .unwrap()
        .transmittance()
}

/// The oracle's optical depths of the rays from `every`-th voxel toward `light`:
/// `(value written, oracle T)`.
fn oracle(
    vol: &Volume,
    light: &Light,
    rb: &ReadBack,
    every: usize,
    scale: f64,
    interp: Interp,
    dir: &Path,
) -> Vec<(f64, f64)> {
    let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/tools/oracle.py");
    let mut txt = String::new();
    let picked: Vec<_> = rb.voxels.iter().step_by(every).collect();
    for (ijk, _) in &picked {
        let p = vol.to_world(glam::DVec3::from_array(ijk.map(f64::from)));
        let ray = light.ray_from(vol, p.to_array()).unwrap();
        let e = ray.at(ray.t_max());
        txt += &format!("{} {} {} {} {} {}\n", p.x, p.y, p.z, e[0], e[1], e[2]);
    }
    let rays = dir.join("rays.txt");
    let out = dir.join("oracle.csv");
    std::fs::write(&rays, txt).unwrap();
    let o = Command::new("/usr/bin/python3")
        .arg(shared)
        .args(["rays", cloud().to_str().unwrap(), "--grid", "density"])
        .args(["--scale", &scale.to_string()])
        .args([
            "--rays",
            rays.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "oracle: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let col = match interp {
        Interp::Nearest => 2,
        Interp::Trilinear => 4,
    };
    std::fs::read_to_string(out)
        .unwrap()
        .lines()
        .skip(1)
        .zip(&picked)
        .map(|(l, (_, v))| {
            let tau: f64 = l.split(',').nth(col).unwrap().parse().unwrap();
            (*v, (-tau).exp())
        })
        .collect()
}

/// The common checks: topology, background, name, transform, every value against exact
/// regular tracking (`tol` absolute), a sample against the oracle.
#[allow(clippy::too_many_arguments)]
fn check(
    dir: &Path,
    out: &Path,
    grid: &str,
    light: Light,
    scale: f64,
    interp: Interp,
    xform: Option<&umbra::internals::xform::Xform>,
    tol: f64,
) {
    let rb = read_back(out, grid, &cloud());
    let mut vol = Volume::load(cloud(), "density", scale).unwrap();
    if let Some(x) = xform {
        vol = vol.with_xform(x).unwrap();
    }
    assert_eq!(rb.name, grid);
    assert_eq!(rb.background, 1.0);
    assert_eq!(
        rb.voxels.len() as u64,
        rb.density_count,
        "active voxel count"
    );
    assert_eq!(umbra::bake::output_voxels(&vol), rb.density_count);
    assert!(
        rb.all_on_in_density,
        "a written voxel is not active in the density"
    );
    for (k, p) in [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ]
    .iter()
    .enumerate()
    {
        let want = vol.to_world(glam::DVec3::from_array(*p)).to_array();
        for a in 0..3 {
            assert!(
                (rb.index_to_world[k][a] - want[a]).abs() <= 1e-9 * (1.0 + want[a].abs()),
                "indexToWorld {p:?}: {:?} vs {want:?}",
                rb.index_to_world[k]
            );
        }
    }
    let mut worst = 0.0f64;
    for (ijk, v) in &rb.voxels {
        let t = exact(&vol, &light, *ijk, interp);
        worst = worst.max((v - t).abs());
        assert!((v - t).abs() <= tol, "voxel {ijk:?}: {v} vs exact {t}");
    }
    if xform.is_none() {
        let pairs = oracle(&vol, &light, &rb, 500, scale, interp, dir);
        assert!(pairs.len() >= 250);
        for (v, t) in pairs {
            assert!(
                (v - t).abs() <= tol + 1e-6,
                "oracle: written {v} vs OpenVDB oracle {t}"
            );
        }
    }
    eprintln!(
        "{}: {} voxels, worst |T - exact| {worst:.2e}",
        out.display(),
        rb.voxels.len()
    );
}

#[test]
fn lattice_suns_share_lines_and_are_exact() {
    if !pyopenvdb() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // Axis suns, diagonal ones and one along the lattice step (3, -10, 2) (a typed 0.3,-1,0.2).
    for (name, d, interp, share) in [
        ("down.vdb", [0.0, -1.0, 0.0], Interp::Trilinear, 10),
        ("side.vdb", [1.0, 0.0, 0.0], Interp::Nearest, 10),
        ("back.vdb", [0.0, 0.0, -2.0], Interp::Trilinear, 10),
        ("diag.vdb", [1.0, -1.0, 0.0], Interp::Trilinear, 10),
        ("diag_near.vdb", [-1.0, -1.0, 1.0], Interp::Nearest, 10),
        ("lattice.vdb", [0.3, -1.0, 0.2], Interp::Trilinear, 2),
    ] {
        let out = dir.path().join(name);
        let ds = format!("{},{},{}", d[0], d[1], d[2]);
        let interp_arg = format!("{interp:?}").to_lowercase();
        let j = bake(
            &out,
            &[
                &format!("--light-dir={ds}"),
                "--density-scale",
                "4",
                "--interp",
                &interp_arg,
            ],
        );
        assert_eq!(j["sharing"], "lines", "{j}");
        // Fewer rays than voxels: one per line of voxels.
        assert!(
            j["rays"].as_u64().unwrap() * share < j["voxels"].as_u64().unwrap(),
            "{j}"
        );
        check(
            dir.path(),
            &out,
            "transmittance",
            Light::Directional { dir: d },
            4.0,
            interp,
            None,
            2e-6,
        );
    }
}

#[test]
fn oblique_and_point_lights_trace_every_voxel_exactly() {
    if !pyopenvdb() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("obl.vdb");
    // No lattice step of at most 16 is parallel to this one.
    let d = [0.413_579_246_8, -1.0, 0.271_939_182_5];
    let ds = format!("--light-dir={},{},{}", d[0], d[1], d[2]);
    let j = bake(&out, &[&ds, "--density-scale", "4"]);
    assert_eq!(j["sharing"], "rays", "{j}");
    assert_eq!(j["rays"], j["voxels"], "{j}");
    check(
        dir.path(),
        &out,
        "transmittance",
        Light::Directional { dir: d },
        4.0,
        Interp::Trilinear,
        None,
        2e-7,
    );
    let out = dir.path().join("pt.vdb");
    bake(
        &out,
        &[
            "--light-pos=0.5,3,0.2",
            "--interp",
            "nearest",
            "--out-grid",
            "shadow",
        ],
    );
    check(
        dir.path(),
        &out,
        "shadow",
        Light::Point {
            pos: [0.5, 3.0, 0.2],
        },
        1.0,
        Interp::Nearest,
        None,
        2e-7,
    );
}

#[test]
fn xform_and_half_floats_read_back() {
    if !pyopenvdb() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("moved.vdb");
    // Turned 30 degrees about y, scaled 2, moved.
    let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
    let m = [
        2.0 * c,
        0.0,
        2.0 * s,
        10.0,
        0.0,
        2.0,
        0.0,
        -3.0,
        -2.0 * s,
        0.0,
        2.0 * c,
        4.0,
        0.0,
        0.0,
        0.0,
        1.0,
    ];
    let ms: Vec<String> = m.iter().map(|v| v.to_string()).collect();
    let xform = umbra::internals::xform::Xform::from_row_major(&m).unwrap();
    bake(
        &out,
        &["--light-dir=0,-1,0", "--xform", &ms.join(","), "--half"],
    );
    // Half floats: within half's rounding (relative 2^-11) of the exact value.
    check(
        dir.path(),
        &out,
        "transmittance",
        Light::Directional {
            dir: [0.0, -1.0, 0.0],
        },
        1.0,
        Interp::Trilinear,
        Some(&xform),
        5e-4,
    );
}

#[test]
fn vdb_print_lists_the_grid() {
    let ok = Command::new("vdb_print").arg("-version").output().is_ok();
    if !have("vdb_print (Debian libopenvdb-tools)", ok) {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.vdb");
    let j = bake(&out, &["--light-dir=0,-1,0"]);
    let o = Command::new("vdb_print")
        .args(["-l", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout).replace(',', "");
    let voxels = j["voxels"].as_u64().unwrap().to_string();
    assert!(text.contains("Name: transmittance"), "{text}");
    assert!(
        text.contains(&format!("Number of active voxels:       {voxels}"))
            || text.contains(&voxels),
        "{text}"
    );
    assert!(text.contains("Background value: 1"), "{text}");
}

#[test]
fn transmittance_volumes_refuse_map_options_and_leave_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.vdb");
    let o = out.to_str().unwrap();
    let f = cloud();
    let file = f.to_str().unwrap();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["--light-dir=0,-1,0", "--preview", "p.png"],
            "'--preview': applies to maps",
        ),
        (
            vec!["--light-dir=0,-1,0", "--sigma-t", "1,1,1"],
            "'--sigma-t': applies to maps",
        ),
        (
            vec!["--light-dir=0,-1,0", "--deep"],
            "'--deep': applies to maps",
        ),
        (
            vec!["--light-dir=0,-1,0", "--res", "64"],
            "'--res': applies to maps",
        ),
        (vec![], "'--light-dir': no light"),
        (vec!["--light-dir=0,-1,0", "--light-pos=0,5,0"], "not both"),
        (vec!["--light-dir=0,0,0"], "light-dir"),
        (vec!["--light-dir=0,-1,0", "--out-grid", ""], "out-grid"),
        (vec!["--light-dir=0,-1,0", "--grid", "nope"], "nope"),
    ];
    for (args, want) in cases {
        let r = umbra_bin()
            .args(["bake", file, "-o", o])
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&r.stderr);
        assert_eq!(r.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.starts_with("umbra: error:") && err.contains(want),
            "{args:?}: {err}"
        );
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            0,
            "{args:?}"
        );
    }
    // An existing file is kept without --force.
    std::fs::write(&out, b"keep").unwrap();
    let r = umbra_bin()
        .args(["bake", file, "-o", o, "--light-dir=0,-1,0"])
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(1));
    assert_eq!(std::fs::read(&out).unwrap(), b"keep");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    // --out-grid and --half belong to .vdb outputs.
    let r = umbra_bin()
        .args(["bake", file, "-o"])
        .arg(dir.path().join("m.exr"))
        .args(["--light-dir=0,-1,0", "--half"])
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(1));
}

/// A batch job whose output pattern ends in `.vdb` writes transmittance volumes: each task's
/// file equals `umbra bake INPUT --light-dir D -o OUT.vdb`'s byte for byte (sun and point
/// light, `out_grid`, `half`); map keys with a `.vdb` pattern, and `half` with an `.exr`
/// pattern, are refused naming the key.
#[test]
fn batch_jobs_write_transmittance_volumes() {
    let dir = tempfile::tempdir().unwrap();
    let job = |output: &str, extra: &str| {
        let p = dir.path().join("job.toml");
        std::fs::write(
            &p,
            format!(
                "output = \"{}/{output}\"\n[[inputs]]\nfile = {:?}\n\
                 [[lights]]\nname = \"sun\"\ndir = [0, -1, 0]\n\
                 [[lights]]\nname = \"lamp\"\npos = [0.5, 4, 0.2]\n\
                 [bake]\ndensity_scale = 2\n{extra}\n",
                dir.path().display(),
                cloud().display().to_string()
            ),
        )
        .unwrap();
        umbra_bin()
            .args(["batch", p.to_str().unwrap(), "-q", "--force"])
            .output()
            .unwrap()
    };
    let o = job("{stem}_{light}.vdb", "out_grid = \"shadow\"\nhalf = true");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for (name, light) in [
        ("sun", "--light-dir=0,-1,0"),
        ("lamp", "--light-pos=0.5,4,0.2"),
    ] {
        let cli = dir.path().join(format!("cli_{name}.vdb"));
        let r = umbra_bin()
            .arg("bake")
            .arg(cloud())
            .args([
                light,
                "--density-scale",
                "2",
                "--out-grid",
                "shadow",
                "--half",
                "-q",
                "-o",
            ])
            .arg(&cli)
            .output()
            .unwrap();
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        // The batch's file is the command's, but for the task's key it carries.
        let from_batch = dir.path().join(format!("cloud_{name}.vdb"));
        assert!(
            crate::common::same_volume_but_key(&from_batch, &cli),
            "{name}: batch and CLI files differ"
        );
    }
    for (output, extra, key) in [
        (
            "{stem}_{light}.vdb",
            "preview = \"p_{light}.png\"",
            "bake.preview",
        ),
        ("{stem}_{light}.vdb", "res = 64", "bake.res"),
        ("{stem}_{light}.vdb", "deep = true", "bake.deep"),
        ("{stem}_{light}.exr", "half = true", "bake.half"),
        ("{stem}_{light}.exr", "out_grid = \"t\"", "bake.out_grid"),
    ] {
        let o = job(output, extra);
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{extra}: {e}");
        assert!(e.contains(key), "{extra}: {e}");
    }
}

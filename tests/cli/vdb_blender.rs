//! Transmittance volumes (`umbra bake ... -o NAME.vdb`) load in Blender (Debian's 3.4, run
//! headless as `python/tests/test_blender.py` does): a volume datablock pointed at the file lists
//! exactly one grid, named as baked (`transmittance`, or the `--out-grid` name), of type `FLOAT`
//! with 1 channel, for 32-bit floats, `--half` and an `--xform` (an `AffineMap`); every grid's
//! tree loads (`VolumeGrid.load()`); its `matrix_object` equals the index-to-world transform
//! umbra computes for the density (`Volume::world_from_index`, with the `--xform` applied: the
//! same matrix umbra reads back from the written file) within 1e-6; and the object's bounds,
//! which Blender takes from the loaded tree, are the world box of the written leaves.
//!
//! What Blender 3.4 reports: `VolumeGrid.matrix_object` is "transformation matrix from voxel
//! index to object space", `BKE_volume_grid_transform_matrix`: the grid transform's
//! `baseMap()->getAffineMap()->getMat4()` copied into a single-precision 4x4 (so within f32
//! rounding of the file's doubles). Read through `mathutils` row by row, it is the column-vector
//! matrix `world = M (i, j, k, 1)`: the linear part in the upper 3x3, the translation in the last
//! column, `(0, 0, 0, 1)` in the bottom row; integer index coordinates are voxel centres, no
//! half-voxel shift. "Object space" is the VDB file's world space (the object's own
//! `matrix_world` then places it in the scene; identity here). The object's `bound_box` is
//! `BKE_volume_grid_bounds`: the index-to-world image of the grid's *leaf* bounding box
//! (`evalLeafBoundingBox`, corners at voxel centres), which is what the last check compares.
//!
//! Without `blender` the test fails under `CI`, else prints a skip message and passes.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use glam::{DAffine3, DVec3};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use umbra::Volume;

/// Prefix of the one stdout line of the Blender script that holds its JSON report.
const PREFIX: &str = "UMBRA_BLENDER_GRIDS ";

/// The Blender script: for every file after `--`, a volume datablock with that file path, its
/// grids' metadata, each grid's tree loaded, and the evaluated object's bounds.
const SCRIPT: &str = r#"
import bpy, json, sys
report = []
for path in sys.argv[sys.argv.index("--") + 1:]:
    vol = bpy.data.volumes.new("v")
    vol.filepath = path
    rec = {"path": path, "load": vol.grids.load(), "is_loaded": vol.grids.is_loaded,
           "error": vol.grids.error_message, "grids": []}
    for g in vol.grids:
        rec["grids"].append({
            "name": g.name, "data_type": g.data_type, "channels": g.channels,
            "matrix_object": [list(row) for row in g.matrix_object],
            "tree_loaded": bool(g.load()) and g.is_loaded})
    ob = bpy.data.objects.new("o", vol)
    bpy.context.scene.collection.objects.link(ob)
    ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    corners = [tuple(c) for c in ev.bound_box]
    rec["bounds"] = [[min(c[a] for c in corners) for a in range(3)],
                     [max(c[a] for c in corners) for a in range(3)]]
    report.append(rec)
print("UMBRA_BLENDER_GRIDS " + json.dumps(report), flush=True)
"#;

fn cloud() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb")
}

/// Whether `blender` runs; under `CI` a missing one fails the test.
fn have_blender() -> bool {
    let ok = Command::new("blender")
        .args(["-b", "--factory-startup", "--version"])
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        assert!(
            std::env::var_os("CI").is_none(),
            "blender is needed under CI (Debian's `blender`)"
        );
        eprintln!("skipping: blender is not installed");
    }
    ok
}

/// `umbra bake data/cloud.vdb ARGS -o OUT`: a transmittance volume.
fn bake(out: &Path, args: &[&str]) {
    let o = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .arg("bake")
        .arg(cloud())
        .args(args)
        .args(["-o", out.to_str().unwrap(), "--quiet"])
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "umbra bake {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Blender's report on `files`, one object per file.
fn blender_report(dir: &Path, files: &[&Path]) -> Vec<Value> {
    let script = dir.join("grids.py");
    std::fs::write(&script, SCRIPT).unwrap();
    let o = Command::new("blender")
        .args([
            "-b",
            "--factory-startup",
            "--python-exit-code",
            "1",
            "--python",
        ])
        .arg(&script)
        .arg("--")
        .args(files)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    let all = || format!("{stdout}\n{}", String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "blender failed:\n{}", all());
    let line = stdout
        .lines()
        .find_map(|l| l.strip_prefix(PREFIX))
        .unwrap_or_else(|| panic!("no {PREFIX:?} line from blender:\n{}", all()));
    serde_json::from_str::<Value>(line)
        .unwrap()
        .as_array()
        .unwrap()
        .clone()
}

/// `matrix_object` as Blender printed it (rows) against `m` (column vectors): the upper 3x4
/// within `tol`, the bottom row exactly `(0, 0, 0, 1)`.
fn assert_matrix(what: &str, rows: &Value, m: DAffine3, tol: f64) {
    let got: Vec<Vec<f64>> = rows
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            r.as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect()
        })
        .collect();
    assert_eq!(got.len(), 4, "{what}: {got:?}");
    let cols = [
        m.matrix3.x_axis,
        m.matrix3.y_axis,
        m.matrix3.z_axis,
        m.translation,
    ];
    for (r, row) in got.iter().enumerate() {
        assert_eq!(row.len(), 4, "{what}: {got:?}");
        for (c, &v) in row.iter().enumerate() {
            let want = if r < 3 {
                cols[c][r]
            } else if c == 3 {
                1.0
            } else {
                0.0
            };
            assert!(
                (v - want).abs() <= tol,
                "{what}: matrix_object[{r}][{c}] = {v}, umbra's world_from_index has {want} \
                 (Blender: {got:?}, umbra: {m:?})"
            );
        }
    }
}

/// The world box of the leaves of a transmittance volume as umbra reads it: the axis-aligned
/// box of the index-to-world image of the leaves' index box (inclusive, voxel centres).
fn leaf_world_box(vol: &Volume) -> [DVec3; 2] {
    let leaves = vol.tree().leaves();
    assert!(!leaves.is_empty());
    let mut lo = [i32::MAX; 3];
    let mut hi = [i32::MIN; 3];
    for l in leaves {
        for a in 0..3 {
            lo[a] = lo[a].min(l.origin[a]);
            hi[a] = hi[a].max(l.origin[a] + 7);
        }
    }
    let m = vol.world_from_index();
    let mut b = [DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)];
    for n in 0..8 {
        let ijk = [0, 1, 2].map(|a| f64::from(if n >> a & 1 == 0 { lo[a] } else { hi[a] }));
        let p = m.transform_point3(DVec3::from_array(ijk));
        b = [b[0].min(p), b[1].max(p)];
    }
    b
}

#[test]
fn blender_loads_transmittance_volumes() {
    if !have_blender() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("cloud_t.vdb");
    let half = dir.path().join("cloud_t_half.vdb");
    let moved = dir.path().join("cloud_t_moved.vdb");
    bake(&plain, &["--light-dir=0,-1,0", "--density-scale", "4"]);
    bake(
        &half,
        &["--light-dir=0.4,-1,0.3", "--density-scale", "4", "--half"],
    );
    // Turned 30 degrees about y, scaled 1.5, moved: an AffineMap in the file.
    let (c, s) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
    let m = [
        1.5 * c,
        0.0,
        1.5 * s,
        1.0,
        0.0,
        1.5,
        0.0,
        -2.0,
        -1.5 * s,
        0.0,
        1.5 * c,
        0.5,
        0.0,
        0.0,
        0.0,
        1.0,
    ];
    let ms: Vec<String> = m.iter().map(|v| format!("{v:?}")).collect();
    bake(
        &moved,
        &[
            "--light-dir=0,-1,0",
            "--xform",
            &ms.join(","),
            "--out-grid",
            "shadow",
        ],
    );

    let density = Volume::load(cloud(), "density", 1.0).unwrap();
    let xform = umbra::internals::xform::Xform::from_row_major(&m).unwrap();
    let moved_density = Volume::load(cloud(), "density", 1.0)
        .unwrap()
        .with_xform(&xform)
        .unwrap();
    let cases = [
        (&plain, "transmittance", density.world_from_index()),
        (&half, "transmittance", density.world_from_index()),
        (&moved, "shadow", moved_density.world_from_index()),
    ];
    let files: Vec<&Path> = cases.iter().map(|c| c.0.as_path()).collect();
    let report = blender_report(dir.path(), &files);
    assert_eq!(report.len(), cases.len(), "{report:?}");

    for ((path, grid, want), rec) in cases.iter().zip(&report) {
        let what = path.file_name().unwrap().to_string_lossy();
        eprintln!("blender on {what}: {rec}");
        assert_eq!(rec["load"], true, "{what}: {rec}");
        assert_eq!(rec["is_loaded"], true, "{what}: {rec}");
        assert_eq!(rec["error"], "", "{what}: {rec}");
        let grids = rec["grids"].as_array().unwrap();
        assert_eq!(grids.len(), 1, "{what}: exactly one grid: {rec}");
        let g = &grids[0];
        assert_eq!(g["name"], *grid, "{what}: {rec}");
        assert_eq!(g["data_type"], "FLOAT", "{what}: {rec}");
        assert_eq!(g["channels"], 1, "{what}: {rec}");
        assert_eq!(g["tree_loaded"], true, "{what}: the grid's tree: {rec}");

        // The transform: umbra's own for the density (with the --xform), which is also what
        // umbra reads back from the written file.
        let written = Volume::load(path, grid, 1.0).unwrap();
        let back = written.world_from_index();
        assert!(
            back.abs_diff_eq(*want, 1e-12),
            "{what}: written {back:?}, wanted {want:?}"
        );
        assert_matrix(&what, &g["matrix_object"], *want, 1e-6);

        // The bounds Blender takes from the loaded tree: the written leaves' world box.
        let b = leaf_world_box(&written);
        for (k, end) in ["min", "max"].into_iter().enumerate() {
            for a in 0..3 {
                let v = rec["bounds"][k][a].as_f64().unwrap();
                assert!(
                    (v - b[k][a]).abs() <= 1e-5,
                    "{what}: bounds {end}[{a}] = {v}, leaves' world box {b:?}: {rec}"
                );
            }
        }
    }
}

//! Independent cross-check: for every corpus file that vdb-rs 0.6.0 reads correctly (per the
//! corpus manifest), every active voxel and tile vdb-rs yields must have the same value and be
//! active in umbra's tree, and the active leaf-voxel counts must agree.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

fn corpus() -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus");
    if p.is_dir() {
        Some(p)
    } else {
        assert!(
            std::env::var("UMBRA_SKIP_CORPUS").as_deref() == Ok("1"),
            "../shared/corpus is missing (set UMBRA_SKIP_CORPUS=1 to skip corpus tests)"
        );
        None
    }
}

/// (file, stored grid name) pairs vdb-rs reads without loss, float grids.
const FLOAT_CASES: &[(&str, &str)] = &[
    ("gen/cloud_fbm.vdb", "density"),
    ("gen/puff_blosc.vdb", "density"),
    ("gen/puff_zip.vdb", "density"),
    ("gen/puff_none.vdb", "density"),
    ("gen/puff_blosc_nomask.vdb", "density"),
    ("gen/puff_zip_nomask.vdb", "density"),
    ("gen/puff_activemask_only.vdb", "density"),
    ("gen/sphere_fog.vdb", "density"),
    ("gen/sphere_levelset.vdb", "ls_sphere"),
    ("gen/tiles_constant_box.vdb", "density"),
    ("gen/tiles_mixed.vdb", "density"),
    ("gen/negative_coords.vdb", "density"),
    ("gen/extreme_nan_inf.vdb", "density"),
    ("gen/extreme_negative.vdb", "density"),
    ("gen/extreme_thick_1e6.vdb", "density"),
    ("gen/extreme_tiny_1e-8.vdb", "density"),
    ("gen/fog_nonzero_background.vdb", "density"),
    ("gen/sparse_far_blobs.vdb", "density"),
    ("gen/multigrid_smoke.vdb", "temperature"),
    ("gen/duplicate_grid_names.vdb", "density\u{1e}1"),
    ("gen/xform_scale_translate.vdb", "density"),
    ("real/openvdb_smoke1_houdini_v222.vdb", "density"),
    ("real/openvdb_sphere_levelset_houdini_v222.vdb", "ls_sphere"),
    ("real/unnamed_levelset_sphere.vdb", "\u{1e}0"),
    ("real/blender_smoke_fluid_data_0050.vdb", "density"),
    ("real/blender_smoke_fluid_data_0050.vdb", "phi_obstacle"),
];

fn vdbrs_items(path: &std::path::Path, grid: &str) -> Vec<([i32; 3], f32, u32)> {
    let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
    let mut reader = vdb_rs::VdbReader::new(file).unwrap();
    let g = reader.read_grid::<f32>(grid).unwrap();
    g.iter()
        .map(|(c, v, level)| {
            let dim = level.scale() as u32;
            ([c.x as i32, c.y as i32, c.z as i32], v, dim)
        })
        .collect()
}

#[test]
fn every_active_value_vdb_rs_reads_matches_umbra() {
    let Some(dir) = corpus() else { return };
    let mut checked_values = 0u64;
    let mut failures = Vec::new();
    for &(file, grid) in FLOAT_CASES {
        let path = dir.join(file);
        let ours = umbra::internals::vdb::load_grid(&path, grid).unwrap();
        let tree = &ours.tree;
        let theirs = vdbrs_items(&path, grid);
        let mut leaf_voxels = 0u64;
        let mut bad = 0;
        for (ijk, v, dim) in &theirs {
            if *dim == 1 {
                leaf_voxels += 1;
            }
            let u = tree.value(*ijk);
            let same = u.to_bits() == v.to_bits() || (u.is_nan() && v.is_nan());
            if !same || !tree.is_active(*ijk) {
                bad += 1;
                if bad <= 3 {
                    failures.push(format!(
                        "{file}:{grid}: at {ijk:?} (dim {dim}) vdb-rs {v} vs umbra {u} (active {})",
                        tree.is_active(*ijk)
                    ));
                }
            }
            checked_values += 1;
        }
        let stats = tree.stats();
        if stats.active_leaf_voxels != leaf_voxels {
            failures.push(format!(
                "{file}:{grid}: active leaf voxels vdb-rs {leaf_voxels} vs umbra {}",
                stats.active_leaf_voxels
            ));
        }
    }
    eprintln!(
        "vdb-rs cross-check: {} grids, {checked_values} active values/tiles compared",
        FLOAT_CASES.len()
    );
    assert!(
        checked_values > 1_000_000,
        "too few values compared: {checked_values}"
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn int32_grid_matches_vdb_rs() {
    let Some(dir) = corpus() else { return };
    let path = dir.join("gen/int32_flags.vdb");
    let ours = umbra::internals::vdb::load_grid(&path, "flags").unwrap();
    let file = std::io::BufReader::new(std::fs::File::open(&path).unwrap());
    let mut reader = vdb_rs::VdbReader::new(file).unwrap();
    let g = reader.read_grid::<i32>("flags").unwrap();
    let mut n = 0;
    for (c, v, _) in g.iter() {
        let ijk = [c.x as i32, c.y as i32, c.z as i32];
        assert_eq!(ours.tree.value(ijk), v as f32, "at {ijk:?}");
        n += 1;
    }
    assert!(n > 1000);
}

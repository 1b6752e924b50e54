//! The project's own samples in `data/` read back exactly as OpenVDB describes them in
//! `data/stats.json` (written by `tools/make_data.py` with pyopenvdb).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use serde_json::Value;
use std::path::PathBuf;

#[test]
fn data_samples_match_their_openvdb_stats() {
    let data = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data");
    let stats: Value =
        serde_json::from_str(&std::fs::read_to_string(data.join("stats.json")).unwrap()).unwrap();
    let mut grids = 0;
    for (file, entry) in stats["files"].as_object().unwrap() {
        let archive = umbra::internals::vdb::open(data.join(file)).unwrap();
        let info = umbra::info::FileInfo::from_archive(&archive);
        for want in entry["grids"].as_array().unwrap() {
            let name = want["name"].as_str().unwrap();
            let got = info
                .grids
                .iter()
                .find(|g| g.name == name)
                .unwrap_or_else(|| panic!("{file}: no grid {name}"));
            let ctx = format!("{file}:{name}");
            assert_eq!(got.error, None, "{ctx}");
            assert_eq!(
                got.active_voxels,
                want["active_voxel_count"].as_u64(),
                "{ctx} active voxels"
            );
            assert_eq!(got.leaf_count, want["leaf_count"].as_u64(), "{ctx} leaves");
            let bbox = got.index_bbox.unwrap();
            let lo: Vec<i64> = want["active_bbox_min"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_i64().unwrap())
                .collect();
            let hi: Vec<i64> = want["active_bbox_max"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_i64().unwrap())
                .collect();
            assert_eq!(bbox[0].map(i64::from).to_vec(), lo, "{ctx} bbox min");
            assert_eq!(bbox[1].map(i64::from).to_vec(), hi, "{ctx} bbox max");
            // f32 values; stats.json went through Python's float repr, so allow f32 rounding.
            for key in ["min", "max"] {
                let g = if key == "min" {
                    &got.value_min
                } else {
                    &got.value_max
                };
                let (g, w) = (
                    g.as_ref().and_then(Value::as_f64).unwrap(),
                    want[key].as_f64().unwrap(),
                );
                assert!((g - w).abs() <= 1e-7 * w.abs(), "{ctx} {key} {g} vs {w}");
            }
            let (s, w) = (got.value_sum.unwrap(), want["active_sum"].as_f64().unwrap());
            assert!(
                (s - w).abs() <= 1e-9 * w.abs().max(1.0),
                "{ctx} sum {s} vs {w}"
            );
            assert_eq!(
                got.background.as_ref().and_then(Value::as_f64),
                want["background"].as_f64(),
                "{ctx} background"
            );
            assert_eq!(
                got.saved_as_half,
                want["saved_as_half"].as_bool().unwrap(),
                "{ctx} half"
            );
            let tiles = got.tiles.as_ref().unwrap();
            let n_tiles: u64 = ["root", "upper", "lower"]
                .iter()
                .map(|k| tiles[k].as_u64().unwrap())
                .sum();
            assert_eq!(
                Some(n_tiles),
                want["active_tile_count"].as_u64(),
                "{ctx} tiles"
            );
            grids += 1;
        }
    }
    assert_eq!(grids, 5, "expected 5 grids in data/stats.json");
}

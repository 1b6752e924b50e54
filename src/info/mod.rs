//! `umbra info`: what a `.vdb` file holds, grid by grid, as a serializable report; what a
//! baked map says about itself ([`map`]).

pub mod map;

use crate::vdb::{Archive, Grid, LazyGrid, ValueKind};
use serde::Serialize;
use serde_json::{json, Value};

/// Which bytes of a NanoVDB grid buffer its checksum covered (`.nvdb` only). The magic number
/// and the checksum itself, the buffer's first 16 bytes, are not counted:
/// `checked_bytes + unchecked_bytes = grid_bytes` = the buffer's size - 16.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct ChecksumCoverage {
    /// Bytes the checksum covered.
    pub checked_bytes: u64,
    /// Bytes of the grid buffer after its magic number and checksum.
    pub grid_bytes: u64,
    /// Bytes it did not cover: `grid_bytes - checked_bytes` (0 for a full checksum of 32.5 on
    /// and for fixed-size leaves without blind data).
    pub unchecked_bytes: u64,
    /// Of those, the bytes of FpN leaves' codes (voxel values): a checksum of NanoVDB 32.4
    /// (and 32.5 to 32.6 checked the 32.4 way) covers each leaf's fixed 96 bytes only, so a
    /// corrupt code is not detected, by umbra or by NanoVDB.
    pub unchecked_code_bytes: u64,
}

/// Per-grid report, the JSON schema of `umbra info --json`.
#[derive(Debug, Clone, Serialize)]
pub struct GridInfo {
    /// Display name (`density[1]` for duplicates, `[0]` for unnamed grids).
    pub name: String,
    /// Name as stored (with OpenVDB's `\x1e` separator).
    pub stored_name: String,
    /// OpenVDB value type (`float`, `double`, `vec3s`, ...).
    pub value_type: String,
    /// Tree type name as stored, without `_HalfFloat`.
    pub tree_type: String,
    /// `class` metadata, if any.
    pub class: Option<String>,
    /// Compression as OpenVDB names it.
    pub compression: Option<String>,
    /// Whether values are stored as halves.
    pub saved_as_half: bool,
    /// Background value.
    pub background: Option<Value>,
    /// World length of each index axis.
    pub voxel_size: Option<[f64; 3]>,
    /// OpenVDB map type name.
    pub map: Option<String>,
    /// 4x4 affine, column-vector convention, row-major (translation in the last column).
    pub world_from_index: Option<[[f64; 4]; 4]>,
    /// Inclusive index bbox of active voxels `[[min], [max]]`.
    pub index_bbox: Option<[[i32; 3]; 2]>,
    /// World bbox of the active voxel centres (the 8 corners of `index_bbox` mapped to world).
    pub world_bbox: Option<[[f64; 3]; 2]>,
    /// Active voxels; tiles count as the voxels they cover.
    pub active_voxels: Option<u64>,
    /// Number of leaf nodes.
    pub leaf_count: Option<u64>,
    /// Active tile counts per level.
    pub tiles: Option<Value>,
    /// Smallest active value (NaN ignored; `"inf"`/`"-inf"` as strings).
    pub value_min: Option<Value>,
    /// Largest active value.
    pub value_max: Option<Value>,
    /// Sum of finite active values, tiles weighted by voxel count.
    pub value_sum: Option<f64>,
    /// Active NaN voxels.
    pub nan_count: Option<u64>,
    /// Active ±Inf voxels.
    pub inf_count: Option<u64>,
    /// What the value statistics are of: `value` or `vector length`.
    pub value_stats_of: &'static str,
    /// Bytes of umbra's tree.
    pub memory_bytes: Option<u64>,
    /// OpenVDB's `file_mem_bytes` metadata, if present.
    pub file_mem_bytes: Option<i64>,
    /// Double grids only: the cost of converting to `f32` for tracing.
    pub precision_loss: Option<crate::vdb::PrecisionLoss>,
    /// Why the grid could not be decoded, if it could not.
    pub error: Option<String>,
    /// Why only the header is described (a grid type umbra does not decode: point data, other
    /// tree configurations), if so. Such a grid is valid: it is not an error.
    pub note: Option<String>,
    /// `.nvdb` only: the file's codec for the grid (`NONE`, `ZIP`, `BLOSC`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub codec: Option<String>,
    /// `.nvdb` only: how the leaves quantise values (`none`, `fp4`, `fp8`, `fp16`, `fpN`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub quantisation: Option<String>,
    /// `.nvdb` only: `full` (the file carries a full checksum, head and tail, and the grid
    /// matches it: every byte but where `checksum_coverage` says otherwise), `partial` (the
    /// file carries only the head's, NanoVDB's default: the headers match, the nodes were not
    /// checked), `absent` (the file carries none) or `mismatch` (then `error` says what
    /// disagrees).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub checksum: Option<String>,
    /// `.nvdb` only, with a matching `full` or `partial` checksum: which bytes it covered.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub checksum_coverage: Option<ChecksumCoverage>,
    /// `.nvdb` only: the grid buffer's NanoVDB version (`32.8.0`); the file header's may
    /// differ (Warp writes 32.3.3 there).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nanovdb_version: Option<String>,
    /// Vector grids only: what a motion or advection setup needs to know of the vectors.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vector: Option<VectorInfo>,
}

/// What a vector grid's metadata says of its vectors.
#[derive(Debug, Clone, Serialize)]
pub struct VectorInfo {
    /// Component type: `vec3s`, `vec3d` or `vec3i`.
    pub value_type: String,
    /// Whether the grid's class is `staggered` (a MAC grid: each component sits on a face,
    /// not at the voxel centre).
    pub staggered: bool,
    /// OpenVDB's `vector_type` metadata (`invariant`, `covariant`, `covariant normalize`,
    /// `contravariant relative`, `contravariant absolute`), if the file has it.
    pub vector_type: Option<String>,
    /// OpenVDB's `is_local_space` metadata (vectors in index space, not world space), if the
    /// file has it.
    pub is_local_space: Option<bool>,
}

impl VectorInfo {
    /// The vector facts of `grid`, `None` for a scalar grid.
    #[must_use]
    pub fn of(grid: &Grid) -> Option<Self> {
        use crate::input::VectorFacts;
        if !matches!(
            grid.value_type,
            ValueKind::Vec3s | ValueKind::Vec3d | ValueKind::Vec3i
        ) {
            return None;
        }
        Some(Self {
            value_type: grid.value_type.name().to_string(),
            staggered: grid.is_staggered(),
            vector_type: grid.vector_type().map(str::to_string),
            is_local_space: grid.local_space(),
        })
    }
}

/// A float as JSON: a number when finite, else `"inf"`, `"-inf"` or `"nan"`.
#[must_use]
pub fn json_f32(v: f32) -> Value {
    if v.is_finite() {
        json!(f64::from(v))
    } else if v.is_nan() {
        json!("nan")
    } else if v > 0.0 {
        json!("inf")
    } else {
        json!("-inf")
    }
}

impl GridInfo {
    /// Report on a decoded grid.
    #[must_use]
    pub fn from_grid(grid: &Grid, tree_type: &str) -> Self {
        let mut info = Self::describe(grid, tree_type, &grid.tree.stats());
        info.memory_bytes = Some(grid.tree.memory_bytes());
        info.precision_loss = grid.precision_loss;
        info
    }

    /// Report on a lazily opened grid: the same report as [`GridInfo::from_grid`] of its full
    /// load (`memory_bytes` from the topology, see [`LazyGrid::loaded_memory_bytes`]), with
    /// the values streamed chunk by chunk ([`LazyGrid::stats`]) instead of held.
    ///
    /// # Errors
    /// Decoding errors of the leaf values.
    pub fn from_lazy(lazy: &LazyGrid, tree_type: &str) -> crate::error::Result<Self> {
        let (stats, precision) = lazy.stats()?;
        let mut info = Self::describe(lazy.shell(), tree_type, &stats);
        info.memory_bytes = Some(lazy.loaded_memory_bytes());
        info.precision_loss = precision;
        Ok(info)
    }

    /// Everything but the memory and precision figures.
    fn describe(grid: &Grid, tree_type: &str, s: &crate::tree::TreeStats) -> Self {
        let t = &grid.transform;
        let world_bbox = s.index_bbox.filter(|_| t.is_affine()).map(|b| {
            let mut lo = [f64::INFINITY; 3];
            let mut hi = [f64::NEG_INFINITY; 3];
            for c in 0..8 {
                let p = [0, 1, 2].map(|a| f64::from(b[(c >> a) & 1][a]));
                let w = t.index_to_world(p);
                for a in 0..3 {
                    lo[a] = lo[a].min(w[a]);
                    hi[a] = hi[a].max(w[a]);
                }
            }
            [lo, hi]
        });
        let vector = matches!(
            grid.value_type,
            ValueKind::Vec3s | ValueKind::Vec3d | ValueKind::Vec3i
        );
        Self {
            name: grid.name.clone(),
            stored_name: grid.stored_name.clone(),
            value_type: grid.value_type.name().to_string(),
            tree_type: tree_type.to_string(),
            class: grid.class.clone(),
            compression: Some(grid.compression.describe()),
            saved_as_half: grid.saved_as_half,
            background: Some(json_f32(grid.tree.background)),
            voxel_size: t.is_affine().then(|| t.voxel_size()),
            map: Some(t.map.clone()),
            world_from_index: t.is_affine().then_some(t.world_from_index),
            index_bbox: s.index_bbox,
            world_bbox,
            active_voxels: Some(s.active_voxels),
            leaf_count: Some(s.leaf_count),
            tiles: Some(
                json!({"root": s.root_tiles, "upper": s.upper_tiles, "lower": s.lower_tiles}),
            ),
            value_min: s.value_range.map(|r| json_f32(r.0)),
            value_max: s.value_range.map(|r| json_f32(r.1)),
            value_sum: Some(s.value_sum),
            nan_count: Some(s.nan_count),
            inf_count: Some(s.inf_count),
            value_stats_of: if vector { "vector length" } else { "value" },
            memory_bytes: None,
            file_mem_bytes: grid.file_mem_bytes(),
            precision_loss: None,
            error: None,
            note: None,
            codec: None,
            quantisation: None,
            checksum: None,
            checksum_coverage: None,
            nanovdb_version: None,
            vector: VectorInfo::of(grid),
        }
    }

    /// Report on a grid umbra does not decode, from its header `h`: identity, class,
    /// compression and transform; `note` says why the tree's figures are absent.
    #[must_use]
    pub fn from_header(gd: &crate::vdb::GridDescriptor, h: &crate::vdb::GridHeader) -> Self {
        let t = &h.transform;
        let what = if gd.tree_type.contains("ptdata") {
            "point data"
        } else {
            "a grid type umbra does not decode"
        };
        Self {
            class: h.class.clone(),
            compression: Some(h.compression.describe()),
            voxel_size: t.is_affine().then(|| t.voxel_size()),
            map: Some(t.map.clone()),
            world_from_index: t.is_affine().then_some(t.world_from_index),
            file_mem_bytes: h.file_mem_bytes(),
            error: None,
            note: Some(format!(
                "{what} ({}): described from its header; umbra traces float and double grids",
                gd.tree_type
            )),
            ..Self::failed(
                &gd.display_name,
                &gd.stored_name,
                &gd.tree_type,
                gd.saved_as_half,
                String::new(),
            )
        }
    }

    /// Report on a grid that failed to decode: what the directory says, plus the error.
    #[must_use]
    pub fn failed(name: &str, stored: &str, tree_type: &str, half: bool, err: String) -> Self {
        Self {
            name: name.to_string(),
            stored_name: stored.to_string(),
            value_type: tree_type
                .strip_prefix("Tree_")
                .and_then(|t| t.strip_suffix("_5_4_3"))
                .unwrap_or(tree_type)
                .to_string(),
            tree_type: tree_type.to_string(),
            class: None,
            compression: None,
            saved_as_half: half,
            background: None,
            voxel_size: None,
            map: None,
            world_from_index: None,
            index_bbox: None,
            world_bbox: None,
            active_voxels: None,
            leaf_count: None,
            tiles: None,
            value_min: None,
            value_max: None,
            value_sum: None,
            nan_count: None,
            inf_count: None,
            value_stats_of: "value",
            memory_bytes: None,
            file_mem_bytes: None,
            precision_loss: None,
            error: Some(err),
            note: None,
            codec: None,
            quantisation: None,
            checksum: None,
            checksum_coverage: None,
            nanovdb_version: None,
            vector: None,
        }
    }
}

/// Report on a whole file: header facts and one [`GridInfo`] per grid, in file order. Grids
/// that fail to decode are reported with their error; the file-level call still succeeds.
#[derive(Debug, Clone, Serialize)]
pub struct FileInfo {
    /// Path as given.
    pub path: String,
    /// The file's format: `vdb` (OpenVDB) or `nvdb` (NanoVDB).
    pub format: &'static str,
    /// File size in bytes.
    pub file_bytes: u64,
    /// File format version (`.nvdb`: NanoVDB's major version, the ABI).
    pub file_version: u32,
    /// Writer library version `major.minor` (`.nvdb`: the first segment's `major.minor.patch`).
    pub library_version: String,
    /// File UUID (`.nvdb`: empty, NanoVDB files have none).
    pub uuid: String,
    /// Grids the file holds (`grids` has fewer when one grid was asked for).
    pub grid_count: usize,
    /// Grids in file order.
    pub grids: Vec<GridInfo>,
}

impl FileInfo {
    /// The report on `path` (`umbra info`): every grid, or only `grid` (display name such as
    /// `density[1]`, or the stored name), whose values alone are then read.
    ///
    /// # Errors
    /// [`crate::error::Error::InvalidArgument`] (name `files`) for a scene file; opening errors;
    /// [`crate::error::Error::GridNotFound`]. A grid that cannot be decoded is reported with its
    /// error instead.
    pub fn read(path: &std::path::Path, grid: Option<&str>) -> crate::error::Result<Self> {
        let source = crate::input::Source::new(path, crate::input::SourceOptions::default());
        if source.kind().is_scene_file() {
            return Err(crate::error::Error::InvalidArgument {
                name: "files".into(),
                reason: format!(
                    "{} is a scene file; info reports on .vdb files (run it on the files the \
                     scene names)",
                    path.display()
                ),
            });
        }
        if source.kind() == crate::input::InputKind::Nvdb {
            return Self::read_nvdb(path, grid);
        }
        let archive = crate::vdb::open(path)?;
        let only = match grid {
            Some(name) => Some(archive.find_grid(name)?.stored_name.clone()),
            None => None,
        };
        Ok(Self::from_archive_grids(&archive, |gd| {
            only.as_ref().is_none_or(|s| *s == gd.stored_name)
        }))
    }

    /// Decode every grid of `archive` and report on it (streaming each grid's values, see
    /// [`GridInfo::from_lazy`]).
    #[must_use]
    pub fn from_archive(archive: &Archive) -> Self {
        Self::from_archive_grids(archive, |_| true)
    }

    /// [`FileInfo::from_archive`] for the grids `wanted` accepts; the others are not read.
    #[must_use]
    pub fn from_archive_grids(
        archive: &Archive,
        wanted: impl Fn(&crate::vdb::GridDescriptor) -> bool,
    ) -> Self {
        let grids = archive
            .grids
            .iter()
            .filter(|gd| wanted(gd))
            .map(|gd| {
                let failed = |e: crate::error::Error| {
                    let (name, stored, half) =
                        (&gd.display_name, &gd.stored_name, gd.saved_as_half);
                    GridInfo::failed(name, stored, &gd.tree_type, half, e.to_string())
                };
                if crate::vdb::ValueKind::from_tree_type(&gd.tree_type).is_err() {
                    // Valid, but not a grid umbra decodes: its header still says what it is.
                    return archive
                        .header(gd)
                        .map_or_else(failed, |h| GridInfo::from_header(gd, &h));
                }
                archive
                    .open_lazy(gd)
                    .and_then(|lazy| GridInfo::from_lazy(&lazy, &gd.tree_type))
                    .unwrap_or_else(failed)
            })
            .collect();
        Self {
            path: archive.path.display().to_string(),
            format: crate::input::InputKind::Vdb.format(),
            file_bytes: archive.file_len,
            file_version: archive.file_version,
            library_version: format!(
                "{}.{}",
                archive.library_version.0, archive.library_version.1
            ),
            uuid: archive.uuid.clone(),
            grid_count: archive.grids.len(),
            grids,
        }
    }
}

impl FileInfo {
    /// The report on a NanoVDB file: every grid (or only `grid`) decoded whole and described
    /// with the keys of a `.vdb` grid plus its codec, quantisation and checksum; a grid type
    /// umbra does not decode is described from the file's metadata (a note, not an error).
    fn read_nvdb(path: &std::path::Path, grid: Option<&str>) -> crate::error::Result<Self> {
        let file = crate::nvdb::NvdbFile::open(path)?;
        let only = grid.map(|g| file.find_grid(g)).transpose()?;
        let grids = (0..file.grids.len())
            .filter(|&i| only.is_none_or(|o| o == i))
            .map(|i| GridInfo::from_nvdb(&file, i))
            .collect();
        let version = file.grids.first().map(|g| g.version);
        Ok(Self {
            path: path.display().to_string(),
            format: crate::input::InputKind::Nvdb.format(),
            file_bytes: file.file_len,
            file_version: version.map_or(0, crate::nvdb::Version::major),
            library_version: version.map_or_else(String::new, |v| v.to_string()),
            uuid: String::new(),
            grid_count: file.grids.len(),
            grids,
        })
    }
}

impl GridInfo {
    /// Report on grid `i` of a NanoVDB file.
    fn from_nvdb(file: &crate::nvdb::NvdbFile, i: usize) -> Self {
        use crate::nvdb::{class_name, quantisation, type_name, Checksum};
        let meta = &file.grids[i];
        let tree_type = type_name(meta.grid_type);
        let mut info = match file.decode(i) {
            Ok(d) => {
                let mut info = Self::from_grid(&d.grid, tree_type);
                if let Checksum::Mismatch(why) = &d.checksum {
                    info.error = Some(format!("checksum mismatch: {why}"));
                }
                info.checksum = Some(d.checksum.name().to_string());
                info.checksum_coverage = d.checksum.coverage().map(|c| ChecksumCoverage {
                    checked_bytes: c.checked,
                    grid_bytes: c.grid,
                    unchecked_bytes: c.unchecked(),
                    unchecked_code_bytes: c.codes,
                });
                info.nanovdb_version = Some(d.version.to_string());
                info
            }
            Err(crate::error::Error::Unsupported { what, .. })
                if !crate::nvdb::is_decoded(meta.grid_type) =>
            {
                let [lo, hi] = meta.index_bbox;
                let empty = (0..3).any(|a| lo[a] > hi[a]);
                // Counts a writer left out (Warp's zeros) are not reported as counts.
                let counted = meta.counted.then_some(());
                Self {
                    class: Some(class_name(meta.grid_class).to_string()),
                    voxel_size: Some(meta.voxel_size),
                    index_bbox: counted.and((!empty).then_some(meta.index_bbox)),
                    world_bbox: (!empty).then_some(meta.world_bbox),
                    active_voxels: counted.map(|()| meta.voxel_count),
                    leaf_count: counted.map(|()| u64::from(meta.node_count[0])),
                    tiles: counted.map(|()| {
                        json!({"root": meta.tile_count[2], "upper": meta.tile_count[1],
                        "lower": meta.tile_count[0]})
                    }),
                    error: None,
                    note: Some(format!(
                        "{what}: described from the file's metadata{}",
                        if meta.counted {
                            ""
                        } else {
                            " (its writer left the counts and index bbox out)"
                        }
                    )),
                    ..Self::failed(&file.names[i], &meta.name, tree_type, false, String::new())
                }
            }
            Err(e) => Self::failed(&file.names[i], &meta.name, tree_type, false, e.to_string()),
        };
        info.codec = Some(meta.codec.name().to_string());
        info.quantisation = Some(quantisation(meta.grid_type).to_string());
        info
    }
}

//! A minimal OpenVDB writer for tests: uncompressed (compression flags 0) files in format 224,
//! in the layout `openvdb::io::File::write` uses (header, file metadata, grid count, then per
//! grid its descriptor, compression flags, metadata, transform, topology and leaf buffers, with
//! the descriptor's three offsets filled in), without the statistics metadata OpenVDB adds
//! (`file_bbox_min` ...), so `vdb_print`, pyopenvdb and umbra all read what it writes (the
//! round-trip test in `tests/cli/hostile.rs` checks this). On top of valid files it records where every
//! offset and length field sits ([`Layout`]) and can patch them, to craft hostile files.
//!
//! Format facts (OpenVDB 10 `io/Archive.cc`, `tree/RootNode.h`, `tree/InternalNode.h`,
//! `tree/LeafNode.h`, `io/Compression.h`, `math/Maps.h`):
//! - strings are a u32 length then the bytes; all numbers little-endian;
//! - a metadata entry is name, type name, u32 byte size, the bytes;
//! - a node's value array (`writeCompressedValues` without active-mask compression) is the
//!   per-node metadata byte 6 (`NO_MASK_AND_ALL_VALS`) then every value;
//! - root children go out in the order of OpenVDB's root table (`std::map` of `Coord`:
//!   lexicographic x, y, z), because the reader reads the buffers in that order;
//! - an instanced grid has compression flags, metadata and transform but no topology or buffers,
//!   and OpenVDB leaves its block offset at 0.
#![allow(dead_code)]

use std::collections::BTreeMap;

/// `OPENVDB_MAGIC` as written at the start of every file.
pub const MAGIC: [u8; 8] = [0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0];
/// File format version written (OpenVDB 6+ "multipass I/O").
pub const FILE_VERSION: u32 = 224;
/// Library version written (OpenVDB 10.0).
pub const LIBRARY_VERSION: (u32, u32) = (10, 0);
/// A fixed UUID, so the same grids always give the same bytes.
pub const UUID: &str = "5ab5c0de-0123-4567-89ab-cdef01234567";

/// Voxels per leaf and the log2 sizes of the standard 5-4-3 tree.
pub const LEAF_VOXELS: usize = 512;
const LEAF_LOG2: u32 = 3;
const LOWER_LOG2: u32 = 4;
const UPPER_LOG2: u32 = 5;

/// Value type of a grid: decides the tree type name and how values are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValueType {
    /// `Tree_float_5_4_3`, f32 values.
    Float,
    /// `Tree_double_5_4_3`, f64 values.
    Double,
    /// `Tree_int32_5_4_3`, values rounded to i32.
    Int32,
    /// `Tree_vec3s_5_4_3`, each value `v` stored as `(v, 0, 0)`.
    Vec3s,
}

impl ValueType {
    /// OpenVDB's tree type name.
    pub fn tree_type(self) -> &'static str {
        match self {
            Self::Float => "Tree_float_5_4_3",
            Self::Double => "Tree_double_5_4_3",
            Self::Int32 => "Tree_int32_5_4_3",
            Self::Vec3s => "Tree_vec3s_5_4_3",
        }
    }

    fn put(self, out: &mut Vec<u8>, v: f64) {
        match self {
            Self::Float => out.extend_from_slice(&(v as f32).to_le_bytes()),
            Self::Double => out.extend_from_slice(&v.to_le_bytes()),
            Self::Int32 => out.extend_from_slice(&(v.round() as i32).to_le_bytes()),
            Self::Vec3s => {
                for c in [v as f32, 0.0, 0.0] {
                    out.extend_from_slice(&c.to_le_bytes());
                }
            }
        }
    }
}

/// A grid transform: an OpenVDB map type name and its parameters.
#[derive(Debug, Clone, PartialEq)]
pub enum Map {
    /// `UniformScaleMap` with this voxel size.
    UniformScale(f64),
    /// `ScaleMap` with these per-axis voxel sizes.
    Scale([f64; 3]),
    /// `ScaleTranslateMap`: index `i` maps to `scale * i + translate`.
    ScaleTranslate {
        /// Per-axis voxel size.
        scale: [f64; 3],
        /// World position of index (0, 0, 0).
        translate: [f64; 3],
    },
    /// `TranslationMap`.
    Translation([f64; 3]),
    /// `AffineMap` with OpenVDB's row-vector matrix (`p_world = [i j k 1] * m`, translation in
    /// the last row), stored row by row.
    Affine([[f64; 4]; 4]),
    /// Any map type name followed by these f64 parameters, as given.
    Raw {
        /// The map type name written.
        name: String,
        /// Its parameters.
        params: Vec<f64>,
    },
}

impl Map {
    fn write(&self, out: &mut Vec<u8>) {
        // ScaleMap::write: scale, voxel size, inverse scale, inverse scale squared, inverse
        // twice scale; ScaleTranslateMap writes its translation first.
        let scale_params = |s: [f64; 3]| -> Vec<f64> {
            let mut p = Vec::with_capacity(15);
            p.extend(s);
            p.extend(s);
            p.extend(s.map(|v| 1.0 / v));
            p.extend(s.map(|v| 1.0 / (v * v)));
            p.extend(s.map(|v| 0.5 / v));
            p
        };
        let (name, params): (&str, Vec<f64>) = match self {
            Self::UniformScale(s) => ("UniformScaleMap", scale_params([*s; 3])),
            Self::Scale(s) => ("ScaleMap", scale_params(*s)),
            Self::ScaleTranslate { scale, translate } => {
                let mut p = translate.to_vec();
                p.extend(scale_params(*scale));
                ("ScaleTranslateMap", p)
            }
            Self::Translation(t) => ("TranslationMap", t.to_vec()),
            Self::Affine(m) => ("AffineMap", m.iter().flatten().copied().collect()),
            Self::Raw { name, params } => (name.as_str(), params.clone()),
        };
        put_str(out, name.as_bytes());
        for p in params {
            out.extend_from_slice(&p.to_le_bytes());
        }
    }
}

/// A leaf: its origin (a multiple of 8 on each axis), 512 values in OpenVDB's order (index
/// `(x & 7) << 6 | (y & 7) << 3 | (z & 7)`) and its active-value mask.
#[derive(Debug, Clone, PartialEq)]
pub struct Leaf {
    /// Index-space origin.
    pub origin: [i32; 3],
    /// The 512 values.
    pub values: Vec<f64>,
    /// Active mask, bit `n` of word `n / 64`.
    pub active: [u64; 8],
}

impl Leaf {
    /// A leaf with every voxel active and set to `value`.
    pub fn filled(origin: [i32; 3], value: f64) -> Self {
        Self::from_fn(origin, |_| value)
    }

    /// A leaf with every voxel active, voxel `(i, j, k)` (offsets 0..8 from the origin) set to
    /// `f([i, j, k])`.
    pub fn from_fn(origin: [i32; 3], f: impl Fn([usize; 3]) -> f64) -> Self {
        assert!(
            origin.iter().all(|c| c & 7 == 0),
            "leaf origin {origin:?} is not a multiple of 8"
        );
        let values = (0..LEAF_VOXELS)
            .map(|n| f([n >> 6, (n >> 3) & 7, n & 7]))
            .collect();
        Self {
            origin,
            values,
            active: [u64::MAX; 8],
        }
    }

    /// The value of voxel `(i, j, k)` (offsets from the origin).
    pub fn value(&self, ijk: [usize; 3]) -> f64 {
        self.values[ijk[0] << 6 | ijk[1] << 3 | ijk[2]]
    }
}

/// A root-level tile: a 4096^3 region of one value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RootTile {
    /// Origin, a multiple of 4096 on each axis.
    pub origin: [i32; 3],
    /// Its value.
    pub value: f64,
    /// Whether it is active.
    pub active: bool,
}

/// One grid to write.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    /// The name as stored (OpenVDB's unique name), any bytes.
    pub name: Vec<u8>,
    /// Value type (decides how values are written).
    pub value_type: ValueType,
    /// Tree type name written in the descriptor; `None`: the value type's own.
    pub tree_type: Option<String>,
    /// Instance parent written in the descriptor; non-empty makes this an instanced grid (no
    /// topology, no buffers).
    pub instance_parent: Vec<u8>,
    /// With an instance parent: write the block offset as the grid's end (an empty block)
    /// instead of 0, which is what OpenVDB writes.
    pub instance_block_at_end: bool,
    /// Background value.
    pub background: f64,
    /// `class` metadata (`fog volume`, `level set`), if any.
    pub class: Option<String>,
    /// More metadata entries: name, type name, value bytes.
    pub metadata: Vec<(String, String, Vec<u8>)>,
    /// The transform.
    pub map: Map,
    /// Root-level tiles.
    pub tiles: Vec<RootTile>,
    /// Leaves (distinct origins).
    pub leaves: Vec<Leaf>,
}

impl Grid {
    /// A float fog volume called `name` with a unit `UniformScaleMap` and these leaves.
    pub fn fog(name: &str, leaves: Vec<Leaf>) -> Self {
        Self {
            name: name.as_bytes().to_vec(),
            value_type: ValueType::Float,
            tree_type: None,
            instance_parent: Vec::new(),
            instance_block_at_end: false,
            background: 0.0,
            class: Some("fog volume".into()),
            metadata: Vec::new(),
            map: Map::UniformScale(1.0),
            tiles: Vec::new(),
            leaves,
        }
    }

    /// A grid called `name` sharing the tree of the grid called `parent`, with this value type.
    pub fn instance(name: &str, value_type: ValueType, parent: &str) -> Self {
        Self {
            value_type,
            instance_parent: parent.as_bytes().to_vec(),
            ..Self::fog(name, Vec::new())
        }
    }

    /// Set the value type.
    pub fn with_type(mut self, value_type: ValueType) -> Self {
        self.value_type = value_type;
        self
    }

    /// Set the transform.
    pub fn with_map(mut self, map: Map) -> Self {
        self.map = map;
        self
    }

    fn tree_type_name(&self) -> String {
        self.tree_type
            .clone()
            .unwrap_or_else(|| self.value_type.tree_type().to_string())
    }
}

/// Where the fields of one written grid sit in the file (absolute byte offsets).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct GridLayout {
    /// Start of the grid's descriptor (its name's length field).
    pub descriptor: u64,
    /// Offsets of the descriptor's `grid_pos`, `block_pos` and `end_pos` fields (i64 each).
    pub offset_fields: [u64; 3],
    /// The values written there: grid, block and end positions.
    pub grid_pos: u64,
    /// Start of the leaf buffers (0 for instances, as OpenVDB writes it).
    pub block_pos: u64,
    /// One past the grid.
    pub end_pos: u64,
    /// Offsets of the u32 size fields of the grid's metadata entries, in order: `class` when
    /// present, `name`, then [`Grid::metadata`].
    pub metadata_size_fields: Vec<u64>,
    /// Start of the transform (its map name's length field).
    pub transform: u64,
    /// Leaves written, in file order.
    pub leaf_count: usize,
}

/// Where the fields of a written file sit.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Layout {
    /// Offset of the i32 grid count.
    pub grid_count_field: u64,
    /// Offsets of the u32 size fields of the file metadata entries.
    pub file_metadata_size_fields: Vec<u64>,
    /// Per grid, in file order.
    pub grids: Vec<GridLayout>,
}

/// A whole file: file metadata and grids.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct VdbFile {
    /// File-level metadata entries: name, type name, value bytes.
    pub metadata: Vec<(String, String, Vec<u8>)>,
    /// The grids, in file order.
    pub grids: Vec<Grid>,
}

impl VdbFile {
    /// A file holding these grids.
    pub fn new(grids: Vec<Grid>) -> Self {
        Self {
            metadata: Vec::new(),
            grids,
        }
    }

    /// The file's bytes and where its fields sit.
    pub fn to_bytes(&self) -> (Vec<u8>, Layout) {
        let mut out = Vec::new();
        let mut layout = Layout::default();
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&FILE_VERSION.to_le_bytes());
        out.extend_from_slice(&LIBRARY_VERSION.0.to_le_bytes());
        out.extend_from_slice(&LIBRARY_VERSION.1.to_le_bytes());
        out.push(1); // has grid offsets
        assert_eq!(UUID.len(), 36);
        out.extend_from_slice(UUID.as_bytes());
        layout.file_metadata_size_fields = put_meta_map(&mut out, &self.metadata);
        layout.grid_count_field = out.len() as u64;
        let count = i32::try_from(self.grids.len()).expect("grid count fits i32");
        out.extend_from_slice(&count.to_le_bytes());
        for g in &self.grids {
            let gl = write_grid(&mut out, g);
            layout.grids.push(gl);
        }
        (out, layout)
    }

    /// Write the file to `path`; returns the layout.
    pub fn write(&self, path: &std::path::Path) -> Layout {
        let (bytes, layout) = self.to_bytes();
        std::fs::write(path, bytes).expect("write the .vdb file");
        layout
    }
}

/// Overwrite 4 bytes at `at` with `v`.
pub fn patch_u32(bytes: &mut [u8], at: u64, v: u32) {
    let at = usize::try_from(at).expect("offset fits usize");
    bytes[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

/// Overwrite 4 bytes at `at` with `v`.
pub fn patch_i32(bytes: &mut [u8], at: u64, v: i32) {
    let at = usize::try_from(at).expect("offset fits usize");
    bytes[at..at + 4].copy_from_slice(&v.to_le_bytes());
}

/// Overwrite 8 bytes at `at` with `v`.
pub fn patch_i64(bytes: &mut [u8], at: u64, v: i64) {
    let at = usize::try_from(at).expect("offset fits usize");
    bytes[at..at + 8].copy_from_slice(&v.to_le_bytes());
}

impl Layout {
    /// Overwrite the header's grid count.
    pub fn set_grid_count(&self, bytes: &mut [u8], count: i32) {
        patch_i32(bytes, self.grid_count_field, count);
    }

    /// Overwrite grid `i`'s descriptor offsets (grid, block, end position).
    pub fn set_offsets(&self, bytes: &mut [u8], i: usize, grid: u64, block: u64, end: u64) {
        for (field, v) in self.grids[i].offset_fields.iter().zip([grid, block, end]) {
            patch_i64(bytes, *field, i64::try_from(v).expect("offset fits i64"));
        }
    }
}

fn put_str(out: &mut Vec<u8>, s: &[u8]) {
    let len = u32::try_from(s.len()).expect("string length fits u32");
    out.extend_from_slice(&len.to_le_bytes());
    out.extend_from_slice(s);
}

/// Write a MetaMap; returns the offsets of the entries' size fields.
fn put_meta_map(out: &mut Vec<u8>, entries: &[(String, String, Vec<u8>)]) -> Vec<u64> {
    let count = u32::try_from(entries.len()).expect("metadata count fits u32");
    out.extend_from_slice(&count.to_le_bytes());
    let mut sizes = Vec::new();
    for (name, ty, value) in entries {
        put_str(out, name.as_bytes());
        put_str(out, ty.as_bytes());
        sizes.push(out.len() as u64);
        put_str(out, value);
    }
    sizes
}

/// The position of `c` inside a node whose children have edge `2^child_log2` and which has
/// `2^dim_log2` children per side (OpenVDB's `coordToOffset`).
fn slot(c: [i32; 3], child_log2: u32, dim_log2: u32) -> usize {
    let mask = (1i32 << (child_log2 + dim_log2)) - 1;
    let l = |a: usize| ((c[a] & mask) >> child_log2) as usize;
    l(0) << (2 * dim_log2) | l(1) << dim_log2 | l(2)
}

fn floor_to(c: [i32; 3], log2: u32) -> [i32; 3] {
    c.map(|v| v & !((1i32 << log2) - 1))
}

/// The tree as OpenVDB holds it: root children (upper nodes) by origin, their lower nodes by
/// slot, the lower nodes' leaves by slot (leaf index into `Grid::leaves`).
type Upper = BTreeMap<usize, BTreeMap<usize, usize>>;

fn build_tree(g: &Grid) -> BTreeMap<[i32; 3], Upper> {
    let upper_log2 = LEAF_LOG2 + LOWER_LOG2 + UPPER_LOG2;
    let lower_log2 = LEAF_LOG2 + LOWER_LOG2;
    let mut root: BTreeMap<[i32; 3], Upper> = BTreeMap::new();
    for (i, leaf) in g.leaves.iter().enumerate() {
        assert!(leaf.values.len() == LEAF_VOXELS, "a leaf has 512 values");
        let upper = root.entry(floor_to(leaf.origin, upper_log2)).or_default();
        let lower = upper
            .entry(slot(leaf.origin, lower_log2, UPPER_LOG2))
            .or_default();
        let prev = lower.insert(slot(leaf.origin, LEAF_LOG2, LOWER_LOG2), i);
        assert!(prev.is_none(), "two leaves at {:?}", leaf.origin);
    }
    for t in &g.tiles {
        assert!(
            t.origin.iter().all(|c| c & 4095 == 0),
            "root tile origin {:?} is not a multiple of 4096",
            t.origin
        );
        assert!(
            !root.contains_key(&t.origin),
            "root tile {:?} overlaps a leaf's upper node",
            t.origin
        );
    }
    root
}

/// Child mask, empty value mask, then all values (children's slots zero, others background).
fn write_internal_head(
    out: &mut Vec<u8>,
    vt: ValueType,
    background: f64,
    dim_log2: u32,
    children: impl Iterator<Item = usize> + Clone,
) {
    let n = 1usize << (3 * dim_log2);
    let mut child_mask = vec![0u64; n / 64];
    for s in children.clone() {
        child_mask[s / 64] |= 1 << (s % 64);
    }
    for w in &child_mask {
        out.extend_from_slice(&w.to_le_bytes());
    }
    out.resize(out.len() + n / 8, 0); // value mask: no active tiles
    out.push(6); // NO_MASK_AND_ALL_VALS
    for s in 0..n {
        let is_child = child_mask[s / 64] >> (s % 64) & 1 != 0;
        vt.put(out, if is_child { 0.0 } else { background });
    }
}

fn write_grid(out: &mut Vec<u8>, g: &Grid) -> GridLayout {
    let mut gl = GridLayout {
        descriptor: out.len() as u64,
        ..GridLayout::default()
    };
    put_str(out, &g.name);
    put_str(out, g.tree_type_name().as_bytes());
    put_str(out, &g.instance_parent);
    for f in &mut gl.offset_fields {
        *f = out.len() as u64;
        out.extend_from_slice(&[0; 8]);
    }
    gl.grid_pos = out.len() as u64;
    out.extend_from_slice(&0u32.to_le_bytes()); // compression: none
    let mut meta = Vec::new();
    if let Some(class) = &g.class {
        meta.push((
            "class".to_string(),
            "string".to_string(),
            class.as_bytes().to_vec(),
        ));
    }
    // OpenVDB keeps the grid name as metadata too (pyopenvdb reads it from there).
    meta.push(("name".to_string(), "string".to_string(), g.name.clone()));
    meta.extend(g.metadata.iter().cloned());
    gl.metadata_size_fields = put_meta_map(out, &meta);
    gl.transform = out.len() as u64;
    g.map.write(out);
    if g.instance_parent.is_empty() {
        let vt = g.value_type;
        let root = build_tree(g);
        // Topology.
        out.extend_from_slice(&1i32.to_le_bytes()); // buffer count
        vt.put(out, g.background);
        let tiles = u32::try_from(g.tiles.len()).expect("tile count fits u32");
        let children = u32::try_from(root.len()).expect("child count fits u32");
        out.extend_from_slice(&tiles.to_le_bytes());
        out.extend_from_slice(&children.to_le_bytes());
        for t in &g.tiles {
            for c in t.origin {
                out.extend_from_slice(&c.to_le_bytes());
            }
            vt.put(out, t.value);
            out.push(u8::from(t.active));
        }
        let mut order = Vec::new(); // leaves in file order
        for (origin, upper) in &root {
            for c in origin {
                out.extend_from_slice(&c.to_le_bytes());
            }
            write_internal_head(out, vt, g.background, UPPER_LOG2, upper.keys().copied());
            for lower in upper.values() {
                write_internal_head(out, vt, g.background, LOWER_LOG2, lower.keys().copied());
                for &leaf in lower.values() {
                    for w in g.leaves[leaf].active {
                        out.extend_from_slice(&w.to_le_bytes());
                    }
                    order.push(leaf);
                }
            }
        }
        // Buffers.
        gl.block_pos = out.len() as u64;
        for &i in &order {
            let leaf = &g.leaves[i];
            for w in leaf.active {
                out.extend_from_slice(&w.to_le_bytes());
            }
            out.push(6); // NO_MASK_AND_ALL_VALS
            for &v in &leaf.values {
                vt.put(out, v);
            }
        }
        gl.leaf_count = order.len();
    }
    gl.end_pos = out.len() as u64;
    if !g.instance_parent.is_empty() && g.instance_block_at_end {
        gl.block_pos = gl.end_pos;
    }
    for (field, v) in gl
        .offset_fields
        .iter()
        .zip([gl.grid_pos, gl.block_pos, gl.end_pos])
    {
        let at = usize::try_from(*field).expect("offset fits usize");
        out[at..at + 8].copy_from_slice(&i64::try_from(v).expect("fits i64").to_le_bytes());
    }
    gl
}

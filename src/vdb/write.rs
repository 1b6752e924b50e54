//! umbra's own OpenVDB writer for one float grid: [`FloatGridOut`] (validated leaves, background,
//! transform, options) encoded by [`encode_vdb`] into the bytes `openvdb::io::File::write` would
//! produce for the same tree, or written atomically by [`write_vdb`].
//!
//! Format facts (OpenVDB 10 `io/Archive.cc`, `io/GridDescriptor.cc`, `io/Compression.h/.cc`,
//! `tree/RootNode.h`, `tree/InternalNode.h`, `tree/LeafNode.h`, `math/Maps.h`, `MetaMap.cc`):
//! - all numbers little-endian; a string is a `u32` length then its bytes;
//! - header: magic `0x56444220` as `i64`, file format 224, library version 10.0, the byte 1
//!   ("has grid offsets"), a 36-character UUID; then the file metadata (none here) and the
//!   grid count (`i32` 1);
//! - grid descriptor: unique name (the grid name), tree type `Tree_float_5_4_3` (plus
//!   `_HalfFloat` when the values are stored as halves), instance parent (empty), then the grid,
//!   block and end positions (`i64` each);
//! - grid: compression flags (`u32`), the metadata (a `std::map`, so sorted by name: `u32`
//!   count, then name, type name, `u32` size, value), the transform (map type name, then the
//!   map's parameters), the topology, then the leaf buffers (block position);
//! - topology: buffer count (`i32` 1), the background (`f32`; for half grids the background
//!   rounded to half precision, stored as `f32`), root tile count (0) and child count, then per
//!   root child in the order of OpenVDB's root `std::map<Coord>` (lexicographic x, y, z) its
//!   origin and its upper node: child mask, value mask, compressed values (`32^3`; child slots
//!   hold 0, the others the background), its lower nodes in slot order (same, `16^3`), and each
//!   lower node's leaves' value masks in slot order;
//! - leaf buffers, in the same order: value mask, then the compressed values (`8^3`);
//! - compressed values (`io::writeCompressedValues`): without `COMPRESS_ACTIVE_MASK`, the byte 6
//!   (`NO_MASK_AND_ALL_VALS`) and every value; with it, the metadata byte of `MaskCompress` (up to
//!   two distinct inactive values, compared to the background and its negative), those inactive
//!   values (full `f32`, rounded to half precision for half grids), a selection mask when two
//!   inactive values alternate, then only the active values (or all of them when there are more
//!   than two distinct inactive values);
//! - a value run goes out as halves (half grids; an empty half run writes nothing at all) or
//!   `f32`, then raw, or with `COMPRESS_ZIP` as an `i64` byte count and the zlib stream
//!   (`compress2` at the default level), or, when deflating does not make it smaller, the
//!   negated raw byte count and the raw bytes.

use crate::error::{Error, Result};
use crate::tree::{lower_offset, node_origin, upper_offset};
use glam::DAffine3;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

/// `OPENVDB_MAGIC` (`0x56444220` as a little-endian `i64`).
const MAGIC: [u8; 8] = [0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0];
/// File format version written: 224 (`OPENVDB_FILE_VERSION_MULTIPASS_IO`, OpenVDB 6 and later).
const FILE_VERSION: u32 = 224;
/// Library version written: OpenVDB 10.0.
const LIBRARY_VERSION: (u32, u32) = (10, 0);
/// Byte offset of the UUID in the header (magic 8, versions 12, offsets flag 1).
const UUID_AT: usize = 21;
/// `GridDescriptor`'s half-float suffix of the tree type name.
const HALF_SUFFIX: &str = "_HalfFloat";
/// OpenVDB's suffix separator in unique grid names (`GridDescriptor::addSuffix`).
const NAME_SEPARATOR: char = '\u{1e}';

/// `io::COMPRESS_ZIP`.
const COMPRESS_ZIP: u32 = 0x1;
/// `io::COMPRESS_ACTIVE_MASK`.
const COMPRESS_ACTIVE_MASK: u32 = 0x2;

/// Per-node metadata bytes (`io::NodeMetadata`).
const NO_MASK_OR_INACTIVE_VALS: u8 = 0;
const NO_MASK_AND_MINUS_BG: u8 = 1;
const NO_MASK_AND_ONE_INACTIVE_VAL: u8 = 2;
const MASK_AND_NO_INACTIVE_VALS: u8 = 3;
const MASK_AND_ONE_INACTIVE_VAL: u8 = 4;
const MASK_AND_TWO_INACTIVE_VALS: u8 = 5;
const NO_MASK_AND_ALL_VALS: u8 = 6;

/// log2 of the upper (32^3) and lower (16^3) node dimensions, in children per side.
const UPPER_LOG2: u32 = 5;
const LOWER_LOG2: u32 = 4;
/// log2 of the voxel edge of an upper node (4096).
const UPPER_TOTAL_LOG2: u32 = 12;

/// OpenVDB's smallest accepted `|det|` of a map's linear part (`3 * Tolerance<double>`): its
/// `AffineMap` and `ScaleTranslateMap` refuse nearly singular maps when the file is read.
const MIN_DETERMINANT: f64 = 3e-15;

/// What OpenVDB 10 (x86-64, libstdc++) reports as a float tree's `memUsage()`, which `File::write`
/// stores as `file_mem_bytes`: the tree and root objects, then per upper and lower node
/// `NUM_VALUES * 8 + 2 * mask bytes + 12`, per leaf `sizeof(LeafNode) + 512 * 4`.
const MEM_TREE_AND_ROOT: i64 = 1304;
const MEM_UPPER: i64 = 32_768 * 8 + 2 * 4096 + 12;
const MEM_LOWER: i64 = 4096 * 8 + 2 * 512 + 12;
const MEM_LEAF: i64 = 96 + 512 * 4;

/// One 8^3 leaf to write: origin (multiple of 8, index space), its 512 values in OpenVDB's
/// order (x-major: offset = (x&7)<<6 | (y&7)<<3 | (z&7)), and its active mask (bit n of word
/// n/64). Inactive values are stored too, as OpenVDB stores them (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct LeafOut {
    /// Index coordinate of the leaf's voxel (0, 0, 0); a multiple of 8 on each axis.
    pub origin: [i32; 3],
    /// The 512 values, offset `(x & 7) << 6 | (y & 7) << 3 | (z & 7)`.
    pub values: Box<[f32; 512]>,
    /// Active (value) mask: voxel `n` is active when bit `n % 64` of word `n / 64` is set.
    pub active: [u64; 8],
}

/// How node values are compressed. Every mode but `None` also sets OpenVDB's
/// `COMPRESS_ACTIVE_MASK` (only active values and at most two distinct inactive values are
/// stored per node). Blosc is not offered: writing it through c-blosc needs `unsafe` FFI.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum VdbCompression {
    /// Compression flags 0 (`file_compression` "none"): every value of every node, raw.
    None,
    /// `COMPRESS_ZIP | COMPRESS_ACTIVE_MASK` (flags 3, "zip + active values"): active values,
    /// zlib-deflated per node.
    #[default]
    Zip,
}

impl VdbCompression {
    /// The grid's compression flags.
    fn flags(self) -> u32 {
        match self {
            Self::None => 0,
            Self::Zip => COMPRESS_ZIP | COMPRESS_ACTIVE_MASK,
        }
    }

    /// `io::compressionToString` of the flags, as `file_compression` holds it.
    fn describe(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Zip => "zip + active values",
        }
    }
}

/// The grid class written as the `class` metadata (`GridBase::gridClassToString`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum GridClassOut {
    /// `"fog volume"`: a density (what umbra traces).
    #[default]
    FogVolume,
    /// `"unknown"`: no particular class.
    Unknown,
}

impl GridClassOut {
    fn name(self) -> &'static str {
        match self {
            Self::FogVolume => "fog volume",
            Self::Unknown => "unknown",
        }
    }
}

/// One float grid ready to be written: a validated name, background, index-to-world transform
/// and leaves, plus the storage options (half floats, compression, class, extra metadata).
#[derive(Debug, Clone)]
pub struct FloatGridOut {
    name: String,
    background: f32,
    world_from_index: DAffine3,
    leaves: Vec<LeafOut>,
    half: bool,
    compression: VdbCompression,
    class: GridClassOut,
    extra: BTreeMap<String, String>,
}

fn invalid(reason: impl Into<String>) -> Error {
    Error::InvalidArgument {
        name: "vdb".into(),
        reason: reason.into(),
    }
}

/// Metadata names the writer fills itself: OpenVDB's grid name and class, its half-float flag
/// and the statistics `File::write` adds (every `file_` name is OpenVDB's).
fn is_reserved(key: &str) -> bool {
    matches!(key, "name" | "class" | "is_saved_as_half_float") || key.starts_with("file_")
}

impl FloatGridOut {
    /// A grid called `name` with this background, `world_from_index` (index point `(i, j, k)` to
    /// world, glam's column-vector convention) and leaves, stored by default as full floats,
    /// zip + active-mask compressed, class `fog volume`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] named `vdb` when the name is empty, contains NUL or OpenVDB's
    /// suffix separator `\x1e`, or is longer than `u32::MAX` bytes; the background is not
    /// finite; `world_from_index` has a non-finite entry, is not invertible or is nearly
    /// singular for OpenVDB (`|det| < 3e-15`, which its maps refuse on read); a leaf origin is
    /// not a multiple of 8 or repeats another; a leaf value (active or not) is not finite; or
    /// there are more than `u32::MAX` leaves.
    pub fn new(
        name: &str,
        background: f32,
        world_from_index: DAffine3,
        leaves: Vec<LeafOut>,
    ) -> Result<Self> {
        if name.is_empty() {
            return Err(invalid("the grid name is empty"));
        }
        if name.contains('\0') || name.contains(NAME_SEPARATOR) {
            return Err(invalid(format!(
                "the grid name '{}' contains a NUL or \\x1e byte (OpenVDB's name separator)",
                crate::text::escape(name)
            )));
        }
        if u32::try_from(name.len()).is_err() {
            return Err(invalid("the grid name is longer than 4 GiB"));
        }
        if !background.is_finite() {
            return Err(invalid(format!(
                "the background {background} is not finite"
            )));
        }
        let m = world_from_index;
        if !m.to_cols_array().iter().all(|v| v.is_finite()) {
            return Err(invalid("world_from_index has a non-finite entry"));
        }
        let det = m.matrix3.determinant();
        if !det.is_finite() || det.abs() < MIN_DETERMINANT {
            return Err(invalid(format!(
                "world_from_index is singular or nearly so (determinant {det:e}; OpenVDB reads \
                 no map with |det| < 3e-15)"
            )));
        }
        if !m.inverse().to_cols_array().iter().all(|v| v.is_finite()) {
            return Err(invalid("world_from_index has no finite inverse"));
        }
        if u32::try_from(leaves.len()).is_err() {
            return Err(invalid(format!(
                "{} leaves: OpenVDB counts leaves in 32 bits",
                leaves.len()
            )));
        }
        let mut seen = std::collections::HashSet::with_capacity(leaves.len());
        for leaf in &leaves {
            let o = leaf.origin;
            if o.iter().any(|c| c & 7 != 0) {
                return Err(invalid(format!("leaf origin {o:?} is not a multiple of 8")));
            }
            if !seen.insert(o) {
                return Err(invalid(format!("two leaves at origin {o:?}")));
            }
            if let Some(n) = leaf.values.iter().position(|v| !v.is_finite()) {
                return Err(invalid(format!(
                    "leaf {o:?} value {n} ({}) is not finite",
                    leaf.values[n]
                )));
            }
        }
        Ok(Self {
            name: name.to_string(),
            background,
            world_from_index,
            leaves,
            half: false,
            compression: VdbCompression::default(),
            class: GridClassOut::default(),
            extra: BTreeMap::new(),
        })
    }

    /// Store the values as 16-bit half floats (OpenVDB's "save float as half"): the tree type
    /// becomes `Tree_float_5_4_3_HalfFloat`, `is_saved_as_half_float` is true, every value and
    /// the background are rounded to the nearest half (beyond ±65504 they become ±infinity, as
    /// in OpenVDB).
    #[must_use]
    pub fn with_half(mut self, half: bool) -> Self {
        self.half = half;
        self
    }

    /// The compression of node values ([`VdbCompression::Zip`] by default).
    #[must_use]
    pub fn with_compression(mut self, c: VdbCompression) -> Self {
        self.compression = c;
        self
    }

    /// Add a string metadata entry `key = value` to the grid (OpenVDB `StringMetadata`; a later
    /// call with the same key replaces the value). Ignored: an empty key (OpenVDB refuses to read
    /// one), a key the writer fills itself (`name`, `class`, `is_saved_as_half_float`, any
    /// `file_...`), and a value longer than `u32::MAX` bytes.
    #[must_use]
    pub fn with_metadata(mut self, key: &str, value: &str) -> Self {
        if !key.is_empty()
            && !is_reserved(key)
            && u32::try_from(key.len()).is_ok()
            && u32::try_from(value.len()).is_ok()
        {
            self.extra.insert(key.to_string(), value.to_string());
        }
        self
    }

    /// The `class` metadata ([`GridClassOut::FogVolume`] by default).
    #[must_use]
    pub fn with_class(mut self, class: GridClassOut) -> Self {
        self.class = class;
        self
    }

    /// The grid name.
    #[must_use]
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The leaves, as given.
    #[must_use]
    pub fn leaves(&self) -> &[LeafOut] {
        &self.leaves
    }
}

// ---------------------------------------------------------------------------------------------
// Byte helpers

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_i32(out: &mut Vec<u8>, v: i32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_i64(out: &mut Vec<u8>, v: i64) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_f32(out: &mut Vec<u8>, v: f32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_f64s(out: &mut Vec<u8>, v: &[f64]) {
    for x in v {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

/// A length-prefixed string; callers validated that the length fits `u32`.
fn put_str(out: &mut Vec<u8>, s: &[u8]) {
    put_u32(out, u32::try_from(s.len()).unwrap_or(u32::MAX));
    out.extend_from_slice(s);
}

/// `util::NodeMask::save`: the words in order.
fn put_mask(out: &mut Vec<u8>, mask: &[u64]) {
    for w in mask {
        out.extend_from_slice(&w.to_le_bytes());
    }
}

fn bit(mask: &[u64], i: usize) -> bool {
    mask.get(i >> 6).is_some_and(|w| w >> (i & 63) & 1 != 0)
}

/// A value rounded to half precision, as `io::truncateRealToHalf` (round to nearest even).
fn to_half(v: f32) -> f32 {
    half::f16::from_f32(v).to_f32()
}

// ---------------------------------------------------------------------------------------------
// Node values

/// `io::MaskCompress`: the per-node metadata byte and the (at most two) inactive values, from
/// the inactive, non-child slots in index order; values compare with `==` (`isExactlyEqual`).
fn mask_compress(src: &[f32], value_mask: &[u64], child_mask: &[u64], bg: f32) -> (u8, [f32; 2]) {
    let mut inactive = [bg, bg];
    let mut unique = 0;
    for (i, &v) in src.iter().enumerate() {
        if unique >= 3 {
            break;
        }
        if bit(value_mask, i) || bit(child_mask, i) {
            continue;
        }
        let seen = (unique > 0 && v == inactive[0]) || (unique > 1 && v == inactive[1]);
        if !seen {
            if unique < 2 {
                inactive[unique] = v;
            }
            unique += 1;
        }
    }
    let meta = match unique {
        0 => NO_MASK_OR_INACTIVE_VALS,
        1 if inactive[0] == bg => NO_MASK_OR_INACTIVE_VALS,
        1 if inactive[0] == -bg => NO_MASK_AND_MINUS_BG,
        1 => NO_MASK_AND_ONE_INACTIVE_VAL,
        2 if inactive[0] != bg && inactive[1] != bg => MASK_AND_TWO_INACTIVE_VALS,
        2 if inactive[1] == bg => {
            if inactive[0] == -bg {
                MASK_AND_NO_INACTIVE_VALS
            } else {
                MASK_AND_ONE_INACTIVE_VAL
            }
        }
        2 => {
            // inactive[0] is the background: swap, so the other value is the one stored.
            inactive.swap(0, 1);
            if inactive[0] == -bg {
                MASK_AND_NO_INACTIVE_VALS
            } else {
                MASK_AND_ONE_INACTIVE_VAL
            }
        }
        _ => NO_MASK_AND_ALL_VALS,
    };
    (meta, inactive)
}

/// `io::zipToStream`: the `i64` size and the zlib stream, or the negated size and the raw
/// bytes when deflating does not make the run smaller.
fn zip_to_stream(out: &mut Vec<u8>, raw: &[u8]) {
    let mut enc = flate2::write::ZlibEncoder::new(
        Vec::with_capacity(raw.len() / 2 + 16),
        flate2::Compression::default(),
    );
    let zipped = enc.write_all(raw).and_then(|()| enc.finish());
    match zipped {
        Ok(z) if z.len() < raw.len() => {
            put_i64(out, i64::try_from(z.len()).unwrap_or(i64::MAX));
            out.extend_from_slice(&z);
        }
        _ => {
            put_i64(out, -i64::try_from(raw.len()).unwrap_or(i64::MAX));
            out.extend_from_slice(raw);
        }
    }
}

/// `io::writeData` / `HalfWriter::write`: a run of values as halves or `f32`, raw or zipped.
fn write_data(out: &mut Vec<u8>, values: &[f32], half: bool, flags: u32) {
    if half && values.is_empty() {
        return; // HalfWriter writes nothing for an empty run, not even a size
    }
    let mut raw = Vec::with_capacity(values.len() * 4);
    for &v in values {
        if half {
            raw.extend_from_slice(&half::f16::from_f32(v).to_le_bytes());
        } else {
            raw.extend_from_slice(&v.to_le_bytes());
        }
    }
    if flags & COMPRESS_ZIP != 0 {
        zip_to_stream(out, &raw);
    } else {
        out.extend_from_slice(&raw);
    }
}

/// `io::writeCompressedValues` for a node's value array with its value and child masks (an
/// empty child mask for leaves).
fn write_compressed_values(
    out: &mut Vec<u8>,
    src: &[f32],
    value_mask: &[u64],
    child_mask: &[u64],
    bg: f32,
    half: bool,
    flags: u32,
) {
    if flags & COMPRESS_ACTIVE_MASK == 0 {
        out.push(NO_MASK_AND_ALL_VALS);
        write_data(out, src, half, flags);
        return;
    }
    let (meta, inactive) = mask_compress(src, value_mask, child_mask, bg);
    out.push(meta);
    if matches!(
        meta,
        NO_MASK_AND_ONE_INACTIVE_VAL | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS
    ) {
        let stored = |v: f32| if half { to_half(v) } else { v };
        put_f32(out, stored(inactive[0]));
        if meta == MASK_AND_TWO_INACTIVE_VALS {
            put_f32(out, stored(inactive[1]));
        }
    }
    if meta == NO_MASK_AND_ALL_VALS {
        write_data(out, src, half, flags);
        return;
    }
    let active: Vec<f32> = src
        .iter()
        .enumerate()
        .filter(|&(i, _)| bit(value_mask, i))
        .map(|(_, &v)| v)
        .collect();
    if matches!(
        meta,
        MASK_AND_NO_INACTIVE_VALS | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS
    ) {
        // Selection mask: inactive slots holding the second inactive value.
        let mut selection = vec![0u64; src.len().div_ceil(64)];
        for (i, &v) in src.iter().enumerate() {
            if !bit(value_mask, i) && v == inactive[1] {
                selection[i >> 6] |= 1 << (i & 63);
            }
        }
        put_mask(out, &selection);
    }
    write_data(out, &active, half, flags);
}

// ---------------------------------------------------------------------------------------------
// Topology

/// The tree as OpenVDB holds it: root children (upper nodes) by origin, their lower nodes by
/// slot, the lower nodes' leaves by slot (index into the grid's leaves).
type Lower = BTreeMap<usize, usize>;
type Upper = BTreeMap<usize, Lower>;

fn build_root(leaves: &[LeafOut]) -> BTreeMap<[i32; 3], Upper> {
    let mut root: BTreeMap<[i32; 3], Upper> = BTreeMap::new();
    for (i, leaf) in leaves.iter().enumerate() {
        let o = leaf.origin;
        root.entry(node_origin(o, UPPER_TOTAL_LOG2))
            .or_default()
            .entry(upper_offset(o))
            .or_default()
            .insert(lower_offset(o), i);
    }
    root
}

/// `InternalNode::writeTopology` without active tiles: child mask, empty value mask, then the
/// compressed values (0 in child slots, the background elsewhere).
fn write_internal(
    out: &mut Vec<u8>,
    dim_log2: u32,
    children: impl Iterator<Item = usize>,
    bg: f32,
    half: bool,
    flags: u32,
) {
    let n = 1usize << (3 * dim_log2);
    let mut child_mask = vec![0u64; n / 64];
    let mut values = vec![bg; n];
    for s in children {
        child_mask[s >> 6] |= 1 << (s & 63);
        values[s] = 0.0;
    }
    let value_mask = vec![0u64; n / 64];
    put_mask(out, &child_mask);
    put_mask(out, &value_mask);
    write_compressed_values(out, &values, &value_mask, &child_mask, bg, half, flags);
}

/// `LeafNode::writeBuffers`: the value mask, then the compressed values.
fn leaf_buffer(leaf: &LeafOut, bg: f32, half: bool, flags: u32) -> Vec<u8> {
    let mut out = Vec::with_capacity(64 + 1 + 8 + 512 * 4);
    put_mask(&mut out, &leaf.active);
    write_compressed_values(
        &mut out,
        &leaf.values[..],
        &leaf.active,
        &[],
        bg,
        half,
        flags,
    );
    out
}

// ---------------------------------------------------------------------------------------------
// Transform

/// `Transform::write`: the map type name and the map's parameters. A diagonal linear part is a
/// `UniformScaleTranslateMap` (equal scales) or `ScaleTranslateMap`: translation, scale, voxel
/// size `|scale|`, `1 / scale`, `1 / scale^2`, `1 / (2 scale)` (what its constructor computes
/// and `read` takes as stored). Anything else is an `AffineMap`: its `Mat4d` row by row in
/// OpenVDB's row-vector convention (`p_world = [i j k 1] * M`: the images of the index axes in
/// rows 0..3, the translation in row 3, last column `(0, 0, 0, 1)`).
fn write_transform(out: &mut Vec<u8>, m: &DAffine3) {
    let (x, y, z, t) = (
        m.matrix3.x_axis,
        m.matrix3.y_axis,
        m.matrix3.z_axis,
        m.translation,
    );
    let diagonal = x.y == 0.0 && x.z == 0.0 && y.x == 0.0 && y.z == 0.0 && z.x == 0.0 && z.y == 0.0;
    if diagonal {
        let s = [x.x, y.y, z.z];
        let name = if s[0] == s[1] && s[1] == s[2] {
            "UniformScaleTranslateMap"
        } else {
            "ScaleTranslateMap"
        };
        put_str(out, name.as_bytes());
        let inv = s.map(|v| 1.0 / v);
        put_f64s(out, &t.to_array());
        put_f64s(out, &s);
        put_f64s(out, &s.map(f64::abs));
        put_f64s(out, &inv);
        put_f64s(out, &inv.map(|v| v * v));
        put_f64s(out, &inv.map(|v| v / 2.0));
    } else {
        put_str(out, b"AffineMap");
        for row in [x.extend(0.0), y.extend(0.0), z.extend(0.0), t.extend(1.0)] {
            put_f64s(out, &row.to_array());
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Metadata and the file

/// A grid metadata value and its OpenVDB type name.
enum Meta {
    Str(Vec<u8>),
    Bool(bool),
    Vec3i([i32; 3]),
    Int64(i64),
}

fn put_meta(out: &mut Vec<u8>, key: &str, m: &Meta) {
    put_str(out, key.as_bytes());
    let (ty, value): (&str, Vec<u8>) = match m {
        Meta::Str(s) => ("string", s.clone()),
        Meta::Bool(b) => ("bool", vec![u8::from(*b)]),
        Meta::Vec3i(v) => ("vec3i", v.iter().flat_map(|c| c.to_le_bytes()).collect()),
        Meta::Int64(v) => ("int64", v.to_le_bytes().to_vec()),
    };
    put_str(out, ty.as_bytes());
    put_str(out, &value);
}

/// Active voxel count and inclusive index box of the active voxels (OpenVDB's empty
/// `CoordBBox`, min `i32::MAX` and max `i32::MIN`, when none is active).
fn active_stats(leaves: &[LeafOut]) -> (i64, [i32; 3], [i32; 3]) {
    let mut count = 0i64;
    let (mut lo, mut hi) = ([i32::MAX; 3], [i32::MIN; 3]);
    for leaf in leaves {
        for (w, &word) in leaf.active.iter().enumerate() {
            count += i64::from(word.count_ones());
            let mut bits = word;
            while bits != 0 {
                let n = (w << 6) as i32 | bits.trailing_zeros() as i32;
                bits &= bits - 1;
                let p = [n >> 6, (n >> 3) & 7, n & 7];
                for a in 0..3 {
                    let c = leaf.origin[a] + p[a];
                    lo[a] = lo[a].min(c);
                    hi[a] = hi[a].max(c);
                }
            }
        }
    }
    (count, lo, hi)
}

/// A UUID derived from the file's content (two 64-bit multiplicative hash lanes over its
/// words, RFC 9562 version 8 layout): the same grid always gives the same bytes, and
/// different files get different identifiers, as OpenVDB's random ones are.
fn content_uuid(bytes: &[u8]) -> [u8; 36] {
    let mut a: u64 = 0xcbf2_9ce4_8422_2325;
    let mut b: u64 = 0x6c62_272e_07bb_0142;
    let mut chunks = bytes.chunks_exact(8);
    let mut mix = |w: u64| {
        a = (a ^ w).wrapping_mul(0x0000_0100_0000_01b3);
        b = (b ^ w.rotate_left(29)).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    };
    for c in &mut chunks {
        let mut w = [0u8; 8];
        w.copy_from_slice(c);
        mix(u64::from_le_bytes(w));
    }
    let mut last = [0u8; 8];
    last[..chunks.remainder().len()].copy_from_slice(chunks.remainder());
    mix(u64::from_le_bytes(last));
    mix(bytes.len() as u64);
    let fin = |mut z: u64| {
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    };
    let mut id = [0u8; 16];
    id[..8].copy_from_slice(&fin(a ^ b.rotate_left(17)).to_be_bytes());
    id[8..].copy_from_slice(&fin(b ^ a.rotate_left(41)).to_be_bytes());
    id[6] = (id[6] & 0x0f) | 0x80; // version 8 (custom)
    id[8] = (id[8] & 0x3f) | 0x80; // RFC variant
    let hex = b"0123456789abcdef";
    let mut s = [b'-'; 36];
    let mut at = 0;
    for (i, byte) in id.iter().enumerate() {
        if matches!(i, 4 | 6 | 8 | 10) {
            at += 1;
        }
        s[at] = hex[usize::from(byte >> 4)];
        s[at + 1] = hex[usize::from(byte & 15)];
        at += 2;
    }
    s
}

/// The whole `.vdb` file for `grid`, in memory: the layout `openvdb::io::File::write` produces
/// for one grid (see the module docs), with the grid metadata OpenVDB writes (`class`,
/// `file_bbox_min`/`file_bbox_max` (vec3i), `file_compression`, `file_mem_bytes` and
/// `file_voxel_count` (int64), `is_saved_as_half_float` (bool), `name`) and the caller's extra
/// strings, sorted by name. Deterministic: the header's UUID is derived from the content. Leaf
/// buffers are compressed in parallel.
#[must_use]
pub fn encode_vdb(grid: &FloatGridOut) -> Vec<u8> {
    let flags = grid.compression.flags();
    let half = grid.half;
    let bg = grid.background;
    let root = build_root(&grid.leaves);

    let mut out = Vec::new();
    out.extend_from_slice(&MAGIC);
    put_u32(&mut out, FILE_VERSION);
    put_u32(&mut out, LIBRARY_VERSION.0);
    put_u32(&mut out, LIBRARY_VERSION.1);
    out.push(1); // has grid offsets
    out.extend_from_slice(&[b'0'; 36]); // UUID, filled in at the end
    put_u32(&mut out, 0); // file metadata: none
    put_i32(&mut out, 1); // grid count

    // Grid descriptor.
    put_str(&mut out, grid.name.as_bytes());
    let tree_type = format!("Tree_float_5_4_3{}", if half { HALF_SUFFIX } else { "" });
    put_str(&mut out, tree_type.as_bytes());
    put_str(&mut out, b""); // instance parent
    let offsets_at = out.len();
    out.extend_from_slice(&[0; 24]);
    let grid_pos = out.len();
    put_u32(&mut out, flags);

    // Metadata.
    let (voxels, lo, hi) = active_stats(&grid.leaves);
    let uppers = root.len() as i64;
    let lowers: i64 = root.values().map(|u| u.len() as i64).sum();
    let mem = MEM_TREE_AND_ROOT
        + MEM_UPPER * uppers
        + MEM_LOWER * lowers
        + MEM_LEAF * grid.leaves.len() as i64;
    let mut meta: BTreeMap<&str, Meta> = BTreeMap::new();
    for (k, v) in &grid.extra {
        meta.insert(k, Meta::Str(v.as_bytes().to_vec()));
    }
    meta.insert("class", Meta::Str(grid.class.name().as_bytes().to_vec()));
    meta.insert("file_bbox_min", Meta::Vec3i(lo));
    meta.insert("file_bbox_max", Meta::Vec3i(hi));
    meta.insert(
        "file_compression",
        Meta::Str(grid.compression.describe().as_bytes().to_vec()),
    );
    meta.insert("file_mem_bytes", Meta::Int64(mem));
    meta.insert("file_voxel_count", Meta::Int64(voxels));
    meta.insert("is_saved_as_half_float", Meta::Bool(half));
    meta.insert("name", Meta::Str(grid.name.as_bytes().to_vec()));
    put_u32(&mut out, u32::try_from(meta.len()).unwrap_or(u32::MAX));
    for (k, m) in &meta {
        put_meta(&mut out, k, m);
    }

    write_transform(&mut out, &grid.world_from_index);

    // Topology.
    put_i32(&mut out, 1); // buffer count
    put_f32(&mut out, if half { to_half(bg) } else { bg });
    put_u32(&mut out, 0); // root tiles
    put_u32(&mut out, u32::try_from(root.len()).unwrap_or(u32::MAX));
    let mut order = Vec::with_capacity(grid.leaves.len());
    for (origin, upper) in &root {
        for &c in origin {
            put_i32(&mut out, c);
        }
        write_internal(&mut out, UPPER_LOG2, upper.keys().copied(), bg, half, flags);
        for lower in upper.values() {
            write_internal(&mut out, LOWER_LOG2, lower.keys().copied(), bg, half, flags);
            for &i in lower.values() {
                put_mask(&mut out, &grid.leaves[i].active);
                order.push(i);
            }
        }
    }

    // Leaf buffers.
    let block_pos = out.len();
    let buffers: Vec<Vec<u8>> = order
        .par_iter()
        .map(|&i| leaf_buffer(&grid.leaves[i], bg, half, flags))
        .collect();
    out.reserve(buffers.iter().map(Vec::len).sum());
    for b in &buffers {
        out.extend_from_slice(b);
    }
    drop(buffers);
    let end_pos = out.len();

    for (k, pos) in [grid_pos, block_pos, end_pos].into_iter().enumerate() {
        let at = offsets_at + 8 * k;
        let v = i64::try_from(pos).unwrap_or(i64::MAX);
        out[at..at + 8].copy_from_slice(&v.to_le_bytes());
    }
    let uuid = content_uuid(&out[UUID_AT + 36..]);
    out[UUID_AT..UUID_AT + 36].copy_from_slice(&uuid);
    out
}

/// Write `grid` to `path` as [`encode_vdb`] encodes it, atomically through
/// [`crate::output::write_atomic`] (a temporary file beside `path`, renamed over it when
/// complete).
///
/// # Errors
/// [`Error::Output`] when `path` exists and `overwrite` is false (checked before encoding), is
/// a directory, its directory does not exist, or the file cannot be written; nothing is left
/// behind on error.
pub fn write_vdb(path: &Path, grid: &FloatGridOut, overwrite: bool) -> Result<()> {
    crate::output::check_target(path, overwrite)?;
    let bytes = encode_vdb(grid);
    crate::output::write_atomic(path, overwrite, |w| {
        w.write_all(&bytes).map_err(|e| format!("writing: {e}"))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn leaf(origin: [i32; 3], f: impl Fn(usize) -> f32, active: [u64; 8]) -> LeafOut {
        LeafOut {
            origin,
            values: Box::new(std::array::from_fn(f)),
            active,
        }
    }

    #[test]
    fn mask_compress_cases_follow_openvdb() {
        let mask = [0b1u64, 0, 0, 0, 0, 0, 0, 0]; // voxel 0 active
        let none: &[u64] = &[];
        let mut v = [0.5f32; 512];
        v[0] = 9.0;
        // All inactive = background.
        assert_eq!(
            mask_compress(&v, &mask, none, 0.5).0,
            NO_MASK_OR_INACTIVE_VALS
        );
        // All inactive = -background.
        assert_eq!(mask_compress(&v, &mask, none, -0.5).0, NO_MASK_AND_MINUS_BG);
        // One other value.
        let (m, iv) = mask_compress(&v, &mask, none, 0.0);
        assert_eq!((m, iv[0]), (NO_MASK_AND_ONE_INACTIVE_VAL, 0.5));
        // Background first, then another: swapped, one value stored.
        v[1] = 0.0;
        let (m, iv) = mask_compress(&v, &mask, none, 0.0);
        assert_eq!((m, iv), (MASK_AND_ONE_INACTIVE_VAL, [0.5, 0.0]));
        // -bg and bg.
        let mut w = [1.0f32; 512];
        w[5] = -1.0;
        assert_eq!(
            mask_compress(&w, &mask, none, 1.0).0,
            MASK_AND_NO_INACTIVE_VALS
        );
        // Two non-background values.
        w[5] = 3.0;
        assert_eq!(
            mask_compress(&w, &mask, none, 0.0).0,
            MASK_AND_TWO_INACTIVE_VALS
        );
        // Three.
        w[6] = 4.0;
        assert_eq!(mask_compress(&w, &mask, none, 0.0).0, NO_MASK_AND_ALL_VALS);
        // Child slots are skipped.
        let child = [0b110_0000u64, 0, 0, 0, 0, 0, 0, 0];
        assert_eq!(
            mask_compress(&w, &mask, &child, 0.0).0,
            NO_MASK_AND_ONE_INACTIVE_VAL
        );
    }

    #[test]
    fn zip_falls_back_to_raw_with_a_negative_count() {
        let mut out = Vec::new();
        zip_to_stream(&mut out, &[]);
        assert_eq!(out, 0i64.to_le_bytes());
        out.clear();
        zip_to_stream(&mut out, &[7, 1, 200]);
        assert_eq!(&out[..8], &(-3i64).to_le_bytes());
        assert_eq!(&out[8..], &[7, 1, 200]);
        out.clear();
        zip_to_stream(&mut out, &[0; 4096]);
        let n = i64::from_le_bytes(out[..8].try_into().unwrap());
        assert!(n > 0 && (n as usize) == out.len() - 8 && n < 100);
    }

    #[test]
    fn encoding_is_deterministic_and_the_uuid_follows_the_content() {
        let l = leaf(
            [0, 8, -16],
            |n| n as f32 * 0.25,
            [u64::MAX, 3, 0, 0, 0, 0, 0, 9],
        );
        let g = FloatGridOut::new("d", 0.0, DAffine3::IDENTITY, vec![l.clone()]).unwrap();
        let a = encode_vdb(&g);
        assert_eq!(a, encode_vdb(&g));
        let uuid = std::str::from_utf8(&a[UUID_AT..UUID_AT + 36]).unwrap();
        assert_eq!(uuid.len(), 36);
        assert_eq!(uuid.as_bytes()[14], b'8');
        let g2 = FloatGridOut::new("d", 0.0, DAffine3::IDENTITY, vec![l]).unwrap();
        let b = encode_vdb(&g2.with_metadata("k", "v"));
        assert_ne!(&a[UUID_AT..UUID_AT + 36], &b[UUID_AT..UUID_AT + 36]);
    }

    #[test]
    fn diagonal_and_general_transforms_pick_their_maps() {
        let mut out = Vec::new();
        write_transform(
            &mut out,
            &DAffine3::from_scale_rotation_translation(
                glam::DVec3::splat(0.5),
                glam::DQuat::IDENTITY,
                glam::DVec3::new(1.0, 2.0, 3.0),
            ),
        );
        assert_eq!(&out[4..28], b"UniformScaleTranslateMap");
        assert_eq!(out.len(), 4 + 24 + 18 * 8);
        out.clear();
        write_transform(
            &mut out,
            &DAffine3::from_cols_array(&[
                1.0, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 2.0, 4.0, 5.0, 6.0,
            ]),
        );
        assert_eq!(&out[4..13], b"AffineMap");
        let f = |i: usize| f64::from_le_bytes(out[13 + 8 * i..21 + 8 * i].try_into().unwrap());
        // Row 0 is the image of the x axis; row 3 the translation.
        assert_eq!([f(0), f(1), f(2), f(3)], [1.0, 0.5, 0.0, 0.0]);
        assert_eq!([f(12), f(13), f(14), f(15)], [4.0, 5.0, 6.0, 1.0]);
    }

    #[test]
    fn active_stats_of_an_empty_grid_are_openvdbs_empty_box() {
        assert_eq!(active_stats(&[]), (0, [i32::MAX; 3], [i32::MIN; 3]));
        let l = leaf([-8, 0, 8], |_| 1.0, [0b10, 0, 0, 0, 0, 0, 0, 1 << 63]);
        assert_eq!(active_stats(&[l]), (2, [-8, 0, 9], [-1, 7, 15]));
    }
}

//! The NanoVDB grid buffer (`NanoVDB.h`, ABI 32; the same layout from 32.4 to 32.8, whose grids
//! differ only in their magic number, "NanoVDB0" before 32.7 and "NanoVDB1" from it, and in
//! their checksum): where each structure sits and how big it is for each value type. A grid
//! buffer is
//!
//! ```text
//! GridData  672 B  magic (u64) @0, checksum (u64) @8, version @16, flags @20, grid index @24,
//!                  grid count @28, grid size (u64) @32, name (256 B) @40, Map @296 (3x3 f32
//!                  matrix, its inverse, f32 translation, taper; then the same in f64: matrix
//!                  @384, inverse @456, translation @528), world bbox @560, voxel size @608,
//!                  class @632, type @636, blind metadata offset @640 and count @648
//! TreeData   64 B  @672: byte offsets from the tree to the first leaf, lower, upper node and
//!                  the root (4 u64); node counts (leaf, lower, upper); active tile counts
//!                  (lower, upper, root); active voxel count (u64)
//! RootData         index bbox (6 i32), table size (u32), background, min, max (value type),
//!                  average, deviation (stats type), padded to 32 B; then `table size` tiles of
//!                  32 B: key (u64: x, y, z >> 12 in 21 bits each, x highest), child offset
//!                  from the root (i64, 0 for a tile), state (u32), value
//! upper, lower     bbox (6 i32), flags (u64), value mask, child mask (32^3 or 16^3 bits),
//!                  min, max, average, deviation, padded to 32 B; then one table entry per slot
//!                  (a value, or a child offset from the node as i64), 8 B or the value's size
//! leaves           bbox min (3 i32), bbox extent (3 u8), flags (u8), value mask (512 bits) @16;
//!                  then min, max, average, deviation and the 512 values at the next 32 B
//!                  (float, double, Vec3f), or for quantised leaves minimum (f32) @80, quantum
//!                  (f32) @84, four u16 statistics, and the codes @96
//! ```
//!
//! A node's origin is its bbox minimum with the low bits cleared (`& ~(dim - 1)`).

use crate::vdb::ValueKind;

/// Bytes of `GridData`.
pub(crate) const GRID_BYTES: u64 = 672;
/// Bytes of `TreeData`.
pub(crate) const TREE_BYTES: u64 = 64;
/// Bytes of a root tile.
pub(crate) const TILE_BYTES: u64 = 32;
/// The `GridFlags` bit of a breadth-first node layout.
pub(crate) const BREADTH_FIRST: u32 = 1 << 5;
/// The `GridFlags` bit of a name too long for `GridData` (held in blind data).
pub(crate) const LONG_NAME: u32 = 1 << 0;

/// How a grid's leaves hold their values.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Leaves {
    /// 512 values of the grid's value type.
    Raw,
    /// 512 codes of a fixed width (4, 8 or 16 bits): `code * quantum + minimum`.
    Fixed(u32),
    /// FpN: each leaf's width in its flags, `1 << (flags >> 5)` bits (1 to 16).
    Variable,
}

/// NanoVDB's `GridType` codes.
#[must_use]
pub fn type_name(code: u32) -> &'static str {
    // Codes 20 to 26 came with 32.5 to 32.8.
    const NAMES: [&str; 27] = [
        "unknown",
        "float",
        "double",
        "int16",
        "int32",
        "int64",
        "Vec3f",
        "Vec3d",
        "mask",
        "half",
        "uint32",
        "bool",
        "RGBA8",
        "Fp4",
        "Fp8",
        "Fp16",
        "FpN",
        "Vec4f",
        "Vec4d",
        "index",
        "onindex",
        "indexmask",
        "onindexmask",
        "pointindex",
        "Vec3u8",
        "Vec3u16",
        "uint8",
    ];
    NAMES.get(code as usize).copied().unwrap_or("unknown")
}

/// NanoVDB's `GridClass` codes, as OpenVDB's `class` metadata names them.
#[must_use]
pub fn class_name(code: u32) -> &'static str {
    match code {
        1 => "level set",
        2 => "fog volume",
        3 => "staggered",
        4 => "point index",
        5 => "point data",
        6 => "topology",
        7 => "voxel volume",
        8 => "index",
        9 => "tensor",
        _ => "unknown",
    }
}

/// The quantisation of a grid type's leaves: `none`, `fp4`, `fp8`, `fp16`, `fpN`.
#[must_use]
pub fn quantisation(code: u32) -> &'static str {
    match code {
        13 => "fp4",
        14 => "fp8",
        15 => "fp16",
        16 => "fpN",
        _ => "none",
    }
}

/// Whether umbra decodes grids of `GridType` `code` (float, double, Vec3f, Fp4, Fp8, Fp16,
/// FpN); other types are described from their metadata.
#[must_use]
pub fn is_decoded(code: u32) -> bool {
    Layout::of(code).is_some()
}

/// Sizes and offsets of every structure of a grid of one value type.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Layout {
    /// The type of root and internal values (and of raw leaf values), as umbra decodes it.
    pub kind: ValueKind,
    /// Bytes of one value.
    pub value: u64,
    /// Bytes of `RootData` (before its tiles).
    pub root_bytes: u64,
    /// Offset of the background in `RootData`.
    pub root_background: u64,
    /// Offset of the value in a root tile.
    pub tile_value: u64,
    /// Offset of the table in an upper and a lower node.
    pub table: [u64; 2],
    /// Bytes of an upper and a lower node.
    pub node_bytes: [u64; 2],
    /// Bytes of a table entry.
    pub entry: u64,
    /// How leaves hold values.
    pub leaves: Leaves,
    /// Offset of the values (raw) or codes (quantised) in a leaf.
    pub leaf_values: u64,
    /// Bytes of a leaf (quantised variable: of its fixed part, 96).
    pub leaf_bytes: u64,
}

fn align(x: u64, a: u64) -> u64 {
    x.div_ceil(a) * a
}

impl Layout {
    /// The layout of `GridType` `code`, `None` for a type umbra does not decode.
    pub(crate) fn of(code: u32) -> Option<Self> {
        let (kind, leaves) = match code {
            1 => (ValueKind::Float, Leaves::Raw),
            2 => (ValueKind::Double, Leaves::Raw),
            6 => (ValueKind::Vec3s, Leaves::Raw),
            13 => (ValueKind::Float, Leaves::Fixed(4)),
            14 => (ValueKind::Float, Leaves::Fixed(8)),
            15 => (ValueKind::Float, Leaves::Fixed(16)),
            16 => (ValueKind::Float, Leaves::Variable),
            _ => return None,
        };
        // Value size and alignment; statistics (average, deviation) are f64 for double, else
        // f32 (a Vec3f's statistics are of its length).
        let (v, va, s) = match kind {
            ValueKind::Double => (8, 8, 8),
            ValueKind::Vec3s => (12, 4, 4),
            _ => (4, 4, 4),
        };
        let root_background = align(28, va);
        let root_bytes = align(align(root_background + 3 * v, s) + 2 * s, 32);
        let table = [4096, 512].map(|mask| align(32 + 2 * mask + 2 * v + 2 * s, 32));
        let entry = align(v.max(8), 8);
        let node_bytes = [table[0] + 32768 * entry, table[1] + 4096 * entry];
        let (leaf_values, leaf_bytes) = match leaves {
            Leaves::Raw => {
                let at = align(80 + 2 * v + 2 * s, 32);
                (at, at + 512 * v)
            }
            Leaves::Fixed(bits) => (96, 96 + 64 * u64::from(bits)),
            Leaves::Variable => (96, 96),
        };
        Some(Self {
            kind,
            value: v,
            root_bytes,
            root_background,
            tile_value: align(20, va),
            table,
            node_bytes,
            entry,
            leaves,
            leaf_values,
            leaf_bytes,
        })
    }
}

/// What `GridData` and `TreeData` say, read from the first 736 bytes of a grid buffer.
#[derive(Debug, Clone)]
pub(crate) struct GridHead {
    pub checksum: u64,
    pub version: super::file::Version,
    pub flags: u32,
    pub grid_index: u32,
    pub grid_count: u32,
    pub grid_size: u64,
    pub name: Vec<u8>,
    /// Index-to-world 3x3 matrix, row-major (`world = M ijk + t`).
    pub mat: [f64; 9],
    pub translation: [f64; 3],
    pub grid_class: u32,
    pub grid_type: u32,
    /// Offset of the blind metadata from the grid, and their count.
    pub blind_offset: i64,
    pub blind_count: u32,
    /// Offsets from the tree to the first leaf, lower, upper node and the root.
    pub node_offset: [u64; 4],
    pub node_count: [u32; 3],
    pub tile_count: [u32; 3],
    pub voxel_count: u64,
}

impl GridHead {
    /// Parse the grid and tree headers of `buf`.
    pub(crate) fn parse(buf: &super::bytes::Bytes<'_>) -> crate::error::DecodeResult<Self> {
        let magic = buf.u64(0)?;
        if magic != super::file::MAGIC && magic != super::file::MAGIC_GRID {
            return Err(super::bytes::invalid(format!(
                "the grid buffer starts with {magic:#018x}, not a NanoVDB grid's magic number \
                 (\"NanoVDB0\" or \"NanoVDB1\")"
            )));
        }
        let raw_name = buf.slice(40, 256)?;
        let name_len = raw_name.iter().position(|&c| c == 0).unwrap_or(256);
        let mut mat = [0f64; 9];
        for (i, m) in mat.iter_mut().enumerate() {
            *m = buf.f64(384 + 8 * i as u64)?;
        }
        let t = GRID_BYTES;
        Ok(Self {
            checksum: buf.u64(8)?,
            version: super::file::Version(buf.u32(16)?),
            flags: buf.u32(20)?,
            grid_index: buf.u32(24)?,
            grid_count: buf.u32(28)?,
            grid_size: buf.u64(32)?,
            name: raw_name[..name_len].to_vec(),
            mat,
            translation: buf.vec3d(528)?,
            grid_class: buf.u32(632)?,
            grid_type: buf.u32(636)?,
            blind_offset: buf.i64(640)?,
            blind_count: buf.u32(648)?,
            node_offset: [
                buf.u64(t)?,
                buf.u64(t + 8)?,
                buf.u64(t + 16)?,
                buf.u64(t + 24)?,
            ],
            node_count: [buf.u32(t + 32)?, buf.u32(t + 36)?, buf.u32(t + 40)?],
            tile_count: [buf.u32(t + 44)?, buf.u32(t + 48)?, buf.u32(t + 52)?],
            voxel_count: buf.u64(t + 56)?,
        })
    }

    /// `world_from_index` as umbra keeps it (4x4, column vectors, row-major).
    pub(crate) fn world_from_index(&self) -> [[f64; 4]; 4] {
        let m = &self.mat;
        let t = &self.translation;
        [
            [m[0], m[1], m[2], t[0]],
            [m[3], m[4], m[5], t[1]],
            [m[6], m[7], m[8], t[2]],
            [0.0, 0.0, 0.0, 1.0],
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_are_nanovdbs() {
        // sizeof(RootData), sizeof(InternalNode<.., 5>), <.., 4>, sizeof(LeafNode) in NanoVDB
        // 32.4 for float, double and Vec3f, and the quantised leaves (96 + codes).
        let f = Layout::of(1).unwrap();
        assert_eq!(
            (f.root_bytes, f.node_bytes, f.leaf_bytes),
            (64, [270400, 33856], 2144)
        );
        let d = Layout::of(2).unwrap();
        assert_eq!(
            (d.root_bytes, d.root_background, d.leaf_values),
            (96, 32, 128)
        );
        assert_eq!(d.leaf_bytes, 4224);
        let v = Layout::of(6).unwrap();
        assert_eq!((v.root_bytes, v.entry, v.leaf_bytes), (96, 16, 6272));
        assert_eq!(Layout::of(13).unwrap().leaf_bytes, 352);
        assert_eq!(Layout::of(14).unwrap().leaf_bytes, 608);
        assert_eq!(Layout::of(15).unwrap().leaf_bytes, 1120);
        assert!(Layout::of(4).is_none());
    }
}

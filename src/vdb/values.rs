//! Value types and OpenVDB's node-value compression (`io::readCompressedValues`): the per-node
//! metadata byte, up to two inactive values, the selection mask, then the (active or all) values,
//! optionally as 16-bit halves, raw, zlib or blosc compressed. Everything decodes to `f32`, the
//! precision umbra traces in; a vector value to the part of it a [`Pick`] selects (its length,
//! or one component).

use super::archive::Compression;
use super::blosc;
use super::bytes::ByteReader;
use crate::error::{DecodeError, DecodeResult};
use std::io::Read;

/// Value type of a grid, from its tree type name (`Tree_float_5_4_3` etc.).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValueKind {
    /// `float`
    Float,
    /// `double`, converted to f32.
    Double,
    /// `int32`
    Int32,
    /// `int64`
    Int64,
    /// `bool`
    Bool,
    /// `vec3s`; a `Grid` keeps the vector length, a `VectorGrid` its components.
    Vec3s,
    /// `vec3d`; a `Grid` keeps the vector length, a `VectorGrid` its components.
    Vec3d,
    /// `vec3i`; a `Grid` keeps the vector length, a `VectorGrid` its components.
    Vec3i,
}

/// What one `f32` of a decoded tree holds of a stored value: scalars are themselves whatever
/// the pick; a vector value is its length or one of its components (0 = x, 1 = y, 2 = z). The
/// background, tile, inactive and voxel values of a tree are all decoded with one pick.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) enum Pick {
    /// The vector length (what a tree of a vector grid holds unless asked otherwise).
    #[default]
    Length,
    /// Component `k` (0, 1 or 2) of the vector.
    Component(usize),
}

impl ValueKind {
    /// Parse the OpenVDB tree type name; only the standard 5-4-3 configuration is accepted.
    pub(crate) fn from_tree_type(tree_type: &str) -> DecodeResult<Self> {
        let Some(rest) = tree_type.strip_prefix("Tree_") else {
            return Err(DecodeError::unsupported(format!("grid type '{tree_type}'")));
        };
        let Some(value) = rest.strip_suffix("_5_4_3") else {
            return Err(DecodeError::unsupported(format!(
                "tree configuration '{tree_type}' (umbra reads 5-4-3 trees)"
            )));
        };
        Ok(match value {
            "float" => Self::Float,
            "double" => Self::Double,
            "int32" => Self::Int32,
            "int64" => Self::Int64,
            "bool" => Self::Bool,
            "vec3s" => Self::Vec3s,
            "vec3d" => Self::Vec3d,
            "vec3i" => Self::Vec3i,
            other => {
                return Err(DecodeError::unsupported(format!(
                    "value type '{other}' ({tree_type})"
                )))
            }
        })
    }

    /// OpenVDB's value type name.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Float => "float",
            Self::Double => "double",
            Self::Int32 => "int32",
            Self::Int64 => "int64",
            Self::Bool => "bool",
            Self::Vec3s => "vec3s",
            Self::Vec3d => "vec3d",
            Self::Vec3i => "vec3i",
        }
    }

    /// True for scalar floating-point grids, the ones that can be a density.
    #[must_use]
    pub fn is_scalar_real(self) -> bool {
        matches!(self, Self::Float | Self::Double)
    }

    /// True for the vector types (`vec3s`, `vec3d`, `vec3i`).
    #[must_use]
    pub fn is_vector(self) -> bool {
        matches!(self, Self::Vec3s | Self::Vec3d | Self::Vec3i)
    }

    /// True for types OpenVDB stores as halves when "save as half" is on.
    fn is_real(self) -> bool {
        matches!(self, Self::Float | Self::Double | Self::Vec3s | Self::Vec3d)
    }

    /// Bytes of one full-precision value on disk.
    pub(crate) fn size(self) -> usize {
        match self {
            Self::Float | Self::Int32 => 4,
            Self::Double | Self::Int64 => 8,
            Self::Bool => 1,
            Self::Vec3s | Self::Vec3i => 12,
            Self::Vec3d => 24,
        }
    }

    /// Bytes of one value in a value array, which is half precision for real types in a
    /// `_HalfFloat` grid.
    fn array_size(self, half: bool) -> usize {
        match (half && self.is_real(), self) {
            (true, Self::Float | Self::Double) => 2,
            (true, _) => 6,
            (false, _) => self.size(),
        }
    }

    /// Decode one full-precision value (`b.len() == self.size()`), a vector as `pick` says.
    pub(crate) fn decode(self, b: &[u8], pick: Pick) -> f32 {
        let f32_at = |i: usize| f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        let i32_at = |i: usize| i32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
        let f64_at = |i: usize| {
            let mut a = [0u8; 8];
            a.copy_from_slice(&b[i..i + 8]);
            f64::from_le_bytes(a)
        };
        let len3 = |x: f64, y: f64, z: f64| (x * x + y * y + z * z).sqrt() as f32;
        match self {
            Self::Float => f32_at(0),
            Self::Double => f64_at(0) as f32,
            Self::Int32 => i32_at(0) as f32,
            Self::Int64 => {
                let mut a = [0u8; 8];
                a.copy_from_slice(&b[..8]);
                i64::from_le_bytes(a) as f32
            }
            Self::Bool => f32::from(u8::from(b[0] != 0)),
            Self::Vec3s | Self::Vec3d | Self::Vec3i if pick != Pick::Length => {
                let k = pick.component();
                match self {
                    Self::Vec3s => f32_at(4 * k),
                    Self::Vec3d => f64_at(8 * k) as f32,
                    _ => i32_at(4 * k) as f32,
                }
            }
            Self::Vec3s => len3(f32_at(0).into(), f32_at(4).into(), f32_at(8).into()),
            Self::Vec3d => len3(f64_at(0), f64_at(8), f64_at(16)),
            Self::Vec3i => len3(i32_at(0).into(), i32_at(4).into(), i32_at(8).into()),
        }
    }

    /// Decode one array element (half precision when `half` and the type is real), a vector
    /// as `pick` says.
    fn decode_array(self, b: &[u8], half: bool, pick: Pick) -> f32 {
        if !(half && self.is_real()) {
            return self.decode(b, pick);
        }
        let h = |i: usize| half::f16::from_le_bytes([b[i], b[i + 1]]).to_f32();
        match (self, pick) {
            (Self::Float | Self::Double, _) => h(0),
            (_, Pick::Component(_)) => h(2 * pick.component()),
            (_, Pick::Length) => {
                let (x, y, z) = (h(0), h(2), h(4));
                (x * x + y * y + z * z).sqrt()
            }
        }
    }
}

impl Pick {
    /// The component index (0, 1 or 2; a length picks 0, never asked).
    fn component(self) -> usize {
        match self {
            Self::Length => 0,
            Self::Component(k) => k.min(2),
        }
    }
}

/// What converting a double-precision grid to `f32` cost, over every stored value.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct PrecisionLoss {
    /// Values converted.
    pub values: u64,
    /// Largest relative rounding error `|f32(v) - v| / |v|` among finite, in-range values.
    pub max_relative_error: f64,
    /// Finite values beyond the `f32` range (became ±Inf).
    pub overflowed: u64,
    /// Non-zero values that became 0 or subnormal in `f32`.
    pub underflowed: u64,
}

impl PrecisionLoss {
    /// Fold in what another part of the same grid cost.
    pub fn merge(&mut self, o: Self) {
        self.values += o.values;
        self.max_relative_error = self.max_relative_error.max(o.max_relative_error);
        self.overflowed += o.overflowed;
        self.underflowed += o.underflowed;
    }

    pub(crate) fn add(&mut self, v: f64) {
        self.values += 1;
        let f = v as f32;
        if v.is_finite() && f.is_infinite() {
            self.overflowed += 1;
        } else if v != 0.0 && v.is_finite() && !f.is_normal() {
            self.underflowed += 1;
        } else if v != 0.0 && v.is_finite() {
            let rel = ((f64::from(f) - v) / v).abs();
            self.max_relative_error = self.max_relative_error.max(rel);
        }
    }
}

/// Everything a node decoder needs to know about the stream it reads.
#[derive(Debug, Clone)]
pub(crate) struct StreamInfo {
    pub kind: ValueKind,
    /// What of a vector value the decoded tree holds.
    pub pick: Pick,
    pub half: bool,
    pub compression: Compression,
    pub background: f32,
    /// Conversion cost of double grids, accumulated while decoding.
    pub precision: std::cell::Cell<PrecisionLoss>,
    /// Decompression buffer reused by every node.
    pub scratch: std::cell::RefCell<Vec<u8>>,
}

impl StreamInfo {
    /// Record the `f64` values of a run of full-precision double bytes.
    pub(crate) fn track_doubles(&self, bytes: &[u8]) {
        if self.kind != ValueKind::Double || self.half {
            return;
        }
        let mut p = self.precision.get();
        for c in bytes.chunks_exact(8) {
            let mut a = [0u8; 8];
            a.copy_from_slice(c);
            p.add(f64::from_le_bytes(a));
        }
        self.precision.set(p);
    }
}

/// `io::readData`: a run of `nbytes` bytes, raw, zlib (`i64` size prefix) or blosc (`i64` size
/// prefix). A non-positive prefix means the bytes follow uncompressed. Decompressed bytes go to
/// `scratch`, which is reused from node to node (no allocation or zeroing per leaf).
pub(crate) fn read_data<'x, 'a: 'x>(
    r: &mut ByteReader<'a>,
    comp: Compression,
    nbytes: usize,
    scratch: &'x mut Vec<u8>,
) -> DecodeResult<&'x [u8]> {
    if !(comp.blosc || comp.zip) {
        return r.take(nbytes, "uncompressed values");
    }
    let codec = if comp.blosc { "blosc" } else { "zip" };
    let n = r.i64("compressed size")?;
    if n <= 0 {
        let raw = n.unsigned_abs();
        if raw != nbytes as u64 {
            return Err(DecodeError::invalid(format!(
                "{codec} block at offset {} stores {raw} raw bytes, expected {nbytes}",
                r.offset()
            )));
        }
        return r.take(nbytes, "values");
    }
    let at = r.offset();
    let len = usize::try_from(n).unwrap_or(usize::MAX);
    let src = r.take(len, "compressed values")?;
    let out = if comp.blosc {
        if scratch.len() < nbytes {
            scratch.resize(nbytes, 0);
        }
        blosc::decompress_into(src, &mut scratch[..nbytes])
    } else {
        inflate(src, nbytes, scratch)
    };
    match out {
        Ok(()) => Ok(&scratch[..nbytes]),
        Err(DecodeError::Invalid(m) | DecodeError::Truncated { msg: m, .. }) => {
            Err(DecodeError::invalid(format!("{m} (block at offset {at})")))
        }
        Err(other) => Err(other),
    }
}

/// Inflate a zlib block that must expand to exactly `expected` bytes into `out[..expected]`.
fn inflate(src: &[u8], expected: usize, out: &mut Vec<u8>) -> DecodeResult<()> {
    out.clear();
    let mut dec = flate2::read::ZlibDecoder::new(src).take(expected as u64 + 1);
    dec.read_to_end(out)
        .map_err(|e| DecodeError::invalid(format!("zlib data is corrupt: {e}")))?;
    if out.len() != expected {
        return Err(DecodeError::invalid(format!(
            "zlib block expands to {} bytes, expected {expected}",
            out.len()
        )));
    }
    Ok(())
}

/// Per-node flag saying which inactive values and masks follow (`io::NodeMetadata`).
const NO_MASK_OR_INACTIVE_VALS: u8 = 0;
// 1 = NO_MASK_AND_MINUS_BG: inactive values are -background, the default below.
const NO_MASK_AND_ONE_INACTIVE_VAL: u8 = 2;
const MASK_AND_NO_INACTIVE_VALS: u8 = 3;
const MASK_AND_ONE_INACTIVE_VAL: u8 = 4;
const MASK_AND_TWO_INACTIVE_VALS: u8 = 5;
const NO_MASK_AND_ALL_VALS: u8 = 6;

/// `io::readCompressedValues` for a node of `dest.len()` values with the given value mask.
/// `dest.len()` must be `64 * mask.len()`.
pub(crate) fn read_compressed_values(
    r: &mut ByteReader<'_>,
    s: &StreamInfo,
    mask: &[u64],
    dest: &mut [f32],
) -> DecodeResult<()> {
    debug_assert_eq!(dest.len(), mask.len() * 64);
    let mask_compressed = s.compression.active_mask;
    let meta = r.u8("node metadata")?;
    if meta > NO_MASK_AND_ALL_VALS {
        return Err(DecodeError::invalid(format!(
            "node metadata byte {meta} at offset {} is not 0..=6",
            r.offset() - 1
        )));
    }
    let bg = s.background;
    // "Minus the background" of a vector grid read as its length is the background's length:
    // |-v| = |v|.
    let minus_bg = if s.kind.is_vector() && s.pick == Pick::Length {
        bg
    } else {
        -bg
    };
    let mut inactive0 = if meta == NO_MASK_OR_INACTIVE_VALS {
        bg
    } else {
        minus_bg
    };
    let mut inactive1 = bg;
    if matches!(
        meta,
        NO_MASK_AND_ONE_INACTIVE_VAL | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS
    ) {
        inactive0 = s
            .kind
            .decode(r.take(s.kind.size(), "inactive value")?, s.pick);
        if meta == MASK_AND_TWO_INACTIVE_VALS {
            inactive1 = s
                .kind
                .decode(r.take(s.kind.size(), "inactive value")?, s.pick);
        }
    }
    // Leaves have 8 mask words; only internal nodes need more (no 4 KiB zeroing per leaf).
    let mut small = [0u64; 8];
    let mut big = Vec::new();
    let selection: &mut [u64] = if mask.len() <= small.len() {
        &mut small[..mask.len()]
    } else {
        big.resize(mask.len(), 0);
        &mut big
    };
    let has_selection = matches!(
        meta,
        MASK_AND_NO_INACTIVE_VALS | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS
    );
    if has_selection {
        r.u64_words(selection, "selection mask")?;
    }
    let only_active = mask_compressed && meta != NO_MASK_AND_ALL_VALS;
    let count = if only_active {
        mask.iter().map(|w| w.count_ones() as usize).sum()
    } else {
        dest.len()
    };
    let half = s.half && s.kind.is_real();
    let fill_inactive = |dest: &mut [f32]| {
        if has_selection {
            for (w, &sel) in selection.iter().enumerate() {
                for (b, d) in dest[w * 64..w * 64 + 64].iter_mut().enumerate() {
                    *d = if sel >> b & 1 != 0 {
                        inactive1
                    } else {
                        inactive0
                    };
                }
            }
        } else {
            dest.fill(inactive0);
        }
    };
    // HalfWriter writes nothing at all for an empty array (not even a size prefix).
    if half && count == 0 {
        fill_inactive(dest);
        return Ok(());
    }
    let elem = s.kind.array_size(s.half);
    let mut scratch = s.scratch.borrow_mut();
    let data = read_data(r, s.compression, count * elem, &mut scratch)?;
    s.track_doubles(data);
    if !only_active {
        decode_array_into(s.kind, half, s.pick, data, dest);
        return Ok(());
    }
    // Decode the active values contiguously, then scatter them to the mask's set bits.
    let mut stack = [0f32; 512];
    let mut heap = Vec::new();
    let vals: &mut [f32] = if count <= stack.len() {
        &mut stack[..count]
    } else {
        heap.resize(count, 0.0);
        &mut heap
    };
    decode_array_into(s.kind, half, s.pick, data, vals);
    fill_inactive(dest);
    let mut next = 0;
    for (w, &word) in mask.iter().enumerate() {
        if word == u64::MAX {
            dest[w * 64..w * 64 + 64].copy_from_slice(&vals[next..next + 64]);
            next += 64;
            continue;
        }
        let mut bits = word;
        while bits != 0 {
            dest[w * 64 + bits.trailing_zeros() as usize] = vals[next];
            next += 1;
            bits &= bits - 1;
        }
    }
    Ok(())
}

/// Step over what [`read_compressed_values`] would read for a node with value mask `mask`,
/// without decompressing: the metadata byte, inactive values, selection mask, then the value
/// run (its size prefix says how long a compressed run is). This is how a leaf's buffer is found
/// without decoding the ones before it.
pub(crate) fn skip_compressed_values(
    r: &mut ByteReader<'_>,
    s: &StreamInfo,
    mask: &[u64],
) -> DecodeResult<()> {
    let meta = r.u8("node metadata")?;
    if meta > NO_MASK_AND_ALL_VALS {
        return Err(DecodeError::invalid(format!(
            "node metadata byte {meta} at offset {} is not 0..=6",
            r.offset() - 1
        )));
    }
    if matches!(
        meta,
        NO_MASK_AND_ONE_INACTIVE_VAL | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS
    ) {
        r.skip(s.kind.size(), "inactive value")?;
        if meta == MASK_AND_TWO_INACTIVE_VALS {
            r.skip(s.kind.size(), "inactive value")?;
        }
    }
    if matches!(
        meta,
        MASK_AND_NO_INACTIVE_VALS | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS
    ) {
        r.skip(8 * mask.len(), "selection mask")?;
    }
    let only_active = s.compression.active_mask && meta != NO_MASK_AND_ALL_VALS;
    let count = if only_active {
        mask.iter().map(|w| w.count_ones() as usize).sum()
    } else {
        64 * mask.len()
    };
    if s.half && s.kind.is_real() && count == 0 {
        return Ok(());
    }
    let nbytes = count * s.kind.array_size(s.half);
    if !(s.compression.blosc || s.compression.zip) {
        return r.skip(nbytes, "uncompressed values");
    }
    let n = r.i64("compressed size")?;
    if n <= 0 {
        if n.unsigned_abs() != nbytes as u64 {
            return Err(DecodeError::invalid(format!(
                "compressed block at offset {} stores {} raw bytes, expected {nbytes}",
                r.offset(),
                n.unsigned_abs()
            )));
        }
        return r.skip(nbytes, "values");
    }
    r.skip(
        usize::try_from(n).unwrap_or(usize::MAX),
        "compressed values",
    )
}

/// Decode a value array (`out.len()` elements of `data`) into `out`, vectors as `pick` says,
/// with the common types' loops specialised (no per-value dispatch).
fn decode_array_into(kind: ValueKind, half: bool, pick: Pick, data: &[u8], out: &mut [f32]) {
    match (kind, half) {
        (ValueKind::Float, false) => {
            for (o, c) in out.iter_mut().zip(data.chunks_exact(4)) {
                *o = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
            }
        }
        (ValueKind::Float | ValueKind::Double, true) => {
            for (o, c) in out.iter_mut().zip(data.chunks_exact(2)) {
                *o = half::f16::from_le_bytes([c[0], c[1]]).to_f32();
            }
        }
        (ValueKind::Double, false) => {
            for (o, c) in out.iter_mut().zip(data.chunks_exact(8)) {
                let mut a = [0u8; 8];
                a.copy_from_slice(c);
                *o = f64::from_le_bytes(a) as f32;
            }
        }
        (ValueKind::Vec3s, false) if pick != Pick::Length => {
            let at = 4 * pick.component();
            for (o, c) in out.iter_mut().zip(data.chunks_exact(12)) {
                *o = f32::from_le_bytes([c[at], c[at + 1], c[at + 2], c[at + 3]]);
            }
        }
        _ => {
            let elem = kind.array_size(half);
            for (o, c) in out.iter_mut().zip(data.chunks_exact(elem)) {
                *o = kind.decode_array(c, half, pick);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stream(comp: u32, half: bool) -> StreamInfo {
        StreamInfo {
            kind: ValueKind::Float,
            pick: Pick::Length,
            half,
            compression: Compression::from_flags(comp),
            background: 0.5,
            precision: std::cell::Cell::default(),
            scratch: std::cell::RefCell::default(),
        }
    }

    #[test]
    fn active_mask_values_restore_inactive_as_background_or_minus_background() {
        let mut mask = [0u64; 8];
        mask[0] = 0b101; // voxels 0 and 2 active
        for (meta, expect_inactive) in [(0u8, 0.5f32), (1, -0.5)] {
            let mut bytes = vec![meta];
            bytes.extend_from_slice(&1.0f32.to_le_bytes());
            bytes.extend_from_slice(&2.0f32.to_le_bytes());
            let mut dest = [9.0f32; 512];
            let mut r = ByteReader::new(&bytes, 0);
            let res = read_compressed_values(&mut r, &stream(2, false), &mask, &mut dest);
            assert!(res.is_ok(), "{res:?}");
            assert_eq!(
                (dest[0], dest[1], dest[2], dest[511]),
                (1.0, expect_inactive, 2.0, expect_inactive)
            );
            assert_eq!(r.remaining(), 0);
        }
    }

    #[test]
    fn a_pick_keeps_one_component_of_every_vector_type() {
        let (x, y, z) = (3.0f64, -4.0f64, 12.0f64);
        let mut s = Vec::new();
        let mut d = Vec::new();
        let mut i = Vec::new();
        let mut h = Vec::new();
        for c in [x, y, z] {
            s.extend_from_slice(&(c as f32).to_le_bytes());
            d.extend_from_slice(&c.to_le_bytes());
            i.extend_from_slice(&(c as i32).to_le_bytes());
            h.extend_from_slice(&half::f16::from_f64(c).to_le_bytes());
        }
        for (kind, b) in [
            (ValueKind::Vec3s, &s),
            (ValueKind::Vec3d, &d),
            (ValueKind::Vec3i, &i),
        ] {
            assert_eq!(kind.decode(b, Pick::Length), 13.0, "{kind:?}");
            let picked = [0, 1, 2].map(|k| kind.decode(b, Pick::Component(k)));
            assert_eq!(picked, [3.0, -4.0, 12.0], "{kind:?}");
            let mut out = [0f32; 1];
            decode_array_into(kind, false, Pick::Component(2), b, &mut out);
            assert_eq!(out, [12.0], "{kind:?}");
        }
        for kind in [ValueKind::Vec3s, ValueKind::Vec3d] {
            assert_eq!(kind.decode_array(&h, true, Pick::Length), 13.0);
            let picked = [0, 1, 2].map(|k| kind.decode_array(&h, true, Pick::Component(k)));
            assert_eq!(picked, [3.0, -4.0, 12.0], "{kind:?}");
        }
        // A scalar is itself whatever the pick.
        let f = 2.5f32.to_le_bytes();
        assert_eq!(ValueKind::Float.decode(&f, Pick::Component(1)), 2.5);
    }

    #[test]
    fn vector_inactive_values_are_minus_the_background_component() {
        // Active-mask compression, node metadata 1: inactive voxels are -background.
        let mut mask = [0u64; 8];
        mask[0] = 0b1;
        let mut bytes = vec![1u8];
        for c in [1.0f32, 2.0, 3.0] {
            bytes.extend_from_slice(&c.to_le_bytes());
        }
        for (k, (bg, active)) in [(0.5f32, 1.0f32), (-0.25, 2.0), (1.5, 3.0)]
            .into_iter()
            .enumerate()
        {
            let s = StreamInfo {
                kind: ValueKind::Vec3s,
                pick: Pick::Component(k),
                background: bg,
                ..stream(2, false)
            };
            let mut dest = [9.0f32; 512];
            let mut r = ByteReader::new(&bytes, 0);
            let res = read_compressed_values(&mut r, &s, &mask, &mut dest);
            assert!(res.is_ok(), "{res:?}");
            assert_eq!((dest[0], dest[1], dest[511]), (active, -bg, -bg));
        }
    }

    #[test]
    fn precision_loss_counts_overflow_underflow_and_rounding() {
        let mut p = PrecisionLoss::default();
        for v in [1.0, 0.1, 1e300, 1e-300, 0.0] {
            p.add(v);
        }
        assert_eq!((p.values, p.overflowed, p.underflowed), (5, 1, 1));
        assert!(p.max_relative_error > 1e-9 && p.max_relative_error < 6e-8);
    }

    #[test]
    fn empty_half_array_reads_nothing() {
        // A node with no active values in a half grid: just the metadata byte, then the next node.
        let bytes = [0u8, 0xAB];
        let mut dest = [1.0f32; 512];
        let mut r = ByteReader::new(&bytes, 0);
        let res = read_compressed_values(&mut r, &stream(6, true), &[0u64; 8], &mut dest);
        assert!(res.is_ok());
        assert_eq!(r.remaining(), 1);
        assert!(dest.iter().all(|&v| v == 0.5));
    }

    #[test]
    fn zip_round_trip_and_size_mismatch() {
        use std::io::Write;
        let raw: Vec<u8> = (0..64u8).collect();
        let mut enc = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        let _ = enc.write_all(&raw);
        let z = enc.finish().unwrap_or_default();
        let mut bytes = (z.len() as i64).to_le_bytes().to_vec();
        bytes.extend_from_slice(&z);
        let comp = Compression::from_flags(1);
        let mut sc = Vec::new();
        let got = read_data(&mut ByteReader::new(&bytes, 0), comp, 64, &mut sc);
        assert_eq!(got.ok().map(<[u8]>::to_vec), Some(raw));
        assert!(read_data(&mut ByteReader::new(&bytes, 0), comp, 65, &mut sc).is_err());
    }
}

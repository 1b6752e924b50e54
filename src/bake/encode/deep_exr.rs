//! A writer for OpenEXR **deep scanline** files (the `exr` crate reads but cannot write deep
//! data): [`DeepImage`] holds per-pixel sample lists of f32 channels, [`encode_deep_exr`] turns
//! it into file bytes and [`write_deep_exr`] writes them atomically.
//!
//! **Layout written** (OpenEXR's `OpenEXRFileLayout.rst`; all numbers little-endian):
//!
//! * magic `76 2f 31 01`, then the version field `2 | 0x800` (bit 11: a "non-image", deep part;
//!   no tile bit 9, no multi-part bit 12), plus `0x400` (long names) only when a channel,
//!   attribute or attribute type name is longer than 31 bytes.
//! * one header: attributes `name\0 type\0 i32 size, value`, sorted by name byte-wise (the
//!   order OpenEXR writes), ended by one `0` byte. Always present: `channels` (chlist: per
//!   channel `name\0`, i32 pixel type 2 = FLOAT, u8 pLinear 0, 3 zero bytes, i32 xSampling 1,
//!   i32 ySampling 1, the list ended by `\0`), `chunkCount` (int = height), `compression` (u8
//!   2 = ZIPS, one scanline per chunk), `dataWindow` = `displayWindow` (box2i `0 0 W-1 H-1`),
//!   `lineOrder` (u8 0 = INCREASING_Y), `maxSamplesPerPixel` (int, the largest count),
//!   `name` (string, [`DeepAttributes::part_name`]), `pixelAspectRatio` (float 1),
//!   `screenWindowCenter` (v2f 0 0), `screenWindowWidth` (float 1), `type` (string
//!   `deepscanline`), `version` (int 1); then the caller's [`DeepAttributes::extra`].
//! * the offset table: one u64 per scanline, the file offset of its chunk.
//! * one chunk per scanline, top to bottom: i32 `y`, u64 packed size of the pixel offset table,
//!   u64 packed size of the sample data, u64 unpacked size of the sample data, the packed
//!   offset table, the packed sample data. The unpacked offset table is one i32 per pixel, the
//!   number of samples of that pixel and all pixels left of it in the line (`W x 4` bytes). The
//!   unpacked sample data is, per channel in name order, the f32 samples of every pixel of the
//!   line, left to right (`samples x channels x 4` bytes; `0` for a line without samples).
//! * ZIPS packing of either buffer (OpenEXR's `internal_zip.c`): split the bytes into the
//!   even-indexed then the odd-indexed ones, replace each byte after the first by
//!   `(b[i] - b[i-1] + 384) mod 256` (differences of the split bytes), zlib-compress. When that
//!   is not smaller than the raw bytes, the raw bytes are stored instead, which readers detect
//!   by packed size == unpacked size.
//!
//! Channels are sorted by name (byte-wise) whatever order they are given in; the same image and
//! attributes always give the same bytes.

use crate::error::{Error, Result};
use exr::meta::attribute::AttributeValue;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

/// OpenEXR pixel type FLOAT.
const PIXEL_FLOAT: i32 = 2;
/// OpenEXR compression ZIPS_COMPRESSION (zlib, one scanline per chunk).
const COMPRESSION_ZIPS: u8 = 2;
/// Version field: format version 2 with the non-image (deep) bit 11.
const VERSION_DEEP: u32 = 2 | 0x800;
/// Version field bit 10: names up to 255 bytes instead of 31.
const LONG_NAMES: u32 = 0x400;
/// Longest name without the long-names bit.
const SHORT_NAME_MAX: usize = 31;
/// Longest name (channel, attribute, attribute type) OpenEXR allows.
const NAME_MAX: usize = 255;

/// Header attributes the writer sets itself; [`DeepAttributes::extra`] may not use them.
pub const RESERVED_ATTRIBUTES: [&str; 14] = [
    "channels",
    "chunkCount",
    "compression",
    "dataWindow",
    "displayWindow",
    "lineOrder",
    "maxSamplesPerPixel",
    "name",
    "pixelAspectRatio",
    "screenWindowCenter",
    "screenWindowWidth",
    "tiles",
    "type",
    "version",
];

fn invalid(reason: impl Into<String>) -> Error {
    Error::InvalidArgument {
        name: "deep".into(),
        reason: reason.into(),
    }
}

/// A deep image: per pixel a list of samples, each with the same f32 channels.
#[derive(Debug, Clone, PartialEq)]
pub struct DeepImage {
    width: u32,
    height: u32,
    /// Channel names, sorted byte-wise.
    channels: Vec<String>,
    /// Samples per pixel, row-major, row 0 at the top.
    counts: Vec<u32>,
    /// Per channel (in `channels` order) all samples of all pixels in pixel order.
    data: Vec<Vec<f32>>,
    /// `line_start[y]`: index of the first sample of row `y` (`height + 1` entries).
    line_start: Vec<usize>,
}

impl DeepImage {
    /// A `width x height` deep image with f32 channels named `channels` (e.g. `["A", "Z",
    /// "ZBack"]`, in any order: they are stored sorted by name, with `data` reordered alike).
    /// `counts` is the number of samples of each pixel, row-major with row 0 at the top
    /// (`width * height` entries); `data[c]` holds channel `channels[c]`'s samples of all
    /// pixels in pixel order (`sum(counts)` values each).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (named `deep`) for a zero or over-`i32` width or height, a
    /// wrong number of counts or of samples in a channel, a row with more than `i32::MAX`
    /// samples, no channels, or a channel name that is empty, not ASCII, contains NUL, is
    /// 256 bytes or longer, or is repeated.
    pub fn new(
        width: u32,
        height: u32,
        channels: Vec<String>,
        counts: Vec<u32>,
        data: Vec<Vec<f32>>,
    ) -> Result<Self> {
        let max_side = i32::MAX as u32;
        if width == 0 || height == 0 || width > max_side || height > max_side {
            return Err(invalid(format!(
                "the size {width} x {height} must be at least 1 x 1 and at most {max_side} per side"
            )));
        }
        let pixels = u64::from(width) * u64::from(height);
        if counts.len() as u64 != pixels {
            return Err(invalid(format!(
                "{} sample counts for {width} x {height} = {pixels} pixels",
                counts.len()
            )));
        }
        if channels.is_empty() {
            return Err(invalid("a deep image needs at least one channel"));
        }
        for name in &channels {
            if name.is_empty() || !name.is_ascii() || name.contains('\0') || name.len() > NAME_MAX {
                return Err(invalid(format!(
                    "channel name {name:?} must be 1 to {NAME_MAX} ASCII bytes without NUL"
                )));
            }
        }
        if data.len() != channels.len() {
            return Err(invalid(format!(
                "{} data planes for {} channels",
                data.len(),
                channels.len()
            )));
        }
        let w = width as usize;
        let mut line_start = Vec::with_capacity(height as usize + 1);
        let mut total = 0usize;
        line_start.push(0);
        for (y, row) in counts.chunks(w).enumerate() {
            let line: u64 = row.iter().map(|&c| u64::from(c)).sum();
            if line > i32::MAX as u64 {
                return Err(invalid(format!(
                    "row {y} has {line} samples, more than {}",
                    i32::MAX
                )));
            }
            total = usize::try_from(line)
                .ok()
                .and_then(|l| total.checked_add(l))
                .ok_or_else(|| invalid("too many samples"))?;
            line_start.push(total);
        }
        for (name, plane) in channels.iter().zip(&data) {
            if plane.len() != total {
                return Err(invalid(format!(
                    "channel {name:?} has {} samples, the counts say {total}",
                    plane.len()
                )));
            }
        }
        // Sort the channels (with their data) by name, byte-wise, as OpenEXR stores them.
        let mut planes: Vec<(String, Vec<f32>)> = channels.into_iter().zip(data).collect();
        planes.sort_by(|a, b| a.0.as_bytes().cmp(b.0.as_bytes()));
        if let Some(pair) = planes.windows(2).find(|p| p[0].0 == p[1].0) {
            return Err(invalid(format!("channel {:?} is given twice", pair[0].0)));
        }
        let (channels, data) = planes.into_iter().unzip();
        Ok(Self {
            width,
            height,
            channels,
            counts,
            data,
            line_start,
        })
    }

    /// Width in pixels.
    #[must_use]
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    #[must_use]
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Channel names, sorted byte-wise (the order of the file).
    #[must_use]
    pub fn channels(&self) -> &[String] {
        &self.channels
    }

    /// Samples per pixel, row-major, row 0 at the top.
    #[must_use]
    pub fn counts(&self) -> &[u32] {
        &self.counts
    }

    /// Channel `name`'s samples of all pixels in pixel order, if there is such a channel.
    #[must_use]
    pub fn channel(&self, name: &str) -> Option<&[f32]> {
        let k = self.channels.iter().position(|c| c == name)?;
        Some(&self.data[k])
    }

    /// Total number of samples.
    #[must_use]
    pub fn total_samples(&self) -> usize {
        self.line_start[self.line_start.len() - 1]
    }

    /// The largest number of samples of one pixel.
    #[must_use]
    pub fn max_samples_per_pixel(&self) -> u32 {
        self.counts.iter().copied().max().unwrap_or(0)
    }
}

/// Header attributes of a deep file beyond the structural ones the writer sets itself.
#[derive(Debug, Clone, PartialEq)]
pub struct DeepAttributes {
    /// The part's `name` attribute (a `string`), which OpenEXR requires in deep files; `"deep"`
    /// by default. Must not be empty.
    pub part_name: String,
    /// Further attributes as `(name, value)`, written with the value's OpenEXR type
    /// (`AttributeValue::Text` is `string`, `F64` is `double`, `Matrix4x4` is `m44f`, a
    /// `Custom { kind: "v3d", .. }` with three little-endian f64 is `v3d`, ...). Names must be
    /// 1 to 255 bytes without NUL, distinct, and none of [`RESERVED_ATTRIBUTES`].
    pub extra: Vec<(String, AttributeValue)>,
}

impl Default for DeepAttributes {
    fn default() -> Self {
        Self {
            part_name: "deep".into(),
            extra: Vec::new(),
        }
    }
}

/// Whether `name` is acceptable as an attribute or attribute type name.
fn good_name(name: &[u8]) -> bool {
    !name.is_empty() && name.len() <= NAME_MAX && !name.contains(&0)
}

impl DeepAttributes {
    /// Check the attributes as [`write_deep_exr`] does.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (named `deep`) for an empty `part_name`, an extra attribute
    /// whose name or type name is empty, 256 bytes or longer or contains NUL, a reserved
    /// name ([`RESERVED_ATTRIBUTES`]) or a name given twice.
    pub fn validate(&self) -> Result<()> {
        if self.part_name.is_empty() || self.part_name.contains('\0') {
            return Err(invalid("the part name must be non-empty, without NUL"));
        }
        let mut seen = std::collections::BTreeSet::new();
        for (name, value) in &self.extra {
            if !good_name(name.as_bytes()) {
                return Err(invalid(format!(
                    "attribute name {name:?} must be 1 to {NAME_MAX} bytes without NUL"
                )));
            }
            if RESERVED_ATTRIBUTES.contains(&name.as_str()) {
                return Err(invalid(format!(
                    "attribute {name:?} is set by the deep writer itself"
                )));
            }
            if !good_name(value.kind_name()) {
                return Err(invalid(format!(
                    "attribute {name:?} has a bad type name (1 to {NAME_MAX} bytes without NUL)"
                )));
            }
            if !seen.insert(name.as_str()) {
                return Err(invalid(format!("attribute {name:?} is given twice")));
            }
        }
        Ok(())
    }
}

/// One attribute: name, type name and value bytes.
struct RawAttribute {
    kind: Vec<u8>,
    value: Vec<u8>,
}

fn raw(kind: &str, value: Vec<u8>) -> RawAttribute {
    RawAttribute {
        kind: kind.as_bytes().to_vec(),
        value,
    }
}

fn i32s(v: &[i32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn f32s(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// The `chlist` value: every channel FLOAT, linear 0, sampling 1 x 1.
fn chlist(channels: &[String]) -> Vec<u8> {
    let mut out = Vec::new();
    for name in channels {
        out.extend_from_slice(name.as_bytes());
        out.push(0);
        out.extend_from_slice(&PIXEL_FLOAT.to_le_bytes());
        out.extend_from_slice(&[0, 0, 0, 0]); // pLinear, 3 reserved
        out.extend_from_slice(&i32s(&[1, 1]));
    }
    out.push(0);
    out
}

/// All header attributes by name (byte-wise order, as OpenEXR writes them).
fn header_attributes(img: &DeepImage, attrs: &DeepAttributes) -> BTreeMap<Vec<u8>, RawAttribute> {
    // The width and height fit an i32 (checked by `DeepImage::new`).
    let w = img.width as i32;
    let h = img.height as i32;
    let window = i32s(&[0, 0, w - 1, h - 1]);
    let max_samples = i32::try_from(img.max_samples_per_pixel()).unwrap_or(i32::MAX);
    let mut map: BTreeMap<Vec<u8>, RawAttribute> = BTreeMap::new();
    for (name, value) in &attrs.extra {
        let name = name.as_bytes();
        let kind = value.kind_name();
        if !good_name(name) || !good_name(kind) {
            continue;
        }
        let mut bytes = Vec::with_capacity(value.byte_size());
        if value.write(&mut bytes).is_ok() {
            map.insert(
                name.to_vec(),
                RawAttribute {
                    kind: kind.to_vec(),
                    value: bytes,
                },
            );
        }
    }
    let part_name = if attrs.part_name.is_empty() || attrs.part_name.contains('\0') {
        "deep"
    } else {
        attrs.part_name.as_str()
    };
    let fixed = [
        ("channels", raw("chlist", chlist(&img.channels))),
        ("chunkCount", raw("int", i32s(&[h]))),
        ("compression", raw("compression", vec![COMPRESSION_ZIPS])),
        ("dataWindow", raw("box2i", window.clone())),
        ("displayWindow", raw("box2i", window)),
        ("lineOrder", raw("lineOrder", vec![0])),
        ("maxSamplesPerPixel", raw("int", i32s(&[max_samples]))),
        ("name", raw("string", part_name.as_bytes().to_vec())),
        ("pixelAspectRatio", raw("float", f32s(&[1.0]))),
        ("screenWindowCenter", raw("v2f", f32s(&[0.0, 0.0]))),
        ("screenWindowWidth", raw("float", f32s(&[1.0]))),
        ("type", raw("string", b"deepscanline".to_vec())),
        ("version", raw("int", i32s(&[1]))),
    ];
    // Reserved names always carry the writer's values (`tiles` is dropped: no tiles here).
    map.remove(b"tiles".as_slice());
    for (name, value) in fixed {
        map.insert(name.as_bytes().to_vec(), value);
    }
    map
}

/// OpenEXR's ZIP/ZIPS packing of `raw`: byte split, delta predictor, zlib; the raw bytes when
/// that is not smaller (`internal_zip.c`: `apply_zip_impl`).
fn zip_pack(raw: &[u8]) -> Vec<u8> {
    if raw.is_empty() {
        return Vec::new();
    }
    let mut t: Vec<u8> = Vec::with_capacity(raw.len());
    t.extend(raw.iter().step_by(2));
    t.extend(raw.iter().skip(1).step_by(2));
    let mut prev = t[0];
    for b in t.iter_mut().skip(1) {
        let cur = *b;
        *b = cur.wrapping_sub(prev).wrapping_add(128);
        prev = cur;
    }
    let mut enc = flate2::write::ZlibEncoder::new(
        Vec::with_capacity(raw.len() / 2),
        flate2::Compression::default(),
    );
    match enc.write_all(&t).and_then(|()| enc.finish()) {
        Ok(z) if z.len() < raw.len() => z,
        _ => raw.to_vec(),
    }
}

/// The chunk of scanline `y`.
fn encode_line(img: &DeepImage, y: usize) -> Vec<u8> {
    let w = img.width as usize;
    let counts = &img.counts[y * w..(y + 1) * w];
    let (start, end) = (img.line_start[y], img.line_start[y + 1]);
    // Cumulative counts fit an i32 (checked by `DeepImage::new`).
    let mut table = Vec::with_capacity(w * 4);
    let mut acc: i32 = 0;
    for &c in counts {
        acc = acc.wrapping_add(c as i32);
        table.extend_from_slice(&acc.to_le_bytes());
    }
    let mut samples = Vec::with_capacity((end - start) * 4 * img.channels.len());
    for plane in &img.data {
        for v in &plane[start..end] {
            samples.extend_from_slice(&v.to_le_bytes());
        }
    }
    let packed_table = zip_pack(&table);
    let packed_samples = zip_pack(&samples);
    let mut out = Vec::with_capacity(28 + packed_table.len() + packed_samples.len());
    out.extend_from_slice(&(y as i32).to_le_bytes());
    out.extend_from_slice(&(packed_table.len() as u64).to_le_bytes());
    out.extend_from_slice(&(packed_samples.len() as u64).to_le_bytes());
    out.extend_from_slice(&(samples.len() as u64).to_le_bytes());
    out.extend_from_slice(&packed_table);
    out.extend_from_slice(&packed_samples);
    out
}

/// Encode `img` as a single-part deep scanline OpenEXR file (ZIPS, increasing Y, the layout of
/// README's *Deep maps* and the `bake/encode/deep_exr.rs` source) with the attributes `attrs`. Extra attributes that
/// [`DeepAttributes::validate`] would refuse for their name or type name are left out, a
/// reserved name never overrides the writer's value, and of a repeated name the last wins;
/// an invalid `part_name` becomes `"deep"`. Scanlines are compressed in parallel (in the
/// current rayon pool); the bytes do not depend on the thread count.
#[must_use]
pub fn encode_deep_exr(img: &DeepImage, attrs: &DeepAttributes) -> Vec<u8> {
    let header = header_attributes(img, attrs);
    let long = img.channels.iter().any(|c| c.len() > SHORT_NAME_MAX)
        || header
            .iter()
            .any(|(n, a)| n.len() > SHORT_NAME_MAX || a.kind.len() > SHORT_NAME_MAX);
    let version = VERSION_DEEP | if long { LONG_NAMES } else { 0 };
    let mut out = Vec::new();
    out.extend_from_slice(&[0x76, 0x2f, 0x31, 0x01]);
    out.extend_from_slice(&version.to_le_bytes());
    for (name, a) in &header {
        out.extend_from_slice(name);
        out.push(0);
        out.extend_from_slice(&a.kind);
        out.push(0);
        let size = i32::try_from(a.value.len()).unwrap_or(i32::MAX);
        out.extend_from_slice(&size.to_le_bytes());
        out.extend_from_slice(&a.value);
    }
    out.push(0);
    let chunks: Vec<Vec<u8>> = (0..img.height as usize)
        .into_par_iter()
        .map(|y| encode_line(img, y))
        .collect();
    let mut offset = (out.len() + 8 * chunks.len()) as u64;
    for c in &chunks {
        out.extend_from_slice(&offset.to_le_bytes());
        offset += c.len() as u64;
    }
    out.reserve(chunks.iter().map(Vec::len).sum());
    for c in &chunks {
        out.extend_from_slice(c);
    }
    out
}

/// Write `img` to `path` as [`encode_deep_exr`] encodes it, atomically (a temporary file
/// renamed into place, see [`crate::output::write_atomic`]).
///
/// # Errors
/// [`Error::InvalidArgument`] when [`DeepAttributes::validate`] refuses `attrs`;
/// [`Error::Output`] as [`crate::output::write_atomic`] (e.g. `path` exists and not
/// `overwrite`); then `path` is untouched.
pub fn write_deep_exr(
    path: &Path,
    img: &DeepImage,
    attrs: &DeepAttributes,
    overwrite: bool,
) -> Result<()> {
    attrs.validate()?;
    let bytes = encode_deep_exr(img, attrs);
    crate::output::write_atomic(path, overwrite, |w| {
        w.write_all(&bytes).map_err(|e| format!("writing: {e}"))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// OpenEXR's `internal_zip_reconstruct_bytes` (the reader's inverse), for the round trip.
    fn unpredict(t: &[u8]) -> Vec<u8> {
        let mut r = t.to_vec();
        for i in 1..r.len() {
            r[i] = r[i - 1].wrapping_add(r[i]).wrapping_sub(128);
        }
        let half = r.len().div_ceil(2);
        let (a, b) = r.split_at(half);
        let mut out = Vec::with_capacity(r.len());
        for i in 0..r.len() {
            out.push(if i % 2 == 0 { a[i / 2] } else { b[i / 2] });
        }
        out
    }

    #[test]
    fn zip_pack_round_trips_and_falls_back() {
        let raw: Vec<u8> = (0..1001u32).flat_map(|i| (i / 7).to_le_bytes()).collect();
        let packed = zip_pack(&raw);
        assert!(packed.len() < raw.len());
        let mut z = flate2::read::ZlibDecoder::new(packed.as_slice());
        let mut t = Vec::new();
        std::io::Read::read_to_end(&mut z, &mut t).unwrap_or_default();
        assert_eq!(unpredict(&t), raw);
        // Too short to win: stored raw.
        assert_eq!(zip_pack(&[1, 200, 3]), vec![1, 200, 3]);
        assert!(zip_pack(&[]).is_empty());
    }
}

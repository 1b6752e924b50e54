//! The NanoVDB file layer (`nanovdb/io/IO.h`, formats 32.0 to 32.8: OpenVDB 10 to 12's
//! `nanovdb_convert`, Warp's `Volume.save_to_nvdb`, fVDB): a file is one or more *segments*
//! back to back, each
//!
//! ```text
//! Header   16 B   magic "NanoVDB0" or, from 32.7 on, "NanoVDB2" (u64), version (u32: major
//!                 << 21 | minor << 10 | patch), grid count (u16), codec (u16: 0 NONE, 1 ZIP,
//!                 2 BLOSC)
//! MetaData 176 B  per grid: grid size, file size, name key, voxel count (u64 each), grid type,
//!                 grid class (u32), world bbox (6 f64), index bbox (6 i32), voxel size (3 f64),
//!                 name size (u32, with the NUL), node counts (4 u32), tile counts (3 u32),
//!                 codec (u16), padding (u16), version (u32); then the name, `name size` bytes
//! blobs           per grid, `file size` bytes: the grid buffer as is (NONE), or a u64 byte
//!                 count and a zlib stream (ZIP, zlib's `compress`), or chunks of at most 2^30
//!                 uncompressed bytes, each a u64 byte count and a blosc buffer (BLOSC)
//! ```
//!
//! Warp writes the same header (version 32.3.3 whatever its grids' version) with only the sizes,
//! type, class, world bbox, voxel size, name and codec of the metadata filled in (the counts,
//! index bbox and name key are zero: [`GridMeta::counted`] is false), and a ZIP or BLOSC blob as
//! one u64 byte count and one stream, the count not included in the file size.
//!
//! Every size is checked against the file before it is used; a blob decompresses to exactly
//! its grid size or the file is refused.

use super::bytes::Bytes;
use crate::error::{DecodeError, DecodeResult};

/// `NANOVDB_MAGIC_NUMB`: "NanoVDB0" read as a little-endian u64, the magic number of every
/// segment header and of grids before 32.7.
pub(crate) const MAGIC: u64 = 0x3042_4456_6f6e_614e;
/// `NANOVDB_MAGIC_GRID`: "NanoVDB1", the magic number of grids from 32.7 on (Warp, OpenVDB 12).
pub(crate) const MAGIC_GRID: u64 = 0x3142_4456_6f6e_614e;
/// `NANOVDB_MAGIC_FILE`: "NanoVDB2", the newer segment header's magic number (32.7 on, when
/// NanoVDB is built with its new magic numbers).
pub(crate) const MAGIC_FILE: u64 = 0x3242_4456_6f6e_614e;
/// The major version of the format umbra reads (the ABI, which fixes the file layout).
pub(crate) const MAJOR: u32 = 32;
/// The newest minor version of major 32 umbra reads: 32.8 (OpenVDB 12.1, Warp 1.19, fVDB);
/// the node layouts are those of 32.4, the magic number and the checksum changed (32.6, 32.7).
pub(crate) const MAX_MINOR: u32 = 8;
/// Bytes of a segment header.
const HEADER_BYTES: u64 = 16;
/// Bytes of a grid's file metadata before its name.
const META_BYTES: u64 = 176;
/// The most a grid buffer may expand from its compressed bytes (zlib's limit is about 1032:1;
/// blosc with LZ4 about 255:1): a grid size beyond it is a lie, refused before any allocation.
const MAX_RATIO: u64 = 1100;

/// A NanoVDB codec (`nanovdb::io::Codec`): how a grid's buffer is stored in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Codec {
    /// Stored as is.
    None,
    /// zlib (`compress`), after a u64 byte count.
    Zip,
    /// blosc (LZ4, byte shuffle of 4-byte words), in chunks of at most 2^30 bytes.
    Blosc,
}

impl Codec {
    fn from_u16(c: u16) -> Option<Self> {
        match c {
            0 => Some(Self::None),
            1 => Some(Self::Zip),
            2 => Some(Self::Blosc),
            _ => None,
        }
    }

    /// The name NanoVDB prints (`NONE`, `ZIP`, `BLOSC`).
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "NONE",
            Self::Zip => "ZIP",
            Self::Blosc => "BLOSC",
        }
    }
}

/// A NanoVDB version number, `major << 21 | minor << 10 | patch`.
/// Ordered as versions are (major, then minor, then patch).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct Version(pub u32);

impl Version {
    /// Major version (the ABI).
    #[must_use]
    pub fn major(self) -> u32 {
        self.0 >> 21
    }
    /// Minor version.
    #[must_use]
    pub fn minor(self) -> u32 {
        (self.0 >> 10) & 0x7ff
    }
    /// Patch version.
    #[must_use]
    pub fn patch(self) -> u32 {
        self.0 & 0x3ff
    }
}

impl std::fmt::Display for Version {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}.{}.{}", self.major(), self.minor(), self.patch())
    }
}

/// What the file says of one grid before its buffer (`nanovdb::io::GridMetaData`).
#[derive(Debug, Clone)]
pub struct GridMeta {
    /// Name as stored.
    pub name: String,
    /// Uncompressed bytes of the grid buffer.
    pub grid_size: u64,
    /// Bytes of the grid's blob in the file.
    pub file_size: u64,
    /// Absolute file offset of the blob.
    pub offset: u64,
    /// NanoVDB's hash of the name.
    pub name_key: u64,
    /// Active voxels (tiles count as the voxels they cover).
    pub voxel_count: u64,
    /// `GridType` code.
    pub grid_type: u32,
    /// `GridClass` code.
    pub grid_class: u32,
    /// World bbox of the active values `[min, max]`.
    pub world_bbox: [[f64; 3]; 2],
    /// Inclusive index bbox of the active values `[min, max]`.
    pub index_bbox: [[i32; 3]; 2],
    /// Voxel size.
    pub voxel_size: [f64; 3],
    /// Nodes per level: leaves, lower, upper, root (always 1).
    pub node_count: [u32; 4],
    /// Active tiles in lower nodes, upper nodes and the root.
    pub tile_count: [u32; 3],
    /// The codec of the grid's segment.
    pub codec: Codec,
    /// The segment's version (Warp writes 32.3.3 here whatever its grids' version).
    pub version: Version,
    /// Bytes of the grid's blob in the file: `file_size`, or `file_size + 8` when a ZIP or
    /// BLOSC blob's byte count is not counted in it (as Warp writes them).
    pub blob_bytes: u64,
    /// Whether the writer filled in the name key, voxel, node and tile counts and index bbox
    /// (NanoVDB does; Warp leaves them zero, so the grid's own headers are all there is).
    pub counted: bool,
}

/// Reads `n` bytes at absolute file offset `at` (the caller checks them against the file).
pub(crate) type ReadAt<'a> = &'a dyn Fn(u64, u64) -> DecodeResult<Vec<u8>>;

/// Parse every segment of a file of `len` bytes read through `read`, giving each grid's
/// metadata in file order (the blobs are stepped over, not read). `Err(None)` means the file
/// is not a NanoVDB file at all (too short, or its first magic number is not NanoVDB's); other
/// errors say where the file is corrupt.
pub(crate) fn parse_segments(
    len: u64,
    read: ReadAt<'_>,
) -> Result<Vec<GridMeta>, Option<DecodeError>> {
    if len < HEADER_BYTES {
        return Err(None);
    }
    let head = read(0, 8).map_err(Some)?;
    if !is_file_magic(Bytes::new(&head).u64(0).map_err(Some)?) {
        return Err(None);
    }
    let mut grids = Vec::new();
    let mut at = 0u64;
    while at < len {
        parse_segment(len, read, &mut at, &mut grids).map_err(Some)?;
    }
    Ok(grids)
}

/// One segment from `*at`: its header, its grids' metadata, then a step over their blobs.
fn parse_segment(
    len: u64,
    read: ReadAt<'_>,
    at: &mut u64,
    grids: &mut Vec<GridMeta>,
) -> DecodeResult<()> {
    let start = *at;
    let bytes = read(start, HEADER_BYTES)?;
    let h = Bytes::new(&bytes);
    let magic = h.u64(0)?;
    if !is_file_magic(magic) {
        return Err(DecodeError::invalid(format!(
            "segment at byte {start}: magic number {magic:#018x} is not NanoVDB's"
        )));
    }
    let version = Version(h.u32(8)?);
    check_version(version, &format!("file header (segment at byte {start})"))?;
    let count = h.u16(12)?;
    let raw_codec = h.u16(14)?;
    let codec = Codec::from_u16(raw_codec).ok_or_else(|| {
        DecodeError::invalid(format!(
            "segment at byte {start}: unknown codec {raw_codec}"
        ))
    })?;
    if count == 0 {
        return Err(DecodeError::invalid(format!(
            "segment at byte {start} holds no grids (NanoVDB never writes one)"
        )));
    }
    let mut p = start + HEADER_BYTES;
    let first = grids.len();
    for i in 0..count {
        let (m, name_size) = parse_meta(read, p, codec)
            .map_err(|e| prefix(e, &format!("segment at byte {start}, grid {i}")))?;
        p += META_BYTES + name_size;
        grids.push(m);
    }
    for g in &mut grids[first..] {
        g.offset = p;
        g.blob_bytes = blob_bytes(len, read, p, g)?;
        p = p
            .checked_add(g.blob_bytes)
            .filter(|&e| e <= len)
            .ok_or_else(|| {
                DecodeError::invalid(format!(
                    "grid '{}' claims {} bytes at byte {p}, past the end of the file ({len} bytes)",
                    crate::text::escape(&g.name),
                    g.blob_bytes,
                ))
            })?;
        check_sizes(g)?;
    }
    *at = p;
    Ok(())
}

/// Whether `magic` opens a segment: "NanoVDB0", or "NanoVDB2" from 32.7 on.
fn is_file_magic(magic: u64) -> bool {
    magic == MAGIC || magic == MAGIC_FILE
}

/// Bytes of grid `g`'s blob at `p`: a ZIP or BLOSC blob opens with a u64 byte count, which
/// NanoVDB counts in the file size (so it is `file size - 8`, or less for several BLOSC chunks)
/// and Warp does not (it equals the file size, and the blob is 8 bytes longer).
fn blob_bytes(len: u64, read: ReadAt<'_>, p: u64, g: &GridMeta) -> DecodeResult<u64> {
    if g.codec == Codec::None || p.saturating_add(8) > len {
        return Ok(g.file_size);
    }
    let count = Bytes::new(&read(p, 8)?).u64(0)?;
    Ok(if count == g.file_size {
        g.file_size.saturating_add(8)
    } else {
        g.file_size
    })
}

/// A grid's metadata at `p` and the length of its name field.
fn parse_meta(read: ReadAt<'_>, p: u64, codec: Codec) -> DecodeResult<(GridMeta, u64)> {
    let bytes = read(p, META_BYTES)?;
    let b = Bytes::new(&bytes);
    let name_size = u64::from(b.u32(136)?);
    let name_bytes = read(p + META_BYTES, name_size)?;
    let name = match name_bytes.split_last() {
        Some((0, name)) if !name.contains(&0) => String::from_utf8_lossy(name).into_owned(),
        _ => {
            return Err(DecodeError::invalid(format!(
                "the name at byte {} is not {name_size} bytes ending in its only NUL",
                p + META_BYTES
            )))
        }
    };
    let own_codec = b.u16(168)?;
    if Codec::from_u16(own_codec) != Some(codec) {
        return Err(DecodeError::invalid(format!(
            "'{}': metadata codec {own_codec} disagrees with its segment's {}",
            crate::text::escape(&name),
            codec.name()
        )));
    }
    let version = Version(b.u32(172)?);
    check_version(
        version,
        &format!("grid '{}' (file metadata)", crate::text::escape(&name)),
    )?;
    let node_count = [b.u32(140)?, b.u32(144)?, b.u32(148)?, b.u32(152)?];
    let m = GridMeta {
        grid_size: b.u64(0)?,
        file_size: b.u64(8)?,
        offset: 0,
        name_key: b.u64(16)?,
        voxel_count: b.u64(24)?,
        grid_type: b.u32(32)?,
        grid_class: b.u32(36)?,
        world_bbox: [b.vec3d(40)?, b.vec3d(64)?],
        index_bbox: [b.vec3i(88)?, b.vec3i(100)?],
        voxel_size: b.vec3d(112)?,
        node_count,
        tile_count: [b.u32(156)?, b.u32(160)?, b.u32(164)?],
        codec,
        version,
        blob_bytes: 0,
        // Every tree has one root: a root count of 0 says the counts were not written.
        counted: node_count[3] != 0,
        name,
    };
    Ok((m, name_size))
}

/// The sizes of a grid's metadata must be those a grid of its codec can have.
fn check_sizes(g: &GridMeta) -> DecodeResult<()> {
    let name = crate::text::escape(&g.name);
    if g.codec == Codec::None && g.grid_size != g.file_size {
        return Err(DecodeError::invalid(format!(
            "grid '{name}' is stored uncompressed but its grid size ({}) differs from its file \
             size ({})",
            g.grid_size, g.file_size
        )));
    }
    if g.grid_size / MAX_RATIO > g.file_size {
        return Err(DecodeError::invalid(format!(
            "grid '{name}' claims {} bytes from {} compressed ones, more than any codec expands",
            g.grid_size, g.file_size
        )));
    }
    if g.counted && g.name_key != name_hash(&g.name) {
        return Err(DecodeError::invalid(format!(
            "grid '{name}': the name key {:#x} is not the hash of its name",
            g.name_key
        )));
    }
    Ok(())
}

/// `nanovdb::io::stringHash`: `h = h * 67 + byte + (h >> 56)` over the name's bytes.
#[must_use]
pub(crate) fn name_hash(name: &str) -> u64 {
    name.bytes().fold(0u64, |h, c| {
        let overflow = h >> 56;
        h.wrapping_mul(67)
            .wrapping_add(u64::from(c))
            .wrapping_add(overflow)
    })
}

/// Only major version 32 up to minor [`MAX_MINOR`] has a layout umbra reads; `what` names the
/// structure (`grid 'density'`, `file header (segment at byte 0)`).
pub(crate) fn check_version(v: Version, what: &str) -> DecodeResult<()> {
    if v.major() != MAJOR || v.minor() > MAX_MINOR {
        return Err(DecodeError::unsupported(format!(
            "NanoVDB {v} {what}: not supported (umbra reads NanoVDB {MAJOR}.0 to \
             {MAJOR}.{MAX_MINOR}, as OpenVDB 10 to 12, Warp and fVDB write it)"
        )));
    }
    Ok(())
}

fn prefix(e: DecodeError, what: &str) -> DecodeError {
    match e {
        DecodeError::Invalid(m) => DecodeError::Invalid(format!("{what}: {m}")),
        DecodeError::Truncated { msg, need } => DecodeError::Truncated {
            msg: format!("{what}: {msg}"),
            need,
        },
        DecodeError::Unsupported(m) => DecodeError::Unsupported(format!("{what}: {m}")),
    }
}

/// The grid buffer of `g` from its blob (`blob`, `g.file_size` bytes): exactly `g.grid_size`
/// bytes, decompressed as its codec says.
pub(crate) fn grid_buffer(g: &GridMeta, blob: Vec<u8>) -> DecodeResult<Vec<u8>> {
    let want = usize::try_from(g.grid_size)
        .map_err(|_| DecodeError::unsupported("a grid larger than the address space"))?;
    match g.codec {
        Codec::None => Ok(blob),
        Codec::Zip => {
            let b = Bytes::new(&blob);
            let n = b.u64(0)?;
            let src = b.slice(8, n)?;
            if 8 + n != blob.len() as u64 {
                return Err(DecodeError::invalid(format!(
                    "ZIP stream of {n} bytes in a blob of {}",
                    blob.len()
                )));
            }
            inflate(src, want)
        }
        Codec::Blosc => blosc_chunks(&blob, want),
    }
}

/// A ZIP blob's zlib stream, which must expand to exactly `want` bytes: inflated straight from
/// the blob into the buffer (no reader's copy of the input), the buffer grown as the stream
/// expands (the size is the file's claim, not yet a fact).
fn inflate(src: &[u8], want: usize) -> DecodeResult<Vec<u8>> {
    use flate2::{Decompress, FlushDecompress, Status};
    let mut z = Decompress::new(true);
    // One byte past the claim, so that a stream longer than it is seen.
    let limit = want.saturating_add(1);
    let mut out = Vec::with_capacity(limit.min(src.len().saturating_mul(8)));
    loop {
        if out.len() == out.capacity() {
            out.reserve_exact((limit - out.len()).min(out.len().max(1 << 20)));
        }
        let (before_in, before_out) = (z.total_in(), z.total_out());
        let rest = src
            .get(usize::try_from(before_in).unwrap_or(usize::MAX)..)
            .unwrap_or(&[]);
        let status = z
            .decompress_vec(rest, &mut out, FlushDecompress::Finish)
            .map_err(|e| DecodeError::invalid(format!("ZIP stream: {e}")))?;
        let stuck = z.total_in() == before_in && z.total_out() == before_out;
        if status == Status::StreamEnd || out.len() >= limit || stuck {
            break;
        }
    }
    if out.len() != want {
        return Err(DecodeError::invalid(format!(
            "ZIP stream expands to {}{} bytes, the metadata says {want}",
            out.len().min(want),
            if out.len() > want { "+" } else { "" }
        )));
    }
    Ok(out)
}

/// BLOSC blobs: chunks, each after its u64 compressed size, each expanding to the size its own
/// header says (NanoVDB cuts at 2^30 bytes; Warp writes one chunk whatever the size).
fn blosc_chunks(blob: &[u8], want: usize) -> DecodeResult<Vec<u8>> {
    let b = Bytes::new(blob);
    // The chunks' own headers (uncompressed size, u32 at byte 4) must add up to the grid size
    // before the buffer is allocated.
    let (mut at, mut total) = (0u64, 0u64);
    while at < b.len() {
        let n = b.u64(at)?;
        let src = Bytes::new(b.slice(at + 8, n)?);
        total += u64::from(src.u32(4)?);
        at += 8 + n;
    }
    if total != want as u64 {
        return Err(DecodeError::invalid(format!(
            "BLOSC chunks hold {total} bytes, the metadata says {want}"
        )));
    }
    // Each chunk's source and its share of the buffer, in order (the sizes were added up
    // above, so the shares tile the buffer).
    let mut out = vec![0u8; want];
    let mut chunks: Vec<(u64, &[u8], &mut [u8])> = Vec::new();
    let (mut at, mut rest) = (0u64, out.as_mut_slice());
    while !rest.is_empty() {
        let n = b.u64(at)?;
        let src = b.slice(at + 8, n)?;
        let size = (Bytes::new(src).u32(4)? as usize).min(rest.len());
        if size == 0 {
            break;
        }
        let (share, tail) = std::mem::take(&mut rest).split_at_mut(size);
        chunks.push((at, src, share));
        rest = tail;
        at += 8 + n;
    }
    if at != blob.len() as u64 {
        return Err(DecodeError::invalid(format!(
            "BLOSC chunks end at blob byte {at}, the blob has {}",
            blob.len()
        )));
    }
    // Every core busy: the chunks side by side, and each chunk's blocks on c-blosc's own
    // threads (NanoVDB's chunks are 2^30 bytes, Warp's one chunk whatever the size: a single
    // chunk gets all the threads). The bytes are the same whatever the count.
    let threads = (rayon::current_num_threads() / chunks.len().max(1)).max(1);
    let done: Vec<DecodeResult<()>> = {
        use rayon::prelude::*;
        chunks
            .into_par_iter()
            .map(|(at, src, share)| {
                crate::vdb::blosc::decompress_on(src, share, threads)
                    .map_err(|e| prefix(e, &format!("BLOSC chunk at blob byte {at}")))
            })
            .collect()
    };
    done.into_iter().collect::<DecodeResult<()>>()?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(n: u32) -> Vec<u8> {
        (0..n)
            .flat_map(|i| ((i % 977) as f32 * 0.5 + (i / 3000) as f32).to_le_bytes())
            .collect()
    }

    /// A zlib stream inflated into the buffer is the source, whether the buffer starts at its
    /// size or grows (a stream expanding more than 8 times); a claim one byte short or long, or
    /// a cut stream, is refused.
    #[test]
    fn inflate_gives_exactly_the_stream_or_an_error() {
        use std::io::Write;
        for src in [data(1 << 20), vec![7u8; 5 << 20]] {
            let mut enc = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::new(6));
            enc.write_all(&src).unwrap();
            let z = enc.finish().unwrap();
            assert!(inflate(&z, src.len()).unwrap() == src);
            let long = inflate(&z, src.len() - 1).unwrap_err();
            assert!(
                matches!(&long, DecodeError::Invalid(m) if m.contains("expands to") && m.contains("+ bytes")),
                "{long:?}"
            );
            assert!(inflate(&z, src.len() + 1).is_err());
            assert!(inflate(&z[..z.len() / 2], src.len()).is_err());
        }
    }

    /// BLOSC chunks are decompressed side by side, each into its share of the buffer: the
    /// buffer is the chunks' bytes in order whatever the thread count; a blob with bytes after
    /// its chunks, or chunks short of the grid size, is refused.
    #[test]
    fn blosc_chunks_in_parallel_are_the_chunks_in_order() {
        let parts = [data(70_000), data(1 << 18), data(12_345)];
        let mut blob = Vec::new();
        for p in &parts {
            let c = crate::vdb::blosc::compress_for_tests(p, 8 << 10);
            blob.extend_from_slice(&(c.len() as u64).to_le_bytes());
            blob.extend_from_slice(&c);
        }
        let whole = parts.concat();
        for threads in [1, 2, 4] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let out = pool.install(|| blosc_chunks(&blob, whole.len())).unwrap();
            assert!(out == whole, "{threads} threads");
        }
        assert!(blosc_chunks(&blob, whole.len() - 1).is_err());
        let mut longer = blob.clone();
        longer.extend_from_slice(&[0u8; 8]);
        assert!(blosc_chunks(&longer, whole.len()).is_err());
    }

    #[test]
    fn name_hash_is_nanovdbs() {
        assert_eq!(name_hash(""), 0);
        assert_eq!(name_hash("a"), 97);
        assert_eq!(name_hash("ab"), 97 * 67 + 98);
        // From a file nanovdb_convert wrote: "density".
        assert_eq!(name_hash("density"), 0x0000_085a_6c08_0218);
    }

    #[test]
    fn versions_split_and_only_32_up_to_8_is_read() {
        let v = Version(32 << 21 | 4 << 10 | 2);
        assert_eq!((v.major(), v.minor(), v.patch()), (32, 4, 2));
        assert_eq!(v.to_string(), "32.4.2");
        assert!(check_version(v, "x").is_ok());
        assert!(check_version(Version(32 << 21 | 8 << 10 | 3), "x").is_ok());
        assert!(check_version(Version(32 << 21 | 9 << 10), "x").is_err());
        assert!(check_version(Version(31 << 21), "x").is_err());
        let e = check_version(Version(33 << 21), "grid 'd'").unwrap_err();
        assert_eq!(
            e,
            DecodeError::Unsupported(
                "NanoVDB 33.0.0 grid 'd': not supported (umbra reads NanoVDB 32.0 to 32.8, as \
                 OpenVDB 10 to 12, Warp and fVDB write it)"
                    .into()
            )
        );
    }
}

//! The archive layer of a `.vdb` file: header (magic, versions, UUID), file metadata and the grid
//! descriptors with their byte offsets. Grid descriptors are interleaved with grid data
//! (descriptor, grid, next descriptor at the previous grid's `end_pos`), so each one is read from
//! a small window at its own offset; nothing but the header and descriptors is read here.

use super::bytes::ByteReader;
use super::metadata::{read_meta_map, MetaMap};
use crate::error::{DecodeError, DecodeResult, Error, Result};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// `OPENVDB_MAGIC`: the int64 0x56444220 ("VDB " little-endian, then four zero bytes).
pub const VDB_MAGIC: [u8; 8] = [0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0];
/// Oldest file format version umbra decodes (OpenVDB 2.x+ "node mask compression": per-grid
/// compression flags and per-node metadata; every Houdini and OpenVDB release since 2013).
pub const MIN_FILE_VERSION: u32 = 222;
/// Newest file format version known (OpenVDB 6+ "multipass I/O").
pub const MAX_FILE_VERSION: u32 = 224;
/// The separator OpenVDB puts between a grid name and its duplicate index (ASCII RS).
pub const NAME_SEPARATOR: char = '\u{1e}';
const HALF_SUFFIX: &str = "_HalfFloat";

/// Per-grid compression flags (`io::COMPRESS_*`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct Compression {
    /// `COMPRESS_ZIP` (zlib).
    pub zip: bool,
    /// `COMPRESS_ACTIVE_MASK`: inactive values are omitted.
    pub active_mask: bool,
    /// `COMPRESS_BLOSC`.
    pub blosc: bool,
}

impl Compression {
    /// Decode the flag word.
    #[must_use]
    pub fn from_flags(f: u32) -> Self {
        Self {
            zip: f & 1 != 0,
            active_mask: f & 2 != 0,
            blosc: f & 4 != 0,
        }
    }
    /// A human-readable name, as OpenVDB prints it.
    #[must_use]
    pub fn describe(self) -> String {
        let codec = if self.blosc {
            "blosc"
        } else if self.zip {
            "zip"
        } else {
            "none"
        };
        if self.active_mask {
            format!("{codec} + active mask")
        } else {
            codec.to_string()
        }
    }
}

/// One grid's entry in the archive.
#[derive(Debug, Clone)]
pub struct GridDescriptor {
    /// The name as stored, with OpenVDB's `\x1e` duplicate suffix.
    pub stored_name: String,
    /// The name users see: `density`, `density[1]` for duplicates, `[0]` for unnamed grids.
    pub display_name: String,
    /// Tree type name without the `_HalfFloat` suffix, e.g. `Tree_float_5_4_3`.
    pub tree_type: String,
    /// Whether floating-point values are stored as 16-bit halves.
    pub saved_as_half: bool,
    /// Stored name of the grid whose tree this one shares (grid instancing), or empty.
    pub instance_parent: String,
    /// Byte offset of the grid (compression flags, metadata, transform, topology).
    pub grid_pos: u64,
    /// Byte offset of the leaf buffers (for an instanced grid, which has none, the end
    /// offset: OpenVDB stores 0 there).
    pub block_pos: u64,
    /// Byte offset one past the grid.
    pub end_pos: u64,
}

/// Header and grid directory of a `.vdb` file.
#[derive(Debug, Clone)]
pub struct Archive {
    /// Path it was read from.
    pub path: PathBuf,
    /// File size in bytes.
    pub file_len: u64,
    /// File format version (220..=224 supported).
    pub file_version: u32,
    /// Library (major, minor) version that wrote the file.
    pub library_version: (u32, u32),
    /// The file's UUID string.
    pub uuid: String,
    /// File-level metadata.
    pub metadata: MetaMap,
    /// Grids in file order.
    pub grids: Vec<GridDescriptor>,
}

/// Turn OpenVDB's stored unique name into the name users know.
#[must_use]
pub fn display_name(stored: &str) -> String {
    match stored.split_once(NAME_SEPARATOR) {
        Some((base, index)) => format!("{base}[{index}]"),
        None => stored.to_string(),
    }
}

/// Read `len` bytes at `offset` (fewer if the file ends first).
pub(crate) fn read_window(file: &mut File, offset: u64, len: u64, path: &Path) -> Result<Vec<u8>> {
    let io = |err| Error::Io {
        path: path.to_path_buf(),
        err,
    };
    file.seek(SeekFrom::Start(offset)).map_err(io)?;
    let mut buf = Vec::new();
    file.take(len).read_to_end(&mut buf).map_err(io)?;
    Ok(buf)
}

/// Parse the bytes `[offset, limit)` of `file` through a window that starts at `first` bytes
/// and grows (at least fourfold, or to what the parser asked for) while the parser runs out of
/// bytes. A field that needs bytes past `limit` fails at once, before anything that size is
/// read: no corrupt length makes umbra read more of a file than the region it belongs to, and
/// what it reads is what the parser consumed (within a factor of four). `region` names the
/// limit in the error ("the file", "grid 'density'").
pub(crate) fn parse_window<T>(
    file: &mut File,
    (offset, limit): (u64, u64),
    first: u64,
    region: &str,
    path: &Path,
    mut parse: impl FnMut(&mut ByteReader<'_>) -> DecodeResult<T>,
) -> Result<(T, u64)> {
    let mut len = first.min(limit.saturating_sub(offset));
    loop {
        let buf = read_window(file, offset, len, path)?;
        let mut r = ByteReader::new(&buf, offset);
        match parse(&mut r) {
            Ok(v) => return Ok((v, r.offset())),
            Err(DecodeError::Truncated { msg, need }) => {
                if need > limit {
                    return Err(DecodeError::invalid(format!(
                        "{msg}, past the end of {region} at offset {limit}"
                    ))
                    .at(path));
                }
                if (buf.len() as u64) < len {
                    return Err(DecodeError::invalid(format!(
                        "{msg}, but the file ends at offset {}",
                        offset + buf.len() as u64
                    ))
                    .at(path));
                }
                len = len.saturating_mul(4).max(need - offset).min(limit - offset);
            }
            Err(e) => return Err(e.at(path)),
        }
    }
}

/// The smallest grid descriptor: three empty strings (u32 lengths) and three i64 offsets.
const MIN_DESCRIPTOR_BYTES: u64 = 3 * 4 + 3 * 8;
/// The smallest grid: compression flags and an empty metadata map (u32 each), then at least a
/// transform type name's length.
const MIN_GRID_BYTES: u64 = 3 * 4;
/// First window for a descriptor: names are short, and a file of many tiny grids must not cost
/// a large read per grid.
const DESCRIPTOR_WINDOW: u64 = 512;

impl Archive {
    /// Open `path` and read its header and grid directory.
    ///
    /// # Errors
    /// [`Error::Io`] if the file cannot be read, [`Error::NotVdb`] for a directory, an empty or
    /// short file or a wrong magic number, [`Error::Unsupported`] for format versions outside
    /// 220..=224 or streams without grid offsets, [`Error::Invalid`] for corrupt or truncated data.
    pub fn open(path: &Path) -> Result<Self> {
        let not_vdb = |reason: &str| Error::NotVdb {
            path: path.to_path_buf(),
            format: "VDB",
            reason: reason.to_string(),
        };
        let io = |err| Error::Io {
            path: path.to_path_buf(),
            err,
        };
        let meta = std::fs::metadata(path).map_err(io)?;
        if meta.is_dir() {
            return Err(not_vdb("it is a directory"));
        }
        let mut file = File::open(path).map_err(io)?;
        let file_len = meta.len();
        let head = read_window(&mut file, 0, 8, path)?;
        if head.len() < 8 {
            return Err(not_vdb(&format!(
                "{} bytes long, shorter than the 8-byte magic number",
                head.len()
            )));
        }
        if head[..] != VDB_MAGIC {
            return Err(not_vdb("bad magic number"));
        }
        let (header, mut pos) = parse_window(
            &mut file,
            (8, file_len),
            1 << 16,
            "the file",
            path,
            read_header,
        )?;
        let Header {
            file_version,
            library_version,
            has_offsets,
            uuid,
            metadata,
            grid_count: count,
        } = header;
        if !has_offsets {
            return Err(Error::Unsupported {
                path: path.to_path_buf(),
                what: "VDB stream without grid offsets".into(),
            });
        }
        // Every grid takes at least a descriptor and a minimal grid, so a count the rest of the
        // file cannot hold is refused before anything is allocated or read.
        let room = (file_len - pos) / (MIN_DESCRIPTOR_BYTES + MIN_GRID_BYTES);
        if u64::from(count) > room {
            return Err(DecodeError::invalid(format!(
                "the header says {count} grids, but the {} bytes after it can hold at most {room}",
                file_len - pos
            ))
            .at(path));
        }
        let mut grids = Vec::new();
        for i in 0..count {
            let (gd, desc_end) = parse_window(
                &mut file,
                (pos, file_len),
                DESCRIPTOR_WINDOW,
                "the file",
                path,
                read_descriptor,
            )?;
            validate_offsets(&gd, i, count, desc_end, file_len).map_err(|e| e.at(path))?;
            pos = gd.end_pos;
            grids.push(gd);
        }
        Ok(Self {
            path: path.to_path_buf(),
            file_len,
            file_version,
            library_version,
            uuid,
            metadata,
            grids,
        })
    }

    /// Find a grid by display name (`density[1]`), stored name (`density\x1e1`), or plain base
    /// name when exactly one grid has it.
    ///
    /// # Errors
    /// [`Error::GridNotFound`] listing the available display names.
    pub fn find_grid(&self, name: &str) -> Result<&GridDescriptor> {
        let exact = self
            .grids
            .iter()
            .find(|g| g.display_name == name || g.stored_name == name);
        if let Some(g) = exact {
            return Ok(g);
        }
        let base: Vec<&GridDescriptor> = self
            .grids
            .iter()
            .filter(|g| g.stored_name.split(NAME_SEPARATOR).next() == Some(name))
            .collect();
        if let [only] = base.as_slice() {
            return Ok(only);
        }
        Err(Error::GridNotFound {
            path: self.path.clone(),
            name: name.to_string(),
            available: self.grids.iter().map(|g| g.display_name.clone()).collect(),
        })
    }
}

struct Header {
    file_version: u32,
    library_version: (u32, u32),
    has_offsets: bool,
    uuid: String,
    metadata: MetaMap,
    grid_count: u32,
}

fn read_header(r: &mut ByteReader<'_>) -> DecodeResult<Header> {
    let file_version = r.u32("file version")?;
    if !(MIN_FILE_VERSION..=MAX_FILE_VERSION).contains(&file_version) {
        return Err(DecodeError::unsupported(format!(
            "file format version {file_version} (umbra reads {MIN_FILE_VERSION} to {MAX_FILE_VERSION})"
        )));
    }
    let library_version = (r.u32("library version")?, r.u32("library version")?);
    let has_offsets = r.u8("grid offsets flag")? != 0;
    let uuid = String::from_utf8_lossy(r.take(36, "UUID")?).into_owned();
    let metadata = read_meta_map(r)?;
    let count = r.i32("grid count")?;
    let grid_count = u32::try_from(count)
        .map_err(|_| DecodeError::invalid(format!("negative grid count {count}")))?;
    Ok(Header {
        file_version,
        library_version,
        has_offsets,
        uuid,
        metadata,
        grid_count,
    })
}

fn read_descriptor(r: &mut ByteReader<'_>) -> DecodeResult<GridDescriptor> {
    let stored_name = r.string("grid name")?;
    let mut tree_type = r.string("grid type")?;
    let saved_as_half = tree_type.ends_with(HALF_SUFFIX);
    if saved_as_half {
        tree_type.truncate(tree_type.len() - HALF_SUFFIX.len());
    }
    let instance_parent = r.string("instance parent")?;
    let mut pos = |what| -> DecodeResult<u64> {
        let v = r.i64(what)?;
        u64::try_from(v).map_err(|_| DecodeError::invalid(format!("negative {what} {v}")))
    };
    let grid_pos = pos("grid position")?;
    let mut block_pos = pos("block position")?;
    let end_pos = pos("end position")?;
    // OpenVDB writes block position 0 for an instanced grid (it has no topology or buffers):
    // its head (metadata and transform) runs to the end position.
    if !instance_parent.is_empty() && block_pos == 0 {
        block_pos = end_pos;
    }
    Ok(GridDescriptor {
        display_name: display_name(&stored_name),
        stored_name,
        tree_type,
        saved_as_half,
        instance_parent,
        grid_pos,
        block_pos,
        end_pos,
    })
}

/// A grid's offsets must follow its descriptor in order (`desc_end <= grid_pos <= block_pos <=
/// end_pos <= file length`, with room for a minimal grid), so the descriptor chain only moves
/// forward: it cannot point back at itself or loop, and its length is bounded by the file's.
fn validate_offsets(
    gd: &GridDescriptor,
    index: u32,
    count: u32,
    desc_end: u64,
    file_len: u64,
) -> DecodeResult<()> {
    let name = crate::text::escape(&gd.display_name);
    let (g, b, e) = (gd.grid_pos, gd.block_pos, gd.end_pos);
    if g < desc_end {
        return Err(DecodeError::invalid(format!(
            "grid {index} of {count} ('{name}') starts at offset {g}, inside or before its own \
             descriptor (which ends at {desc_end}): the grid descriptors loop"
        )));
    }
    if !(g <= b && b <= e && e <= file_len) {
        return Err(DecodeError::invalid(format!(
            "grid {index} of {count} ('{name}') has offsets grid {g} / block {b} / end {e} out of \
             order or outside the file ({file_len} bytes)"
        )));
    }
    if b - g < MIN_GRID_BYTES {
        return Err(DecodeError::invalid(format!(
            "grid {index} of {count} ('{name}') spans {} bytes (offsets {g} to {b}), too few for \
             its compression flags, metadata and transform",
            b - g
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_names_follow_vdb_print() {
        assert_eq!(display_name("density"), "density");
        assert_eq!(display_name("density\u{1e}1"), "density[1]");
        assert_eq!(display_name("\u{1e}0"), "[0]");
    }

    #[test]
    fn compression_flags() {
        let c = Compression::from_flags(6);
        assert!(c.blosc && c.active_mask && !c.zip);
        assert_eq!(c.describe(), "blosc + active mask");
    }
}

//! Decode one grid's topology and leaf buffers straight into umbra's flat [`Tree`]: a single
//! depth-first pass over the topology (root table, upper nodes, lower nodes, leaf masks), then
//! the leaf buffers, which OpenVDB writes in the same depth-first order. The topology comes
//! from memory; the leaf buffers are streamed from the file through a [`BufferWindow`] (1 MiB at
//! a time), so a load never holds the whole compressed grid next to the decoded tree.

use super::bytes::ByteReader;
use super::values::{
    read_compressed_values, skip_compressed_values, Pick, PrecisionLoss, StreamInfo, ValueKind,
};
use crate::error::{DecodeError, DecodeResult, Error, Result};
use crate::tree::{Bounds, Internal, Leaf, RootEntry, RootSlot, Tree, UNLOADED};
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

/// Bytes of leaf buffers read from the file at a time.
const WINDOW: usize = 1 << 20;

/// The leaf buffers `[start, end)` of a grid, read from the file window by window.
#[derive(Debug)]
pub(crate) struct BufferWindow<'f> {
    file: &'f mut std::fs::File,
    path: &'f Path,
    /// File bytes from `base`.
    buf: Vec<u8>,
    base: u64,
    /// Bytes of `buf` already decoded.
    used: usize,
    end: u64,
}

impl<'f> BufferWindow<'f> {
    /// The region `[start, end)` of `file`.
    pub(crate) fn new(file: &'f mut std::fs::File, path: &'f Path, start: u64, end: u64) -> Self {
        Self {
            file,
            path,
            buf: Vec::new(),
            base: start,
            used: 0,
            end,
        }
    }

    /// Run `f` on a reader at the next undecoded byte. If `f` runs out of bytes before the end
    /// of the region, the window is refilled (and grown) and `f` runs again from the same byte.
    fn read<T>(&mut self, mut f: impl FnMut(&mut ByteReader<'_>) -> DecodeResult<T>) -> Result<T> {
        loop {
            let mut r = ByteReader::new(&self.buf[self.used..], self.base + self.used as u64);
            match f(&mut r) {
                Ok(v) => {
                    self.used = usize::try_from(r.offset() - self.base).unwrap_or(usize::MAX);
                    return Ok(v);
                }
                Err(DecodeError::Truncated { msg, need }) => {
                    if need > self.end {
                        return Err(DecodeError::invalid(format!(
                            "{msg}, past the end of the grid's leaf buffers at offset {}",
                            self.end
                        ))
                        .at(self.path));
                    }
                    self.refill(need)?;
                }
                Err(e) => return Err(e.at(self.path)),
            }
        }
    }

    /// The file offset of the next undecoded byte.
    pub(crate) fn position(&self) -> u64 {
        self.base + self.used as u64
    }

    fn loaded_end(&self) -> u64 {
        self.base + self.buf.len() as u64
    }

    /// Drop the decoded bytes, then read at least a window (or twice what is left undecoded,
    /// or up to `need`, the offset the decoder asked for) up to the end of the region.
    fn refill(&mut self, need: u64) -> Result<()> {
        self.buf.drain(..self.used);
        self.base += self.used as u64;
        self.used = 0;
        let at = self.loaded_end();
        let want = (WINDOW as u64)
            .max(2 * self.buf.len() as u64)
            .max(need.saturating_sub(at))
            .min(self.end - at);
        let io = |err| Error::Io {
            path: self.path.to_path_buf(),
            err,
        };
        self.file.seek(SeekFrom::Start(at)).map_err(io)?;
        let got = (&mut *self.file)
            .take(want)
            .read_to_end(&mut self.buf)
            .map_err(|err| Error::Io {
                path: self.path.to_path_buf(),
                err,
            })?;
        if (got as u64) < want {
            return Err(DecodeError::invalid(format!(
                "the leaf buffers end at offset {} but the file has only {} bytes",
                self.end,
                at + got as u64
            ))
            .at(self.path));
        }
        Ok(())
    }
}

/// A grid's topology, decoded: the tree without leaf values, the leaves' origins and masks in
/// buffer order, and the stream settings the buffers are decoded with.
pub(crate) struct Topology {
    tree: Tree,
    leaves: Vec<LeafTopology>,
    stream: StreamInfo,
}

/// Decode the topology from `r`, which must end exactly at `block_pos`, where the descriptor
/// says the buffers start; vector values (background, tiles, and later the leaves) as `pick`
/// says. A truncation is returned as such (with the offset it needs), so a
/// windowed reader can grow its window; past `block_pos` it is the caller's error to report.
pub(crate) fn read_topology(
    r: &mut ByteReader<'_>,
    kind: ValueKind,
    pick: Pick,
    half: bool,
    compression: super::Compression,
    block_pos: u64,
) -> DecodeResult<Topology> {
    let (tree, leaves, stream) = decode_topology(r, kind, pick, half, compression, block_pos)?;
    Ok(Topology {
        tree,
        leaves,
        stream,
    })
}

impl Topology {
    /// The index box of every leaf and every non-background tile (as
    /// [`crate::Volume::value_box`]), without the leaf values.
    pub(crate) fn value_box(&self) -> Option<[[i64; 3]; 2]> {
        crate::tree::value_box_of(&self.tree, self.leaves.iter().map(|(o, _)| *o))
    }
}

impl Topology {
    /// The tree with every leaf present and unloaded (no values), the stream settings, and
    /// the leaves' masks in buffer order (leaf `i` of the tree is buffer `i`).
    pub(crate) fn into_parts(self) -> (Tree, StreamInfo) {
        let Topology {
            mut tree,
            leaves,
            stream,
        } = self;
        tree.leaves.reserve_exact(leaves.len());
        tree.leaves
            .extend(leaves.into_iter().map(|(origin, value_mask)| Leaf {
                origin,
                value_mask,
                bounds: Bounds::EMPTY,
                halo: Bounds::EMPTY,
                data: UNLOADED,
            }));
        (tree, stream)
    }
}

/// Find where every leaf's buffer starts, without decoding any: `offsets[i]` for leaf `i` of
/// `tree` (buffer order), then the end of the last one. Each buffer's header is parsed (value
/// mask, metadata byte, inactive values, selection mask, the size prefix of its value run) and
/// its values are stepped over. The value mask must match the topology's.
pub(crate) fn locate_buffers(
    tree: &Tree,
    s: &StreamInfo,
    buffers: &mut BufferWindow<'_>,
) -> Result<Vec<u64>> {
    let mut offsets = Vec::with_capacity(tree.leaves.len() + 1);
    for leaf in &tree.leaves {
        let at = buffers.read(|r| {
            let at = r.offset();
            let mask = read_buffer_mask(r, leaf)?;
            if s.kind == ValueKind::Bool {
                r.skip(12 + 64, "bool leaf origin and values")?;
            } else {
                skip_compressed_values(r, s, &mask)?;
            }
            Ok(at)
        })?;
        offsets.push(at);
    }
    offsets.push(buffers.position());
    Ok(offsets)
}

/// Where every leaf's buffer starts, from OpenVDB's `file_delayed_load` table instead of a
/// pass over the buffers: the table holds, per leaf, its metadata byte (which inactive values
/// and selection mask follow the value mask) and the byte size of its value run (size prefix
/// included). A buffer is then `64` (value mask) `+ 1 + inactive values + selection mask + run`
/// bytes. `None` when the table is malformed, is for another leaf count, the grid is not
/// compressed, or the sizes do not add up to exactly the grid's buffer region `[start, end)`:
/// the caller then scans ([`locate_buffers`]).
pub(crate) fn offsets_from_table(
    table: &[u8],
    tree: &Tree,
    s: &StreamInfo,
    start: u64,
    end: u64,
) -> Option<Vec<u64>> {
    if s.kind == ValueKind::Bool || !(s.compression.blosc || s.compression.zip) {
        return None;
    }
    let n = tree.leaves.len();
    if n == 0 {
        // OpenVDB writes an empty table for a grid without leaves.
        return (start == end).then(|| vec![start]);
    }
    let mut r = ByteReader::new(table, 0);
    let count = r.u32("delayed-load count").ok()? as usize;
    if count != n {
        return None;
    }
    let section = |r: &mut ByteReader<'_>, width: usize| -> Option<Vec<u8>> {
        let bytes = r.u32("delayed-load section size").ok()?;
        let mut out = vec![0u8; n.checked_mul(width)?];
        if bytes == u32::MAX {
            return None;
        }
        if bytes > 0 {
            // OpenVDB pads short buffers before compressing them (to 128 bytes): the chunk
            // may hold more than the table needs; its own header says how much.
            let src = r.take(bytes as usize, "delayed-load section").ok()?;
            let held = u32::from_le_bytes(src.get(4..8)?.try_into().ok()?) as usize;
            if held < out.len() || held > out.len() + TABLE_PAD {
                return None;
            }
            let mut all = vec![0u8; held];
            super::blosc::decompress_into(src, &mut all).ok()?;
            let len = out.len();
            out.copy_from_slice(&all[..len]);
        } else {
            let len = out.len();
            out.copy_from_slice(r.take(len, "delayed-load section").ok()?);
        }
        Some(out)
    };
    let metas = section(&mut r, 1)?;
    let sizes = section(&mut r, 8)?;
    let value = s.kind.size() as u64;
    let mut offsets = Vec::with_capacity(n + 1);
    let mut at = start;
    for (k, &meta) in metas.iter().enumerate() {
        offsets.push(at);
        let mut b = [0u8; 8];
        b.copy_from_slice(&sizes[8 * k..8 * k + 8]);
        let run = u64::try_from(i64::from_le_bytes(b)).ok()?;
        let (inactive, selection) = match meta {
            0 | 1 | 6 => (0, 0),
            2 => (1, 0),
            3 => (0, 64),
            4 => (1, 64),
            5 => (2, 64),
            _ => return None,
        };
        at = at
            .checked_add(64 + 1 + inactive * value + selection)?
            .checked_add(run)?;
    }
    offsets.push(at);
    (at == end).then_some(offsets)
}

/// Most padding a `file_delayed_load` section may carry past the bytes it describes.
const TABLE_PAD: usize = 4096;

/// Bytes of leaf buffers one decoding task reads at a time (one positioned read).
const TASK_BYTES: u64 = 1 << 20;
/// Below this many leaves a load decodes on the calling thread.
const PARALLEL_LEAVES: usize = 2048;

/// Decode the buffers of the leaves `ids` (increasing) of `tree` into `out` (one block per
/// id), reading `file` by positioned reads (runs of consecutive leaves, up to about 1 MiB per
/// read), on all of rayon's threads when there are many. Errors name the file, the leaf and
/// the byte offset of its buffer.
pub(crate) fn decode_leaves(
    file: &std::fs::File,
    path: &Path,
    stream: Stream,
    tree: &Tree,
    offsets: &[u64],
    ids: &[u32],
    out: &mut [[f32; 512]],
) -> Result<Option<PrecisionLoss>> {
    debug_assert_eq!(ids.len(), out.len());
    // Runs of consecutive leaves, each with its slice of `out`.
    let mut tasks = Vec::new();
    let mut rest = out;
    let mut i = 0;
    while i < ids.len() {
        let mut j = i + 1;
        while j < ids.len()
            && ids[j] == ids[j - 1] + 1
            && offsets[ids[j] as usize + 1] - offsets[ids[i] as usize] <= TASK_BYTES
        {
            j += 1;
        }
        let (head, tail) = std::mem::take(&mut rest).split_at_mut(j - i);
        tasks.push((&ids[i..j], head));
        rest = tail;
        i = j;
    }
    let run = |(run, dest): (&[u32], &mut [[f32; 512]])| -> Result<PrecisionLoss> {
        let s = stream.info();
        let (a, b) = (
            offsets[run[0] as usize],
            offsets[run[run.len() - 1] as usize + 1],
        );
        READ_BUFFER.with_borrow_mut(|bytes| -> Result<PrecisionLoss> {
            read_at(file, path, a, b - a, bytes)?;
            for (&l, d) in run.iter().zip(dest.iter_mut()) {
                let leaf = &tree.leaves[l as usize];
                let at = offsets[l as usize];
                let end = offsets[l as usize + 1];
                let lo = usize::try_from(at - a).unwrap_or(usize::MAX);
                let hi = usize::try_from(end - a).unwrap_or(usize::MAX);
                let mut r = ByteReader::new(&bytes[lo..hi], at);
                read_leaf_buffer(&mut r, &s, leaf, d).map_err(|e| {
                    let why = match e {
                        DecodeError::Invalid(m) | DecodeError::Truncated { msg: m, .. } => m,
                        DecodeError::Unsupported(m) => m,
                    };
                    DecodeError::invalid(format!(
                        "leaf at {:?} (buffer at byte offset {at}): {why}",
                        leaf.origin
                    ))
                    .at(path)
                })?;
            }
            Ok(s.precision.get())
        })
    };
    let parts: Vec<PrecisionLoss> = if ids.len() >= PARALLEL_LEAVES {
        use rayon::prelude::*;
        tasks.into_par_iter().map(run).collect::<Result<_>>()?
    } else {
        tasks.into_iter().map(run).collect::<Result<_>>()?
    };
    if stream.kind != ValueKind::Double || stream.half {
        return Ok(None);
    }
    let mut p = PrecisionLoss::default();
    for q in parts {
        p.merge(q);
    }
    Ok(Some(p))
}

thread_local! {
    /// Each decoding thread's read buffer, reused from run to run (a fresh megabyte per run
    /// was a megabyte of page faults per run).
    static READ_BUFFER: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Read `len` bytes of `file` from byte `at` into `buf` (a positioned read: no shared cursor,
/// so any number of threads read one file at once).
fn read_at(file: &std::fs::File, path: &Path, at: u64, len: u64, buf: &mut Vec<u8>) -> Result<()> {
    let n = usize::try_from(len).map_err(|_| {
        DecodeError::invalid(format!("a leaf buffer run of {len} bytes at offset {at}")).at(path)
    })?;
    buf.resize(n, 0);
    positioned_read(file, buf, at).map_err(|err| Error::Io {
        path: path.to_path_buf(),
        err,
    })
}

/// Read exactly `buf.len()` bytes of `file` at byte `at`, without moving a shared cursor (so
/// threads may read one file at once): `pread` on Unix, `seek_read` in a loop on Windows.
#[cfg(unix)]
pub(crate) fn positioned_read(
    file: &std::fs::File,
    buf: &mut [u8],
    at: u64,
) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, at)
}

/// As the Unix version: `seek_read` until `buf` is full.
#[cfg(windows)]
pub(crate) fn positioned_read(
    file: &std::fs::File,
    mut buf: &mut [u8],
    mut at: u64,
) -> std::io::Result<()> {
    while !buf.is_empty() {
        let n = std::os::windows::fs::FileExt::seek_read(file, buf, at)?;
        if n == 0 {
            return Err(std::io::ErrorKind::UnexpectedEof.into());
        }
        buf = &mut buf[n..];
        at += n as u64;
    }
    Ok(())
}

/// The settings a leaf decoder needs, without the per-thread scratch of [`StreamInfo`] (so
/// that decoding tasks on several threads can each make their own).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Stream {
    pub(crate) kind: ValueKind,
    pub(crate) pick: Pick,
    pub(crate) half: bool,
    pub(crate) compression: super::Compression,
    pub(crate) background: f32,
}

impl Stream {
    /// The settings of `s`.
    pub(crate) fn of(s: &StreamInfo) -> Self {
        Self {
            kind: s.kind,
            pick: s.pick,
            half: s.half,
            compression: s.compression,
            background: s.background,
        }
    }
    /// A fresh decoder state (no precision tracked yet, empty scratch).
    pub(crate) fn info(self) -> StreamInfo {
        StreamInfo {
            kind: self.kind,
            pick: self.pick,
            half: self.half,
            compression: self.compression,
            background: self.background,
            precision: std::cell::Cell::default(),
            scratch: std::cell::RefCell::default(),
        }
    }
}

/// The topology: the tree without leaf values, the leaves' origins and masks, and the stream
/// settings the buffers are decoded with (vector values as `pick` says).
fn decode_topology(
    r: &mut ByteReader<'_>,
    kind: ValueKind,
    pick: Pick,
    half: bool,
    compression: super::Compression,
    block_pos: u64,
) -> DecodeResult<(Tree, Vec<LeafTopology>, StreamInfo)> {
    let buffer_count = r.i32("tree buffer count")?;
    if buffer_count != 1 {
        return Err(DecodeError::unsupported(format!(
            "multi-buffer tree ({buffer_count} buffers)"
        )));
    }
    let bg_bytes = r.take(kind.size(), "background value")?;
    let background = kind.decode(bg_bytes, pick);
    let s = StreamInfo {
        kind,
        pick,
        half,
        compression,
        background,
        precision: std::cell::Cell::default(),
        scratch: std::cell::RefCell::default(),
    };
    s.track_doubles(bg_bytes);
    let mut tree = Tree {
        background,
        ..Tree::default()
    };
    let num_tiles = r.u32("root tile count")?;
    let num_children = r.u32("root child count")?;
    for _ in 0..num_tiles {
        let origin = r.vec3i("root tile origin")?;
        let bytes = r.take(kind.size(), "root tile value")?;
        s.track_doubles(bytes);
        let value = kind.decode(bytes, pick);
        let active = r.u8("root tile state")? != 0;
        tree.root.push(RootEntry {
            origin,
            slot: RootSlot::Tile { value, active },
        });
    }
    // Leaf origins and masks first; the leaves themselves are allocated once, at their exact
    // count, when their buffers are read.
    let mut leaf_topo = Vec::new();
    for _ in 0..num_children {
        let origin = r.vec3i("root child origin")?;
        let index = read_internal(r, &s, &mut tree, &mut leaf_topo, origin, Level::Upper)?;
        tree.root.push(RootEntry {
            origin,
            slot: RootSlot::Child(index),
        });
    }
    for e in &tree.root {
        if e.origin.iter().any(|c| c & 4095 != 0) {
            return Err(DecodeError::invalid(format!(
                "root entry origin {:?} is not a multiple of 4096",
                e.origin
            )));
        }
    }
    tree.root.sort_by_key(|e| e.origin);
    if tree.root.windows(2).any(|w| w[0].origin == w[1].origin) {
        return Err(DecodeError::invalid("two root entries share an origin"));
    }
    if r.offset() != block_pos {
        return Err(DecodeError::invalid(format!(
            "topology ends at offset {} but the grid descriptor puts the leaf buffers at {block_pos}",
            r.offset()
        )));
    }
    Ok((tree, leaf_topo, s))
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Level {
    Upper,
    Lower,
}

impl Level {
    /// (log2 of slots per side, log2 of child edge in voxels, slot count)
    fn shape(self) -> (u32, u32, usize) {
        match self {
            Self::Upper => (5, 7, 32768),
            Self::Lower => (4, 3, 4096),
        }
    }
}

/// `InternalNode::readTopology`: child mask, value mask, tile values, then each child.
fn read_internal(
    r: &mut ByteReader<'_>,
    s: &StreamInfo,
    tree: &mut Tree,
    leaf_topo: &mut Vec<LeafTopology>,
    origin: [i32; 3],
    level: Level,
) -> DecodeResult<u32> {
    let (side_log2, child_log2, n) = level.shape();
    let words = n / 64;
    let mut child_mask = vec![0u64; words].into_boxed_slice();
    let mut value_mask = vec![0u64; words].into_boxed_slice();
    r.u64_words(&mut child_mask, "internal node child mask")?;
    r.u64_words(&mut value_mask, "internal node value mask")?;
    let mut values = vec![0f32; n];
    read_compressed_values(r, s, &value_mask, &mut values)?;
    let mut slots: Box<[u32]> = values.iter().map(|v| v.to_bits()).collect();
    drop(values);
    let side_mask = (1usize << side_log2) - 1;
    for (w, &word) in child_mask.iter().enumerate() {
        let mut bits = word;
        while bits != 0 {
            let slot = w * 64 + bits.trailing_zeros() as usize;
            bits &= bits - 1;
            let local = [
                slot >> (2 * side_log2),
                (slot >> side_log2) & side_mask,
                slot & side_mask,
            ];
            let child_origin =
                [0, 1, 2].map(|a| origin[a].wrapping_add((local[a] as i32) << child_log2));
            slots[slot] = match level {
                Level::Upper => read_internal(r, s, tree, leaf_topo, child_origin, Level::Lower)?,
                Level::Lower => read_leaf_topology(r, leaf_topo, child_origin)?,
            };
        }
    }
    let node = Internal::unbounded(origin, child_mask, value_mask, slots);
    let list = match level {
        Level::Upper => &mut tree.uppers,
        Level::Lower => &mut tree.lowers,
    };
    let index = u32::try_from(list.len())
        .map_err(|_| DecodeError::unsupported("more than 2^32 internal nodes"))?;
    list.push(node);
    Ok(index)
}

/// A leaf's origin and value mask, from the topology.
type LeafTopology = ([i32; 3], [u64; 8]);

/// `LeafNode::readTopology`: just the value mask; values come with the buffers.
fn read_leaf_topology(
    r: &mut ByteReader<'_>,
    leaf_topo: &mut Vec<LeafTopology>,
    origin: [i32; 3],
) -> DecodeResult<u32> {
    let mut value_mask = [0u64; 8];
    r.u64_words(&mut value_mask, "leaf value mask")?;
    let index = u32::try_from(leaf_topo.len())
        .map_err(|_| DecodeError::unsupported("more than 2^32 leaves"))?;
    leaf_topo.push((origin, value_mask));
    Ok(index)
}

/// The value mask at the start of a leaf's buffer, which must equal the topology's.
fn read_buffer_mask(r: &mut ByteReader<'_>, leaf: &Leaf) -> DecodeResult<[u64; 8]> {
    let at = r.offset();
    let mut mask = [0u64; 8];
    r.u64_words(&mut mask, "leaf buffer value mask")?;
    if mask != leaf.value_mask {
        return Err(DecodeError::invalid(format!(
            "leaf at {:?}: value mask in the buffers (offset {at}) differs from the topology",
            leaf.origin
        )));
    }
    Ok(mask)
}

/// `LeafNode::readBuffers`: the value mask again, then the values (bool leaves: origin and a
/// value bit mask instead), into `out`.
fn read_leaf_buffer(
    r: &mut ByteReader<'_>,
    s: &StreamInfo,
    leaf: &Leaf,
    out: &mut [f32; 512],
) -> DecodeResult<()> {
    let mask = read_buffer_mask(r, leaf)?;
    if s.kind == ValueKind::Bool {
        r.skip(12, "bool leaf origin")?;
        let mut bits = [0u64; 8];
        r.u64_words(&mut bits, "bool leaf values")?;
        for (i, v) in out.iter_mut().enumerate() {
            *v = f32::from(u8::from(crate::tree::bit(&bits, i)));
        }
        return Ok(());
    }
    read_compressed_values(r, s, &mask, out)
}

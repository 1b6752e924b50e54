//! NanoVDB's grid checksum (`GridChecksum.h`): a u64 at byte 8 of the grid buffer holding two
//! CRC-32s (the IEEE polynomial `0xEDB88320`, as zlib's `crc32`), the *head* in its low half and
//! the *tail* in its high half. All 64 bits set: no checksum; only the tail's bits set: a
//! *partial* checksum (`CheckMode::Partial`, the head alone); otherwise a *full* one. What each
//! half covers depends on the grid's version:
//!
//! - up to 32.4: the head is the CRC-32 of the buffer from byte 16 (after the magic and the
//!   checksum) to the end of the root's tiles (`672 + 64 + sizeof(RootData) + 32 x tiles`); the
//!   tail is the CRC-32 of an array holding the CRC-32 of each upper node, then each lower node,
//!   then each leaf (in memory order; a node's `sizeof`, so 96 bytes for an FpN leaf), stored as
//!   `std::uint_fast32_t`: 8 bytes each on the 64-bit Linux and macOS that write these files, 4
//!   on Windows and from NanoVDB 32.7 on (both are accepted);
//! - 32.5 to 32.6.0: the head runs from byte 16 to the tree header's offset of the upper nodes
//!   (with none: to the blind metadata, or the end of the grid); the tail is the *blocked* CRC-32
//!   of the rest of the grid. Since NanoVDB 32.7 computes these grids' tail the 32.4 way, both
//!   are accepted;
//! - after 32.6.0: the head covers the grid and tree headers only (bytes 16 to 736); the tail is
//!   the blocked CRC-32 of bytes 736 to the grid's end (nodes and blind data).
//!
//! What a matching checksum covered is its [`Coverage`]: a 32.4 tail (and a 32.5/32.6 grid
//! checked that way) takes each node's `sizeof`, so an FpN leaf's codes after its first 96
//! bytes, blind data and padding are in no CRC, and the coverage counts them (docs/loading.md).
//!
//! The blocked CRC-32 of `n` bytes is the CRC-32 of the array of the CRC-32s (u32 each) of its
//! `n >> 12` blocks of 4096 bytes, the last block taking the remainder.

use super::bytes::Bytes;
use super::file::Version;
use super::layout::{GridHead, Layout, BREADTH_FIRST, GRID_BYTES, TILE_BYTES, TREE_BYTES};
use super::tree::{leaf_size, Nodes};
use crate::error::DecodeResult;

/// "Not computed": all bits of a CRC half set.
const EMPTY: u32 = u32::MAX;
/// Bytes of a block of the blocked CRC-32 (`NANOVDB_CRC32_LOG2_BLOCK_SIZE` = 12).
const BLOCK_LOG2: u32 = 12;
/// 32.6.0, the last version whose checksum is not the 32.7 one.
const V32_6_0: Version = Version(32 << 21 | 6 << 10);
/// 32.5.0, the first version whose checksum may be blocked.
const V32_5_0: Version = Version(32 << 21 | 5 << 10);

/// Which bytes of a grid buffer a matching checksum covers. The 16 bytes of the magic number
/// and the checksum itself are never covered (the magic is checked by parsing), so a grid of
/// `n` bytes has `grid = n - 16` bytes a checksum can cover and `grid - checked` it does not.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Coverage {
    /// Bytes the checksum covered.
    pub checked: u64,
    /// Bytes of the grid buffer after its magic number and checksum.
    pub grid: u64,
    /// Of the bytes not covered, those of FpN leaves' codes (values umbra decodes): a tail of
    /// the 32.4 kind takes each leaf's `sizeof`, 96 bytes for FpN, so the `64 x bits` bytes of
    /// codes after them are in no CRC (NanoVDB's own `nanovdb_validate` passes a flipped code).
    pub codes: u64,
}

impl Coverage {
    /// Bytes of the grid buffer not covered: `grid - checked`.
    #[must_use]
    pub fn unchecked(&self) -> u64 {
        self.grid.saturating_sub(self.checked)
    }
}

/// What checking a grid's checksum found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Checksum {
    /// The file carries a full checksum (head and tail) and the grid matches both. Every byte
    /// of the grid after the magic and the checksum is covered (a 32.7 tail), or every byte
    /// of the headers, the root and each node's `sizeof` (a 32.4 tail: FpN leaves' codes, blind
    /// data and padding are not): the [`Coverage`] says which.
    Full(Coverage),
    /// The file carries a partial checksum (NanoVDB's default `CheckMode::Partial`: the head
    /// alone) and the grid matches it: only the headers (and before 32.7 the root) were
    /// checked, not the nodes. Also what a full checksum umbra cannot recompute gives (a 32.4
    /// tail of nodes not laid out breadth-first): its head matched.
    Partial(Coverage),
    /// The file carries none (all bits set).
    Absent,
    /// The file's checksum and the grid disagree: what disagrees.
    Mismatch(String),
}

impl Checksum {
    /// `full`, `partial`, `absent` or `mismatch`.
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            Self::Full(_) => "full",
            Self::Partial(_) => "partial",
            Self::Absent => "absent",
            Self::Mismatch(_) => "mismatch",
        }
    }

    /// Which bytes a matching checksum covered (`None` when absent or mismatched).
    #[must_use]
    pub fn coverage(&self) -> Option<Coverage> {
        match self {
            Self::Full(c) | Self::Partial(c) => Some(*c),
            Self::Absent | Self::Mismatch(_) => None,
        }
    }
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = flate2::Crc::new();
    c.update(bytes);
    c.sum()
}

/// NanoVDB's blocked CRC-32 of `bytes`.
fn blocked_crc32(bytes: &[u8]) -> u32 {
    let count = bytes.len() >> BLOCK_LOG2;
    let block = 1usize << BLOCK_LOG2;
    let crcs: Vec<u8> = (0..count)
        .flat_map(|i| {
            let end = if i + 1 == count {
                bytes.len()
            } else {
                (i + 1) * block
            };
            crc32(&bytes[i * block..end]).to_le_bytes()
        })
        .collect();
    crc32(&crcs)
}

/// Check the checksum of the grid buffer `b` (headers `h`, nodes at `nodes`).
pub(crate) fn check(
    b: &Bytes<'_>,
    h: &GridHead,
    l: &Layout,
    nodes: &Nodes,
) -> DecodeResult<Checksum> {
    let head = h.checksum as u32;
    let tail = (h.checksum >> 32) as u32;
    if head == EMPTY && tail == EMPTY {
        return Ok(Checksum::Absent);
    }
    let root_end = GRID_BYTES + TREE_BYTES + l.root_bytes + nodes.table_size * TILE_BYTES;
    // Where the head ends (and a blocked tail starts), by version. 32.6 ends it at the first
    // upper node's offset (set even with no upper node: then the root's), else at the blind
    // metadata, else at the end of the grid.
    let mid_32_6 = if h.node_offset[2] != 0 {
        nodes.first[0]
    } else if h.blind_count > 0 {
        u64::try_from(h.blind_offset).unwrap_or(u64::MAX)
    } else {
        b.len()
    };
    let heads: &[u64] = if h.version > V32_6_0 {
        &[GRID_BYTES + TREE_BYTES]
    } else if h.version >= V32_5_0 {
        &[mid_32_6, root_end]
    } else {
        &[root_end]
    };
    let mut got = 0;
    let mut head_end = None;
    for &end in heads {
        let Ok(bytes) = b.slice(16, end.saturating_sub(16)) else {
            continue;
        };
        got = crc32(bytes);
        if got == head {
            head_end = Some(end);
            break;
        }
    }
    let Some(head_end) = head_end else {
        return Ok(Checksum::Mismatch(format!(
            "the head checksum is {head:#010x} but the grid's headers hash to {got:#010x}"
        )));
    };
    let grid = b.len().saturating_sub(16);
    let head_only = Coverage {
        checked: head_end.saturating_sub(16).min(grid),
        grid,
        codes: 0,
    };
    if tail == EMPTY {
        return Ok(Checksum::Partial(head_only));
    }
    // Each candidate tail with what it covers.
    let mut candidates = Vec::new();
    if h.version >= V32_5_0 {
        let every = Coverage {
            checked: grid,
            grid,
            codes: 0,
        };
        candidates.push((blocked_crc32(b.slice(head_end, b.len() - head_end)?), every));
    }
    if h.version <= V32_6_0 {
        // The 32.4 tail needs NanoVDB's traversal order: every NanoVDB writer lays nodes out
        // breadth-first.
        if h.flags & BREADTH_FIRST == 0 {
            return Ok(Checksum::Partial(head_only));
        }
        let covered = node_coverage(b, l, nodes, h.node_count, head_end)?;
        for crc in node_tails(b, l, nodes, h.node_count)? {
            candidates.push((crc, covered));
        }
    }
    match candidates.iter().find(|(crc, _)| *crc == tail) {
        Some((_, covered)) => Ok(Checksum::Full(*covered)),
        None => Ok(Checksum::Mismatch(format!(
            "the tail checksum is {tail:#010x} but the nodes hash to {:#010x}",
            candidates.first().map(|c| c.0).unwrap_or_default()
        ))),
    }
}

/// What the head (bytes 16 to `head_end`) and a 32.4 tail (each node's `sizeof` bytes) cover
/// together: the union of those ranges, and the FpN codes after each leaf's 96 bytes.
fn node_coverage(
    b: &Bytes<'_>,
    l: &Layout,
    nodes: &Nodes,
    counts: [u32; 3],
    head_end: u64,
) -> DecodeResult<Coverage> {
    let mut ranges = vec![(16, head_end)];
    for (level, size) in [(2usize, l.node_bytes[0]), (1, l.node_bytes[1])] {
        let first = nodes.first[2 - level];
        let n = u64::from(counts[level]);
        if n > 0 {
            ranges.push((first, first.saturating_add(n.saturating_mul(size))));
        }
    }
    let mut codes = 0u64;
    for &at in &nodes.leaves {
        ranges.push((at, at.saturating_add(l.leaf_bytes)));
        codes += leaf_size(b, l, at)?.saturating_sub(l.leaf_bytes);
    }
    ranges.sort_unstable();
    let (mut checked, mut reach) = (0u64, 0u64);
    for (start, end) in ranges {
        let end = end.min(b.len());
        let start = start.max(reach);
        if end > start {
            checked += end - start;
            reach = end;
        }
    }
    Ok(Coverage {
        checked,
        grid: b.len().saturating_sub(16),
        codes,
    })
}

/// The 32.4 tail: the CRC-32 of each node's CRC-32, stored 8 bytes and 4 bytes each.
fn node_tails(
    b: &Bytes<'_>,
    l: &Layout,
    nodes: &Nodes,
    counts: [u32; 3],
) -> DecodeResult<[u32; 2]> {
    let mut crcs = Vec::new();
    for (level, size) in [(2usize, l.node_bytes[0]), (1, l.node_bytes[1])] {
        let first = nodes.first[2 - level];
        for i in 0..u64::from(counts[level]) {
            crcs.push(crc32(b.slice(first + i * size, size)?));
        }
    }
    for &at in &nodes.leaves {
        crcs.push(crc32(b.slice(at, l.leaf_bytes)?));
    }
    let wide: Vec<u8> = crcs
        .iter()
        .flat_map(|c| u64::from(*c).to_le_bytes())
        .collect();
    let narrow: Vec<u8> = crcs.iter().flat_map(|c| c.to_le_bytes()).collect();
    Ok([crc32(&wide), crc32(&narrow)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocked_crc_takes_the_remainder_in_the_last_block() {
        let data: Vec<u8> = (0..10_000u32).map(|i| (i * 7 % 256) as u8).collect();
        let want = {
            let mut crcs = crc32(&data[..4096]).to_le_bytes().to_vec();
            crcs.extend(crc32(&data[4096..]).to_le_bytes());
            crc32(&crcs)
        };
        assert_eq!(blocked_crc32(&data), want);
        // Shorter than a block: no blocks, the CRC-32 of nothing.
        assert_eq!(blocked_crc32(&data[..100]), 0);
    }
}

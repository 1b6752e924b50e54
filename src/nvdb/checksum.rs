//! NanoVDB's grid checksum (`nanovdb/util/GridChecksum.h`, 32.4): a u64 at byte 8 of the grid
//! buffer holding two CRC-32s (the IEEE polynomial `0xEDB88320`, as zlib's `crc32`), the *head*
//! in its low half and the *tail* in its high half; `0xFFFFFFFF` in a half means "not computed".
//!
//! - head: the CRC-32 of the grid buffer from byte 16 (after the magic and the checksum) to the
//!   end of the root's tiles: `672 (GridData) + 64 (TreeData) + sizeof(RootData) + 32 x tiles`;
//! - tail (the "full" mode only): each upper node, then each lower node, then each leaf (in
//!   memory order; a node's `sizeof`, so 96 bytes for an FpN leaf) gets its own CRC-32; the
//!   tail is the CRC-32 of that array of CRCs stored as `std::uint_fast32_t`, 8 bytes each on
//!   the 64-bit Linux and macOS that write these files (4 on Windows: both are accepted).

use super::bytes::Bytes;
use super::layout::{Layout, BREADTH_FIRST, GRID_BYTES, TILE_BYTES, TREE_BYTES};
use super::tree::Nodes;
use crate::error::DecodeResult;

/// "Not computed": all bits of a CRC half set.
const EMPTY: u32 = u32::MAX;

/// What checking a grid's checksum found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Checksum {
    /// The file carries a checksum and the grid matches it (the head, and the tail when
    /// present).
    Checked,
    /// The file carries none (all bits set).
    Absent,
    /// The file's checksum and the grid disagree: what disagrees.
    Mismatch(String),
}

impl Checksum {
    /// `checked`, `absent` or `mismatch`.
    #[must_use]
    pub fn name(&self) -> &'static str {
        match self {
            Self::Checked => "checked",
            Self::Absent => "absent",
            Self::Mismatch(_) => "mismatch",
        }
    }
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = flate2::Crc::new();
    c.update(bytes);
    c.sum()
}

/// Check the checksum of the grid buffer `b` (flags `flags`, nodes at `nodes`).
pub(crate) fn check(
    b: &Bytes<'_>,
    stored: u64,
    flags: u32,
    l: &Layout,
    nodes: &Nodes,
    counts: [u32; 3],
) -> DecodeResult<Checksum> {
    let head = stored as u32;
    let tail = (stored >> 32) as u32;
    if head == EMPTY && tail == EMPTY {
        return Ok(Checksum::Absent);
    }
    let end = GRID_BYTES + TREE_BYTES + l.root_bytes + nodes.table_size * TILE_BYTES;
    let got = crc32(b.slice(16, end.saturating_sub(16))?);
    if got != head {
        return Ok(Checksum::Mismatch(format!(
            "the head checksum is {head:#010x} but the grid, tree and root hash to {got:#010x}"
        )));
    }
    // A tail of a layout other than breadth-first would need NanoVDB's traversal order; every
    // NanoVDB writer lays nodes out breadth-first.
    if tail == EMPTY || flags & BREADTH_FIRST == 0 || counts.iter().all(|&c| c == 0) {
        return Ok(Checksum::Checked);
    }
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
    if crc32(&wide) == tail || crc32(&narrow) == tail {
        Ok(Checksum::Checked)
    } else {
        Ok(Checksum::Mismatch(format!(
            "the tail checksum is {tail:#010x} but the nodes hash to {:#010x}",
            crc32(&wide)
        )))
    }
}

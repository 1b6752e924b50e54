//! Decode a NanoVDB grid buffer's tree into umbra's flat [`Tree`]: the root table, then each
//! upper node, lower node and leaf depth-first from it, each at an offset checked to be one of
//! the nodes of its level (every node reached exactly once, so a file cannot make a node count
//! twice), each node's stored origin checked against the slot it hangs from. Values become `f32`
//! as NanoVDB returns them: quantised leaves `code * quantum + minimum` in `f32`, doubles
//! rounded, Vec3f their length or one component (a [`Pick`]). Bounds are computed from the values afterwards
//! ([`Tree::compute_bounds`]), never taken from the file's min/max.

use super::bytes::{invalid, Bytes};
use super::layout::{GridHead, Layout, Leaves, GRID_BYTES, TILE_BYTES};
use crate::error::DecodeResult;
use crate::tree::{Bounds, Internal, Leaf, RootEntry, RootSlot, Tree};
use crate::vdb::{Pick, PrecisionLoss, ValueKind};

/// Where each level's nodes are in the buffer.
pub(crate) struct Nodes {
    /// Absolute offset of the first upper and lower node.
    pub(crate) first: [u64; 2],
    /// Absolute offset of every leaf, increasing.
    pub(crate) leaves: Vec<u64>,
    /// Absolute offset of the root.
    pub(crate) root: u64,
    /// Root tiles.
    pub(crate) table_size: u64,
}

/// Locate the nodes of every level from the tree header, each level's nodes within the buffer.
pub(crate) fn locate(b: &Bytes<'_>, h: &GridHead, l: &Layout) -> DecodeResult<Nodes> {
    let tree = GRID_BYTES;
    let abs = |k: usize| tree.checked_add(h.node_offset[k]);
    // Offsets in the buffer, so that the small constants added to them cannot overflow.
    let root = abs(3)
        .filter(|&r| r <= b.len())
        .ok_or_else(|| invalid("the root offset points outside the grid buffer"))?;
    let table_size = u64::from(b.u32(root + 24)?);
    b.slice(root, l.root_bytes + table_size * TILE_BYTES)?;
    let mut first = [0u64; 2];
    for (i, k) in [(0usize, 2usize), (1, 1)] {
        let n = u64::from(h.node_count[k]);
        let at = abs(k).ok_or_else(|| invalid("node offset overflows"))?;
        if n > 0 {
            let bytes = n
                .checked_mul(l.node_bytes[i])
                .ok_or_else(|| invalid("node count overflows"))?;
            b.slice(at, bytes).map_err(|_| {
                invalid(format!(
                    "{n} {} nodes of {} bytes at byte {at} do not fit in the grid buffer of {} \
                     bytes",
                    ["upper", "lower"][i],
                    l.node_bytes[i],
                    b.len()
                ))
            })?;
        }
        first[i] = at;
    }
    let leaves = leaf_offsets(b, h, l)?;
    Ok(Nodes {
        first,
        leaves,
        root,
        table_size,
    })
}

/// The offset of every leaf: fixed-size leaves one after the other, FpN leaves each as long as
/// its own bit width says.
fn leaf_offsets(b: &Bytes<'_>, h: &GridHead, l: &Layout) -> DecodeResult<Vec<u64>> {
    let n = h.node_count[0] as usize;
    let mut at = GRID_BYTES
        .checked_add(h.node_offset[0])
        .filter(|&a| a <= b.len())
        .ok_or_else(|| invalid("the leaf offset points outside the grid buffer"))?;
    // Every leaf is at least 96 bytes: a count the buffer cannot hold is refused before any
    // allocation.
    if (n as u64).saturating_mul(96) > b.len() {
        return Err(invalid(format!(
            "{n} leaves cannot fit in a grid buffer of {} bytes",
            b.len()
        )));
    }
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let size = leaf_size(b, l, at)?;
        b.slice(at, size).map_err(|_| {
            invalid(format!(
                "leaf {i} of {size} bytes at byte {at} runs past the end of the grid buffer \
                 ({} bytes)",
                b.len()
            ))
        })?;
        out.push(at);
        at += size;
    }
    Ok(out)
}

/// FpN's bit width from a leaf's flags: `1 << (flags >> 5)`, 1 to 16 bits.
fn fpn_bits(b: &Bytes<'_>, at: u64) -> DecodeResult<u32> {
    let shift = b.u8(at + 15)? >> 5;
    if shift > 4 {
        return Err(invalid(format!(
            "FpN leaf at byte {at}: bit width 2^{shift} (NanoVDB writes 1 to 16 bits)"
        )));
    }
    Ok(1 << shift)
}

/// Bytes of the leaf at `at`: its layout's, or for FpN 96 and its own codes.
pub(crate) fn leaf_size(b: &Bytes<'_>, l: &Layout, at: u64) -> DecodeResult<u64> {
    Ok(match l.leaves {
        Leaves::Variable => 96 + 64 * u64::from(fpn_bits(b, at)?),
        _ => l.leaf_bytes,
    })
}

/// The decoded tree, with what decoding it counted.
pub(crate) struct Decoded {
    pub tree: Tree,
    pub precision: Option<PrecisionLoss>,
    /// Active voxels, tiles counting the voxels they cover.
    pub voxels: u64,
    /// Active tiles in lower nodes, upper nodes and the root.
    pub tiles: [u64; 3],
}

/// The decoder's state: the buffer, the layout, where the nodes are and which were reached.
struct Decoder<'a> {
    b: Bytes<'a>,
    l: Layout,
    nodes: &'a Nodes,
    /// What of a Vec3f value the tree holds.
    pick: Pick,
    counts: [u32; 3],
    seen: [Vec<bool>; 3],
    tree: Tree,
    precision: PrecisionLoss,
    voxels: u64,
    tiles: [u64; 3],
    /// Each leaf's byte offset, in leaf order: their values are decoded after the walk, on
    /// every core ([`leaf_values`]).
    leaf_at: Vec<u64>,
}

/// Leaves per parallel work item of the value decode.
const LEAF_CHUNK: usize = 256;

/// Decode the tree of the grid buffer `b` whose headers are `h`, Vec3f values as `pick` says.
pub(crate) fn decode(
    b: &Bytes<'_>,
    h: &GridHead,
    l: &Layout,
    nodes: &Nodes,
    pick: Pick,
) -> DecodeResult<Decoded> {
    let mut precision = PrecisionLoss::default();
    let background = decode_value(b, l, nodes.root + l.root_background, pick, &mut precision)?;
    let mut d = Decoder {
        b: *b,
        l: *l,
        nodes,
        pick,
        counts: h.node_count,
        seen: [
            vec![false; h.node_count[0] as usize],
            vec![false; h.node_count[1] as usize],
            vec![false; h.node_count[2] as usize],
        ],
        tree: Tree {
            background,
            ..Tree::default()
        },
        precision,
        voxels: 0,
        tiles: [0; 3],
        leaf_at: Vec::new(),
    };
    // Exact capacities (the counts fit the buffer, `locate` checked): no growth slack held.
    let [leaves, lowers, uppers] = h.node_count.map(|c| c as usize);
    d.tree.leaves.reserve_exact(leaves);
    d.leaf_at.reserve_exact(leaves);
    d.tree.lowers.reserve_exact(lowers);
    d.tree.uppers.reserve_exact(uppers);
    d.tree.root.reserve_exact(nodes.table_size as usize);
    for t in 0..nodes.table_size {
        d.root_tile(t)?;
    }
    d.tree.root.sort_by_key(|e| e.origin);
    if d.tree.root.windows(2).any(|w| w[0].origin == w[1].origin) {
        return Err(invalid("two root tiles share an origin"));
    }
    for (k, name) in ["leaves", "lower nodes", "upper nodes"].iter().enumerate() {
        let reached = d.seen[k].iter().filter(|&&s| s).count();
        if reached != d.seen[k].len() {
            return Err(invalid(format!(
                "the tree header counts {} {name} but {reached} hang from the root",
                d.seen[k].len()
            )));
        }
    }
    // The leaves' values, on every core: each chunk of leaves is decoded by one worker into
    // its own slots, so the tree is the serial walk's, bit for bit, whatever the thread count;
    // the first error in leaf order is the one reported. The slots are allocated zeroed (the
    // allocator's fresh pages, no pass over them), so each page is first touched by the worker
    // that fills it, on every core.
    d.tree.values = vec![[0f32; 512]; d.leaf_at.len()];
    let (values, at) = (&mut d.tree.values, &d.leaf_at);
    let parts: Vec<DecodeResult<PrecisionLoss>> = {
        use rayon::prelude::*;
        values
            .par_chunks_mut(LEAF_CHUNK)
            .zip(at.par_chunks(LEAF_CHUNK))
            .map(|(vals, ats)| {
                let mut p = PrecisionLoss::default();
                for (v, &a) in vals.iter_mut().zip(ats) {
                    leaf_values(b, l, pick, a, v, &mut p)?;
                }
                Ok(p)
            })
            .collect()
    };
    for part in parts {
        d.precision.merge(part?);
    }
    let precision = (l.kind == ValueKind::Double).then_some(d.precision);
    d.tree.compute_bounds();
    Ok(Decoded {
        tree: d.tree,
        precision,
        voxels: d.voxels,
        tiles: d.tiles,
    })
}

/// One value of the grid's value type at `at` (a Vec3f: what `pick` says), doubles tracked.
fn decode_value(
    b: &Bytes<'_>,
    l: &Layout,
    at: u64,
    pick: Pick,
    p: &mut PrecisionLoss,
) -> DecodeResult<f32> {
    let bytes = b.slice(at, l.value)?;
    if l.kind == ValueKind::Double {
        p.add(b.f64(at)?);
    }
    Ok(l.kind.decode(bytes, pick))
}

impl Decoder<'_> {
    fn root_tile(&mut self, t: u64) -> DecodeResult<()> {
        let at = self.nodes.root + self.l.root_bytes + t * TILE_BYTES;
        let key = self.b.u64(at)?;
        if key >> 63 != 0 {
            return Err(invalid(format!(
                "root tile {t}: key {key:#x} has its top bit set"
            )));
        }
        let coord = |shift: u32| (((key >> shift) & 0x1f_ffff) << 12) as u32 as i32;
        let origin = [coord(42), coord(21), coord(0)];
        let child = self.b.i64(at + 8)?;
        let slot = if child == 0 {
            let active = self.b.u32(at + 16)? != 0;
            let value = decode_value(
                &self.b,
                &self.l,
                at + self.l.tile_value,
                self.pick,
                &mut self.precision,
            )?;
            if active {
                self.tiles[2] += 1;
                self.voxels = self.voxels.saturating_add(1 << 36);
            }
            RootSlot::Tile { value, active }
        } else {
            let node = self.child_at(self.nodes.root, child, 2)?;
            RootSlot::Child(self.internal(node, origin, 2)?)
        };
        self.tree.root.push(RootEntry { origin, slot });
        Ok(())
    }

    /// The absolute offset `base + rel` as node `index` of level `level` (0 leaf, 1 lower, 2
    /// upper), marked reached; an offset that is no node of the level, or one reached before,
    /// is an error.
    fn child_at(&mut self, base: u64, rel: i64, level: usize) -> DecodeResult<u64> {
        let at = base.checked_add_signed(rel);
        let index = at.and_then(|at| match level {
            0 => self.nodes.leaves.binary_search(&at).ok(),
            _ => {
                let size = self.l.node_bytes[2 - level];
                let off = at.checked_sub(self.nodes.first[2 - level])?;
                (off % size == 0).then_some((off / size) as usize)
            }
        });
        let names = ["leaf", "lower node", "upper node"];
        let Some(i) = index.filter(|&i| i < self.counts[level] as usize) else {
            return Err(invalid(format!(
                "a child offset {rel} from byte {base} is not a {} of the tree",
                names[level]
            )));
        };
        if std::mem::replace(&mut self.seen[level][i], true) {
            return Err(invalid(format!(
                "{} {i} hangs from two parents",
                names[level]
            )));
        }
        Ok(at.unwrap_or_default())
    }

    /// The node at `at` must be the one whose origin its parent's slot says.
    fn check_origin(&self, at: u64, want: [i32; 3], dim: i32) -> DecodeResult<()> {
        let stored = self.b.vec3i(at)?.map(|c| c & !(dim - 1));
        if stored != want {
            return Err(invalid(format!(
                "node at byte {at} has origin {stored:?} but hangs where {want:?} belongs"
            )));
        }
        Ok(())
    }

    /// An upper (`level` 2) or lower (1) node at `at`, origin `origin`: its index in umbra's
    /// node list.
    fn internal(&mut self, at: u64, origin: [i32; 3], level: usize) -> DecodeResult<u32> {
        let (log2, child_log2, n) = if level == 2 {
            (5, 7, 32768)
        } else {
            (4, 3, 4096)
        };
        self.check_origin(at, origin, 1 << (log2 + child_log2))?;
        let mask_bytes = n as u64 / 8;
        let value_mask = self.b.word_slice(at + 32, n / 64)?;
        let child_mask = self.b.word_slice(at + 32 + mask_bytes, n / 64)?;
        let table = at + self.l.table[2 - level];
        let mut slots = vec![0u32; n].into_boxed_slice();
        for (s, slot) in slots.iter_mut().enumerate() {
            let e = table + s as u64 * self.l.entry;
            if crate::tree::bit(&child_mask, s) {
                let side = (1usize << log2) - 1;
                let local = [s >> (2 * log2), (s >> log2) & side, s & side];
                let o = [0, 1, 2].map(|a| origin[a].wrapping_add((local[a] as i32) << child_log2));
                let rel = self.b.i64(e)?;
                let child = self.child_at(at, rel, level - 1)?;
                *slot = if level == 2 {
                    self.internal(child, o, 1)?
                } else {
                    self.leaf(child, o)?
                };
            } else {
                let v = decode_value(&self.b, &self.l, e, self.pick, &mut self.precision)?;
                if crate::tree::bit(&value_mask, s) {
                    self.tiles[level - 1] += 1;
                    self.voxels = self.voxels.saturating_add(1 << (3 * child_log2));
                }
                *slot = v.to_bits();
            }
        }
        let node = Internal::unbounded(origin, child_mask, value_mask, slots);
        let list = if level == 2 {
            &mut self.tree.uppers
        } else {
            &mut self.tree.lowers
        };
        let index = u32::try_from(list.len()).map_err(|_| invalid("more than 2^32 nodes"))?;
        list.push(node);
        Ok(index)
    }

    /// The leaf at `at`, origin `origin`: its index in umbra's leaf list.
    fn leaf(&mut self, at: u64, origin: [i32; 3]) -> DecodeResult<u32> {
        self.check_origin(at, origin, 8)?;
        let value_mask = self.b.words::<8>(at + 16)?;
        self.voxels = self
            .voxels
            .saturating_add(value_mask.iter().map(|w| u64::from(w.count_ones())).sum());
        let index =
            u32::try_from(self.tree.leaves.len()).map_err(|_| invalid("too many leaves"))?;
        self.tree.leaves.push(Leaf {
            origin,
            value_mask,
            bounds: Bounds::EMPTY,
            halo: Bounds::EMPTY,
            data: index,
        });
        // Its values come after the walk, in parallel ([`leaf_values`]).
        self.leaf_at.push(at);
        Ok(index)
    }
}

/// The 512 values of the leaf at byte `at` into `out`, doubles' precision tracked in `p`.
fn leaf_values(
    b: &Bytes<'_>,
    l: &Layout,
    pick: Pick,
    at: u64,
    out: &mut [f32; 512],
    p: &mut PrecisionLoss,
) -> DecodeResult<()> {
    let codes = at + l.leaf_values;
    match l.leaves {
        Leaves::Raw => {
            // One bounds check for the leaf's 512 values, then a pass over them.
            let bytes = b.slice(codes, 512 * l.value)?;
            let each = bytes.chunks_exact(l.value as usize);
            match l.kind {
                ValueKind::Float => {
                    for (v, c) in out.iter_mut().zip(each) {
                        *v = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                    }
                }
                ValueKind::Double => {
                    for (v, c) in out.iter_mut().zip(each) {
                        let d =
                            f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]);
                        p.add(d);
                        *v = l.kind.decode(c, pick);
                    }
                }
                kind => {
                    for (v, c) in out.iter_mut().zip(each) {
                        *v = kind.decode(c, pick);
                    }
                }
            }
            Ok(())
        }
        Leaves::Fixed(bits) => dequantise(b, at, bits, out),
        Leaves::Variable => dequantise(b, at, fpn_bits(b, at)?, out),
    }
}

/// Quantised leaf values: code `i` is bits `[i w, (i + 1) w)` of the little-endian code
/// array at byte 96 (`w` = `bits`); its value `code * quantum + minimum`, in `f32` as
/// NanoVDB computes it (`LeafData<Fp4..FpN>::getValue`).
fn dequantise(b: &Bytes<'_>, at: u64, bits: u32, out: &mut [f32; 512]) -> DecodeResult<()> {
    let minimum = b.f32(at + 80)?;
    let quantum = b.f32(at + 84)?;
    let codes = b.slice(at + 96, 64 * u64::from(bits))?;
    let mask = (1u32 << bits) - 1;
    for (i, v) in out.iter_mut().enumerate() {
        let bit = i * bits as usize;
        let byte = bit / 8;
        let word = if bits == 16 {
            u32::from(u16::from_le_bytes([codes[byte], codes[byte + 1]]))
        } else {
            u32::from(codes[byte]) >> (bit % 8)
        };
        let code = word & mask;
        *v = code as f32 * quantum + minimum;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A raw leaf's values read in one pass are those read value by value ([`decode_value`]),
    /// bit for bit, for float, double (with the same precision tally) and Vec3f (length and
    /// components).
    #[test]
    fn raw_leaf_values_in_one_pass_are_the_values_one_by_one() {
        for code in [1, 2, 6] {
            let l = Layout::of(code).unwrap();
            let n = (l.leaf_values + 512 * l.value) as usize;
            // Bytes that make finite values of every type, some negative, some tiny.
            let buf: Vec<u8> = (0..n as u32)
                .map(|i| match i % 8 {
                    3 | 7 => (i % 61) as u8,
                    _ => (i.wrapping_mul(2_654_435_761) >> 24) as u8,
                })
                .collect();
            let b = Bytes::new(&buf);
            for pick in [Pick::Length, Pick::Component(1), Pick::Component(2)] {
                let (mut fast, mut p_fast) = ([0f32; 512], PrecisionLoss::default());
                leaf_values(&b, &l, pick, 0, &mut fast, &mut p_fast).unwrap();
                let mut p_one = PrecisionLoss::default();
                for (i, v) in fast.iter().enumerate() {
                    let at = l.leaf_values + i as u64 * l.value;
                    let one = decode_value(&b, &l, at, pick, &mut p_one).unwrap();
                    assert_eq!(
                        v.to_bits(),
                        one.to_bits(),
                        "type {code}, {pick:?}, value {i}"
                    );
                }
                assert_eq!(p_fast, p_one, "type {code}");
            }
            let short = Bytes::new(&buf[..n - 1]);
            let mut out = [0f32; 512];
            assert!(leaf_values(
                &short,
                &l,
                Pick::Length,
                0,
                &mut out,
                &mut PrecisionLoss::default()
            )
            .is_err());
        }
    }
}

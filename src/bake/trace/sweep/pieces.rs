//! The sweep's pieces: the `8^3` blocks a map's rays cross, what each adds ([`Part`]), the
//! pixels it may cover, and their bins by band of rows.

use super::rays::Rays;
use crate::regular::kernel::{blocks_around, fill, kernel_ok, max_chord, BLOCK};
use crate::tree::{Accessor, Block, RootSlot, Tree};
use crate::volume::Volume;

/// What a block adds to the rays crossing it.
#[derive(Debug, Clone, Copy)]
pub(super) enum Part {
    /// `mu x chord`.
    Const(f64),
    /// The exact integral of a leaf's field (`fast`: on the f32 kernel).
    Leaf { leaf: u32, fast: bool },
    /// The exact integral of a lower node's tile slot with a varying halo.
    Tile { lower: u32, slot: u32, fast: bool },
    /// The exact integral of an 8^3 block outside every lower node (in a tile of an upper node
    /// or an empty root cell) whose corners on its + faces read a lower node's values.
    Shell { fast: bool },
}

/// One block of the sweep.
#[derive(Debug, Clone, Copy)]
pub(super) struct Piece {
    pub(super) part: Part,
    /// Lookup-space origin of its `[o, o + 8]^3` box.
    pub(super) origin: [i64; 3],
    /// Pixels `[i0, i1] x [j0, j1]` it may cover.
    pub(super) rect: [u32; 4],
}

/// Every block of every lower node the ray walk would enter, in tree order; then, with
/// `shells`, the blocks outside lower nodes whose trilinear corners read them (sorted by
/// origin).
pub(super) fn pieces(vol: &Volume, rays: &Rays, shells: bool) -> Vec<Piece> {
    let tree = vol.tree();
    let entered = entered_lowers(tree, 0..tree.lowers.len());
    let mut out = Vec::new();
    let mut outside = std::collections::BTreeSet::new();
    for l in 0..tree.lowers.len() {
        if lower_pieces(vol, rays, l, &mut out) && shells {
            shell_blocks(&entered, tree.lowers[l].origin.map(i64::from), &mut outside);
        }
    }
    if shells {
        shell_pieces(vol, rays, &outside, &mut out);
    }
    out
}

/// The origins of the lower nodes among `lowers` a ray walk would enter (halo not just the
/// background).
fn entered_lowers(
    tree: &Tree,
    lowers: impl Iterator<Item = usize>,
) -> std::collections::HashSet<[i32; 3]> {
    lowers
        .map(|l| &tree.lowers[l])
        .filter(|n| entered(tree, n))
        .map(|n| n.origin)
        .collect()
}

/// Whether a ray walk would enter lower node `n` of `tree` (its halo is not just the
/// background).
pub(super) fn entered(tree: &Tree, n: &crate::tree::Internal) -> bool {
    !(n.halo.min == tree.background && n.halo.max == tree.background)
}

/// The pieces of lower node `l` (every child block whose halo is not a zero extinction, and
/// whose footprint meets the image) appended to `out`, in slot order; false when the walk
/// would not enter the node or the map does not see it.
pub(super) fn lower_pieces(vol: &Volume, rays: &Rays, l: usize, out: &mut Vec<Piece>) -> bool {
    let tree = vol.tree();
    let node = &tree.lowers[l];
    let bg = tree.background;
    if !entered(tree, node) {
        return false;
    }
    if rays.footprint(node.origin.map(i64::from), 128).is_none() {
        return false;
    }
    let scale = vol.density_scale();
    let mu_bg = vol.mu_background();
    let chord = max_chord(vol);
    let base = node.origin.map(i64::from);
    for slot in 0..4096usize {
        let local = [slot >> 8, (slot >> 4) & 15, slot & 15];
        let origin = [0, 1, 2].map(|a| base[a] + 8 * local[a] as i64);
        let child = node.has_child(slot).then(|| node.slots[slot]);
        let h = match child {
            Some(leaf) => tree.leaves[leaf as usize].halo,
            None => node.tile_halo_of(slot),
        };
        let part = if h.min == h.max {
            let mu = if h.min == bg {
                mu_bg
            } else {
                crate::math::scaled(scale, f64::from(h.min))
            };
            if mu == 0.0 {
                continue;
            }
            Part::Const(mu)
        } else {
            let fast = kernel_ok(h.min, h.max, chord);
            match child {
                Some(leaf) => Part::Leaf { leaf, fast },
                None => Part::Tile {
                    lower: l as u32,
                    slot: slot as u32,
                    fast,
                },
            }
        };
        if let Some(rect) = rays.footprint(origin, 8) {
            out.push(Piece { part, origin, rect });
        }
    }
    true
}

/// The shell blocks `outside` (see [`shell_blocks`]) that hold something other than the
/// background and meet the image, appended to `out` in their (sorted) order.
pub(super) fn shell_pieces(
    vol: &Volume,
    rays: &Rays,
    outside: &std::collections::BTreeSet<[i64; 3]>,
    out: &mut Vec<Piece>,
) {
    let tree = vol.tree();
    let bg = tree.background;
    let chord = max_chord(vol);
    let mut acc = Accessor::new(tree);
    let mut block = [0f32; BLOCK];
    for &origin in outside {
        let probe = Piece {
            part: Part::Shell { fast: false },
            origin,
            rect: [0; 4],
        };
        fill(&neighbourhood(tree, &mut acc, &probe), &mut block);
        let (lo, hi) = block
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        if lo == hi && lo == bg {
            continue;
        }
        if let Some(rect) = rays.footprint(origin, 8) {
            let part = Part::Shell {
                fast: kernel_ok(lo, hi, chord),
            };
            out.push(Piece { part, origin, rect });
        }
    }
}

/// The 8^3 blocks before lower node `base` (on its - sides: faces, edges, corner) that lie in
/// no entered lower node: their dual cells on the + faces read `base`'s first voxels.
pub(super) fn shell_blocks(
    entered: &std::collections::HashSet<[i32; 3]>,
    base: [i64; 3],
    out: &mut std::collections::BTreeSet<[i64; 3]>,
) {
    for bits in 1..8i64 {
        let step = [bits >> 2, (bits >> 1) & 1, bits & 1];
        let lower = [0, 1, 2].map(|a| base[a] - 128 * step[a]);
        let inside = lower.map(i32::try_from).iter().all(Result::is_ok)
            && entered.contains(&lower.map(|c| c as i32));
        if inside {
            continue;
        }
        // The blocks of that neighbour touching `base`: the last block on each stepped axis,
        // every block on the others.
        let span = |a: usize| if step[a] == 1 { 15..16 } else { 0..16 };
        for x in span(0) {
            for y in span(1) {
                for z in span(2) {
                    out.insert([lower[0] + 8 * x, lower[1] + 8 * y, lower[2] + 8 * z]);
                }
            }
        }
    }
}

/// True when a ray can meet a non-zero extinction outside lower nodes other than in the shell
/// blocks ([`shell_blocks`]): a non-zero background, or a root or upper-node tile other than
/// the background. Then the rays are walked for everything outside lower nodes (shells
/// included) instead.
pub(super) fn needs_rest(vol: &Volume) -> bool {
    let tree = vol.tree();
    let bg = tree.background;
    if vol.mu_background() != 0.0 {
        return true;
    }
    let root_tile = tree
        .root
        .iter()
        .any(|e| matches!(e.slot, RootSlot::Tile { value, .. } if value != bg));
    let upper = tree
        .uppers
        .iter()
        .any(|n| (0..n.slots.len()).any(|s| !n.has_child(s) && n.tile_value(s) != bg));
    root_tile || upper
}

/// The 8 blocks whose values a block's trilinear corners read: itself (`k = 0`) and its + face,
/// edge and corner neighbours (`k` = bits x, y, z).
pub(super) fn neighbourhood<'t>(
    tree: &'t Tree,
    acc: &mut Accessor<'t>,
    p: &Piece,
) -> [Block<'t>; 8] {
    let (first, nb) = match p.part {
        Part::Leaf { leaf, .. } => (
            Block::Leaf(tree.leaf_values(leaf)),
            tree.neighbours.get(leaf as usize),
        ),
        Part::Tile { lower, slot, .. } => (
            Block::Const(tree.lowers[lower as usize].tile_value(slot as usize)),
            None,
        ),
        Part::Const(_) | Part::Shell { .. } => (acc.block_at(p.origin), None),
    };
    blocks_around(tree, acc, p.origin, first, nb)
}

/// The pieces of each band of `rows` rows, in piece order.
pub(super) fn bins(pieces: &[Piece], rows: u32, height: u32) -> Vec<Vec<u32>> {
    bins_of(pieces.iter().map(|p| p.rect), rows, height)
}

/// The ids (positions in `rects`) of the footprints `[i0, i1, j0, j1]` meeting each band of
/// `rows` rows, in their order.
pub(super) fn bins_of(
    rects: impl Iterator<Item = [u32; 4]>,
    rows: u32,
    height: u32,
) -> Vec<Vec<u32>> {
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); height.div_ceil(rows) as usize];
    for (id, rect) in rects.enumerate() {
        for b in (rect[2] / rows)..=(rect[3] / rows) {
            bins[b as usize].push(id as u32);
        }
    }
    bins
}

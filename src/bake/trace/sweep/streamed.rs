//! The sweep of a lazily opened grid in bounded memory: the blocks of [`super::render`], in the
//! same order, taken a region of the tree at a time.
//!
//! A part is a run of consecutive units in the whole sweep's order: lower nodes the map sees
//! (tree order), then the shell blocks (sorted by origin). A part decodes the leaves its units'
//! trilinear corners read (`[o, o + 128]` of a lower node, `[o, o + 8]` of a shell block) into
//! a region of the topology holding only the lower nodes those boxes reach
//! ([`crate::tree::Tree::region`]), bounds it, sweeps its pieces into the whole image's f64
//! optical depth and drops it. Every pixel adds the same pieces in the same order as the
//! whole-grid sweep, so the map is bit-identical; no part copies or bounds the whole topology.
//! Ray-marched maps (`riemann`, `jittered`, `mc`) go the same way: a chord's points depend on
//! its block, its pixel and the sample alone, and each pixel keeps its `samples x (1 + K)`
//! marched optical depths across the parts, finished once at the end as the whole sweep
//! finishes a band.

use super::pieces::{entered, lower_pieces, needs_rest, shell_blocks, shell_pieces, Piece};
use super::rays::Rays;
use super::{finish_rows, stack_faces, view_map, Band, Sweep};
use crate::bake::camera::Camera;
use crate::bake::map::{BakeSettings, Map};
use crate::error::Result;
use crate::tree::{RegionIndex, Tree, REGION_LEAF_BYTES, REGION_LOWER_BYTES};
use crate::volume::Volume;
use rayon::prelude::*;
use std::collections::{BTreeSet, HashSet};

/// Bytes a part holds per leaf it decodes: the values, and the block of the sweep it makes (a
/// piece, three times over while the vector of pieces grows, and its index in a band's bin or
/// two).
const LEAF_BYTES: u64 =
    (std::mem::size_of::<[f32; 512]>() + 3 * std::mem::size_of::<Piece>() + 8) as u64;

/// Whether [`render_streamed`] can take `camera`'s map of `vol` (a shell is enough: only the
/// topology, the tiles and the transform are read): no extinction outside lower nodes, and
/// rays the sweep takes (every face's, for a cube map).
///
/// # Errors
/// Camera errors.
pub(crate) fn streams(vol: &Volume, camera: &Camera) -> Result<bool> {
    if needs_rest(vol) {
        return Ok(false);
    }
    Ok(view_rays(vol, camera)?.is_some())
}

/// The views of `camera` (itself, or a cube map's six faces, swept as [`super::render_cube`]
/// does) and their rays, or `None` when the sweep cannot take a view's rays ([`Rays::new`]).
fn view_rays(vol: &Volume, camera: &Camera) -> Result<Option<(Vec<Camera>, Vec<Rays>)>> {
    let views: Vec<Camera> = camera
        .cube_faces()
        .map_or_else(|| vec![*camera], |f| f.to_vec());
    let mut rays = Vec::with_capacity(views.len());
    for v in &views {
        let Some(r) = Rays::new(vol, v)? else {
            return Ok(None);
        };
        rays.push(r);
    }
    Ok(Some((views, rays)))
}

/// What a streamed sweep ([`render_streamed`]) read.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Streamed {
    /// Parts decoded one after the other (the shell blocks' parts included).
    pub groups: u64,
    /// Leaves decoded over all parts (a leaf next to two parts is decoded twice).
    pub leaves_decoded: u64,
    /// Most leaves one part held.
    pub max_group_leaves: u64,
    /// What the bad-voxel policy changed in the leaves the parts decoded, each leaf counted
    /// once (tiles are the shell's: [`Volume::sanitized`] of the shell volume).
    pub sanitized: crate::volume::Sanitized,
}

/// The origins of the lower nodes a ray walk enters, and per view the entered ones it sees.
type Entered = (HashSet<[i32; 3]>, Vec<Vec<u32>>);

/// A part's pieces for view `v`, from its volume and its region's index.
type PiecesOf<'a> = dyn Fn(&Volume, &RegionIndex, usize) -> Result<Vec<Piece>> + 'a;

/// One part being gathered: the lower nodes its region keeps and the leaves it decodes
/// (topology indices), and the bytes they take.
#[derive(Default)]
struct Part {
    kept: HashSet<u32>,
    leaves: HashSet<u32>,
    bytes: u64,
}

impl Part {
    /// The bytes a unit reading the voxels `[o, o + dim]` adds: its new lower nodes (each with
    /// its leaves' topology, [`REGION_LOWER_BYTES`] and [`REGION_LEAF_BYTES`]) and its new
    /// leaves' values; with the nodes and leaves, to [`Part::take`].
    fn extra(&self, topo: &Tree, o: [i64; 3], dim: i64) -> (u64, Vec<u32>, Vec<u32>) {
        let mut lowers = Vec::new();
        for bits in 0..8i64 {
            let c = [0, 1, 2].map(|a| o[a] + dim * ((bits >> (2 - a)) & 1));
            if let Some(l) = topo.lower_at(c) {
                if !self.kept.contains(&l) && !lowers.contains(&l) {
                    lowers.push(l);
                }
            }
        }
        let mut leaves = Vec::new();
        topo.leaves_in_box(o, o.map(|c| c + dim), &mut |l| {
            if !self.leaves.contains(&l) {
                leaves.push(l);
            }
        });
        let nodes: u64 = lowers
            .iter()
            .map(|&l| {
                let n = &topo.lowers[l as usize];
                let children: u64 = n.child_mask.iter().map(|w| u64::from(w.count_ones())).sum();
                REGION_LOWER_BYTES + children * REGION_LEAF_BYTES
            })
            .sum();
        (nodes + leaves.len() as u64 * LEAF_BYTES, lowers, leaves)
    }

    fn take(&mut self, (bytes, lowers, leaves): (u64, Vec<u32>, Vec<u32>)) {
        self.bytes += bytes;
        self.kept.extend(lowers);
        self.leaves.extend(leaves);
    }

    fn is_empty(&self) -> bool {
        self.kept.is_empty() && self.leaves.is_empty()
    }

    /// The kept lower nodes and the leaves, sorted (what a part holds once gathered).
    fn lists(self) -> Lists {
        let mut kept: Vec<u32> = self.kept.into_iter().collect();
        let mut leaves: Vec<u32> = self.leaves.into_iter().collect();
        kept.sort_unstable();
        leaves.sort_unstable();
        Lists { kept, leaves }
    }
}

/// A gathered part: the lower nodes its region keeps and the leaves it decodes, sorted.
struct Lists {
    kept: Vec<u32>,
    leaves: Vec<u32>,
}

/// Split `units` (each reading the voxels `[o, o + dim]`) into runs whose parts take at most
/// `part_bytes` (a unit larger than that is a part of its own), handing each run to `each` as
/// soon as it is gathered (so only one run's lists are held at a time).
fn runs<T>(
    topo: &Tree,
    units: impl IntoIterator<Item = (T, [i64; 3])>,
    dim: i64,
    part_bytes: u64,
    each: &mut dyn FnMut(Vec<T>, Lists) -> Result<()>,
) -> Result<()> {
    let (mut items, mut part) = (Vec::new(), Part::default());
    for (item, o) in units {
        let mut extra = part.extra(topo, o, dim);
        if !part.is_empty() && part.bytes + extra.0 > part_bytes {
            each(
                std::mem::take(&mut items),
                std::mem::take(&mut part).lists(),
            )?;
            extra = part.extra(topo, o, dim);
        }
        part.take(extra);
        items.push(item);
    }
    if !items.is_empty() {
        each(items, part.lists())?;
    }
    Ok(())
}

/// What the bad-voxel policy will change in the leaves `leaves` of `tree` (values as decoded),
/// on all cores; a leaf that is all finite and non-negative (the usual case) is passed over by
/// one vectorised test.
fn bad_voxels(tree: &Tree, leaves: &[u32]) -> crate::volume::Sanitized {
    leaves
        .par_iter()
        .map(|&l| tree.leaf_values(l))
        .filter(|v| {
            v.iter()
                .fold(false, |bad, &x| bad | !(0.0..f32::INFINITY).contains(&x))
        })
        .map(|v| {
            let mut s = crate::volume::Sanitized::default();
            for &x in v {
                s.tally(x);
            }
            s
        })
        .reduce(
            crate::volume::Sanitized::default,
            crate::volume::Sanitized::merged,
        )
}

/// The bytes of the least part that holds lower node `l` of `topo`: what a budget must leave
/// for parts.
pub(crate) fn part_bytes(topo: &Tree, l: usize) -> u64 {
    let o = topo.lowers[l].origin.map(i64::from);
    Part::default().extra(topo, o, 128).0
}

/// A streamed sweep under way: what its parts read (the lazy grid, its topology, how a decoded
/// region becomes a volume), the views they sweep, and what they have added so far: each view's
/// image of f64 optical depths (the whole sweep's band buffers end to end: per pixel, per
/// sample, the full ray and its slices), the lookups, and what was decoded.
struct Streaming<'a> {
    lazy: &'a crate::vdb::LazyGrid,
    topo: &'a Tree,
    volume_of: &'a (dyn Fn(crate::vdb::Grid) -> Result<Volume> + Sync),
    views: &'a [Camera],
    rays: &'a [Rays],
    march: Option<super::March>,
    depths: &'a [f64],
    rows: u32,
    tau: Vec<f64>,
    /// Values in one view's image.
    view_len: usize,
    lookups: u64,
    stats: Streamed,
    /// The leaves whose bad voxels are counted (a bit per topology leaf).
    counted: Vec<u64>,
}

impl Streaming<'_> {
    /// Decode a part's region, make each view's pieces (given the region's index of each
    /// topology lower node) and add them to its image; the part's volume and index.
    fn sweep_part(&mut self, part: &Lists, pieces: &PiecesOf) -> Result<(Volume, RegionIndex)> {
        let (grid, index) = self.lazy.load_region(self.topo, &part.kept, &part.leaves)?;
        let mut fresh = Vec::new();
        for &l in &part.leaves {
            let (w, bit) = (l as usize / 64, 1u64 << (l % 64));
            if let (0, Some(r)) = (self.counted[w] & bit, index.leaf(l)) {
                self.counted[w] |= bit;
                fresh.push(r);
            }
        }
        let bad = bad_voxels(&grid.tree, &fresh);
        let stats = &mut self.stats;
        stats.sanitized = stats.sanitized.merged(bad);
        let vol = (self.volume_of)(grid)?;
        stats.groups += 1;
        let loaded = vol.tree().loaded_leaf_count() as u64;
        stats.leaves_decoded += loaded;
        stats.max_group_leaves = stats.max_group_leaves.max(loaded);
        for (v, image) in self.tau.chunks_mut(self.view_len).enumerate() {
            let pieces = pieces(&vol, &index, v)?;
            let (view, rays) = (&self.views[v], self.rays[v]);
            let sweep = Sweep::from_pieces(&vol, view, rays, pieces, false, self.rows, self.depths)
                .marching(self.march, None)
                .ok_or_else(|| crate::error::Error::InvalidArgument {
                    name: "max-memory".into(),
                    reason: "a part of this map cannot be marched in object order".into(),
                })?;
            self.lookups += sweep.add_all(image)?;
        }
        Ok((vol, index))
    }

    /// The lower nodes any view sees, in tree order, swept in parts of at most about
    /// `part_bytes`; the origins of those a ray walk enters, and per view the entered ones it
    /// sees (whose shell blocks it sweeps).
    fn lower_parts(&mut self, part_bytes: u64) -> Result<Entered> {
        let (topo, rays) = (self.topo, self.rays);
        let seen = topo
            .lowers
            .iter()
            .enumerate()
            .map(|(l, n)| (l as u32, n.origin.map(i64::from)))
            .filter(|(_, o)| rays.iter().any(|r| r.footprint(*o, 128).is_some()));
        let mut entered_set = HashSet::new();
        let mut bases = vec![Vec::new(); rays.len()];
        runs(topo, seen, 128, part_bytes, &mut |lowers, part| {
            let (vol, index) = self.sweep_part(&part, &|vol, index, v| {
                let mut out = Vec::new();
                for &l in &lowers {
                    lower_pieces(vol, &rays[v], own(index, l)?, &mut out);
                }
                Ok(out)
            })?;
            for &l in &lowers {
                let node = &vol.tree().lowers[own(&index, l)?];
                if entered(vol.tree(), node) {
                    entered_set.insert(node.origin);
                    for (v, r) in rays.iter().enumerate() {
                        if r.footprint(node.origin.map(i64::from), 128).is_some() {
                            bases[v].push(l);
                        }
                    }
                }
            }
            drop(vol);
            crate::memory::release_freed();
            Ok(())
        })?;
        Ok((entered_set, bases))
    }

    /// The shell blocks next to the entered lower nodes (`entered_set`; per view, those it
    /// sees, `bases`), after every lower node's pieces, in their sorted order, swept in parts of
    /// at most about `part_bytes` (per view; a cube map's parts take the union of its faces'
    /// blocks, each face its own).
    fn shell_parts(
        &mut self,
        entered_set: &HashSet<[i32; 3]>,
        bases: &[Vec<u32>],
        part_bytes: u64,
    ) -> Result<()> {
        let (topo, rays) = (self.topo, self.rays);
        let mut outside = vec![BTreeSet::new(); rays.len()];
        for (v, out) in outside.iter_mut().enumerate() {
            for &l in &bases[v] {
                shell_blocks(
                    entered_set,
                    topo.lowers[l as usize].origin.map(i64::from),
                    out,
                );
            }
        }
        // One view sweeps its own blocks; a cube map's parts take the union, each face its own.
        let all: std::borrow::Cow<'_, BTreeSet<[i64; 3]>> = match outside.as_slice() {
            [one] => std::borrow::Cow::Borrowed(one),
            many => std::borrow::Cow::Owned(many.iter().flatten().copied().collect()),
        };
        let blocks = all.iter().map(|&o| (o, o));
        runs(topo, blocks, 8, part_bytes, &mut |blocks, part| {
            self.sweep_part(&part, &|vol, _, v| {
                let mine: BTreeSet<[i64; 3]> = blocks
                    .iter()
                    .filter(|o| outside[v].contains(*o))
                    .copied()
                    .collect();
                let mut out = Vec::new();
                shell_pieces(vol, &rays[v], &mine, &mut out);
                Ok(out)
            })?;
            crate::memory::release_freed();
            Ok(())
        })
    }
}

/// Index in its part's region of lower node `l`, a unit's own lower node (in its part's
/// region: its box starts in it).
fn own(index: &RegionIndex, l: u32) -> Result<usize> {
    index
        .lower(l)
        .map(|r| r as usize)
        .ok_or_else(|| crate::error::Error::InvalidArgument {
            name: "region".into(),
            reason: format!("lower node {l} is not in its part's region"),
        })
}

/// The sweep's map of a lazily opened grid in bounded memory (see the module docs): parts of
/// at most about `part_bytes` each, decoded by [`crate::vdb::LazyGrid::load_region`], made
/// volumes by `volume_of` (density scale, transform; `shell` is the lazy grid's shell made a
/// volume the same way). `None` when the sweep cannot take this map in pieces: its rays
/// ([`Rays::new`]), or extinction outside lower nodes (a non-zero background or tiles above
/// lower nodes, which the rays walk whole).
///
/// # Errors
/// Decoding errors of the parts' leaves, and those of [`super::render`].
#[allow(clippy::too_many_arguments)]
pub(crate) fn render_streamed(
    lazy: &crate::vdb::LazyGrid,
    shell: &Volume,
    volume_of: &(dyn Fn(crate::vdb::Grid) -> Result<Volume> + Sync),
    camera: &Camera,
    s: &BakeSettings,
    depths: &[f64],
    rows: u32,
    part_bytes: u64,
    progress: &dyn crate::progress::Progress,
) -> Result<Option<(Map, Streamed)>> {
    let start = std::time::Instant::now();
    if needs_rest(shell) {
        return Ok(None);
    }
    let Some((views, rays)) = view_rays(shell, camera)? else {
        return Ok(None);
    };
    let topo = shell.tree();
    // A ray march ([`super::marches`]) keeps `samples x (1 + K)` optical depths per pixel, as
    // the whole-grid sweep's bands do; every part adds its pieces' marches to them in the
    // whole sweep's order, so the map is the whole bake's, bit for bit.
    let march = super::marches(s);
    let samples = march.map_or(1, |m| m.samples());
    let stride = samples * (1 + depths.len());
    let view_len = views[0].pixels() as usize * stride;
    let mut parts = Streaming {
        lazy,
        topo,
        volume_of,
        views: &views,
        rays: &rays,
        march,
        depths,
        rows,
        tau: vec![0.0f64; view_len * views.len()],
        view_len,
        lookups: 0,
        stats: Streamed::default(),
        counted: vec![0u64; topo.leaves.len().div_ceil(64)],
    };
    let (entered_set, bases) = parts.lower_parts(part_bytes)?;
    parts.shell_parts(&entered_set, &bases, part_bytes)?;
    let Streaming {
        tau,
        lookups,
        stats,
        ..
    } = parts;
    let mut maps = Vec::with_capacity(views.len());
    for (view, tau) in views.iter().zip(tau.chunks(view_len)) {
        let w = view.width as usize;
        let mut t_image = vec![0.0f32; view.pixels() as usize];
        let done: Vec<(Band, Vec<f32>)> = t_image
            .par_chunks_mut(rows as usize * w)
            .zip(tau.par_chunks(rows as usize * w * stride))
            .enumerate()
            .map(|(b, (t_band, tau))| {
                let y0 = b as u32 * rows;
                let (slices, err) =
                    finish_rows(view, y0, tau, (stride, samples), None, s.std_err, t_band)?;
                progress.advance(t_band.len() as u64);
                Ok(((0, slices), err))
            })
            .collect::<Result<_>>()?;
        let sampled = (samples > 1).then_some(samples);
        maps.push(view_map(view, s, depths, t_image, done, sampled, start));
    }
    let mut map = if views.len() > 1 {
        stack_faces(camera, maps)
    } else {
        maps.pop()
    }
    .ok_or_else(|| crate::error::Error::InvalidArgument {
        name: "camera".into(),
        reason: "a map without a view".into(),
    })?;
    map.stats.lookups = lookups;
    map.stats.parts = stats.groups;
    Ok(Some((map, stats)))
}

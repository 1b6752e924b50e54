//! Deterministic mutation fuzzing of the whole library (load, query, bake) on hostile copies of
//! corpus files.
//!
//! **Mutants.** Two families, derived from fixed seeds and from the layout of the unmutated files
//! (parsed here, independently of umbra's decoder, down to every leaf buffer, and checked against
//! the descriptors' offsets):
//! - *byte-level*: truncated copies, and copies with flipped bytes or extreme 4/8-byte values,
//!   spread over the header, the grid descriptors, the grid metadata and transform, the topology
//!   and the leaf buffers;
//! - *structure-aware*: fields edited by meaning, in the header and in a few grids of each file
//!   (the first, the last, the first float fog grid, the first of another value type).
//!   Descriptor offsets (0, ±1, the descriptor's own start, the file length and past it,
//!   `i64::MAX`, -1, the grid's other offsets, other grids' offsets, chains that loop back with
//!   grid counts up to 2^31 - 1), descriptor string lengths and tree type names, the header's
//!   grid count (0, ±1, 2^31 - 1, 2^31, -1), metadata counts and each entry's name/type/value
//!   length (0, len + 1, 2^31 - 1, 0xFFFFFFFF) and type name (swapped for another), the `class`
//!   value, the compression flags (0..=7, 0xFFFFFFFF), the transform's map type name (every other
//!   known map, an unknown one, empty) and each of its f64 parameters (0, -0, 5e-324, 1e-150,
//!   1e300, NaN, ±inf, 1e17; derived parameters only 0, NaN, 1e300; scales and translations also
//!   all three at once), the tree's buffer count and background, root tile and child counts
//!   (0, ±1, 2^31 - 1, 0xFFFFFFFF) and origins (`i32::MIN`, `i32::MAX - 4095`, not a multiple of
//!   4096, shifted, duplicated), internal-node child and value masks and leaf value masks (all
//!   ones, all zeros, one bit set, one cleared; leaf masks also in the buffers' copy, alone and
//!   together with the topology's), per-node compression metadata bytes (0..=6, 255), zip/blosc
//!   size prefixes (0, -1, ±huge, off by one, a raw-size claim), node values (every value of a
//!   leaf, or every tile of an internal node, NaN, ±inf, -1, huge or subnormal, or 0.5 with every
//!   7th value so: a compressed block is rewritten raw), and grid instancing in files with
//!   several grids (an instance of another grid, of itself, of a missing grid, cycles, chains,
//!   another value type). Edits that change a length rebuild the file and move every descriptor
//!   offset after them. The two families of edits that were slowest while the library did not
//!   bound them (loops with 2^31 - 1 grids, a root origin at the far end of index space on all
//!   three axes) run on a few sources only.
//!
//! **What every mutant must survive.** Opening it and loading every grid (and describing each as
//! `umbra info` does) returns `Ok` or a typed error (`NotVdb`, `Invalid`, `Unsupported`); a
//! truncated file never loads completely. The float or double grid the edit is in, and the first
//! grid of the mutant that makes a volume, are made a [`Volume`] as the CLI does (density scale
//! 1; refused only as `Invalid` or `Unsupported`), traced along 4 rays through the volume box
//! (the three axes through its centre and a diagonal half-line to infinity; a fifth through the
//! node an edit is in) with exact regular tracking (nearest and trilinear) and the `ratio`
//! estimator (4 samples, fixed seed), and baked to an 8x8 map through [`BakeJob::run_on`] (ratio
//! tracking, 2 spp, standard error and 2 depth slices, EXR and PNG written). Each step returns
//! `Ok` or a typed [`umbra::Error`] (a NaN reported as `Error::NotANumber` is one), never panics,
//! and never returns `Ok` with a NaN or infinite transmittance, a NaN or negative optical depth,
//! a transmittance outside [0, 1] or a majorant violation. A whole case (write the mutant, load,
//! trace, bake) takes at most 10 s and 2 GiB.
//!
//! **How.** The cases run in worker processes (this test binary re-run on its `mutation_worker`
//! test, one per core, each on an interleaved share of the cases) under a supervisor, so that a
//! case that hangs (killed after 15 s, naming the step it was in), crashes the process (abort,
//! stack overflow, failed allocation) or runs away with memory is reported against that case and
//! the worker restarts after it: the report lists every failing case with its file, region, kind
//! and edit, the step a panic or slow case was in and the panic locations. The summary counts
//! cases per kind and outcome, typed errors per step and time per step; `UMBRA_MUTATION_DUMP=path`
//! also writes every case's report as JSON lines. `cli_survives_mutated_files` runs `umbra info`
//! on a sample of the same mutants (time- and memory-limited).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use common::{corpus_dir, panic_message, peak_rss_bytes};
use rand::{Rng, SeedableRng};
use std::cell::Cell;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::os::unix::fs::FileExt;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};
use umbra::bake::{BakeJob, BakeSettings, Camera, Depths, Projection, Resolution, View};
use umbra::estimate::{estimate, Estimator, Options};
use umbra::glam::DVec3;
use umbra::info::GridInfo;
use umbra::internals::vdb::Grid;
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

/// Source files and how many byte-level mutations (half flips, half overwrites) each gets:
/// fewer for the files that take longest to load, to keep the test fast. Files with 0 get no
/// byte-level mutations and no truncations, only structure-aware edits.
const SOURCES: &[(&str, usize)] = &[
    ("gen/puff_blosc.vdb", 200),
    ("gen/puff_zip.vdb", 160),
    ("gen/cloud_fbm_half.vdb", 60),
    ("gen/tiles_mixed.vdb", 60),
    ("real/openvdb_smoke1_houdini_v222.vdb", 120),
    ("gen/puff_none.vdb", 120),
    ("gen/xform_affine_rotated.vdb", 100),
    ("gen/bool_mask.vdb", 120),
    ("real/blender_smoke_fluid_data_0050.vdb", 100),
    // Structure-aware edits only: several grids (instancing), root-level tiles.
    ("gen/multigrid_smoke.vdb", 0),
    ("gen/duplicate_grid_names.vdb", 0),
    ("gen/tiles_root_level.vdb", 0),
];
const SEED: u64 = 0x756d_6272_615f_6d75; // "umbra_mu"
/// Truncate at every offset below this.
const DENSE_TRUNCATION_BYTES: u64 = 300;
const RANDOM_TRUNCATIONS_PER_FILE: usize = 40;
/// Most memory one case may use (peak resident set of its worker, reset before each case).
const RSS_LIMIT: u64 = 2 << 30;
/// Longest a case may take (write the mutant, load, trace, bake).
const SLOW_CASE: Duration = Duration::from_secs(10);
/// A case without a result after this long is declared hung and its worker killed.
const HANG_LIMIT: Duration = Duration::from_secs(15);
/// Address space of one `umbra info` run in the CLI test.
const CLI_MEMORY: u64 = 4 << 30;
/// Collision cap per sample of the stochastic estimators (keeps a case bounded in time).
const MAX_COLLISIONS: u64 = 20_000;
/// The worker test reads its share of the cases from this variable: shard, shard count, first
/// case, scratch directory and output directory, one a line.
const WORKER_ENV: &str = "UMBRA_MUTATION_WORKER";
/// If set, every case's report is written to this file as JSON lines (for timing analysis).
const DUMP_ENV: &str = "UMBRA_MUTATION_DUMP";
/// Prefix of the worker's protocol lines on stdout.
const LINE: &str = "@@mutation ";

// ---------------------------------------------------------------------------------------------
// Mutations and cases
// ---------------------------------------------------------------------------------------------

/// Replace `[at, at + remove)` of the original file with `insert`.
#[derive(Debug, Clone)]
struct Edit {
    at: u64,
    remove: u64,
    insert: Vec<u8>,
}

#[derive(Debug, Clone)]
enum Mutation {
    /// Keep only the first `n` bytes.
    Truncate(u64),
    /// XOR one byte.
    Flip { at: u64, xor: u8 },
    /// Overwrite bytes at `at` (same length).
    Overwrite { at: u64, bytes: Vec<u8> },
    /// Overwrite several places at once.
    Patch(Vec<(u64, Vec<u8>)>),
    /// Non-overlapping edits in original coordinates, lengths may change (descriptor offsets
    /// after the edits are fixed by edits of the list).
    Rebuild(Vec<Edit>),
}

impl std::fmt::Display for Mutation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let short = |b: &[u8]| {
            if b.len() <= 8 {
                format!("{b:02x?}")
            } else {
                format!("{} bytes {:02x?}..", b.len(), &b[..4])
            }
        };
        match self {
            Self::Truncate(n) => write!(f, "truncate to {n} bytes"),
            Self::Flip { at, xor } => write!(f, "xor byte {at} with {xor:#04x}"),
            Self::Overwrite { at, bytes } => {
                write!(f, "overwrite bytes {at}.. with {}", short(bytes))
            }
            Self::Patch(p) => {
                let parts: Vec<String> = p
                    .iter()
                    .map(|(at, b)| format!("{at}: {}", short(b)))
                    .collect();
                write!(f, "overwrite {}", parts.join(", "))
            }
            Self::Rebuild(e) => {
                let d: i64 = e
                    .iter()
                    .map(|e| e.insert.len() as i64 - e.remove as i64)
                    .sum();
                write!(f, "rebuild with {} edits (length {d:+})", e.len())
            }
        }
    }
}

impl Mutation {
    /// The mutated copy of `orig`.
    fn apply(&self, orig: &[u8]) -> Vec<u8> {
        if let Self::Truncate(n) = self {
            return orig[..*n as usize].to_vec();
        }
        if let Some(p) = self.patches(orig) {
            let mut v = orig.to_vec();
            for (at, b) in p {
                v[at as usize..at as usize + b.len()].copy_from_slice(&b);
            }
            return v;
        }
        let Self::Rebuild(edits) = self else {
            unreachable!()
        };
        let mut edits: Vec<&Edit> = edits.iter().collect();
        edits.sort_by_key(|e| e.at);
        let mut out = Vec::with_capacity(orig.len() + 256);
        let mut at = 0usize;
        for e in edits {
            assert!(e.at as usize >= at, "overlapping edits in {self}");
            out.extend_from_slice(&orig[at..e.at as usize]);
            out.extend_from_slice(&e.insert);
            at = (e.at + e.remove) as usize;
        }
        out.extend_from_slice(&orig[at..]);
        out
    }

    /// Same-length overwrites (applied to a working copy in place), or `None` for truncations
    /// and rebuilds.
    fn patches(&self, orig: &[u8]) -> Option<Vec<(u64, Vec<u8>)>> {
        match self {
            Self::Flip { at, xor } => Some(vec![(*at, vec![orig[*at as usize] ^ xor])]),
            Self::Overwrite { at, bytes } => Some(vec![(*at, bytes.clone())]),
            Self::Patch(p) => Some(p.clone()),
            Self::Truncate(_) | Self::Rebuild(_) => None,
        }
    }
}

#[derive(Debug, Clone)]
struct Case {
    file: usize,
    region: &'static str,
    /// The family of the edit: `truncation`, `flip`, `overwrite`, or the field a structure-aware
    /// edit targets.
    kind: &'static str,
    /// What a structure-aware edit did, by meaning.
    label: Option<String>,
    /// The grid (index in the original file) the edit is in, if any: it is traced and baked,
    /// as is the first grid of the mutant that makes a volume.
    grid: Option<usize>,
    /// An index-space point in the node the edit is in: that grid gets one more ray, through it.
    probe: Option<[f64; 3]>,
    mutation: Mutation,
}

impl Case {
    fn structured(&self) -> bool {
        self.label.is_some()
    }

    fn describe(&self) -> String {
        match &self.label {
            Some(l) => format!(
                "{} [{} / {}] {l} ({})",
                SOURCES[self.file].0, self.region, self.kind, self.mutation
            ),
            None => format!(
                "{} [{}] {}",
                SOURCES[self.file].0, self.region, self.mutation
            ),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The layout of a source file, parsed independently of umbra
// ---------------------------------------------------------------------------------------------

/// A length-prefixed string (or metadata value): its u32 length field at `at`, then `len` bytes.
#[derive(Debug, Clone, Copy)]
struct Str {
    at: u64,
    len: u32,
}

impl Str {
    fn bytes<'f>(&self, file: &'f [u8]) -> &'f [u8] {
        &file[self.at as usize + 4..][..self.len as usize]
    }
    fn text(&self, file: &[u8]) -> String {
        String::from_utf8_lossy(self.bytes(file)).into_owned()
    }
}

/// A cursor over a whole (valid) source file; running off the end is a bug of this test.
struct Rd<'f> {
    b: &'f [u8],
    at: usize,
}

impl<'f> Rd<'f> {
    fn pos(&self) -> u64 {
        self.at as u64
    }
    fn take(&mut self, n: usize) -> &'f [u8] {
        let s = &self.b[self.at..self.at + n];
        self.at += n;
        s
    }
    fn u8(&mut self) -> u8 {
        self.take(1)[0]
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take(4).try_into().unwrap())
    }
    fn i32(&mut self) -> i32 {
        i32::from_le_bytes(self.take(4).try_into().unwrap())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take(8).try_into().unwrap())
    }
    fn i64(&mut self) -> i64 {
        i64::from_le_bytes(self.take(8).try_into().unwrap())
    }
    fn str(&mut self) -> Str {
        let at = self.pos();
        let len = self.u32();
        self.take(len as usize);
        Str { at, len }
    }
}

/// Value type of a grid, as far as stepping over its values needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Vt {
    Float,
    Double,
    Int32,
    Int64,
    Bool,
    Vec3s,
    Vec3d,
    Vec3i,
}

impl Vt {
    fn of(tree_type: &str) -> Self {
        let v = tree_type
            .strip_prefix("Tree_")
            .and_then(|t| t.strip_suffix("_5_4_3"))
            .unwrap_or_else(|| panic!("mutation source with tree type {tree_type}"));
        match v {
            "float" => Self::Float,
            "double" => Self::Double,
            "int32" => Self::Int32,
            "int64" => Self::Int64,
            "bool" => Self::Bool,
            "vec3s" => Self::Vec3s,
            "vec3d" => Self::Vec3d,
            "vec3i" => Self::Vec3i,
            other => panic!("mutation source with value type {other}"),
        }
    }
    fn size(self) -> usize {
        match self {
            Self::Float | Self::Int32 => 4,
            Self::Double | Self::Int64 => 8,
            Self::Bool => 1,
            Self::Vec3s | Self::Vec3i => 12,
            Self::Vec3d => 24,
        }
    }
    fn real(self) -> bool {
        matches!(self, Self::Float | Self::Double | Self::Vec3s | Self::Vec3d)
    }
    /// Bytes of one element of a value array (halves in `_HalfFloat` grids).
    fn array_size(self, half: bool) -> usize {
        match (half && self.real(), self) {
            (true, Self::Float | Self::Double) => 2,
            (true, _) => 6,
            (false, _) => self.size(),
        }
    }
}

/// How a grid's node values are stored.
#[derive(Debug, Clone, Copy)]
struct Stream {
    vt: Vt,
    half: bool,
    zip: bool,
    blosc: bool,
    active_mask: bool,
}

/// One run of node values (`io::readCompressedValues`).
#[derive(Debug, Clone)]
struct Values {
    /// The per-node metadata byte.
    meta_at: u64,
    /// The i64 size prefix of a zip/blosc block: where, its value, and where the block ends.
    size: Option<(u64, i64, u64)>,
    /// Uncompressed bytes of the values.
    nbytes: usize,
    /// Where the values start when stored raw (no compression, or a non-positive prefix).
    raw_at: Option<u64>,
}

#[derive(Debug, Clone)]
struct Node {
    upper: bool,
    origin: [i32; 3],
    child_mask_at: u64,
    value_mask_at: u64,
    child_mask: Vec<u64>,
    value_mask: Vec<u64>,
    values: Values,
}

#[derive(Debug, Clone)]
struct LeafL {
    origin: [i32; 3],
    topo_mask_at: u64,
    mask: [u64; 8],
    buf_mask_at: u64,
    values: Option<Values>,
}

#[derive(Debug, Clone)]
struct MetaEntry {
    name: Str,
    ty: Str,
    value: Str,
}

#[derive(Debug, Clone)]
struct Meta {
    count_at: u64,
    entries: Vec<MetaEntry>,
}

#[derive(Debug, Clone, Default)]
struct Topology {
    buffer_count_at: u64,
    background_at: u64,
    root_tiles_at: u64,
    root_tiles: u32,
    root_children_at: u64,
    root_children: u32,
    /// Root tiles: where each origin is.
    tiles: Vec<u64>,
    /// Root children: where each origin is, and the origin.
    children: Vec<(u64, [i32; 3])>,
    /// Internal nodes in file order.
    nodes: Vec<Node>,
    leaves: Vec<LeafL>,
}

#[derive(Debug, Clone)]
struct GridL {
    desc_start: u64,
    name: Str,
    ty: Str,
    parent: Str,
    /// Where the three i64 offsets are.
    offsets_at: u64,
    /// grid_pos, block_pos, end_pos.
    pos: [u64; 3],
    stream: Stream,
    class: Option<String>,
    flags: u32,
    meta: Meta,
    map: Str,
    map_name: String,
    /// Offsets of the map's f64 parameters.
    params: Vec<u64>,
    xform_end: u64,
    topo: Topology,
}

/// Every field of a source file the structure-aware edits target, by file offset.
#[derive(Debug, Clone)]
struct Structure {
    len: u64,
    grid_count_at: u64,
    file_meta: Meta,
    grids: Vec<GridL>,
}

fn read_meta(r: &mut Rd<'_>) -> Meta {
    let count_at = r.pos();
    let n = r.u32();
    let entries = (0..n)
        .map(|_| MetaEntry {
            name: r.str(),
            ty: r.str(),
            value: r.str(),
        })
        .collect();
    Meta { count_at, entries }
}

fn read_values(r: &mut Rd<'_>, s: &Stream, mask: &[u64]) -> Values {
    let n = mask.len() * 64;
    let meta_at = r.pos();
    let meta = r.u8();
    assert!(meta <= 6, "node metadata {meta} at {meta_at}");
    if matches!(meta, 2 | 4 | 5) {
        r.take(s.vt.size());
    }
    if meta == 5 {
        r.take(s.vt.size());
    }
    if matches!(meta, 3..=5) {
        r.take(n / 8);
    }
    let count = if s.active_mask && meta != 6 {
        mask.iter().map(|w| w.count_ones() as usize).sum()
    } else {
        n
    };
    let mut v = Values {
        meta_at,
        size: None,
        nbytes: 0,
        raw_at: None,
    };
    if s.half && s.vt.real() && count == 0 {
        return v;
    }
    v.nbytes = count * s.vt.array_size(s.half);
    if s.zip || s.blosc {
        let at = r.pos();
        let size = r.i64();
        if size <= 0 {
            v.raw_at = Some(r.pos());
            r.take(v.nbytes);
        } else {
            r.take(size as usize);
        }
        v.size = Some((at, size, r.pos()));
    } else {
        v.raw_at = Some(r.pos());
        r.take(v.nbytes);
    }
    v
}

fn read_node(r: &mut Rd<'_>, s: &Stream, upper: bool, origin: [i32; 3], t: &mut Topology) {
    let words = if upper { 512 } else { 64 };
    // log2 of the slots per side and of a child's side in voxels
    let (side, child) = if upper { (5, 7) } else { (4, 3) };
    let child_mask_at = r.pos();
    let child_mask: Vec<u64> = (0..words).map(|_| r.u64()).collect();
    let value_mask_at = r.pos();
    let value_mask: Vec<u64> = (0..words).map(|_| r.u64()).collect();
    let values = read_values(r, s, &value_mask);
    t.nodes.push(Node {
        upper,
        origin,
        child_mask_at,
        value_mask_at,
        child_mask: child_mask.clone(),
        value_mask,
        values,
    });
    for (w, word) in child_mask.into_iter().enumerate() {
        for b in (0..64).filter(|b| word >> b & 1 == 1) {
            let slot = w * 64 + b;
            let local = [
                slot >> (2 * side),
                (slot >> side) & ((1 << side) - 1),
                slot & ((1 << side) - 1),
            ];
            let origin = [0, 1, 2].map(|a| origin[a] + ((local[a] as i32) << child));
            if upper {
                read_node(r, s, false, origin, t);
            } else {
                let topo_mask_at = r.pos();
                let mask = [0; 8].map(|_: u64| r.u64());
                t.leaves.push(LeafL {
                    origin,
                    topo_mask_at,
                    mask,
                    buf_mask_at: 0,
                    values: None,
                });
            }
        }
    }
}

fn read_grid(file: &[u8], desc_start: u64) -> GridL {
    let mut r = Rd {
        b: file,
        at: desc_start as usize,
    };
    let (name, ty, parent) = (r.str(), r.str(), r.str());
    let offsets_at = r.pos();
    let pos = [0; 3].map(|_: u64| u64::try_from(r.i64()).unwrap());
    let ty_text = ty.text(file);
    let half = ty_text.ends_with("_HalfFloat");
    let vt = Vt::of(ty_text.trim_end_matches("_HalfFloat"));
    let mut r = Rd {
        b: file,
        at: pos[0] as usize,
    };
    let flags = r.u32();
    let meta = read_meta(&mut r);
    let class = meta
        .entries
        .iter()
        .find(|e| e.name.bytes(file) == b"class")
        .map(|e| e.value.text(file));
    let map = r.str();
    let map_name = map.text(file);
    let mut params = Vec::new();
    let mut f64s = |r: &mut Rd<'_>, n: usize| {
        for _ in 0..n {
            params.push(r.pos());
            r.take(8);
        }
    };
    match map_name.as_str() {
        "UniformScaleMap" | "ScaleMap" => f64s(&mut r, 15),
        "UniformScaleTranslateMap" | "ScaleTranslateMap" => f64s(&mut r, 18),
        "TranslationMap" => f64s(&mut r, 3),
        "AffineMap" | "UnitaryMap" => f64s(&mut r, 16),
        "NonlinearFrustumMap" => {
            f64s(&mut r, 8);
            r.str();
            f64s(&mut r, 16);
        }
        other => panic!("mutation source with map {other}"),
    }
    let xform_end = r.pos();
    let stream = Stream {
        vt,
        half,
        zip: flags & 1 != 0,
        active_mask: flags & 2 != 0,
        blosc: flags & 4 != 0,
    };
    let mut t = Topology::default();
    if parent.len == 0 {
        t.buffer_count_at = r.pos();
        r.take(4);
        t.background_at = r.pos();
        r.take(vt.size());
        t.root_tiles_at = r.pos();
        t.root_tiles = r.u32();
        t.root_children_at = r.pos();
        t.root_children = r.u32();
        for _ in 0..t.root_tiles {
            t.tiles.push(r.pos());
            r.take(12 + vt.size() + 1);
        }
        for _ in 0..t.root_children {
            let at = r.pos();
            let origin = [r.i32(), r.i32(), r.i32()];
            t.children.push((at, origin));
            read_node(&mut r, &stream, true, origin, &mut t);
        }
        assert_eq!(r.pos(), pos[1], "topology parse must end at block_pos");
        for leaf in &mut t.leaves {
            leaf.buf_mask_at = r.pos();
            r.take(64);
            if vt == Vt::Bool {
                r.take(12 + 64);
            } else {
                leaf.values = Some(read_values(&mut r, &stream, &leaf.mask));
            }
        }
        assert_eq!(r.pos(), pos[2], "buffer parse must end at end_pos");
    }
    GridL {
        desc_start,
        name,
        ty,
        parent,
        offsets_at,
        pos,
        stream,
        class,
        flags,
        meta,
        map,
        map_name,
        params,
        xform_end,
        topo: t,
    }
}

/// Parse a (valid) source file down to every leaf buffer.
fn parse(file: &[u8]) -> Structure {
    let mut r = Rd { b: file, at: 8 };
    // file version, library major and minor, grid offsets flag, UUID
    r.take(4 + 4 + 4 + 1 + 36);
    let file_meta = read_meta(&mut r);
    let grid_count_at = r.pos();
    let count = r.u32();
    let mut grids = Vec::new();
    let mut pos = r.pos();
    for _ in 0..count {
        let g = read_grid(file, pos);
        pos = g.pos[2];
        grids.push(g);
    }
    Structure {
        len: file.len() as u64,
        grid_count_at,
        file_meta,
        grids,
    }
}

/// Byte ranges of one source file, for the byte-level mutations.
struct Layout {
    len: u64,
    /// (region name, start, end) half-open ranges, possibly several per name (one per grid).
    regions: Vec<(&'static str, u64, u64)>,
    /// Structure boundaries worth truncating at.
    boundaries: Vec<u64>,
    /// Each grid's bytes, descriptor included: `[desc_start, end_pos)`.
    grids: Vec<(u64, u64)>,
}

impl Layout {
    /// The grid whose bytes hold offset `at`.
    fn grid_at(&self, at: u64) -> Option<usize> {
        self.grids.iter().position(|&(a, b)| (a..b).contains(&at))
    }
}

const REGIONS: &[&str] = &[
    "header",
    "descriptor",
    "grid metadata",
    "transform",
    "topology",
    "buffers",
];

fn layout(s: &Structure) -> Layout {
    assert!(!s.grids.is_empty(), "mutation sources need grids");
    let mut regions = vec![("header", 0, s.grids[0].desc_start)];
    let mut boundaries = Vec::new();
    for g in &s.grids {
        let [grid_pos, block_pos, end_pos] = g.pos;
        // The grid metadata region starts with the compression flags.
        let meta_end = g.map.at;
        regions.push(("descriptor", g.desc_start, grid_pos));
        regions.push(("grid metadata", grid_pos, meta_end));
        regions.push(("transform", meta_end, g.xform_end));
        regions.push(("topology", g.xform_end, block_pos));
        regions.push(("buffers", block_pos, end_pos));
        for b in [
            g.desc_start,
            grid_pos,
            meta_end,
            g.xform_end,
            block_pos,
            end_pos,
        ] {
            boundaries.extend([b.saturating_sub(1), b, b + 1]);
        }
    }
    boundaries.retain(|&b| b < s.len);
    regions.retain(|r| r.1 < r.2);
    Layout {
        len: s.len,
        regions,
        boundaries,
        grids: s.grids.iter().map(|g| (g.desc_start, g.pos[2])).collect(),
    }
}

// ---------------------------------------------------------------------------------------------
// Byte-level cases
// ---------------------------------------------------------------------------------------------

fn extreme_bytes(rng: &mut rand_pcg::Pcg64) -> Vec<u8> {
    const V32: [u32; 7] = [
        0xFFFF_FFFF,
        0x7FFF_FFFF,
        0x8000_0000,
        0,
        1,
        0x7F80_0000,
        0xFFFF_FFFE,
    ];
    const V64: [u64; 6] = [
        u64::MAX,
        0x7FFF_FFFF_FFFF_FFFF,
        0x8000_0000_0000_0000,
        0,
        0x7FFF_FFFF,
        0x7FF0_0000_0000_0000, // +inf as f64
    ];
    match rng.gen_range(0..5) {
        0 | 1 => V32[rng.gen_range(0..V32.len())].to_le_bytes().to_vec(),
        2 | 3 => V64[rng.gen_range(0..V64.len())].to_le_bytes().to_vec(),
        _ => rng.gen::<u64>().to_le_bytes().to_vec(),
    }
}

fn make_cases(layouts: &[Layout]) -> Vec<Case> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(SEED);
    let mut cases = Vec::new();
    for (file, l) in layouts.iter().enumerate() {
        let byte_mutations = SOURCES[file].1;
        if byte_mutations == 0 {
            continue;
        }
        let mut push = |region, kind, mutation: Mutation| {
            let at = match &mutation {
                Mutation::Truncate(n) => *n,
                Mutation::Flip { at, .. } | Mutation::Overwrite { at, .. } => *at,
                Mutation::Patch(_) | Mutation::Rebuild(_) => unreachable!(),
            };
            cases.push(Case {
                file,
                region,
                kind,
                label: None,
                grid: l.grid_at(at),
                probe: None,
                mutation,
            });
        };
        for n in 0..DENSE_TRUNCATION_BYTES.min(l.len) {
            push("truncation (dense)", "truncation", Mutation::Truncate(n));
        }
        for &b in &l.boundaries {
            push("truncation (boundary)", "truncation", Mutation::Truncate(b));
        }
        for _ in 0..RANDOM_TRUNCATIONS_PER_FILE {
            push(
                "truncation (random)",
                "truncation",
                Mutation::Truncate(rng.gen_range(DENSE_TRUNCATION_BYTES..l.len)),
            );
        }
        for i in 0..byte_mutations {
            // Round-robin over the regions so small ones (header, descriptors) get their share.
            let region = REGIONS[i % REGIONS.len()];
            let spans: Vec<(u64, u64)> = l
                .regions
                .iter()
                .filter(|r| r.0 == region)
                .map(|r| (r.1, r.2))
                .collect();
            let (lo, hi) = spans[rng.gen_range(0..spans.len())];
            let at = rng.gen_range(lo..hi);
            if i < byte_mutations / 2 {
                let xor = if rng.gen_bool(0.5) {
                    1u8 << rng.gen_range(0..8)
                } else {
                    rng.gen_range(1..=255)
                };
                push(region, "flip", Mutation::Flip { at, xor });
            } else {
                let mut bytes = extreme_bytes(&mut rng);
                bytes.truncate((l.len - at) as usize);
                push(region, "overwrite", Mutation::Overwrite { at, bytes });
            }
        }
    }
    cases
}

// ---------------------------------------------------------------------------------------------
// Structure-aware cases
// ---------------------------------------------------------------------------------------------

const MAP_NAMES: &[&str] = &[
    "ScaleMap",
    "AffineMap",
    "TranslationMap",
    "UniformScaleMap",
    "ScaleTranslateMap",
    "UniformScaleTranslateMap",
    "UnitaryMap",
    "NonlinearFrustumMap",
    "SphericalMap",
    "",
];
const META_TYPES: &[&str] = &[
    "string", "int64", "int32", "bool", "float", "double", "vec3i", "vec3s", "vec3d", "mat4d",
];
const F64_VALUES: &[(&str, f64)] = &[
    ("0", 0.0),
    ("-0", -0.0),
    ("5e-324", 5e-324),
    ("1e-150", 1e-150),
    ("1e300", 1e300),
    ("NaN", f64::NAN),
    ("inf", f64::INFINITY),
    ("-inf", f64::NEG_INFINITY),
    ("1e17", 1e17),
];
const NAMES: [&str; 3] = ["grid_pos", "block_pos", "end_pos"];

/// Special values for every value of a leaf, as stored: f32, f64 or half bits.
fn special_values(s: &Stream) -> Vec<(&'static str, Vec<u8>)> {
    let half = s.half && s.vt.real();
    let f32s = [
        ("NaN", f32::NAN),
        ("inf", f32::INFINITY),
        ("-inf", f32::NEG_INFINITY),
        ("-1", -1.0),
        ("1e38", 1e38),
        ("f32::MAX", f32::MAX),
        ("1e-45", 1e-45),
    ];
    match (s.vt, half) {
        (Vt::Float | Vt::Double, true) => [
            ("NaN", 0x7E00u16),
            ("inf", 0x7C00),
            ("-inf", 0xFC00),
            ("-1", 0xBC00),
            ("65504", 0x7BFF),
            ("half subnormal", 0x0001),
        ]
        .iter()
        .map(|(l, v)| (*l, v.to_le_bytes().to_vec()))
        .collect(),
        (Vt::Float, false) => f32s
            .iter()
            .map(|(l, v)| (*l, v.to_le_bytes().to_vec()))
            .collect(),
        (Vt::Double, false) => f32s
            .iter()
            .map(|(l, v)| (*l, f64::from(*v).to_le_bytes().to_vec()))
            .chain([("1e300", 1e300f64.to_le_bytes().to_vec())])
            .collect(),
        _ => Vec::new(),
    }
}

/// 0.5 as stored: a half, an f32 or an f64 (`None` for other value types).
fn fill_value(s: &Stream) -> Option<Vec<u8>> {
    match (s.vt, s.half && s.vt.real()) {
        (Vt::Float | Vt::Double, true) => Some(0x3800u16.to_le_bytes().to_vec()),
        (Vt::Float, false) => Some(0.5f32.to_le_bytes().to_vec()),
        (Vt::Double, false) => Some(0.5f64.to_le_bytes().to_vec()),
        _ => None,
    }
}

/// First, middle and last index of a list of `n`.
fn pick(n: usize) -> Vec<usize> {
    let mut v = if n == 0 {
        Vec::new()
    } else {
        vec![0, n / 2, n - 1]
    };
    v.dedup();
    v
}

/// Mask edits: all ones, all zeros, the first set bit cleared, the first clear bit set.
fn mask_edits(words: &[u64]) -> Vec<(&'static str, Vec<u64>)> {
    let mut out = vec![
        ("all ones", vec![u64::MAX; words.len()]),
        ("all zeros", vec![0; words.len()]),
    ];
    let bit =
        |want: bool| (0..words.len() * 64).find(|&i| (words[i / 64] >> (i % 64) & 1 == 1) == want);
    for (label, found) in [
        ("first set bit cleared", bit(true)),
        ("first clear bit set", bit(false)),
    ] {
        if let Some(i) = found {
            let mut w = words.to_vec();
            w[i / 64] ^= 1 << (i % 64);
            out.push((label, w));
        }
    }
    out
}

fn words_le(w: &[u64]) -> Vec<u8> {
    w.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// Replace a length-prefixed string.
fn replace_str(s: Str, new: &[u8]) -> Edit {
    let mut insert = (new.len() as u32).to_le_bytes().to_vec();
    insert.extend_from_slice(new);
    Edit {
        at: s.at,
        remove: 4 + u64::from(s.len),
        insert,
    }
}

/// u32 count edits: 0, one less, one more, 2^31 - 1, 0xFFFFFFFF.
fn count_values(cur: u32) -> Vec<(String, u32)> {
    let mut v = vec![
        ("0".to_string(), 0),
        (format!("{}", cur.wrapping_add(1)), cur.wrapping_add(1)),
        ("2^31-1".into(), 0x7FFF_FFFF),
        ("0xFFFFFFFF".into(), u32::MAX),
    ];
    if cur > 1 {
        v.push((format!("{}", cur - 1), cur - 1));
    }
    v
}

/// Builds the structure-aware cases of one source file.
struct Gen<'a> {
    file: usize,
    /// The grid the next edits are in, and a point of the node they are in.
    gi: Option<usize>,
    probe: Option<[f64; 3]>,
    bytes: &'a [u8],
    s: &'a Structure,
    cases: Vec<Case>,
}

impl Gen<'_> {
    fn push(&mut self, region: &'static str, kind: &'static str, label: String, m: Mutation) {
        self.cases.push(Case {
            file: self.file,
            region,
            kind,
            label: Some(label),
            grid: self.gi,
            probe: self.probe,
            mutation: m,
        });
    }

    /// Overwrite `at` with `bytes`, unless that changes nothing.
    fn set(
        &mut self,
        region: &'static str,
        kind: &'static str,
        label: String,
        at: u64,
        bytes: Vec<u8>,
    ) {
        if self.bytes[at as usize..at as usize + bytes.len()] != bytes[..] {
            self.push(region, kind, label, Mutation::Overwrite { at, bytes });
        }
    }

    fn patch(
        &mut self,
        region: &'static str,
        kind: &'static str,
        label: String,
        p: Vec<(u64, Vec<u8>)>,
    ) {
        if p.iter()
            .any(|(at, b)| self.bytes[*at as usize..*at as usize + b.len()] != b[..])
        {
            self.push(region, kind, label, Mutation::Patch(p));
        }
    }

    /// Apply `edits` and move every descriptor offset that points past an edit by the length it
    /// added.
    fn rebuild(
        &mut self,
        region: &'static str,
        kind: &'static str,
        label: String,
        mut edits: Vec<Edit>,
    ) {
        let shift = |v: u64| -> i64 {
            edits
                .iter()
                .filter(|e| e.at + e.remove <= v)
                .map(|e| e.insert.len() as i64 - e.remove as i64)
                .sum()
        };
        let mut fix = Vec::new();
        for g in &self.s.grids {
            for (k, &v) in g.pos.iter().enumerate() {
                let d = shift(v);
                if d != 0 {
                    fix.push(Edit {
                        at: g.offsets_at + 8 * k as u64,
                        remove: 8,
                        insert: (v as i64 + d).to_le_bytes().to_vec(),
                    });
                }
            }
        }
        edits.extend(fix);
        self.push(region, kind, label, Mutation::Rebuild(edits));
    }

    fn meta(&mut self, region: &'static str, what: &str, m: &Meta) {
        let n = m.entries.len() as u32;
        for (l, v) in count_values(n) {
            let label = format!("{what} metadata count {n} -> {l}");
            self.set(
                region,
                "metadata count",
                label,
                m.count_at,
                v.to_le_bytes().to_vec(),
            );
        }
        for (i, e) in m.entries.iter().enumerate() {
            let name = e.name.text(self.bytes);
            for (field, s) in [("name", e.name), ("type", e.ty), ("value", e.value)] {
                for (l, v) in [
                    ("0", 0),
                    ("len+1", s.len + 1),
                    ("2^31-1", 0x7FFF_FFFF),
                    ("0xFFFFFFFF", u32::MAX),
                ] {
                    let label = format!("{what} metadata '{name}' {field} length {} -> {l}", s.len);
                    self.set(
                        region,
                        "metadata length",
                        label,
                        s.at,
                        v.to_le_bytes().to_vec(),
                    );
                }
            }
            let ty = e.ty.text(self.bytes);
            let others: Vec<&str> = META_TYPES.iter().copied().filter(|t| *t != ty).collect();
            let k = others.len() - 1;
            let mut picks = vec![others[0], others[1 + i % k], others[1 + (i + 4) % k]];
            picks.dedup();
            for new in picks {
                let label = format!("{what} metadata '{name}' type {ty} -> {new}");
                self.rebuild(
                    region,
                    "metadata type",
                    label,
                    vec![replace_str(e.ty, new.as_bytes())],
                );
            }
            if name == "class" {
                let cur = e.value.text(self.bytes);
                for new in ["level set", "fog volume", "", "unknown"] {
                    if new != cur {
                        let label = format!("{what} metadata class '{cur}' -> '{new}'");
                        let edit = replace_str(e.value, new.as_bytes());
                        self.rebuild(region, "metadata class", label, vec![edit]);
                    }
                }
            }
        }
    }

    fn header(&mut self) {
        let s = self.s;
        let n = s.grids.len() as u32;
        let mut seen = vec![n];
        for (l, v) in [
            ("0", 0u32),
            ("count+1", n + 1),
            ("count-1", n - 1),
            ("2^31-1", 0x7FFF_FFFF),
            ("2^31", 0x8000_0000),
            ("-1", u32::MAX),
        ] {
            if seen.contains(&v) {
                continue;
            }
            seen.push(v);
            let label = format!("grid count {n} -> {l}");
            self.set(
                "header",
                "grid count",
                label,
                s.grid_count_at,
                v.to_le_bytes().to_vec(),
            );
        }
        self.meta("header", "file", &s.file_meta);
    }

    fn descriptor(&mut self, gi: usize) {
        let s = self.s;
        let g = &s.grids[gi];
        let len = s.len as i64;
        for (k, name) in NAMES.iter().enumerate() {
            let cur = g.pos[k] as i64;
            let mut vals: Vec<(String, i64)> = vec![
                ("0".into(), 0),
                ("pos-1".into(), cur - 1),
                ("pos+1".into(), cur + 1),
                ("own descriptor start".into(), g.desc_start as i64),
                ("file_len".into(), len),
                ("file_len+1".into(), len + 1),
                ("i64::MAX".into(), i64::MAX),
                ("-1".into(), -1),
            ];
            for j in (0..3).filter(|&j| j != k) {
                vals.push((format!("own {}", NAMES[j]), g.pos[j] as i64));
            }
            let n = s.grids.len();
            let others = [(gi + n - 1) % n, (gi + 1) % n];
            for o in others.into_iter().filter(|&o| o != gi) {
                let og = &s.grids[o];
                vals.push((format!("grid {o}'s {name}"), og.pos[k] as i64));
                vals.push((format!("grid {o}'s descriptor start"), og.desc_start as i64));
            }
            let mut seen = Vec::new();
            for (l, v) in vals {
                if seen.contains(&v) {
                    continue;
                }
                seen.push(v);
                let label = format!("grid {gi} {name} {cur} -> {l} ({v})");
                let at = g.offsets_at + 8 * k as u64;
                self.set(
                    "descriptor",
                    "descriptor offset",
                    label,
                    at,
                    v.to_le_bytes().to_vec(),
                );
            }
        }
        // Descriptor chains that loop: every offset at a descriptor start, with grid counts that
        // make the reader go round.
        let n = s.grids.len() as u32;
        let mut targets = vec![("its own descriptor", g.desc_start)];
        if gi > 0 {
            targets.push(("grid 0's descriptor", s.grids[0].desc_start));
        }
        for (t, start) in targets {
            // A loop with 2^31 - 1 grids runs until the reader bounds the count (or the case
            // times out): only on a few sources, to keep the suite's time bounded while it fails.
            let huge = gi == 0 && self.file.is_multiple_of(3);
            for (l, count) in [
                ("unchanged", n),
                ("count+1", n + 1),
                ("count+1000", n + 1000),
                ("2^31-1", 0x7FFF_FFFF),
            ] {
                if count == 0x7FFF_FFFF && !huge {
                    continue;
                }
                let label =
                    format!("grid {gi} offsets all -> {t} start ({start}), grid count -> {l}");
                let offsets = [start; 3].map(|v| v.to_le_bytes()).concat();
                let mut p = vec![(g.offsets_at, offsets)];
                if count != n {
                    p.push((s.grid_count_at, count.to_le_bytes().to_vec()));
                }
                self.patch("descriptor", "descriptor loop", label, p);
            }
        }
        for (field, st) in [
            ("name", g.name),
            ("type", g.ty),
            ("instance parent", g.parent),
        ] {
            for (l, v) in [("0", 0), ("len+1", st.len + 1), ("0xFFFFFFFF", u32::MAX)] {
                let label = format!("grid {gi} {field} length {} -> {l}", st.len);
                self.set(
                    "descriptor",
                    "descriptor string",
                    label,
                    st.at,
                    v.to_le_bytes().to_vec(),
                );
            }
        }
        let ty = g.ty.text(self.bytes);
        let toggled = match ty.strip_suffix("_HalfFloat") {
            Some(t) => t.to_string(),
            None => format!("{ty}_HalfFloat"),
        };
        let swapped = if ty.contains("float") {
            ty.replace("float", "double")
        } else {
            "Tree_float_5_4_3".to_string()
        };
        for new in [
            toggled,
            swapped,
            "Tree_vec3s_5_4_3".into(),
            "Tree_bool_5_4_3".into(),
            "Tree_float_5_4_4".into(),
            "Tree_float".into(),
        ] {
            if new != ty {
                let label = format!("grid {gi} tree type {ty} -> {new}");
                let edit = replace_str(g.ty, new.as_bytes());
                self.rebuild("descriptor", "tree type", label, vec![edit]);
            }
        }
    }

    fn grid_head(&mut self, gi: usize) {
        let g = &self.s.grids[gi];
        for v in (0..=7u32).chain([u32::MAX]) {
            let label = format!("grid {gi} compression flags {} -> {v:#x}", g.flags);
            self.set(
                "grid metadata",
                "compression flags",
                label,
                g.pos[0],
                v.to_le_bytes().to_vec(),
            );
        }
        self.meta("grid metadata", &format!("grid {gi}"), &g.meta);
        for new in MAP_NAMES.iter().filter(|m| **m != g.map_name) {
            let label = format!("grid {gi} map {} -> '{new}'", g.map_name);
            self.rebuild(
                "transform",
                "map name",
                label,
                vec![replace_str(g.map, new.as_bytes())],
            );
        }
        // The parameters that define the map get every value; the derived ones (voxel size,
        // inverse scales) and the projective column of a matrix get 0, NaN and 1e300.
        let defining = |p: usize| match g.map_name.as_str() {
            "UniformScaleMap" | "ScaleMap" | "TranslationMap" => p < 3,
            "UniformScaleTranslateMap" | "ScaleTranslateMap" => p < 6,
            "AffineMap" | "UnitaryMap" => p % 4 != 3,
            _ => true,
        };
        for (p, &at) in g.params.iter().enumerate() {
            let cur =
                f64::from_le_bytes(self.bytes[at as usize..at as usize + 8].try_into().unwrap());
            let values = F64_VALUES
                .iter()
                .filter(|(l, _)| defining(p) || matches!(*l, "0" | "NaN" | "1e300"));
            for (l, v) in values {
                let label = format!("grid {gi} {} parameter {p} ({cur}) -> {l}", g.map_name);
                self.set(
                    "transform",
                    "map parameter",
                    label,
                    at,
                    v.to_le_bytes().to_vec(),
                );
            }
        }
        // Scales and translations, all three at once.
        let (scale, translation): (&[usize], &[usize]) = match g.map_name.as_str() {
            "UniformScaleMap" | "ScaleMap" => (&[0, 1, 2], &[]),
            "UniformScaleTranslateMap" | "ScaleTranslateMap" => (&[3, 4, 5], &[0, 1, 2]),
            "TranslationMap" => (&[], &[0, 1, 2]),
            "AffineMap" | "UnitaryMap" => (&[0, 5, 10], &[12, 13, 14]),
            _ => (&[], &[]),
        };
        for (what, idx, values) in [
            (
                "scale",
                scale,
                &[1e-150, 1e-110, 1e110, 1e17, 5e-324, -1.0][..],
            ),
            (
                "translation",
                translation,
                &[1e17, 1e300, -1e300, f64::NAN][..],
            ),
        ] {
            if idx.is_empty() {
                continue;
            }
            for &v in values {
                let label = format!("grid {gi} {} {what} all -> {v:e}", g.map_name);
                let p = idx
                    .iter()
                    .map(|&i| (g.params[i], v.to_le_bytes().to_vec()))
                    .collect();
                self.patch("transform", "map parameters (together)", label, p);
            }
        }
    }

    fn values(&mut self, region: &'static str, what: &str, v: &Values, s: &Stream) {
        for m in (0..=6u8).chain([255]) {
            let label = format!("{what} metadata byte -> {m}");
            self.set(region, "node metadata byte", label, v.meta_at, vec![m]);
        }
        if let Some((at, cur, _)) = v.size {
            let n = v.nbytes as i64;
            for (l, x) in [
                ("0", 0),
                ("-1", -1),
                ("i64::MAX", i64::MAX),
                ("i64::MIN", i64::MIN),
                ("size+1", cur + 1),
                ("size-1", cur - 1),
                ("2^40", 1 << 40),
                ("-(raw bytes)", -n),
            ] {
                let label = format!("{what} compressed size {cur} -> {l}");
                self.set(
                    region,
                    "compressed size",
                    label,
                    at,
                    x.to_le_bytes().to_vec(),
                );
            }
        }
        // Every value special, or 0.5 with every 7th special (mixed nodes: trilinear cells with
        // one infinite or NaN corner): a compressed block is rewritten raw (a non-positive size
        // prefix).
        let elem = s.vt.array_size(s.half);
        let n = v.nbytes / elem;
        let mut blocks: Vec<(String, Vec<u8>)> = Vec::new();
        for (l, val) in special_values(s) {
            blocks.push((format!("values all -> {l}"), val.repeat(n)));
        }
        if let Some(fill) = fill_value(s) {
            let mixed = special_values(s)
                .into_iter()
                .filter(|(l, _)| matches!(*l, "NaN" | "inf" | "-1" | "f32::MAX" | "65504"));
            for (l, val) in mixed {
                let b = (0..n).flat_map(|i| {
                    if i % 7 == 0 {
                        val.clone()
                    } else {
                        fill.clone()
                    }
                });
                blocks.push((format!("values 0.5, every 7th -> {l}"), b.collect()));
            }
        }
        if n == 0 || v.nbytes > 1 << 18 {
            return;
        }
        for (l, block) in blocks {
            let label = format!("{what} {l}");
            match (v.size, v.raw_at) {
                (Some((at, _, end)), _) => {
                    let mut insert = (-(v.nbytes as i64)).to_le_bytes().to_vec();
                    insert.extend(block);
                    let edit = Edit {
                        at,
                        remove: end - at,
                        insert,
                    };
                    self.rebuild(
                        region,
                        "node values",
                        format!("{label} (block stored raw)"),
                        vec![edit],
                    );
                }
                (None, Some(at)) => self.set(region, "node values", label, at, block),
                (None, None) => {}
            }
        }
    }

    /// Origin edits: +1 and +4096 on each axis; with `extreme`, also `i32::MIN` and
    /// `i32::MAX - 4095` on each axis, and on all three at once. An origin at the far end of
    /// index space makes the value box ~2^32 voxels wide: while tracing across it is slow, the
    /// all-axes edits each take most of `SLOW_CASE`, so they run on a few sources only.
    fn origin(
        &mut self,
        gi: usize,
        what: &str,
        at: u64,
        cur: [i32; 3],
        kind: &'static str,
        extreme: bool,
    ) {
        for (a, &c) in cur.iter().enumerate() {
            let mut values = vec![
                ("+1 (not a multiple of 4096)", c.wrapping_add(1)),
                ("+4096", c.wrapping_add(4096)),
            ];
            if extreme {
                values.extend([("i32::MIN", i32::MIN), ("i32::MAX-4095", i32::MAX - 4095)]);
            }
            for (l, v) in values {
                let label = format!("grid {gi} {what} origin[{a}] {c} -> {l}");
                self.set(
                    "topology",
                    kind,
                    label,
                    at + 4 * a as u64,
                    v.to_le_bytes().to_vec(),
                );
            }
        }
        let all_axes = extreme && (kind == "root tile" || self.file.is_multiple_of(3));
        for (l, v) in [("i32::MIN", i32::MIN), ("i32::MAX-4095", i32::MAX - 4095)] {
            if !all_axes {
                continue;
            }
            let label = format!("grid {gi} {what} origin {cur:?} -> all {l}");
            let bytes = [v; 3].map(i32::to_le_bytes).concat();
            self.set("topology", kind, label, at, bytes);
        }
    }

    fn topology(&mut self, gi: usize) {
        let g = &self.s.grids[gi];
        let t = &g.topo;
        let s = g.stream;
        if g.parent.len != 0 {
            return;
        }
        for v in [0i32, 2, -1] {
            let label = format!("grid {gi} buffer count 1 -> {v}");
            self.set(
                "topology",
                "buffer count",
                label,
                t.buffer_count_at,
                v.to_le_bytes().to_vec(),
            );
        }
        for (l, v) in special_values(&Stream { half: false, ..s }) {
            let label = format!("grid {gi} background -> {l}");
            self.set("topology", "background", label, t.background_at, v);
        }
        for (what, at, cur) in [
            ("root tile count", t.root_tiles_at, t.root_tiles),
            ("root child count", t.root_children_at, t.root_children),
        ] {
            for (l, v) in count_values(cur) {
                let label = format!("grid {gi} {what} {cur} -> {l}");
                self.set(
                    "topology",
                    "root counts",
                    label,
                    at,
                    v.to_le_bytes().to_vec(),
                );
            }
        }
        for i in pick(t.tiles.len()) {
            let at = t.tiles[i];
            let cur = [0, 4, 8].map(|o| {
                i32::from_le_bytes(self.bytes[(at + o) as usize..][..4].try_into().unwrap())
            });
            self.probe = Some(cur.map(|c| f64::from(c) + 2048.0));
            self.origin(gi, &format!("root tile {i}"), at, cur, "root tile", i == 0);
            let value_at = at + 12;
            for (l, v) in special_values(&Stream { half: false, ..s }) {
                let label = format!("grid {gi} root tile {i} value -> {l}");
                self.set("topology", "root tile", label, value_at, v);
            }
            let state_at = value_at + s.vt.size() as u64;
            for v in [0u8, 1, 255] {
                let label = format!("grid {gi} root tile {i} active byte -> {v}");
                self.set("topology", "root tile", label, state_at, vec![v]);
            }
        }
        self.probe = None;
        for i in pick(t.children.len()) {
            let (at, cur) = t.children[i];
            let extreme = i == 0 && gi == 0;
            self.origin(
                gi,
                &format!("root child {i}"),
                at,
                cur,
                "root origin",
                extreme,
            );
        }
        if t.children.len() >= 2 {
            let (at, _) = t.children[t.children.len() - 1];
            let (_, first) = t.children[0];
            let label = format!("grid {gi} last root child origin -> the first's {first:?}");
            let bytes = first.map(i32::to_le_bytes).concat();
            self.set("topology", "root origin", label, at, bytes);
        }
        if let (Some(&tile), Some(&(at, _))) = (t.tiles.first(), t.children.first()) {
            let label = format!("grid {gi} first root child origin -> the first root tile's");
            let bytes = self.bytes[tile as usize..tile as usize + 12].to_vec();
            self.set("topology", "root origin", label, at, bytes);
        }
        let uppers: Vec<usize> = (0..t.nodes.len()).filter(|&i| t.nodes[i].upper).collect();
        let lowers: Vec<usize> = (0..t.nodes.len()).filter(|&i| !t.nodes[i].upper).collect();
        let mut chosen: Vec<usize> = [0, uppers.len().saturating_sub(1)]
            .iter()
            .filter_map(|&i| uppers.get(i).copied())
            .collect();
        chosen.extend(pick(lowers.len()).into_iter().map(|i| lowers[i]));
        chosen.dedup();
        for ni in chosen {
            let node = &t.nodes[ni];
            let what = format!(
                "grid {gi} {} node {ni}",
                if node.upper { "upper" } else { "lower" }
            );
            // Probe the centre of the node's first tile (a slot without a child), if any.
            let (side, child) = if node.upper { (5, 7) } else { (4, 3) };
            let tile = (0..node.child_mask.len() * 64)
                .find(|&i| node.child_mask[i / 64] >> (i % 64) & 1 == 0)
                .unwrap_or(0);
            let local = [
                tile >> (2 * side),
                (tile >> side) & ((1 << side) - 1),
                tile & ((1 << side) - 1),
            ];
            self.probe = Some([0, 1, 2].map(|a| {
                f64::from(node.origin[a])
                    + ((local[a] << child) as f64)
                    + f64::from(1 << (child - 1))
            }));
            for (mask, at, words) in [
                ("child", node.child_mask_at, &node.child_mask),
                ("value", node.value_mask_at, &node.value_mask),
            ] {
                for (l, w) in mask_edits(words) {
                    let label = format!("{what} {mask} mask {l}");
                    self.set("topology", "internal mask", label, at, words_le(&w));
                }
            }
            self.values(
                "topology",
                &format!("{what} tile values"),
                &node.values.clone(),
                &s,
            );
        }
        for li in pick(t.leaves.len()) {
            let leaf = &t.leaves[li];
            let what = format!("grid {gi} leaf {li}");
            self.probe = Some(leaf.origin.map(|c| f64::from(c) + 4.0));
            for (l, w) in mask_edits(&leaf.mask) {
                let label = format!("{what} value mask (topology) {l}");
                self.set(
                    "topology",
                    "leaf mask",
                    label,
                    leaf.topo_mask_at,
                    words_le(&w),
                );
            }
            for (l, w) in mask_edits(&leaf.mask) {
                let label = format!("{what} value mask (topology and buffer) {l}");
                let p = vec![
                    (leaf.topo_mask_at, words_le(&w)),
                    (leaf.buf_mask_at, words_le(&w)),
                ];
                self.patch("buffers", "leaf mask (both copies)", label, p);
            }
            if let Some((l, w)) = mask_edits(&leaf.mask).pop() {
                let label = format!("{what} value mask (buffer copy) {l}");
                self.set(
                    "buffers",
                    "leaf mask (buffer copy)",
                    label,
                    leaf.buf_mask_at,
                    words_le(&w),
                );
            }
            if let Some(v) = leaf.values.clone() {
                self.values("buffers", &what, &v, &s);
            }
        }
        self.probe = None;
    }

    /// Grid instancing: make a grid share another's tree.
    fn instances(&mut self) {
        let s = self.s;
        let n = s.grids.len();
        if n < 2 {
            return;
        }
        let name = |i: usize| s.grids[i].name.bytes(self.bytes).to_vec();
        let parent = |i: usize, p: &[u8]| replace_str(s.grids[i].parent, p);
        let mut sets: Vec<(String, Vec<Edit>)> = vec![
            (
                "grid 1 -> instance of grid 0".into(),
                vec![parent(1, &name(0))],
            ),
            (
                "grid 1 -> instance of itself".into(),
                vec![parent(1, &name(1))],
            ),
            (
                "grid 0 -> instance of grid 1".into(),
                vec![parent(0, &name(1))],
            ),
            (
                "grids 0 and 1 -> instances of each other".into(),
                vec![parent(0, &name(1)), parent(1, &name(0))],
            ),
            (
                "grid 1 -> instance of a missing grid".into(),
                vec![parent(1, b"no such grid")],
            ),
        ];
        if n >= 3 {
            sets.push((
                "grid 2 -> instance of grid 1 -> instance of grid 0".into(),
                vec![parent(2, &name(1)), parent(1, &name(0))],
            ));
            sets.push((
                format!("grid {} -> instance of grid 0", n - 1),
                vec![parent(n - 1, &name(0))],
            ));
        }
        for (label, edits) in sets {
            // Trace the grid whose parent changed first.
            self.gi = s.grids.iter().position(|g| g.parent.at == edits[0].at);
            self.rebuild("descriptor", "instance", label, edits);
        }
    }
}

/// The grids of a file that get per-grid edits: the first, the last, the first float fog grid
/// and the first grid whose value type differs from the first's.
fn focus_grids(s: &Structure) -> Vec<usize> {
    let n = s.grids.len();
    let mut f = vec![0, n - 1];
    let fog = s
        .grids
        .iter()
        .position(|g| g.stream.vt == Vt::Float && g.class.as_deref() == Some("fog volume"));
    let other = s
        .grids
        .iter()
        .position(|g| g.stream.vt != s.grids[0].stream.vt);
    f.extend(fog);
    f.extend(other);
    f.sort_unstable();
    f.dedup();
    f
}

fn structure_cases(file: usize, bytes: &[u8], s: &Structure) -> Vec<Case> {
    let mut g = Gen {
        file,
        gi: None,
        probe: None,
        bytes,
        s,
        cases: Vec::new(),
    };
    g.header();
    for gi in focus_grids(s) {
        g.gi = Some(gi);
        g.descriptor(gi);
        g.grid_head(gi);
        g.topology(gi);
    }
    g.instances();
    g.cases
}

/// The originals, and every case: byte-level ones first, then structure-aware ones.
fn all_cases(dir: &Path) -> (Vec<Vec<u8>>, Vec<Case>) {
    let originals: Vec<Vec<u8>> = SOURCES
        .iter()
        .map(|f| std::fs::read(dir.join(f.0)).unwrap())
        .collect();
    let structures: Vec<Structure> = originals.iter().map(|b| parse(b)).collect();
    let layouts: Vec<Layout> = structures.iter().map(layout).collect();
    let mut cases = make_cases(&layouts);
    for (file, (b, s)) in originals.iter().zip(&structures).enumerate() {
        cases.extend(structure_cases(file, b, s));
    }
    (originals, cases)
}

// ---------------------------------------------------------------------------------------------
// Running one case: load, trace, bake
// ---------------------------------------------------------------------------------------------

/// What one case did. Made by a worker (serialised as one line of JSON) or, for a case that
/// killed its worker, by the supervisor.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
struct Report {
    /// Error kind of `open`, if it failed.
    open_err: Option<String>,
    /// Grids loaded Ok and grids that failed to load.
    loaded: usize,
    load_failed: usize,
    /// Grids made a `Volume`.
    volumes: usize,
    /// Rays traced (and refused by `Ray::new` because the box maps to non-finite world points).
    rays: usize,
    rays_refused: usize,
    /// Maps baked.
    bakes: usize,
    /// Typed errors by step and kind ("load: Invalid", "bake: InvalidArgument").
    errors: BTreeMap<String, usize>,
    /// What went wrong: panics, wrong error kinds, bad results with `Ok`.
    problems: Vec<String>,
    /// The worker died or was killed on this case.
    killed: bool,
    micros: u64,
    /// Time per step (summed over grids).
    stage_micros: BTreeMap<String, u64>,
    peak_rss: u64,
}

/// Where a case is (step and grid) and how long each step took, mirrored in [`STAGE`] for the
/// worker's watchdog.
struct Stage {
    now: Cell<(&'static str, Instant)>,
    grid: std::cell::RefCell<String>,
    micros: std::cell::RefCell<BTreeMap<String, u64>>,
}

impl Stage {
    fn new() -> Self {
        let s = Self {
            now: Cell::new(("open", Instant::now())),
            grid: std::cell::RefCell::default(),
            micros: std::cell::RefCell::default(),
        };
        s.set("open");
        s
    }

    /// The grid the next steps work on.
    fn grid(&self, name: &str) {
        name.clone_into(&mut self.grid.borrow_mut());
    }

    fn set(&self, step: &'static str) {
        self.close();
        self.now.set((step, Instant::now()));
        *STAGE.lock().unwrap_or_else(|e| e.into_inner()) = self.describe();
    }

    fn close(&self) {
        let (step, since) = self.now.get();
        let us = since.elapsed().as_micros() as u64;
        *self.micros.borrow_mut().entry(step.into()).or_default() += us;
        self.now.set((step, Instant::now()));
    }

    fn describe(&self) -> String {
        let grid = self.grid.borrow();
        match self.now.get().0 {
            s @ "open" => s.to_string(),
            s => format!("{s} of grid '{grid}'"),
        }
    }
}

impl Report {
    fn error(&mut self, step: &str, e: &umbra::Error) -> &'static str {
        let k = kind(e);
        *self.errors.entry(format!("{step}: {k}")).or_default() += 1;
        k
    }

    fn killed(problem: String) -> Self {
        Self {
            killed: true,
            problems: vec![problem],
            ..Self::default()
        }
    }
}

fn kind(e: &umbra::Error) -> &'static str {
    match e {
        umbra::Error::Io { .. } => "Io",
        umbra::Error::NotVdb { .. } => "NotVdb",
        umbra::Error::Invalid { .. } | umbra::Error::InvalidNanoVdb { .. } => "Invalid",
        umbra::Error::Unsupported { .. } | umbra::Error::LevelSet { .. } => "Unsupported",
        umbra::Error::GridNotFound { .. } => "GridNotFound",
        umbra::Error::InvalidArgument { .. } => "InvalidArgument",
        umbra::Error::Output { .. } => "Output",
        umbra::Error::Exists { .. } => "Exists",
        umbra::Error::NotANumber { .. } => "NotANumber",
        _ => "other",
    }
}

/// Open `path`, load every grid (and report on it as `umbra info` does), and trace and bake every
/// float or double grid that loads; panics are caught and reported with the step they hit.
fn check_mutant(path: &Path, case: &Case, out: &Path) -> Report {
    let mut rep = Report::default();
    let stage = Stage::new();
    PANIC_SITES
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .clear();
    let r = catch_unwind(AssertUnwindSafe(|| {
        load_and_trace(path, case, out, &stage, &mut rep)
    }));
    if let Err(p) = r {
        let sites = PANIC_SITES
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .join("; ");
        rep.problems.push(format!(
            "PANIC during {}: {} [{sites}]",
            stage.describe(),
            panic_message(p.as_ref())
        ));
    }
    stage.close();
    rep.stage_micros = stage.micros.take();
    rep
}

fn load_and_trace(path: &Path, case: &Case, out: &Path, stage: &Stage, rep: &mut Report) {
    stage.set("open");
    let a = match umbra::internals::vdb::open(path) {
        Ok(a) => a,
        Err(e) => {
            let k = rep.error("open", &e);
            rep.open_err = Some(k.into());
            if !matches!(k, "NotVdb" | "Invalid" | "Unsupported") {
                rep.problems
                    .push(format!("open: unexpected error kind {k}: {e}"));
            }
            return;
        }
    };
    let mut traced = false;
    for (i, gd) in a.grids.iter().enumerate() {
        stage.grid(&gd.display_name);
        stage.set("load");
        match a.load(gd) {
            Ok(g) => {
                stage.set("info");
                std::hint::black_box(GridInfo::from_grid(&g, &gd.tree_type));
                rep.loaded += 1;
                let target = case.grid == Some(i);
                if g.value_type.is_scalar_real() && (!traced || target) {
                    let probe = case.probe.filter(|_| target);
                    traced |= trace_grid(path, g, probe, out, stage, rep);
                }
            }
            Err(e) => {
                rep.load_failed += 1;
                let k = rep.error("load", &e);
                // A regular, readable file can only be not-a-VDB, corrupt or unsupported.
                if !matches!(k, "NotVdb" | "Invalid" | "Unsupported") {
                    let d = &gd.display_name;
                    rep.problems
                        .push(format!("load '{d}': unexpected error kind {k}: {e}"));
                }
            }
        }
    }
}

/// The rays of a volume: through the centre of its volume box along each index axis (segments
/// from one voxel outside to one voxel outside), the diagonal from one voxel outside the low
/// corner, to infinity, and through `probe` (index space, the node a case edited) if given, along
/// (1, 0.7, 0.4) across the whole box. A volume holding only its background gets the box
/// [-1, 9]^3.
fn probe_rays(vol: &Volume, probe: Option<[f64; 3]>) -> Vec<umbra::Result<Ray>> {
    let (lo, hi) = vol
        .box_index()
        .unwrap_or((DVec3::splat(-1.0), DVec3::splat(9.0)));
    let c = (lo + hi) * 0.5;
    let mut rays: Vec<umbra::Result<Ray>> = (0..3)
        .map(|a| {
            let (mut p0, mut p1) = (c, c);
            p0[a] = lo[a] - 1.0;
            p1[a] = hi[a] + 1.0;
            Ray::between(vol.to_world(p0), vol.to_world(p1))
        })
        .collect();
    let o = vol.to_world(lo - 1.0);
    rays.push(Ray::new(o, vol.to_world(hi + 1.0) - o, 0.0, f64::INFINITY));
    if let Some(p) = probe {
        let (p, d) = (DVec3::from_array(p), DVec3::new(1.0, 0.7, 0.4));
        let reach = (hi - lo).length() + 2.0;
        rays.push(Ray::between(
            vol.to_world(p - d * reach),
            vol.to_world(p + d * reach),
        ));
    }
    rays
}

/// Make `grid` a volume, trace and bake it; whether it became a volume.
fn trace_grid(
    path: &Path,
    grid: Grid,
    probe: Option<[f64; 3]>,
    out: &Path,
    stage: &Stage,
    rep: &mut Report,
) -> bool {
    let name = grid.name.clone();
    stage.set("Volume::new");
    let vol = match Volume::new(grid, 1.0, path) {
        Ok(v) => v,
        Err(e) => {
            let k = rep.error("volume", &e);
            if !matches!(k, "Invalid" | "Unsupported") {
                rep.problems.push(format!(
                    "grid '{name}': Volume::new: unexpected error kind {k}: {e}"
                ));
            }
            return false;
        }
    };
    rep.volumes += 1;
    let ratio = Estimator::from_name("ratio").unwrap();
    let opts = Options {
        interp: Interp::Trilinear,
        samples: 4,
        seed: SEED,
        max_collisions: MAX_COLLISIONS,
        ..Options::default()
    };
    for (r, ray) in probe_rays(&vol, probe).into_iter().enumerate() {
        let ray = match ray {
            Ok(ray) => ray,
            Err(e) => {
                rep.error("ray", &e);
                rep.rays_refused += 1;
                continue;
            }
        };
        rep.rays += 1;
        for interp in [Interp::Nearest, Interp::Trilinear] {
            stage.set(match interp {
                Interp::Nearest => "optical_depth (nearest)",
                Interp::Trilinear => "optical_depth (trilinear)",
            });
            match optical_depth(&vol, &ray, interp) {
                Ok(od) if od.tau.is_nan() || od.tau < 0.0 || od.transmittance().is_nan() => {
                    rep.problems.push(format!(
                        "grid '{name}' ray {r}: non-finite result with Ok: optical_depth \
                         ({interp:?}) tau = {}",
                        od.tau
                    ));
                }
                Ok(_) => {}
                Err(e) => {
                    rep.error("optical_depth", &e);
                }
            }
        }
        stage.set("estimate (ratio)");
        match estimate(&vol, &ray, r as u64, &ratio, &opts) {
            Ok(e) => {
                let bad = if !(e.value.is_finite() && e.std_err.is_finite()) {
                    Some("non-finite result with Ok")
                } else if !ratio.may_leave_unit_interval() && !(0.0..=1.0).contains(&e.value) {
                    Some("transmittance outside [0, 1] with Ok")
                } else if e.majorant_violations > 0 {
                    Some("majorant violations")
                } else {
                    None
                };
                if let Some(b) = bad {
                    rep.problems.push(format!(
                        "grid '{name}' ray {r}: {b}: estimate (ratio) T = {} +- {}, {} \
                         majorant violations",
                        e.value, e.std_err, e.majorant_violations
                    ));
                }
            }
            Err(e) => {
                rep.error("estimate", &e);
            }
        }
    }
    lazy_matches(path, &name, &vol, probe, &ratio, &opts, stage, rep);
    bake_grid(path, vol, &name, out, stage, rep);
    true
}

/// The same grid opened lazily: the leaves the probe rays touch, decoded alone, must load
/// (the whole grid did) and answer exactly as the eager volume `vol` does.
#[allow(clippy::too_many_arguments)]
fn lazy_matches(
    path: &Path,
    name: &str,
    vol: &Volume,
    probe: Option<[f64; 3]>,
    est: &Estimator,
    opts: &Options,
    stage: &Stage,
    rep: &mut Report,
) {
    stage.set("lazy: open");
    let lazy = umbra::internals::vdb::open(path)
        .and_then(|a| a.find_grid(name).cloned().and_then(|gd| a.open_lazy(&gd)));
    let lazy = match lazy {
        Ok(l) => l,
        Err(e) => {
            rep.problems
                .push(format!("grid '{name}': loads eagerly but not lazily: {e}"));
            return;
        }
    };
    let rays: Vec<Ray> = probe_rays(vol, probe).into_iter().flatten().collect();
    stage.set("lazy: touched leaves");
    let Ok(shell) = Volume::new(lazy.shell().clone(), 1.0, path) else {
        rep.problems
            .push(format!("grid '{name}': its shell is not a volume"));
        return;
    };
    let leaves = umbra::internals::demand::leaves_touched(
        &shell,
        &rays,
        Interp::Trilinear,
        umbra::internals::traverse::Granularity::Leaf,
    );
    stage.set("lazy: partial load");
    let part = match lazy.load(&leaves).and_then(|g| Volume::new(g, 1.0, path)) {
        Ok(v) => v,
        Err(e) => {
            rep.problems
                .push(format!("grid '{name}': partial load failed: {e}"));
            return;
        }
    };
    stage.set("lazy: answers");
    for (r, ray) in rays.iter().enumerate() {
        let same = match (
            estimate(vol, ray, r as u64, est, opts),
            estimate(&part, ray, r as u64, est, opts),
        ) {
            (Ok(a), Ok(b)) => a.value.to_bits() == b.value.to_bits() && a.lookups == b.lookups,
            (Err(a), Err(b)) => a.to_string() == b.to_string(),
            _ => false,
        };
        if !same {
            rep.problems.push(format!(
                "grid '{name}' ray {r}: the partial load answers differently"
            ));
        }
    }
}

/// An 8x8 ortho map of `vol` through the bake pipeline (`BakeJob::run_on`: bake, warnings, EXR
/// and PNG written).
fn bake_grid(path: &Path, vol: Volume, name: &str, out: &Path, stage: &Stage, rep: &mut Report) {
    let view = View {
        projection: Projection::Ortho,
        light_dir: Some([0.3, -1.0, 0.45]),
        light_pos: None,
        fov_deg: None,
        res: Some(Resolution::Exact(8, 8)),
        up: None,
        frame_box: None,
    };
    let est = Estimator::from_name("ratio").unwrap();
    let mut settings = BakeSettings::new(
        est,
        Options {
            interp: Interp::Trilinear,
            samples: 2,
            seed: SEED,
            max_collisions: MAX_COLLISIONS,
            ..Options::default()
        },
    );
    settings.std_err = true;
    settings.depths = Depths::Slices(2);
    stage.set("bake: box corners");
    let corners = match vol.box_corners() {
        Ok(c) => c,
        Err(e) => {
            rep.error("box corners", &e);
            return;
        }
    };
    stage.set("bake: camera");
    let camera = match Camera::frame(&view, &corners) {
        Ok(c) => c,
        Err(e) => {
            rep.error("camera", &e);
            return;
        }
    };
    let job = BakeJob {
        source: umbra::input::Source::new(
            path.to_path_buf(),
            umbra::input::SourceOptions {
                grid: name.to_string(),
                density_scale: 1.0,
                ..umbra::input::SourceOptions::default()
            },
        ),
        view,
        camera: None,
        settings,
        output: out.join("map.exr"),
        preview: Some(out.join("map.png")),
        overwrite: true,
        max_memory: None,
        layout: umbra::bake::ExrLayout::default(),
        product: umbra::bake::Product::Map,
        key: None,
    };
    stage.set("bake");
    match job.run_loaded(&umbra::scene::Scene::from_volume(vol), camera, &|_| {}) {
        Ok(report) => {
            rep.bakes += 1;
            let m = &report.map;
            let t_ok = |v: &f32| {
                v.is_finite() && (est.may_leave_unit_interval() || (0.0..=1.0).contains(v))
            };
            let bad_t =
                m.t.iter()
                    .chain(m.slices.iter().flatten())
                    .filter(|&v| !t_ok(v))
                    .count();
            let bad_e = m
                .std_err
                .iter()
                .flatten()
                .filter(|v| !(v.is_finite() && **v >= 0.0))
                .count();
            if bad_t + bad_e > 0 || m.t.len() != 64 {
                let first =
                    m.t.iter()
                        .chain(m.slices.iter().flatten())
                        .find(|&v| !t_ok(v));
                let what = if first.is_some_and(|v| v.is_finite()) {
                    "transmittance outside [0, 1] with Ok"
                } else {
                    "non-finite result with Ok"
                };
                let first = first.map_or("none".into(), |v| v.to_string());
                rep.problems.push(format!(
                    "grid '{name}' bake: {what}: {bad_t} bad T or slice values (first {first}), \
                     {bad_e} bad standard errors, {} pixels",
                    m.t.len()
                ));
            }
            if m.stats.majorant_violations > 0 {
                rep.problems.push(format!(
                    "grid '{name}' bake: majorant violations: {}",
                    m.stats.majorant_violations
                ));
            }
        }
        Err(e) => {
            rep.error("bake", &e);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Workers
// ---------------------------------------------------------------------------------------------

/// Panic messages and locations seen by the worker's hook (the payload has only the message).
static PANIC_SITES: Mutex<Vec<String>> = Mutex::new(Vec::new());
/// Set while a worker runs cases: their panics are expected, caught and reported quietly.
static IN_CASES: AtomicBool = AtomicBool::new(false);
/// The case a worker is running, since when, and in which step.
static CURRENT: AtomicUsize = AtomicUsize::new(usize::MAX);
static CASE_START: Mutex<Option<Instant>> = Mutex::new(None);
static STAGE: Mutex<String> = Mutex::new(String::new());

fn install_panic_hook() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let default_hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let site = info
                .location()
                .map_or("?".into(), |l| format!("{}:{}", l.file(), l.line()));
            let msg = panic_message(info.payload());
            PANIC_SITES
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .push(format!("{msg} (at {site})"));
            if !IN_CASES.load(Ordering::Relaxed) {
                default_hook(info);
            }
        }));
    });
}

fn current_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Run by the supervisor in a child process (see the module docs); a no-op in a normal test run.
#[test]
fn mutation_worker() {
    let Ok(spec) = std::env::var(WORKER_ENV) else {
        return;
    };
    let mut it = spec.splitn(5, '\n');
    let mut num = || -> usize { it.next().unwrap().parse().unwrap() };
    let (shard, shards, from) = (num(), num(), num());
    let tmp = PathBuf::from(it.next().unwrap());
    let out = PathBuf::from(it.next().unwrap()).join(format!("out{shard}"));
    let dir = corpus_dir().expect("corpus");
    let (originals, cases) = all_cases(&dir);
    install_panic_hook();
    let _ = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build_global();
    std::fs::create_dir_all(&out).unwrap();
    // One working copy per source file, patched in place and restored after each case.
    let work: Vec<PathBuf> = (0..SOURCES.len())
        .map(|f| tmp.join(format!("w{shard}_{f}.vdb")))
        .collect();
    for (w, o) in work.iter().zip(&originals) {
        std::fs::write(w, o).unwrap();
    }
    let whole = tmp.join(format!("m{shard}.vdb"));
    // A case that runs away with memory stops the worker before it takes the machine with it;
    // a slow one says which step it is in, in case the supervisor has to kill it.
    std::thread::spawn(|| {
        let mut told = usize::MAX;
        loop {
            let i = CURRENT.load(Ordering::Relaxed);
            if let Some(rss) = current_rss_bytes().filter(|&r| r > RSS_LIMIT) {
                let stage = STAGE.lock().unwrap_or_else(|e| e.into_inner()).clone();
                println!("{LINE}rss {i} {rss} {stage}");
                std::process::exit(3);
            }
            let start = *CASE_START.lock().unwrap_or_else(|e| e.into_inner());
            if told != i && start.is_some_and(|t| t.elapsed() > SLOW_CASE) {
                let stage = STAGE.lock().unwrap_or_else(|e| e.into_inner()).clone();
                println!("{LINE}slow {i} {stage}");
                told = i;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    });
    IN_CASES.store(true, Ordering::Relaxed);
    for i in (from..cases.len()).filter(|i| i % shards == shard) {
        let case = &cases[i];
        let orig = &originals[case.file];
        CURRENT.store(i, Ordering::Relaxed);
        // Reset the peak resident set so that it measures this case alone.
        let _ = std::fs::write("/proc/self/clear_refs", "5");
        println!("{LINE}start {i}");
        let t0 = Instant::now();
        *CASE_START.lock().unwrap() = Some(t0);
        let mut rep = match case.mutation.patches(orig) {
            Some(p) => {
                let f = File::options().write(true).open(&work[case.file]).unwrap();
                for (at, b) in &p {
                    f.write_all_at(b, *at).unwrap();
                }
                let rep = check_mutant(&work[case.file], case, &out);
                for (at, b) in &p {
                    f.write_all_at(&orig[*at as usize..*at as usize + b.len()], *at)
                        .unwrap();
                }
                rep
            }
            None => {
                std::fs::write(&whole, case.mutation.apply(orig)).unwrap();
                check_mutant(&whole, case, &out)
            }
        };
        rep.micros = t0.elapsed().as_micros() as u64;
        rep.peak_rss = peak_rss_bytes().unwrap_or(0);
        println!("{LINE}done {i} {}", serde_json::to_string(&rep).unwrap());
    }
    IN_CASES.store(false, Ordering::Relaxed);
}

/// Run the share `shard` of `shards` of the cases in worker processes, one at a time, restarting
/// after a case that kills its worker.
fn supervise(
    shard: usize,
    shards: usize,
    n_cases: usize,
    (tmp, out): (&Path, &Path),
    results: &Mutex<Vec<Option<Report>>>,
) {
    let last = (shard..n_cases).step_by(shards).next_back();
    let mut from = 0;
    let record = |i: usize, r: Report| results.lock().unwrap()[i] = Some(r);
    while last.is_some_and(|l| from <= l) {
        let mut child = Command::new(std::env::current_exe().unwrap())
            .args([
                "mutation::mutation_worker",
                "--exact",
                "--nocapture",
                "--test-threads=1",
            ])
            .env(
                WORKER_ENV,
                format!(
                    "{shard}\n{shards}\n{from}\n{}\n{}",
                    tmp.display(),
                    out.display()
                ),
            )
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let (tx, rx) = mpsc::channel();
        let stdout = child.stdout.take().unwrap();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let stderr_tail = Arc::new(Mutex::new(Vec::<u8>::new()));
        let (tail, mut stderr) = (stderr_tail.clone(), child.stderr.take().unwrap());
        let drain = std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            while let Ok(n @ 1..) = stderr.read(&mut buf) {
                let mut t = tail.lock().unwrap();
                t.extend_from_slice(&buf[..n]);
                let excess = t.len().saturating_sub(4000);
                t.drain(..excess);
            }
        });
        let started_from = from;
        // The case running, since when, and the step it was in when the worker said it is slow.
        let mut current: Option<(usize, Instant)> = None;
        let mut slow_in = String::new();
        loop {
            let wait = current.map_or(HANG_LIMIT, |(_, t)| HANG_LIMIT.saturating_sub(t.elapsed()));
            match rx.recv_timeout(wait) {
                Ok(Ok(line)) => {
                    // libtest prints "test mutation_worker ... " without a newline before the
                    // first line of the worker.
                    let Some(msg) = line.find(LINE).map(|k| &line[k + LINE.len()..]) else {
                        continue;
                    };
                    let mut parts = msg.splitn(3, ' ');
                    let (what, i) = (parts.next().unwrap(), parts.next().unwrap());
                    let i: usize = i.parse().unwrap();
                    let rest = parts.next().unwrap_or_default();
                    match what {
                        "start" => {
                            current = Some((i, Instant::now()));
                            slow_in.clear();
                        }
                        "slow" => rest.clone_into(&mut slow_in),
                        "done" => {
                            record(i, serde_json::from_str(rest).unwrap());
                            current = None;
                            from = i + 1;
                        }
                        "rss" => {
                            let (rss, stage) = rest.split_once(' ').unwrap_or((rest, ""));
                            let rss: u64 = rss.parse().unwrap();
                            let problem = format!(
                                "RSS: {} MiB resident (limit {} MiB) during {stage}, worker stopped",
                                rss >> 20,
                                RSS_LIMIT >> 20
                            );
                            record(i, Report::killed(problem));
                            current = None;
                            from = i + 1;
                        }
                        other => panic!("unexpected worker line {other}"),
                    }
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {
                    let _ = child.kill();
                    let _ = child.wait();
                    let (i, _) = current
                        .unwrap_or_else(|| panic!("mutation worker {shard} stalled between cases"));
                    let problem = format!(
                        "hung: no result after {HANG_LIMIT:?} (slow during {slow_in}), worker \
                         killed"
                    );
                    record(i, Report::killed(problem));
                    from = i + 1;
                    break;
                }
                Ok(Err(_)) | Err(mpsc::RecvTimeoutError::Disconnected) => {
                    let status = child.wait().unwrap();
                    let _ = drain.join();
                    let tail = String::from_utf8_lossy(&stderr_tail.lock().unwrap()).into_owned();
                    if let Some((i, _)) = current {
                        let tail = tail.lines().rev().take(6).collect::<Vec<_>>().join(" | ");
                        let problem = format!(
                            "crashed: worker {status}; stderr (last lines, newest first): {tail}"
                        );
                        record(i, Report::killed(problem));
                        from = i + 1;
                    } else if from == started_from && last.is_some_and(|l| from <= l) {
                        panic!("mutation worker {shard} ran no case ({status}):\n{tail}");
                    }
                    break;
                }
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The tests
// ---------------------------------------------------------------------------------------------

/// Per-kind tally: cases, failed to open, a grid failed, loaded Ok, volumes, bakes.
type Tally = [usize; 6];

#[test]
fn mutated_corpus_files_never_panic() {
    let Some(dir) = corpus_dir() else { return };
    let started = Instant::now();
    let (_, cases) = all_cases(&dir);
    let structured = cases.iter().filter(|c| c.structured()).count();
    eprintln!(
        "mutation fuzz: running {} cases ({} byte-level, {structured} structure-aware)",
        cases.len(),
        cases.len() - structured
    );
    let tmp = tempfile::tempdir().unwrap();
    // Maps and previews go to a tmpfs when there is one: the atomic writes fsync every file,
    // which on a disk costs more than the rest of a case.
    let shm = tempfile::tempdir_in("/dev/shm").ok();
    let out = shm.as_ref().map_or(tmp.path(), |d| d.path());
    let workers = std::thread::available_parallelism()
        .map_or(2, |n| n.get())
        .min(4);
    let results: Mutex<Vec<Option<Report>>> = Mutex::new(vec![None; cases.len()]);
    std::thread::scope(|s| {
        for w in 0..workers {
            let (results, dirs, n) = (&results, (tmp.path(), out), cases.len());
            s.spawn(move || supervise(w, workers, n, dirs, results));
        }
    });
    let results: Vec<Report> = results
        .into_inner()
        .unwrap()
        .into_iter()
        .enumerate()
        .map(|(i, r)| r.unwrap_or_else(|| panic!("no result for case {i}")))
        .collect();
    if let Some(p) = std::env::var_os(DUMP_ENV) {
        let lines: Vec<String> = cases
            .iter()
            .zip(&results)
            .map(|(c, r)| {
                let j = serde_json::json!({"case": c.describe(), "kind": c.kind, "report": r});
                j.to_string()
            })
            .collect();
        std::fs::write(p, lines.join("\n")).unwrap();
    }

    let mut failures = Vec::new();
    let (mut open_err, mut load_err, mut ok, mut partial, mut killed) = (0, 0, 0, 0, 0);
    let (mut volumes, mut rays, mut refused, mut bakes) = (0, 0, 0, 0);
    let mut errors = BTreeMap::<String, usize>::new();
    let mut step_micros = BTreeMap::<String, u64>::new();
    let mut slowest = (0u64, 0);
    let mut biggest = (0u64, 0);
    // Per region (byte-level cases): (cases, errors).
    let mut by_region = BTreeMap::<&str, (usize, usize)>::new();
    let mut by_kind = BTreeMap::<&str, Tally>::new();
    let mut time_per_file = vec![0u64; SOURCES.len()];
    for (i, (case, rep)) in cases.iter().zip(&results).enumerate() {
        let what = case.describe();
        time_per_file[case.file] += rep.micros;
        if rep.micros > slowest.0 {
            slowest = (rep.micros, i);
        }
        if rep.peak_rss > biggest.0 {
            biggest = (rep.peak_rss, i);
        }
        if Duration::from_micros(rep.micros) > SLOW_CASE {
            let mut steps: Vec<(&String, &u64)> = rep.stage_micros.iter().collect();
            steps.sort_by_key(|s| std::cmp::Reverse(*s.1));
            let steps: Vec<String> = steps
                .iter()
                .take(3)
                .map(|(s, us)| format!("{s} {:.1}s", **us as f64 * 1e-6))
                .collect();
            failures.push(format!(
                "{what}: slow: took {:?} ({})",
                Duration::from_micros(rep.micros),
                steps.join(", ")
            ));
        }
        if rep.peak_rss > RSS_LIMIT {
            failures.push(format!("{what}: RSS: peak {} MiB", rep.peak_rss >> 20));
        }
        for p in &rep.problems {
            failures.push(format!("{what}: {p}"));
        }
        for (k, n) in &rep.errors {
            *errors.entry(k.clone()).or_default() += n;
        }
        for (k, us) in &rep.stage_micros {
            *step_micros.entry(k.clone()).or_default() += us;
        }
        let failed = rep.open_err.is_some() || rep.load_failed > 0;
        let tally = by_kind.entry(case.kind).or_default();
        tally[0] += 1;
        if rep.killed {
            killed += 1;
        } else if rep.open_err.is_some() {
            open_err += 1;
            tally[1] += 1;
        } else if rep.load_failed > 0 {
            load_err += 1;
            tally[2] += 1;
            partial += usize::from(rep.loaded > 0);
        } else {
            ok += 1;
            tally[3] += 1;
        }
        tally[4] += rep.volumes;
        tally[5] += rep.bakes;
        volumes += rep.volumes;
        rays += rep.rays;
        refused += rep.rays_refused;
        bakes += rep.bakes;
        if !case.structured() {
            let t = by_region.entry(case.region).or_default();
            t.0 += 1;
            t.1 += usize::from(failed);
        }
        // Every truncation is shorter than the file, so the last grid's end offset is past EOF.
        if matches!(case.mutation, Mutation::Truncate(_)) && !failed && !rep.killed {
            failures.push(format!("{what}: truncated file loaded without error"));
        }
    }
    let elapsed = started.elapsed();
    eprintln!(
        "mutation fuzz: {} cases ({} byte-level, {structured} structure-aware) over {} files in \
         {elapsed:.1?} on {workers} workers: {open_err} failed to open, {load_err} opened but a \
         grid failed ({partial} with other grids loaded), {ok} loaded Ok, {killed} killed their \
         worker; {volumes} volumes traced along {rays} rays ({refused} rays not finite in world \
         space) and {bakes} maps baked",
        cases.len(),
        cases.len() - structured,
        SOURCES.len(),
    );
    eprintln!(
        "  slowest case {:?} ({}); largest peak RSS {} MiB ({})",
        Duration::from_micros(slowest.0),
        cases[slowest.1].describe(),
        biggest.0 >> 20,
        cases[biggest.1].describe(),
    );
    eprintln!("  typed errors by step: {errors:?}");
    let mut steps: Vec<(&String, &u64)> = step_micros.iter().collect();
    steps.sort_by_key(|s| std::cmp::Reverse(*s.1));
    let steps: Vec<String> = steps
        .iter()
        .map(|(s, us)| format!("{s} {:.1}s", **us as f64 * 1e-6))
        .collect();
    eprintln!("  time per step (all workers): {}", steps.join(", "));
    eprintln!("  byte-level cases per region (cases, errors): {by_region:?}");
    eprintln!("  cases per kind (cases / failed to open / a grid failed / loaded Ok / volumes traced / maps baked):");
    for (k, t) in &by_kind {
        eprintln!(
            "    {k:<28} {:>5} / {:>5} / {:>5} / {:>5} / {:>5} / {:>5}",
            t[0], t[1], t[2], t[3], t[4], t[5]
        );
    }
    let per_file: Vec<String> = SOURCES
        .iter()
        .map(|s| s.0)
        .zip(&time_per_file)
        .map(|(f, t)| format!("{f} {:.1}s", *t as f64 * 1e-6))
        .collect();
    eprintln!("  time per file: {}", per_file.join(", "));
    if !failures.is_empty() {
        panic!(
            "{} of {} mutation cases failed:\n{}",
            failures.len(),
            cases.len(),
            failures.join("\n"),
        );
    }
    assert!(
        cases.len() - structured >= 3000,
        "only {} byte-level mutation cases",
        cases.len() - structured
    );
    assert!(
        structured >= 2000,
        "only {structured} structure-aware cases"
    );
    assert!(
        ok > 0 && open_err + load_err > 0,
        "mutations should both pass and fail sometimes"
    );
    assert!(volumes > 0 && bakes > 0, "no mutant was traced and baked");
}

/// Run the CLI with `args`, its address space limited to [`CLI_MEMORY`] (`ulimit -v`), killed
/// after [`HANG_LIMIT`]: its exit status (`None` if it was killed), stdout and stderr.
fn run_cli_bounded(args: &[&str]) -> (Option<std::process::ExitStatus>, Vec<u8>, Vec<u8>) {
    let mut child = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -v {} && exec \"$0\" \"$@\"",
            CLI_MEMORY >> 10
        ))
        .arg(env!("CARGO_BIN_EXE_umbra"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    fn read_all(mut r: impl Read + Send + 'static) -> std::thread::JoinHandle<Vec<u8>> {
        std::thread::spawn(move || {
            let mut v = Vec::new();
            let _ = r.read_to_end(&mut v);
            v
        })
    }
    let out = read_all(child.stdout.take().unwrap());
    let err = read_all(child.stderr.take().unwrap());
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break Some(s);
        }
        if t0.elapsed() > HANG_LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(2));
    };
    (status, out.join().unwrap(), err.join().unwrap())
}

/// The CLI on a sample of the same mutants: `umbra info --json` must exit 0 (valid JSON), 3
/// (valid JSON, some grid has an `error`, one `umbra: error:` line) or 1 (one `umbra: error:`
/// line), never crash, hang or exhaust its memory.
#[test]
fn cli_survives_mutated_files() {
    let Some(dir) = corpus_dir() else { return };
    let (originals, cases) = all_cases(&dir);
    // Every 15th byte-level mutation, every 100th truncation, every 40th structure-aware edit.
    let bytes = |c: &&Case| !c.structured() && !matches!(c.mutation, Mutation::Truncate(_));
    let sample: Vec<&Case> = cases
        .iter()
        .filter(bytes)
        .step_by(15)
        .chain(
            cases
                .iter()
                .filter(|c| matches!(c.mutation, Mutation::Truncate(_)))
                .step_by(100),
        )
        .chain(cases.iter().filter(|c| c.structured()).step_by(40))
        .collect();
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("mutant.vdb");
    let mut failures = Vec::new();
    let mut codes = BTreeMap::<i32, usize>::new();
    for case in &sample {
        std::fs::write(&path, case.mutation.apply(&originals[case.file])).unwrap();
        let (status, stdout, stderr) = run_cli_bounded(&["info", path.to_str().unwrap(), "--json"]);
        let what = case.describe();
        let stderr = String::from_utf8_lossy(&stderr);
        let Some(status) = status else {
            failures.push(format!(
                "{what}: hung: killed after {HANG_LIMIT:?}, stderr {stderr:?}"
            ));
            continue;
        };
        let code = status.code().unwrap_or(-1);
        *codes.entry(code).or_default() += 1;
        let json = serde_json::from_slice::<serde_json::Value>(&stdout).ok();
        let grids = json
            .as_ref()
            .and_then(|j| j["grids"].as_array())
            .map(|g| (g.len(), g.iter().filter(|g| !g["error"].is_null()).count()));
        let one_line = stderr.lines().count() == 1
            && stderr.starts_with("umbra: error: ")
            && stderr.contains("mutant.vdb");
        // 0: everything read; 3: some grids failed, the others described; 1: nothing
        // readable (no report, or a report whose every grid failed).
        let ok = match code {
            0 => grids.is_some_and(|(_, bad)| bad == 0),
            3 => one_line && grids.is_some_and(|(n, bad)| bad > 0 && bad < n),
            1 => one_line && (stdout.is_empty() || grids.is_some_and(|(n, bad)| bad == n)),
            _ => false,
        };
        if !ok || stderr.contains("panicked") {
            failures.push(format!("{what}: {status}, stderr {stderr:?}"));
        }
    }
    eprintln!("CLI on {} mutants: exit codes {codes:?}", sample.len());
    assert!(sample.len() >= 50, "only {} CLI mutants", sample.len());
    assert!(
        failures.is_empty(),
        "{} CLI failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

//! The lane kernel of exact maps and query batches: the exact integral of the trilinear field of
//! one 8^3 block of dual cells along up to [`LANES`] rays at once (parallel ones for an
//! orthographic map, rays from one point for a perspective map, any rays for a query batch
//! ([`super::batch`]): each lane carries its own entry point and direction).
//!
//! **Block.** The lookup cells `[o, o + 7]^3` of a leaf or tile and the corners they read, the
//! values at `o + (x, y, z)`, `x, y, z in 0..=8`, copied into a padded `9^3` array
//! (`x * 81 + y * 9 + z`) that stays in L1 while every ray of the footprint crosses it.
//!
//! **Per lane.** A ray enters the block at `e` (block-centred coordinates: lookup space minus
//! `o + 4`, so `|e| <= 4`) and runs along its direction `d` (lookup units per world unit) for
//! `len` world units. A DDA over the unit cells cuts `[0, len]` into pieces `[s, s']`, one
//! per dual cell `c`; inside one the field is the trilinear interpolation of the cell's 8
//! corners, a cubic in `t`, integrated exactly by two-point Gauss-Legendre:
//! `int_s^s' f = h (f(m - h / sqrt3) + f(m + h / sqrt3))`, `m = (s + s') / 2`, `h = (s' - s) / 2`,
//! the point at `t` being `u = (e - c) + d t` in the cell's own coordinates.
//!
//! **Precision.** The cell arithmetic is f32 (16 lanes per AVX-512 register, 8 per AVX2 one); each cell's integral is
//! widened to f64 and summed in f64. Positions are block-centred, so a lane's coordinates have
//! absolute error below `2^-22 |e| + |d t| 2^-24` (under `1e-6` voxels); the trilinear field is
//! continuous across cell faces, so misplacing a face by `dt` changes the integral by
//! `|f(before) - f(after)| dt = 0` to first order, and a position error `dx` moves the
//! integral by at most `|grad f| dx len`. Callers use the kernel only on blocks whose values
//! lie in `[1e-20, 1e20]` in magnitude (no overflow, no subnormals, no infinities) and fall
//! back to the f64 per-ray code otherwise. The bench `ortho_view --check` reports the largest
//! relative difference of optical depth against the f64 ray path.
//!
//! **Marching.** [`Kernel::march`] is the same block walk for ray marching: a lane's chord
//! of length `len` is cut into `n` equal pieces of length `dt = len / n` (counted in f64 by
//! the caller, as the ray path counts them) and the field is read at each piece's midpoint
//! `s_j = (j + 1/2) dt`: `sum_j f(e + d s_j) dt`, the midpoint rule of
//! [`crate::estimate::marching`] on the same chord. A point's cell is `floor(e + d s)` clamped
//! to the block, its weights `(e - c) + d s` with the same split entry and direction as above.
//!
//! **Dispatch.** A batch holds up to [`LANES`] = 16 rays. [`Kernel`] runs the AVX-512F version
//! (the 16 lanes in one register, lane masks) where the CPU has it, else the AVX2 + FMA version
//! (8 lanes a register: callers fill [`Kernel::width`] = 8 lanes, a batch of 16 runs as two
//! registers one after the other), else a portable one ([`Simd::active`]; the environment
//! variable `UMBRA_SIMD=portable|avx2|avx512` caps the choice, for benchmarks and for checking
//! a result on another machine's path). All do the same f32 operations per lane in the same
//! order, with fused multiply-adds at the same places (`f32::mul_add` in the portable one) and
//! IEEE-exact division, floor and min/max with the same operand order, so they agree bit for
//! bit (unit tests compare every version the CPU runs).

use crate::tree::{Accessor, Block, Neighbour, Tree};
use crate::volume::Volume;
use glam::{DMat3, DVec3};

/// Rays integrated side by side: one AVX-512 register, two AVX2 registers.
pub(crate) const LANES: usize = 16;
/// Side of the padded block: the 8 cells of a block edge plus the corners on its + face.
pub(crate) const SIDE: usize = 9;
/// Values in a padded block.
pub(crate) const BLOCK: usize = SIDE * SIDE * SIDE;
/// Offsets of a cell's 8 corners in the padded block, index `x << 2 | y << 1 | z`.
const CORNERS: [i32; 8] = [0, 1, 9, 10, 81, 82, 90, 91];
/// Block stride of each axis.
const STRIDE: [i32; 3] = [81, 9, 1];
/// `1 / sqrt(3)`: the Gauss-Legendre points of the unit interval around its midpoint.
const GAUSS: f32 = 0.577_350_26;
/// Most steps of a lane: at most 7 face crossings per axis plus the first cell, and one step
/// per axis that would leave the block early (round-off) and ends that axis instead.
const MAX_STEPS: usize = 25;

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod avx2;
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod avx512;

/// An instruction set the kernel has a version for, narrowest first. Every version does the
/// same f32 operations per lane in the same order, so all give the same bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Simd {
    /// Plain Rust, one lane after the other (`f32::mul_add` where the others fuse).
    Portable,
    /// AVX2 + FMA: 8 lanes a register, a batch in two halves.
    Avx2,
    /// AVX-512F: the 16 lanes of a batch in one register, lane masks instead of blends.
    Avx512,
}

impl Simd {
    /// The name `UMBRA_SIMD` takes and reports give: `portable`, `avx2` or `avx512`.
    pub fn name(self) -> &'static str {
        match self {
            Simd::Portable => "portable",
            Simd::Avx2 => "avx2",
            Simd::Avx512 => "avx512",
        }
    }

    /// The widest version this CPU runs, capped by the environment variable `UMBRA_SIMD`
    /// (`portable`, `avx2` or `avx512`; a level the CPU lacks falls to the widest it has; an
    /// unknown value is ignored). Decided once per process.
    pub fn active() -> Simd {
        static ACTIVE: std::sync::OnceLock<Simd> = std::sync::OnceLock::new();
        *ACTIVE.get_or_init(|| {
            let best = Simd::detected();
            let cap = std::env::var("UMBRA_SIMD")
                .ok()
                .and_then(|v| Simd::parse(&v));
            cap.map_or(best, |c| c.min(best))
        })
    }

    /// The level named `s` (see [`Simd::name`]).
    pub fn parse(s: &str) -> Option<Simd> {
        match s.trim().to_ascii_lowercase().as_str() {
            "portable" | "scalar" | "none" => Some(Simd::Portable),
            "avx2" => Some(Simd::Avx2),
            "avx512" | "avx-512" | "avx512f" => Some(Simd::Avx512),
            _ => None,
        }
    }

    /// The widest version the CPU supports.
    #[cfg(target_arch = "x86_64")]
    pub fn detected() -> Simd {
        let avx2 = std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma");
        if avx2 && std::arch::is_x86_feature_detected!("avx512f") {
            Simd::Avx512
        } else if avx2 {
            Simd::Avx2
        } else {
            Simd::Portable
        }
    }

    /// The widest version the CPU supports.
    #[cfg(not(target_arch = "x86_64"))]
    pub fn detected() -> Simd {
        Simd::Portable
    }
}

/// Which version of the kernel runs.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Kernel {
    simd: Simd,
}

impl Kernel {
    /// The version [`Simd::active`] picks.
    pub(crate) fn new() -> Self {
        Self {
            simd: Simd::active(),
        }
    }

    /// Every version this CPU runs (tests compare them).
    #[cfg(test)]
    pub(crate) fn every() -> Vec<Self> {
        [Simd::Portable, Simd::Avx2, Simd::Avx512]
            .into_iter()
            .filter(|&s| s <= Simd::detected())
            .map(|simd| Self { simd })
            .collect()
    }

    /// The portable version (tests compare the others with it).
    #[cfg(test)]
    pub(crate) fn portable() -> Self {
        Self {
            simd: Simd::Portable,
        }
    }

    /// Lanes a batch should fill: 16 for AVX-512 (one register), 8 otherwise (one AVX2
    /// register; the portable version does the AVX2 one's lanes in order). Callers that fill
    /// only these lanes leave the rest unused (`len = 0`, `n = 0`), which every version skips.
    pub(crate) fn width(self) -> usize {
        match self.simd {
            Simd::Avx512 => LANES,
            Simd::Avx2 | Simd::Portable => LANES / 2,
        }
    }

    /// The instruction set this version runs on.
    pub(crate) fn simd(self) -> Simd {
        self.simd
    }

    /// Integrate the block's field along every used lane.
    pub(crate) fn integrate(self, block: &[f32; BLOCK], lanes: &Lanes) -> Sums {
        #[cfg(target_arch = "x86_64")]
        match self.simd {
            // SAFETY: `Avx512` is chosen only when the CPU reports AVX-512F, AVX2 and FMA.
            #[allow(unsafe_code)]
            Simd::Avx512 => return unsafe { avx512::integrate(block, lanes) },
            Simd::Avx2 => {
                let mut out = Sums::default();
                let used = |l0: usize| lanes.len[l0..l0 + avx2::WIDTH].iter().any(|&x| x > 0.0);
                // SAFETY: `Avx2` is chosen only when the CPU reports AVX2 and FMA; both halves
                // lie in the batch (`8 + WIDTH <= LANES`).
                #[allow(unsafe_code)]
                unsafe {
                    avx2::integrate::<0>(block, lanes, &mut out);
                    if used(avx2::WIDTH) {
                        avx2::integrate::<{ avx2::WIDTH }>(block, lanes, &mut out);
                    }
                }
                return out;
            }
            Simd::Portable => {}
        }
        portable(block, lanes)
    }

    /// A march along every used lane: `n[l]` pieces of length `dt[l]` (a lane with `n = 0` is
    /// unused), point `j` at `s = (j + w) dt` with `w = offsets[j][l]`, or the midpoint
    /// `w = 1/2` without offsets (at least `max n` rows); `Sums::cells` counts the points read.
    pub(crate) fn march(
        self,
        block: &[f32; BLOCK],
        lanes: &Lanes,
        steps: &Steps,
        offsets: Option<&[[f32; LANES]]>,
    ) -> Sums {
        #[cfg(target_arch = "x86_64")]
        match self.simd {
            // SAFETY: `Avx512` is chosen only when the CPU reports AVX-512F, AVX2 and FMA.
            #[allow(unsafe_code)]
            Simd::Avx512 => return unsafe { avx512::march(block, lanes, steps, offsets) },
            Simd::Avx2 => {
                let mut out = Sums::default();
                let used = |l0: usize| steps.n[l0..l0 + avx2::WIDTH].iter().any(|&n| n > 0);
                // SAFETY: as in `integrate`.
                #[allow(unsafe_code)]
                unsafe {
                    avx2::march::<0>(block, lanes, steps, offsets, &mut out);
                    if used(avx2::WIDTH) {
                        avx2::march::<{ avx2::WIDTH }>(block, lanes, steps, offsets, &mut out);
                    }
                }
                return out;
            }
            Simd::Portable => {}
        }
        portable_march(block, lanes, steps, offsets)
    }
}

/// Most values a block may hold in magnitude for the f32 kernel (no overflow in `h (f + f)`).
const KERNEL_MAX: f64 = 1e20;
/// Least non-zero magnitude for the f32 kernel (no subnormal products).
const KERNEL_MIN: f64 = 1e-20;
/// Range of a block's largest chord (world units) the f32 kernel accepts.
const CHORD_RANGE: (f64, f64) = (1e-15, 1e15);

/// Whether a block whose halo values lie in `[min, max]` goes on the f32 kernel, for a volume
/// whose chords through a block are at most `chord` world units long ([`max_chord`]): its
/// largest magnitude finite and in `[1e-20, 1e20]`, the chord in `[1e-15, 1e15]`. Other
/// blocks take the f64 per-ray code.
pub(crate) fn kernel_ok(min: f32, max: f32, chord: f64) -> bool {
    let m = f64::from(min.abs().max(max.abs()));
    m.is_finite()
        && (KERNEL_MIN..=KERNEL_MAX).contains(&m)
        && (CHORD_RANGE.0..=CHORD_RANGE.1).contains(&chord)
}

/// An upper bound on the world length of a ray inside an 8^3 block: its diagonal `8 sqrt3`
/// index units times the largest world length of an index unit, `||W||_2 <= ||W||_F` for the
/// linear part `W` of world-from-index.
pub(crate) fn max_chord(vol: &Volume) -> f64 {
    let m = DMat3::from_cols(
        vol.to_index_dir(DVec3::X),
        vol.to_index_dir(DVec3::Y),
        vol.to_index_dir(DVec3::Z),
    );
    let w = m.inverse();
    let frobenius =
        (w.x_axis.length_squared() + w.y_axis.length_squared() + w.z_axis.length_squared()).sqrt();
    8.0 * 3f64.sqrt() * frobenius
}

/// The 8 blocks whose values the trilinear corners of the block at `origin` read: `first`
/// (itself, `k = 0`) and its + face, edge and corner neighbours (`k` = bits x, y, z), from a
/// leaf's neighbour table where there is one, else looked up.
pub(crate) fn blocks_around<'t>(
    tree: &'t Tree,
    acc: &mut Accessor<'t>,
    origin: [i64; 3],
    first: Block<'t>,
    neighbours: Option<&[Neighbour; 7]>,
) -> [Block<'t>; 8] {
    let mut b = [first; 8];
    for (k, block) in b.iter_mut().enumerate().skip(1) {
        *block = match neighbours.map(|n| n[k - 1]) {
            Some(Neighbour::Leaf(i)) => Block::Leaf(tree.leaf_values(i)),
            Some(Neighbour::Const(c)) => Block::Const(c),
            _ => acc.block_at([0, 1, 2].map(|a| origin[a] + 8 * ((k >> (2 - a)) & 1) as i64)),
        };
    }
    b
}

/// Copy a block's `9^3` corner values (`x * 81 + y * 9 + z`) into `out`.
pub(crate) fn fill(src: &[Block<'_>; 8], out: &mut [f32; BLOCK]) {
    for x in 0..SIDE {
        for y in 0..SIDE {
            let row = (x * SIDE + y) * SIDE;
            let k = ((x >> 3) << 2) | ((y >> 3) << 1);
            let n = ((x & 7) << 6) | ((y & 7) << 3);
            match src[k] {
                Block::Leaf(v) => out[row..row + 8].copy_from_slice(&v[n..n + 8]),
                Block::Const(c) => out[row..row + 8].fill(c),
            }
            out[row + 8] = src[k | 1].get(n);
        }
    }
}

/// The pieces of each lane's chord for [`Kernel::march`].
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Steps {
    /// Pieces (0: the lane is unused).
    pub(crate) n: [u32; LANES],
    /// Length of a piece (world units).
    pub(crate) dt: [f32; LANES],
}

/// The trilinear interpolation of a cell's 8 corners (`v[x << 2 | y << 1 | z]`) at weights
/// `w`, as `a (1 - w) + b w` (no cancellation for values of one sign: the error stays
/// relative to the interpolated value).
#[inline]
fn trilinear(v: &[f32; 8], w: [f32; 3]) -> f32 {
    let lerp = |a: f32, b: f32, w: f32| b.mul_add(w, a * (1.0 - w));
    let z = |a: f32, b: f32| lerp(a, b, w[2]);
    let (z0, z1, z2, z3) = (z(v[0], v[1]), z(v[2], v[3]), z(v[4], v[5]), z(v[6], v[7]));
    lerp(lerp(z0, z1, w[1]), lerp(z2, z3, w[1]), w[0])
}

/// The block's trilinear field at the block-centred point `u` (lookup space minus `o + 4`),
/// in f64: the cell `c = floor(u)` clamped to the block, weights `w = u - c`, and
/// `sum_k v_k prod_a (w_a or 1 - w_a)` as nested `a (1 - w) + b w` (no cancellation for values
/// of one sign). A point a round-off outside the block reads the nearest cell, extrapolated by
/// that round-off. Plain arithmetic (no `floor` or fused multiply-add calls, which are library
/// calls without those instruction sets at build time): what a null-collision map swept in
/// object order reads at each tentative collision.
#[inline]
pub(crate) fn point(block: &[f32; BLOCK], u: [f64; 3]) -> f64 {
    let mut w = [0.0f64; 3];
    let mut idx = 0i32;
    for a in 0..3 {
        // floor by truncation (|u| <= 4 + round-off), then the block's cells -4..=3.
        let t = u[a] as i32;
        let c = (t - i32::from(f64::from(t) > u[a])).clamp(-4, 3);
        w[a] = u[a] - f64::from(c);
        idx += (c + 4) * STRIDE[a];
    }
    let v = CORNERS.map(|k| f64::from(block[(idx + k) as usize]));
    let lerp = |a: f64, b: f64, w: f64| a * (1.0 - w) + b * w;
    let z = |a: f64, b: f64| lerp(a, b, w[2]);
    let (z0, z1, z2, z3) = (z(v[0], v[1]), z(v[2], v[3]), z(v[4], v[5]), z(v[6], v[7]));
    lerp(lerp(z0, z1, w[1]), lerp(z2, z3, w[1]), w[0])
}

/// The portable midpoint march: one lane after the other, the AVX2 version's operations in
/// order.
fn portable_march(
    block: &[f32; BLOCK],
    lanes: &Lanes,
    steps: &Steps,
    offsets: Option<&[[f32; LANES]]>,
) -> Sums {
    let mut out = Sums::default();
    for l in 0..LANES {
        let (n, dt) = (steps.n[l], steps.dt[l]);
        let e = [lanes.e[0][l], lanes.e[1][l], lanes.e[2][l]];
        let e_lo = [lanes.e_lo[0][l], lanes.e_lo[1][l], lanes.e_lo[2][l]];
        let d = [lanes.d[0][l], lanes.d[1][l], lanes.d[2][l]];
        let d_lo = [lanes.d_lo[0][l], lanes.d_lo[1][l], lanes.d_lo[2][l]];
        let mut acc = 0.0f64;
        for j in 0..n {
            let off = offsets.map_or(0.5, |o| o[j as usize][l]);
            let s = (j as f32 + off) * dt;
            let mut w = [0.0f32; 3];
            let mut idx = 0.0f32;
            for a in 0..3 {
                let c = d[a].mul_add(s, e[a]).floor().clamp(-4.0, 3.0);
                let u = d[a].mul_add(s, (e[a] - c) + e_lo[a]);
                w[a] = d_lo[a].mul_add(s, u);
                idx += (c + 4.0) * STRIDE[a] as f32;
            }
            let v = CORNERS.map(|k| block[(idx as i32 + k) as usize]);
            acc += f64::from(trilinear(&v, w) * dt);
        }
        out.tau[l] = acc;
        out.cells[l] = n;
    }
    out
}

/// Up to [`LANES`] rays through one block. A lane with `len <= 0` is unused.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Lanes {
    /// Directions (lookup units per world unit, not all zero), per axis.
    pub(crate) d: [[f32; LANES]; 3],
    /// `d - d as f32` of the f64 directions.
    pub(crate) d_lo: [[f32; LANES]; 3],
    /// Entry points, block-centred (lookup space minus `o + 4`), per axis.
    pub(crate) e: [[f32; LANES]; 3],
    /// `e - e as f32` of the f64 entry points (`e + e_lo` is the entry to ~1e-14 voxels).
    pub(crate) e_lo: [[f32; LANES]; 3],
    /// World length of each ray inside the block.
    pub(crate) len: [f32; LANES],
}

impl Lanes {
    /// Set lane `l`: the ray from `e` (block-centred, f64) along `d` (lookup space) for `len`
    /// world units, each split into an f32 and the f32 of its rest.
    #[inline]
    pub(crate) fn set(&mut self, l: usize, e: [f64; 3], d: [f64; 3], len: f64) {
        for k in 0..3 {
            let (hi, dhi) = (e[k] as f32, d[k] as f32);
            self.e[k][l] = hi;
            self.e_lo[k][l] = (e[k] - f64::from(hi)) as f32;
            self.d[k][l] = dhi;
            self.d_lo[k][l] = (d[k] - f64::from(dhi)) as f32;
        }
        self.len[l] = len as f32;
    }
}

/// Per lane: the integral of the (unscaled) field and the dual cells it crossed.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Sums {
    pub(crate) tau: [f64; LANES],
    pub(crate) cells: [u32; LANES],
}

/// The first cell of a lane (block-centred, `-4..=3` per axis), its padded-block index and the
/// `t` of the next face per axis.
#[inline]
fn start(e: [f32; 3], d: [f32; 3]) -> ([f32; 3], i32, [f32; 3]) {
    let c = e.map(|x| x.floor().clamp(-4.0, 3.0));
    let idx = (0..3).fold(0, |acc, a| acc + (c[a] + 4.0) as i32 * STRIDE[a]);
    let tn = [0, 1, 2].map(|a| {
        if d[a] == 0.0 {
            f32::INFINITY
        } else {
            let face = if d[a] > 0.0 { c[a] + 1.0 } else { c[a] };
            (face - e[a]) / d[a]
        }
    });
    (c, idx, tn)
}

/// The portable version: one lane after the other, the AVX2 version's operations in order.
fn portable(block: &[f32; BLOCK], lanes: &Lanes) -> Sums {
    let mut out = Sums::default();
    for l in 0..LANES {
        let len = lanes.len[l];
        if len.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            continue;
        }
        let e = [lanes.e[0][l], lanes.e[1][l], lanes.e[2][l]];
        let e_lo = [lanes.e_lo[0][l], lanes.e_lo[1][l], lanes.e_lo[2][l]];
        let d = [lanes.d[0][l], lanes.d[1][l], lanes.d[2][l]];
        let d_lo = [lanes.d_lo[0][l], lanes.d_lo[1][l], lanes.d_lo[2][l]];
        let step = d.map(|c| {
            if c > 0.0 {
                1.0f32
            } else if c < 0.0 {
                -1.0
            } else {
                0.0
            }
        });
        // `|1 / d|`, infinite where `d = 0`: the `t` between two faces.
        let delta = d.map(|c| (1.0 / c).abs());
        let (mut c, mut idx, mut tn) = start(e, d);
        let (mut s, mut acc, mut n) = (0.0f32, 0.0f64, 0u32);
        for _ in 0..MAX_STEPS {
            let tm = tn[0].min(tn[1].min(tn[2]));
            let te = tm.min(len);
            let h = 0.5 * (te - s);
            let (hm, hp) = (h * (1.0 - GAUSS), h * (1.0 + GAUSS));
            let mut um = [0.0f32; 3];
            let mut up = [0.0f32; 3];
            for a in 0..3 {
                let us = d[a].mul_add(s, (e[a] - c[a]) + e_lo[a]);
                let us = d_lo[a].mul_add(s, us);
                um[a] = d[a].mul_add(hm, us);
                up[a] = d[a].mul_add(hp, us);
            }
            let v = CORNERS.map(|k| block[(idx + k) as usize]);
            // `a (1 - w) + b w`: no cancellation for values of one sign, so the error stays
            // relative to the interpolated value, not to the corners.
            let f = |w: [f32; 3]| {
                let lerp = |a: f32, b: f32, w: f32| b.mul_add(w, a * (1.0 - w));
                let z = |a: f32, b: f32| lerp(a, b, w[2]);
                let (z0, z1, z2, z3) = (z(v[0], v[1]), z(v[2], v[3]), z(v[4], v[5]), z(v[6], v[7]));
                lerp(lerp(z0, z1, w[1]), lerp(z2, z3, w[1]), w[0])
            };
            let r = h * (f(um) + f(up));
            acc += f64::from(r);
            n += 1;
            if tm.partial_cmp(&len) != Some(std::cmp::Ordering::Less) {
                break;
            }
            let axis = if tn[0] <= tn[1] && tn[0] <= tn[2] {
                0
            } else if tn[1] <= tn[2] {
                1
            } else {
                2
            };
            // A step out of the block before `len` is round-off in the face times: the rest
            // of the chord stays in this cell, and that axis is done.
            let next = c[axis] + step[axis];
            if (-4.0..=3.0).contains(&next) {
                c[axis] = next;
                tn[axis] += delta[axis];
                idx += step[axis] as i32 * STRIDE[axis];
            } else {
                tn[axis] = f32::INFINITY;
            }
            s = te;
        }
        out.tau[l] = acc;
        out.cells[l] = n;
    }
    out
}

#[cfg(test)]
mod tests;

//! The lane kernel of the sweep: the exact integral of the trilinear field of one 8^3 block of
//! dual cells along up to [`LANES`] rays at once (parallel ones for an orthographic map, rays
//! from one point for a perspective map: each lane carries its own direction).
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
//! **Precision.** The cell arithmetic is f32 (8 lanes per AVX2 register); each cell's integral is
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
//! **Dispatch.** [`Kernel::integrate`] runs the AVX2 + FMA version where the CPU has it and a portable
//! version elsewhere. Both do the same f32 operations in the same order, with fused
//! multiply-adds at the same places (`f32::mul_add` in the portable one), so they agree bit for
//! bit (checked by a unit test on machines with AVX2).

/// Rays integrated side by side.
pub(crate) const LANES: usize = 8;
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

/// Which version of the kernel runs.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Kernel {
    /// Run the AVX2 + FMA version.
    simd: bool,
}

impl Kernel {
    /// The fastest version this CPU runs.
    pub(crate) fn new() -> Self {
        Self {
            simd: simd_available(),
        }
    }

    /// The portable version (tests compare the two).
    #[cfg(test)]
    pub(crate) fn portable() -> Self {
        Self { simd: false }
    }

    /// Integrate the block's field along every used lane.
    pub(crate) fn integrate(self, block: &[f32; BLOCK], lanes: &Lanes) -> Sums {
        #[cfg(target_arch = "x86_64")]
        if self.simd {
            // SAFETY: `simd` is set only when the CPU reports AVX2 and FMA.
            #[allow(unsafe_code)]
            return unsafe { avx2::integrate(block, lanes) };
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
        if self.simd {
            // SAFETY: `simd` is set only when the CPU reports AVX2 and FMA.
            #[allow(unsafe_code)]
            return unsafe { avx2::march(block, lanes, steps, offsets) };
        }
        portable_march(block, lanes, steps, offsets)
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

#[cfg(target_arch = "x86_64")]
fn simd_available() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

#[cfg(not(target_arch = "x86_64"))]
fn simd_available() -> bool {
    false
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

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod avx2 {
    use super::{start, Lanes, Steps, Sums, BLOCK, CORNERS, GAUSS, LANES, MAX_STEPS, STRIDE};
    use std::arch::x86_64::*;

    /// The AVX2 + FMA version: the 8 lanes in one register each.
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn integrate(block: &[f32; BLOCK], lanes: &Lanes) -> Sums {
        let mut cx = [0f32; LANES];
        let mut cy = [0f32; LANES];
        let mut cz = [0f32; LANES];
        let mut ix = [0i32; LANES];
        let mut t = [[0f32; LANES]; 3];
        for l in 0..LANES {
            let (c, idx, tn) = start(
                [lanes.e[0][l], lanes.e[1][l], lanes.e[2][l]],
                [lanes.d[0][l], lanes.d[1][l], lanes.d[2][l]],
            );
            (cx[l], cy[l], cz[l], ix[l]) = (c[0], c[1], c[2], idx);
            for a in 0..3 {
                t[a][l] = tn[a];
            }
        }
        // SAFETY (every load below): reads of `LANES` f32 or i32 from arrays of that length.
        let ld = |v: &[f32; LANES]| unsafe { _mm256_loadu_ps(v.as_ptr()) };
        let len = ld(&lanes.len);
        let zero = _mm256_setzero_ps();
        let mut active = _mm256_cmp_ps::<_CMP_GT_OQ>(len, zero);
        let e = [ld(&lanes.e[0]), ld(&lanes.e[1]), ld(&lanes.e[2])];
        let e_lo = [ld(&lanes.e_lo[0]), ld(&lanes.e_lo[1]), ld(&lanes.e_lo[2])];
        let mut c = [ld(&cx), ld(&cy), ld(&cz)];
        let mut tn = [ld(&t[0]), ld(&t[1]), ld(&t[2])];
        let mut idx = unsafe { _mm256_loadu_si256(ix.as_ptr().cast()) };
        let d = [ld(&lanes.d[0]), ld(&lanes.d[1]), ld(&lanes.d[2])];
        let d_lo = [ld(&lanes.d_lo[0]), ld(&lanes.d_lo[1]), ld(&lanes.d_lo[2])];
        let (gm, gp) = (_mm256_set1_ps(1.0 - GAUSS), _mm256_set1_ps(1.0 + GAUSS));
        // Per lane and axis: the cell step (the sign of `d`: +1, -1 or 0), the `t` between two
        // faces `|1 / d|` (infinite where `d = 0`) and the step's offset in the block.
        let (one, neg_one) = (_mm256_set1_ps(1.0), _mm256_set1_ps(-1.0));
        let sign_bit = _mm256_set1_ps(-0.0);
        let mut step = [zero; 3];
        let mut delta = [zero; 3];
        let mut stride = [_mm256_setzero_si256(); 3];
        for a in 0..3 {
            let pos = _mm256_cmp_ps::<_CMP_GT_OQ>(d[a], zero);
            let neg = _mm256_cmp_ps::<_CMP_LT_OQ>(d[a], zero);
            step[a] = _mm256_or_ps(_mm256_and_ps(pos, one), _mm256_and_ps(neg, neg_one));
            delta[a] = _mm256_andnot_ps(sign_bit, _mm256_div_ps(one, d[a]));
            let (up, down) = (_mm256_set1_epi32(STRIDE[a]), _mm256_set1_epi32(-STRIDE[a]));
            stride[a] = _mm256_or_si256(
                _mm256_and_si256(_mm256_castps_si256(pos), up),
                _mm256_and_si256(_mm256_castps_si256(neg), down),
            );
        }
        let pair = [0, 2, 4, 6].map(|k| CORNERS[k]);
        let base: *const f32 = block.as_ptr();
        let (lo, hi) = (_mm256_set1_ps(-4.0), _mm256_set1_ps(3.0));
        let half = _mm256_set1_ps(0.5);
        let inf = _mm256_set1_ps(f32::INFINITY);
        let mut s = zero;
        let mut acc_lo = _mm256_setzero_pd();
        let mut acc_hi = _mm256_setzero_pd();
        let mut cells = _mm256_setzero_si256();
        for _ in 0..MAX_STEPS {
            if _mm256_movemask_ps(active) == 0 {
                break;
            }
            let tm = _mm256_min_ps(tn[0], _mm256_min_ps(tn[1], tn[2]));
            let te = _mm256_min_ps(tm, len);
            let h = _mm256_mul_ps(half, _mm256_sub_ps(te, s));
            let (hm, hp) = (_mm256_mul_ps(h, gm), _mm256_mul_ps(h, gp));
            let mut um = [zero; 3];
            let mut up = [zero; 3];
            for a in 0..3 {
                let local = _mm256_add_ps(_mm256_sub_ps(e[a], c[a]), e_lo[a]);
                let us = _mm256_fmadd_ps(d[a], s, local);
                let us = _mm256_fmadd_ps(d_lo[a], s, us);
                um[a] = _mm256_fmadd_ps(d[a], hm, us);
                up[a] = _mm256_fmadd_ps(d[a], hp, us);
            }
            // Corners come in z pairs (`v[2k]`, `v[2k + 1]` adjacent in the block): each lane
            // loads its 4 pairs as 64-bit scalars (AVX2 gathers are slow on some cores; plain
            // loads run 2-3 a cycle everywhere). Inactive lanes read pair 0 (index masked to 0).
            let at = _mm256_and_si256(idx, _mm256_castps_si256(active));
            let mut ix = [0i32; LANES];
            // SAFETY: a store of 8 i32 into an array of 8.
            unsafe { _mm256_storeu_si256(ix.as_mut_ptr().cast(), at) };
            let v = pair.map(|k| {
                // SAFETY: an active lane's cell is in -4..=3 on every axis (checked when it
                // steps), so `ix + k + 1 <= 637 + 90 + 1 < BLOCK`; inactive lanes read 0..1.
                let at = |l: usize| unsafe { base.add((ix[l] + k) as usize).cast::<f64>() };
                let q = |a: usize| unsafe {
                    _mm_loadh_pd(_mm_loadl_pd(_mm_setzero_pd(), at(a)), at(a + 1))
                };
                // [a0 b0 a1 b1 | a4 b4 a5 b5] and [a2 b2 a3 b3 | a6 b6 a7 b7]: one in-lane
                // shuffle each gives the evens and the odds with the lanes in order.
                let lo = _mm256_castpd_ps(_mm256_set_m128d(q(4), q(0)));
                let hi = _mm256_castpd_ps(_mm256_set_m128d(q(6), q(2)));
                (
                    _mm256_shuffle_ps::<0x88>(lo, hi),
                    _mm256_shuffle_ps::<0xDD>(lo, hi),
                )
            });
            let v = [
                v[0].0, v[0].1, v[1].0, v[1].1, v[2].0, v[2].1, v[3].0, v[3].1,
            ];
            let f = |w: [__m256; 3]| {
                let lerp = |a: __m256, b: __m256, w: __m256| {
                    _mm256_fmadd_ps(b, w, _mm256_mul_ps(a, _mm256_sub_ps(one, w)))
                };
                let z = |a: __m256, b: __m256| lerp(a, b, w[2]);
                let (z0, z1, z2, z3) = (z(v[0], v[1]), z(v[2], v[3]), z(v[4], v[5]), z(v[6], v[7]));
                lerp(lerp(z0, z1, w[1]), lerp(z2, z3, w[1]), w[0])
            };
            let r = _mm256_and_ps(_mm256_mul_ps(h, _mm256_add_ps(f(um), f(up))), active);
            acc_lo = _mm256_add_pd(acc_lo, _mm256_cvtps_pd(_mm256_castps256_ps128(r)));
            acc_hi = _mm256_add_pd(acc_hi, _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(r)));
            cells = _mm256_sub_epi32(cells, _mm256_castps_si256(active));
            // Step the lanes that go on: the axis of the nearest face (ties to the lower axis).
            active = _mm256_and_ps(active, _mm256_cmp_ps::<_CMP_LT_OQ>(tm, len));
            let le = |a: __m256, b: __m256| _mm256_cmp_ps::<_CMP_LE_OQ>(a, b);
            let mx = _mm256_and_ps(le(tn[0], tn[1]), le(tn[0], tn[2]));
            let my = _mm256_andnot_ps(mx, le(tn[1], tn[2]));
            let mz = _mm256_andnot_ps(_mm256_or_ps(mx, my), _mm256_cmp_ps::<_CMP_EQ_OQ>(s, s));
            for (a, mask) in [mx, my, mz].into_iter().enumerate() {
                let next = _mm256_add_ps(c[a], step[a]);
                let ok = _mm256_and_ps(le(lo, next), le(next, hi));
                let go = _mm256_and_ps(_mm256_and_ps(mask, active), ok);
                let stop = _mm256_andnot_ps(ok, _mm256_and_ps(mask, active));
                c[a] = _mm256_blendv_ps(c[a], next, go);
                tn[a] = _mm256_add_ps(tn[a], _mm256_and_ps(go, delta[a]));
                tn[a] = _mm256_blendv_ps(tn[a], inf, stop);
                idx = _mm256_add_epi32(idx, _mm256_and_si256(_mm256_castps_si256(go), stride[a]));
            }
            s = te;
        }
        let mut out = Sums::default();
        let mut n = [0i32; LANES];
        // SAFETY: stores of 4 f64 / 8 i32 into arrays of that length.
        unsafe {
            _mm256_storeu_pd(out.tau.as_mut_ptr(), acc_lo);
            _mm256_storeu_pd(out.tau.as_mut_ptr().add(4), acc_hi);
            _mm256_storeu_si256(n.as_mut_ptr().cast(), cells);
        }
        out.cells = n.map(|x| x as u32);
        out
    }

    /// Each lane's 8 cell corners (`v[x << 2 | y << 1 | z]`) at padded-block index `idx`
    /// (masked to 0 where `active` is clear).
    ///
    /// # Safety
    /// AVX2; every active lane's `idx` is a cell of the block (`idx + 91 < BLOCK`).
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn corners(block: &[f32; BLOCK], idx: __m256i, active: __m256) -> [__m256; 8] {
        let pair = [0, 2, 4, 6].map(|k| CORNERS[k]);
        let base: *const f32 = block.as_ptr();
        let at = _mm256_and_si256(idx, _mm256_castps_si256(active));
        let mut ix = [0i32; LANES];
        // SAFETY: a store of 8 i32 into an array of 8.
        unsafe { _mm256_storeu_si256(ix.as_mut_ptr().cast(), at) };
        let v = pair.map(|k| {
            // SAFETY: as the caller promises; inactive lanes read 0..1.
            let at = |l: usize| unsafe { base.add((ix[l] + k) as usize).cast::<f64>() };
            let q = |a: usize| unsafe {
                _mm_loadh_pd(_mm_loadl_pd(_mm_setzero_pd(), at(a)), at(a + 1))
            };
            let lo = _mm256_castpd_ps(_mm256_set_m128d(q(4), q(0)));
            let hi = _mm256_castpd_ps(_mm256_set_m128d(q(6), q(2)));
            (
                _mm256_shuffle_ps::<0x88>(lo, hi),
                _mm256_shuffle_ps::<0xDD>(lo, hi),
            )
        });
        [
            v[0].0, v[0].1, v[1].0, v[1].1, v[2].0, v[2].1, v[3].0, v[3].1,
        ]
    }

    /// The AVX2 + FMA midpoint march: lane `l`'s point `j` while `j < n[l]`.
    ///
    /// # Safety
    /// The CPU must support AVX2 and FMA.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn march(
        block: &[f32; BLOCK],
        lanes: &Lanes,
        steps: &Steps,
        offsets: Option<&[[f32; LANES]]>,
    ) -> Sums {
        // SAFETY (every load below): reads of `LANES` f32 or i32 from arrays of that length.
        let ld = |v: &[f32; LANES]| unsafe { _mm256_loadu_ps(v.as_ptr()) };
        let e = [ld(&lanes.e[0]), ld(&lanes.e[1]), ld(&lanes.e[2])];
        let e_lo = [ld(&lanes.e_lo[0]), ld(&lanes.e_lo[1]), ld(&lanes.e_lo[2])];
        let d = [ld(&lanes.d[0]), ld(&lanes.d[1]), ld(&lanes.d[2])];
        let d_lo = [ld(&lanes.d_lo[0]), ld(&lanes.d_lo[1]), ld(&lanes.d_lo[2])];
        let dt = ld(&steps.dt);
        let n = _mm256_cvtepi32_ps(unsafe { _mm256_loadu_si256(steps.n.as_ptr().cast()) });
        let most = steps.n.iter().copied().max().unwrap_or(0);
        let (one, half) = (_mm256_set1_ps(1.0), _mm256_set1_ps(0.5));
        let (lo, hi, four) = (
            _mm256_set1_ps(-4.0),
            _mm256_set1_ps(3.0),
            _mm256_set1_ps(4.0),
        );
        let stride = STRIDE.map(|k| _mm256_set1_ps(k as f32));
        let mut acc_lo = _mm256_setzero_pd();
        let mut acc_hi = _mm256_setzero_pd();
        for j in 0..most {
            let jf = _mm256_set1_ps(j as f32);
            let active = _mm256_cmp_ps::<_CMP_LT_OQ>(jf, n);
            let off = match offsets {
                Some(o) => ld(&o[j as usize]),
                None => half,
            };
            let s = _mm256_mul_ps(_mm256_add_ps(jf, off), dt);
            let mut w = [one; 3];
            let mut idx = _mm256_setzero_ps();
            for a in 0..3 {
                let p = _mm256_fmadd_ps(d[a], s, e[a]);
                let c = _mm256_min_ps(_mm256_max_ps(_mm256_floor_ps(p), lo), hi);
                let local = _mm256_add_ps(_mm256_sub_ps(e[a], c), e_lo[a]);
                let u = _mm256_fmadd_ps(d[a], s, local);
                w[a] = _mm256_fmadd_ps(d_lo[a], s, u);
                idx = _mm256_add_ps(idx, _mm256_mul_ps(_mm256_add_ps(c, four), stride[a]));
            }
            // SAFETY: every cell is clamped into the block.
            let v = unsafe { corners(block, _mm256_cvttps_epi32(idx), active) };
            let lerp = |a: __m256, b: __m256, w: __m256| {
                _mm256_fmadd_ps(b, w, _mm256_mul_ps(a, _mm256_sub_ps(one, w)))
            };
            let z = |a: __m256, b: __m256| lerp(a, b, w[2]);
            let (z0, z1, z2, z3) = (z(v[0], v[1]), z(v[2], v[3]), z(v[4], v[5]), z(v[6], v[7]));
            let f = lerp(lerp(z0, z1, w[1]), lerp(z2, z3, w[1]), w[0]);
            let r = _mm256_and_ps(_mm256_mul_ps(f, dt), active);
            acc_lo = _mm256_add_pd(acc_lo, _mm256_cvtps_pd(_mm256_castps256_ps128(r)));
            acc_hi = _mm256_add_pd(acc_hi, _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(r)));
        }
        let mut out = Sums::default();
        // SAFETY: stores of 4 f64 into an array of 8, twice.
        unsafe {
            _mm256_storeu_pd(out.tau.as_mut_ptr(), acc_lo);
            _mm256_storeu_pd(out.tau.as_mut_ptr().add(4), acc_hi);
        }
        out.cells = steps.n;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(state: &mut u64) -> f64 {
        *state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    /// The trilinear field of a padded block at a block-centred point, in f64.
    fn field(block: &[f32; BLOCK], p: [f64; 3]) -> f64 {
        let q = p.map(|x| x + 4.0);
        let c = q.map(|x| (x.floor() as i64).clamp(0, 7));
        let u = [0, 1, 2].map(|a| q[a] - c[a] as f64);
        let mut f = 0.0;
        for k in 0..8usize {
            let b = [k >> 2, (k >> 1) & 1, k & 1];
            let w: f64 = (0..3)
                .map(|a| if b[a] == 1 { u[a] } else { 1.0 - u[a] })
                .product();
            let i = (0..3)
                .map(|a| (c[a] as usize + b[a]) * STRIDE[a] as usize)
                .sum::<usize>();
            f += w * f64::from(block[i]);
        }
        f
    }

    /// Random blocks and rays: the kernel against fine midpoint quadrature of the f64 field,
    /// and the AVX2 version bit for bit against the portable one.
    #[test]
    fn kernel_integrates_the_trilinear_field() {
        let mut st = 7u64;
        for _ in 0..40 {
            let mut block = [0f32; BLOCK];
            for v in &mut block {
                *v = (lcg(&mut st) * 3.0) as f32;
            }
            // Odd rounds: one direction for every lane (an orthographic map); even rounds: one
            // per lane (a perspective map), an axis-parallel one among them.
            let shared = lcg(&mut st) < 0.5;
            let random_dir = |st: &mut u64| {
                let raw = [0; 3].map(|_| lcg(st) - 0.5);
                let n = raw.iter().map(|x| x * x).sum::<f64>().sqrt();
                let speed = 0.5 + 2.0 * lcg(st);
                raw.map(|x| x / n * speed)
            };
            let first = random_dir(&mut st);
            let mut lanes = Lanes::default();
            let mut dirs = [[0.0f64; 3]; LANES];
            for (l, d) in dirs.iter_mut().enumerate() {
                *d = if shared { first } else { random_dir(&mut st) };
                if !shared && l == 2 {
                    *d = [0.0, -1.5, 0.0];
                }
                // A random point inside, traced back and forth to the block's faces.
                let p = [0; 3].map(|_| (lcg(&mut st) - 0.5) * 7.9);
                let (a, b) = crate::ray::clip_box(p, *d, [-4.0; 3], [4.0; 3]).expect("inside");
                let e = [0, 1, 2].map(|k| p[k] + d[k] * a);
                lanes.set(l, e, *d, if l == 5 { 0.0 } else { b - a });
            }
            let got = Kernel::new().integrate(&block, &lanes);
            let portable = Kernel::portable().integrate(&block, &lanes);
            assert_eq!(got, portable, "AVX2 and portable differ");
            for (l, d) in dirs.iter().enumerate() {
                let len = f64::from(lanes.len[l]);
                let e = [0, 1, 2].map(|k| f64::from(lanes.e[k][l]) + f64::from(lanes.e_lo[k][l]));
                let steps = 20_000;
                let dt = len / f64::from(steps);
                let want: f64 = (0..steps)
                    .map(|i| {
                        let t = (f64::from(i) + 0.5) * dt;
                        field(&block, [0, 1, 2].map(|k| e[k] + d[k] * t)) * dt
                    })
                    .sum();
                let tol = 1e-5 * (1.0 + want.abs());
                assert!(
                    (got.tau[l] - want).abs() < tol,
                    "lane {l}: {} vs {want}",
                    got.tau[l]
                );
                if l == 5 {
                    assert_eq!((got.tau[l], got.cells[l]), (0.0, 0));
                } else {
                    assert!(got.cells[l] >= 1 && got.cells[l] as usize <= MAX_STEPS);
                }
            }
        }
    }

    /// Random blocks and chords: the midpoint march against the same points read from the f64
    /// field, and the AVX2 version bit for bit against the portable one.
    #[test]
    fn march_reads_the_midpoints() {
        let mut st = 11u64;
        for round in 0..40 {
            let mut block = [0f32; BLOCK];
            for v in &mut block {
                *v = (lcg(&mut st) * 3.0) as f32;
            }
            let mut lanes = Lanes::default();
            let mut steps = Steps::default();
            let mut dirs = [[0.0f64; 3]; LANES];
            for (l, d) in dirs.iter_mut().enumerate() {
                let raw = [0; 3].map(|_| lcg(&mut st) - 0.5);
                let norm = raw.iter().map(|x| x * x).sum::<f64>().sqrt();
                *d = raw.map(|x| x / norm * (0.5 + 2.0 * lcg(&mut st)));
                if l == 3 {
                    *d = [0.0, 0.0, 1.25]; // axis-parallel
                }
                let p = [0; 3].map(|_| (lcg(&mut st) - 0.5) * 7.9);
                let (a, b) = crate::ray::clip_box(p, *d, [-4.0; 3], [4.0; 3]).expect("inside");
                let e = [0, 1, 2].map(|k| p[k] + d[k] * a);
                lanes.set(l, e, *d, b - a);
                let n = if l == 6 { 0 } else { 1 + (round + l) % 14 };
                steps.n[l] = n as u32;
                steps.dt[l] = ((b - a) / n.max(1) as f64) as f32;
            }
            // Odd rounds: random points in their pieces (jittered marching).
            let offsets: Vec<[f32; LANES]> = (0..14)
                .map(|_| [0; LANES].map(|_| lcg(&mut st) as f32))
                .collect();
            let offsets = (round % 2 == 1).then_some(&offsets[..]);
            let got = Kernel::new().march(&block, &lanes, &steps, offsets);
            let portable = Kernel::portable().march(&block, &lanes, &steps, offsets);
            assert_eq!(got, portable, "AVX2 and portable differ");
            for (l, d) in dirs.iter().enumerate() {
                let e = [0, 1, 2].map(|k| f64::from(lanes.e[k][l]) + f64::from(lanes.e_lo[k][l]));
                let dt = f64::from(steps.dt[l]);
                let want: f64 = (0..steps.n[l])
                    .map(|j| {
                        let w = offsets.map_or(0.5, |o| f64::from(o[j as usize][l]));
                        let t = (f64::from(j) + w) * dt;
                        field(&block, [0, 1, 2].map(|k| e[k] + d[k] * t)) * dt
                    })
                    .sum();
                assert!(
                    (got.tau[l] - want).abs() < 1e-5 * (1.0 + want),
                    "lane {l}: {} vs {want}",
                    got.tau[l]
                );
                assert_eq!(got.cells[l], steps.n[l]);
            }
        }
    }

    /// Axis-parallel rays (two direction components zero) walk one row of cells.
    #[test]
    fn axis_parallel_rays() {
        let mut block = [0f32; BLOCK];
        for (i, v) in block.iter_mut().enumerate() {
            *v = (i % 9) as f32; // the value is the z coordinate: f = z + 4 block-centred
        }
        let mut lanes = Lanes::default();
        for l in 0..LANES {
            // 8 voxels at 2 voxels per unit t.
            lanes.set(l, [0.25, -1.5, 4.0], [0.0, 0.0, -2.0], 4.0);
        }
        let got = Kernel::new().integrate(&block, &lanes);
        // int_0^4 (8 - 2 t) dt = 16.
        for l in 0..LANES {
            assert!((got.tau[l] - 16.0).abs() < 1e-5, "{}", got.tau[l]);
            assert_eq!(got.cells[l], 8);
        }
    }
}

//! The AVX-512F kernels: the 16 lanes of a batch in one register each, lane masks (`__mmask16`)
//! where the AVX2 version blends with all-ones vectors. Every per-lane operation is the AVX2
//! version's, in its order and with its operands (a masked-off value is added as `+0`, as the
//! AVX2 version's `and` with a zero mask adds it), so the three versions agree bit for bit.

use super::{start, Lanes, Steps, Sums, BLOCK, CORNERS, GAUSS, LANES, MAX_STEPS, STRIDE};
use std::arch::x86_64::*;

/// `floor` for `_mm512_roundscale_ps`: round toward -inf, no precision exception.
const FLOOR: i32 = _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC;

/// Each lane's 8 cell corners (`v[x << 2 | y << 1 | z]`, `[__m512; 8]`) of the padded block
/// `$block` at index `$idx` (`__m512i`; lanes outside the `__mmask16` `$active` read cell 0).
///
/// Corners come in z pairs (`v[2k]`, `v[2k + 1]` adjacent in the block): one gather of 8
/// 64-bit pairs takes 8 lanes' pair `k`, `[a0 b0 a1 b1 .. a7 b7]`, and one two-source permute
/// of the lanes `0..8` and `8..16` registers gives the 16 `a` (evens) and the 16 `b` (odds) in
/// lane order. Measured on an AMD EPYC with AVX-512 (2048^2 exact map of cloud_fbm, one
/// thread): 1.09 s, against 1.16 s for 64-bit scalar loads assembled by inserts (the AVX2
/// version's way) and 1.38 s for one 16-lane f32 gather per corner.
/// A macro, not a function: LLVM kept the function out of line (an eighth of the kernel's
/// time in the call), and `#[inline(always)]` is refused beside `#[target_feature]`.
///
/// Safety: AVX-512F; every active lane's index is a cell of the block (`idx + 91 < BLOCK`).
macro_rules! corners {
    ($block:expr, $idx:expr, $active:expr) => {{
        let base: *const f32 = $block.as_ptr();
        let at = _mm512_maskz_mov_epi32($active, $idx);
        let evens = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
        let odds = _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31);
        let mut v = [_mm512_setzero_ps(); 8];
        for (p, k) in [0, 2, 4, 6].map(|k| CORNERS[k]).into_iter().enumerate() {
            let i = _mm512_add_epi32(at, _mm512_set1_epi32(k));
            let lo_i = _mm512_castsi512_si256(i);
            let hi_i = _mm512_extracti64x4_epi64::<1>(i);
            // SAFETY: as the caller promises.
            let a = unsafe { _mm512_castpd_ps(_mm512_i32gather_pd::<4>(lo_i, base.cast())) };
            let b = unsafe { _mm512_castpd_ps(_mm512_i32gather_pd::<4>(hi_i, base.cast())) };
            v[2 * p] = _mm512_permutex2var_ps(a, evens, b);
            v[2 * p + 1] = _mm512_permutex2var_ps(a, odds, b);
        }
        v
    }};
}

/// The trilinear interpolation of the corners `v` at weights `w`, `a (1 - w) + b w` per axis
/// (the AVX2 version's order).
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn trilinear(v: &[__m512; 8], w: [__m512; 3]) -> __m512 {
    let one = _mm512_set1_ps(1.0);
    let lerp = |a: __m512, b: __m512, w: __m512| {
        _mm512_fmadd_ps(b, w, _mm512_mul_ps(a, _mm512_sub_ps(one, w)))
    };
    let z = |a: __m512, b: __m512| lerp(a, b, w[2]);
    let (z0, z1, z2, z3) = (z(v[0], v[1]), z(v[2], v[3]), z(v[4], v[5]), z(v[6], v[7]));
    lerp(lerp(z0, z1, w[1]), lerp(z2, z3, w[1]), w[0])
}

/// Add lanes `0..8` and `8..16` of `r`, widened to f64, to `lo` and `hi`.
#[inline]
#[target_feature(enable = "avx512f,avx2,fma")]
fn widen_add(lo: &mut __m512d, hi: &mut __m512d, r: __m512) {
    let upper = _mm256_castpd_ps(_mm512_extractf64x4_pd::<1>(_mm512_castps_pd(r)));
    *lo = _mm512_add_pd(*lo, _mm512_cvtps_pd(_mm512_castps512_ps256(r)));
    *hi = _mm512_add_pd(*hi, _mm512_cvtps_pd(upper));
}

/// The exact integral on all 16 lanes (the AVX2 version's steps, see [`super`]).
///
/// # Safety
/// The CPU must support AVX-512F, AVX2 and FMA.
#[target_feature(enable = "avx512f,avx2,fma")]
pub(super) unsafe fn integrate(block: &[f32; BLOCK], lanes: &Lanes) -> Sums {
    let mut cs = [[0f32; LANES]; 3];
    let mut ix = [0i32; LANES];
    let mut t = [[0f32; LANES]; 3];
    for l in 0..LANES {
        let (c, idx, tn) = start(
            [lanes.e[0][l], lanes.e[1][l], lanes.e[2][l]],
            [lanes.d[0][l], lanes.d[1][l], lanes.d[2][l]],
        );
        ix[l] = idx;
        for a in 0..3 {
            cs[a][l] = c[a];
            t[a][l] = tn[a];
        }
    }
    // SAFETY (every load below): reads of 16 f32 or i32 from arrays of 16.
    let ld = |v: &[f32; LANES]| unsafe { _mm512_loadu_ps(v.as_ptr()) };
    let len = ld(&lanes.len);
    let zero = _mm512_setzero_ps();
    let mut active = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(len, zero);
    let e = [ld(&lanes.e[0]), ld(&lanes.e[1]), ld(&lanes.e[2])];
    let e_lo = [ld(&lanes.e_lo[0]), ld(&lanes.e_lo[1]), ld(&lanes.e_lo[2])];
    let mut c = [ld(&cs[0]), ld(&cs[1]), ld(&cs[2])];
    let mut tn = [ld(&t[0]), ld(&t[1]), ld(&t[2])];
    let mut idx = unsafe { _mm512_loadu_si512(ix.as_ptr().cast()) };
    let d = [ld(&lanes.d[0]), ld(&lanes.d[1]), ld(&lanes.d[2])];
    let d_lo = [ld(&lanes.d_lo[0]), ld(&lanes.d_lo[1]), ld(&lanes.d_lo[2])];
    let (gm, gp) = (_mm512_set1_ps(1.0 - GAUSS), _mm512_set1_ps(1.0 + GAUSS));
    // Per lane and axis: the cell step (the sign of `d`: +1, -1 or 0), the `t` between two
    // faces `|1 / d|` (infinite where `d = 0`) and the step's offset in the block.
    let (one, neg_one) = (_mm512_set1_ps(1.0), _mm512_set1_ps(-1.0));
    let mut step = [zero; 3];
    let mut delta = [zero; 3];
    let mut stride = [_mm512_setzero_si512(); 3];
    for a in 0..3 {
        let pos = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(d[a], zero);
        let neg = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(d[a], zero);
        step[a] = _mm512_mask_mov_ps(_mm512_maskz_mov_ps(pos, one), neg, neg_one);
        delta[a] = _mm512_abs_ps(_mm512_div_ps(one, d[a]));
        let (up, down) = (_mm512_set1_epi32(STRIDE[a]), _mm512_set1_epi32(-STRIDE[a]));
        stride[a] = _mm512_mask_mov_epi32(_mm512_maskz_mov_epi32(pos, up), neg, down);
    }
    let (lo, hi) = (_mm512_set1_ps(-4.0), _mm512_set1_ps(3.0));
    let half = _mm512_set1_ps(0.5);
    let inf = _mm512_set1_ps(f32::INFINITY);
    let mut s = zero;
    let mut acc_lo = _mm512_setzero_pd();
    let mut acc_hi = _mm512_setzero_pd();
    let mut cells = _mm512_setzero_si512();
    let one_i = _mm512_set1_epi32(1);
    for _ in 0..MAX_STEPS {
        if active == 0 {
            break;
        }
        let tm = _mm512_min_ps(tn[0], _mm512_min_ps(tn[1], tn[2]));
        let te = _mm512_min_ps(tm, len);
        let h = _mm512_mul_ps(half, _mm512_sub_ps(te, s));
        let (hm, hp) = (_mm512_mul_ps(h, gm), _mm512_mul_ps(h, gp));
        let mut um = [zero; 3];
        let mut up = [zero; 3];
        for a in 0..3 {
            let local = _mm512_add_ps(_mm512_sub_ps(e[a], c[a]), e_lo[a]);
            let us = _mm512_fmadd_ps(d[a], s, local);
            let us = _mm512_fmadd_ps(d_lo[a], s, us);
            um[a] = _mm512_fmadd_ps(d[a], hm, us);
            up[a] = _mm512_fmadd_ps(d[a], hp, us);
        }
        // An active lane's cell is in -4..=3 on every axis (checked when it steps).
        let v = corners!(block, idx, active);
        let f = _mm512_add_ps(trilinear(&v, um), trilinear(&v, up));
        let r = _mm512_maskz_mov_ps(active, _mm512_mul_ps(h, f));
        widen_add(&mut acc_lo, &mut acc_hi, r);
        cells = _mm512_mask_add_epi32(cells, active, cells, one_i);
        // Step the lanes that go on: the axis of the nearest face (ties to the lower axis).
        active &= _mm512_cmp_ps_mask::<_CMP_LT_OQ>(tm, len);
        let le = |a: __m512, b: __m512| _mm512_cmp_ps_mask::<_CMP_LE_OQ>(a, b);
        let mx = le(tn[0], tn[1]) & le(tn[0], tn[2]);
        let my = !mx & le(tn[1], tn[2]);
        let mz = !(mx | my) & _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(s, s);
        for (a, mask) in [mx, my, mz].into_iter().enumerate() {
            let next = _mm512_add_ps(c[a], step[a]);
            let ok = le(lo, next) & le(next, hi);
            let go = mask & active & ok;
            let stop = !ok & mask & active;
            c[a] = _mm512_mask_mov_ps(c[a], go, next);
            tn[a] = _mm512_add_ps(tn[a], _mm512_maskz_mov_ps(go, delta[a]));
            tn[a] = _mm512_mask_mov_ps(tn[a], stop, inf);
            idx = _mm512_add_epi32(idx, _mm512_maskz_mov_epi32(go, stride[a]));
        }
        s = te;
    }
    let mut out = Sums::default();
    let mut n = [0i32; LANES];
    // SAFETY: stores of 8 f64 at 0 and 8 into an array of 16, and of 16 i32 into 16.
    unsafe {
        _mm512_storeu_pd(out.tau.as_mut_ptr(), acc_lo);
        _mm512_storeu_pd(out.tau.as_mut_ptr().add(8), acc_hi);
        _mm512_storeu_si512(n.as_mut_ptr().cast(), cells);
    }
    out.cells = n.map(|x| x as u32);
    out
}

/// The midpoint (or offset) march on all 16 lanes: lane `l`'s point `j` while `j < n[l]`.
///
/// # Safety
/// The CPU must support AVX-512F, AVX2 and FMA.
#[target_feature(enable = "avx512f,avx2,fma")]
pub(super) unsafe fn march(
    block: &[f32; BLOCK],
    lanes: &Lanes,
    steps: &Steps,
    offsets: Option<&[[f32; LANES]]>,
) -> Sums {
    // SAFETY (every load below): reads of 16 f32 or i32 from arrays of 16.
    let ld = |v: &[f32; LANES]| unsafe { _mm512_loadu_ps(v.as_ptr()) };
    let e = [ld(&lanes.e[0]), ld(&lanes.e[1]), ld(&lanes.e[2])];
    let e_lo = [ld(&lanes.e_lo[0]), ld(&lanes.e_lo[1]), ld(&lanes.e_lo[2])];
    let d = [ld(&lanes.d[0]), ld(&lanes.d[1]), ld(&lanes.d[2])];
    let d_lo = [ld(&lanes.d_lo[0]), ld(&lanes.d_lo[1]), ld(&lanes.d_lo[2])];
    let dt = ld(&steps.dt);
    let n = _mm512_cvtepi32_ps(unsafe { _mm512_loadu_si512(steps.n.as_ptr().cast()) });
    let most = steps.n.iter().copied().max().unwrap_or(0);
    let (one, half) = (_mm512_set1_ps(1.0), _mm512_set1_ps(0.5));
    let (lo, hi, four) = (
        _mm512_set1_ps(-4.0),
        _mm512_set1_ps(3.0),
        _mm512_set1_ps(4.0),
    );
    let stride = STRIDE.map(|k| _mm512_set1_ps(k as f32));
    let mut acc_lo = _mm512_setzero_pd();
    let mut acc_hi = _mm512_setzero_pd();
    for j in 0..most {
        let jf = _mm512_set1_ps(j as f32);
        let active = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(jf, n);
        let off = match offsets {
            Some(o) => ld(&o[j as usize]),
            None => half,
        };
        let s = _mm512_mul_ps(_mm512_add_ps(jf, off), dt);
        let mut w = [one; 3];
        let mut idx = _mm512_setzero_ps();
        for a in 0..3 {
            let p = _mm512_fmadd_ps(d[a], s, e[a]);
            let floor = _mm512_roundscale_ps::<FLOOR>(p);
            let c = _mm512_min_ps(_mm512_max_ps(floor, lo), hi);
            let local = _mm512_add_ps(_mm512_sub_ps(e[a], c), e_lo[a]);
            let u = _mm512_fmadd_ps(d[a], s, local);
            w[a] = _mm512_fmadd_ps(d_lo[a], s, u);
            idx = _mm512_add_ps(idx, _mm512_mul_ps(_mm512_add_ps(c, four), stride[a]));
        }
        // Every cell is clamped into the block.
        let v = corners!(block, _mm512_cvttps_epi32(idx), active);
        let f = trilinear(&v, w);
        let r = _mm512_maskz_mov_ps(active, _mm512_mul_ps(f, dt));
        widen_add(&mut acc_lo, &mut acc_hi, r);
    }
    let mut out = Sums::default();
    // SAFETY: stores of 8 f64 at 0 and 8 into an array of 16.
    unsafe {
        _mm512_storeu_pd(out.tau.as_mut_ptr(), acc_lo);
        _mm512_storeu_pd(out.tau.as_mut_ptr().add(8), acc_hi);
    }
    out.cells = steps.n;
    out
}

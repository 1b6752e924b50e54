//! The AVX2 + FMA kernels: one half of a batch (8 of its [`LANES`] lanes, from lane `l0`) in one
//! register each; [`super::Kernel`] runs both halves.

use super::{start, Lanes, Steps, Sums, BLOCK, CORNERS, GAUSS, LANES, MAX_STEPS, STRIDE};
use std::arch::x86_64::*;

/// Lanes in one AVX2 register.
pub(super) const WIDTH: usize = 8;

/// The AVX2 + FMA version on lanes `l0..l0 + 8`, written to the same lanes of `out`.
///
/// # Safety
/// The CPU must support AVX2 and FMA; `l0 + 8 <= LANES`.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn integrate<const L0: usize>(
    block: &[f32; BLOCK],
    lanes: &Lanes,
    out: &mut Sums,
) {
    let l0 = L0;
    debug_assert!(l0 + WIDTH <= LANES);
    let mut cx = [0f32; WIDTH];
    let mut cy = [0f32; WIDTH];
    let mut cz = [0f32; WIDTH];
    let mut ix = [0i32; WIDTH];
    let mut t = [[0f32; WIDTH]; 3];
    for l in 0..WIDTH {
        let (c, idx, tn) = start(
            [lanes.e[0][l0 + l], lanes.e[1][l0 + l], lanes.e[2][l0 + l]],
            [lanes.d[0][l0 + l], lanes.d[1][l0 + l], lanes.d[2][l0 + l]],
        );
        (cx[l], cy[l], cz[l], ix[l]) = (c[0], c[1], c[2], idx);
        for a in 0..3 {
            t[a][l] = tn[a];
        }
    }
    // SAFETY (every load below): reads of 8 f32 from `l0` in arrays of `LANES >= l0 + 8`.
    let ld = |v: &[f32; LANES]| unsafe { _mm256_loadu_ps(v.as_ptr().add(l0)) };
    let ld8 = |v: &[f32; WIDTH]| unsafe { _mm256_loadu_ps(v.as_ptr()) };
    let len = ld(&lanes.len);
    let zero = _mm256_setzero_ps();
    let mut active = _mm256_cmp_ps::<_CMP_GT_OQ>(len, zero);
    let e = [ld(&lanes.e[0]), ld(&lanes.e[1]), ld(&lanes.e[2])];
    let e_lo = [ld(&lanes.e_lo[0]), ld(&lanes.e_lo[1]), ld(&lanes.e_lo[2])];
    let mut c = [ld8(&cx), ld8(&cy), ld8(&cz)];
    let mut tn = [ld8(&t[0]), ld8(&t[1]), ld8(&t[2])];
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
        let mut ix = [0i32; WIDTH];
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
    let mut n = [0i32; WIDTH];
    // SAFETY: stores of 4 f64 from `l0` / `l0 + 4` into an array of `LANES >= l0 + 8`, and of
    // 8 i32 into an array of 8.
    unsafe {
        _mm256_storeu_pd(out.tau.as_mut_ptr().add(l0), acc_lo);
        _mm256_storeu_pd(out.tau.as_mut_ptr().add(l0 + 4), acc_hi);
        _mm256_storeu_si256(n.as_mut_ptr().cast(), cells);
    }
    for (o, x) in out.cells[l0..l0 + WIDTH].iter_mut().zip(n) {
        *o = x as u32;
    }
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
    let mut ix = [0i32; WIDTH];
    // SAFETY: a store of 8 i32 into an array of 8.
    unsafe { _mm256_storeu_si256(ix.as_mut_ptr().cast(), at) };
    let v = pair.map(|k| {
        // SAFETY: as the caller promises; inactive lanes read 0..1.
        let at = |l: usize| unsafe { base.add((ix[l] + k) as usize).cast::<f64>() };
        let q =
            |a: usize| unsafe { _mm_loadh_pd(_mm_loadl_pd(_mm_setzero_pd(), at(a)), at(a + 1)) };
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

/// The AVX2 + FMA midpoint march on lanes `l0..l0 + 8`: lane `l`'s point `j` while `j < n[l]`,
/// written to the same lanes of `out`.
///
/// # Safety
/// The CPU must support AVX2 and FMA; `l0 + 8 <= LANES`.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn march<const L0: usize>(
    block: &[f32; BLOCK],
    lanes: &Lanes,
    steps: &Steps,
    offsets: Option<&[[f32; LANES]]>,
    out: &mut Sums,
) {
    let l0 = L0;
    debug_assert!(l0 + WIDTH <= LANES);
    // SAFETY (every load below): reads of 8 f32 or i32 from `l0` in arrays of `LANES >= l0 + 8`.
    let ld = |v: &[f32; LANES]| unsafe { _mm256_loadu_ps(v.as_ptr().add(l0)) };
    let e = [ld(&lanes.e[0]), ld(&lanes.e[1]), ld(&lanes.e[2])];
    let e_lo = [ld(&lanes.e_lo[0]), ld(&lanes.e_lo[1]), ld(&lanes.e_lo[2])];
    let d = [ld(&lanes.d[0]), ld(&lanes.d[1]), ld(&lanes.d[2])];
    let d_lo = [ld(&lanes.d_lo[0]), ld(&lanes.d_lo[1]), ld(&lanes.d_lo[2])];
    let dt = ld(&steps.dt);
    let n = _mm256_cvtepi32_ps(unsafe { _mm256_loadu_si256(steps.n.as_ptr().add(l0).cast()) });
    let most = steps.n[l0..l0 + WIDTH].iter().copied().max().unwrap_or(0);
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
    // SAFETY: stores of 4 f64 from `l0` and `l0 + 4` into an array of `LANES >= l0 + 8`.
    unsafe {
        _mm256_storeu_pd(out.tau.as_mut_ptr().add(l0), acc_lo);
        _mm256_storeu_pd(out.tau.as_mut_ptr().add(l0 + 4), acc_hi);
    }
    out.cells[l0..l0 + WIDTH].copy_from_slice(&steps.n[l0..l0 + WIDTH]);
}

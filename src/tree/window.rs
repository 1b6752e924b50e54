//! [`Window`]: a dense copy of a box of a tree's voxel values, for a burst of lookups that stay
//! in one small region (a block's points at every shutter time of a motion-blurred map).
//!
//! A lookup in a window reads its 8 voxels straight from a flat array, without the accessor's
//! cached descent or its slow path for the 1 - (7/8)^3 = 33 % of trilinear stencils that
//! straddle a leaf's edge; the blend is [`super::accessor::interpolate`], the accessor's own,
//! so a window gives [`Accessor::trilinear`]'s bits wherever its stencil lies inside.

use super::accessor::{interpolate, Accessor, Block};
use super::leaf_offset;

/// Voxels `[lo, lo + dims)` of a tree, x-major (`z` fastest); empty until [`Window::fill`].
#[derive(Debug, Clone, Default)]
pub struct Window {
    lo: [i64; 3],
    dims: [usize; 3],
    values: Vec<f32>,
}

impl Window {
    /// Hold nothing: every read misses ([`Window::trilinear`] gives `None`).
    pub fn clear(&mut self) {
        self.dims = [0; 3];
        self.values.clear();
    }

    /// Copy voxels `[lo, lo + dims)` of `acc`'s tree (background outside its `i32` range), an
    /// `8^3` block at a time through the accessor's cache.
    pub fn fill(&mut self, acc: &mut Accessor<'_>, lo: [i64; 3], dims: [usize; 3]) {
        self.lo = lo;
        self.dims = dims;
        let n = dims.iter().product::<usize>();
        self.values.clear();
        self.values.resize(n, 0.0);
        if n == 0 {
            return;
        }
        let hi = [0, 1, 2].map(|a| lo[a] + dims[a] as i64);
        let first = lo.map(|c| c.div_euclid(8) * 8);
        let mut bx = first[0];
        while bx < hi[0] {
            let mut by = first[1];
            while by < hi[1] {
                let mut bz = first[2];
                while bz < hi[2] {
                    let block = acc.block_at([bx, by, bz]);
                    let a = [bx.max(lo[0]), by.max(lo[1]), bz.max(lo[2])];
                    let b = [
                        (bx + 8).min(hi[0]),
                        (by + 8).min(hi[1]),
                        (bz + 8).min(hi[2]),
                    ];
                    let (z0, z1) = ((a[2] - lo[2]) as usize, (b[2] - lo[2]) as usize);
                    for x in a[0]..b[0] {
                        for y in a[1]..b[1] {
                            let row =
                                (((x - lo[0]) as usize * dims[1]) + (y - lo[1]) as usize) * dims[2];
                            let out = &mut self.values[row + z0..row + z1];
                            match block {
                                // A leaf's z-run is contiguous (z is the fastest of its
                                // offsets, the low 3 bits of each coordinate).
                                Block::Leaf(v) => {
                                    let o = leaf_offset([x as i32, y as i32, a[2] as i32]);
                                    out.copy_from_slice(&v[o..o + out.len()]);
                                }
                                Block::Const(c) => out.fill(c),
                            }
                        }
                    }
                    bz += 8;
                }
                by += 8;
            }
            bx += 8;
        }
    }

    /// The value of voxel `lo + o` (`o` inside `[0, dims)`, as [`Window::fill`] was given).
    #[inline]
    #[must_use]
    pub fn at(&self, o: [usize; 3]) -> f32 {
        self.values[(o[0] * self.dims[1] + o[1]) * self.dims[2] + o[2]]
    }

    /// The trilinear sample at index point `p` ([`Accessor::trilinear`]'s bits), or `None`
    /// when its 8 voxels (from `floor(p)`, as the accessor takes them) are not all in the
    /// window.
    #[inline(always)]
    pub fn trilinear(&self, p: [f64; 3]) -> Option<f32> {
        use crate::math::floor_i64;
        let (wx, wy, wz) = (floor_i64(p[0]), floor_i64(p[1]), floor_i64(p[2]));
        // The stencil `w, w + 1` inside `[0, dims)` on each axis; a huge `p` fails here.
        let inside = |w: i64, lo: i64, d: usize| {
            let r = w.wrapping_sub(lo);
            (r >= 0 && r < d as i64 - 1).then_some(r as usize)
        };
        let ax = inside(wx, self.lo[0], self.dims[0])?;
        let ay = inside(wy, self.lo[1], self.dims[1])?;
        let az = inside(wz, self.lo[2], self.dims[2])?;
        let u = [p[0] - wx as f64, p[1] - wy as f64, p[2] - wz as f64];
        let (sy, sx) = (self.dims[2], self.dims[1] * self.dims[2]);
        let base = ax * sx + ay * sy + az;
        let g = &self.values[base..base + sx + sy + 2];
        let v = [
            [[g[0], g[1]], [g[sy], g[sy + 1]]],
            [[g[sx], g[sx + 1]], [g[sx + sy], g[sx + sy + 1]]],
        ];
        Some(interpolate(&v, u))
    }

    /// [`Window::trilinear`] on 8 lanes in AVX-512F registers (index points
    /// `(x[l], y[l], z[l])`): `out[l]` for every lane whose stencil lies inside, with the same
    /// bits (floor by rounding toward -inf, which is the accessor's `floor_i64` wherever a
    /// stencil is inside; the 8 voxels gathered; each blend `a + (b - a) w` in f64, unfused,
    /// rounded to f32, with the guards as masks); the returned mask has bit `l` set for each
    /// lane outside (its `out[l]` is unspecified: read it elsewhere).
    ///
    /// # Safety
    /// The CPU must run AVX-512F.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    #[allow(unsafe_code)]
    #[inline]
    pub unsafe fn trilinear8_avx512(&self, [x, y, z]: [&[f64; 8]; 3], out: &mut [f32; 8]) -> u32 {
        use std::arch::x86_64::*;
        if self.dims.iter().any(|&d| d < 2) {
            return 0xff;
        }
        let (sy, sx) = (self.dims[2] as i32, (self.dims[1] * self.dims[2]) as i32);
        // SAFETY: unaligned loads of 8 f64 from arrays of 8.
        let p = unsafe {
            [
                _mm512_loadu_pd(x.as_ptr()),
                _mm512_loadu_pd(y.as_ptr()),
                _mm512_loadu_pd(z.as_ptr()),
            ]
        };
        let zero = _mm512_setzero_pd();
        let mut inside: __mmask8 = 0xff;
        let mut r = [zero; 3];
        let mut u = [zero; 3];
        for a in 0..3 {
            let f = _mm512_roundscale_pd::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(p[a]);
            r[a] = _mm512_sub_pd(f, _mm512_set1_pd(self.lo[a] as f64));
            inside &= _mm512_cmp_pd_mask::<_CMP_GE_OQ>(r[a], zero);
            inside &=
                _mm512_cmp_pd_mask::<_CMP_LT_OQ>(r[a], _mm512_set1_pd((self.dims[a] - 1) as f64));
            u[a] = _mm512_sub_pd(p[a], f);
        }
        // Lanes outside read voxel 0's stencil: inside the window, as `dims >= 2`.
        let mut idx = _mm256_setzero_si256();
        for (a, stride) in [sx, sy, 1].into_iter().enumerate() {
            let ia = _mm512_cvttpd_epi32(_mm512_maskz_mov_pd(inside, r[a]));
            idx = _mm256_add_epi32(idx, _mm256_mullo_epi32(ia, _mm256_set1_epi32(stride)));
        }
        let base = self.values.as_ptr();
        // SAFETY: every lane's index plus `sx + sy + 1` is a voxel of the window (inside lanes
        // by the test above, the others at 0).
        let g = |off: i32| unsafe {
            _mm512_cvtps_pd(_mm256_i32gather_ps::<4>(
                base,
                _mm256_add_epi32(idx, _mm256_set1_epi32(off)),
            ))
        };
        let one = _mm512_set1_pd(1.0);
        let lerp = |a: __m512d, b: __m512d, w: __m512d| {
            let mix = _mm512_add_pd(a, _mm512_mul_pd(_mm512_sub_pd(b, a), w));
            let mix = _mm512_cvtps_pd(_mm512_cvtpd_ps(mix));
            let end = _mm512_mask_blend_pd(_mm512_cmp_pd_mask::<_CMP_EQ_OQ>(w, one), mix, b);
            let keep =
                _mm512_cmp_pd_mask::<_CMP_EQ_OQ>(a, b) | _mm512_cmp_pd_mask::<_CMP_EQ_OQ>(w, zero);
            _mm512_mask_blend_pd(keep, end, a)
        };
        let y0 = lerp(lerp(g(0), g(1), u[2]), lerp(g(sy), g(sy + 1), u[2]), u[1]);
        let y1 = lerp(
            lerp(g(sx), g(sx + 1), u[2]),
            lerp(g(sx + sy), g(sx + sy + 1), u[2]),
            u[1],
        );
        let v = _mm512_cvtpd_ps(lerp(y0, y1, u[0]));
        // SAFETY: an unaligned store of 8 f32 into an array of 8.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr(), v) };
        u32::from(!inside)
    }

    /// [`Window::trilinear8_avx512`] for AVX2 CPUs: the same 8 lanes, read as two halves of 4
    /// `f64` lanes (`_mm_i32gather_ps` for the 8 voxels of each, the comparisons as blend
    /// masks), with the same bits and the same returned mask of lanes outside.
    ///
    /// # Safety
    /// The CPU must run AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(unsafe_code)]
    #[inline]
    pub unsafe fn trilinear8_avx2(&self, [x, y, z]: [&[f64; 8]; 3], out: &mut [f32; 8]) -> u32 {
        let mut outside = 0;
        for half in 0..2 {
            let r = half * 4..half * 4 + 4;
            let q = [&x[r.clone()], &y[r.clone()], &z[r.clone()]];
            let mut o = [0f32; 4];
            // SAFETY: the CPU runs AVX2 (this function's contract).
            outside |= unsafe { self.trilinear4_avx2(q, &mut o) } << (half * 4);
            out[half * 4..half * 4 + 4].copy_from_slice(&o);
        }
        outside
    }

    /// Four lanes of [`Window::trilinear8_avx2`] in AVX2 registers.
    ///
    /// # Safety
    /// The CPU must run AVX2; each of `p`'s slices holds 4 values.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(unsafe_code)]
    #[inline]
    unsafe fn trilinear4_avx2(&self, p: [&[f64]; 3], out: &mut [f32; 4]) -> u32 {
        use std::arch::x86_64::*;
        if self.dims.iter().any(|&d| d < 2) || p.iter().any(|c| c.len() < 4) {
            return 0xf;
        }
        let (sy, sx) = (self.dims[2] as i32, (self.dims[1] * self.dims[2]) as i32);
        // SAFETY: unaligned loads of 4 f64 from slices of at least 4 (checked above).
        let p = unsafe {
            [
                _mm256_loadu_pd(p[0].as_ptr()),
                _mm256_loadu_pd(p[1].as_ptr()),
                _mm256_loadu_pd(p[2].as_ptr()),
            ]
        };
        let zero = _mm256_setzero_pd();
        let mut inside = _mm256_castsi256_pd(_mm256_set1_epi64x(-1));
        let mut r = [zero; 3];
        let mut u = [zero; 3];
        for a in 0..3 {
            let f = _mm256_floor_pd(p[a]);
            r[a] = _mm256_sub_pd(f, _mm256_set1_pd(self.lo[a] as f64));
            inside = _mm256_and_pd(inside, _mm256_cmp_pd::<_CMP_GE_OQ>(r[a], zero));
            let top = _mm256_set1_pd((self.dims[a] - 1) as f64);
            inside = _mm256_and_pd(inside, _mm256_cmp_pd::<_CMP_LT_OQ>(r[a], top));
            u[a] = _mm256_sub_pd(p[a], f);
        }
        // Lanes outside read voxel 0's stencil: inside the window, as `dims >= 2`.
        let mut idx = _mm_setzero_si128();
        for (a, stride) in [sx, sy, 1].into_iter().enumerate() {
            let ia = _mm256_cvttpd_epi32(_mm256_and_pd(inside, r[a]));
            idx = _mm_add_epi32(idx, _mm_mullo_epi32(ia, _mm_set1_epi32(stride)));
        }
        let base = self.values.as_ptr();
        // SAFETY: every lane's index plus `sx + sy + 1` is a voxel of the window (inside lanes
        // by the test above, the others at 0).
        let g = |off: i32| unsafe {
            _mm256_cvtps_pd(_mm_i32gather_ps::<4>(
                base,
                _mm_add_epi32(idx, _mm_set1_epi32(off)),
            ))
        };
        let one = _mm256_set1_pd(1.0);
        let lerp = |a: __m256d, b: __m256d, w: __m256d| {
            let mix = _mm256_add_pd(a, _mm256_mul_pd(_mm256_sub_pd(b, a), w));
            let mix = _mm256_cvtps_pd(_mm256_cvtpd_ps(mix));
            let end = _mm256_blendv_pd(mix, b, _mm256_cmp_pd::<_CMP_EQ_OQ>(w, one));
            let keep = _mm256_or_pd(
                _mm256_cmp_pd::<_CMP_EQ_OQ>(a, b),
                _mm256_cmp_pd::<_CMP_EQ_OQ>(w, zero),
            );
            _mm256_blendv_pd(end, a, keep)
        };
        let y0 = lerp(lerp(g(0), g(1), u[2]), lerp(g(sy), g(sy + 1), u[2]), u[1]);
        let y1 = lerp(
            lerp(g(sx), g(sx + 1), u[2]),
            lerp(g(sx + sy), g(sx + sy + 1), u[2]),
            u[1],
        );
        let v = _mm256_cvtpd_ps(lerp(y0, y1, u[0]));
        // SAFETY: an unaligned store of 4 f32 into an array of 4.
        unsafe { _mm_storeu_ps(out.as_mut_ptr(), v) };
        (!(_mm256_movemask_pd(inside) as u32)) & 0xf
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tree::TreeBuilder;

    #[test]
    fn a_window_reads_the_accessors_bits() {
        let mut b = TreeBuilder::new(0.25);
        for x in -9..13 {
            for y in -3..11 {
                for z in 0..17 {
                    let v = ((x * 31 + y * 7 + z * 3) % 11) as f32 * 0.37 - 1.0;
                    b.set(
                        [x, y, z],
                        if (x + y + z) % 13 == 0 {
                            f32::INFINITY
                        } else {
                            v
                        },
                    );
                }
            }
        }
        let tree = b.build();
        let mut acc = Accessor::new(&tree);
        let mut w = Window::default();
        w.fill(&mut acc, [-12, -6, -4], [28, 20, 26]);
        let mut rng = 0x2545F4914F6CDD1Du64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut inside, mut outside) = (0, 0);
        for _ in 0..20000 {
            let p = [
                next() * 34.0 - 15.0,
                next() * 26.0 - 9.0,
                next() * 32.0 - 7.0,
            ];
            match w.trilinear(p) {
                Some(v) => {
                    inside += 1;
                    assert_eq!(v.to_bits(), acc.trilinear(p).to_bits(), "{p:?}");
                }
                None => outside += 1,
            }
        }
        assert!(inside > 5000 && outside > 1000, "{inside} {outside}");
        #[cfg(target_arch = "x86_64")]
        for level in ["avx512f", "avx2"] {
            let runs = match level {
                "avx512f" => std::arch::is_x86_feature_detected!("avx512f"),
                _ => std::arch::is_x86_feature_detected!("avx2"),
            };
            if !runs {
                continue;
            }
            for round in 0..4000 {
                let mut q = [[0f64; 8]; 3];
                for (a, (scale, shift)) in [(34.0, 15.0), (26.0, 9.0), (32.0, 7.0)]
                    .into_iter()
                    .enumerate()
                {
                    q[a] = std::array::from_fn(|_| next() * scale - shift);
                }
                if round % 7 == 0 {
                    // Integer, negative-zero and far points on one lane.
                    q[0][3] = [2.0, -0.0, 1e300, f64::NAN][round % 4];
                }
                let mut out = [0f32; 8];
                #[allow(unsafe_code)]
                // SAFETY: the CPU runs the level (checked above).
                let outside = unsafe {
                    match level {
                        "avx512f" => w.trilinear8_avx512([&q[0], &q[1], &q[2]], &mut out),
                        _ => w.trilinear8_avx2([&q[0], &q[1], &q[2]], &mut out),
                    }
                };
                for l in 0..8 {
                    let p = [q[0][l], q[1][l], q[2][l]];
                    match w.trilinear(p) {
                        Some(v) if outside >> l & 1 == 0 => {
                            assert_eq!(v.to_bits(), out[l].to_bits(), "{level} lane {l} at {p:?}");
                        }
                        // NaN: the scalar read takes voxel 0 as the accessor does; the lanes
                        // leave it to them.
                        Some(_) => assert!(p.iter().any(|c| c.is_nan()), "{p:?}"),
                        None => assert!(outside >> l & 1 == 1, "lane {l} at {p:?}"),
                    }
                }
            }
        }
        // On the window's last cells and just past them.
        assert!(w.trilinear([14.5, 12.5, 20.5]).is_some());
        assert!(w.trilinear([15.0, 0.0, 0.0]).is_none());
        // A NaN point reads the voxels at `floor_i64(NaN)` as the accessor does: the same bits.
        let nan = [f64::NAN, 0.0, 0.0];
        assert_eq!(
            w.trilinear(nan).map(f32::to_bits),
            Some(acc.trilinear(nan).to_bits())
        );
        assert!(w.trilinear([1e300, 0.0, 0.0]).is_none());
    }
}

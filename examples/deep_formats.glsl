// umbra fixed-size deep shadow maps (`umbra bake --deep-format`): T at a texel and depth.
//
// The same reconstructions as umbra's encoder (src/bake/encode/fixed/) and Python's
// umbra.deep_transmittance, in GLSL (4.00 or later; GLSL ES 3.10 with the loops unrolled by the
// driver). Feed a texel's channels in the order the format names them (docs/deep_formats.md):
//   fourier:K   a0, a1, b1, ..., aN, bN                 (K = 2N + 1 values)
//   moments:k   b0, m1, ..., mk                          (k = 4 or 6)
//   avsm:K      z0, tau0, z1, tau1, ..., z{K-1}, tau{K-1}
// and the normalised depth u = (z - near) / (far - near), z the distance along the texel's ray,
// near and far the map's umbra:deep_near and umbra:deep_far. Every function returns T in [0, 1],
// never growing with u. The moment bound runs in UMBRA_REAL (float by default; define it as
// double before including this file for the last digits on thick media).
//
// tests: python/tests/test_deep_formats.py runs these functions on a GPU (Mesa's llvmpipe
// through EGL where no other is present) against umbra.deep_transmittance on every texel of
// a baked map.

#ifndef UMBRA_REAL
#define UMBRA_REAL float
#endif
#define UMBRA_FOURIER_MAX 63
#define UMBRA_AVSM_MAX 32

// fourier:K: tau(u) = a0 u + sum_k f_k (a_k sin(w u) + b_k (1 - cos(w u))) / w, w = 2 pi k,
// f_k = 1 - k / (N + 1) (Fejer's window: the density stays non-negative).
float umbraFourierT(float c[UMBRA_FOURIER_MAX], int K, float u) {
    u = clamp(u, 0.0, 1.0);
    int n = K / 2;
    float tau = c[0] * u;
    for (int i = 1; i <= n; ++i) {
        float w = 6.283185307179586 * float(i);
        float f = 1.0 - float(i) / float(n + 1);
        tau += f * (c[2 * i - 1] * sin(w * u) + c[2 * i] * (1.0 - cos(w * u))) / w;
    }
    return exp(-max(tau, 0.0));
}

// avsm:K: tau linear between the nodes (u_i, tau_i), 0 before the first, the last after it.
float umbraAvsmT(float c[2 * UMBRA_AVSM_MAX], int K, float u) {
    if (u < c[0]) {
        return 1.0;
    }
    for (int i = 0; i < K - 1; ++i) {
        float u0 = c[2 * i];
        float u1 = c[2 * i + 2];
        if (u < u1) {
            float w = u1 > u0 ? clamp((u - u0) / (u1 - u0), 0.0, 1.0) : 1.0;
            return exp(-max(mix(c[2 * i + 1], c[2 * i + 3], w), 0.0));
        }
    }
    return exp(-max(c[2 * K - 1], 0.0));
}

// moments:k (k = 4 or 6): T = exp(-b0 F(x)), x = 2u - 1, F the Hamburger bound on the share of
// extinction in front of x from the moments biased toward the uniform distribution's
// (beta 5e-7 / 5e-6), the overestimation 1/4 (docs/deep_formats.md has the derivation).
float umbraMomentsT(float c[7], int k, float u) {
    float b0 = c[0];
    if (!(b0 > 0.0)) {
        return 1.0;
    }
    int n = k / 2;
    int s = n + 1;
    UMBRA_REAL x = UMBRA_REAL(clamp(2.0 * u - 1.0, -1.0, 1.0));
    UMBRA_REAL beta = k == 4 ? UMBRA_REAL(5e-7) : UMBRA_REAL(5e-6);
    UMBRA_REAL m[7];
    m[0] = UMBRA_REAL(1.0);
    for (int j = 1; j <= 2 * n; ++j) {
        UMBRA_REAL star = (j % 2 == 0) ? UMBRA_REAL(1.0) / UMBRA_REAL(j + 1) : UMBRA_REAL(0.0);
        m[j] = (UMBRA_REAL(1.0) - beta) * UMBRA_REAL(c[j]) + beta * star;
    }
    // B c = (1, x, ..., x^n) by B = L D L^T, B_ij = m[i + j].
    UMBRA_REAL L[16];
    UMBRA_REAL D[4];
    UMBRA_REAL y[4];
    UMBRA_REAL xp = UMBRA_REAL(1.0);
    for (int i = 0; i < 4; ++i) {
        y[i] = xp;
        xp *= x;
        D[i] = UMBRA_REAL(0.0);
        for (int j = 0; j < 4; ++j) {
            L[4 * i + j] = UMBRA_REAL(0.0);
        }
    }
    for (int i = 0; i < s; ++i) {
        for (int j = 0; j <= i; ++j) {
            UMBRA_REAL v = m[i + j];
            for (int q = 0; q < j; ++q) {
                v -= L[4 * i + q] * L[4 * j + q] * D[q];
            }
            if (i == j) {
                if (!(v > UMBRA_REAL(0.0))) {
                    return exp(-b0 * (float(x) < c[1] ? 0.0 : 1.0));
                }
                D[i] = v;
                L[4 * i + i] = UMBRA_REAL(1.0);
            } else {
                L[4 * i + j] = v / D[j];
            }
        }
    }
    for (int i = 0; i < s; ++i) {
        for (int q = 0; q < i; ++q) {
            y[i] -= L[4 * i + q] * y[q];
        }
    }
    for (int i = 0; i < s; ++i) {
        y[i] /= D[i];
    }
    for (int i = s - 1; i >= 0; --i) {
        for (int q = i + 1; q < s; ++q) {
            y[i] -= L[4 * q + i] * y[q];
        }
    }
    // The roots of the kernel polynomial y0 + y1 t + ... + yn t^n; a root beyond 1e3 (its
    // weight of order |t|^-2n) is dropped.
    UMBRA_REAL r3[3];
    if (n == 2) {
        UMBRA_REAL a = y[2], b = y[1], cc = y[0];
        UMBRA_REAL disc = max(b * b - UMBRA_REAL(4.0) * a * cc, UMBRA_REAL(0.0));
        UMBRA_REAL q = UMBRA_REAL(-0.5) * (b + (b >= UMBRA_REAL(0.0) ? UMBRA_REAL(1.0) : UMBRA_REAL(-1.0)) * sqrt(disc));
        r3[0] = q / a;
        r3[1] = cc / q;
        r3[2] = UMBRA_REAL(1e30);
    } else {
        // The largest root by the trigonometric solution, polished by Newton in UMBRA_REAL,
        // then the quadratic left from the constant term up (stable for a large root).
        UMBRA_REAL b = y[2] / y[3], cc = y[1] / y[3], dd = y[0] / y[3];
        UMBRA_REAL p = min(cc - b * b / UMBRA_REAL(3.0), UMBRA_REAL(-1e-30));
        UMBRA_REAL q = UMBRA_REAL(2.0) * b * b * b / UMBRA_REAL(27.0) - b * cc / UMBRA_REAL(3.0) + dd;
        UMBRA_REAL rm = UMBRA_REAL(2.0) * sqrt(-p / UMBRA_REAL(3.0));
        float phi = acos(clamp(float(UMBRA_REAL(3.0) * q / (p * rm)), -1.0, 1.0)) / 3.0;
        UMBRA_REAL r = UMBRA_REAL(0.0);
        for (int i = 0; i < 3; ++i) {
            UMBRA_REAL t = rm * UMBRA_REAL(cos(phi - 2.0943951023931953 * float(i))) - b / UMBRA_REAL(3.0);
            if (abs(t) > abs(r)) {
                r = t;
            }
        }
        for (int it = 0; it < 2; ++it) {
            UMBRA_REAL f = ((y[3] * r + y[2]) * r + y[1]) * r + y[0];
            UMBRA_REAL df = (UMBRA_REAL(3.0) * y[3] * r + UMBRA_REAL(2.0) * y[2]) * r + y[1];
            if (df != UMBRA_REAL(0.0)) {
                r -= f / df;
            }
        }
        UMBRA_REAL qc = -y[0] / r;
        UMBRA_REAL qb = (qc - y[1]) / r;
        UMBRA_REAL qa = (qb - y[2]) / r;
        UMBRA_REAL disc = max(qb * qb - UMBRA_REAL(4.0) * qa * qc, UMBRA_REAL(0.0));
        UMBRA_REAL qq = UMBRA_REAL(-0.5) * (qb + (qb >= UMBRA_REAL(0.0) ? UMBRA_REAL(1.0) : UMBRA_REAL(-1.0)) * sqrt(disc));
        r3[0] = qq / qa;
        r3[1] = qc / qq;
        r3[2] = r;
    }
    UMBRA_REAL z[4];
    int d = 0;
    z[0] = x;
    for (int i = 0; i < 3; ++i) {
        if (abs(r3[i]) <= UMBRA_REAL(1e3)) {
            d += 1;
            z[d] = r3[i];
        }
    }
    // The polynomial interpolating 1/4 at x and [z_i < x] at the roots, in the monomial basis
    // (constant loop bounds: Mesa's llvmpipe skipped loops bounded by d).
    UMBRA_REAL dv[4];
    dv[0] = UMBRA_REAL(0.25);
    for (int i = 1; i < 4; ++i) {
        dv[i] = (i <= d && z[i] < x) ? UMBRA_REAL(1.0) : UMBRA_REAL(0.0);
    }
    for (int lvl = 1; lvl < 4; ++lvl) {
        for (int i = 3; i >= 1; --i) {
            if (lvl <= d && i <= d && i >= lvl) {
                dv[i] = (dv[i] - dv[i - 1]) / (z[i] - z[i - lvl]);
            }
        }
    }
    UMBRA_REAL poly[4];
    for (int i = 0; i < 4; ++i) {
        poly[i] = UMBRA_REAL(0.0);
    }
    poly[0] = dv[d];
    for (int i = 2; i >= 0; --i) {
        if (i <= d - 1) {
            for (int j = 3; j >= 1; --j) {
                if (j <= d - i) {
                    poly[j] = poly[j - 1] - z[i] * poly[j];
                }
            }
            poly[0] = dv[i] - z[i] * poly[0];
        }
    }
    UMBRA_REAL f = UMBRA_REAL(0.0);
    for (int j = 0; j < 4; ++j) {
        if (j <= d) {
            f += poly[j] * m[j];
        }
    }
    float F = float(f);
    if (isnan(F) || isinf(F)) {
        F = float(x) < c[1] ? 0.0 : 1.0;
    }
    return exp(-b0 * clamp(F, 0.0, 1.0));
}

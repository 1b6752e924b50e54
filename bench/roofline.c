// Roofline ceilings of this machine for docs/performance.md section 7: memory bandwidth
// (STREAM-style triad a = b + s c over arrays far larger than the caches) and peak f32/f64
// fused multiply-add throughput (independent FMA chains in AVX-512 registers, or AVX2 where
// AVX-512 is missing), each on 1 and N threads. Build and run:
//   gcc -O3 -march=native -fopenmp bench/roofline.c -o /tmp/roofline && /tmp/roofline
#include <immintrin.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <string.h>

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static double triad(int threads, size_t n, int reps) {
    double *a = aligned_alloc(64, n * 8), *b = aligned_alloc(64, n * 8), *c = aligned_alloc(64, n * 8);
#pragma omp parallel for num_threads(threads)
    for (size_t i = 0; i < n; i++) { a[i] = 0; b[i] = 1; c[i] = 2; }
    double best = 1e30;
    for (int r = 0; r < reps; r++) {
        double t0 = now();
#pragma omp parallel for num_threads(threads)
        for (size_t i = 0; i < n; i++) a[i] = b[i] + 3.0 * c[i];
        double t = now() - t0;
        if (t < best) best = t;
    }
    volatile double sink = a[n / 2];
    (void)sink;
    free(a); free(b); free(c);
    return 3.0 * 8.0 * n / best / 1e9; // GB/s (2 reads + 1 write; write-allocate not counted)
}

#if defined(__AVX512F__)
#define VEC __m512
#define VFMA(a, b, c) _mm512_fmadd_ps(a, b, c)
#define VSET(x) _mm512_set1_ps(x)
#define LANES 16
#else
#define VEC __m256
#define VFMA(a, b, c) _mm256_fmadd_ps(a, b, c)
#define VSET(x) _mm256_set1_ps(x)
#define LANES 8
#endif

static double fma_rate(int threads, long iters) {
    double best = 1e30;
    for (int r = 0; r < 5; r++) {
        double t0 = now();
#pragma omp parallel num_threads(threads)
        {
            VEC x0 = VSET(1.0f), x1 = VSET(1.1f), x2 = VSET(1.2f), x3 = VSET(1.3f);
            VEC x4 = VSET(1.4f), x5 = VSET(1.5f), x6 = VSET(1.6f), x7 = VSET(1.7f);
            VEC x8 = VSET(1.8f), x9 = VSET(1.9f), xa = VSET(2.0f), xb = VSET(2.1f);
            const VEC m = VSET(0.999999f), k = VSET(1e-7f);
            for (long i = 0; i < iters; i++) {
                x0 = VFMA(x0, m, k); x1 = VFMA(x1, m, k); x2 = VFMA(x2, m, k); x3 = VFMA(x3, m, k);
                x4 = VFMA(x4, m, k); x5 = VFMA(x5, m, k); x6 = VFMA(x6, m, k); x7 = VFMA(x7, m, k);
                x8 = VFMA(x8, m, k); x9 = VFMA(x9, m, k); xa = VFMA(xa, m, k); xb = VFMA(xb, m, k);
                // Keep every chain in a register and every FMA executed.
                __asm__ volatile("" : "+v"(x0), "+v"(x1), "+v"(x2), "+v"(x3), "+v"(x4), "+v"(x5));
                __asm__ volatile("" : "+v"(x6), "+v"(x7), "+v"(x8), "+v"(x9), "+v"(xa), "+v"(xb));
            }
            float out[LANES];
            VEC s = VFMA(x0, x1, VFMA(x2, x3, VFMA(x4, x5, VFMA(x6, x7, VFMA(x8, x9, VFMA(xa, xb, k))))));
            memcpy(out, &s, sizeof out);
            volatile float sink = out[0];
            (void)sink;
        }
        double t = now() - t0;
        if (t < best) best = t;
    }
    return 12.0 * 2.0 * LANES * iters * threads / best / 1e9; // GFLOP/s (FMA = 2 flops)
}

int main(void) {
    int n = omp_get_num_procs();
    printf("vector width: %d f32 lanes (%s)\n", LANES, LANES == 16 ? "AVX-512" : "AVX2");
    for (int t = 1; t <= n; t *= 2) {
        printf("threads %d: triad %.1f GB/s, f32 FMA peak %.1f GFLOP/s\n", t,
               triad(t, (size_t)1 << 25, 10), fma_rate(t, 200000000L / LANES));
        if (t * 2 > n && t != n) t = n / 2;
    }
    return 0;
}

//! The kernel against f64 quadrature, and every SIMD version against the portable one.
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
/// and every SIMD version this CPU runs bit for bit against the portable one.
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
        let got = Kernel::portable().integrate(&block, &lanes);
        for k in Kernel::every() {
            assert_eq!(
                k.integrate(&block, &lanes),
                got,
                "{:?} and portable differ",
                k.simd
            );
        }
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
/// field, and every SIMD version this CPU runs bit for bit against the portable one.
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
        let got = Kernel::portable().march(&block, &lanes, &steps, offsets);
        for k in Kernel::every() {
            let other = k.march(&block, &lanes, &steps, offsets);
            assert_eq!(other, got, "{:?} and portable differ", k.simd);
        }
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
    for k in Kernel::every() {
        let got = k.integrate(&block, &lanes);
        // int_0^4 (8 - 2 t) dt = 16.
        for l in 0..LANES {
            assert!((got.tau[l] - 16.0).abs() < 1e-5, "{}", got.tau[l]);
            assert_eq!(got.cells[l], 8);
        }
    }
}

/// Rays on the lattice: entries on cell faces, edges and corners (`e` an integer, so a
/// first face time of `-0`), directions with zero and negative components, grazing a face,
/// unused lanes (holding a stale ray) in either half of the batch and a whole half unused:
/// every SIMD version bit for bit against the portable one, exact and marched.
#[test]
fn lattice_rays_agree_bit_for_bit() {
    let mut st = 23u64;
    let mut block = [0f32; BLOCK];
    for v in &mut block {
        *v = (lcg(&mut st) * 2.0) as f32;
    }
    let pick = |st: &mut u64, from: &[f64]| from[(lcg(st) * from.len() as f64) as usize];
    for round in 0..200 {
        let mut lanes = Lanes::default();
        let mut steps = Steps::default();
        let used = match round % 4 {
            0 => LANES,
            1 => LANES / 2,
            2 => 3,
            _ => LANES - 1,
        };
        for l in 0..used {
            let d = [0; 3].map(|_| pick(&mut st, &[0.0, 0.0, 1.0, -1.0, 0.5, -2.0, 0.3]));
            let d = if d == [0.0; 3] { [0.0, 0.0, -1.0] } else { d };
            let e = [0; 3].map(|_| pick(&mut st, &[-4.0, -3.0, 0.0, 2.0, 3.5, 4.0, -0.5]));
            let len = pick(&mut st, &[0.0, 0.25, 1.0, 3.0, 8.0]);
            lanes.set(l, e, d, len);
            let n = if len > 0.0 { 1 + (l + round) % 9 } else { 0 };
            steps.n[l] = n as u32;
            steps.dt[l] = (len / n.max(1) as f64) as f32;
        }
        // Unused lanes keep a stale ray (callers reset only `len` and `n`).
        for l in used..LANES {
            lanes.set(l, [1.5, -2.0, 0.25], [0.3, 0.0, -1.0], 0.0);
            steps.dt[l] = 0.5;
        }
        let (whole, marched) = (
            Kernel::portable().integrate(&block, &lanes),
            Kernel::portable().march(&block, &lanes, &steps, None),
        );
        for k in Kernel::every() {
            assert_eq!(
                k.integrate(&block, &lanes),
                whole,
                "{:?}, round {round}",
                k.simd
            );
            let m = k.march(&block, &lanes, &steps, None);
            assert_eq!(m, marched, "{:?} march, round {round}", k.simd);
        }
        for l in used..LANES {
            assert_eq!((whole.tau[l], whole.cells[l]), (0.0, 0));
        }
    }
}

/// `UMBRA_SIMD`'s names, and the level in use is one the CPU runs.
#[test]
fn simd_levels() {
    for s in [Simd::Portable, Simd::Avx2, Simd::Avx512] {
        assert_eq!(Simd::parse(s.name()), Some(s));
    }
    assert_eq!(Simd::parse("AVX-512"), Some(Simd::Avx512));
    assert_eq!(Simd::parse("sse9"), None);
    assert!(Simd::active() <= Simd::detected());
}

//! Render one orthographic transmittance view exactly as `vdb_render -camera ortho` frames it
//! (the convention of `../shared/tools/oracle.py image`), in parallel, and write `T` to an EXR
//! (`R = G = B = T`, `A = 1 - T`, as vdb_render's alpha). The peer benchmark (`bench/peer.sh`)
//! runs it against vdb_render on the same view.
//!
//! ```sh
//! cargo run --release --example ortho_view -- FILE --grid density --scale 5 \
//!     --dir=0.6,-0.35,-1 --center=-2.07,1.21,1.93 --up=0,1,0 --frame 4.4 --res 512x512 \
//!     [--estimator regular|riemann] [--step 1] [--interp trilinear|nearest] [--threads 0] \
//!     [--reps 1] [--out t.exr]
//! ```
//!
//! Camera (OpenVDB `OrthographicCamera`): `d = normalise(dir)`, `u = normalise(up - (up.d) d)`,
//! `r = d x u`; pixel `(i, j)` (row 0 at the top) starts at
//! `center + r (2 (i + .5) / W - 1) frame / 2 + u (1 - 2 (j + .5) / H) (frame / 2) H / W`
//! and runs along `d` for `t` in `[0, inf)`. Prints one JSON line: load and render seconds
//! (median of `--reps`), rays/s, cells and lookups per ray, peak resident memory.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use rayon::prelude::*;
use std::time::Instant;
use umbra::estimate::{estimate, Estimator, Options};
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

fn vec3(s: &str) -> [f64; 3] {
    let v: Vec<f64> = s.split(',').map(|x| x.trim().parse().unwrap()).collect();
    assert_eq!(v.len(), 3, "expected x,y,z: {s}");
    [v[0], v[1], v[2]]
}

fn norm(v: [f64; 3]) -> [f64; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|c| c / l)
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// A minimal single-part scanline OpenEXR file, uncompressed, float channels `A, B, G, R` with
/// `R = G = B = T` and `A = 1 - T` (what vdb_render writes), row 0 at the top.
fn exr_rgba(t: &[f32], w: usize, h: usize) -> Vec<u8> {
    let mut b: Vec<u8> = vec![0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0];
    let attr = |b: &mut Vec<u8>, name: &str, ty: &str, v: &[u8]| {
        b.extend_from_slice(name.as_bytes());
        b.push(0);
        b.extend_from_slice(ty.as_bytes());
        b.push(0);
        b.extend_from_slice(&(v.len() as i32).to_le_bytes());
        b.extend_from_slice(v);
    };
    let mut ch = Vec::new();
    for c in ["A", "B", "G", "R"] {
        ch.extend_from_slice(c.as_bytes());
        ch.push(0);
        ch.extend_from_slice(&2i32.to_le_bytes()); // FLOAT
        ch.extend_from_slice(&[0, 0, 0, 0]); // pLinear, reserved
        ch.extend_from_slice(&1i32.to_le_bytes());
        ch.extend_from_slice(&1i32.to_le_bytes());
    }
    ch.push(0);
    let win: Vec<u8> = [0i32, 0, w as i32 - 1, h as i32 - 1]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    attr(&mut b, "channels", "chlist", &ch);
    attr(&mut b, "compression", "compression", &[0]);
    attr(&mut b, "dataWindow", "box2i", &win);
    attr(&mut b, "displayWindow", "box2i", &win);
    attr(&mut b, "lineOrder", "lineOrder", &[0]);
    attr(&mut b, "pixelAspectRatio", "float", &1f32.to_le_bytes());
    attr(&mut b, "screenWindowCenter", "v2f", &[0; 8]);
    attr(&mut b, "screenWindowWidth", "float", &1f32.to_le_bytes());
    b.push(0);
    let line = 8 + 16 * w;
    let first = b.len() + 8 * h;
    for y in 0..h {
        b.extend_from_slice(&((first + y * line) as u64).to_le_bytes());
    }
    for y in 0..h {
        b.extend_from_slice(&(y as i32).to_le_bytes());
        b.extend_from_slice(&((16 * w) as i32).to_le_bytes());
        let row = &t[y * w..(y + 1) * w];
        for f in [|t: f32| 1.0 - t, |t| t, |t| t, |t| t] {
            row.iter()
                .for_each(|&v| b.extend_from_slice(&f(v).to_le_bytes()));
        }
    }
    b
}

/// Peak resident set size (VmHWM) of this process in bytes.
fn peak_rss() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
        })
        .map_or(0, |kb| kb * 1024)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut file = None;
    let mut opt = std::collections::HashMap::new();
    let mut i = 0;
    while i < args.len() {
        let a = &args[i];
        if let Some(k) = a.strip_prefix("--") {
            if let Some((k, v)) = k.split_once('=') {
                opt.insert(k.to_string(), v.to_string());
            } else {
                opt.insert(k.to_string(), args[i + 1].clone());
                i += 1;
            }
        } else {
            file = Some(a.clone());
        }
        i += 1;
    }
    let get = |k: &str, d: &str| opt.get(k).cloned().unwrap_or_else(|| d.to_string());
    let file = file.expect("FILE");
    let grid = get("grid", "density");
    let scale: f64 = get("scale", "1").parse().unwrap();
    let dir = norm(vec3(&get("dir", "0,0,-1")));
    let center = vec3(&get("center", "0,0,0"));
    let up = vec3(&get("up", "0,1,0"));
    let frame: f64 = get("frame", "1").parse().unwrap();
    let (w, h) = {
        let r = get("res", "512x512");
        let (a, b) = r.split_once('x').unwrap();
        (a.parse::<usize>().unwrap(), b.parse::<usize>().unwrap())
    };
    let threads: usize = get("threads", "0").parse().unwrap();
    let reps: usize = get("reps", "1").parse().unwrap();
    let step: f64 = get("step", "1").parse().unwrap();
    let interp = match get("interp", "trilinear").as_str() {
        "nearest" => Interp::Nearest,
        _ => Interp::Trilinear,
    };
    let est = match get("estimator", "regular").as_str() {
        "regular" => Estimator::Regular,
        "riemann" => Estimator::Riemann { step },
        other => Estimator::from_name(other, step, 0.0).expect("estimator name"),
    };
    let out = opt.get("out").cloned();

    let t = Instant::now();
    let vol = Volume::load(&file, &grid, scale).unwrap();
    let load_s = t.elapsed().as_secs_f64();
    let rss_loaded = peak_rss();

    let u = norm({
        let k = up[0] * dir[0] + up[1] * dir[1] + up[2] * dir[2];
        [0, 1, 2].map(|a| up[a] - k * dir[a])
    });
    let r = norm(cross(dir, u));
    let half = frame / 2.0;
    let aspect = h as f64 / w as f64;
    let pixel_ray = |i: usize, j: usize| {
        let x = (2.0 * (i as f64 + 0.5) / w as f64 - 1.0) * half;
        let y = (1.0 - 2.0 * (j as f64 + 0.5) / h as f64) * half * aspect;
        let o = [0, 1, 2].map(|a| center[a] + r[a] * x + u[a] * y);
        Ray::new(o, dir, 0.0, f64::INFINITY).unwrap()
    };
    let opts = Options {
        interp,
        ..Options::default()
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let mut img = vec![0f32; w * h];
    let mut times = Vec::new();
    let (mut cells, mut lookups) = (0u64, 0u64);
    for _ in 0..reps {
        let t = Instant::now();
        let (c, l) = pool.install(|| {
            img.par_chunks_mut(w)
                .enumerate()
                .map(|(j, row)| {
                    let (mut c, mut l) = (0u64, 0u64);
                    for (i, px) in row.iter_mut().enumerate() {
                        let ray = pixel_ray(i, j);
                        *px = if let Estimator::Regular = est {
                            let od = optical_depth(&vol, &ray, interp).unwrap();
                            c += od.cells;
                            l += od.lookups;
                            od.transmittance() as f32
                        } else {
                            let e = estimate(&vol, &ray, (j * w + i) as u64, &est, &opts).unwrap();
                            l += e.lookups;
                            e.value as f32
                        };
                    }
                    (c, l)
                })
                .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
        });
        times.push(t.elapsed().as_secs_f64());
        (cells, lookups) = (c, l);
    }
    times.sort_by(f64::total_cmp);
    let render_s = times[times.len() / 2];
    if let Some(path) = &out {
        std::fs::write(path, exr_rgba(&img, w, h)).unwrap();
    }
    let rays = (w * h) as f64;
    println!(
        "{}",
        serde_json::json!({
            "file": file, "estimator": est.name(), "step": step, "interp": format!("{interp:?}"),
            "threads": pool.current_num_threads(), "res": [w, h],
            "load_s": load_s, "render_s": render_s, "render_s_all": times,
            "rays_per_s": rays / render_s,
            "cells_per_ray": cells as f64 / rays, "lookups_per_ray": lookups as f64 / rays,
            "ns_per_cell_thread": if cells > 0 {
                render_s * 1e9 * pool.current_num_threads() as f64 / cells as f64
            } else { 0.0 },
            "tree_bytes": vol.tree.memory_bytes(),
            "peak_rss_after_load": rss_loaded, "peak_rss": peak_rss(),
        })
    );
}

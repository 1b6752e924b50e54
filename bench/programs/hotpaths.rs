//! A driver for profilers (callgrind, perf): runs one hot path many times with no harness
//! noise. `cargo run --release --ignore-rust-version --example hotpaths -- MODE [FILE] [REPS]`, MODE one of
//! `nearest`, `trilinear`, `vdbrs` (vdb-rs bare parse) (exact regular tracking of 2000 random rays crossing the grid's box,
//! REPS times) or `load` (full load of FILE's `density` grid, REPS times).
//! `segments FILE CSV SCALE REPS [OUT]`: a query batch as `umbra query --rays CSV` and Python's
//! `Volume.transmittance` trace it (every row's exact transmittance from `o` to `e`:
//! `umbra::regular::optical_depths`, leaf chords in object order on the SIMD kernel;
//! `segments-rays`: each row's own walk, `estimate::estimate`, rows in parallel on rayon's
//! threads), the trace alone timed (median of REPS); one JSON line, and the
//! T of every row as f32 into OUT (bench/queries.py compares them with NanoVDB's).
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use rand::{Rng, SeedableRng};
use std::hint::black_box;
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let mode = args.get(1).map_or("trilinear", String::as_str);
    let file = args
        .get(2)
        .cloned()
        .unwrap_or_else(|| "../shared/corpus/gen/cloud_fbm.vdb".into());
    let reps: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(1);
    if mode == "vdbrs" {
        let t = std::time::Instant::now();
        for _ in 0..reps {
            let f = std::io::BufReader::new(std::fs::File::open(&file).unwrap());
            let mut r = vdb_rs::VdbReader::new(f).unwrap();
            black_box(r.read_grid::<f32>("density").unwrap());
        }
        eprintln!(
            "vdb-rs: {:.3} ms/parse",
            t.elapsed().as_secs_f64() * 1e3 / reps as f64
        );
        return;
    }
    if mode == "load" {
        let t = std::time::Instant::now();
        for _ in 0..reps {
            black_box(umbra::internals::vdb::load_grid(&file, "density").unwrap());
        }
        eprintln!(
            "load: {:.3} ms/load",
            t.elapsed().as_secs_f64() * 1e3 / reps as f64
        );
        return;
    }
    if mode == "segments" || mode == "segments-rays" {
        segments(&args, mode == "segments-rays");
        return;
    }
    let interp = if mode == "nearest" {
        Interp::Nearest
    } else {
        Interp::Trilinear
    };
    let vol = Volume::load(&file, "density", 5.0).unwrap();
    let info = umbra::info::FileInfo::from_archive(&umbra::internals::vdb::open(&file).unwrap());
    let [lo, hi] = info.grids[0].world_bbox.unwrap();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let rays: Vec<Ray> = (0..2000)
        .map(|_| {
            let mut p = || [0, 1, 2].map(|a| rng.gen_range(lo[a]..hi[a]));
            let (a, b) = (p(), p());
            let d = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let o = [0, 1, 2].map(|k| a[k] - 2.0 * d[k]);
            let e = [0, 1, 2].map(|k| a[k] + 3.0 * d[k]);
            Ray::between(o, e).unwrap()
        })
        .collect();
    let t = std::time::Instant::now();
    let (mut tau, mut cells, mut segs) = (0.0, 0u64, 0u64);
    for _ in 0..reps {
        for r in &rays {
            let od = optical_depth(&vol, r, interp).unwrap();
            tau += od.tau;
            cells += od.cells;
            segs += od.segments;
        }
    }
    let s = t.elapsed().as_secs_f64();
    let n = (reps * rays.len()) as f64;
    eprintln!(
        "{mode}: {:.0} rays/s, {:.1} cells/ray, {:.1} segments/ray, {:.1} ns/cell, sum tau {tau:.9e}",
        n / s,
        cells as f64 / n,
        segs as f64 / n,
        s * 1e9 / cells as f64
    );
}

fn segments(args: &[String], by_ray: bool) {
    use rayon::prelude::*;
    let (file, csv) = (&args[2], &args[3]);
    let scale: f64 = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(1.0);
    let reps: usize = args.get(5).and_then(|s| s.parse().ok()).unwrap_or(1);
    let vol = Volume::load(file, "density", scale).unwrap();
    let rays: Vec<Ray> = std::fs::read_to_string(csv)
        .unwrap()
        .lines()
        .filter_map(|l| {
            let v: Vec<f64> = l.split(',').filter_map(|x| x.trim().parse().ok()).collect();
            (v.len() == 6).then(|| Ray::between([v[0], v[1], v[2]], [v[3], v[4], v[5]]).unwrap())
        })
        .collect();
    let (est, opts) = (
        umbra::estimate::Estimator::REGULAR,
        umbra::estimate::Options::default(),
    );
    let mut times = Vec::new();
    let mut t = Vec::new();
    for _ in 0..reps {
        let start = std::time::Instant::now();
        t = if by_ray {
            rays.par_iter()
                .enumerate()
                .map(|(k, r)| {
                    umbra::estimate::estimate(&vol, r, k as u64, &est, &opts)
                        .unwrap()
                        .value as f32
                })
                .collect::<Vec<f32>>()
        } else {
            umbra::regular::optical_depths(&vol, &rays, Interp::Trilinear)
                .into_iter()
                .map(|od| od.unwrap().transmittance() as f32)
                .collect()
        };
        times.push(start.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    let secs = times[times.len() / 2];
    if let Some(out) = args.get(6) {
        let bytes: Vec<u8> = t.iter().flat_map(|x| x.to_le_bytes()).collect();
        std::fs::write(out, bytes).unwrap();
    }
    println!(
        "{{\"segments\":{},\"by_ray\":{by_ray},\"simd\":\"{}\",\"threads\":{},\"trace_s\":{secs:.6},\"mrays_per_s\":{:.4}}}",
        rays.len(),
        umbra::regular::Simd::active().name(),
        rayon::current_num_threads(),
        rays.len() as f64 / secs / 1e6
    );
}

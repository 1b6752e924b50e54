//! How long a whole grid takes to load, by file format: `Volume::load` (decode, build the flat
//! tree, compute its bounds) of each file given, timed in `REPS` rounds that alternate the files after one
//! warm-up round, median and spread printed with the file's size on disk and the loaded tree's memory. With
//! `--once`, one load and the process's peak resident memory (`VmHWM`), for one file per
//! process (what `bench/nvdb_load.sh` runs to compare memory).
//!
//! ```sh
//! cargo run --release --ignore-rust-version --example load_formats -- [--once] GRID REPS FILE...
//! ```
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::time::Instant;
use umbra::Volume;

fn peak_rss_kib() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or(0)
}

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let once = args.first().is_some_and(|a| a == "--once");
    if once {
        args.remove(0);
    }
    let grid = args.first().cloned().unwrap_or_else(|| "density".into());
    let reps: usize = args.get(1).map_or(7, |s| s.parse().unwrap());
    if once {
        let file = &args[2];
        let t0 = Instant::now();
        let vol = Volume::load(file, &grid, 1.0).unwrap();
        let s = t0.elapsed().as_secs_f64();
        println!(
            "{file}\tseconds {s:.4}\ttree_bytes {}\tpeak_rss_kib {}",
            vol.tree().memory_bytes(),
            peak_rss_kib()
        );
        return;
    }
    // Files alternate within each round; the first round is a warm-up (page cache, allocator).
    let files = &args[2..];
    let mut times = vec![Vec::with_capacity(reps); files.len()];
    let mut tree_bytes = vec![0; files.len()];
    for round in 0..=reps {
        for (k, file) in files.iter().enumerate() {
            let t0 = Instant::now();
            let vol = Volume::load(file, &grid, 1.0).unwrap();
            let s = t0.elapsed().as_secs_f64();
            tree_bytes[k] = vol.tree().memory_bytes();
            drop(vol);
            if round > 0 {
                times[k].push(s);
            }
        }
    }
    println!("file\tbytes_on_disk\ttree_bytes\tmedian_s\tmin_s\tmax_s");
    for (k, file) in files.iter().enumerate() {
        let on_disk = std::fs::metadata(file).map_or(0, |m| m.len());
        let t = &mut times[k];
        t.sort_by(f64::total_cmp);
        println!(
            "{file}\t{on_disk}\t{}\t{:.4}\t{:.4}\t{:.4}",
            tree_bytes[k],
            t[t.len() / 2],
            t[0],
            t[t.len() - 1]
        );
    }
}

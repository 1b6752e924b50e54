//! Deep shadow maps against depth slices at equal error: how many samples per pixel a deep map
//! (`bake --deep --deep-error E`) takes, and how many evenly spaced `--slices K` a flat map
//! needs to describe the same transmittance function `T(z)` within the same `E`.
//!
//! ```sh
//! cargo run --release --ignore-rust-version --example deep_vs_slices -- [FILE] [--res N] [--error E ...] \
//!     [--scale S ...] [--light-dir X,Y,Z] [--grid NAME]
//! ```
//!
//! Defaults: `data/cloud.vdb`, grid `density`, light direction `0.3,-1,0.2`, density scales
//! 4 and 1, `--res 128` (long side), errors 0.01, 0.002 and 0.0005. For every scale and `E`:
//!
//! 1. **Deep.** The library's [`BakeJob`] with [`Product::Deep`] bakes the deep map (regular
//!    tracking, trilinear) into a temporary directory; its [`umbra::bake::DeepStats`] give the
//!    mean and largest samples per pixel, the file its size.
//! 2. **Reference.** On the deep map's camera, every pixel's ray ([`Camera::pixel_ray`]) gets
//!    an optical-depth profile from [`optical_depth_profile`] with the bound `E / 100`: its
//!    `exp(-tau_lin(z))` is within `E / 100` of the exact prefix transmittance at every depth
//!    (see `src/regular/profile.rs`), so it stands in for the exact `T(z)`, and the errors
//!    measured below are exact up to that `E / 100`.
//! 3. **Slices.** `K` slices sit at `t_k = t_near + (t_max - t_near) (k + 1) / K`, `k = 0..K`
//!    (`Depths::Slices(K)`), holding the reference `T(t_k)`. What they describe: `T = 1` at
//!    `t_near` and before, linear in `T` between consecutive slice depths, constant after the
//!    last. Its error against the reference is computed exactly, not sampled: on each interval
//!    between consecutive breakpoints of either function the reference is `exp` of a linear
//!    function (convex) and the description linear, so `|difference|` peaks at an end or where
//!    the slopes match, and all three are evaluated. Every depth of the ray `[0, t_max]` counts.
//! 4. **Smallest K.** The map-wide `K` (one `K` for all pixels: what a slice map needs) is
//!    found by doubling then bisection on "every pixel within `E`"; each pixel's own minimal
//!    `K` likewise on "this pixel within `E`", with `K = 0` (`T = 1` everywhere) allowed for a
//!    pixel whose `T` never drops below `1 - E` (as a deep pixel with no samples). The error is
//!    not strictly monotone in `K` (the slice depths move with `K`), so "smallest" means: `K`
//!    passes and `K - 1` fails; some smaller `K` might pass by luck of the grid.
//! 5. **Flat file.** With `K <= 64` (the most slices umbra bakes) the library bakes the flat
//!    map with `Depths::Slices(K)` on the same camera, for its file size.
//!
//! The mean per-pixel `K` is over all pixels, empty ones included (`K = 0`), as the deep mean
//! samples per pixel are. Everything is deterministic: exact tracking, results collected in
//! pixel order, no timings in the table.

use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use umbra::bake::{
    BakeJob, BakeSettings, Camera, Depths, ExrLayout, Product, Projection, Resolution, View,
    MAX_SLICES,
};
use umbra::estimate::{Estimator, Options};
use umbra::regular::optical_depth_profile;
use umbra::{Interp, Volume};

/// Largest `K` tried before giving up on a pixel or a map.
const MAX_K: usize = 1 << 22;
/// The reference profile's bound, as a fraction of `E`.
const REFERENCE_SHARE: f64 = 0.01;

/// Command-line settings.
#[derive(Debug)]
struct Args {
    file: PathBuf,
    grid: String,
    res: u32,
    errors: Vec<f64>,
    scales: Vec<f64>,
    light_dir: [f64; 3],
}

const USAGE: &str = "usage: deep_vs_slices [FILE] [--res N] [--error E ...] [--scale S ...] \
                     [--light-dir X,Y,Z] [--grid NAME]";

fn parse_args(argv: &[String]) -> Result<Args, String> {
    let mut args = Args {
        file: PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/data/cloud.vdb")),
        grid: "density".into(),
        res: 128,
        errors: Vec::new(),
        scales: Vec::new(),
        light_dir: [0.3, -1.0, 0.2],
    };
    let mut file = None;
    let mut i = 0;
    let value = |i: usize, flag: &str| -> Result<&String, String> {
        argv.get(i + 1)
            .ok_or_else(|| format!("{flag} needs a value\n{USAGE}"))
    };
    // Values after `--error` / `--scale` up to the next flag.
    let list = |i: &mut usize, flag: &str, out: &mut Vec<f64>| -> Result<(), String> {
        let start = *i;
        while let Some(v) = argv.get(*i + 1).filter(|v| !v.starts_with("--")) {
            out.push(number(v, flag)?);
            *i += 1;
        }
        if *i == start {
            return Err(format!("{flag} needs at least one value\n{USAGE}"));
        }
        Ok(())
    };
    while i < argv.len() {
        let a = argv[i].as_str();
        match a {
            "--res" => {
                let v = value(i, a)?;
                args.res = v
                    .parse()
                    .ok()
                    .filter(|n| *n > 0)
                    .ok_or_else(|| format!("--res {v}: a positive pixel count"))?;
                i += 1;
            }
            "--grid" => {
                args.grid = value(i, a)?.clone();
                i += 1;
            }
            "--light-dir" => {
                let v = value(i, a)?;
                let c: Vec<f64> = v
                    .split(',')
                    .map(|x| number(x, a))
                    .collect::<Result<_, _>>()?;
                args.light_dir = c
                    .try_into()
                    .map_err(|_| format!("--light-dir {v}: three numbers X,Y,Z"))?;
                i += 1;
            }
            "--error" => list(&mut i, a, &mut args.errors)?,
            "--scale" => list(&mut i, a, &mut args.scales)?,
            _ if a.starts_with("--") => return Err(format!("unknown option {a}\n{USAGE}")),
            _ if file.is_none() => file = Some(PathBuf::from(a)),
            _ => return Err(format!("one input file only ({a})\n{USAGE}")),
        }
        i += 1;
    }
    if let Some(f) = file {
        args.file = f;
    }
    if args.errors.is_empty() {
        args.errors = vec![0.01, 0.002, 0.0005];
    }
    if args.scales.is_empty() {
        args.scales = vec![4.0, 1.0];
    }
    if let Some(e) = args.errors.iter().find(|e| !(**e > 0.0 && **e < 1.0)) {
        return Err(format!(
            "--error {e}: an error bound between 0 and 1 (in T)"
        ));
    }
    if let Some(s) = args.scales.iter().find(|s| !(s.is_finite() && **s >= 0.0)) {
        return Err(format!("--scale {s}: a finite non-negative density scale"));
    }
    Ok(args)
}

fn number(s: &str, flag: &str) -> Result<f64, String> {
    s.trim()
        .parse()
        .map_err(|_| format!("{flag} {s}: not a number"))
}

/// A piecewise-linear function evaluated at increasing `t` in one pass: `y` linear between the
/// breakpoints `x` (strictly increasing), `before` ahead of the first, the last `y` after the
/// last.
struct Cursor<'a> {
    x: &'a [f64],
    y: &'a [f64],
    before: f64,
    i: usize,
}

impl<'a> Cursor<'a> {
    fn new(x: &'a [f64], y: &'a [f64], before: f64) -> Self {
        Self { x, y, before, i: 0 }
    }

    /// The value at `t`, no smaller than the `t` of the previous call.
    fn at(&mut self, t: f64) -> f64 {
        while self.i < self.x.len() && self.x[self.i] <= t {
            self.i += 1;
        }
        match self.i {
            0 => self.before,
            i if i == self.x.len() => self.y[i - 1],
            i => {
                let (t0, t1) = (self.x[i - 1], self.x[i]);
                let (a, b) = (self.y[i - 1], self.y[i]);
                a + (b - a) * (t - t0) / (t1 - t0)
            }
        }
    }
}

/// A pixel's reference `tau(t)`: breakpoints `t` (strictly increasing) and `tau`, linear
/// between them, 0 before the first, constant after the last.
#[derive(Debug)]
struct Reference {
    t: Vec<f64>,
    tau: Vec<f64>,
}

impl Reference {
    /// The largest `|T_K(z) - exp(-tau(z))|` over `z` in `[0, t_max]` for `K` slices between
    /// `t_near` and `t_max` (module docs, step 3). `K = 0`: `T_K = 1` everywhere.
    fn slice_error(&self, k: usize, t_near: f64, t_max: f64) -> f64 {
        // Description nodes: (t_near, 1), then (t_n, T(t_n)), n = 1..=K.
        let node_t: Vec<f64> = (0..=k)
            .map(|n| t_near + (t_max - t_near) * n as f64 / k.max(1) as f64)
            .collect();
        let mut tau = Cursor::new(&self.t, &self.tau, 0.0);
        let node_v: Vec<f64> = node_t
            .iter()
            .enumerate()
            .map(|(n, &t)| if n == 0 { 1.0 } else { (-tau.at(t)).exp() })
            .collect();
        let (mut tau, mut desc) = (
            Cursor::new(&self.t, &self.tau, 0.0),
            Cursor::new(&node_t, &node_v, 1.0),
        );
        // Walk every breakpoint of either function in [0, t_max] in order: between consecutive
        // ones tau and T_K are both linear. On (t0, t1), T_ref = exp(-(tau0 + m s)) and T_K =
        // d0 + slope s (s = t - t0): T_ref - T_K is convex, so |T_ref - T_K| peaks at an end or
        // at the minimum, where -m T_ref = slope.
        let (mut a, mut b) = (0, 0);
        let mut t0 = 0.0;
        let (mut tau0, mut d0) = (tau.at(0.0), desc.at(0.0));
        let mut worst = ((-tau0).exp() - d0).abs();
        loop {
            let next = match (self.t.get(a), node_t.get(b)) {
                (Some(&x), Some(&y)) if x <= y => {
                    a += 1;
                    x
                }
                (_, Some(&y)) => {
                    b += 1;
                    y
                }
                (Some(&x), None) => {
                    a += 1;
                    x
                }
                (None, None) => t_max,
            };
            let t = next.min(t_max);
            if t > t0 {
                let (tau1, d1) = (tau.at(t), desc.at(t));
                worst = worst.max(((-tau1).exp() - d1).abs());
                let h = t - t0;
                let (m, slope) = ((tau1 - tau0) / h, (d1 - d0) / h);
                if m > 0.0 && slope < 0.0 {
                    let s = ((-tau0).exp() * m / -slope).ln() / m;
                    if s > 0.0 && s < h {
                        worst = worst.max(((-(tau0 + m * s)).exp() - (d0 + slope * s)).abs());
                    }
                }
                (t0, tau0, d0) = (t, tau1, d1);
            }
            if t >= t_max {
                return worst;
            }
        }
    }
}

/// The smallest `k >= lo` with `pass(k)` such that `pass(k - 1)` fails (or `k == lo`):
/// doubling from `lo`, then bisection. `None` past [`MAX_K`].
fn smallest_k(lo: usize, pass: impl Fn(usize) -> bool) -> Option<usize> {
    if pass(lo) {
        return Some(lo);
    }
    let (mut bad, mut good) = (lo, (2 * lo).max(1));
    while !pass(good) {
        bad = good;
        good *= 2;
        if good > MAX_K {
            return None;
        }
    }
    while good - bad > 1 {
        let mid = bad + (good - bad) / 2;
        if pass(mid) {
            good = mid;
        } else {
            bad = mid;
        }
    }
    Some(good)
}

/// One row of the table.
#[derive(Debug)]
struct Row {
    scale: f64,
    error: f64,
    mean_samples: f64,
    max_samples: u32,
    map_k: Option<usize>,
    mean_k: f64,
    max_pixel_k: usize,
    deep_bytes: u64,
    flat_bytes: Option<u64>,
    size: (u32, u32),
}

fn job(args: &Args, scale: f64, output: PathBuf, camera: Option<Camera>) -> BakeJob {
    BakeJob {
        source: umbra::input::Source::new(
            args.file.clone(),
            umbra::input::SourceOptions {
                grid: args.grid.clone(),
                density_scale: scale,
                ..umbra::input::SourceOptions::default()
            },
        ),
        view: View {
            projection: Projection::Ortho,
            light_dir: Some(args.light_dir),
            res: Some(Resolution::LongSide(args.res)),
            ..View::default()
        },
        camera,
        settings: BakeSettings::new(
            Estimator::REGULAR,
            Options {
                interp: Interp::Trilinear,
                ..Options::default()
            },
        ),
        output,
        preview: None,
        overwrite: true,
        layout: ExrLayout::default(),
        max_memory: None,
        product: Product::Map,
        key: None,
    }
}

fn file_size(p: &Path) -> Result<u64, String> {
    std::fs::metadata(p)
        .map(|m| m.len())
        .map_err(|e| format!("{}: {e}", p.display()))
}

fn measure(args: &Args, dir: &Path, vol: &Volume, scale: f64, e: f64) -> Result<Row, String> {
    let err = |x: umbra::Error| x.to_string();
    let deep_path = dir.join(format!("deep_s{scale}_e{e}.exr"));
    let mut deep = job(args, scale, deep_path.clone(), None);
    deep.product = Product::Deep { max_error: e };
    let report = deep.run(&|_| {}).map_err(err)?;
    let stats = report
        .deep
        .ok_or("the deep bake reported no deep statistics")?;
    let cam = report.map.camera;
    let (w, h) = (cam.width(), cam.height());
    let (t_near, t_max) = (cam.t_near(), cam.t_max());

    // Reference profiles, in pixel order.
    let refs: Vec<Reference> = (0..w * h)
        .into_par_iter()
        .map(|p| {
            let ray = cam.pixel_ray(p % w, p / w).map_err(err)?;
            let prof = optical_depth_profile(vol, &ray, Interp::Trilinear, e * REFERENCE_SHARE)
                .map_err(err)?;
            if let Some(o) = prof.opaque_at() {
                return Err(format!(
                    "pixel {p} meets an opaque voxel at t = {o}: no slice map describes the step"
                ));
            }
            Ok(Reference {
                t: prof.t().to_vec(),
                tau: prof.tau().to_vec(),
            })
        })
        .collect::<Result<_, String>>()?;
    let pixel_k: Vec<Option<usize>> = refs
        .par_iter()
        .map(|r| smallest_k(0, |k| r.slice_error(k, t_near, t_max) <= e))
        .collect();
    let mut sum = 0usize;
    let mut max_pixel_k = 0usize;
    for (p, k) in pixel_k.iter().enumerate() {
        let k = k.ok_or_else(|| format!("pixel {p}: more than {MAX_K} slices at E {e}"))?;
        sum += k;
        max_pixel_k = max_pixel_k.max(k);
    }
    let map_k = smallest_k(1, |k| {
        refs.par_iter()
            .all(|r| r.slice_error(k, t_near, t_max) <= e)
    });

    let flat_bytes = match map_k {
        Some(k) if k <= MAX_SLICES => {
            let path = dir.join(format!("flat_s{scale}_e{e}_k{k}.exr"));
            let mut flat = job(args, scale, path.clone(), Some(cam));
            flat.settings.depths = Depths::Slices(k);
            flat.run(&|_| {}).map_err(err)?;
            Some(file_size(&path)?)
        }
        _ => None,
    };
    Ok(Row {
        scale,
        error: e,
        mean_samples: stats.mean_samples(),
        max_samples: stats.max_samples,
        map_k,
        mean_k: sum as f64 / refs.len() as f64,
        max_pixel_k,
        deep_bytes: file_size(&deep_path)?,
        flat_bytes,
        size: (w, h),
    })
}

fn run(args: &Args) -> Result<(), String> {
    let dir = tempfile::tempdir().map_err(|e| format!("temporary directory: {e}"))?;
    let mut rows = Vec::new();
    for &scale in &args.scales {
        let vol = Volume::load(&args.file, &args.grid, scale).map_err(|e| e.to_string())?;
        for &e in &args.errors {
            let row = measure(args, dir.path(), &vol, scale, e)?;
            eprintln!(
                "scale {scale}, E {e}: deep {:.2} samples/px, map-wide K {}",
                row.mean_samples,
                row.map_k.map_or("?".into(), |k| k.to_string())
            );
            rows.push(row);
        }
    }
    let size = rows.first().map_or((0, 0), |r| r.size);
    let [x, y, z] = args.light_dir;
    println!(
        "{} (grid {}), light dir {x},{y},{z}, {}x{} pixels, regular tracking, trilinear.",
        args.file.display(),
        args.grid,
        size.0,
        size.1
    );
    println!(
        "Reference: optical_depth_profile per pixel within E/100 in T; slice errors computed \
         exactly against it at every depth in [0, t_max]."
    );
    println!(
        "K: smallest K that passes while K - 1 fails (doubling, then bisection); per-pixel K \
         averaged over all pixels, 0 where T stays above 1 - E. Flat EXR: T plus K slice \
         channels, baked by the library on the deep map's camera ({MAX_SLICES} slices at most)."
    );
    println!();
    println!(
        "| density scale | E | deep samples/px (mean) | deep samples/px (max) | \
         slices K (map-wide) | per-pixel K (mean) | per-pixel K (max) | deep EXR bytes | \
         flat EXR bytes with K slices |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in &rows {
        let k = r
            .map_k
            .map_or_else(|| format!("> {MAX_K}"), |k| k.to_string());
        let flat = match (r.flat_bytes, r.map_k) {
            (Some(b), _) => b.to_string(),
            _ => format!("> {MAX_SLICES} slices"),
        };
        println!(
            "| {} | {} | {:.2} | {} | {k} | {:.2} | {} | {} | {flat} |",
            r.scale, r.error, r.mean_samples, r.max_samples, r.mean_k, r.max_pixel_k, r.deep_bytes
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    let argv: Vec<String> = std::env::args().skip(1).collect();
    if argv.iter().any(|a| a == "-h" || a == "--help") {
        println!("{USAGE}");
        return ExitCode::SUCCESS;
    }
    let result = parse_args(&argv).and_then(|args| run(&args));
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(msg) => {
            eprintln!("deep_vs_slices: {msg}");
            ExitCode::FAILURE
        }
    }
}

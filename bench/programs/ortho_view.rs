//! Render one orthographic transmittance view exactly as `vdb_render -camera ortho` frames it
//! (the convention of `../shared/tools/oracle.py image`) with the bake library
//! (`umbra::bake::bake`, parallel 16x16 tiles) and write it with `umbra::bake::write_exr`
//! (channel `T`). The peer benchmark (`bench/peer.sh`) runs it against vdb_render on the same
//! view. `--compare A.exr:CH B.exr:CH` instead prints the RMSE, max and mean signed difference
//! of two images (`CH` a channel name, or `1-A` for vdb_render's `T = 1 - alpha`).
//!
//! ```sh
//! cargo run --release --ignore-rust-version --example ortho_view -- FILE --grid density --scale 5 \
//!     --dir=0.6,-0.35,-1 --center=-2.07,1.21,1.93 --up=0,1,0 --frame 4.4 --res 512x512 \
//!     [--estimator regular|riemann|NAME] [--step 1] [--spp 1] [--seed 0] \
//!     [--interp trilinear|nearest] [--threads 0] [--reps 1] [--index-offset 0] [--out t.exr] \
//!     [--order auto|rays] [--check 1] [--slices K] [--pinhole DIST]
//! cargo run --release --ignore-rust-version --example ortho_view -- --compare umbra.exr:T vdb_render.exr:1-A
//! ```
//!
//! Camera (OpenVDB `OrthographicCamera`): `d = normalise(dir)`, `u = normalise(up - (up.d) d)`,
//! `r = d x u`; pixel `(i, j)` (row 0 at the top) starts at
//! `center + r (2 (i + .5) / W - 1) frame / 2 + u (1 - 2 (j + .5) / H) (frame / 2) H / W`
//! and runs along `d` for `t` in `[0, inf)`. `--pinhole DIST` makes it a perspective view of
//! the same frame instead: every ray starts at `center - DIST d` and passes through that
//! pixel's point on the plane through `center`. Prints one JSON line: load and render seconds
//! (median of `--reps`), rays/s, cells and lookups per ray, peak resident memory.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::time::Instant;
use umbra::bake::{
    bake, write_exr, BakeSettings, Camera, CameraSpec, Order, Projection, Provenance,
};
use umbra::estimate::{Estimator, Options};
use umbra::{Interp, Volume};

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

/// One channel of an EXR as f64, row 0 at the top; `1-CH` gives `1 - CH`.
fn read_channel(spec: &str) -> (Vec<f64>, usize) {
    let (path, ch) = spec.rsplit_once(':').unwrap_or((spec, "T"));
    let (ch, flip) = match ch.strip_prefix("1-") {
        Some(c) => (c, true),
        None => (ch, false),
    };
    let img = exr::prelude::read_first_flat_layer_from_file(path).unwrap();
    let width = img.layer_data.size.0;
    let c = img
        .layer_data
        .channel_data
        .list
        .iter()
        .find(|c| c.name.to_string() == ch)
        .unwrap_or_else(|| panic!("{path} has no channel {ch}"));
    let v = c
        .sample_data
        .values_as_f32()
        .map(|x| {
            if flip {
                1.0 - f64::from(x)
            } else {
                f64::from(x)
            }
        })
        .collect();
    (v, width)
}

/// `--compare A B`: RMSE, max |A - B| and mean (A - B) over pixels finite in both.
fn compare(a: &str, b: &str) {
    let ((x, wa), (y, wb)) = (read_channel(a), read_channel(b));
    assert!(x.len() == y.len() && wa == wb, "{a} and {b} differ in size");
    let d: Vec<f64> = x
        .iter()
        .zip(&y)
        .filter(|(p, q)| p.is_finite() && q.is_finite())
        .map(|(p, q)| p - q)
        .collect();
    let n = d.len() as f64;
    println!(
        "{}",
        serde_json::json!({
            "pixels": d.len(),
            "rmse": (d.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
            "max_abs": d.iter().fold(0.0f64, |m, e| m.max(e.abs())),
            "mean_signed": d.iter().sum::<f64>() / n,
        })
    );
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
    if args.is_empty() || args.iter().any(|a| a == "--help" || a == "-h") {
        // The usage is the module comment's example.
        println!(
            "usage: ortho_view FILE --grid density --scale 5 --dir=DX,DY,DZ --center=X,Y,Z \
             --up=X,Y,Z --frame F --res WxH [--estimator NAME] [--step S] [--spp N] [--seed S] \
             [--interp trilinear|nearest] [--threads N[,M]] [--reps R] [--index-offset O] \
             [--out t.exr] [--order auto|rays] [--check 1] [--slices K] [--pinhole DIST]\n       \
             ortho_view --compare A.exr:CH B.exr:CH"
        );
        return;
    }
    if args.first().map(String::as_str) == Some("--compare") && args.len() == 3 {
        compare(&args[1], &args[2]);
        return;
    }
    let mut file = None;
    let mut opt = std::collections::HashMap::new();
    let mut i = 0;
    while i < args.len() {
        let a = &args[i];
        if let Some(k) = a.strip_prefix("--") {
            if let Some((k, v)) = k.split_once('=') {
                opt.insert(k.to_string(), v.to_string());
            } else {
                let Some(v) = args.get(i + 1) else {
                    eprintln!("ortho_view: --{k} needs a value (see --help)");
                    std::process::exit(2);
                };
                opt.insert(k.to_string(), v.clone());
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
    // `--threads 1,2`: the renders of each rep alternate between the thread counts (so slow
    // drift of the machine hits every count alike); the first count is the one reported.
    let thread_list: Vec<usize> = get("threads", "0")
        .split(',')
        .map(|t| t.parse().unwrap())
        .collect();
    let threads = thread_list[0];
    let reps: usize = get("reps", "1").parse().unwrap();
    let step: f64 = get("step", "1").parse().unwrap();
    let interp = match get("interp", "trilinear").as_str() {
        "nearest" => Interp::Nearest,
        _ => Interp::Trilinear,
    };
    let name = get("estimator", "regular");
    let est = Estimator::from_name(&name).expect("estimator name");
    let est = est.set("step", step).unwrap_or(est);
    let out = opt.get("out").cloned();

    let rss_start = peak_rss();
    let t = Instant::now();
    // A .vdb or a NanoVDB .nvdb (the Warp rows of peer.sh run on the .nvdb).
    let mut g = umbra::input::load_grid(&file, &grid).unwrap();
    // `--index-offset 0.5`: voxel (i, j, k) sits at index (i, j, k) + offset (Cycles' convention).
    let offset: f64 = get("index-offset", "0").parse().unwrap();
    if offset != 0.0 {
        let m = &mut g.transform.world_from_index;
        for row in m.iter_mut().take(3) {
            row[3] += offset * (row[0] + row[1] + row[2]);
        }
    }
    let file_mem_bytes = g.file_mem_bytes();
    let vol = Volume::new(g, scale, std::path::Path::new(&file)).unwrap();
    let load_s = t.elapsed().as_secs_f64();
    let rss_loaded = peak_rss();

    let u = norm({
        let k = up[0] * dir[0] + up[1] * dir[1] + up[2] * dir[2];
        [0, 1, 2].map(|a| up[a] - k * dir[a])
    });
    let r = norm(cross(dir, u));
    let s = frame / w as f64;
    let (x0, y0) = (
        -frame / 2.0 + s / 2.0,
        frame / 2.0 * h as f64 / w as f64 - s / 2.0,
    );
    let origin = [0, 1, 2].map(|a| center[a] + r[a] * x0 + u[a] * y0);
    // Trace every ray to the far side of the volume box (nothing behind the image plane).
    let corners = vol.box_corners().unwrap();
    let depth = |p: &glam::DVec3| (0..3).map(|a| (p[a] - center[a]) * dir[a]).sum::<f64>();
    let t_max = corners.iter().map(depth).fold(0.0, f64::max);
    let spec = match opt.get("pinhole") {
        None => CameraSpec {
            kind: Projection::Ortho,
            width: w as u32,
            height: h as u32,
            origin,
            step_x: r.map(|c| c * s),
            step_y: u.map(|c| -c * s),
            direction: dir,
            t_max,
        },
        Some(dist) => {
            // The plane at distance 1 from the pinhole is the frame scaled by 1 / dist.
            let dist: f64 = dist.parse().unwrap();
            let p = [0, 1, 2].map(|a| center[a] - dist * dir[a]);
            let far = corners
                .iter()
                .map(|c| (0..3).map(|a| (c[a] - p[a]).powi(2)).sum::<f64>().sqrt())
                .fold(0.0, f64::max);
            CameraSpec {
                kind: Projection::Perspective,
                width: w as u32,
                height: h as u32,
                origin: p,
                step_x: r.map(|c| c * s / dist),
                step_y: u.map(|c| -c * s / dist),
                direction: [0, 1, 2].map(|a| dir[a] + (origin[a] - center[a]) / dist),
                t_max: far,
            }
        }
    };
    let camera = Camera::from_spec(&spec).unwrap();
    let mut settings = BakeSettings::new(
        est,
        Options {
            interp,
            samples: get("spp", "1").parse().unwrap(),
            seed: get("seed", "0").parse().unwrap(),
            ..Options::default()
        },
    );
    settings.threads = threads;
    if let Some(k) = opt.get("slices") {
        settings.depths = umbra::bake::Depths::Slices(k.parse().unwrap());
    }
    settings.order = match get("order", "auto").as_str() {
        "rays" => Order::Rays,
        _ => Order::Auto,
    };
    let nthreads = if threads == 0 {
        rayon::current_num_threads()
    } else {
        threads
    };
    let mut times = vec![Vec::new(); thread_list.len()];
    let mut map = None;
    for _ in 0..reps {
        // The first count last, so that the image kept is its own.
        for (k, &n) in thread_list.iter().enumerate().rev() {
            settings.threads = n;
            map = None; // the previous render's image is not part of this one's footprint
            let t = Instant::now();
            let m = bake(&vol, &camera, &settings, &|_| {}).unwrap();
            times[k].push(t.elapsed().as_secs_f64());
            if k == 0 {
                map = Some(m);
            }
        }
    }
    settings.threads = threads;
    let map = map.expect("--reps must be at least 1");
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let medians: Vec<f64> = times.iter_mut().map(median).collect();
    let render_s = medians[0];
    let times = times.swap_remove(0);
    let rss_baked = peak_rss();
    if let Some(path) = &out {
        let prov = Provenance {
            xform: None,
            sigma_t: None,
            source_file: file.clone(),
            grid: grid.clone(),
            density_scale: scale,
            light_dir: Some(dir),
            light_pos: (spec.kind == Projection::Perspective).then_some(spec.origin),
            key: None,
        };
        write_exr(std::path::Path::new(path), &map, &prov, true).unwrap();
    }
    // `--check`: the same map traced ray by ray (`Order::Rays`); the largest difference of T
    // between the two (the sweep's f32 cell arithmetic against the f64 ray path).
    let check = opt.contains_key("check").then(|| {
        let by_rays = BakeSettings {
            order: Order::Rays,
            ..settings.clone()
        };
        let rays = bake(&vol, &camera, &by_rays, &|_| {}).unwrap();
        let max_abs = map
            .t
            .iter()
            .zip(&rays.t)
            .fold(0.0f64, |m, (a, b)| m.max(f64::from((a - b).abs())));
        serde_json::json!({"max_abs_t": max_abs,
            "lookups_per_ray_rays": rays.stats.lookups as f64 / (w * h) as f64})
    });
    let lookups = map.stats.lookups;
    let rays = (w * h) as f64;
    println!(
        "{}",
        serde_json::json!({
            "file": file, "estimator": est.name(), "step": step, "interp": format!("{interp:?}"),
            "threads": nthreads, "res": [w, h], "simd": umbra::regular::Simd::active().name(),
            "load_s": load_s, "render_s": render_s, "render_s_all": times,
            "thread_counts": thread_list, "render_s_by_threads": medians,
            "rays_per_s": rays / render_s, "lookups_per_ray": lookups as f64 / rays,
            "tree_bytes": vol.tree().memory_bytes(), "file_mem_bytes": file_mem_bytes,
            "peak_rss_start": rss_start, "peak_rss_after_load": rss_loaded,
            "peak_rss_after_bake": rss_baked, "peak_rss": peak_rss(),
            "order": get("order", "auto"), "check": check,
        })
    );
}

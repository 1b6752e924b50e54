//! `umbra bake`: transmittance / shadow maps from a light, written to OpenEXR.

use crate::common::{parse_vec3, progress_bar, EstimatorArgs, InterpArg};
use anyhow::{bail, Context, Result};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use umbra::bake::{BakeJob, BakeSettings, Depths, Map, Projection, Provenance, Resolution, View};
use umbra::Interp;

/// Arguments of `umbra bake`.
#[derive(Debug, clap::Args)]
pub struct BakeArgs {
    /// The .vdb file, or a .toml scene file (several volumes, colour, solids).
    file: PathBuf,
    /// Grid to trace (display name such as `density[1]`, or the stored name).
    #[arg(long, default_value = "density")]
    grid: String,
    /// Direction the light travels, DX,DY,DZ: an orthographic map framing the volume box.
    /// With --light-pos it aims the perspective map.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    light_dir: Option<[f64; 3]>,
    /// Light position X,Y,Z: a perspective map from the light (aimed at the volume box centre
    /// unless --light-dir is given).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    light_pos: Option<[f64; 3]>,
    /// With --light-pos: an orthographic map whose image plane passes through the light.
    #[arg(long)]
    ortho: bool,
    /// Perspective field of view across the longer image side, degrees (default: just holds
    /// the volume box).
    #[arg(long, allow_negative_numbers = true)]
    fov: Option<f64>,
    /// The world direction that is up in the map, X,Y,Z (default 0,1,0; when it is parallel to
    /// the light, the default's rule applies).
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    up: Option<[f64; 3]>,
    /// Frame this world box instead of the volume box: X0,Y0,Z0,X1,Y1,Z1 (the rays still cover
    /// the whole volume in depth).
    #[arg(long, allow_hyphen_values = true)]
    frame_box: Option<String>,
    /// Place the volume in the shot: a world-from-object 4x4 matrix, 16 comma-separated numbers,
    /// row-major, the translation in the last column.
    #[arg(long, value_parser = crate::common::parse_xform, allow_hyphen_values = true)]
    xform: Option<umbra::xform::Xform>,
    #[command(flatten)]
    trace: crate::common::TraceArgs,
    /// Reuse exactly the camera of an earlier umbra map (.exr) or of a JSON file holding the
    /// `camera` object `bake --json` prints; its resolution unless --res is given (then the
    /// same window at that size).
    #[arg(long, conflicts_with_all = ["light_dir", "light_pos", "ortho", "fov", "up", "frame_box"])]
    camera: Option<PathBuf>,
    /// Output: an OpenEXR map (.exr; written atomically, together with the preview), or a
    /// transmittance volume (.vdb: T toward the light at every active voxel of the density).
    #[arg(short, long)]
    output: PathBuf,
    /// With -o NAME.vdb: the name of the written grid.
    #[arg(long, default_value = umbra::bake::DEFAULT_OUT_GRID)]
    out_grid: String,
    /// With -o NAME.vdb: store 16-bit half floats.
    #[arg(long)]
    half: bool,
    /// Resolution: WxH, or N for N pixels on the long side with the framed box's aspect
    /// (default 1024).
    #[arg(long, allow_hyphen_values = true)]
    res: Option<String>,
    /// Write a tiled EXR with N x N tiles (renderers page large maps in by tile).
    #[arg(long, value_name = "N")]
    tile: Option<u32>,
    /// With --tile: also write box-filtered mip levels of every channel (round-down, down to
    /// 1x1; each level pixel the mean of T over its footprint).
    #[arg(long)]
    mipmap: bool,
    /// Write a deep OpenEXR map: per pixel the whole transmittance function along its ray as
    /// volumetric samples (channels A, Z, ZBack; AR, AG, AB, OpenEXR's per-channel
    /// opacities, with colour).
    #[arg(long)]
    deep: bool,
    /// With --deep: the bound E on |T_deep(z) - T(z)| at every depth z (default 0.002).
    #[arg(long, requires = "deep", allow_negative_numbers = true)]
    deep_error: Option<f64>,
    /// Overwrite existing outputs.
    #[arg(long)]
    force: bool,
    /// Also write an 8-bit grayscale PNG preview of T here (.png).
    #[arg(long)]
    preview: Option<PathBuf>,
    /// K extra channels `sliceNN.T`: T at K depths evenly spaced across the volume's depth range.
    #[arg(long)]
    slices: Option<usize>,
    /// Extra channels `sliceNN.T` at these depths (world distance along each ray): a,b,c.
    #[arg(long, allow_hyphen_values = true)]
    depths: Option<String>,
    /// Also write each pixel's standard error (`T.stderr`).
    #[arg(long)]
    stderr: bool,
    /// Adaptive sampling: double a pixel's samples until its standard error is below E.
    #[arg(long, allow_negative_numbers = true)]
    target_error: Option<f64>,
    /// Cap on samples per pixel for --target-error.
    #[arg(long, default_value_t = 65_536)]
    max_spp: u32,
    /// How the density between voxel centres is defined.
    #[arg(long, value_enum, default_value = "trilinear")]
    interp: InterpArg,
    /// mu_t = S x value, per world unit.
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    density_scale: f64,
    /// Worker threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Memory budget (bytes, or with K, M, G: `512M`, `1.5G`; powers of 1024). When the
    /// decoded grid and the image would not fit, an exact map is baked a part of the grid at
    /// a time (the same map, bit for bit); other maps are refused before any work.
    #[arg(long, value_parser = umbra::math::parse_bytes)]
    max_memory: Option<u64>,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    est: EstimatorArgs,
}

/// Parse `WxH` or `N` (N on the long side): the library's one parser, checked.
fn parse_res(s: &str) -> Result<Resolution> {
    let r: Resolution = s
        .parse()
        .map_err(|e: String| anyhow::anyhow!("invalid argument '--res': {e}"))?;
    r.check().map_err(crate::common::flag_error)?;
    Ok(r)
}

fn parse_depths(s: &str) -> Result<Vec<f64>> {
    s.split(',')
        .map(|c| {
            c.trim()
                .parse::<f64>()
                .with_context(|| format!("invalid argument '--depths': '{c}' is not a number"))
        })
        .collect()
}

/// Parse `X0,Y0,Z0,X1,Y1,Z1`.
fn parse_box(s: &str) -> Result<[[f64; 3]; 2]> {
    let v: Vec<f64> = s
        .split(',')
        .map(|c| c.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .ok()
        .filter(|v: &Vec<f64>| v.len() == 6)
        .with_context(|| {
            format!(
                "invalid argument '--frame-box': '{s}': expected X0,Y0,Z0,X1,Y1,Z1 (six numbers)"
            )
        })?;
    Ok([[v[0], v[1], v[2]], [v[3], v[4], v[5]]])
}

/// The camera request the arguments make.
fn view(a: &BakeArgs) -> Result<View> {
    let res = a.res.as_deref().map(parse_res).transpose()?;
    if a.camera.is_some() {
        return Ok(View {
            res,
            ..View::default()
        });
    }
    let projection = match (a.light_dir, a.light_pos) {
        (None, None) => bail!(
            "give --light-dir DX,DY,DZ (orthographic map) or --light-pos X,Y,Z (perspective map)"
        ),
        (_, Some(_)) if !a.ortho => Projection::Perspective,
        _ => Projection::Ortho,
    };
    if a.fov.is_some() && projection == Projection::Ortho {
        bail!("--fov applies to perspective maps (--light-pos without --ortho)");
    }
    Ok(View {
        projection,
        light_dir: a.light_dir,
        light_pos: a.light_pos,
        fov_deg: a.fov,
        res,
        up: a.up,
        frame_box: a.frame_box.as_deref().map(parse_box).transpose()?,
    })
}

/// Bake, write, report: the shared pipeline ([`BakeJob`]) with a progress bar.
pub fn run(a: &BakeArgs) -> Result<ExitCode> {
    let vdb = a
        .output
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("vdb"));
    if vdb {
        return run_volume(a);
    }
    if a.out_grid != umbra::bake::DEFAULT_OUT_GRID || a.half {
        bail!("--out-grid and --half apply to transmittance volumes (-o NAME.vdb)");
    }
    let total = std::time::Instant::now();
    let view = view(a)?;
    let depths = match (a.slices, &a.depths) {
        (Some(_), Some(_)) => bail!("give --slices K or --depths a,b,c, not both"),
        (Some(k), None) => Depths::Slices(k),
        (None, Some(d)) => Depths::At(parse_depths(d)?),
        (None, None) => Depths::None,
    };
    let interp: Interp = a.interp.into();
    let (estimator, options) = a.est.resolve(interp)?;
    let camera = match &a.camera {
        Some(path) => {
            Some(umbra::bake::read_camera(path, view.res).map_err(crate::common::flag_error)?)
        }
        None => None,
    };
    let job = BakeJob {
        input: a.file.clone(),
        grid: a.grid.clone(),
        density_scale: a.density_scale,
        xform: a.xform,
        sigma_t: a.trace.sigma_t,
        levelset_solid: a.trace.levelset.is_some(),
        view,
        camera,
        settings: BakeSettings {
            target_error: a.target_error,
            max_spp: a.max_spp,
            depths,
            std_err: a.stderr,
            threads: a.threads,
            ..BakeSettings::new(estimator, options)
        },
        output: a.output.clone(),
        preview: a.preview.clone(),
        overwrite: a.force,
        max_memory: a.max_memory,
        layout: umbra::bake::ExrLayout {
            tile: a.tile,
            mipmap: a.mipmap,
        },
        product: if a.deep {
            umbra::bake::Product::Deep {
                max_error: a.deep_error.unwrap_or(umbra::bake::DEFAULT_DEEP_ERROR),
            }
        } else {
            umbra::bake::Product::Map
        },
    };
    let scene_file = umbra::scene::is_scene_file(&job.input);
    let setup_error = |e: umbra::Error| match e {
        umbra::Error::Output { .. }
        | umbra::Error::Exists { .. }
        | umbra::Error::InvalidArgument { .. } => anyhow::Error::from(crate::common::flag_error(e)),
        other if scene_file => anyhow::Error::from(other).context("loading the scene"),
        other => anyhow::Error::from(other).context(format!("loading grid '{}'", job.grid)),
    };
    let bounded = job.plan_bounded().map_err(setup_error)?;
    let result = match bounded {
        // Over --max-memory: the grid a part at a time.
        Some(plan) => {
            let bar = progress_bar(
                a.quiet,
                "{spinner} baking in parts [{bar:30}] {percent:>3}% {human_pos}/{human_len} px, eta {eta}",
                plan.camera().pixels(),
            );
            let r = job.run_bounded(plan, &|n| bar.inc(n));
            bar.finish_and_clear();
            r
        }
        None => {
            let (scene, camera) = job.prepare().map_err(setup_error)?;
            let bar = progress_bar(
                a.quiet,
                "{spinner} baking [{bar:30}] {percent:>3}% {human_pos}/{human_len} px, eta {eta}",
                camera.pixels(),
            );
            let r = job.run_on(scene, camera, &|n| bar.inc(n));
            bar.finish_and_clear();
            r
        }
    };
    let done = result.map_err(|e| match e {
        umbra::Error::InvalidArgument { .. } => crate::common::flag_error(e),
        other => other,
    })?;
    report(
        a,
        &done.map,
        &done.provenance,
        done.deep.as_ref(),
        &done.warnings,
        total.elapsed().as_secs_f64(),
    )?;
    for w in &done.warnings {
        eprintln!("umbra: warning: {}: {w}", a.file.display());
    }
    Ok(ExitCode::SUCCESS)
}

fn report(
    a: &BakeArgs,
    map: &Map,
    prov: &Provenance,
    deep: Option<&umbra::bake::DeepStats>,
    warnings: &[umbra::bake::Warning],
    total: f64,
) -> Result<()> {
    let c = &map.camera;
    let st = &map.stats;
    let rays_per_second = st.rays as f64 / st.seconds.max(1e-9);
    let n = map.t.len().max(1) as f64;
    let t_mean = map.t.iter().map(|&t| f64::from(t)).sum::<f64>() / n;
    let t_min = map.t.iter().copied().fold(f32::INFINITY, f32::min);
    let t_max = map.t.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let summary = umbra::bake::MapSummary::new(map, prov);
    let channels = &summary.channels;
    let threads = if a.threads == 0 {
        rayon::current_num_threads()
    } else {
        a.threads
    };
    let s = &map.settings;
    let mut out = std::io::stdout().lock();
    if a.json {
        // The map's own description (what the Python module returns as its camera dict),
        // then what this run adds.
        let mut v = serde_json::to_value(&summary)?;
        let run = serde_json::json!({
            "output": a.output, "preview": a.preview, "threads": threads,
            "tile": a.tile, "mipmap": a.mipmap,
            "seconds": st.seconds, "total_seconds": total,
            "rays_per_second": rays_per_second, "lookups": st.lookups,
            "lookups_per_ray": st.lookups as f64 / st.rays.max(1) as f64,
            "order": if st.sweep { "sweep" } else { "rays" }, "parts": st.parts,
            "capped": st.capped, "majorant_violations": st.majorant_violations,
            "unconverged": st.unconverged, "max_std_err": st.max_std_err,
            "T_min": t_min, "T_max": t_max, "T_mean": t_mean,
            "deep": deep.map(|d| serde_json::json!({
                "max_error": d.max_error, "samples": d.samples,
                "mean_samples_per_pixel": d.mean_samples(), "max_samples_per_pixel": d.max_samples,
                "empty_pixels": d.empty_pixels, "profile_breakpoints": d.breakpoints,
                "coarse_cells": d.coarse_cells, "seconds": d.seconds,
            })),
            // Each warning as data (its `kind` and fields) with the line stderr prints.
            "warnings": warnings.iter().map(|w| {
                let mut v = serde_json::to_value(w).unwrap_or_default();
                if let Some(o) = v.as_object_mut() {
                    o.insert("message".into(), w.to_string().into());
                }
                v
            }).collect::<Vec<_>>(),
        });
        if let (Some(o), serde_json::Value::Object(r)) = (v.as_object_mut(), run) {
            o.extend(r);
        }
        writeln!(out, "{v}")?;
    } else {
        writeln!(
            out,
            "{}: {}x{} {} map of {}:{} ({}), T in [{t_min:.4}, {t_max:.4}], mean {t_mean:.4}",
            a.output.display(),
            c.width(),
            c.height(),
            match c.kind() {
                Projection::Ortho => "ortho",
                Projection::Perspective => "perspective",
            },
            prov.source_file,
            prov.grid,
            channels.join(", "),
        )?;
        writeln!(
            out,
            "{:.3} s on {threads} threads, {:.0} rays/s, {}, {:.1} spp, {:.0} lookups/ray",
            st.seconds,
            rays_per_second,
            s.estimator.name(),
            summary.mean_spp,
            st.lookups as f64 / st.rays.max(1) as f64
        )?;
        if st.unconverged > 0 {
            writeln!(
                out,
                "{} pixels stopped at --max-spp above the target error (largest std_err {:.2e})",
                st.unconverged, st.max_std_err
            )?;
        }
        if let Some(d) = deep {
            writeln!(
                out,
                "deep: {} samples, {:.2} per pixel (most {}), {} empty pixels, within {} in T \
                 ({:.1} profile breakpoints per pixel, {:.3} s)",
                d.samples,
                d.mean_samples(),
                d.max_samples,
                d.empty_pixels,
                d.max_error,
                d.breakpoints as f64 / d.pixels.max(1) as f64,
                d.seconds
            )?;
        }
        if let Some(p) = &a.preview {
            writeln!(out, "preview: {}", p.display())?;
        }
    }
    Ok(())
}

/// `bake ... -o NAME.vdb`: a transmittance volume beside the density.
fn run_volume(a: &BakeArgs) -> Result<ExitCode> {
    let total = std::time::Instant::now();
    let map_only: [(&str, bool); 16] = [
        ("--camera", a.camera.is_some()),
        ("--ortho", a.ortho),
        ("--fov", a.fov.is_some()),
        ("--up", a.up.is_some()),
        ("--frame-box", a.frame_box.is_some()),
        ("--res", a.res.is_some()),
        ("--tile", a.tile.is_some()),
        ("--mipmap", a.mipmap),
        ("--deep", a.deep),
        ("--preview", a.preview.is_some()),
        ("--slices", a.slices.is_some()),
        ("--depths", a.depths.is_some()),
        ("--stderr", a.stderr),
        ("--target-error", a.target_error.is_some()),
        ("--max-memory", a.max_memory.is_some()),
        ("--sigma-t", a.trace.sigma_t.is_some()),
    ];
    if let Some((flag, _)) = map_only.iter().find(|(_, set)| *set) {
        bail!("{flag} applies to maps (.exr); a transmittance volume (.vdb) is one float grid of T toward the light");
    }
    if a.trace.levelset.is_some() {
        bail!(
            "--levelset applies to maps (.exr); a transmittance volume is made from a fog volume"
        );
    }
    if umbra::scene::is_scene_file(&a.file) {
        bail!(
            "a transmittance volume (.vdb) is made from one density grid; {} is a scene file",
            a.file.display()
        );
    }
    let light = match (a.light_dir, a.light_pos) {
        (Some(dir), None) => umbra::Light::Directional { dir },
        (None, Some(pos)) => umbra::Light::Point { pos },
        (None, None) => {
            bail!("give --light-dir DX,DY,DZ or --light-pos X,Y,Z: the light the volume is lit by")
        }
        (Some(_), Some(_)) => {
            bail!("give --light-dir or --light-pos for a transmittance volume, not both")
        }
    };
    let interp: Interp = a.interp.into();
    let (estimator, options) = a.est.resolve(interp)?;
    umbra::bake::check_threads(a.threads).map_err(crate::common::flag_error)?;
    let job = umbra::bake::VolumeJob {
        input: a.file.clone(),
        grid: a.grid.clone(),
        density_scale: a.density_scale,
        xform: a.xform,
        light,
        estimator,
        options,
        threads: a.threads,
        output: a.output.clone(),
        out_grid: a.out_grid.clone(),
        half: a.half,
        overwrite: a.force,
    };
    job.check_outputs().map_err(crate::common::flag_error)?;
    options.validate().map_err(crate::common::flag_error)?;
    let vol = job
        .load()
        .with_context(|| format!("loading grid '{}'", job.grid))?;
    let bar = progress_bar(
        a.quiet,
        "{spinner} transmittance volume [{bar:30}] {percent:>3}% {human_pos}/{human_len} voxels, eta {eta}",
        umbra::bake::output_voxels(&vol),
    );
    let r = job.run_on(&vol, &|n| bar.inc(n));
    bar.finish_and_clear();
    let done = r.map_err(|e| match e {
        umbra::Error::InvalidArgument { .. } => crate::common::flag_error(e),
        other => other,
    })?;
    let st = &done.stats;
    let mut out = std::io::stdout().lock();
    if a.json {
        let v = serde_json::json!({
            "output": a.output, "grid": a.out_grid, "source_grid": job.grid, "half": a.half,
            "light": job.light, "estimator": estimator.name(), "interp": interp,
            "voxels": st.voxels, "leaves": st.leaves, "tile_leaves": st.tile_leaves,
            "sharing": st.sharing, "line_step": st.line_step, "rays": st.rays, "lookups": st.lookups,
            "T_min": st.t_min, "T_max": st.t_max, "T_mean": st.t_mean,
            "seconds": st.seconds, "ns_per_voxel": st.ns_per_voxel(),
            "total_seconds": total.elapsed().as_secs_f64(),
        });
        writeln!(out, "{v}")?;
    } else {
        writeln!(
            out,
            "{}: grid '{}' of {} voxels ({} leaves, {} from active tiles), T in [{:.4}, {:.4}], mean {:.4}",
            a.output.display(),
            a.out_grid,
            st.voxels,
            st.leaves,
            st.tile_leaves,
            st.t_min,
            st.t_max,
            st.t_mean
        )?;
        writeln!(
            out,
            "{:.3} s, {:.0} ns/voxel, {}, {} ({} rays for {} voxels)",
            st.seconds,
            st.ns_per_voxel(),
            estimator.name(),
            match (st.sharing, st.line_step) {
                (umbra::bake::Sharing::Lines, Some(w)) =>
                    format!("one exact ray per line of voxel centres, step {w:?} toward the light"),
                _ => "one ray per voxel".to_string(),
            },
            st.rays,
            st.voxels
        )?;
    }
    for w in &done.warnings {
        eprintln!("umbra: warning: {}: {w}", a.file.display());
    }
    Ok(ExitCode::SUCCESS)
}

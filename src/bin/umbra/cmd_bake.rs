//! `umbra bake`: transmittance / shadow maps from a light, written to OpenEXR.

use crate::common::{bake_template, CliProgress, ProgressArgs};
use anyhow::Result;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use umbra::bake::{BakeJob, Projection, VolumeJob};
use umbra::request::{BakeOptions, BakeOutcome, BakeRequest};

/// Arguments of `umbra bake`: the input, the output and the library's [`BakeOptions`] (every
/// option's flag, help and default come from that one type).
#[derive(Debug, clap::Args)]
#[command(mut_arg("estimator", |a| a.long_help(crate::common::estimator_help())))]
pub struct BakeArgs {
    /// The .vdb or NanoVDB .nvdb file, a .toml scene file (several volumes, colour, solids) or
    /// a USD stage (.usd, .usda, .usdc, .usdz: its volumes and lights at --frame).
    file: PathBuf,
    /// Output: an OpenEXR map (.exr; written atomically, together with the preview), or a
    /// transmittance volume (.vdb: T toward the light at every active voxel of the density).
    #[arg(short, long)]
    output: PathBuf,
    #[command(flatten)]
    options: BakeOptions,
    /// No progress bar and no summary on stdout (warnings and errors still go to stderr;
    /// `--json` still prints its summary).
    #[arg(long, short)]
    quiet: bool,
    /// Print a JSON summary on stdout.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    progress: ProgressArgs,
}

/// Bake through the library's one entry point ([`BakeRequest::run`]: plan, load, trace,
/// encode, commit every output together), drawing its progress, then report.
pub fn run(a: &BakeArgs) -> Result<ExitCode> {
    let total = std::time::Instant::now();
    let request = BakeRequest {
        input: a.file.clone(),
        output: a.output.clone(),
        options: a.options.clone(),
    };
    let progress = CliProgress::new(a.progress.progress, a.quiet, bake_template);
    let outcome = request.run(&progress);
    progress.finish();
    let outcome = outcome.map_err(|e| {
        let e = e.worded(crate::common::flag_error);
        match e.context {
            Some(c) => anyhow::Error::from(e.error).context(c),
            None => anyhow::Error::from(e.error),
        }
    })?;
    let seconds = total.elapsed().as_secs_f64();
    match outcome {
        BakeOutcome::Map { job, report, .. } => {
            report_map(a, &job, &report, seconds)?;
            for w in &report.warnings {
                eprintln!("umbra: warning: {}: {w}", a.file.display());
            }
        }
        BakeOutcome::Volume { job, report } => {
            report_volume(a, &job, &report, seconds)?;
            for w in &report.warnings {
                eprintln!("umbra: warning: {}: {w}", a.file.display());
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// What a map's report says besides the map's own description: its range of T, the
/// threads it ran on and its speed.
struct Facts {
    t_min: f32,
    t_max: f32,
    t_mean: f64,
    threads: usize,
    rays_per_second: f64,
}

impl Facts {
    fn of(job: &BakeJob, map: &umbra::bake::Map) -> Self {
        let st = &map.stats;
        let n = map.t.len().max(1) as f64;
        Self {
            t_min: map.t.iter().copied().fold(f32::INFINITY, f32::min),
            t_max: map.t.iter().copied().fold(f32::NEG_INFINITY, f32::max),
            t_mean: map.t.iter().map(|&t| f64::from(t)).sum::<f64>() / n,
            threads: if job.settings.threads == 0 {
                rayon::current_num_threads()
            } else {
                job.settings.threads
            },
            rays_per_second: st.rays as f64 / st.seconds.max(1e-9),
        }
    }
}

/// The report of a map: `--json`'s object, or (unless `--quiet`) a few lines of text.
fn report_map(
    a: &BakeArgs,
    job: &BakeJob,
    done: &umbra::bake::BakeReport,
    total: f64,
) -> Result<()> {
    let facts = Facts::of(job, &done.map);
    let mut out = std::io::stdout().lock();
    if a.json {
        writeln!(out, "{}", map_json(a, job, done, total, &facts)?)?;
    } else if !a.quiet {
        map_text(&mut out, a, job, done, &facts)?;
    }
    Ok(())
}

/// `--json`: the map's own description (what the Python module returns as its camera dict),
/// then what this run adds.
fn map_json(
    a: &BakeArgs,
    job: &BakeJob,
    done: &umbra::bake::BakeReport,
    total: f64,
    f: &Facts,
) -> Result<serde_json::Value> {
    let (map, warnings) = (&done.map, &done.warnings);
    let (deep, fixed) = (done.deep.as_ref(), done.fixed.as_ref());
    let st = &map.stats;
    let mut v = serde_json::to_value(umbra::bake::MapSummary::new(map, &done.provenance))?;
    let run = serde_json::json!({
        "output": a.output, "preview": job.preview, "threads": f.threads,
        "tile": job.layout.tile, "mipmap": job.layout.mipmap,
        "seconds": st.seconds, "total_seconds": total,
        "rays_per_second": f.rays_per_second, "lookups": st.lookups,
        "lookups_per_ray": st.lookups as f64 / st.rays.max(1) as f64,
        "order": if st.sweep { "sweep" } else { "rays" }, "parts": st.parts,
        "simd": umbra::regular::Simd::active().name(),
        "capped": st.capped, "majorant_violations": st.majorant_violations,
        "unconverged": st.unconverged, "max_std_err": st.max_std_err,
        "T_min": f.t_min, "T_max": f.t_max, "T_mean": f.t_mean,
        "deep": deep.map(|d| serde_json::json!({
            "max_error": d.max_error, "samples": d.samples,
            "mean_samples_per_pixel": d.mean_samples(), "max_samples_per_pixel": d.max_samples,
            "empty_pixels": d.empty_pixels, "profile_breakpoints": d.breakpoints,
            "coarse_cells": d.coarse_cells, "rms_error": d.rms_error, "seconds": d.seconds,
        })),
        "deep_format": fixed,
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
    Ok(v)
}

/// The text report: what was written, how fast, and the deep products' statistics.
fn map_text(
    out: &mut impl Write,
    a: &BakeArgs,
    job: &BakeJob,
    done: &umbra::bake::BakeReport,
    f: &Facts,
) -> Result<()> {
    let (map, prov) = (&done.map, &done.provenance);
    let (deep, fixed) = (done.deep.as_ref(), done.fixed.as_ref());
    let (c, st, s) = (&map.camera, &map.stats, &map.settings);
    let summary = umbra::bake::MapSummary::new(map, prov);
    let (t_min, t_max, t_mean) = (f.t_min, f.t_max, f.t_mean);
    writeln!(
        out,
        "{}: {}x{} {} map of {}:{} ({}), T in [{t_min:.4}, {t_max:.4}], mean {t_mean:.4}",
        a.output.display(),
        c.width(),
        c.height(),
        match c.kind() {
            Projection::Ortho => "ortho",
            Projection::Perspective => "perspective",
            Projection::Cube => "cube",
            Projection::LatLong => "latlong",
        },
        prov.source_file,
        prov.grid,
        summary.channels.join(", "),
    )?;
    // Solids are searched, not looked up: a map of solids alone counts no lookups.
    let lookups = if st.lookups > 0 {
        format!(
            ", {:.0} lookups/ray",
            st.lookups as f64 / st.rays.max(1) as f64
        )
    } else {
        String::new()
    };
    writeln!(
        out,
        "{:.3} s on {} threads, {:.0} rays/s, {}, {:.1} spp{lookups}",
        st.seconds,
        f.threads,
        f.rays_per_second,
        s.estimator.name(),
        summary.mean_spp,
    )?;
    if let (Some(soft), Some([sampled, receivers])) = (&s.soft, st.light_sampled) {
        let d = st.light_directions.unwrap_or_default();
        let count = match soft.light.target {
            Some(e) => format!(
                "directions per receiver to reach std_err {e:.2e} (at most {}): mean {:.1}, \
                 99th percentile {}, most {}, {} receivers capped",
                soft.light.samples, d.mean, d.p99, d.max, d.capped
            ),
            None => format!("{} directions per receiver", soft.light.samples),
        };
        writeln!(
            out,
            "light with extent ({}): {count} at the {}; {sampled} of {receivers} receivers \
             sampled ({:.1}%), {} answered by a bound, largest std_err {:.2e}",
            soft.light.extent,
            soft.receiver,
            100.0 * sampled as f64 / receivers.max(1) as f64,
            st.light_bounded.unwrap_or(0),
            st.max_std_err,
        )?;
    }
    if st.unconverged > 0 {
        writeln!(
            out,
            "{} pixels stopped at --max-spp above the target error (largest std_err {:.2e})",
            st.unconverged, st.max_std_err
        )?;
    }
    if let Some(f) = fixed {
        writeln!(
            out,
            "deep format {}: {} channels ({} bytes) per texel, error in T at most {:.2e} \
             (RMS {:.2e}) over depths {:.4}..{:.4}, {} texels refined ({:.3} s)",
            f.format,
            f.channels,
            f.bytes_per_texel,
            f.max_error,
            f.rms_error,
            f.near,
            f.far,
            f.refined_texels,
            f.seconds
        )?;
    }
    if let (Some(d), true) = (deep, s.soft.is_some()) {
        writeln!(
            out,
            "deep: {} samples, {:.2} per pixel (most {}), {} empty pixels: T_L at {} receivers \
             per pixel as it is, not fitted ({:.3} s)",
            d.samples,
            d.mean_samples(),
            d.max_samples,
            d.empty_pixels,
            umbra::bake::SOFT_DEEP_DEPTHS + 1,
            d.seconds
        )?;
    } else if let Some(d) = deep {
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
    if let Some(p) = &job.preview {
        writeln!(out, "preview: {}", p.display())?;
    }
    Ok(())
}

/// The report of a transmittance volume (`bake ... -o NAME.vdb`).
fn report_volume(
    a: &BakeArgs,
    job: &VolumeJob,
    done: &umbra::bake::VolumeReport,
    total: f64,
) -> Result<()> {
    let st = &done.stats;
    let mut out = std::io::stdout().lock();
    if a.json {
        let v = serde_json::json!({
            "output": a.output, "grid": job.out_grid, "source_grid": job.source.options().grid, "half": job.half,
            "light": job.light, "estimator": job.estimator.name(), "interp": job.options.interp,
            "voxels": st.voxels, "leaves": st.leaves, "tile_leaves": st.tile_leaves,
            "sharing": st.sharing, "line_step": st.line_step, "rays": st.rays, "lookups": st.lookups,
            "T_min": st.t_min, "T_max": st.t_max, "T_mean": st.t_mean,
            "seconds": st.seconds, "ns_per_voxel": st.ns_per_voxel(),
            "total_seconds": total,
        });
        // Toward a light with extent: its directions, the fraction sampled, the worst error.
        let mut v = v;
        if let (Some(n), Some(f), Some(e)) = (st.light_samples, st.sampled_fraction, st.std_err_max)
        {
            v["light_samples"] = n.into();
            v["sampled_fraction"] = f.into();
            v["std_err_max"] = e.into();
            if let Some(d) = st.light_directions {
                v["light_directions"] = serde_json::to_value(d).unwrap_or_default();
            }
        }
        writeln!(out, "{v}")?;
    } else if !a.quiet {
        writeln!(
            out,
            "{}: grid '{}' of {} voxels ({} leaves, {} from active tiles), T in [{:.4}, {:.4}], mean {:.4}",
            a.output.display(),
            job.out_grid,
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
            job.estimator.name(),
            match (st.sharing, st.line_step) {
                (umbra::bake::Sharing::Lines, Some(w)) =>
                    format!("one exact ray per line of voxel centres, step {w:?} toward the light"),
                (umbra::bake::Sharing::Layers, _) =>
                    "one sweep per layer of voxel centres toward the light".to_string(),
                _ if st.light_samples.is_some() =>
                    "a ray per direction over the light per voxel".to_string(),
                _ => "one ray per voxel".to_string(),
            },
            st.rays,
            st.voxels
        )?;
        if let (Some(n), Some(f), Some(e)) = (st.light_samples, st.sampled_fraction, st.std_err_max)
        {
            let d = st.light_directions.unwrap_or_default();
            writeln!(
                out,
                "light with extent: at most {n} directions per voxel (mean {:.1}, 99th \
                 percentile {}, {} capped), {:.1}% of voxels sampled, std_err max {e:.2e}",
                d.mean,
                d.p99,
                d.capped,
                100.0 * f
            )?;
        }
    }
    Ok(())
}

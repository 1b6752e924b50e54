//! `umbra bake`: transmittance / shadow maps from a light, written to OpenEXR.

use crate::common::progress_bar;
use anyhow::{Context, Result};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use umbra::bake::{BakeJob, Projection, VolumeJob};
use umbra::request::{BakeOptions, BakePlan, BakeRequest};

/// Arguments of `umbra bake`: the input, the output and the library's [`BakeOptions`] (every
/// option's flag, help and default come from that one type).
#[derive(Debug, clap::Args)]
#[command(mut_arg("estimator", |a| a.long_help(crate::common::estimator_help())))]
pub struct BakeArgs {
    /// The .vdb file, or a .toml scene file (several volumes, colour, solids).
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
}

/// Plan the request (the library checks every option), then bake, write and report.
fn request(a: &BakeArgs) -> BakeRequest {
    BakeRequest {
        input: a.file.clone(),
        output: a.output.clone(),
        options: a.options.clone(),
    }
}

pub fn run(a: &BakeArgs) -> Result<ExitCode> {
    let total = std::time::Instant::now();
    match request(a).plan().map_err(crate::common::flag_error)? {
        BakePlan::Map(job) => run_map(a, &job, total),
        BakePlan::Volume(job) => run_volume(a, &job, total),
    }
}

/// Bake and write a map: the shared pipeline ([`BakeJob`]) with a progress bar.
fn run_map(a: &BakeArgs, job: &BakeJob, total: std::time::Instant) -> Result<ExitCode> {
    let scene_file = umbra::input::InputKind::of(&job.input).is_scene_file();
    let setup_error = |e: umbra::Error| match e {
        umbra::Error::Output { .. }
        | umbra::Error::Exists { .. }
        | umbra::Error::InvalidArgument { .. } => anyhow::Error::from(crate::common::flag_error(e)),
        other if scene_file => anyhow::Error::from(other).context("loading the scene"),
        other => anyhow::Error::from(other).context(format!("loading grid '{}'", job.grid)),
    };
    request(a)
        .check_usd_out()
        .map_err(crate::common::flag_error)?;
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
            // A deep product's units are its passes' pixels weighted by cost, not pixels.
            let len = job.progress_len(camera.pixels());
            let template = if len == camera.pixels() {
                "{spinner} baking [{bar:30}] {percent:>3}% {human_pos}/{human_len} px, eta {eta}"
            } else {
                "{spinner} baking [{bar:30}] {percent:>3}%, eta {eta}"
            };
            let bar = progress_bar(a.quiet, template, len);
            let r = job.run_on(scene, camera, &|n| bar.inc(n));
            bar.finish_and_clear();
            r
        }
    };
    let done = result.map_err(|e| match e {
        umbra::Error::InvalidArgument { .. } => crate::common::flag_error(e),
        other => other,
    })?;
    report(a, job, &done, total.elapsed().as_secs_f64())?;
    for w in &done.warnings {
        eprintln!("umbra: warning: {}: {w}", a.file.display());
    }
    request(a)
        .write_usd_out(&done.map.camera)
        .map_err(crate::common::flag_error)?;
    Ok(ExitCode::SUCCESS)
}

fn report(a: &BakeArgs, job: &BakeJob, done: &umbra::bake::BakeReport, total: f64) -> Result<()> {
    let (map, prov, warnings) = (&done.map, &done.provenance, &done.warnings);
    let (deep, fixed) = (done.deep.as_ref(), done.fixed.as_ref());
    let c = &map.camera;
    let st = &map.stats;
    let rays_per_second = st.rays as f64 / st.seconds.max(1e-9);
    let n = map.t.len().max(1) as f64;
    let t_mean = map.t.iter().map(|&t| f64::from(t)).sum::<f64>() / n;
    let t_min = map.t.iter().copied().fold(f32::INFINITY, f32::min);
    let t_max = map.t.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let summary = umbra::bake::MapSummary::new(map, prov);
    let channels = &summary.channels;
    let threads = if job.settings.threads == 0 {
        rayon::current_num_threads()
    } else {
        job.settings.threads
    };
    let s = &map.settings;
    let mut out = std::io::stdout().lock();
    if a.json {
        // The map's own description (what the Python module returns as its camera dict),
        // then what this run adds.
        let mut v = serde_json::to_value(&summary)?;
        let run = serde_json::json!({
            "output": a.output, "preview": job.preview, "threads": threads,
            "tile": job.layout.tile, "mipmap": job.layout.mipmap,
            "seconds": st.seconds, "total_seconds": total,
            "rays_per_second": rays_per_second, "lookups": st.lookups,
            "lookups_per_ray": st.lookups as f64 / st.rays.max(1) as f64,
            "order": if st.sweep { "sweep" } else { "rays" }, "parts": st.parts,
            "simd": umbra::regular::Simd::active().name(),
            "capped": st.capped, "majorant_violations": st.majorant_violations,
            "unconverged": st.unconverged, "max_std_err": st.max_std_err,
            "T_min": t_min, "T_max": t_max, "T_mean": t_mean,
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
        writeln!(out, "{v}")?;
    } else if !a.quiet {
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
            channels.join(", "),
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
            "{:.3} s on {threads} threads, {:.0} rays/s, {}, {:.1} spp{lookups}",
            st.seconds,
            rays_per_second,
            s.estimator.name(),
            summary.mean_spp,
        )?;
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
        if let Some(p) = &job.preview {
            writeln!(out, "preview: {}", p.display())?;
        }
    }
    Ok(())
}

/// `bake ... -o NAME.vdb`: a transmittance volume beside the density.
fn run_volume(a: &BakeArgs, job: &VolumeJob, total: std::time::Instant) -> Result<ExitCode> {
    job.check_outputs().map_err(crate::common::flag_error)?;
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
            "output": a.output, "grid": job.out_grid, "source_grid": job.grid, "half": job.half,
            "light": job.light, "estimator": job.estimator.name(), "interp": job.options.interp,
            "voxels": st.voxels, "leaves": st.leaves, "tile_leaves": st.tile_leaves,
            "sharing": st.sharing, "line_step": st.line_step, "rays": st.rays, "lookups": st.lookups,
            "T_min": st.t_min, "T_max": st.t_max, "T_mean": st.t_mean,
            "seconds": st.seconds, "ns_per_voxel": st.ns_per_voxel(),
            "total_seconds": total.elapsed().as_secs_f64(),
        });
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

//! `umbra info`: describe every grid of a file.

use anyhow::{Context, Result};
use std::io::Write;
use std::process::ExitCode;

/// Print the report; exit code 2 if some grid could not be decoded.
pub fn run(file: &std::path::Path, json: bool, grid: Option<&str>) -> Result<ExitCode> {
    let archive = umbra::vdb::open(file)?;
    let mut info = umbra::info::FileInfo::from_archive(&archive);
    if let Some(name) = grid {
        let gd = archive.find_grid(name)?;
        info.grids.retain(|g| g.stored_name == gd.stored_name);
    }
    let failed = info.grids.iter().filter(|g| g.error.is_some()).count();
    let mut out = std::io::stdout().lock();
    if json {
        serde_json::to_writer_pretty(&mut out, &info).context("writing JSON")?;
        writeln!(out)?;
    } else {
        print_text(&mut out, &info)?;
    }
    for g in info.grids.iter().filter(|g| g.error.is_some()) {
        eprintln!(
            "umbra: warning: grid '{}' could not be read: {}",
            g.name,
            g.error.as_deref().unwrap_or_default()
        );
    }
    Ok(if failed > 0 {
        ExitCode::from(2)
    } else {
        ExitCode::SUCCESS
    })
}

fn print_text(out: &mut impl Write, info: &umbra::info::FileInfo) -> Result<()> {
    writeln!(
        out,
        "{}: VDB format {}, library {}, {} bytes, {} grid(s)",
        info.path,
        info.file_version,
        info.library_version,
        info.file_bytes,
        info.grids.len()
    )?;
    for g in &info.grids {
        writeln!(
            out,
            "\n{} ({}{})",
            g.name,
            g.value_type,
            if g.saved_as_half { ", half" } else { "" }
        )?;
        if let Some(e) = &g.error {
            writeln!(out, "  error: {e}")?;
            continue;
        }
        let v =
            |x: &Option<serde_json::Value>| x.as_ref().map_or("-".to_string(), ToString::to_string);
        writeln!(out, "  class: {}", g.class.as_deref().unwrap_or("-"))?;
        writeln!(
            out,
            "  compression: {}",
            g.compression.as_deref().unwrap_or("-")
        )?;
        writeln!(
            out,
            "  map: {}  voxel size: {:?}",
            g.map.as_deref().unwrap_or("-"),
            g.voxel_size
        )?;
        writeln!(out, "  background: {}", v(&g.background))?;
        writeln!(out, "  index bbox: {:?}", g.index_bbox)?;
        writeln!(out, "  world bbox: {:?}", g.world_bbox)?;
        writeln!(
            out,
            "  active voxels: {}  leaves: {}  active tiles: {}",
            g.active_voxels.unwrap_or(0),
            g.leaf_count.unwrap_or(0),
            v(&g.tiles)
        )?;
        writeln!(
            out,
            "  {} range: [{}, {}]  sum: {}  NaN: {}  Inf: {}",
            g.value_stats_of,
            v(&g.value_min),
            v(&g.value_max),
            g.value_sum.unwrap_or(0.0),
            g.nan_count.unwrap_or(0),
            g.inf_count.unwrap_or(0)
        )?;
        if let Some(p) = &g.precision_loss {
            writeln!(
                out,
                "  double -> float: {} values, max relative rounding {:.2e}, {} overflowed, {} underflowed",
                p.values, p.max_relative_error, p.overflowed, p.underflowed
            )?;
        }
        writeln!(
            out,
            "  memory: {} bytes (OpenVDB file_mem_bytes: {})",
            g.memory_bytes.unwrap_or(0),
            g.file_mem_bytes.map_or("-".to_string(), |b| b.to_string())
        )?;
    }
    Ok(())
}

//! `umbra info`: describe the grids of one or more files, one line per grid in the manner of
//! `vdb_print` (`-v`: everything umbra knows), or JSON.

use crate::common::num;
use anyhow::{Context, Result};
use serde_json::Value;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use umbra::info::{FileInfo, GridInfo};
use umbra::internals::text::escape;

/// Arguments of `umbra info`.
#[derive(Debug, clap::Args)]
pub struct InfoArgs {
    /// The .vdb and .nvdb files, or one USD stage (.usd, .usda, .usdc, .usdz): its volumes and lights
    /// at --frame.
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// Everything about each grid: transform, bounding boxes, tiles, statistics, memory.
    #[arg(short, long)]
    verbose: bool,
    /// JSON: one object per file (an array of them for several files).
    #[arg(long)]
    json: bool,
    /// Only this grid (display name such as `density[1]`; unnamed grids, as Warp writes them,
    /// are `[0]`, `[1]`, ... in file order; or the stored name).
    #[arg(long, value_parser = clap::builder::NonEmptyStringValueParser::new())]
    grid: Option<String>,
    /// A USD stage: the time code and the volumes to report.
    #[command(flatten)]
    stage: crate::info_stage::StageArgs,
}

/// Print the reports. Exit code 3 when some grid or file could not be read but others could;
/// a single file that cannot be opened is an error (1).
pub fn run(a: &InfoArgs) -> Result<ExitCode> {
    if let Some(stage) = a.files.iter().find(|f| {
        umbra::input::Source::new(*f, a.stage.options())
            .kind()
            .is_stage()
    }) {
        if a.files.len() > 1 || a.grid.is_some() || a.verbose {
            anyhow::bail!(
                "{}: info reports on one USD stage alone, without --grid or --verbose (its \
                 volumes are chosen with --volume and --field)",
                stage.display()
            );
        }
        crate::info_stage::print(stage, &a.stage, a.json)?;
        return Ok(ExitCode::SUCCESS);
    }
    if let [one] = a.files.as_slice() {
        if umbra::info::map::is_exr(one) {
            return map_report(one, a.json);
        }
    }
    if let Some(f) = a.files.first() {
        let source = umbra::input::Source::new(f, a.stage.options());
        source.check().map_err(crate::common::flag_error)?;
    }
    let mut reports = Vec::new();
    let mut file_errors = Vec::new();
    for file in &a.files {
        let one = || FileInfo::read(file, a.grid.as_deref());
        match one() {
            Ok(info) => reports.push(info),
            Err(e) if a.files.len() == 1 => return Err(e.into()),
            Err(e) => file_errors.push(e.to_string()),
        }
    }
    // A transmittance volume umbra baked says what it was baked from, and whether it is stale.
    let baked = match a.files.as_slice() {
        [one] => umbra::info::map::MapInfo::read(one)
            .ok()
            .filter(|m| m.baked_by_umbra),
        _ => None,
    };
    let mut out = std::io::stdout().lock();
    if a.json {
        if a.files.len() == 1 {
            let mut v = serde_json::to_value(&reports[0])?;
            if let (Some(m), Some(o)) = (&baked, v.as_object_mut()) {
                o.insert("umbra".into(), serde_json::to_value(m)?);
            }
            serde_json::to_writer_pretty(&mut out, &v).context("writing JSON")?;
        } else {
            serde_json::to_writer_pretty(&mut out, &reports).context("writing JSON")?;
        }
        writeln!(out)?;
    } else {
        for info in &reports {
            if a.verbose {
                print_long(&mut out, info)?;
            } else {
                print_short(&mut out, info)?;
            }
        }
        if let Some(m) = &baked {
            print_baked(&mut out, m)?;
        }
    }
    out.flush()?;
    let failed: Vec<String> = reports
        .iter()
        .flat_map(|f| {
            f.grids.iter().filter_map(move |g| {
                g.error
                    .as_ref()
                    .map(|e| format!("{}: grid '{}': {e}", f.path, g.name))
            })
        })
        .chain(file_errors)
        .collect();
    let total: usize =
        reports.iter().map(|f| f.grids.len()).sum::<usize>() + a.files.len() - reports.len();
    if let Some(first) = failed.first() {
        eprintln!(
            "umbra: error: {} of {total} grids or files could not be read (first: {})",
            failed.len(),
            escape(first)
        );
        // Partial failure (3) when something was described; nothing readable is an error (1).
        return Ok(ExitCode::from(if failed.len() < total { 3 } else { 1 }));
    }
    Ok(ExitCode::SUCCESS)
}

/// A JSON value (number, `"inf"`, vector) as text.
fn val(v: &Option<Value>) -> String {
    match v {
        None => "-".into(),
        Some(Value::Number(n)) => n.as_f64().map_or_else(|| n.to_string(), num),
        Some(Value::String(s)) => s.clone(),
        Some(Value::Array(a)) => {
            let parts: Vec<String> = a.iter().map(|x| val(&Some(x.clone()))).collect();
            format!("({})", parts.join(", "))
        }
        Some(other) => other.to_string(),
    }
}

fn vec3(v: [f64; 3]) -> String {
    if v[0] == v[1] && v[1] == v[2] {
        num(v[0])
    } else {
        format!("({}, {}, {})", num(v[0]), num(v[1]), num(v[2]))
    }
}

fn bbox(b: Option<[[i32; 3]; 2]>) -> String {
    b.map_or("empty".into(), |[lo, hi]| {
        format!(
            "({},{},{})->({},{},{})",
            lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]
        )
    })
}

/// Active voxel count with an SI suffix, as `vdb_print` shows it.
fn count(n: u64) -> String {
    let f = n as f64;
    match n {
        0..=999 => n.to_string(),
        1_000..=999_999 => format!("{:.1}K", f / 1e3),
        1_000_000..=999_999_999 => format!("{:.1}M", f / 1e6),
        _ => format!("{:.2}G", f / 1e9),
    }
}

/// The sum of a grid's finite active values, saying so when some are not finite (an all-+Inf
/// grid sums to 0 over its finite values; its sum is not 0).
fn sum_text(g: &GridInfo) -> String {
    let sum = num(g.value_sum.unwrap_or(0.0));
    match g.inf_count.unwrap_or(0) + g.nan_count.unwrap_or(0) {
        0 => sum,
        n => format!("{sum} over finite values ({n} not finite)"),
    }
}

/// Whether a grid's values are stored as halves: OpenVDB marks every grid of a file written
/// with half floats (`_HalfFloat` on the tree type), but only real-valued grids (float,
/// double and their vectors) are converted; int32, bool and point grids are stored as they
/// are.
fn stored_half(g: &GridInfo) -> bool {
    let real = matches!(g.value_type.as_str(), "float" | "double")
        || (g.value_type.starts_with("vec")
            && matches!(g.value_type.chars().last(), Some('s' | 'd')));
    g.saved_as_half && real
}

/// One line per grid: name, type, class, voxel size, active voxels, index bbox, value range.
/// The name and type columns are as wide as the file's longest (at least 16 and 12), so long
/// names do not push the other columns out of line.
fn print_short(out: &mut impl Write, info: &FileInfo) -> Result<()> {
    writeln!(out, "{}:{}", escape(&info.path), shown(info, ""))?;
    let ty = |g: &GridInfo| {
        format!(
            "{}{}",
            g.value_type,
            if stored_half(g) { " (half)" } else { "" }
        )
    };
    let width = |f: &dyn Fn(&GridInfo) -> usize, least: usize| {
        info.grids.iter().map(f).max().unwrap_or(0).max(least)
    };
    let nw = width(&|g| escape(&g.name).chars().count(), 16);
    let tw = width(&|g| ty(g).chars().count(), 12);
    for g in &info.grids {
        let (name, ty) = (escape(&g.name), ty(g));
        if let Some(e) = &g.error {
            writeln!(out, "  {name:<nw$} {ty:<tw$} error: {}", escape(e))?;
            continue;
        }
        if let Some(n) = &g.note {
            writeln!(
                out,
                "  {name:<nw$} {ty:<tw$} {:<10} voxel {:<10} ({})",
                escape(g.class.as_deref().unwrap_or("-")),
                g.voxel_size.map_or("-".into(), vec3),
                escape(n)
            )?;
            continue;
        }
        writeln!(
            out,
            "  {name:<nw$} {ty:<tw$} {:<10} voxel {:<10} {:>8} active  {}  [{}, {}]",
            escape(g.class.as_deref().unwrap_or("-")),
            g.voxel_size.map_or("-".into(), vec3),
            count(g.active_voxels.unwrap_or(0)),
            bbox(g.index_bbox),
            val(&g.value_min),
            val(&g.value_max),
        )?;
    }
    Ok(())
}

fn print_long(out: &mut impl Write, info: &FileInfo) -> Result<()> {
    writeln!(
        out,
        "{}: {} format {}, library {}, {} bytes,{}",
        escape(&info.path),
        if info.format == umbra::input::InputKind::Nvdb.format() {
            "NanoVDB"
        } else {
            "VDB"
        },
        info.file_version,
        info.library_version,
        info.file_bytes,
        shown(info, " grid(s)")
    )?;
    for g in &info.grids {
        print_grid(out, g)?;
    }
    Ok(())
}

/// How many grids the file holds and how many are shown: ` no grids`, ` 17` + `all`, ` 1 of
/// 17 grids shown` (after `--grid`); empty for the short form of a file whose grids are all shown.
fn shown(info: &FileInfo, all: &str) -> String {
    let (n, total) = (info.grids.len(), info.grid_count);
    if total == 0 {
        " no grids (the file holds none)".into()
    } else if n < total {
        format!(" {n} of {total} grids shown (--grid)")
    } else if all.is_empty() {
        String::new()
    } else {
        format!(" {total}{all}")
    }
}

fn print_grid(out: &mut impl Write, g: &GridInfo) -> Result<()> {
    writeln!(
        out,
        "\n{} ({}{})",
        escape(&g.name),
        g.value_type,
        if stored_half(g) { ", half" } else { "" }
    )?;
    if let Some(e) = &g.error {
        writeln!(out, "  error: {}", escape(e))?;
        return Ok(());
    }
    writeln!(
        out,
        "  class: {}",
        escape(g.class.as_deref().unwrap_or("-"))
    )?;
    writeln!(
        out,
        "  compression: {}",
        g.compression.as_deref().unwrap_or("-")
    )?;
    if let Some(codec) = &g.codec {
        writeln!(
            out,
            "  NanoVDB {}  codec: {codec}  quantisation: {}  checksum: {}",
            g.nanovdb_version.as_deref().unwrap_or("-"),
            g.quantisation.as_deref().unwrap_or("-"),
            checksum_text(g.checksum.as_deref(), g.checksum_coverage.as_ref())
        )?;
    }
    if let Some(v) = &g.vector {
        writeln!(
            out,
            "  vector: {}  staggered: {}  vector_type: {}  is_local_space: {}",
            v.value_type,
            if v.staggered { "yes" } else { "no" },
            escape(v.vector_type.as_deref().unwrap_or("- (not in the file)")),
            v.is_local_space
                .map_or("- (not in the file)".into(), |b| b.to_string())
        )?;
    }
    writeln!(
        out,
        "  map: {}  voxel size: {}",
        g.map.as_deref().unwrap_or("-"),
        g.voxel_size.map_or("-".into(), vec3)
    )?;
    if let Some(m) = g.world_from_index {
        for row in &m[..3] {
            writeln!(
                out,
                "    [{:>12} {:>12} {:>12} {:>12}]",
                num(row[0]),
                num(row[1]),
                num(row[2]),
                num(row[3])
            )?;
        }
    }
    if let Some(n) = &g.note {
        writeln!(out, "  note: {}", escape(n))?;
        writeln!(
            out,
            "  OpenVDB file_mem_bytes: {}",
            g.file_mem_bytes.map_or("-".to_string(), |b| b.to_string())
        )?;
        return Ok(());
    }
    writeln!(out, "  background: {}", val(&g.background))?;
    writeln!(out, "  index bbox: {}", bbox(g.index_bbox))?;
    writeln!(
        out,
        "  world bbox: {}",
        g.world_bbox.map_or("empty".into(), |[lo, hi]| format!(
            "{} -> {}",
            vec3f(lo),
            vec3f(hi)
        ))
    )?;
    writeln!(
        out,
        "  active voxels: {}  leaves: {}  active tiles: {}",
        g.active_voxels.unwrap_or(0),
        g.leaf_count.unwrap_or(0),
        tiles(&g.tiles)
    )?;
    writeln!(
        out,
        "  {} range: [{}, {}]  sum: {}  NaN: {}  Inf: {}",
        g.value_stats_of,
        val(&g.value_min),
        val(&g.value_max),
        sum_text(g),
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
    Ok(())
}

/// A NanoVDB checksum kind with what it covered: every byte, or how many bytes and which were
/// not.
fn checksum_text(kind: Option<&str>, coverage: Option<&umbra::info::ChecksumCoverage>) -> String {
    let what = match (kind, coverage) {
        (Some("full"), Some(c)) if c.unchecked_bytes > 0 => {
            let mut not = Vec::new();
            if c.unchecked_code_bytes > 0 {
                not.push(format!(
                    "{} bytes of FpN leaf codes (NanoVDB 32.4's checksum stops at each leaf's \
                     first 96 bytes: a corrupt value is not detected)",
                    c.unchecked_code_bytes
                ));
            }
            let other = c.unchecked_bytes.saturating_sub(c.unchecked_code_bytes);
            if other > 0 {
                not.push(format!("{other} bytes of blind data or padding"));
            }
            format!(
                "head and nodes: {} of {} bytes checked; not checked: {}",
                c.checked_bytes,
                c.grid_bytes,
                not.join(", ")
            )
        }
        (Some("full"), _) => "head and nodes: every byte of the grid checked".into(),
        (Some("partial"), _) => "head only: the headers checked, not the nodes".into(),
        (Some("absent"), _) => "the file carries none".into(),
        (Some("mismatch"), _) => "the grid disagrees with it".into(),
        _ => return "-".into(),
    };
    format!("{} ({what})", kind.unwrap_or("-"))
}

fn vec3f(v: [f64; 3]) -> String {
    format!("({}, {}, {})", num(v[0]), num(v[1]), num(v[2]))
}

/// Tile counts per level as `key n` pairs.
fn tiles(t: &Option<Value>) -> String {
    match t {
        Some(Value::Object(m)) => m
            .iter()
            .map(|(k, v)| format!("{k} {}", val(&Some(v.clone()))))
            .collect::<Vec<_>>()
            .join(", "),
        other => val(other),
    }
}

/// `umbra info MAP.exr`: what the map is and what it was baked from (text or `--json`).
fn map_report(path: &std::path::Path, json: bool) -> Result<ExitCode> {
    let m = umbra::info::map::MapInfo::read(path)?;
    let mut out = std::io::stdout().lock();
    if json {
        serde_json::to_writer_pretty(&mut out, &m).context("writing JSON")?;
        writeln!(out)?;
        return Ok(ExitCode::SUCCESS);
    }
    let kind = if m.deep { "deep OpenEXR" } else { "OpenEXR" };
    writeln!(
        out,
        "{}: {kind} {} x {}, channels {}{}",
        m.path.display(),
        m.width.unwrap_or(0),
        m.height.unwrap_or(0),
        m.channels.join(", "),
        if m.baked_by_umbra {
            ""
        } else {
            " (not baked by umbra)"
        }
    )?;
    if m.baked_by_umbra {
        print_baked(&mut out, &m)?;
    }
    Ok(ExitCode::SUCCESS)
}

/// The lines of a map (or transmittance volume) umbra baked: its request from the header,
/// its key and whether it is stale against its inputs today.
fn print_baked(out: &mut dyn Write, m: &umbra::info::map::MapInfo) -> Result<()> {
    let a = &m.attributes;
    let text = |k: &str| {
        a.get(k)
            .map(|v| v.as_str().map_or_else(|| v.to_string(), str::to_string))
    };
    writeln!(out, "  baked by umbra from:")?;
    for (label, key) in [
        ("source file", "source_file"),
        ("grid", "grid"),
        ("density scale", "density_scale"),
        ("light dir", "light_dir"),
        ("light pos", "light_pos"),
        ("light", "light"),
        ("estimator", "estimator"),
        ("interp", "interp"),
        ("spp", "spp"),
        ("seed", "seed"),
        ("camera", "camera_kind"),
        ("fov (deg)", "fov_deg"),
        ("xform", "xform"),
        ("sigma_t", "sigma_t"),
    ] {
        if let Some(v) = text(key) {
            writeln!(out, "    {label:<14} {}", escape(&v))?;
        }
    }
    let Some(k) = &m.key else {
        writeln!(
            out,
            "  no batch key: baked outside a job (or by an older umbra); staleness unknown"
        )?;
        return Ok(());
    };
    writeln!(
        out,
        "  batch key ({}): {} request keys, {} input files",
        k.format,
        k.request.len(),
        k.files.len()
    )?;
    for i in &m.inputs {
        writeln!(
            out,
            "    {:<9} {}",
            i.state,
            escape(&i.path.display().to_string())
        )?;
    }
    writeln!(
        out,
        "  {}",
        if m.stale == Some(true) {
            "stale: an input changed since it was baked"
        } else {
            "up to date with its inputs"
        }
    )?;
    Ok(())
}

//! `umbra query`: what does the cloud attenuate along a segment?

use anyhow::{Context, Result};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

/// Lookup interpolation, as the CLI spells it.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum InterpArg {
    /// OpenVDB PointSampler.
    Nearest,
    /// OpenVDB BoxSampler.
    Trilinear,
}

impl From<InterpArg> for Interp {
    fn from(a: InterpArg) -> Self {
        match a {
            InterpArg::Nearest => Interp::Nearest,
            InterpArg::Trilinear => Interp::Trilinear,
        }
    }
}

/// Arguments of `umbra query`.
#[derive(Debug, clap::Args)]
pub struct QueryArgs {
    /// The .vdb file.
    file: PathBuf,
    /// Grid to trace (display name such as `density[1]`, or the stored name).
    #[arg(long, default_value = "density")]
    grid: String,
    /// Segment start, world space: X,Y,Z.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    from: [f64; 3],
    /// Segment end, world space: X,Y,Z.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    to: [f64; 3],
    /// How the density between voxel centres is defined.
    #[arg(long, value_enum, default_value = "trilinear")]
    interp: InterpArg,
    /// mu_t = S x value, per world unit.
    #[arg(long, default_value_t = 1.0)]
    density_scale: f64,
    /// One JSON object per query on stdout.
    #[arg(long)]
    json: bool,
}

/// Parse `X,Y,Z` into three finite numbers.
pub fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|c| c.trim().parse::<f64>().map_err(|e| format!("'{c}': {e}")))
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([*x, *y, *z]),
        _ => Err(format!("expected three finite numbers X,Y,Z, got '{s}'")),
    }
}

/// Run the query and print the answer.
pub fn run(a: &QueryArgs) -> Result<ExitCode> {
    let vol = Volume::load(&a.file, &a.grid, a.density_scale)
        .with_context(|| format!("loading grid '{}'", a.grid))?;
    let s = vol.sanitized;
    if s.nan + s.negative > 0 {
        eprintln!(
            "umbra: warning: {}: {} NaN and {} negative values in grid '{}' treated as 0",
            a.file.display(),
            s.nan,
            s.negative,
            vol.name
        );
    }
    let ray = Ray::between(a.from, a.to)?;
    let start = std::time::Instant::now();
    let interp: Interp = a.interp.into();
    let od = optical_depth(&vol, &ray, interp)?;
    let seconds = start.elapsed().as_secs_f64();
    let t = od.transmittance();
    let mut out = std::io::stdout().lock();
    if a.json {
        let v = serde_json::json!({
            "T": t, "std_err": 0.0, "tau": od.tau, "lookups": od.lookups,
            "estimator": "regular", "interp": interp, "length": ray.t_max,
            "segments": od.segments, "seconds": seconds,
        });
        writeln!(out, "{v}")?;
    } else {
        writeln!(
            out,
            "T = {t:.9} (tau = {:.9}, exact regular tracking, {interp:?}, length {:.6}, {} lookups)",
            od.tau, ray.t_max, od.lookups
        )?;
    }
    Ok(ExitCode::SUCCESS)
}

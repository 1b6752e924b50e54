//! `umbra query`: what does the cloud attenuate along a segment?

use anyhow::{Context, Result};
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use umbra::estimate::{estimate, Estimator, Options, ESTIMATOR_NAMES};
use umbra::traverse::Granularity;
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
    #[command(flatten)]
    est: EstimatorArgs,
}

/// Estimator selection shared by `query` (and later `bake`, `compare`).
#[derive(Debug, clap::Args)]
pub struct EstimatorArgs {
    /// Estimator: regular (exact), riemann, mc, jittered, track-length, collision, ratio,
    /// residual-ratio, residual-ratio-midpoint, next-flight, unbiased-raymarch, decomposition,
    /// jackknife.
    #[arg(long, default_value = "regular")]
    pub estimator: String,
    /// Independent samples per ray (stochastic estimators).
    #[arg(long, default_value_t = 64)]
    pub samples: u32,
    /// Seed of the random streams.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Ray-marching step in voxels (riemann, mc, jittered).
    #[arg(long, default_value_t = 1.0)]
    pub step: f64,
    /// Kernel width in world units (collision).
    #[arg(long, default_value_t = 0.01)]
    pub kernel: f64,
    /// Majorant granularity of the HDDA.
    #[arg(long, value_enum, default_value = "leaf")]
    pub granularity: GranularityArg,
    /// One majorant for the whole grid (the naive baseline).
    #[arg(long)]
    pub global_majorant: bool,
}

/// HDDA granularity, as the CLI spells it.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum GranularityArg {
    /// 8^3 leaves and tiles.
    Leaf,
    /// 128^3 lower nodes.
    Lower,
    /// 4096^3 upper nodes.
    Upper,
}

impl EstimatorArgs {
    /// The estimator and options these arguments select.
    pub fn resolve(&self, interp: Interp) -> Result<(Estimator, Options)> {
        if !(self.step.is_finite() && self.step > 0.0) {
            anyhow::bail!(
                "--step must be a positive number of voxels, got {}",
                self.step
            );
        }
        if !(self.kernel.is_finite() && self.kernel >= 0.0) {
            anyhow::bail!(
                "--kernel must be a non-negative world length, got {}",
                self.kernel
            );
        }
        let est =
            Estimator::from_name(&self.estimator, self.step, self.kernel).ok_or_else(|| {
                anyhow::anyhow!(
                    "unknown estimator '{}' (known: {}, residual-ratio-midpoint)",
                    self.estimator,
                    ESTIMATOR_NAMES.join(", ")
                )
            })?;
        if self.samples == 0 {
            anyhow::bail!("--samples must be at least 1");
        }
        let opts = Options {
            interp,
            samples: self.samples,
            seed: self.seed,
            granularity: match self.granularity {
                GranularityArg::Leaf => Granularity::Leaf,
                GranularityArg::Lower => Granularity::Lower,
                GranularityArg::Upper => Granularity::Upper,
            },
            global_majorant: self.global_majorant,
            ..Options::default()
        };
        Ok((est, opts))
    }
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
    let interp: Interp = a.interp.into();
    let (est, opts) = a.est.resolve(interp)?;
    let ray = Ray::between(a.from, a.to)?;
    let start = std::time::Instant::now();
    let e = estimate(&vol, &ray, 0, &est, &opts)?;
    let seconds = start.elapsed().as_secs_f64();
    let mut out = std::io::stdout().lock();
    if a.json {
        let v = serde_json::json!({
            "T": e.value, "std_err": e.std_err, "tau": e.tau, "lookups": e.lookups,
            "estimator": est.name(), "samples": e.samples, "interp": interp,
            "length": ray.t_max, "segments": e.segments, "capped": e.capped, "seconds": seconds,
        });
        writeln!(out, "{v}")?;
    } else {
        let tau = e.tau.map_or(String::new(), |t| format!(", tau = {t:.9}"));
        let err = if e.std_err > 0.0 {
            format!(" +- {:.2e}", e.std_err)
        } else {
            String::new()
        };
        writeln!(
            out,
            "T = {:.9}{err}{tau} ({}, {interp:?}, {} samples, length {:.6}, {} lookups)",
            e.value,
            est.name(),
            e.samples,
            ray.t_max,
            e.lookups
        )?;
    }
    if e.capped > 0 {
        eprintln!(
            "umbra: warning: {} samples hit the collision cap (biased)",
            e.capped
        );
    }
    Ok(ExitCode::SUCCESS)
}

//! The `umbra` command line, a thin layer over the library: `info` describes files, `query`
//! answers transmittance questions, `bake` writes transmittance (shadow) maps, `batch` runs job
//! files, `compare` measures error against time, `estimators` lists the estimator registry.

mod cmd_bake;
mod cmd_batch;
mod cmd_compare;
mod cmd_estimators;
mod cmd_info;
mod cmd_query;
mod common;
mod plot;

use anyhow::Result;
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser, Debug)]
#[command(
    name = "umbra",
    version,
    about = "How much light gets through this OpenVDB cloud?"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Describe every grid of a .vdb file: type, transform, bounding boxes, statistics.
    Info {
        /// The .vdb file.
        file: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Only this grid (display name such as `density[1]`, or the stored name).
        #[arg(long)]
        grid: Option<String>,
    },
    /// Optical depth and transmittance along world-space segments.
    Query(cmd_query::QueryArgs),
    /// Bake a transmittance (shadow) map seen from a light into an OpenEXR file.
    Bake(cmd_bake::BakeArgs),
    /// Run a batch job file: many inputs x many lights, resumable, shardable for farms.
    Batch(cmd_batch::BatchArgs),
    /// Error against run time of every estimator, and the stress suite on extreme media.
    Compare(cmd_compare::CompareArgs),
    /// List the estimators: name, kind, parameters with defaults and ranges, summary.
    Estimators {
        /// Print a JSON array instead of a table.
        #[arg(long)]
        json: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            // A closed pipe (`umbra info x | head`) is not an error.
            if e.chain().any(|c| {
                c.downcast_ref::<std::io::Error>()
                    .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
            }) {
                return ExitCode::SUCCESS;
            }
            eprintln!("umbra: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<ExitCode> {
    match cli.command {
        Command::Info { file, json, grid } => cmd_info::run(&file, json, grid.as_deref()),
        Command::Query(args) => cmd_query::run(&args),
        Command::Bake(args) => cmd_bake::run(&args),
        Command::Batch(args) => cmd_batch::run(&args),
        Command::Compare(args) => cmd_compare::run(&args),
        Command::Estimators { json } => cmd_estimators::run(json),
    }
}

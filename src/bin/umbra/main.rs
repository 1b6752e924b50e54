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
mod info_stage;
mod plot;
mod query_points;

use anyhow::Result;
use clap::{Parser, Subcommand};
use std::io::Write as _;
use std::process::ExitCode;

/// Exit codes, the same for every command (also in the README).
const EXIT_CODES: &str = "Exit codes (every command):
  0    success
  1    error: bad input, file or I/O; one line on stderr starting 'umbra: error:' naming the file or flag
  2    usage error: unknown flag, missing or malformed argument (clap's message)
  3    partial failure: some of many items failed (batch tasks, query lines, info grids or files,
       compare stress rows); the others were still answered
  130  interrupted by SIGINT: no temporary or partial output is left behind (the message
       names the outputs that were complete before the signal and stay)
  143  interrupted by SIGTERM: the same";

#[derive(Parser, Debug)]
#[command(
    name = "umbra",
    version,
    about = "How much light gets through this OpenVDB cloud?",
    after_help = EXIT_CODES
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Describe the grids of .vdb and .nvdb files (or a USD stage): one line per grid (-v: everything), or JSON.
    Info(cmd_info::InfoArgs),
    /// Optical depth and transmittance along world-space segments.
    Query(cmd_query::QueryArgs),
    /// Bake a transmittance (shadow) map seen from a light into an OpenEXR file.
    Bake(Box<cmd_bake::BakeArgs>),
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

/// Set by the signal thread when a signal arrives, before it removes anything.
static INTERRUPTED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// On SIGINT or SIGTERM: delete every temporary output (waiting for a commit in progress, so a
/// group of outputs is never half renamed), then exit 128 + the signal. The main thread, whose
/// writes fail once the temporaries are gone, leaves the exit to this thread ([`main`]).
fn handle_signals() {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]) else {
        return;
    };
    std::thread::spawn(move || {
        if let Some(sig) = signals.forever().next() {
            INTERRUPTED.store(true, std::sync::atomic::Ordering::SeqCst);
            let left = umbra::internals::output::remove_temporaries();
            // Never a panic here (a closed stderr): the main thread waits for this exit.
            let _ = writeln!(
                std::io::stderr(),
                "umbra: interrupted ({}); {}",
                if sig == SIGINT { "SIGINT" } else { "SIGTERM" },
                left.describe(4)
            );
            std::process::exit(128 + sig);
        }
    });
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    handle_signals();
    let result = run(cli);
    if INTERRUPTED.load(std::sync::atomic::Ordering::SeqCst) {
        // A signal arrived: its thread reports what is on disk and exits 128 + the signal; an
        // error of ours now (a write refused once the temporaries went) would race it with
        // exit code 1.
        loop {
            std::thread::park();
        }
    }
    match result {
        Ok(code) => code,
        Err(e) => {
            // A closed pipe (`umbra info x | head`) is not an error.
            // (serde_json keeps the io::Error's kind, not the io::Error, for `--json`.)
            let broken = Some(std::io::ErrorKind::BrokenPipe);
            if e.chain().any(|c| {
                c.downcast_ref::<std::io::Error>().map(std::io::Error::kind) == broken
                    || c.downcast_ref::<serde_json::Error>()
                        .and_then(serde_json::Error::io_error_kind)
                        == broken
            }) {
                return ExitCode::SUCCESS;
            }
            // One line, whatever names from files or arguments the message carries.
            eprintln!(
                "umbra: error: {}",
                umbra::internals::text::escape(&common::worded(&e))
            );
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<ExitCode> {
    match cli.command {
        Command::Info(args) => cmd_info::run(&args),
        Command::Query(args) => cmd_query::run(&args),
        Command::Bake(args) => cmd_bake::run(&args),
        Command::Batch(args) => cmd_batch::run(&args),
        Command::Compare(args) => cmd_compare::run(&args),
        Command::Estimators { json } => cmd_estimators::run(json),
    }
}

#[cfg(test)]
mod tests {
    /// clap's own checks of every command's arguments (one id per flag: a flattened set of
    /// options and a command's own flag cannot both declare a key), which release builds skip.
    #[test]
    fn every_command_passes_clap_checks() {
        use clap::CommandFactory;
        let mut cmd = super::Cli::command();
        cmd.build();
        for sub in cmd.get_subcommands() {
            let mut ids: Vec<&str> = sub.get_arguments().map(|a| a.get_id().as_str()).collect();
            let n = ids.len();
            ids.sort_unstable();
            ids.dedup();
            assert_eq!(
                ids.len(),
                n,
                "{}: an argument declared twice",
                sub.get_name()
            );
        }
        super::Cli::command().debug_assert();
    }
}

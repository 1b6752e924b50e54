//! `umbra estimators`: the estimator registry, as a table or JSON.

use anyhow::Result;
use std::io::Write;
use std::process::ExitCode;
use umbra::estimate::REGISTRY;

/// Print the registry.
pub fn run(json: bool) -> Result<ExitCode> {
    let mut out = std::io::stdout().lock();
    if json {
        writeln!(out, "{}", serde_json::to_string_pretty(REGISTRY)?)?;
        return Ok(ExitCode::SUCCESS);
    }
    for s in REGISTRY {
        let params: Vec<String> = s
            .params
            .iter()
            .map(|p| {
                format!(
                    "--{} {} (default {}, {} to {})",
                    p.name, p.unit, p.default, p.min, p.max
                )
            })
            .collect();
        writeln!(out, "{:<24} {:<9} {}", s.name, s.kind.as_str(), s.summary)?;
        if !params.is_empty() {
            writeln!(out, "{:<24} {:<9} {}", "", "", params.join("; "))?;
        }
    }
    Ok(ExitCode::SUCCESS)
}

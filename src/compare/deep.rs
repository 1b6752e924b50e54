//! `compare --deep`: which deep encoding to pick for an asset. Every encoding umbra writes is
//! baked on the same camera (exact regular tracking): Lokovic-Veach deep samples at three error
//! bounds (`--deep --deep-error E`) and the fixed-size formats at several sizes
//! (`--deep-format`), and each is set against the exact optical-depth profile of every texel:
//!
//! - **bytes per texel** of the encoding itself: `4 x channels` for a fixed format (the flat
//!   `T` beside it not counted), `4 x channels x samples + 4` (the sample count) on average for
//!   deep samples (f32 `A`, `Z`, `ZBack`; `AR`, `AG`, `AB` too with colour); before the
//!   file's compression;
//! - **max error**: the bound on `|T_enc(z) - T(z)|` over every texel and depth (for deep
//!   samples the asked bound, for fixed formats the one they report, see
//!   [`crate::bake::bake_fixed`]);
//! - **RMS error** at 65 uniform depths of every texel whose ray meets extinction;
//! - **seconds** of the bake (the flat map and the deep pass).

use crate::bake::{BakeJob, DeepFormat, Product};
use crate::error::Result;
use serde::Serialize;

/// The encodings compared, in table order: deep samples at `E = 0.02, 0.005, 0.002`, then
/// `fourier:3, 7, 15, 31`, `moments:4, 6`, `avsm:2, 4, 8, 16`.
#[must_use]
pub fn deep_products() -> Vec<Product> {
    let mut out: Vec<Product> = [0.02, 0.005, 0.002]
        .into_iter()
        .map(|max_error| Product::Deep { max_error })
        .collect();
    out.extend(
        [
            DeepFormat::Fourier(3),
            DeepFormat::Fourier(7),
            DeepFormat::Fourier(15),
            DeepFormat::Fourier(31),
            DeepFormat::Moments(4),
            DeepFormat::Moments(6),
            DeepFormat::Avsm(2),
            DeepFormat::Avsm(4),
            DeepFormat::Avsm(8),
            DeepFormat::Avsm(16),
        ]
        .into_iter()
        .map(|format| Product::Fixed { format }),
    );
    out
}

/// One encoding of the table.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DeepRow {
    /// `lokovic-veach`, `fourier`, `moments` or `avsm`.
    pub family: String,
    /// The budget as the flag spells it (`--deep-error 0.002`, `fourier:15`).
    pub encoding: String,
    /// Bytes per texel of the encoding (module docs): the mean for deep samples.
    pub bytes_per_texel: f64,
    /// The most bytes one texel takes (what a fixed-size buffer must hold): the same as
    /// `bytes_per_texel` for a fixed format, the texel with the most samples for deep samples.
    pub max_bytes_per_texel: f64,
    /// Bound on the error in T over every texel and depth.
    pub max_error: f64,
    /// RMS of the error in T at 65 depths of every lit texel.
    pub rms_error: f64,
    /// Seconds of the bake (flat map and deep pass).
    pub seconds: f64,
}

/// Bake `job` (its product one of [`deep_products`]; it writes its output) and describe it.
///
/// # Errors
/// As [`BakeJob::run`].
pub fn deep_row(job: &BakeJob) -> Result<DeepRow> {
    let report = job.run(&|_| {})?;
    let map_seconds = report.map.stats.seconds;
    if let Some(d) = report.deep {
        let channels = if report.map.channels() == 3 { 6.0 } else { 3.0 };
        let pixels = d.pixels.max(1) as f64;
        return Ok(DeepRow {
            family: "lokovic-veach".into(),
            encoding: format!("--deep-error {}", d.max_error),
            bytes_per_texel: (4.0 * channels * d.samples as f64 + 4.0 * pixels) / pixels,
            max_bytes_per_texel: 4.0 * channels * f64::from(d.max_samples) + 4.0,
            max_error: d.max_error,
            rms_error: d.rms_error,
            seconds: map_seconds + d.seconds,
        });
    }
    let f = report
        .fixed
        .ok_or_else(|| crate::error::Error::InvalidArgument {
            name: "deep".into(),
            reason: "compare --deep compares deep products only".into(),
        })?;
    Ok(DeepRow {
        family: f.format.split(':').next().unwrap_or_default().to_string(),
        encoding: f.format.clone(),
        bytes_per_texel: f.bytes_per_texel as f64,
        max_bytes_per_texel: f.bytes_per_texel as f64,
        max_error: f.max_error,
        rms_error: f.rms_error,
        seconds: map_seconds + f.seconds,
    })
}

/// The table as Markdown, with which encoding to pick: the smallest reaching an RMS error of
/// 0.01, and the smallest whose bound is 0.01.
#[must_use]
pub fn deep_markdown(rows: &[DeepRow], source: &str) -> String {
    let mut s = format!(
        "# Deep encodings of {source}\n\nEach encoding of the same exact map, against the exact \
         optical-depth profile of every texel (`umbra compare --deep`). Bytes per texel are the \
         encoding's own, before compression: the mean, and the most one texel takes (what a \
         fixed-size buffer must hold).\n\n| encoding | bytes per texel | most bytes in a texel | \
         max error in T | RMS error in T | bake (s) |\n|---|---|---|---|---|---|\n"
    );
    for r in rows {
        s += &format!(
            "| {} | {:.1} | {:.0} | {:.2e} | {:.2e} | {:.3} |\n",
            r.encoding,
            r.bytes_per_texel,
            r.max_bytes_per_texel,
            r.max_error,
            r.rms_error,
            r.seconds
        );
    }
    // The row with the fewest bytes (mean, or most in a texel with `most`) among those `ok`.
    let smallest = |ok: &dyn Fn(&DeepRow) -> bool, most: bool| {
        let bytes = |r: &DeepRow| {
            if most {
                r.max_bytes_per_texel
            } else {
                r.bytes_per_texel
            }
        };
        rows.iter()
            .filter(|r| ok(r))
            .min_by(|a, b| bytes(a).total_cmp(&bytes(b)))
            .map_or("none".to_string(), |r| {
                format!("`{}` ({:.1} bytes)", r.encoding, bytes(r))
            })
    };
    s += &format!(
        "\nSmallest on average with an RMS error of 0.01 or less: {}. Smallest on average whose \
         error is at most 0.01 at every depth: {}. Of a fixed size per texel (the most bytes \
         in a texel), the same: {} and {}.\n",
        smallest(&|r| r.rms_error <= 0.01, false),
        smallest(&|r| r.max_error <= 0.01, false),
        smallest(&|r| r.rms_error <= 0.01, true),
        smallest(&|r| r.max_error <= 0.01, true)
    );
    s
}

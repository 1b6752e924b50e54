//! Deep maps toward a light with extent (issue 60): per texel, `T_L` at [`SOFT_DEEP_DEPTHS`]
//! `+ 1` receivers evenly spaced along the texel's ray over the volume's depth range
//! (`t_near + (t_max - t_near) k / 16`, `k = 0..=16`), each answered as a soft map's slice is
//! (`trace/soft.rs`: exactly `query --at` at the receiver), stored **as it is**.
//!
//! **Samples.** Between receivers `k - 1` and `k` one volumetric sample (`Z`, `ZBack` their
//! depths) with `A = 1 - T_L(z_k) / T_L(z_{k-1})`, so compositing the samples front to back
//! gives `T_L` exactly (to f32) at every receiver and OpenEXR's log-linear law in between; a
//! first sample over `[0, z_0]` carries `1 - T_L(z_0)`. `T_L(z)` need not fall with depth (a
//! receiver further from a blocker near the light sees more of the light), and where it rises
//! a sample's `A` is negative: a reader that composites with the standard formula gets `T_L`,
//! one that clamps alpha to `[0, 1]` does not. A `T_L` of exactly 0 (every direction behind a
//! solid) ends the texel's samples there. Samples with `A = 0` are left out.
//!
//! There is no fitting and so no `deep-error`: between receivers the map interpolates, and
//! `umbra:deep_error` is absent; `umbra:deep_receivers` says the above in the header.

use crate::bake::encode::deep_exr::{DeepAttributes, DeepImage};
use crate::bake::{Camera, DeepMap, DeepStats, Map, Provenance};
use crate::error::{Error, Result};
use exr::meta::attribute::{AttributeValue, Text};

/// Intervals between a soft deep map's receivers along each ray.
pub const SOFT_DEEP_DEPTHS: usize = 16;

/// The receivers' depths on `camera`'s rays: `t_near` to `t_max` in [`SOFT_DEEP_DEPTHS`]
/// even steps (strictly increasing; one depth when the range is empty).
#[must_use]
pub fn soft_deep_depths(camera: &Camera) -> Vec<f64> {
    let (a, b) = (camera.t_near().max(0.0), camera.t_max());
    let mut d: Vec<f64> = (0..=SOFT_DEEP_DEPTHS)
        .map(|k| a + (b - a) * k as f64 / SOFT_DEEP_DEPTHS as f64)
        .collect();
    d.dedup_by(|x, y| *x <= *y);
    d
}

/// The deep map of a soft map `flat` whose slices are `T_L` at [`soft_deep_depths`] (module
/// docs).
///
/// # Errors
/// [`Error::InvalidArgument`] naming `deep` for a colour map (not made yet) or a map without
/// those slices.
pub fn soft_deep_image(flat: &Map) -> Result<DeepMap> {
    let start = std::time::Instant::now();
    if flat.channels() != 1 {
        return Err(Error::InvalidArgument {
            name: "deep".into(),
            reason: "a colour deep map toward a light with extent is not made yet (issue 60)"
                .into(),
        });
    }
    if flat.slices.is_empty() || flat.slices.len() != flat.depths.len() {
        return Err(Error::InvalidArgument {
            name: "deep".into(),
            reason: "a deep map toward a light with extent is made from its receivers' slices"
                .into(),
        });
    }
    let n = flat.camera.pixels() as usize;
    let mut counts = Vec::with_capacity(n);
    let mut data: Vec<Vec<f32>> = vec![Vec::new(); 3];
    for p in 0..n {
        let mut count = 0u32;
        let (mut z0, mut t0) = (0.0f64, 1.0f64);
        for (k, &z) in flat.depths.iter().enumerate() {
            let t = f64::from(flat.slices[k][p]);
            let a = if t0 > 0.0 { 1.0 - t / t0 } else { 0.0 };
            if a != 0.0 {
                data[0].push(a as f32);
                data[1].push(z0 as f32);
                data[2].push(z as f32);
                count += 1;
            }
            (z0, t0) = (z, t);
            if t0 <= 0.0 {
                break;
            }
        }
        counts.push(count);
    }
    let names = ["A", "Z", "ZBack"].map(String::from).to_vec();
    let (w, h) = (flat.camera.width(), flat.camera.height());
    let samples: u64 = counts.iter().map(|&c| u64::from(c)).sum();
    let stats = DeepStats {
        max_error: f64::NAN,
        pixels: n as u64,
        empty_pixels: counts.iter().filter(|&&c| c == 0).count() as u64,
        samples,
        max_samples: counts.iter().copied().max().unwrap_or(0),
        breakpoints: (n * flat.depths.len()) as u64,
        coarse_cells: 0,
        rms_error: f64::NAN,
        seconds: start.elapsed().as_secs_f64(),
    };
    let image = DeepImage::new(w, h, names, counts, data)?;
    Ok(DeepMap { image, stats })
}

/// The header of a soft deep map: a deep map's ([`crate::bake::deep_attributes`]) without
/// `umbra:deep_error`, with `umbra:deep_receivers`.
#[must_use]
pub fn soft_deep_attributes(flat: &Map, prov: &Provenance, stats: &DeepStats) -> DeepAttributes {
    let mut attrs = crate::bake::deep_attributes(flat, prov, stats);
    attrs.extra.retain(|(k, _)| k != "umbra:deep_error");
    attrs.extra.push((
        "umbra:deep_receivers".into(),
        AttributeValue::Text(Text::from(
            format!(
                "T_L at {} receivers from t_near to t_max in even steps along each texel's ray, \
                 stored as it is: it may rise with depth (a sample's A is then negative); \
                 log-linear between receivers",
                SOFT_DEEP_DEPTHS + 1
            )
            .as_str(),
        )),
    ));
    attrs
}

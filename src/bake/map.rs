//! What a map is and how it is asked for: the settings of a bake ([`BakeSettings`], its
//! [`Depths`] and [`Order`]), and the result ([`Map`]: transmittance per pixel, its standard
//! error, depth slices, colour channels, [`BakeStats`]). The data every stage of a bake shares:
//! the renderer and the sweep produce it, the encoders and summaries read it; it imports none
//! of them.

use super::camera::Camera;
use crate::error::{Error, Result};
use crate::estimate::{Estimator, Options};

/// Most adaptive batches per pixel (each doubles the sample count).
pub const MAX_BATCHES: u32 = 32;
/// Most depth slices of one map.
pub const MAX_SLICES: usize = 64;

/// Depths at which extra transmittance channels are baked.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Depths {
    /// Only the full-depth `T`.
    None,
    /// `K` depths evenly spaced across the volume's depth range:
    /// `t_k = t_near + (t_max - t_near) (k + 1) / K`, `k = 0..K`.
    Slices(usize),
    /// Explicit depths (world distance along each ray), strictly increasing, non-negative.
    At(Vec<f64>),
}

impl Depths {
    /// The depths these ask for on `camera` (slices across its volume depth range `t_near`
    /// to `t_max`, or the depths given), checked.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `slices` or `depths`.
    pub(crate) fn resolve(&self, camera: &Camera) -> Result<Vec<f64>> {
        match self {
            Depths::None => Ok(Vec::new()),
            Depths::Slices(k) => {
                if *k == 0 || *k > MAX_SLICES {
                    return Err(bad("slices", format!("{k} is not in 1..={MAX_SLICES}")));
                }
                let (a, b) = (camera.t_near, camera.t_max);
                Ok((1..=*k)
                    .map(|n| a + (b - a) * n as f64 / *k as f64)
                    .collect())
            }
            Depths::At(v) => {
                if v.is_empty() || v.len() > MAX_SLICES {
                    return Err(bad("depths", format!("give 1 to {MAX_SLICES} depths")));
                }
                let ok = v.iter().all(|d| d.is_finite() && *d >= 0.0)
                    && v.windows(2).all(|w| w[0] < w[1]);
                if !ok {
                    return Err(bad(
                        "depths",
                        format!("{v:?} must be finite, non-negative and strictly increasing"),
                    ));
                }
                Ok(v.clone())
            }
        }
    }
}

/// Most worker threads accepted (`--threads`): far more than any machine has cores, far fewer
/// than make thread creation fail.
pub const MAX_THREADS: usize = 1024;

/// Check a thread count: 0 (all cores) to [`MAX_THREADS`].
///
/// # Errors
/// [`Error::InvalidArgument`] naming `threads`, with the largest accepted value.
pub fn check_threads(threads: usize) -> Result<()> {
    if threads <= MAX_THREADS {
        return Ok(());
    }
    Err(bad(
        "threads",
        format!("{threads} threads; at most {MAX_THREADS} (0 uses every core)"),
    ))
}

/// How to bake.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BakeSettings {
    /// Estimator of every pixel.
    pub estimator: Estimator,
    /// Estimator options; `options.samples` is the samples per pixel (first batch).
    pub options: Options,
    /// Adaptive sampling: while a pixel's error bound `sqrt(s^2 + (sqrt(3) / n)^2)` (`s` its
    /// standard error over `n` samples; the second term is the rule-of-three bound on a rare
    /// event that n samples all missed) exceeds this, add a batch as large as all its samples
    /// so far (its total doubles), up to `max_spp`. So a pixel takes at least `sqrt(3) / E`
    /// samples unless its ray needs no sampling at all.
    pub target_error: Option<f64>,
    /// Cap on samples per pixel for adaptive sampling.
    pub max_spp: u32,
    /// Extra depth channels.
    pub depths: Depths,
    /// Also keep each pixel's standard error (`T.stderr`).
    pub std_err: bool,
    /// Worker threads: 0 runs on the current rayon pool, `n` on a local pool of `n` threads.
    pub threads: usize,
    /// How pixels are traced: [`Order::Auto`] lets exact maps use the object-order sweep; [`Order::Rays`] traces every pixel's ray (the reference the sweep is tested
    /// against).
    pub order: Order,
    /// A light with extent (issue 60): each texel then stores `T_L` at its receiver
    /// ([`SoftMap`]); `None` for a point light (the map as ever, bit for bit).
    #[serde(skip)]
    pub soft: Option<SoftMap>,
}

/// A map toward a light with extent: every texel stores the mean transmittance over the light
/// (`T_L`, docs/lights.md) at a receiver point on the texel's own ray (the hard map's projector
/// ray from the light's centre), and each slice the same at its depth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SoftMap {
    /// The light, its extent and its directions per receiver.
    pub light: crate::light::SoftLight,
    /// Where the texel's receiver is on its ray.
    pub receiver: Receiver,
}

/// Where a soft map's texel is answered on the texel's ray (`umbra:receiver`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Receiver {
    /// Where the ray leaves the last volume (or solid) box it crosses; a ray that meets no box
    /// ends at the camera's `t_max` (the end of the hard map's ray).
    BoxExit,
    /// At this world distance along the ray (`receiver-depth`), as `depths` measures it.
    Depth(f64),
}

impl std::fmt::Display for Receiver {
    /// `box exit` or `depth D` (the `umbra:receiver` header attribute).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::BoxExit => write!(f, "box exit"),
            Self::Depth(d) => write!(f, "depth {}", crate::math::short(*d)),
        }
    }
}

/// The order in which a map is traced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "lowercase")]
pub enum Order {
    /// Object order (the sweep: each 8^3 block adds its exact integral, its marched points or
    /// its samples' null-collision flights to the pixels it covers) for trilinear maps of the
    /// exact, marching and null-collision estimators (slices included; orthographic,
    /// perspective and cube maps); ray order for everything else.
    #[default]
    Auto,
    /// One ray per pixel, walked down the tree.
    Rays,
}

impl BakeSettings {
    /// Check the settings that do not depend on the camera: the estimator options, at least
    /// one sample, a positive finite target error, `max_spp >= 1`, slice counts.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the setting.
    pub fn validate(&self) -> Result<()> {
        self.options.validate()?;
        if let Some(e) = self.target_error {
            if !(e.is_finite() && e > 0.0) {
                return Err(bad("target-error", format!("{e} is not a positive number")));
            }
        }
        check_threads(self.threads)?;
        if self.max_spp == 0 {
            return Err(bad("max-spp", "must be at least 1".into()));
        }
        crate::estimate::budget::check_samples("max-spp", u64::from(self.max_spp))?;
        match &self.depths {
            Depths::Slices(k) if *k == 0 || *k > MAX_SLICES => {
                Err(bad("slices", format!("{k} is not in 1..={MAX_SLICES}")))
            }
            Depths::At(v) if v.is_empty() || v.len() > MAX_SLICES => {
                Err(bad("depths", format!("give 1 to {MAX_SLICES} depths")))
            }
            _ => Ok(()),
        }
    }

    /// Settings for `estimator` with `options`: no adaptivity, no slices, no stderr channel,
    /// the current thread pool.
    #[must_use]
    pub fn new(estimator: Estimator, options: Options) -> Self {
        Self {
            estimator,
            options,
            target_error: None,
            max_spp: 65_536,
            depths: Depths::None,
            std_err: false,
            threads: 0,
            order: Order::Auto,
            soft: None,
        }
    }
}

/// The larger of two standard errors, unknown (`NaN`) when either is: a map in which some
/// pixel's error bar is unknown (a blurred march over one shutter time) has an unknown largest
/// error bar (`null` in `--json`), never the largest of the known ones.
#[must_use]
pub(crate) fn worse_std_err(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

/// The directions the sampled receivers of a product toward a light with extent traced (a
/// pilot's and its final stage's together; receivers answered without sampling left out).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct LightDirections {
    /// Their mean over the sampled receivers.
    pub mean: f64,
    /// Their 99th percentile (the least count at or above 99% of the sampled receivers').
    pub p99: u64,
    /// The most any receiver traced.
    pub max: u64,
    /// Receivers whose target error asked for more directions than `light-max-samples`
    /// allows: their error bar may be above the target.
    pub capped: u64,
}

impl LightDirections {
    /// From each receiver's `(directions, capped)`; a receiver of 0 directions was answered
    /// without sampling and is left out.
    pub fn of(answers: impl Iterator<Item = (usize, bool)>) -> Self {
        let mut counts = Vec::new();
        let mut capped = 0;
        for (n, c) in answers {
            capped += u64::from(c);
            if n > 0 {
                counts.push(n as u64);
            }
        }
        counts.sort_unstable();
        let k = counts.len();
        let at = |q: f64| counts.get(((q * k as f64).ceil() as usize).clamp(1, k.max(1)) - 1);
        Self {
            mean: counts.iter().sum::<u64>() as f64 / k.max(1) as f64,
            p99: at(0.99).copied().unwrap_or(0),
            max: counts.last().copied().unwrap_or(0),
            capped,
        }
    }
}

/// What a bake cost.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct BakeStats {
    /// Pixels (primary rays).
    pub rays: u64,
    /// Samples of the main `T` summed over pixels (`rays` for deterministic estimators).
    pub samples: u64,
    /// Density lookups, slices included.
    pub lookups: u64,
    /// Samples stopped by the collision cap (biased).
    pub capped: u64,
    /// Lookups outside their segment's bounds (see [`crate::estimate::Estimate::majorant_violations`]).
    pub majorant_violations: u64,
    /// Pixels whose error bound is still above the target (adaptive sampling hit the cap).
    pub unconverged: u64,
    /// Largest per-pixel standard error; `NaN` (unknown) when any pixel's is
    /// ([`worse_std_err`]).
    pub max_std_err: f64,
    /// Wall time of the render, seconds.
    pub seconds: f64,
    /// The map was traced in object order (the sweep) rather than one ray per pixel.
    pub sweep: bool,
    /// Parts of the grid decoded one after another to stay within `--max-memory` (0: the
    /// whole grid was in memory).
    pub parts: u64,
    /// A map toward a light with extent: the receivers whose light was sampled (the others'
    /// every direction provably meets no density: `T = 1` without tracing), over every
    /// receiver (texels times `1 + slices`). Absent for a point light.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub light_sampled: Option<[u64; 2]>,
    /// A map toward a light with extent under a target error: the receivers answered by a
    /// bound on every direction's optical depth (their cones only graze density:
    /// `T = 1` with the bound's error bar, not sampled).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub light_bounded: Option<u64>,
    /// A map toward a light with extent: the directions its sampled receivers traced.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub light_directions: Option<LightDirections>,
    /// A blurred `riemann` map the object-order sweep declined, so it went ray by ray (about
    /// 3-4x the sweep's time): why. Said as a warning ([`crate::bake::Warning::SweepDeclined`]).
    #[serde(skip)]
    pub declined: Option<SweepDeclined>,
}

/// Why the object-order sweep of a blurred `riemann` map (`bake::trace::sweep::blur`) handed
/// it to the ray path. Each is a case the sweep's closed per-block sums do not hold: depth
/// slices and adaptive counts need per-ray state, a nearest lookup and a non-zero background
/// read outside the blocks' windows, an infinite majorant needs the ray path's fine march.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SweepDeclined {
    /// Depth slices (`--depths`, a deep map).
    Slices,
    /// An adaptive count (`--target-error`).
    TargetError,
    /// Nearest lookups (`--interp nearest`).
    Nearest,
    /// One majorant for the whole grid (`--global-majorant`).
    GlobalMajorant,
    /// A non-zero background extinction (per world unit, scaled).
    Background(f64),
    /// A voxel that is infinite (opaque) lies within the shutter's reach of a block.
    Opaque,
    /// A band of rows would hold more per-pixel time values than the sweep keeps
    /// (`values`: rows times width times time samples).
    WideBand {
        /// Time values the band would hold.
        values: u64,
        /// The most the sweep keeps.
        max: u64,
    },
    /// The map is baked in parts under `--max-memory`, which go ray by ray.
    Parts,
}

impl std::fmt::Display for SweepDeclined {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Self::Slices => f.write_str("it has depth slices (--depths)"),
            Self::TargetError => f.write_str("--target-error asks for an adaptive count"),
            Self::Nearest => f.write_str("its lookups are nearest (--interp nearest)"),
            Self::GlobalMajorant => f.write_str("--global-majorant is set"),
            Self::Background(mu) => write!(
                f,
                "the grid's background extinction is not zero ({})",
                crate::math::sig3(mu)
            ),
            Self::Opaque => {
                f.write_str("an infinite (opaque) voxel lies within the shutter's reach")
            }
            Self::WideBand { values, max } => write!(
                f,
                "a band of rows would hold {values} time values (the sweep keeps at most \
                 {max}: fewer time samples or a narrower map)"
            ),
            Self::Parts => f.write_str("it is baked in parts under --max-memory"),
        }
    }
}

/// A baked map: row-major channels, row 0 at the top, pixel `(i, j)` at index `j W + i`.
#[derive(Debug, Clone)]
pub struct Map {
    /// The camera every pixel's ray comes from.
    pub camera: Camera,
    /// The settings it was baked with.
    pub settings: BakeSettings,
    /// Transmittance over `[0, t_max]`.
    pub t: Vec<f32>,
    /// Standard error of `t`, when asked for.
    pub std_err: Option<Vec<f32>>,
    /// Depths of the slices (world distance along each ray).
    pub depths: Vec<f64>,
    /// Transmittance over `[0, depths[k]]`, one image per depth.
    pub slices: Vec<Vec<f32>>,
    /// Green and blue of an RGB scene (`t`, `std_err` and `slices` then hold red).
    pub color: Option<Box<[Channel; 2]>>,
    /// Cost.
    pub stats: BakeStats,
}

/// One colour channel of a map: its transmittance, standard error and slices, laid out as
/// [`Map`]'s.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Channel {
    /// Transmittance over `[0, t_max]`.
    pub t: Vec<f32>,
    /// Standard error of `t`, when asked for.
    pub std_err: Option<Vec<f32>>,
    /// Transmittance over `[0, depths[k]]`.
    pub slices: Vec<Vec<f32>>,
}

/// Split per-channel images (1 or 3) into [`Map`]'s red-or-grey channel and its `color`.
pub(crate) fn split_channels(chans: Vec<Channel>) -> (Channel, Option<Box<[Channel; 2]>>) {
    let mut it = chans.into_iter();
    let red = it.next().unwrap_or_default();
    let color = match (it.next(), it.next()) {
        (Some(g), Some(b)) => Some(Box::new([g, b])),
        _ => None,
    };
    (red, color)
}

impl Map {
    /// 1 (grey) or 3 (R, G, B).
    #[must_use]
    pub fn channels(&self) -> usize {
        if self.color.is_some() {
            3
        } else {
            1
        }
    }

    /// Channel `c` (0 = grey or red, 1 = green, 2 = blue) as `(t, std_err, slices)`.
    #[must_use]
    pub fn channel(&self, c: usize) -> (&[f32], Option<&[f32]>, &[Vec<f32>]) {
        match (c, &self.color) {
            (1 | 2, Some(gb)) => {
                let ch = &gb[c - 1];
                (&ch.t, ch.std_err.as_deref(), &ch.slices)
            }
            _ => (&self.t, self.std_err.as_deref(), &self.slices),
        }
    }
}

/// An invalid argument `name` of a bake.
pub(super) fn bad(name: &str, reason: String) -> Error {
    Error::InvalidArgument {
        name: name.into(),
        reason,
    }
}

/// Name of depth slice `k`'s channel: `slice00.T`, `slice01.T`, ...
#[must_use]
pub fn slice_channel(k: usize) -> String {
    format!("slice{k:02}.T")
}

/// The EXR channel names of a map with `channels` (1: `T`; 3: `R`, `G`, `B`) channels, each
/// followed by its `.stderr` and its `sliceNN` channels.
#[must_use]
pub fn channel_names(channels: usize, std_err: bool, slices: usize) -> Vec<String> {
    let names: &[&str] = if channels == 3 {
        &["R", "G", "B"]
    } else {
        &["T"]
    };
    let mut out = Vec::new();
    for base in names {
        out.push((*base).to_string());
        if std_err {
            out.push(format!("{base}.stderr"));
        }
        out.extend((0..slices).map(|k| slice_channel(k).replace(".T", &format!(".{base}"))));
    }
    out
}

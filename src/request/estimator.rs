//! The estimator options: the one definition of the flags, job keys and Python keywords that
//! choose an estimator, its parameters and its sampling. [`EstimatorOptions`] is the set alone
//! (what `umbra query` flattens); [`EstimatorParams`] the parameters alone (`umbra compare`
//! runs a ladder of estimators with them); [`super::BakeOptions`] has the same fields, spliced
//! in by the macros below, so a job file's `[bake]` stays one flat table whose keys serde
//! checks with their line and column (serde's `flatten` would lose both).

/// Defines `pub struct NAME { BEFORE.. step, kernel, points, AFTER.. }` with the attributes
/// given: the estimator parameters' one definition (flag, help, job key, keyword).
macro_rules! with_estimator_params {
    ($(#[$m:meta])* pub struct $name:ident { $($before:tt)* } { $($after:tt)* }) => {
        $(#[$m])*
        pub struct $name {
            $($before)*
            /// Ray-marching step in voxels (riemann, mc, jittered; default 1).
            #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
            pub step: Option<f64>,
            /// Kernel width in voxels (collision; default 1).
            #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
            pub kernel: Option<f64>,
            /// Points per optical-depth estimate (jackknife; default 10).
            #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
            pub points: Option<f64>,
            $($after)*
        }
    };
}

/// Defines `pub struct NAME { BEFORE.. estimator, samples, seed, step, kernel, points,
/// granularity, global_majorant, colour_walk, AFTER.. }` with the attributes given: the
/// estimator options' one definition. Defaults are [`EstimatorOptions::default`]'s (the
/// `default_value`s here are the CLI's spelling of the same values; a test holds them equal).
macro_rules! with_estimator_options {
    ($(#[$m:meta])* pub struct $name:ident { $($before:tt)* } { $($after:tt)* }) => {
        with_estimator_params! {
            $(#[$m])*
            pub struct $name {
                $($before)*
                /// Estimator (`umbra estimators` lists them with their parameters).
                #[cfg_attr(feature = "cli", arg(long, default_value = "regular"))]
                pub estimator: String,
                /// Independent samples per pixel, voxel or ray (stochastic estimators); alias
                /// spp.
                #[cfg_attr(
                    feature = "cli",
                    arg(long, visible_alias = "spp", default_value_t = 64)
                )]
                #[serde(alias = "spp")]
                pub samples: u32,
                /// Seed of the random streams.
                #[cfg_attr(feature = "cli", arg(long, default_value_t = 0))]
                pub seed: u64,
            } {
                /// Majorant granularity of the HDDA (with a velocity: leaf, the blurred
                /// bounds per 8^3 block).
                #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "leaf"))]
                pub granularity: Granularity,
                /// One majorant for the whole grid (the naive baseline).
                #[cfg_attr(feature = "cli", arg(long))]
                pub global_majorant: bool,
                /// How a coloured medium's channels are tracked by a stochastic estimator:
                /// `shared` (one walk under the largest channel's majorant, lookups shared),
                /// `split` (a walk per channel on its own majorants), `auto` (the estimator's
                /// measured choice; docs/colour.md).
                #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "auto"))]
                #[serde(default)]
                pub colour_walk: ColourWalk,
                /// Motion blur: the vec3 velocity grid of the density's file (cell-centred, or
                /// staggered as its class says; world units per second unless it is marked
                /// local-space): T is the shutter mean through rho(x - S v(x) t / F). Needs a
                /// marching or null-collision estimator (docs/motion.md).
                #[cfg_attr(feature = "cli", arg(long, value_name = "GRID"))]
                pub velocity: Option<String>,
                /// With velocity: the shutter OPEN,CLOSE in frames relative to the baked frame
                /// (default -0.25,0.25).
                #[cfg_attr(
                    feature = "cli",
                    arg(long, value_parser = crate::request::parse_pair, allow_hyphen_values = true)
                )]
                pub shutter: Option<[f64; 2]>,
                /// With velocity: frames per second (default 24; a USD shot's
                /// timeCodesPerSecond).
                #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
                pub fps: Option<f64>,
                /// With velocity: the velocity scale S (default 1).
                #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
                pub velocity_scale: Option<f64>,
                /// With velocity: stratified shutter times per sample of a marching estimator
                /// (default 8; 1 leaves the error bar unknown); refused for the null-collision
                /// estimators, which draw one time per sample.
                #[cfg_attr(feature = "cli", arg(long))]
                pub time_samples: Option<u32>,
                $($after)*
            }
        }
    };
}

use crate::error::{Error, Result};
use crate::estimate::{ColourWalk, Estimator, Options};
use crate::motion::{MotionRequest, MotionSpec};
use crate::traverse::Granularity;
use crate::Interp;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

with_estimator_options! {
    /// Which estimator answers, with its parameters and sampling: `estimator` by its registry
    /// name ([`crate::estimate::REGISTRY`]), `step` / `kernel` / `points` for the estimators
    /// that take them (another is refused by name), `samples` per answer, the `seed` of the
    /// counter-based streams, and the majorants' `granularity`, `global_majorant` and
    /// `colour_walk`.
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    #[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
    #[cfg_attr(feature = "cli", derive(clap::Args))]
    #[serde(deny_unknown_fields, default)]
    pub struct EstimatorOptions {} {}
}

impl Default for EstimatorOptions {
    /// Exact regular tracking, 64 samples (for the stochastic estimators), seed 0, leaf
    /// majorants, the estimator's own colour walk.
    fn default() -> Self {
        Self {
            estimator: "regular".into(),
            samples: 64,
            seed: 0,
            step: None,
            kernel: None,
            points: None,
            granularity: Granularity::Leaf,
            global_majorant: false,
            colour_walk: ColourWalk::Auto,
            velocity: None,
            shutter: None,
            fps: None,
            velocity_scale: None,
            time_samples: None,
        }
    }
}

impl EstimatorOptions {
    /// Options from a JSON object, as the Python module passes its keywords (the names of
    /// [`EstimatorOptions::default`] serialised: the one list Python's keywords come from): a
    /// value of the wrong type or an unknown name is an [`crate::error::Error::InvalidArgument`]
    /// naming that option.
    ///
    /// # Errors
    /// As above.
    pub fn from_json(text: &str) -> Result<Self> {
        from_json_object(text)
    }

    /// The parameters alone.
    #[must_use]
    pub fn params(&self) -> EstimatorParams {
        EstimatorParams {
            step: self.step,
            kernel: self.kernel,
            points: self.points,
        }
    }

    /// The motion blur these options ask for (`crate::motion`), checked: `None` without
    /// `velocity`; `default_fps` is a USD shot's `timeCodesPerSecond` (else 24).
    ///
    /// # Errors
    /// [`crate::error::Error::InvalidArgument`] naming `shutter`, `fps`, `velocity-scale` or
    /// `time-samples` given without `velocity` or out of range, an empty `velocity`, or
    /// `estimator` when it is `regular` (exact only for a still grid).
    pub fn motion(&self, default_fps: Option<f64>) -> Result<Option<MotionRequest>> {
        let Some(velocity) = &self.velocity else {
            let given = [
                ("shutter", self.shutter.is_some()),
                ("fps", self.fps.is_some()),
                ("velocity-scale", self.velocity_scale.is_some()),
                ("time-samples", self.time_samples.is_some()),
            ];
            return match given.iter().find(|(_, g)| *g) {
                Some((k, _)) => Err(Error::InvalidArgument {
                    name: (*k).into(),
                    reason: "applies to motion blur: give the velocity grid (velocity)".into(),
                }),
                None => Ok(None),
            };
        };
        if self.estimator == Estimator::REGULAR.name() {
            return Err(Error::InvalidArgument {
                name: "estimator".into(),
                reason: crate::estimate::blur::REGULAR_REFUSED.into(),
            });
        }
        // Under blur every option is honoured or refused by name: the blurred bounds are per
        // 8^3 block (or one for the grid), and only marchers stratify the shutter.
        if self.granularity != Granularity::Leaf {
            return Err(Error::InvalidArgument {
                name: "granularity".into(),
                reason: "with a velocity the majorants are the blurred bounds of each 8^3 \
                         block (leaf), or one for the grid with global-majorant"
                    .into(),
            });
        }
        if self.time_samples.is_some() {
            if let Ok(e) = Estimator::from_name(&self.estimator) {
                if !e.marches() {
                    return Err(Error::InvalidArgument {
                        name: "time-samples".into(),
                        reason: format!(
                            "applies to the marching estimators (riemann, mc, jittered); {} \
                             draws one uniform shutter time per sample (raise samples instead)",
                            e.name()
                        ),
                    });
                }
            }
        }
        motion_request(
            velocity,
            self.shutter,
            self.fps.or(default_fps),
            self.velocity_scale,
            self.time_samples,
        )
        .map(Some)
    }

    /// The estimator these options select, with its parameters, and the tracing options for
    /// lookups by `interp`, validated.
    ///
    /// # Errors
    /// [`crate::error::Error::InvalidArgument`] naming `estimator`, a parameter it does not take, or
    /// an option out of range.
    pub fn resolve(&self, interp: Interp) -> Result<(Estimator, Options)> {
        let estimator = self.params().apply(&self.estimator)?;
        let mut options = Options {
            interp,
            samples: self.samples,
            seed: self.seed,
            granularity: self.granularity,
            global_majorant: self.global_majorant,
            colour_walk: self.colour_walk,
            ..Options::default()
        };
        options.validate()?;
        if estimator.is_deterministic() {
            // A deterministic estimator answers with one sample whatever was asked: recorded
            // as 1 (the EXR's `spp`, summaries), not as the 64 it never took.
            options.samples = 1;
        }
        Ok((estimator, options))
    }
}

with_estimator_params! {
    /// The estimator parameters alone (`step`, `kernel`, `points`): what a ladder of
    /// estimators shares (`umbra compare`). Unset parameters take each estimator's default.
    #[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
    #[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
    #[cfg_attr(feature = "cli", derive(clap::Args))]
    #[serde(deny_unknown_fields, default)]
    pub struct EstimatorParams {} {}
}

impl EstimatorParams {
    /// The parameters given, as `(name, value)`.
    #[must_use]
    pub fn given(&self) -> Vec<(&'static str, f64)> {
        [
            ("step", self.step),
            ("kernel", self.kernel),
            ("points", self.points),
        ]
        .into_iter()
        .filter_map(|(n, v)| v.map(|v| (n, v)))
        .collect()
    }

    /// Estimator `name` with these parameters.
    ///
    /// # Errors
    /// [`crate::error::Error::InvalidArgument`] naming the estimator, or a parameter it does not take.
    pub fn apply(&self, name: &str) -> Result<Estimator> {
        Estimator::with_params(name, &self.given())
    }
}

/// The motion blur of velocity grid `velocity` with the other options given or their
/// defaults (shutter [`crate::motion::DEFAULT_SHUTTER`], 24 fps, scale 1,
/// [`crate::motion::DEFAULT_TIME_SAMPLES`]): what [`EstimatorOptions::motion`] checks after
/// the options that need a velocity.
///
/// # Errors
/// [`crate::error::Error::InvalidArgument`] naming `velocity` (empty), `shutter`, `fps`,
/// `velocity-scale` or `time-samples` out of range.
fn motion_request(
    velocity: &str,
    shutter: Option<[f64; 2]>,
    fps: Option<f64>,
    scale: Option<f64>,
    time_samples: Option<u32>,
) -> Result<MotionRequest> {
    if velocity.is_empty() {
        return Err(Error::InvalidArgument {
            name: "velocity".into(),
            reason: "must name a vec3 grid".into(),
        });
    }
    let spec = MotionSpec::new(
        shutter.unwrap_or(crate::motion::DEFAULT_SHUTTER),
        fps.unwrap_or(crate::motion::DEFAULT_FPS),
        scale.unwrap_or(1.0),
        time_samples.unwrap_or(crate::motion::DEFAULT_TIME_SAMPLES),
    )?;
    Ok(MotionRequest {
        velocity: velocity.to_string(),
        spec,
        file: None,
        fps_given: fps.is_some(),
    })
}

/// A set of options from a JSON object: a value of the wrong type or an unknown name is an
/// [`Error::InvalidArgument`] naming that option (the first key that does not parse alone).
pub(crate) fn from_json_object<T: DeserializeOwned>(text: &str) -> Result<T> {
    let bad = |name: &str, reason: &str| Error::InvalidArgument {
        name: name.into(),
        reason: reason.into(),
    };
    let value: serde_json::Map<String, serde_json::Value> =
        serde_json::from_str(text).map_err(|e| bad("options", &e.to_string()))?;
    serde_json::from_value(serde_json::Value::Object(value.clone())).map_err(|whole| {
        // Name the first option that does not parse on its own.
        for (k, v) in &value {
            let one = serde_json::Map::from_iter([(k.clone(), v.clone())]);
            if let Err(e) = serde_json::from_value::<T>(serde_json::Value::Object(one)) {
                let reason = e.to_string();
                return bad(k, reason.split(" at line").next().unwrap_or(&reason));
            }
        }
        bad("options", &whole.to_string())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The flags' `default_value`s are the library's defaults, and a bake's estimator options
    /// are the same set with the same defaults.
    #[cfg(feature = "cli")]
    #[test]
    fn cli_defaults_are_the_library_defaults() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            options: EstimatorOptions,
            #[command(flatten)]
            params: EstimatorParams,
        }
        let parsed = Cli::try_parse_from(["umbra"]).unwrap();
        assert_eq!(parsed.options, EstimatorOptions::default());
        assert_eq!(parsed.params, EstimatorParams::default());
        let bake = crate::request::BakeOptions::default();
        assert_eq!(bake.estimator_options(), EstimatorOptions::default());
    }

    /// The same keys and aliases read a job's `[bake]` and the set alone; a parameter an
    /// estimator does not take is refused by name.
    #[test]
    fn keys_and_resolution() {
        let o: EstimatorOptions =
            serde_json::from_str(r#"{"estimator": "riemann", "spp": 3, "step": 0.5}"#).unwrap();
        assert_eq!((o.samples, o.step), (3, Some(0.5)));
        let (e, opts) = o.resolve(Interp::Nearest).unwrap();
        // A deterministic estimator takes one sample whatever was asked, and says so.
        assert_eq!(
            (e.name(), opts.samples, opts.interp),
            ("riemann", 1, Interp::Nearest)
        );
        let mc = EstimatorOptions {
            estimator: "mc".into(),
            ..o.clone()
        };
        assert_eq!(mc.resolve(Interp::Nearest).unwrap().1.samples, 3);
        let bad = EstimatorOptions {
            kernel: Some(2.0),
            ..o
        };
        let err = bad.resolve(Interp::Trilinear).unwrap_err().to_string();
        assert!(err.contains("kernel"), "{err}");
        assert!(serde_json::from_str::<EstimatorOptions>(r#"{"bogus": 1}"#).is_err());
    }
}

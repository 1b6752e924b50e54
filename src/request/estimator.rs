//! The estimator options: the one definition of the flags, job keys and Python keywords that
//! choose an estimator, its parameters and its sampling. [`EstimatorOptions`] is the set alone
//! (what `umbra query` flattens); [`EstimatorParams`] the parameters alone (`umbra compare`
//! runs a ladder of estimators with them); [`super::BakeOptions`] has the same fields, spliced
//! in by the macros below, so a job file's `[bake]` stays one flat table whose keys serde
//! checks with their line and column (serde's `flatten` would lose both).

use crate::error::{Error, Result};
use crate::estimate::{ColourWalk, Estimator, Options};
use crate::input::SourceOptions;
use crate::motion::MotionRequest;
use crate::traverse::Granularity;
use crate::Interp;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// Which estimator answers, with its parameters and sampling: `estimator` by its registry
/// name ([`crate::estimate::REGISTRY`]), `step` / `kernel` / `points` for the estimators that
/// take them ([`EstimatorParams`]; another is refused by name), `samples` per answer, the
/// `seed` of the counter-based streams, and the majorants' `granularity`, `global_majorant`
/// and `colour_walk`. Flattened into [`super::BakeOptions`], `umbra query`'s flags and the
/// Python keywords (serde's and clap's `flatten`), so each key is declared here once.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(default)]
pub struct EstimatorOptions {
    /// Estimator (`umbra estimators` lists them with their parameters).
    #[cfg_attr(feature = "cli", arg(long, default_value = "regular"))]
    pub estimator: String,
    /// Independent samples per pixel, voxel or ray (stochastic estimators); alias spp.
    #[cfg_attr(
        feature = "cli",
        arg(long, visible_alias = "spp", default_value_t = 64)
    )]
    #[serde(alias = "spp")]
    pub samples: u32,
    /// Seed of the random streams.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0))]
    pub seed: u64,
    /// Majorant granularity of the HDDA (with a velocity: leaf, the blurred bounds per 8^3
    /// block).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "leaf"))]
    pub granularity: Granularity,
    /// One majorant for the whole grid (the naive baseline).
    #[cfg_attr(feature = "cli", arg(long))]
    pub global_majorant: bool,
    /// How a coloured medium's channels are tracked by a stochastic estimator: `shared` (one
    /// walk under the largest channel's majorant, lookups shared), `split` (a walk per channel
    /// on its own majorants), `auto` (the estimator's measured choice; docs/colour.md).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value = "auto"))]
    pub colour_walk: ColourWalk,
}

impl Default for EstimatorOptions {
    /// Exact regular tracking, 64 samples (for the stochastic estimators), seed 0, leaf
    /// majorants, the estimator's own colour walk.
    fn default() -> Self {
        Self {
            estimator: "regular".into(),
            samples: 64,
            seed: 0,
            granularity: Granularity::Leaf,
            global_majorant: false,
            colour_walk: ColourWalk::Auto,
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
        from_json_object::<Strict<Self>>(text).map(|s| s.inner)
    }

    /// The motion blur `source` asks for ([`MotionRequest::of`]), checked against these
    /// options: `None` without `velocity`.
    ///
    /// # Errors
    /// As [`MotionRequest::of`], and [`crate::error::Error::InvalidArgument`] naming
    /// `estimator` when it is `regular` (exact only for a still grid), `granularity` other than
    /// leaf, or `time-samples` for an estimator that does not march.
    pub fn motion(&self, source: &SourceOptions) -> Result<Option<MotionRequest>> {
        let Some(request) = MotionRequest::of(source)? else {
            return Ok(None);
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
        if source.time_samples.is_some() {
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
        Ok(Some(request))
    }

    /// The estimator these options select, with its parameters, and the tracing options for
    /// lookups by `interp`, validated.
    ///
    /// # Errors
    /// [`crate::error::Error::InvalidArgument`] naming `estimator`, a parameter it does not take, or
    /// an option out of range.
    pub fn resolve(
        &self,
        params: &EstimatorParams,
        interp: Interp,
    ) -> Result<(Estimator, Options)> {
        let estimator = params.apply(&self.estimator)?;
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

/// The estimator parameters alone (`step`, `kernel`, `points`): what a ladder of
/// estimators shares (`umbra compare`). Unset parameters take each estimator's default.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(default)]
pub struct EstimatorParams {
    /// Ray-marching step in voxels (riemann, mc, jittered; default 1).
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    pub step: Option<f64>,
    /// Kernel width in voxels (collision; default 1).
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    pub kernel: Option<f64>,
    /// Points per optical-depth estimate (jackknife; default 10).
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    pub points: Option<f64>,
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

/// The read options and the estimator options as one flat set of keys: what Python's query
/// functions take as keywords (besides their question), each key declared once in its own
/// set.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields, default)]
pub struct TraceOptions {
    /// How the input is read.
    #[serde(flatten)]
    pub source: SourceOptions,
    /// Which estimator answers.
    #[serde(flatten)]
    pub estimator: EstimatorOptions,
    /// Its parameters.
    #[serde(flatten)]
    pub params: EstimatorParams,
}

impl TraceOptions {
    /// The estimator these options select, with its parameters, for lookups by the read
    /// options' `interp` ([`EstimatorOptions::resolve`]).
    ///
    /// # Errors
    /// As [`EstimatorOptions::resolve`].
    pub fn resolve(&self) -> Result<(Estimator, Options)> {
        self.estimator.resolve(&self.params, self.source.interp)
    }
}

impl TraceOptions {
    /// Options from a JSON object ([`EstimatorOptions::from_json`]'s rules).
    ///
    /// # Errors
    /// [`crate::error::Error::InvalidArgument`] naming the first option that does not parse.
    pub fn from_json(text: &str) -> Result<Self> {
        from_json_object(text)
    }
}

/// `base` with `keys` (a JSON object of options by name) over it: each key replaces `base`'s
/// value of it, an alias (`spp`) its canonical key's (`samples`); a value that does not parse
/// is an [`Error::InvalidArgument`] naming its key. The caller checks that every key is one of
/// the set's ([`read_keys`], [`TraceOptions::from_json`]): a set flattened into others does not
/// deny unknown keys itself.
///
/// # Errors
/// As above.
pub fn overlaid<T: Serialize + DeserializeOwned>(
    base: &T,
    keys: &serde_json::Map<String, serde_json::Value>,
) -> Result<T> {
    let Ok(serde_json::Value::Object(mut all)) = serde_json::to_value(base) else {
        return Err(Error::InvalidArgument {
            name: "options".into(),
            reason: "cannot be written as JSON".into(),
        });
    };
    for (k, v) in keys {
        all.insert(k.clone(), v.clone());
    }
    // serde knows the aliases: a key given as an alias while `base` holds its canonical name
    // is a duplicate, and the given one wins.
    for _ in 0..=keys.len() {
        match serde_json::from_value::<T>(serde_json::Value::Object(all.clone())) {
            Ok(o) => return Ok(o),
            Err(e) => {
                let text = e.to_string();
                let dup = text
                    .strip_prefix("duplicate field `")
                    .and_then(|r| r.split('`').next())
                    .filter(|d| !keys.contains_key(*d))
                    .map(str::to_string);
                match dup {
                    Some(d) if all.remove(&d).is_some() => {}
                    _ => break,
                }
            }
        }
    }
    from_json_object(&serde_json::Value::Object(all).to_string())
}

/// The read options `keys` give alone (every key a read key, each value of its type): what a
/// job's `[[inputs]]` entry may set.
///
/// # Errors
/// [`Error::InvalidArgument`] naming the first key that is no read key or does not parse.
pub fn read_keys(keys: &serde_json::Map<String, serde_json::Value>) -> Result<SourceOptions> {
    from_json_object::<Strict<SourceOptions>>(&serde_json::Value::Object(keys.clone()).to_string())
        .map(|s| s.inner)
}

/// `T` with no key but its own: a set of options with `flatten`ed parts has no
/// `deny_unknown_fields` of its own (a part sees its parent's keys), so a set read alone is
/// read through this.
#[derive(Deserialize)]
#[serde(deny_unknown_fields, bound = "T: DeserializeOwned")]
struct Strict<T> {
    #[serde(flatten)]
    inner: T,
}

/// A set of options from a JSON object: a value of the wrong type or an unknown name (for a
/// set that denies them) is an [`Error::InvalidArgument`] naming that option (the first key
/// that does not parse alone).
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
        assert_eq!(bake.estimator, EstimatorOptions::default());
    }

    /// The same keys and aliases read a job's `[bake]` and the set alone; a parameter an
    /// estimator does not take is refused by name.
    #[test]
    fn keys_and_resolution() {
        let o: EstimatorOptions =
            serde_json::from_str(r#"{"estimator": "riemann", "spp": 3}"#).unwrap();
        let p: EstimatorParams = serde_json::from_str(r#"{"step": 0.5}"#).unwrap();
        assert_eq!((o.samples, p.step), (3, Some(0.5)));
        let (e, opts) = o.resolve(&p, Interp::Nearest).unwrap();
        // A deterministic estimator takes one sample whatever was asked, and says so.
        assert_eq!(
            (e.name(), opts.samples, opts.interp),
            ("riemann", 1, Interp::Nearest)
        );
        let mc = EstimatorOptions {
            estimator: "mc".into(),
            ..o.clone()
        };
        assert_eq!(mc.resolve(&p, Interp::Nearest).unwrap().1.samples, 3);
        let bad = EstimatorParams {
            kernel: Some(2.0),
            ..p
        };
        let err = o.resolve(&bad, Interp::Trilinear).unwrap_err().to_string();
        assert!(err.contains("kernel"), "{err}");
        assert!(EstimatorOptions::from_json(r#"{"bogus": 1}"#).is_err());
        // Read alone, a set refuses another set's key; a bake's options take both.
        assert!(EstimatorOptions::from_json(r#"{"grid": "d"}"#).is_err());
        assert!(crate::request::BakeOptions::from_json(r#"{"grid": "d", "spp": 2}"#).is_ok());
    }
}

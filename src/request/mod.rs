//! One bake request for every front end: [`BakeOptions`] is everything a TD asks of a bake
//! besides its input file and its output path, as plain data, and [`BakeRequest::plan`] turns
//! it into a checked plan ([`BakePlan`]: a map or a transmittance volume) in one place, and
//! [`BakeRequest::run`] runs it: every front end's one entry point of a bake (`request/run.rs`).
//!
//! **One naming rule.** The CLI's long flags, the job file's `[bake]` keys and the Python
//! keywords are this type's fields: a job key and a Python keyword are the long flag with `-`
//! turned into `_` (`--deep-error`, `deep_error = 0.01`, `deep_error=0.01`). The CLI derives its
//! flags from the type (feature `cli`), serde reads job files and Python's keywords from it,
//! and the JSON Schema of job files (`umbra batch --schema`, feature `schema`) is generated
//! from it, so the three cannot drift apart. Where an option had two spellings, the canonical
//! one is the field and the other an alias everywhere: `samples` (alias `spp`), `force`
//! (alias `overwrite`), `stderr` (Python's `return_stderr`).
//!
//! **One set of defaults, one set of errors.** [`BakeOptions::default`] is every front end's
//! default (a test holds the CLI's to it). [`BakeRequest::plan`] refuses what cannot be
//! baked with [`crate::error::Error::InvalidArgument`] naming the option in the library's spelling; each
//! front end respells the name (`--step`, `step =`, `step=`).
//!
//! **What a product reads.** The output's extension picks the product: `.vdb` a
//! transmittance volume, anything else an EXR map (flat, or deep with `deep`). A
//! transmittance volume reads only [`VOLUME_OPTIONS`]; any other option set to a value other
//! than its default is refused naming it, and a map refuses `out_grid` and `half`. So a
//! request that would silently ignore an option cannot be planned.

use crate::bake::{BakeJob, Camera, Resolution, VolumeJob};
use crate::error::Result;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

mod estimator;
pub use crate::input::{parse_pair, parse_vec3, LevelSet, SourceOptions};
pub use crate::light::LightOptions;
pub use estimator::{overlaid, read_keys, EstimatorOptions, EstimatorParams, TraceOptions};
use options::{bad, VOLUME_ONLY};
pub use options::{parse_box, parse_size, BakeOptions, VOLUME_OPTIONS};
mod options;
mod plan;
mod query;
pub use query::{
    answer_rows, check_budget, Answer, Answered, LoadMode, PointsOutcome, QueryError, QueryOutcome,
    QueryRequest, QueryStep, QueryTally, RayAnswers, RayRow,
};
mod run;
#[cfg(feature = "usd")]
pub(crate) use run::shadow_sample;
pub use run::BakeOutcome;

/// How the maps of a batch job are framed (`framing`, job files only).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[serde(rename_all = "kebab-case")]
pub enum Framing {
    /// One camera per light for a whole sequence, framing the union of its volume boxes.
    #[default]
    Shared,
    /// Each input framed on its own volume box.
    PerFrame,
}

/// A camera to reuse (`camera`): the path of an earlier umbra map (`.exr`) or of a JSON file
/// holding the `camera` object `bake --json` prints, or that object itself (job files and
/// Python).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[serde(untagged)]
pub enum CameraSource {
    /// A map or JSON file (relative to a job file's directory in a job).
    File(PathBuf),
    /// The camera object itself.
    Inline(serde_json::Map<String, serde_json::Value>),
}

impl std::str::FromStr for CameraSource {
    type Err = std::convert::Infallible;

    /// A path, as `--camera` takes it.
    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        Ok(Self::File(PathBuf::from(s)))
    }
}

impl CameraSource {
    /// The camera, at `res` when given (the same window at that size).
    ///
    /// # Errors
    /// [`crate::error::Error::Io`] or [`crate::error::Error::InvalidArgument`] from reading it.
    pub fn read(&self, res: Option<Resolution>) -> Result<Camera> {
        match self {
            Self::File(p) => crate::bake::read_camera(p, res),
            Self::Inline(m) => {
                let text = serde_json::to_vec(m).map_err(|e| bad("camera", e.to_string()))?;
                crate::bake::camera_from_json("camera", &text, res)
            }
        }
    }
}

/// One bake: an input, an output and the options.
#[derive(Debug, Clone, PartialEq)]
pub struct BakeRequest {
    /// The `.vdb` or `.nvdb` file, a `.toml` scene file or a USD stage.
    pub input: PathBuf,
    /// The output: an OpenEXR map (`.exr`) or a transmittance volume (`.vdb`).
    pub output: PathBuf,
    /// Everything else.
    pub options: BakeOptions,
}

/// A checked bake, ready to run: a map (flat or deep EXR) or a transmittance volume.
#[derive(Debug, Clone, PartialEq)]
pub enum BakePlan {
    /// An EXR map ([`BakeJob`]; `product` says flat or deep).
    Map(Box<BakeJob>),
    /// A transmittance volume ([`VolumeJob`]).
    Volume(Box<VolumeJob>),
}

/// Whether `output` names a transmittance volume (`.vdb`).
#[must_use]
pub fn is_volume_output(output: &Path) -> bool {
    output
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("vdb"))
}

impl BakeRequest {
    /// What the bake reads: the input with the read options ([`crate::input::Source`]; its
    /// kind decided here, once per plan).
    #[must_use]
    pub fn source(&self) -> crate::input::Source {
        crate::input::Source::new(&self.input, self.options.source.clone())
    }

    /// Check the request and build its plan. Reads nothing but a reused camera's file; outputs
    /// are checked when the plan runs ([`BakeJob::check_outputs`], [`VolumeJob::check_outputs`]).
    ///
    /// # Errors
    /// [`crate::error::Error::InvalidArgument`] naming the first option that cannot be honoured (canonical
    /// spelling, which each front end respells); errors reading a reused camera.
    pub fn plan(&self) -> Result<BakePlan> {
        // Maps and transmittance volumes both answer a light with extent (checked when
        // planned).
        let with_light = self.with_stage_light()?;
        let req = with_light.as_ref().unwrap_or(self);
        req.plan_checked()
    }

    fn plan_checked(&self) -> Result<BakePlan> {
        let o = &self.options;
        o.check_common()?;
        let changed = o.changed();
        if is_volume_output(&self.output) {
            if let Some(k) = changed
                .iter()
                .find(|k| !VOLUME_OPTIONS.contains(&k.as_str()))
            {
                return Err(bad(
                    k,
                    "applies to maps (.exr); a transmittance volume (.vdb) is one float grid of T \
                     toward the light",
                ));
            }
            return self.plan_volume().map(|j| BakePlan::Volume(Box::new(j)));
        }
        if let Some(k) = changed.iter().find(|k| VOLUME_ONLY.contains(&k.as_str())) {
            return Err(bad(
                k,
                "applies to transmittance volumes (an output ending in .vdb)",
            ));
        }
        self.plan_map().map(|j| BakePlan::Map(Box::new(j)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::Error;

    #[test]
    fn defaults_change_nothing() {
        assert!(BakeOptions::default().changed().is_empty());
        let o = BakeOptions {
            tile: Some(64),
            estimator: EstimatorOptions {
                samples: 8,
                ..EstimatorOptions::default()
            },
            ..BakeOptions::default()
        };
        assert_eq!(o.changed(), ["samples", "tile"]);
    }

    #[test]
    fn aliases_and_errors_name_the_option() {
        let o = BakeOptions::from_json(r#"{"spp": 4, "overwrite": true}"#).unwrap();
        assert_eq!((o.estimator.samples, o.force), (4, true));
        let e = BakeOptions::from_json(r#"{"tile": 4, "fov": "wide"}"#).unwrap_err();
        assert!(
            matches!(e, Error::InvalidArgument { ref name, .. } if name == "fov"),
            "{e}"
        );
        let e = BakeOptions::from_json(r#"{"tiles": 4}"#).unwrap_err();
        assert!(
            matches!(e, Error::InvalidArgument { ref name, .. } if name == "tiles"),
            "{e}"
        );
    }

    #[test]
    fn a_volume_refuses_map_options() {
        let r = |options| BakeRequest {
            input: "a.vdb".into(),
            output: "t.vdb".into(),
            options,
        };
        let e = r(BakeOptions {
            light: crate::light::LightOptions {
                light_dir: Some([0.0, -1.0, 0.0]),
                light_pos: None,
                ..crate::light::LightOptions::default()
            },
            tile: Some(16),
            ..BakeOptions::default()
        })
        .plan()
        .unwrap_err();
        assert!(
            matches!(e, Error::InvalidArgument { ref name, .. } if name == "tile"),
            "{e}"
        );
        let ok = r(BakeOptions {
            light: crate::light::LightOptions {
                light_dir: Some([0.0, -1.0, 0.0]),
                light_pos: None,
                ..crate::light::LightOptions::default()
            },
            half: true,
            ..BakeOptions::default()
        })
        .plan()
        .unwrap();
        assert!(matches!(ok, BakePlan::Volume(ref v) if v.half));
    }

    /// Every flag clap derives from the type is a property of the job schema by the naming
    /// rule, and every property but the job's `framing` is a flag.
    #[cfg(all(feature = "cli", feature = "schema"))]
    #[test]
    fn every_flag_is_a_schema_property() {
        use clap::CommandFactory;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            options: BakeOptions,
        }
        let schema = serde_json::to_value(schemars::schema_for!(BakeOptions)).unwrap();
        let props = schema["properties"].as_object().unwrap();
        let flags: Vec<String> = Cli::command()
            .get_arguments()
            .filter_map(|a| a.get_long().map(|l| l.replace('-', "_")))
            .filter(|l| l != "help")
            .collect();
        for f in &flags {
            assert!(props.contains_key(f), "--{f} is not a schema property");
        }
        let mut keys: Vec<&String> = props.keys().filter(|k| *k != "framing").collect();
        keys.sort();
        let mut sorted: Vec<&String> = flags.iter().collect();
        sorted.sort();
        assert_eq!(keys, sorted);
    }

    #[cfg(feature = "cli")]
    #[test]
    fn cli_defaults_are_the_library_defaults() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            options: BakeOptions,
        }
        let parsed = Cli::try_parse_from(["umbra"]).unwrap();
        assert_eq!(parsed.options, BakeOptions::default());
    }
}

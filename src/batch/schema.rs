//! The job file: its types as written (`JobFile`, `[[inputs]]`, `[[lights]]`, `[bake]` as the
//! one [`BakeOptions`] type) and their JSON Schema. `parse.rs` checks a file of these types
//! into a [`super::Job`] of tasks.

use crate::request::BakeOptions;
use serde::Deserialize;

/// The job file as written. Its JSON Schema ([`job_schema`], `umbra batch --schema`) is
/// generated from this type.
#[derive(Debug, Clone, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct JobFile {
    /// Grid to bake in every input (default `density`; or `grid` in `[bake]`).
    pub grid: Option<String>,
    /// Output path pattern: `{light}`, `{stem}`, `{frame}`, `{frame:0N}`; ending in `.vdb`,
    /// transmittance volumes, else EXR maps. Required with `[[inputs]]`.
    pub output: Option<String>,
    /// JSON-lines log (default: `umbra_batch.jsonl` in the first output's directory).
    pub log: Option<String>,
    /// Inputs, in order (none for a job of `[[positions]]` only).
    #[serde(default)]
    pub inputs: Vec<InputSpec>,
    /// Per-point transmittance over a shot, one task per frame after the bakes.
    #[serde(default)]
    pub positions: Vec<super::positions::PositionsSpec>,
    /// Lights, in order (or one light as `light_dir` / `light_pos` in `[bake]`).
    #[serde(default)]
    pub lights: Vec<LightSpec>,
    /// The options of every bake: `umbra bake`'s, with the same names (`_` for `-`) and
    /// defaults ([`BakeOptions`]), plus `framing`.
    #[serde(default)]
    pub bake: BakeOptions,
}

/// The JSON Schema (draft 2020-12) of job files, generated from [`JobFile`] and
/// [`BakeOptions`]: what `umbra batch --schema` prints.
#[cfg(feature = "schema")]
#[must_use]
pub fn job_schema() -> serde_json::Value {
    let schema = schemars::generate::SchemaSettings::draft2020_12()
        .into_generator()
        .into_root_schema_for::<JobFile>();
    serde_json::to_value(schema).unwrap_or_default()
}

/// One `[[inputs]]` entry: `file`, or `pattern` with `frames`.
#[derive(Debug, Clone, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
// No serde `deny_unknown_fields`: the flattened map takes every other key, checked when the
// job is read (serde would refuse them before the map saw them). The schema still says no
// other key is allowed.
#[cfg_attr(feature = "schema", schemars(deny_unknown_fields))]
pub struct InputSpec {
    /// An explicit file.
    pub file: Option<String>,
    /// A sequence pattern: `####` (padding = number of `#`), `$F4` / `$F`, or `%04d` / `%d`.
    pub pattern: Option<String>,
    /// Inclusive frame range `[first, last]` of a pattern.
    pub frames: Option<[i64; 2]>,
    /// Frame step of a pattern (default 1).
    pub step: Option<i64>,
    /// A USD stage (`.usd`, `.usda`, `.usdc`, `.usdz`): its volumes at every frame of `frames`
    /// (time codes; without `frames`, its start time code).
    pub usd: Option<String>,
    /// How this entry's files are read, over `[bake]`'s: any read key
    /// ([`crate::input::SourceOptions`], declared there once): `grid` (default: the job's; a
    /// liquid's `phi` beside a smoke's `density` in one job), `density_scale`, `levelset`
    /// (`solid` traces its grid as an opaque occluder), `xform` (16 numbers, row-major),
    /// `interp`, `sigma_t`, `volume`, `field`, the motion keys. `frame` (give `frames`) and
    /// `light` (give `[[lights]]`) are refused by name.
    #[serde(flatten)]
    #[cfg_attr(feature = "schema", schemars(with = "crate::input::SourceOptions"))]
    pub read: serde_json::Map<String, serde_json::Value>,
}

/// One `[[lights]]` entry.
#[derive(Debug, Clone, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
#[serde(deny_unknown_fields)]
pub struct LightSpec {
    /// Name used by `{light}` (default for a `usd` light: the prim's name).
    pub name: Option<String>,
    /// Direction the light travels (directional light, orthographic map; with `pos`, where a
    /// perspective map from the light looks), as `umbra bake --light-dir`.
    pub dir: Option<[f64; 3]>,
    /// Light position (point light, perspective map), as `umbra bake --light-pos`.
    pub pos: Option<[f64; 3]>,
    /// A UsdLux light of the job's USD stage inputs, by prim path (as `umbra bake --light`),
    /// read at each task's frame.
    pub usd: Option<String>,
}

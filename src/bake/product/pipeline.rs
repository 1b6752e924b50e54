//! The one bake pipeline, shared by `umbra bake`, batch tasks, the Python module and library
//! callers (through [`crate::request::BakeRequest::run`], or [`BakeJob::run`] on a planned job):
//! check the outputs, plan (whole or in parts), load the grid, frame the camera, trace, encode,
//! commit the map, its preview and any other output of the request together, and report what a
//! user should be warned about. Progress goes to one [`Progress`] throughout.

use crate::bake::{bake_scene, BakeSettings, Camera, Map, Provenance, View};
use crate::error::{Error, Result};
use crate::output::{check_writable, Staged};
use crate::progress::{Progress, Silent, Work};
use crate::scene::{Scene, SceneOptions};
use crate::volume::Sanitized;
use std::path::PathBuf;

/// One bake from a file to an EXR map (and optionally a PNG preview).
#[derive(Debug, Clone, PartialEq)]
pub struct BakeJob {
    /// The `.vdb` file, or a `.toml` scene file ([`crate::scene::file`]).
    pub input: PathBuf,
    /// Grid to trace (a `.vdb` input).
    pub grid: String,
    /// `mu_t = density_scale x value` (multiplies a scene's own scales).
    pub density_scale: f64,
    /// Where the volume sits in the shot (world-from-object), applied after loading (after a
    /// scene's own transforms).
    pub xform: Option<crate::xform::Xform>,
    /// Extinction colour: an RGB map with `mu_c = sigma_t[c] x density_scale x value`.
    pub sigma_t: Option<[f64; 3]>,
    /// Trace a level-set grid of a `.vdb` input as an opaque solid (`--levelset solid`).
    pub levelset_solid: bool,
    /// What a USD stage input is read at (time code, volumes, field); ignored otherwise.
    pub stage: crate::usd::Selection,
    /// Camera request.
    pub view: View,
    /// A fixed camera (an earlier map's, or one shared by a sequence): used as it is instead
    /// of framing `view` on the volume box.
    pub camera: Option<Camera>,
    /// Sampling settings.
    pub settings: BakeSettings,
    /// The OpenEXR map.
    pub output: PathBuf,
    /// An 8-bit PNG preview of `T`.
    pub preview: Option<PathBuf>,
    /// Replace existing outputs.
    pub overwrite: bool,
    /// The EXR's layout: scanlines, or tiles with optional mip levels (`--tile`, `--mipmap`).
    pub layout: crate::bake::ExrLayout,
    /// A memory budget in bytes (`--max-memory`): when the decoded grid and the image would
    /// not fit in it, an exact map is swept a part of the grid at a time
    /// ([`BakeJob::plan_bounded`]); `None`: load the whole grid.
    pub max_memory: Option<u64>,
    /// What `output` holds: a flat map (the default) or a deep map.
    pub product: Product,
}

/// What a bake writes at its output.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Product {
    /// A flat OpenEXR map: `T` (or `R`, `G`, `B`), with slices and `T.stderr` when asked for,
    /// in scanlines or tiles ([`BakeJob::layout`]).
    #[default]
    Map,
    /// A deep scanline OpenEXR map ([`crate::bake::bake_deep`]): the transmittance function along
    /// every pixel's ray within `max_error` in T at every depth (`--deep`, `--deep-error`).
    Deep {
        /// The bound `E` on `|T_deep(z) - T(z)|`.
        max_error: f64,
    },
    /// A flat OpenEXR map with the transmittance function of every pixel in a fixed number of
    /// channels ([`crate::bake::bake_fixed`]; `--deep-format`), next to `T`.
    Fixed {
        /// The encoding.
        format: crate::bake::DeepFormat,
    },
}

/// Something a finished bake wants its user to know.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Warning {
    /// NaN or negative voxels were traced as 0 (the bad-voxel policy).
    BadVoxels {
        /// NaN values.
        nan: u64,
        /// Negative values.
        negative: u64,
    },
    /// Samples stopped at the collision cap: those pixels are biased.
    Capped {
        /// Samples stopped.
        samples: u64,
    },
    /// Lookups outside their segment's bounds: the tree's majorants are wrong.
    MajorantViolations {
        /// Lookups outside the bounds.
        lookups: u64,
    },
    /// Every pixel lets more than 99% through: the density scale is probably far too small.
    NearlyEmpty {
        /// Smallest T of the map.
        t_min: f64,
        /// A density scale that would give the densest pixel an optical depth of about 2.
        suggested_scale: f64,
    },
    /// The volume box reaches outside the camera's window (a reused camera framed on another
    /// box): density there is not in the map ([`Camera::outside`]).
    OutsideCamera {
        /// How far, in pixels beyond the window's edge (`inf`: behind a perspective light).
        pixels: f64,
        /// How far, in world units.
        world: f64,
    },
    /// No pixel lets 1% through: the density scale is probably far too large.
    NearlyBlack {
        /// Largest T of the map.
        t_max: f64,
        /// A density scale that would give the clearest pixel an optical depth of about 1.
        suggested_scale: f64,
    },
    /// A level set traced as a solid has a background of 0: outside its narrow band the field
    /// reads as on the surface (Blender writes liquids so). Traced as outside (a hit needs
    /// `phi < 0`), which is right when the band holds the whole surface.
    SolidBackground {
        /// The grid.
        grid: String,
        /// Its background.
        background: f64,
    },
    /// The field of view given crops the volume box: density outside it is not in the map.
    CroppedByFov {
        /// The field of view, degrees.
        fov_deg: f64,
        /// How far the box reaches outside the window, pixels (`inf`: behind the light).
        pixels: f64,
    },
    /// `max_memory` was given for a bake that does not go in parts (a colour map or a scene
    /// file loads whole): the budget was not honoured.
    MemoryBudgetIgnored {
        /// What loads whole.
        what: &'static str,
    },
}

impl std::fmt::Display for Warning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Self::SolidBackground {
                ref grid,
                background,
            } => write!(
                f,
                "level set '{}' has background {background}: outside its narrow band it reads \
                 as on the surface; traced as outside (a hit needs phi < 0)",
                crate::text::escape(grid)
            ),
            Self::CroppedByFov { fov_deg, pixels } => write!(
                f,
                "--fov {fov_deg} crops the volume: its box reaches {pixels:.1} pixels outside \
                 the window, and density there is not in the map (drop --fov to frame it whole)"
            ),
            Self::MemoryBudgetIgnored { what } => write!(
                f,
                "--max-memory is not honoured: {what} load whole (the budget applies to maps of \
                 one grey grid)"
            ),
            Self::BadVoxels { nan, negative } => {
                write!(f, "{nan} NaN and {negative} negative values treated as 0")
            }
            Self::Capped { samples } => {
                write!(f, "{samples} samples hit the collision cap (biased)")
            }
            Self::MajorantViolations { lookups } => write!(
                f,
                "{lookups} lookups exceeded their majorant (the estimate is biased; please report)"
            ),
            Self::NearlyEmpty {
                t_min,
                suggested_scale,
            } => write!(
                f,
                "the map is almost empty (every T >= {t_min:.4}); try --density-scale \
                 {suggested_scale:.2e}"
            ),
            Self::OutsideCamera { pixels, world } if pixels.is_infinite() => write!(
                f,
                "the volume box reaches behind the camera's light (world distance {world}): \
                 density there is not in the map"
            ),
            Self::OutsideCamera { pixels, world } => write!(
                f,
                "the volume box reaches {pixels:.1} pixels ({world:.4} world units) outside the \
                 camera's window: density there is not in the map; frame the camera on a box \
                 that holds every frame"
            ),
            Self::NearlyBlack {
                t_max,
                suggested_scale,
            } => write!(
                f,
                "the map is almost black (every T <= {t_max:.2e}); try --density-scale \
                 {suggested_scale:.2e}"
            ),
        }
    }
}

/// The map-level warnings: almost empty (`min T > 0.99`) or almost black (`max T < 0.01`),
/// with a suggested density scale `s'`. From the map itself when it can: the densest pixel has
/// `tau_max = -ln(min T)` at scale `s`, so `s' = 2 s / tau_max` gives it `tau = 2` (and
/// `s' = s / tau_min` gives the clearest pixel of a black map `tau = 1`); when the map holds no
/// such information (T exactly 1 or 0 everywhere), from the grid's largest value `v_max` and
/// the volume box diagonal `D`: `s' = 2 / (v_max D)`.
#[must_use]
pub fn map_warnings(map: &Map, density_scale: f64, v_max: f64, diagonal: f64) -> Vec<Warning> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for &t in map.t.iter().filter(|t| !t.is_nan()) {
        lo = lo.min(f64::from(t));
        hi = hi.max(f64::from(t));
    }
    if !lo.is_finite() {
        return Vec::new();
    }
    let fallback = || {
        let d = v_max * diagonal;
        if d > 0.0 && d.is_finite() {
            2.0 / d
        } else {
            1.0
        }
    };
    let mut out = Vec::new();
    if lo > 0.99 {
        let tau_max = -lo.ln();
        let suggested_scale = if tau_max > 0.0 && density_scale > 0.0 {
            2.0 * density_scale / tau_max
        } else {
            fallback()
        };
        out.push(Warning::NearlyEmpty {
            t_min: lo,
            suggested_scale,
        });
    } else if hi < 0.01 {
        let tau_min = -hi.ln();
        let suggested_scale = if tau_min.is_finite() && tau_min > 0.0 {
            density_scale / tau_min
        } else {
            fallback()
        };
        out.push(Warning::NearlyBlack {
            t_max: hi,
            suggested_scale,
        });
    }
    out
}

/// Warnings about a scene's solids: a level set whose background is 0
/// ([`Warning::SolidBackground`]; a negative one is refused when it is loaded).
#[must_use]
pub fn solid_warnings(scene: &Scene) -> Vec<Warning> {
    scene
        .solids()
        .iter()
        .filter(|s| s.background() == 0.0)
        .map(|s| Warning::SolidBackground {
            grid: s.name().to_string(),
            background: s.background(),
        })
        .collect()
}

/// Warnings about a volume's bad voxels.
#[must_use]
pub fn volume_warnings(s: &Sanitized) -> Vec<Warning> {
    if s.nan + s.negative > 0 {
        vec![Warning::BadVoxels {
            nan: s.nan,
            negative: s.negative,
        }]
    } else {
        Vec::new()
    }
}

/// What a finished bake produced.
#[derive(Debug, Clone)]
pub struct BakeReport {
    /// The map as written.
    pub map: Map,
    /// Where it came from (as in the EXR header).
    pub provenance: Provenance,
    /// Things the user should be told, in order.
    pub warnings: Vec<Warning>,
    /// The deep map's counts, for [`Product::Deep`].
    pub deep: Option<crate::bake::DeepStats>,
    /// The fixed-size deep map's counts and errors, for [`Product::Fixed`].
    pub fixed: Option<crate::bake::FixedStats>,
}

/// The step of a bake a failure stopped it at ([`BakeError`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// Checking the request: its options, its outputs (writable, not clobbered) and its
    /// settings. Nothing but a reused camera's file was read.
    Check,
    /// Reading the input: the grid (or a scene, a stage's volumes, the topology of a bake in
    /// parts) and framing the camera on it.
    Load,
    /// Tracing, encoding and committing the outputs.
    Bake,
}

/// A bake that failed: the library's error, the [`Step`] it stopped at, and for a load, the
/// context a user reads it in (`loading grid 'density'`, `loading the scene`). Displayed as
/// `context: error`, the line `umbra bake` prints and the Python module raises.
#[derive(Debug)]
pub struct BakeError {
    /// Where the bake stopped.
    pub step: Step,
    /// What was being loaded, for a load error that is not about an argument or an output.
    pub context: Option<String>,
    /// The error.
    pub error: Error,
}

impl BakeError {
    /// `error` at `step`, without context.
    #[must_use]
    pub fn at(step: Step, error: Error) -> Self {
        Self {
            step,
            context: None,
            error,
        }
    }

    /// A load error of `input` (grid `grid`): in the context of loading it, unless it is about
    /// an argument or an output, which speak for themselves.
    #[must_use]
    pub fn loading(input: &std::path::Path, grid: &str, error: Error) -> Self {
        let context = match error {
            Error::Output { .. } | Error::Exists { .. } | Error::InvalidArgument { .. } => None,
            _ if crate::input::InputKind::of(input).is_scene_file() => {
                Some("loading the scene".to_string())
            }
            _ => Some(format!("loading grid '{grid}'")),
        };
        Self {
            step: Step::Load,
            context,
            error,
        }
    }

    /// The failure with its library error worded by a front end (`f`: an option as its user
    /// types it, an existing output with how to replace it); step and context unchanged.
    #[must_use]
    pub fn worded(self, f: impl FnOnce(Error) -> Error) -> Self {
        Self {
            error: f(self.error),
            ..self
        }
    }
}

impl std::fmt::Display for BakeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.context {
            Some(c) => write!(f, "{c}: {}", self.error),
            None => write!(f, "{}", self.error),
        }
    }
}

impl std::error::Error for BakeError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        Some(&self.error)
    }
}

/// A traced product before it is staged: its report and, for a deep product, its encoded
/// bytes (a flat map is encoded when staged, after the scene is dropped).
struct Traced {
    report: BakeReport,
    bytes: Option<Vec<u8>>,
}

impl BakeJob {
    /// Check every output before any work: writable directory, no clobbering without
    /// `overwrite`, the map and the preview distinct.
    ///
    /// # Errors
    /// [`crate::Error::Output`] naming the file.
    pub fn check_outputs(&self) -> Result<()> {
        for p in std::iter::once(&self.output).chain(&self.preview) {
            if p.as_os_str() == "-" {
                return Err(Error::Output {
                    path: p.clone(),
                    reason: "writing a map or preview to standard output is not supported; give \
                             a file name"
                        .into(),
                });
            }
        }
        self.layout.validate()?;
        if let Product::Deep { max_error } = self.product {
            crate::bake::check_deep_error(max_error)?;
        }
        if self.product != Product::Map {
            let flat_only = |flag: &str, what: &str| Error::InvalidArgument {
                name: flag.into(),
                reason: format!(
                    "{what} belongs to flat maps; a deep map holds the whole transmittance \
                     function of every pixel"
                ),
            };
            if self.layout.tile.is_some() || self.layout.mipmap {
                return Err(flat_only(
                    "tile",
                    "a tiled layout (deep maps are written as scanlines)",
                ));
            }
            if self.settings.depths != crate::bake::Depths::None {
                return Err(flat_only("slices", "--slices/--depths"));
            }
            if self.settings.std_err {
                return Err(flat_only("stderr", "the T.stderr channel"));
            }
            if self.max_memory.is_some() {
                return Err(flat_only(
                    "max-memory",
                    "baking in parts under a memory budget",
                ));
            }
        }
        check_writable(&self.output, self.overwrite)?;
        check_extension(&self.output, "exr", "output", "a map is written as OpenEXR")?;
        if let Some(p) = &self.preview {
            check_writable(p, self.overwrite)?;
            check_extension(p, "png", "preview", "the preview is written as PNG")?;
            if crate::output::same_file(p, &self.output) {
                return Err(Error::Output {
                    path: p.clone(),
                    reason: "the preview and the map are the same file".into(),
                });
            }
        }
        Ok(())
    }

    /// Run the bake, every step of it: check the outputs and settings, plan (whole, or in parts
    /// under a memory budget: [`BakeJob::plan_bounded`]), load, trace, encode, and commit the
    /// map and its preview together. `progress` is told the work's units when they are known
    /// ([`Work`]: pixels, pixels in parts, or a deep product's passes by cost) and receives
    /// finished units from worker threads.
    ///
    /// # Errors
    /// Output, load, framing, settings and write errors; nothing is written on error.
    pub fn run(&self, progress: &dyn Progress) -> Result<BakeReport> {
        self.run_with(progress, &|_| Ok(Vec::new()))
            .map_err(|e| e.error)
    }

    /// [`BakeJob::run`], each failure with the [`Step`] it stopped at; `extra` stages more
    /// outputs from the finished report (a request's USD layer), committed with the map.
    pub(crate) fn run_with(
        &self,
        progress: &dyn Progress,
        extra: &dyn Fn(&BakeReport) -> Result<Vec<Staged>>,
    ) -> std::result::Result<BakeReport, BakeError> {
        let check = |e| BakeError::at(Step::Check, e);
        self.check_outputs().map_err(check)?;
        self.settings.validate().map_err(check)?;
        let load = |e| BakeError::loading(&self.input, &self.grid, e);
        let bake = |e| BakeError::at(Step::Bake, e);
        let traced = match self.plan_bounded().map_err(load)? {
            Some(plan) => self.trace_bounded(plan, progress).map_err(bake)?,
            None => {
                let (scene, camera) = self.prepare().map_err(load)?;
                // The scene is dropped before encoding: peak memory is the trees plus the image.
                self.trace(&scene, camera, progress).map_err(bake)?
            }
        };
        self.commit(traced, extra).map_err(bake)
    }

    /// What `progress` is told a bake of `pixels` pixels is: the pixels of each pass in
    /// proportion to its cost. A flat map counts its pixels; a deep product its deep pass's
    /// pixels (and, for a fixed-size format, an eighth more for the second pass that refines its
    /// error bound), plus the flat pass's pixels for a stochastic estimator (whose flat pass
    /// traces the 64 slices; an exact map's flat pass is a few per cent of its deep pass and not
    /// counted).
    fn work(&self, pixels: u64) -> Work {
        let deep = match self.product {
            Product::Map => {
                return Work {
                    units: pixels,
                    what: "baking",
                    unit: Some("px"),
                }
            }
            Product::Deep { .. } => pixels,
            Product::Fixed { .. } => super::fixed_map::fixed_units(pixels),
        };
        let units = if self.settings.estimator == crate::estimate::Estimator::REGULAR {
            deep
        } else {
            pixels + deep
        };
        Work {
            units,
            what: "baking",
            unit: (units == pixels).then_some("px"),
        }
    }

    /// Stage the traced map's outputs (its EXR, the preview) and `extra`'s, and commit them all
    /// together.
    fn commit(
        &self,
        traced: Traced,
        extra: &dyn Fn(&BakeReport) -> Result<Vec<Staged>>,
    ) -> Result<BakeReport> {
        let mut staged = match &traced.bytes {
            Some(bytes) => crate::bake::encode::exr::stage_with_preview(
                &self.output,
                bytes,
                self.preview.as_deref(),
                &traced.report.map,
                self.overwrite,
            )?,
            None => crate::bake::encode::exr::stage_map(
                &self.output,
                self.preview.as_deref(),
                &traced.report.map,
                &traced.report.provenance,
                &self.layout,
                self.overwrite,
            )?,
        };
        staged.extend(extra(&traced.report)?);
        crate::output::commit_all(staged)?;
        Ok(traced.report)
    }

    /// With a memory budget ([`BakeJob::max_memory`]) that the whole decoded grid and the
    /// image would exceed: the plan of a bake in parts (the grid opened lazily, the camera
    /// framed from its topology, how big a part may be). Without a budget, an exact map the
    /// sweep takes of an input of 64 MiB or more on disk is planned against
    /// [`IMPLIED_BUDGET`] (1 GiB): a hero cache is swept a region at a time, never held
    /// whole. `None` when everything fits (or, without a budget, when the map is not such a
    /// sweep, a deep product, or one part would not fit): [`BakeJob::run`] then loads the
    /// whole grid ([`BakeJob::prepare`]).
    ///
    /// The budget counts the topology (kept while the parts come and go), the image and one
    /// part; the process's own code and stacks are outside it. Exact trilinear maps the sweep
    /// takes go in the sweep's order, a region of the tree at a time (`sweep::render_streamed`:
    /// a part holds the lower nodes its blocks read, their leaves' topology and the values of
    /// the leaves it decodes); every other map of one grid (any estimator, nearest lookups,
    /// extinction above lower nodes) goes by runs of image rows on the ray path, each run
    /// decoding the leaves its pixel rays touch onto a copy of the topology. Scene files and
    /// colour maps load whole.
    ///
    /// # Errors
    /// Output and settings errors; [`Error::InvalidArgument`] (name `max-memory`) when the
    /// budget is below the least a part needs (for the ray path an estimate: a run of rows
    /// whose rays touch more leaves than a part holds is baked as one part all the same);
    /// loading errors of the topology.
    pub fn plan_bounded(&self) -> Result<Option<BoundedPlan>> {
        let implied = self.max_memory.is_none();
        let budget = match self.max_memory {
            Some(b) => b,
            // Without a budget, big caches the sweep takes go in parts all the same
            // ([`IMPLIED_BUDGET`]); the size on disk is the cheap first test.
            None if self.product == Product::Map
                && self.is_exact_sweep()
                && file_len(&self.input) >= IMPLIED_MIN_FILE =>
            {
                IMPLIED_BUDGET
            }
            None => return Ok(None),
        };
        self.check_outputs()?;
        self.settings.validate()?;
        let refuse = |reason: String| Error::InvalidArgument {
            name: "max-memory".into(),
            reason,
        };
        if crate::input::InputKind::of(&self.input).is_scene_file() || self.sigma_t.is_some() {
            // Scenes and colour maps load whole; fine if they fit, refused otherwise below.
            return Ok(None);
        }
        let file = crate::input::GridFile::open(&self.input)?;
        let Some(mut lazy) = file.lazy(&self.grid)? else {
            // A format without partial reads loads whole, as scenes do.
            return Ok(None);
        };
        // Opening held the grid's head and topology bytes as read from the file beside the
        // tree they became, and the leaf buffers' offsets twice (as the file's delayed-load
        // table and as the lazy grid keeps them).
        let head_bytes = lazy.head_bytes();
        // The topology is kept once, in the shell volume.
        let loaded = lazy.loaded_memory_bytes();
        let leaves = lazy.leaf_count() as u64;
        let topology = lazy.shell().tree.memory_bytes();
        let shell = Scene::from_volume(self.volume_of(lazy.take_shell())?);
        let (camera, depth_shift) = match self.camera {
            Some(c) => c.covering(&shell.box_corners()?),
            None => (Camera::frame(&self.view, &shell.box_corners()?)?, 0.0),
        };
        let depth_images = match &self.settings.depths {
            crate::bake::Depths::None => 0,
            crate::bake::Depths::Slices(k) => *k as u64,
            crate::bake::Depths::At(d) => d.len() as u64,
        };
        // T (f32) and the f64 optical depth of every pixel, per slice too.
        let image = camera.pixels() * (1 + depth_images) * 12;
        // The whole grid, the image and the process itself.
        let whole = loaded + image + PROCESS_SLACK;
        if whole <= budget {
            return Ok(None);
        }
        // Exact trilinear maps the sweep takes go in tree order (the sweep's own order);
        // every other map by runs of image rows on the ray path.
        let sweep = match shell.fogs().first() {
            Some(f) => {
                (self.is_exact_sweep() || self.is_march_sweep())
                    && crate::bake::trace::sweep::streams(f.volume(), &camera)?
            }
            None => false,
        };
        if implied && !sweep {
            // Only the sweep goes in parts at no cost in time: the rest loads whole.
            return Ok(None);
        }
        // A random march swept in parts keeps every sample's optical depths of every pixel
        // until the last part (the whole bake keeps a band's at a time).
        let samples = crate::bake::trace::sweep::marches(&self.settings).map_or(1, |m| m.samples());
        let samples_image = camera.pixels() * (1 + depth_images) * 8 * (samples as u64 - 1);
        let Some(topo) = shell.fogs().first().map(|f| f.volume().tree()) else {
            return Ok(None);
        };
        // Held throughout: the topology (in the shell volume), the image and the process.
        let offsets = (lazy.leaf_count() as u64 + 1) * 8;
        let held = topology + offsets + image + PROCESS_SLACK;
        let opening = topology + head_bytes + 2 * offsets + PROCESS_SLACK;
        let z = Sizes {
            budget,
            whole,
            held,
            opening,
            loaded,
            leaves,
            samples_image,
        };
        let mut sweep = sweep;
        let (least, what, group_leaves, part_bytes) = if sweep {
            let p = sweep_part(topo, &z);
            if samples > 1 && budget < p.0 {
                // A random march whose samples do not fit beside a part goes by rows on the
                // ray path: the same estimate to the kernel's f32 positions (docs/loading.md).
                sweep = false;
                ray_part(topo, &z)
            } else {
                p
            }
        } else {
            ray_part(topo, &z)
        };
        if budget < least && implied {
            return Ok(None);
        }
        if budget < least {
            return Err(refuse(format!(
                "{} is below what baking {} needs: at least {} in parts (its topology, the \
                 image, {what}; opening it takes {}; the whole grid and the image need {})",
                mib(budget),
                self.input.display(),
                mib(least),
                mib(opening),
                mib(whole)
            )));
        }
        Ok(Some(BoundedPlan {
            lazy,
            shell,
            camera,
            depth_shift,
            group_leaves,
            part_bytes,
            sweep,
        }))
    }

    /// Bake a `BoundedPlan`: the map the whole-grid bake would make, bit for bit, holding a
    /// part of the grid at a time. The sweep reports the bad voxels of the leaves its parts
    /// decoded (each leaf once: every leaf of a map that frames the whole grid) and of the
    /// tiles; the ray path those of the tiles only (its runs overlap).
    ///
    /// # Errors
    /// As [`BakeJob::run`].
    fn trace_bounded(&self, plan: BoundedPlan, progress: &dyn Progress) -> Result<Traced> {
        progress.start(&Work {
            units: plan.camera.pixels(),
            what: "baking in parts",
            unit: Some("px"),
        });
        let volume_of = |g: crate::vdb::Grid| self.volume_of(g);
        let Some(shell) = plan.shell.fogs().first().map(crate::scene::Fog::volume) else {
            return Err(Error::Invalid {
                path: self.input.clone(),
                reason: "the grid's shell is not a fog volume".into(),
            });
        };
        let settings = self.settings_shifted(plan.depth_shift);
        let (map, leaves) = if plan.sweep {
            let baked = crate::bake::trace::bake_streamed(
                &plan.lazy,
                shell,
                &volume_of,
                &plan.camera,
                &settings,
                plan.part_bytes,
                progress,
            )?;
            let Some((map, streamed)) = baked else {
                return Err(Error::InvalidArgument {
                    name: "max-memory".into(),
                    reason: format!(
                        "{} does not fit and this map cannot be swept in parts",
                        self.input.display()
                    ),
                });
            };
            (map, streamed.sanitized)
        } else {
            let load = |ids: &[u32]| self.volume_of(plan.lazy.load_from(shell.tree(), ids)?);
            let (mut map, parts) = crate::bake::trace::bake_rows_streamed(
                shell,
                &load,
                &plan.camera,
                &settings,
                plan.group_leaves,
                progress,
            )?;
            map.stats.parts = parts;
            (map, crate::volume::Sanitized::default())
        };
        let report = self.describe_with(map, &plan.shell, plan.camera, leaves);
        Ok(Traced {
            report,
            bytes: None,
        })
    }

    /// Whether this job's map is one the sweep makes: exact regular tracking with trilinear
    /// lookups, in the automatic order.
    fn is_exact_sweep(&self) -> bool {
        self.settings.estimator == crate::estimate::Estimator::REGULAR
            && self.settings.options.interp == crate::volume::Interp::Trilinear
            && self.settings.order == crate::bake::Order::Auto
    }

    /// Whether this job's map is a ray march the sweep makes (`riemann`, `jittered`, `mc` with
    /// trilinear lookups and a fixed sample count, in the automatic order).
    fn is_march_sweep(&self) -> bool {
        self.settings.order == crate::bake::Order::Auto
            && crate::bake::trace::sweep::marches(&self.settings).is_some()
    }

    /// The grid `g` of the input as this job traces it (density scale, transform).
    fn volume_of(&self, g: crate::vdb::Grid) -> Result<crate::Volume> {
        let mut v = crate::Volume::new(g, self.density_scale, &self.input)?;
        if let Some(x) = &self.xform {
            v = v.with_xform(x)?;
        }
        Ok(v)
    }

    /// Everything before the bake of a whole grid, in the order that fails fastest: check the
    /// outputs and the settings, load the grid, frame the camera. [`BakeJob::run`] does this
    /// when [`BakeJob::plan_bounded`] finds no parts; callers that keep the scene (to bake it
    /// again with [`BakeJob::run_loaded`]) call it themselves.
    ///
    /// # Errors
    /// Output, settings, load and framing errors.
    pub fn prepare(&self) -> Result<(Scene, Camera)> {
        self.check_outputs()?;
        self.settings.validate()?;
        let scene = crate::scene::load(&self.input, &self.scene_options())?;
        let camera = match self.camera {
            Some(c) => c,
            None => Camera::frame(&self.view, &scene.box_corners()?)?,
        };
        Ok((scene, camera))
    }

    /// How [`BakeJob::prepare`] reads the input.
    #[must_use]
    pub fn scene_options(&self) -> SceneOptions {
        SceneOptions {
            grid: self.grid.clone(),
            density_scale: self.density_scale,
            sigma_t: self.sigma_t,
            xform: self.xform,
            levelset_solid: self.levelset_solid,
            stage: self.stage.clone(),
        }
    }

    /// [`BakeJob::run`] on a scene already loaded, kept by the caller (the Python module's
    /// `Volume`; a single volume: [`Scene::from_volume`]) and a camera already framed
    /// (`input`, `grid` and `density_scale` are then only recorded in the header): bake and
    /// write the job's product (flat or deep map, and the preview) from `scene` seen by
    /// `camera`.
    ///
    /// # Errors
    /// As [`BakeJob::run`].
    pub fn run_loaded(
        &self,
        scene: &Scene,
        camera: Camera,
        progress: &dyn Progress,
    ) -> Result<BakeReport> {
        self.check_outputs()?;
        let traced = self.trace(scene, camera, progress)?;
        self.commit(traced, &|_| Ok(Vec::new()))
    }

    /// The traced product of `scene` seen by `camera`: a flat map's report (encoded when it
    /// is staged), or a deep product's report and bytes. Tells `progress` the work first.
    fn trace(&self, scene: &Scene, camera: Camera, progress: &dyn Progress) -> Result<Traced> {
        progress.start(&self.work(camera.pixels()));
        if self.product != Product::Map {
            return self.deep_product(scene, camera, progress);
        }
        let (camera, settings) = self.aimed(scene, camera);
        let map = bake_scene(scene, &camera, &settings, progress)?;
        Ok(Traced {
            report: self.describe(map, scene, camera),
            bytes: None,
        })
    }

    /// The camera and settings `scene` is traced with: `camera`'s ray range extended to the
    /// scene's box ([`Camera::covering`]: a reused camera never cuts density off), and depths
    /// given explicitly moved with a ray start that moved back, so every slice stays at the
    /// world point it was asked for. A camera that covers the box comes back unchanged.
    fn aimed(&self, scene: &Scene, camera: Camera) -> (Camera, BakeSettings) {
        let Ok(corners) = scene.box_corners() else {
            return (camera, self.settings.clone());
        };
        let (camera, delta) = camera.covering(&corners);
        (camera, self.settings_shifted(delta))
    }

    /// The settings with explicit depths moved `delta` further along the rays.
    fn settings_shifted(&self, delta: f64) -> BakeSettings {
        let mut settings = self.settings.clone();
        if let crate::bake::Depths::At(d) = &mut settings.depths {
            if delta > 0.0 {
                d.iter_mut().for_each(|z| *z += delta);
            }
        }
        settings
    }

    /// A deep product ([`Product::Deep`] or [`Product::Fixed`]) of `scene` seen by `camera`,
    /// encoded. The flat map is traced first: with regular tracking as asked, and a
    /// stochastic estimator's with the [`crate::bake::STOCHASTIC_DEPTHS`] slices its deep
    /// function comes from (removed from the written map); then the deep pass. `progress`
    /// counts both as [`BakeJob::work`] says.
    fn deep_product(
        &self,
        scene: &Scene,
        camera: Camera,
        progress: &dyn Progress,
    ) -> Result<Traced> {
        let exact = self.settings.estimator == crate::estimate::Estimator::REGULAR;
        let (camera, settings) = self.aimed(scene, camera);
        let mut map = if exact {
            bake_scene(scene, &camera, &settings, &Silent)?
        } else {
            let settings = BakeSettings {
                depths: crate::bake::Depths::Slices(crate::bake::STOCHASTIC_DEPTHS),
                ..settings
            };
            bake_scene(scene, &camera, &settings, progress)?
        };
        let (deep, fixed) = match self.product {
            Product::Deep { max_error } => (
                Some(crate::bake::bake_deep(scene, &map, max_error, progress)?),
                None,
            ),
            Product::Fixed { format } => (
                None,
                Some(crate::bake::bake_fixed(scene, &map, format, progress)?),
            ),
            Product::Map => (None, None),
        };
        map.settings.depths = crate::bake::Depths::None;
        map.depths.clear();
        map.slices.clear();
        if let Some(gb) = &mut map.color {
            for ch in gb.iter_mut() {
                ch.slices.clear();
            }
        }
        let mut report = self.describe(map, scene, camera);
        let bytes = if let Some(deep) = deep {
            let attrs = crate::bake::deep_attributes(&report.map, &report.provenance, &deep.stats);
            report.deep = Some(deep.stats);
            Some(crate::bake::encode_deep_exr(&deep.image, &attrs))
        } else if let Some(fixed) = fixed {
            let attrs = super::fixed_map::fixed_attributes(&fixed.stats);
            report.fixed = Some(fixed.stats);
            let bytes = crate::bake::encode::exr::encode_exr_with(
                &report.map,
                &report.provenance,
                &self.layout,
                fixed.planes,
                attrs,
            )
            .map_err(|e| Error::Output {
                path: self.output.clone(),
                reason: e,
            })?;
            Some(bytes)
        } else {
            None
        };
        Ok(Traced { report, bytes })
    }

    /// The map of `scene` seen by `camera`, in memory: nothing is read from `input` or
    /// written to `output` (which only name the map's source in its provenance). What the
    /// Python module's `Volume.bake` runs on a volume it holds.
    ///
    /// # Errors
    /// Settings errors; tracing errors.
    pub fn bake_in_memory(
        &self,
        scene: &Scene,
        camera: Camera,
        progress: &dyn Progress,
    ) -> Result<BakeReport> {
        self.settings.validate()?;
        progress.start(&Work {
            units: camera.pixels(),
            what: "baking",
            unit: Some("px"),
        });
        let (camera, settings) = self.aimed(scene, camera);
        let map = bake_scene(scene, &camera, &settings, progress)?;
        Ok(self.describe(map, scene, camera))
    }

    /// The warnings and the provenance of a finished map.
    fn describe(&self, map: Map, scene: &Scene, camera: Camera) -> BakeReport {
        self.describe_with(map, scene, camera, crate::volume::Sanitized::default())
    }

    /// [`BakeJob::describe`], counting `leaves` with the scene's bad voxels.
    fn describe_with(
        &self,
        map: Map,
        scene: &Scene,
        camera: Camera,
        leaves: crate::volume::Sanitized,
    ) -> BakeReport {
        let mut warnings = volume_warnings(&scene.sanitized().merged(leaves));
        warnings.extend(solid_warnings(scene));
        if self.max_memory.is_some() {
            if crate::input::InputKind::of(&self.input).is_scene_file() {
                warnings.push(Warning::MemoryBudgetIgnored {
                    what: "scene files",
                });
            } else if self.sigma_t.is_some() {
                warnings.push(Warning::MemoryBudgetIgnored {
                    what: "colour maps (--sigma-t)",
                });
            }
        }
        let diagonal = scene.box_corners().map_or(0.0, |c| {
            let (lo, hi) = c.iter().fold(
                (glam::DVec3::INFINITY, glam::DVec3::NEG_INFINITY),
                |(lo, hi), p| (lo.min(*p), hi.max(*p)),
            );
            (hi - lo).length()
        });
        // The map warnings speak of the density scale: a scene's largest extinction is
        // expressed per unit of it.
        let v_max = if self.density_scale > 0.0 {
            scene.mu_max() / self.density_scale
        } else {
            0.0
        };
        if scene.solids().is_empty() {
            warnings.extend(map_warnings(&map, self.density_scale, v_max, diagonal));
        }
        // Framed here, a camera holds the whole box unless a frame box or a field of view
        // crops it (a frame box on purpose; a field of view is said, it may not be); a reused
        // camera may not.
        if self.view.frame_box.is_none() {
            if let Some(o) = scene
                .box_corners()
                .ok()
                .and_then(|c| map.camera.outside(&c))
            {
                warnings.push(match self.view.fov_deg {
                    Some(fov_deg) => Warning::CroppedByFov {
                        fov_deg,
                        pixels: o.pixels,
                    },
                    None => Warning::OutsideCamera {
                        pixels: o.pixels,
                        world: o.world,
                    },
                });
            }
        }
        // The light as given; for a fixed camera without one, the light its rays come from.
        let (mut light_dir, mut light_pos) = (self.view.light_dir, self.view.light_pos);
        if light_dir.is_none() && light_pos.is_none() {
            match camera.kind() {
                crate::bake::Projection::Ortho => light_dir = Some(camera.direction()),
                _ => light_pos = Some(camera.origin()),
            }
        }
        let provenance = Provenance {
            source_file: self.input.display().to_string(),
            grid: scene.grid_names(),
            density_scale: self.density_scale,
            light_dir,
            light_pos,
            xform: self.xform.map(|x| x.rows()),
            sigma_t: self.sigma_t,
        };
        if map.stats.capped > 0 {
            warnings.push(Warning::Capped {
                samples: map.stats.capped,
            });
        }
        if map.stats.majorant_violations > 0 {
            warnings.push(Warning::MajorantViolations {
                lookups: map.stats.majorant_violations,
            });
        }
        BakeReport {
            map,
            provenance,
            warnings,
            deep: None,
            fixed: None,
        }
    }
}

/// Bytes per leaf that computing a tree's bounds holds for a moment (a leaf's halo with its
/// neighbour table, its bounds, its faces on the way), counted against `--max-memory`.
const BOUNDS_SCRATCH_PER_LEAF: u64 = 96;
/// The budget a bake without `--max-memory` takes when its map is one the sweep makes in
/// parts: a grid whose decoded size (with the image) passes it is swept a region at a time,
/// at about the whole bake's speed, instead of being held whole. A larger `--max-memory`
/// loads it whole.
pub const IMPLIED_BUDGET: u64 = 1 << 30;
/// Inputs smaller than this on disk are loaded whole without a budget (no topology is read
/// twice for them); a grid that decodes to more than [`IMPLIED_BUDGET`] is far larger.
const IMPLIED_MIN_FILE: u64 = 64 << 20;

/// The size of `path` on disk (0 when it cannot be read: the load reports that).
fn file_len(path: &std::path::Path) -> u64 {
    std::fs::metadata(path).map_or(0, |m| m.len())
}

/// What the process takes besides its data (code, thread stacks, allocator), counted against
/// `--max-memory`.
const PROCESS_SLACK: u64 = 24 << 20;

/// A bake in parts, planned by [`BakeJob::plan_bounded`].
#[derive(Debug)]
pub struct BoundedPlan {
    lazy: crate::vdb::LazyGrid,
    /// The grid's shell as a scene: boxes and names for framing and the header.
    shell: Scene,
    camera: Camera,
    /// How far the camera's ray start moved back to cover the grid ([`Camera::covering`]).
    depth_shift: f64,
    /// Ray path: most leaves a run of rows decodes.
    group_leaves: usize,
    /// Sweep: most bytes a part's region holds.
    part_bytes: u64,
    /// In tree order by the sweep (exact maps it takes), else by runs of rows on the ray path.
    sweep: bool,
}

impl BoundedPlan {
    /// The camera the map is baked with.
    #[must_use]
    pub fn camera(&self) -> &Camera {
        &self.camera
    }
}

/// `path` must end in `.ext` (any case): an output of the wrong format is refused before any
/// work, naming the flag.
pub(super) fn check_extension(
    path: &std::path::Path,
    ext: &str,
    flag: &str,
    what: &str,
) -> Result<()> {
    let ok = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case(ext));
    if ok {
        return Ok(());
    }
    Err(Error::InvalidArgument {
        name: flag.into(),
        reason: format!(
            "{}: {what}; give a file name ending in .{ext}",
            path.display()
        ),
    })
}

/// A size in MiB, as the refusals word it.
fn mib(b: u64) -> String {
    format!("{:.1} MiB", b as f64 / f64::from(1 << 20))
}

/// A decoded leaf's values, bytes.
const LEAF_BYTES: u64 = std::mem::size_of::<[f32; 512]>() as u64;

/// What a bake in parts of one grid holds, bytes: the budget; the whole grid with the image
/// and the process; what is held throughout (topology, leaf offsets, image, process); what
/// opening the file takes; the decoded grid; its leaf count; and a random march's samples.
struct Sizes {
    budget: u64,
    whole: u64,
    held: u64,
    opening: u64,
    loaded: u64,
    leaves: u64,
    samples_image: u64,
}

/// A sweep in parts: `(least budget, what its least part holds, 0, bytes per part)`. A part is
/// a region of the tree: the lower nodes its blocks read with their leaves' topology, the
/// upper nodes above them, and its leaves' values (`sweep::part_bytes`); the least part holds
/// one lower node.
fn sweep_part(topo: &crate::tree::Tree, z: &Sizes) -> (u64, String, usize, u64) {
    let uppers = topo.uppers().len() as u64 * crate::tree::REGION_UPPER_BYTES;
    let fixed = z.held + z.samples_image + uppers;
    let widest = (0..topo.lowers().len())
        .map(|l| crate::bake::trace::sweep::part_bytes(topo, l))
        .max()
        .unwrap_or(0);
    let least = (fixed + widest)
        .max(z.opening)
        .min(z.whole + z.samples_image);
    let part = z.budget.saturating_sub(fixed);
    (
        least,
        format!("the largest part's region, {}", mib(widest)),
        0,
        part,
    )
}

/// The ray path by runs of rows: `(least budget, what its least part holds, leaves per part,
/// 0)`. Per part: a copy of the tree with neighbour tables, faces and halos, and what
/// computing its bounds holds for a moment (per leaf a halo, its neighbours and its bounds);
/// the least part is the lower node with the most leaves in its `[o, o + 128]` box.
fn ray_part(topo: &crate::tree::Tree, z: &Sizes) -> (u64, String, usize, u64) {
    let tree_copy = z.loaded - z.leaves * LEAF_BYTES;
    let transient = z.leaves * BOUNDS_SCRATCH_PER_LEAF;
    let fixed = z.held + tree_copy + transient;
    let widest = topo
        .lowers()
        .iter()
        .map(|n| {
            let o = n.origin.map(i64::from);
            let mut k = 0u64;
            topo.leaves_in_box(o, o.map(|c| c + 128), &mut |_| k += 1);
            k
        })
        .max()
        .unwrap_or(0);
    let least = (fixed + widest * LEAF_BYTES).max(z.opening).min(z.whole);
    let group = usize::try_from(z.budget.saturating_sub(fixed) / LEAF_BYTES).unwrap_or(usize::MAX);
    let what = format!("a part's copy of the tree and the largest part's {widest} leaves");
    (least, what, group, 0)
}

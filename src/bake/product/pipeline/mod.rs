//! The one bake pipeline, shared by `umbra bake`, batch tasks, the Python module and library
//! callers (through [`crate::request::BakeRequest::run`], or [`BakeJob::run`] on a planned job):
//! check the outputs, plan (whole or in parts), load the grid, frame the camera, trace, encode,
//! commit the map, its preview and any other output of the request together, and report what a
//! user should be warned about. Progress goes to one [`Progress`] throughout.

use crate::bake::{bake_scene, BakeSettings, Camera, Map, Provenance, View};
use crate::error::{Error, Result};
use crate::output::{check_writable, Staged};
use crate::progress::{Progress, Work};
use crate::scene::Scene;
use std::path::PathBuf;

mod bounded;
mod deep;
mod failure;
mod moving;
mod warning;

pub use bounded::{BoundedPlan, IMPLIED_BUDGET};
pub use failure::{BakeError, Step};
pub use warning::{
    map_warnings, motion_warnings, solid_warnings, velocity_warnings, volume_warnings, Warning,
};

/// One bake from a file to an EXR map (and optionally a PNG preview).
#[derive(Debug, Clone, PartialEq)]
pub struct BakeJob {
    /// What the bake reads: the input (a grid file, a scene file or a USD stage), its kind,
    /// and how it is read (grid, scale, colour, placement, level sets, stage selection,
    /// motion).
    pub source: crate::input::Source,
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
    /// A batch task's key (`umbra::batch::TaskKey` as text), written into the header as
    /// `umbra:key`; `None` for a bake outside a job.
    pub key: Option<String>,
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
    /// [`crate::error::Error::Output`] naming the file.
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
        if self.settings.soft.is_some() && matches!(self.product, Product::Fixed { .. }) {
            return Err(Error::InvalidArgument {
                name: "deep-format".into(),
                reason: "a fixed-size deep format encodes a transmittance that never rises with \
                         depth (its error bound comes from that); toward a light with extent \
                         T_L(z) can rise: use --deep, which stores it as it is"
                    .into(),
            });
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
        let load = |e| BakeError::loading(&self.source, e);
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

    /// Write this job's map from `from`, the finished bake of another job whose request
    /// differs from this one's only in the source file's name and the key (a held frame of a
    /// sequence: the same content): the same image under this job's provenance, so the bytes
    /// are the ones this job's own bake would write. `None` (nothing written) when `from` does
    /// not hold its whole image in memory (a deep or fixed-size deep map, a map streamed in
    /// parts): this job must bake.
    ///
    /// # Errors
    /// Output and write errors; nothing is written on error.
    pub fn commit_copy(&self, from: &BakeReport) -> Result<Option<Provenance>> {
        let whole = from.map.t.len() as u64 == from.map.camera.pixels();
        if !matches!(self.product, Product::Map)
            || from.deep.is_some()
            || from.fixed.is_some()
            || !whole
        {
            return Ok(None);
        }
        self.check_outputs()?;
        let provenance = Provenance {
            source_file: self.source.path().display().to_string(),
            key: self.key.clone(),
            ..from.provenance.clone()
        };
        let staged = crate::bake::encode::exr::stage_map(
            &self.output,
            self.preview.as_deref(),
            &from.map,
            &provenance,
            &self.layout,
            self.overwrite,
        )?;
        crate::output::commit_all(staged)?;
        Ok(Some(provenance))
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
        let mut v = crate::Volume::new(g, self.density_scale(), self.source.path())?;
        if let Some(x) = &self.source.xform()? {
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
        let scene = self.source.load()?;
        let camera = match self.camera {
            Some(c) => c,
            None => Camera::frame(&self.view, &scene.box_corners()?)?,
        };
        Ok((scene, camera))
    }

    /// `mu_t = density_scale x value` (multiplies a scene's own scales): the source's.
    #[must_use]
    pub fn density_scale(&self) -> f64 {
        self.source.options().density_scale
    }

    /// The extinction colour (an RGB map), the source's.
    #[must_use]
    pub fn sigma_t(&self) -> Option<[f64; 3]> {
        self.source.options().sigma_t
    }

    /// Whether the source moves (a velocity grid is read).
    #[must_use]
    pub fn moving(&self) -> bool {
        self.source.options().velocity.is_some()
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
        if let Some(crate::bake::SoftMap {
            receiver: crate::bake::Receiver::Depth(d),
            ..
        }) = &mut settings.soft
        {
            if delta > 0.0 {
                *d += delta;
            }
        }
        settings
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
        warnings.extend(warning::motion_warnings(scene));
        if let Some(why) = map.stats.declined {
            warnings.push(Warning::SweepDeclined {
                reason: why.to_string(),
            });
        }
        if self.max_memory.is_some() {
            let kind = self.source.kind();
            if kind.is_scene_file() {
                warnings.push(Warning::MemoryBudgetIgnored {
                    what: "scene files",
                });
            } else if self.sigma_t().is_some() {
                warnings.push(Warning::MemoryBudgetIgnored {
                    what: "colour maps (--sigma-t)",
                });
            } else if kind.is_grid_file() && !kind.has_partial_reads() {
                warnings.push(Warning::MemoryBudgetIgnored {
                    what: "NanoVDB grids (one block each)",
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
        let v_max = if self.density_scale() > 0.0 {
            scene.mu_max() / self.density_scale()
        } else {
            0.0
        };
        if scene.solids().is_empty() {
            warnings.extend(map_warnings(&map, self.density_scale(), v_max, diagonal));
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
            source_file: self.source.path().display().to_string(),
            grid: scene.grid_names(),
            density_scale: self.density_scale(),
            light_dir,
            light_pos,
            xform: self.source.xform().ok().flatten().map(|x| x.rows()),
            sigma_t: self.sigma_t(),
            key: self.key.clone(),
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

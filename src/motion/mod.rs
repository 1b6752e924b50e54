//! Motion blur from a velocity grid: the density a renderer sees at shutter time `t` and the
//! bounds that keep a free-flight walk through it honest.
//!
//! **The model** (Eulerian lookup, what Arnold's `velocity_grids`, RenderMan, Karma and Cycles
//! do): with the velocity `v(x)` in world units per second, the velocity scale `S` and the
//! frame rate `F`, the density at shutter time `t` (in frames, relative to the baked frame) is
//!
//! ```text
//! rho_t(x) = rho(x - S v(x) t / F),
//! ```
//!
//! the velocity read at the point itself, and the blurred transmittance along a ray is the
//! shutter mean `T = 1/(c - o) integral_o^c exp(-integral mu_t(x(s)) ds) dt` over the shutter
//! `[o, c]`: the time-averaged visibility of Lokovic and Veach's deep shadow maps.
//!
//! **Bounds** ([`BlurBounds`]): a point `x` of an `8^3` block `C` reads the density within
//! `r_C = S |v|_max(C) max(|o|, |c|) / F` of itself, where `|v|_max(C)` bounds the speed the
//! velocity's interpolation can give anywhere in `C` (its voxels around `C`). So
//! `max rho over C dilated by r_C` (plus the trilinear stencil) majorises `rho_t` on `C` at
//! every shutter time: a majorant per block, dilated by how far the velocity moves density into
//! it, still sparse (blocks far from any density have none). [`IntervalBounds`] holds the same
//! per interval of the shutter, for the estimators that draw one time per sample.
//!
//! [`MotionSpec`] is the request (validated), [`VelocityField`] the decoded velocity
//! ([`field`]), [`Motion`] both with the bounds, what a [`crate::Volume`] carries.

pub mod bounds;
pub mod field;
pub mod intervals;

pub use bounds::BlurBounds;
pub use field::{VelocityField, VelocityLookup};
pub use intervals::IntervalBounds;

use crate::error::{Error, Result};

/// The most stratified shutter times a marching estimator takes per sample.
pub const MAX_TIME_SAMPLES: u32 = 1024;

/// Frame rate when none is given (film).
pub const DEFAULT_FPS: f64 = 24.0;

/// What motion blur a trace asks for: the shutter in frames relative to the baked frame, the
/// frame rate, the velocity scale and the stratified time samples of marching estimators.
/// Valid by construction ([`MotionSpec::new`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionSpec {
    open: f64,
    close: f64,
    fps: f64,
    scale: f64,
    time_samples: u32,
}

fn invalid(name: &str, reason: String) -> Error {
    Error::InvalidArgument {
        name: name.into(),
        reason,
    }
}

impl MotionSpec {
    /// The shutter `[open, close]` (frames), `fps` frames per second, velocity scale `scale`,
    /// `time_samples` stratified times per marching sample.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `shutter` (non-finite, or close before open), `fps`
    /// (not finite and positive), `velocity-scale` (not finite) or `time-samples` (not in
    /// `1..=MAX_TIME_SAMPLES`).
    pub fn new(shutter: [f64; 2], fps: f64, scale: f64, time_samples: u32) -> Result<Self> {
        let [open, close] = shutter;
        if !(open.is_finite() && close.is_finite()) {
            return Err(invalid(
                "shutter",
                format!("{open},{close} is not two finite frame offsets"),
            ));
        }
        if close < open {
            return Err(invalid(
                "shutter",
                format!("close {close} is before open {open}"),
            ));
        }
        if !(fps.is_finite() && fps > 0.0) {
            return Err(invalid(
                "fps",
                format!("{fps} is not a positive frame rate"),
            ));
        }
        if !scale.is_finite() {
            return Err(invalid(
                "velocity-scale",
                format!("{scale} is not a finite scale"),
            ));
        }
        if !(1..=MAX_TIME_SAMPLES).contains(&time_samples) {
            return Err(invalid(
                "time-samples",
                format!("{time_samples} is not in 1..={MAX_TIME_SAMPLES}"),
            ));
        }
        Ok(Self {
            open,
            close,
            fps,
            scale,
            time_samples,
        })
    }

    /// Shutter open (frames).
    #[must_use]
    pub fn open(&self) -> f64 {
        self.open
    }
    /// Shutter close (frames).
    #[must_use]
    pub fn close(&self) -> f64 {
        self.close
    }
    /// Frames per second.
    #[must_use]
    pub fn fps(&self) -> f64 {
        self.fps
    }
    /// Velocity scale `S`.
    #[must_use]
    pub fn scale(&self) -> f64 {
        self.scale
    }
    /// Stratified shutter times per marching sample.
    #[must_use]
    pub fn time_samples(&self) -> u32 {
        self.time_samples
    }

    /// The same spec at another frame rate.
    ///
    /// # Errors
    /// As [`MotionSpec::new`] for `fps`.
    pub fn with_fps(self, fps: f64) -> Result<Self> {
        Self::new([self.open, self.close], fps, self.scale, self.time_samples)
    }

    /// The shutter time of fraction `u` in `[0, 1)` of the shutter: `o + u (c - o)`.
    #[must_use]
    pub fn time_at(&self, u: f64) -> f64 {
        self.open + u * (self.close - self.open)
    }

    /// The world displacement per unit of velocity at shutter time `t` (frames): `S t / F`,
    /// so that the density is read at `x - k v(x)`.
    #[must_use]
    pub fn displacement_per_velocity(&self, t: f64) -> f64 {
        self.scale * t / self.fps
    }

    /// The largest `|S t / F|` over the shutter.
    #[must_use]
    pub fn reach_per_velocity(&self) -> f64 {
        (self.scale * self.open.abs().max(self.close.abs()) / self.fps).abs()
    }

    /// Whether nothing moves: a zero scale or a shutter of one instant at the baked frame
    /// (`[0, 0]`). A shutter of one other instant still moves the density.
    #[must_use]
    pub fn is_still(&self) -> bool {
        self.reach_per_velocity() == 0.0
    }
}

/// A volume's motion: the spec, the velocity field and the blurred majorants of its density.
#[derive(Debug, Clone)]
pub struct Motion {
    spec: MotionSpec,
    field: VelocityField,
    bounds: BlurBounds,
    /// Built on first use ([`Motion::intervals`]): only the estimators that draw one time per
    /// sample read them, so a marcher's bake never pays for them.
    intervals: std::sync::OnceLock<IntervalBounds>,
}

impl Motion {
    /// The motion of a density tree with map `index_from_world` under `field` and `spec`
    /// (the bounds built here, [`BlurBounds::build`]).
    ///
    /// # Errors
    /// As [`BlurBounds::build`].
    pub fn new(
        spec: MotionSpec,
        field: VelocityField,
        density: &crate::tree::Tree,
        index_from_world: glam::DAffine3,
    ) -> Result<Self> {
        let bounds = BlurBounds::build(density, index_from_world, &field, &spec)?;
        Ok(Self {
            spec,
            field,
            bounds,
            intervals: std::sync::OnceLock::new(),
        })
    }

    /// [`Motion::new`] for a density decoded a part at a time: its topology `shell` and the
    /// `(max, min)` of each of its leaves ([`BlurBounds::from_summary`]); the same motion, bit
    /// for bit, as the whole density's.
    ///
    /// # Errors
    /// As [`BlurBounds::from_summary`].
    pub fn from_summary(
        spec: MotionSpec,
        field: VelocityField,
        shell: &crate::tree::Tree,
        leaf_range: &[(f32, f32)],
        index_from_world: glam::DAffine3,
    ) -> Result<Self> {
        let bounds = BlurBounds::from_summary(shell, leaf_range, index_from_world, &field, &spec)?;
        // The bounds per interval need the density's voxels, which a bake in parts never holds
        // at once: its null-collision samples walk the whole shutter's bounds (as valid, looser).
        let intervals = std::sync::OnceLock::from(IntervalBounds::none(&bounds));
        Ok(Self {
            spec,
            field,
            bounds,
            intervals,
        })
    }

    /// The voxel box (inclusive) of the density that the lookups of every point of `8^3` block
    /// `c` (and within one voxel of it) may read over the shutter, for a density with map
    /// `index_from_world` (the bounds' own reach per block, `crate::demand`).
    #[must_use]
    pub fn block_reads(&self, index_from_world: &glam::DAffine3, c: [i64; 3]) -> [[i64; 3]; 2] {
        bounds::block_reads(index_from_world, &self.field, &self.spec, c)
    }

    /// What was asked.
    #[must_use]
    pub fn spec(&self) -> &MotionSpec {
        &self.spec
    }
    /// The velocity.
    #[must_use]
    pub fn field(&self) -> &VelocityField {
        &self.field
    }
    /// The blurred majorants.
    #[must_use]
    pub fn bounds(&self) -> &BlurBounds {
        &self.bounds
    }
    /// The blurred majorants per interval of the shutter (what the estimators that draw one
    /// time per sample walk), built from `density` (map `index_from_world`: the tree and map
    /// this motion was made for) on the first call ([`IntervalBounds::build`], with
    /// [`IntervalBounds::default_count`] intervals); should the build fail, the whole
    /// shutter's bounds serve every time ([`IntervalBounds::none`]), which hold as well.
    pub fn intervals(
        &self,
        density: &crate::tree::Tree,
        index_from_world: glam::DAffine3,
    ) -> &IntervalBounds {
        self.intervals.get_or_init(|| {
            let (field, spec, whole) = (&self.field, &self.spec, &self.bounds);
            let count = IntervalBounds::default_count(whole, index_from_world, field, spec);
            IntervalBounds::build(density, index_from_world, field, spec, (whole, count))
                .unwrap_or_else(|_| IntervalBounds::none(whole))
        })
    }
}

/// The shutter when none is given: a 180-degree shutter centred on the frame, in frames.
pub const DEFAULT_SHUTTER: [f64; 2] = [-0.25, 0.25];

/// Stratified shutter times per marching sample when none is given.
pub const DEFAULT_TIME_SAMPLES: u32 = 8;

/// Motion blur as a request names it: the velocity grid (of the file the density comes from,
/// unless `file` says otherwise) and the spec.
#[derive(Debug, Clone, PartialEq)]
pub struct MotionRequest {
    /// The vec3 grid's name (a USD stage: the field relationship, `field:<velocity>`, until
    /// the stage is read and it becomes the grid that field names).
    pub velocity: String,
    /// Shutter, frame rate, scale, time samples.
    pub spec: MotionSpec,
    /// The file holding the velocity grid when it is not the density's (a USD field's asset).
    pub file: Option<std::path::PathBuf>,
    /// Whether the frame rate was given; when not, a USD stage's `timeCodesPerSecond` replaces
    /// the default.
    pub fps_given: bool,
}

impl MotionRequest {
    /// The motion blur the read options `o` ask for, with the options not given at their
    /// defaults (shutter [`DEFAULT_SHUTTER`], [`DEFAULT_FPS`], scale 1,
    /// [`DEFAULT_TIME_SAMPLES`]): `None` without `velocity`. The checks that involve the
    /// estimator are the request's (`EstimatorOptions::motion`).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `shutter`, `fps`, `velocity-scale` or `time-samples`
    /// given without `velocity` or out of range, or an empty `velocity`.
    pub fn of(o: &crate::input::SourceOptions) -> Result<Option<Self>> {
        let Some(velocity) = &o.velocity else {
            return match o.motion_keys().iter().find(|(_, g)| *g) {
                Some((k, _)) => Err(invalid(
                    k,
                    "applies to motion blur: give the velocity grid (velocity)".into(),
                )),
                None => Ok(None),
            };
        };
        if velocity.is_empty() {
            return Err(invalid("velocity", "must name a vec3 grid".into()));
        }
        let spec = MotionSpec::new(
            o.shutter.unwrap_or(DEFAULT_SHUTTER),
            o.fps.unwrap_or(DEFAULT_FPS),
            o.velocity_scale.unwrap_or(1.0),
            o.time_samples.unwrap_or(DEFAULT_TIME_SAMPLES),
        )?;
        Ok(Some(Self {
            velocity: velocity.clone(),
            spec,
            file: None,
            fps_given: o.fps.is_some(),
        }))
    }

    /// Load the velocity grid of `path` ([`crate::input::GridFile::load_vector`]) as a field:
    /// staggered when its class says so, in index space when its metadata says
    /// `is_local_space`.
    ///
    /// # Errors
    /// [`Error::GridNotFound`], a grid that is not a vec3 grid (naming the file and grid), and
    /// decoding and map errors.
    pub fn field(&self, path: &std::path::Path) -> Result<VelocityField> {
        let path = self.file.as_deref().unwrap_or(path);
        let as_flag = |e: Error| match e {
            Error::GridNotFound { .. } | Error::Unsupported { .. } => Error::InvalidArgument {
                name: "velocity".into(),
                reason: e.to_string(),
            },
            other => other,
        };
        let g = crate::input::GridFile::open(path)?
            .load_vector(&self.velocity)
            .map_err(as_flag)?;
        if !g.transform.is_affine() {
            return Err(Error::Unsupported {
                path: path.to_path_buf(),
                what: format!(
                    "velocity grid '{}' has a frustum map; umbra reads affine maps",
                    crate::text::escape(&g.name)
                ),
            });
        }
        use crate::input::VectorFacts;
        let (staggered, local) = (g.is_staggered(), g.is_local_space());
        let m = g.transform.world_from_index;
        VelocityField::new(g.name, g.components, [m[0], m[1], m[2]], staggered, local).map_err(
            |e| match e {
                Error::InvalidArgument { reason, .. } => Error::Unsupported {
                    path: path.to_path_buf(),
                    what: reason,
                },
                other => other,
            },
        )
    }
}

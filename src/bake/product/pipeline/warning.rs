//! What a finished bake wants its user to know ([`Warning`]): bad voxels, capped samples,
//! majorant violations, a camera that misses part of the volume, solids; worded once here for
//! every front end.

use crate::bake::Map;
use crate::scene::Scene;
use crate::volume::Sanitized;

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
    /// box): density there is not in the map ([`crate::bake::Camera::outside`]).
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
    /// No query's segment met an active voxel, so T = 1 for each (`umbra query`): usually the
    /// volume is not where the rays are (its transform or units) or the light's direction is
    /// wrong.
    MissedEveryVoxel {
        /// Queries answered.
        queries: u64,
    },
    /// Rays start so far from the volumes (about `1e21` times their box's size) that even
    /// moved next to them in double-double ([`crate::scene::Scene`]'s far rays) their walk
    /// resolves less than `1e-9` of the box: the answer may be off.
    FarRays {
        /// Rays so far.
        rays: u64,
    },
    /// NaN or infinite components of a velocity grid were read as 0 (motion blur).
    BadVelocity {
        /// The velocity grid.
        grid: String,
        /// Components set to 0 (over voxels, tiles and the background).
        non_finite: u64,
    },
    /// The shutter moves density farther than the cache's own size: usually a velocity in
    /// other units, a wrong velocity scale or frame rate.
    ShutterMovesFar {
        /// The velocity grid.
        grid: String,
        /// The largest move over the shutter, world units.
        world: f64,
        /// The same in voxels.
        voxels: f64,
        /// The density's extent, voxels.
        extent: f64,
    },
    /// `max_memory` was given for a bake that does not go in parts (a colour map, a scene
    /// file or a NanoVDB grid loads whole): the budget was not honoured.
    MemoryBudgetIgnored {
        /// What loads whole.
        what: &'static str,
    },
    /// A blurred `riemann` map went ray by ray where the object-order sweep usually takes it
    /// (several times slower): why ([`crate::bake::SweepDeclined`]).
    SweepDeclined {
        /// Why, in words.
        reason: String,
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
            // Behind the light (a light inside or beside the box): no perspective view holds
            // the box, so dropping --fov is refused too; the omni map covers every direction.
            Self::CroppedByFov { fov_deg, pixels } if pixels.is_infinite() => write!(
                f,
                "--fov {fov_deg} crops the volume: part of its box is behind the light (the \
                 light is inside or beside it), and density there is not in the map; no \
                 perspective view from the light holds the whole box (--omni cube|latlong bakes \
                 every direction around it)"
            ),
            Self::CroppedByFov { fov_deg, pixels } => write!(
                f,
                "--fov {fov_deg} crops the volume: its box reaches {pixels:.1} pixels outside \
                 the window, and density there is not in the map (drop --fov to frame it whole)"
            ),
            Self::MissedEveryVoxel { queries } => write!(
                f,
                "{} (T = 1): check where the volume is against the rays (its --xform \
                 or the stage's transforms, its units: `umbra info -v` prints its world bbox) \
                 and the light's direction",
                if queries == 1 {
                    "the query met no active voxel".to_string()
                } else {
                    format!("none of the {queries} queries met an active voxel")
                }
            ),
            Self::BadVelocity {
                ref grid,
                non_finite,
            } => write!(
                f,
                "velocity grid '{}': {non_finite} NaN or infinite components read as 0",
                crate::text::escape(grid)
            ),
            Self::ShutterMovesFar {
                ref grid,
                world,
                voxels,
                extent,
            } => write!(
                f,
                "velocity grid '{}' moves density up to {} world units ({} voxels) over the \
                 shutter, farther than the cache's own size ({} voxels): check the velocity's \
                 units, --velocity-scale and --fps",
                crate::text::escape(grid),
                crate::math::sig3(world),
                crate::math::sig3(voxels),
                crate::math::sig3(extent)
            ),
            Self::MemoryBudgetIgnored { what } => write!(
                f,
                "--max-memory is not honoured: {what} load whole (the budget applies to maps of \
                 one grey grid)"
            ),
            Self::SweepDeclined { ref reason } => write!(
                f,
                "this blurred map is traced ray by ray, not swept in object order (several \
                 times slower): {reason}"
            ),
            Self::FarRays { rays } => write!(
                f,
                "{rays} ray(s) start so far from the volumes (about 1e21 times their size or \
                 more) that their walk loses precision: the answer may be off; give points \
                 nearer the volumes"
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

/// Warnings about the velocity grids of a scene's moving volumes: non-finite components, a
/// shutter that moves density past the cache's own size.
#[must_use]
pub fn motion_warnings(scene: &Scene) -> Vec<Warning> {
    scene
        .fogs()
        .iter()
        .flat_map(|f| velocity_warnings(f.volume()))
        .collect()
}

/// The warnings about `vol`'s velocity grid: non-finite components
/// ([`Warning::BadVelocity`]), a shutter moving density farther than the cache's own extent
/// ([`Warning::ShutterMovesFar`]).
#[must_use]
pub fn velocity_warnings(vol: &crate::Volume) -> Vec<Warning> {
    let Some(m) = vol.motion() else {
        return Vec::new();
    };
    let field = m.field();
    let mut out = Vec::new();
    if field.non_finite() > 0 {
        out.push(Warning::BadVelocity {
            grid: field.name().to_string(),
            non_finite: field.non_finite(),
        });
    }
    let ((world, voxels), extent) = m.bounds().reach();
    if extent > 0.0 && voxels > extent {
        out.push(Warning::ShutterMovesFar {
            grid: field.name().to_string(),
            world,
            voxels,
            extent,
        });
    }
    out
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

//! Scenes: what one map or query traces. A scene is one or more fog volumes (each its own grid,
//! transform, density scale and extinction colour `sigma_t`) and any number of opaque solids
//! (level sets). A `.vdb` file is a scene of one volume; a `.toml` scene file lists
//! `[[volume]]` tables (see `scene::file`).
//!
//! Extinction of channel `c` at a world point `x`:
//! `mu_c(x) = sum_k sigma_{k,c} density_scale_k value_k(x)` over the fog volumes, `+inf` inside
//! any solid. A grey scene has one channel (`sigma` only scales it); a scene with any RGB
//! `sigma_t` has three (R, G, B).

mod batch;
mod estimate;
pub mod file;
mod source;

pub(crate) use file::blurred;

pub use batch::estimate_many;
pub use estimate::{estimate, SceneEstimate};

use crate::error::{Error, Result};
use crate::solid::Solid;
use crate::volume::{Sanitized, Volume};
use glam::DVec3;

/// How far, in sizes of the scene's world box, a ray's entry may be from its origin before its
/// walk starts from a moved origin ([`Scene::localise`]): `2^16`, where the walk's round-off is
/// still below `1e-11` of the box.
pub(crate) const FAR: f64 = 65_536.0;

/// Where a far ray is moved to and the box's size: `None` for a ray that misses the box or
/// enters it within [`FAR`] box sizes of its origin.
fn far_entry(ray: &crate::ray::Ray, world: Option<(DVec3, DVec3)>) -> Option<(f64, f64)> {
    let (lo, hi) = world?;
    let size = (hi - lo).max_element().max(f64::MIN_POSITIVE);
    let (t0, _) = crate::ray::clip_box(ray.origin(), ray.direction(), lo, hi)?;
    if !(t0 > FAR * size && t0.is_finite()) {
        return None;
    }
    let t = (t0 - size.max(4.0 * f64::EPSILON * t0)).max(ray.t_min());
    Some((t, size))
}

/// Most fog volumes in one scene (the sampled set of each interval is a 64-bit mask).
pub const MAX_VOLUMES: usize = 64;

/// One fog volume of a scene: `mu_c = sigma[c] x density_scale x value`.
///
/// Invariant (why the fields are private): `sigma` is finite and non-negative, so the
/// per-channel bounds the estimators use are the volume's bounds scaled by `sigma`.
#[derive(Debug, Clone)]
pub struct Fog {
    volume: Volume,
    sigma: [f64; 3],
}

impl Fog {
    /// A fog volume with extinction colour `sigma` (use `[1.0; 3]` for grey).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `sigma-t`) for a negative or non-finite entry.
    pub fn new(volume: Volume, sigma: [f64; 3]) -> Result<Self> {
        check_sigma(sigma)?;
        Ok(Self { volume, sigma })
    }

    /// The volume.
    #[must_use]
    pub fn volume(&self) -> &Volume {
        &self.volume
    }

    /// Extinction colour: channel `c` is scaled by `sigma[c]`.
    #[must_use]
    pub fn sigma(&self) -> [f64; 3] {
        self.sigma
    }
}

/// The bounding box of `corners`; `None` when it is empty or not finite.
fn corner_box(corners: &[DVec3]) -> Option<(DVec3, DVec3)> {
    let lo = corners.iter().fold(DVec3::INFINITY, |a, b| a.min(*b));
    let hi = corners.iter().fold(DVec3::NEG_INFINITY, |a, b| a.max(*b));
    (lo.cmple(hi).all() && lo.is_finite() && hi.is_finite()).then_some((lo, hi))
}

/// Check an extinction colour: finite, non-negative.
///
/// # Errors
/// [`Error::InvalidArgument`] named `sigma-t`.
pub fn check_sigma(sigma: [f64; 3]) -> Result<()> {
    if sigma.iter().all(|s| s.is_finite() && *s >= 0.0) {
        return Ok(());
    }
    Err(Error::InvalidArgument {
        name: "sigma-t".into(),
        reason: format!(
            "{},{},{}: every channel must be a finite, non-negative number",
            sigma[0], sigma[1], sigma[2]
        ),
    })
}

/// What a map or a query traces (see the module docs).
///
/// Invariants: at least one fog volume or solid, at most [`MAX_VOLUMES`] fog volumes; a grey
/// scene (`channels == 1`) has the same `sigma` in every channel.
#[derive(Debug, Clone)]
pub struct Scene {
    fogs: Vec<Fog>,
    solids: Vec<Solid>,
    channels: usize,
    /// [`Scene::world_box`], made once (every ray toward a directional light asks for it).
    world: Option<(DVec3, DVec3)>,
}

impl Scene {
    /// A scene of fog volumes and solids; `rgb` asks for three channels (otherwise every fog's
    /// `sigma` must be grey: the same in all channels).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `scene`) for an empty scene, more than
    /// [`MAX_VOLUMES`] fog volumes, or a coloured `sigma` in a grey scene.
    pub fn new(fogs: Vec<Fog>, solids: Vec<Solid>, rgb: bool) -> Result<Self> {
        let bad = |reason: String| Error::InvalidArgument {
            name: "scene".into(),
            reason,
        };
        if fogs.is_empty() && solids.is_empty() {
            return Err(bad("a scene needs at least one volume".into()));
        }
        let moving = fogs.iter().any(|f| f.volume.motion().is_some());
        if moving && (fogs.len() > 1 || !solids.is_empty() || rgb || fogs[0].sigma != [1.0; 3]) {
            return Err(Error::InvalidArgument {
                name: "velocity".into(),
                reason: "motion blur traces one grey fog volume; this scene has several \
                         volumes, solids or colour"
                    .into(),
            });
        }
        if fogs.len() > MAX_VOLUMES {
            return Err(bad(format!(
                "{} fog volumes; at most {MAX_VOLUMES}",
                fogs.len()
            )));
        }
        if !rgb
            && fogs
                .iter()
                .any(|f| f.sigma[0] != f.sigma[1] || f.sigma[0] != f.sigma[2])
        {
            return Err(bad(
                "a coloured sigma_t needs an RGB scene (three channels)".into(),
            ));
        }
        Ok(Self {
            fogs,
            solids,
            channels: if rgb { 3 } else { 1 },
            world: None,
        }
        .with_world_box())
    }

    /// The scene of one grey volume.
    #[must_use]
    pub fn from_volume(volume: Volume) -> Self {
        Self {
            fogs: vec![Fog {
                volume,
                sigma: [1.0; 3],
            }],
            solids: Vec::new(),
            channels: 1,
            world: None,
        }
        .with_world_box()
    }

    /// The scene with its world box made.
    fn with_world_box(mut self) -> Self {
        self.world = self.box_corners().ok().and_then(|c| corner_box(&c));
        self
    }

    /// The fog volumes.
    #[must_use]
    pub fn fogs(&self) -> &[Fog] {
        &self.fogs
    }

    /// The solids.
    #[must_use]
    pub fn solids(&self) -> &[Solid] {
        &self.solids
    }

    /// Where the ray from `p` along `d` (world units) last leaves a box of the scene: the
    /// largest exit `t >= 0` over every fog volume's index box and every solid's world
    /// bounding box; `None` when it leaves none ahead of `p`. What a directional light's ray
    /// and a soft map's default receiver end at.
    #[must_use]
    pub fn box_exit(&self, p: DVec3, d: DVec3) -> Option<f64> {
        let fogs = self.fogs.iter().filter_map(|f| {
            let v = f.volume();
            let (lo, hi) = v.box_index()?;
            crate::ray::clip_box(v.to_index(p), v.to_index_dir(d), lo, hi).map(|(_, t1)| t1)
        });
        let solids = self.solids.iter().filter_map(|s| {
            let c = s.box_corners().ok()?;
            let lo = c.iter().fold(DVec3::INFINITY, |a, b| a.min(*b));
            let hi = c.iter().fold(DVec3::NEG_INFINITY, |a, b| a.max(*b));
            crate::ray::clip_box(p, d, lo, hi).map(|(_, t1)| t1)
        });
        fogs.chain(solids)
            .filter(|t| *t >= 0.0)
            .fold(None, |a: Option<f64>, t| Some(a.map_or(t, |a| a.max(t))))
    }

    /// The world box of every fog volume and solid (the bounding box of their corners);
    /// `None` for a scene without one.
    #[must_use]
    pub(crate) fn world_box(&self) -> Option<(DVec3, DVec3)> {
        self.world
    }

    /// The world box of one volume (the bounding box of its corners), what a map of one grid
    /// moves its far rays next to ([`Scene::localise`]).
    #[must_use]
    pub(crate) fn volume_box(v: &Volume) -> Option<(DVec3, DVec3)> {
        corner_box(&v.box_corners().ok()?)
    }

    /// `ray` as a walk takes it, with the distance `s` it was moved by: a ray that enters the
    /// scene's world box `[lo, hi]` (of size `L`, its longest side) farther than
    /// [`FAR`]` L` from its origin is moved to `t = max(t_min, t_0 - max(L, 4 eps t_0))`
    /// before its entry `t_0` ([`Ray::moved_to`]: the same line and end, the origin in
    /// double-double), so a far end costs no precision: a walk in index space from an
    /// origin at `|o|` resolves `t` to about `eps |o| / voxel`, 2 world units at 1e16. Any
    /// other ray is returned as it is (`s = 0`), bit for bit. `t` on the moved ray is `t - s`
    /// on the given one.
    #[must_use]
    pub(crate) fn localise(
        ray: &crate::ray::Ray,
        world: Option<(DVec3, DVec3)>,
    ) -> (crate::ray::Ray, f64) {
        let Some((t, _)) = far_entry(ray, world) else {
            return (*ray, 0.0);
        };
        match ray.moved_to(t) {
            Some(moved) => (moved, t),
            None => (*ray, 0.0),
        }
    }

    /// Whether a walk along `ray` loses precision even when moved ([`Scene::localise`]):
    /// the moved origin's error, about `2^-104` of the distance moved plus `eps` of how far
    /// before the box it lands (`4 eps t_0` when that exceeds `L`), is more than `1e-9 L`
    /// (from about `1e21 L` away).
    #[must_use]
    pub(crate) fn loses_precision(&self, ray: &crate::ray::Ray) -> bool {
        let world = self.world_box();
        let Some((t, size)) = far_entry(ray, world) else {
            return false;
        };
        let eps = f64::EPSILON;
        let error = t * eps * eps * 16.0 + eps * (4.0 * eps * t).max(size);
        error > 1e-9 * size || ray.moved_to(t).is_none()
    }

    /// 1 (grey) or 3 (R, G, B).
    #[must_use]
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// The volume itself when the scene is one grey fog volume with `sigma = 1` and no solid:
    /// every single-grid path (the sweep, the budget, the estimators) then applies unchanged.
    #[must_use]
    pub fn single(&self) -> Option<&Volume> {
        match (&self.fogs[..], self.solids.is_empty(), self.channels) {
            ([f], true, 1) if f.sigma == [1.0; 3] => Some(&f.volume),
            _ => None,
        }
    }

    /// The world corners of every volume's and solid's box (what a map frames).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `grid`) when no volume holds anything but its
    /// background.
    pub fn box_corners(&self) -> Result<Vec<DVec3>> {
        let mut out = Vec::new();
        let mut first_err = None;
        let boxes = self
            .fogs
            .iter()
            .map(|f| f.volume.box_corners())
            .chain(self.solids.iter().map(Solid::box_corners));
        for b in boxes {
            match b {
                Ok(c) => out.extend(c),
                Err(e) => {
                    first_err.get_or_insert(e);
                }
            }
        }
        match (out.is_empty(), first_err) {
            (true, Some(e)) => Err(e),
            _ => Ok(out),
        }
    }

    /// What the bad-voxel policy changed, summed over the fog volumes.
    #[must_use]
    pub fn sanitized(&self) -> Sanitized {
        let mut s = Sanitized::default();
        for f in &self.fogs {
            let v = f.volume.sanitized();
            s.nan += v.nan;
            s.negative += v.negative;
            s.pos_inf += v.pos_inf;
        }
        s
    }

    /// Largest extinction any fog volume can reach (for warnings): `max_k max_c sigma_{k,c}
    /// density_scale_k max value_k`.
    #[must_use]
    pub fn mu_max(&self) -> f64 {
        self.fogs
            .iter()
            .map(|f| {
                let s = f.sigma.iter().copied().fold(0.0f64, f64::max);
                crate::math::scaled(
                    s * f.volume.density_scale(),
                    f64::from(f.volume.bounds().max),
                )
            })
            .fold(0.0, f64::max)
    }

    /// The grids traced, as `file-less` names for headers: `density`, or
    /// `density+flame+ship(solid)` for a scene.
    #[must_use]
    pub fn grid_names(&self) -> String {
        let fogs = self.fogs.iter().map(|f| f.volume.name().to_string());
        let solids = self.solids.iter().map(|s| format!("{}(solid)", s.name()));
        fogs.chain(solids).collect::<Vec<_>>().join("+")
    }
}

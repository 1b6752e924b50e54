//! A grid ready to trace: the flat tree with umbra's bad-voxel policy applied, the inverse of
//! its affine transform, the density scale, and the box outside which the density is the
//! background.
//!
//! **Bad-voxel policy** (applied once, here, and counted): extinction must be a finite,
//! non-negative number, so NaN values become 0, negative values become 0, and +Inf stays +Inf
//! (an opaque voxel: T = 0 across it, tau reported as inf). The counts are in
//! [`Volume::sanitized`] and the CLI prints a warning when any is non-zero. The original
//! values remain what `umbra info` reports.

use crate::error::{Error, Result};
use crate::input::Grid;
pub use crate::motion::{Motion, MotionSpec, VelocityField};
use crate::tree::{Bounds, RootSlot, Tree};
use glam::{DAffine3, DMat3, DVec3};
use rayon::prelude::*;

/// How the density between voxel centres is defined (declared with the read options).
pub use crate::input::Interp;

/// Counts of voxels changed by the bad-voxel policy (tiles count once per tile).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct Sanitized {
    /// NaN values set to 0.
    pub nan: u64,
    /// Negative values set to 0.
    pub negative: u64,
    /// +Inf values kept as opaque.
    pub pos_inf: u64,
}

/// A traceable volume.
///
/// Invariants (why the fields are private): the tree's bounds (every node's majorant and
/// minorant, nearest and trilinear) bound the values it holds, after the bad-voxel policy;
/// `index_from_world` is the inverse of `world_from_index`, an invertible affine map with
/// finite entries; the density scale is finite and non-negative; `value_box` holds every value
/// other than the background. A `Volume` is only made by [`Volume::load`], [`Volume::new`] and
/// [`Volume::from_tree`], which establish them, and nothing hands out a mutable tree:
///
/// ```compile_fail
/// fn scale_a_leaf(vol: &mut umbra::Volume) {
///     // Would leave the majorants stale: does not compile.
///     vol.tree.values[0][0] *= 2.0;
/// }
/// ```
#[derive(Debug, Clone)]
pub struct Volume {
    name: String,
    tree: Tree,
    world_from_index: DAffine3,
    index_from_world: DAffine3,
    density_scale: f64,
    value_box: Option<[[i64; 3]; 2]>,
    data_reach: f64,
    sanitized: Sanitized,
    /// The object transform applied on top of the grid's own, if any.
    xform: Option<crate::xform::Xform>,
    /// Motion blur from a velocity grid ([`Volume::with_motion`]), if any.
    motion: Option<std::sync::Arc<crate::motion::Motion>>,
}

fn sanitize(v: &mut f32, s: &mut Sanitized) {
    if s.tally(*v) {
        *v = 0.0;
    }
}

impl Sanitized {
    /// Count `v` as the bad-voxel policy treats it (NaN and negative values are set to 0,
    /// +Inf is kept as opaque); true when the policy replaces it.
    pub(crate) fn tally(&mut self, v: f32) -> bool {
        if v.is_nan() {
            self.nan += 1;
            true
        } else if v < 0.0 {
            self.negative += 1;
            true
        } else {
            if v == f32::INFINITY {
                self.pos_inf += 1;
            }
            false
        }
    }

    /// Both counts together.
    #[must_use]
    pub fn merged(self, o: Self) -> Self {
        Self {
            nan: self.nan + o.nan,
            negative: self.negative + o.negative,
            pos_inf: self.pos_inf + o.pos_inf,
        }
    }
}

impl Volume {
    /// Load grid `grid` of `path` and prepare it for tracing (see [`Volume::new`]). The file is
    /// read by the input layer ([`crate::input::load_grid`]).
    ///
    /// # Errors
    /// Loading errors ([`crate::input::load_grid`]) and those of [`Volume::new`].
    pub fn load(path: impl AsRef<std::path::Path>, grid: &str, density_scale: f64) -> Result<Self> {
        let path = path.as_ref();
        Self::new(crate::input::load_grid(path, grid)?, density_scale, path)
    }

    /// Prepare `grid` for tracing with extinction `mu_t = density_scale * value`.
    ///
    /// # Errors
    /// [`Error::LevelSet`] for level sets (grid class `level set`); [`Error::Unsupported`] for
    /// frustum maps and
    /// non-scalar grids, [`Error::InvalidArgument`] for a negative or non-finite density scale.
    pub fn new(grid: Grid, density_scale: f64, path: &std::path::Path) -> Result<Self> {
        check_density_scale(density_scale)?;
        if grid.class.as_deref() == Some("level set") {
            return Err(Error::LevelSet {
                path: path.to_path_buf(),
                grid: grid.name.clone(),
            });
        }
        if !grid.transform.is_affine() {
            return Err(non_affine(path, &grid.transform, &grid.name));
        }
        if !grid.value_type.is_scalar_real() {
            return Err(Error::Unsupported {
                path: path.to_path_buf(),
                what: format!(
                    "tracing a {} grid ('{}'); density must be a float or double grid",
                    grid.value_type.name(),
                    crate::text::escape(&grid.name)
                ),
            });
        }
        let m = grid.transform.world_from_index;
        let shown = crate::text::escape(&grid.name).into_owned();
        Self::from_tree(grid.name, grid.tree, [m[0], m[1], m[2]], density_scale).map_err(
            |e| match e {
                Error::InvalidArgument { name, reason } if name == "transform" => {
                    Error::Unsupported {
                        path: path.to_path_buf(),
                        what: format!("grid '{shown}' cannot be traced: its transform: {reason}"),
                    }
                }
                other => other,
            },
        )
    }

    /// A volume from a tree built in memory (see [`crate::tree::TreeBuilder`]) and a
    /// `world_from_index` affine map (3x4, column vectors: `world = M [i j k 1]^T`).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for a negative or non-finite density scale (name
    /// `density-scale`), or a map with non-finite entries, a zero or non-finite determinant, or
    /// a non-finite inverse (name `transform`).
    pub fn from_tree(
        name: String,
        mut tree: Tree,
        world_from_index: [[f64; 4]; 3],
        density_scale: f64,
    ) -> Result<Self> {
        check_density_scale(density_scale)?;
        let mut s = Sanitized::default();
        tree.tile_values_mut(|v| sanitize(v, &mut s));
        // Leaf values in parallel; a block that is all finite and non-negative (the usual
        // case) is passed over by one vectorised test.
        let leaves = tree
            .values
            .par_iter_mut()
            .filter(|v| {
                v.iter()
                    .fold(false, |bad, &x| bad | !(0.0..f32::INFINITY).contains(&x))
            })
            .map(|v| {
                let mut s = Sanitized::default();
                v.iter_mut().for_each(|v| sanitize(v, &mut s));
                s
            })
            .reduce(Sanitized::default, |a, b| Sanitized {
                nan: a.nan + b.nan,
                negative: a.negative + b.negative,
                pos_inf: a.pos_inf + b.pos_inf,
            });
        s.nan += leaves.nan;
        s.negative += leaves.negative;
        s.pos_inf += leaves.pos_inf;
        if s.nan + s.negative > 0 && !tree.shell {
            tree.compute_bounds();
        }
        Self::assemble(name, tree, world_from_index, density_scale, s)
    }

    /// What [`Volume::from_tree`] does with density scale 1, but *without* the bad-voxel
    /// policy: negative (and NaN, infinite) values are kept as they are. It exists only for
    /// [`crate::solid::Solid`], whose level-set values are signed distances (negative inside)
    /// and are never traced as fog; a volume made here breaks the non-negative extinction
    /// invariant, which is why it is crate-private.
    ///
    /// # Errors
    /// As [`Volume::from_tree`] for the map (name `transform`).
    pub(crate) fn from_tree_raw(
        name: String,
        tree: Tree,
        world_from_index: [[f64; 4]; 3],
    ) -> Result<Self> {
        Self::assemble(name, tree, world_from_index, 1.0, Sanitized::default())
    }

    /// The common tail of the tree constructors: value box, checked and inverted map, data
    /// reach. `tree`'s bounds must already match its values.
    fn assemble(
        name: String,
        tree: Tree,
        world_from_index: [[f64; 4]; 3],
        density_scale: f64,
        sanitized: Sanitized,
    ) -> Result<Self> {
        let value_box = value_box(&tree);
        let grown = value_box.map(|[lo, hi]| [lo.map(|c| c - 1), hi.map(|c| c + 1)]);
        let (world_from_index, index_from_world) = invert_affine(&world_from_index, grown)?;
        let data_reach = data_reach(&tree, value_box);
        Ok(Self {
            data_reach,
            name,
            tree,
            world_from_index,
            index_from_world,
            density_scale,
            value_box,
            sanitized,
            xform: None,
            motion: None,
        })
    }

    /// The same volume with another density scale (the tree is shared in meaning, copied in
    /// memory).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for a negative or non-finite scale.
    pub fn with_density_scale(mut self, density_scale: f64) -> Result<Self> {
        check_density_scale(density_scale)?;
        self.density_scale = density_scale;
        Ok(self)
    }

    /// Grid name.
    #[must_use]
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The tree, after the bad-voxel policy (read only: its bounds must match its values).
    #[must_use]
    pub fn tree(&self) -> &Tree {
        &self.tree
    }

    /// `world_from_index`: `world = M index`.
    #[must_use]
    pub fn world_from_index(&self) -> DAffine3 {
        self.world_from_index
    }

    /// `world_from_index` as row-major 3x4 rows (column vectors, translation in the last
    /// column): the convention of [`Volume::from_tree`].
    #[must_use]
    pub fn world_from_index_rows(&self) -> [[f64; 4]; 3] {
        let m = self.world_from_index.matrix3;
        let t = self.world_from_index.translation;
        std::array::from_fn(|r| [m.x_axis[r], m.y_axis[r], m.z_axis[r], t[r]])
    }

    /// `index_from_world`, the inverse of [`Volume::world_from_index`].
    #[must_use]
    pub fn index_from_world(&self) -> DAffine3 {
        self.index_from_world
    }

    /// `mu_t = density_scale x value`, per world unit.
    #[must_use]
    pub fn density_scale(&self) -> f64 {
        self.density_scale
    }

    /// Inclusive voxel box holding every leaf and every tile whose value differs from the
    /// background; `None` if the density is the background everywhere.
    #[must_use]
    pub fn value_box(&self) -> Option<[[i64; 3]; 2]> {
        self.value_box
    }

    /// An upper bound on the index-space length (in voxels) a ray can spend where lookups may
    /// read anything but the background: the smaller of the volume box's diagonal and
    /// `sqrt(3) (dim + 2)` summed over leaves and non-background tiles (each node's diagonal
    /// with its trilinear halo). What the work budget charges ray marching for
    /// ([`crate::estimate::budget`]).
    #[must_use]
    pub fn data_reach(&self) -> f64 {
        self.data_reach
    }

    /// What the bad-voxel policy changed.
    #[must_use]
    pub fn sanitized(&self) -> Sanitized {
        self.sanitized
    }

    /// Index-space point of a world point.
    #[must_use]
    pub fn to_index(&self, p: impl Into<DVec3>) -> DVec3 {
        self.index_from_world.transform_point3(p.into())
    }

    /// Index-space vector of a world vector.
    #[must_use]
    pub fn to_index_dir(&self, d: impl Into<DVec3>) -> DVec3 {
        self.index_from_world.transform_vector3(d.into())
    }

    /// World-space point of an index point.
    #[must_use]
    pub fn to_world(&self, p: impl Into<DVec3>) -> DVec3 {
        self.world_from_index.transform_point3(p.into())
    }

    /// Index-space volume box `[lo, hi]`: [`Volume::value_box`] grown by one voxel (the reach
    /// of a trilinear lookup); for a moving volume ([`Volume::moving`]), the box of the blocks
    /// its blurred density may reach over the shutter. What a map frames and where "until the
    /// ray leaves the volume" ends; `None` when the density is the background everywhere.
    #[must_use]
    pub fn box_index(&self) -> Option<(DVec3, DVec3)> {
        let value_box = match self.moving() {
            Some(m) => m.bounds().value_box(),
            None => self.value_box,
        };
        value_box.map(|[lo, hi]| {
            (
                DVec3::from_array(lo.map(|v| (v - 1) as f64)),
                DVec3::from_array(hi.map(|v| (v + 1) as f64)),
            )
        })
    }

    /// The 8 world corners of the volume box (a parallelepiped for a general affine map),
    /// corner `n` taking `hi` on axis `a` when bit `2 - a` of `n` is set.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `grid`) when the grid holds nothing but its
    /// background: there is nothing to frame.
    pub fn box_corners(&self) -> Result<[DVec3; 8]> {
        let (lo, hi) = self.box_index().ok_or_else(|| Error::InvalidArgument {
            name: "grid".into(),
            reason: format!(
                "grid '{}' holds no value other than its background: nothing to frame",
                self.name
            ),
        })?;
        Ok(crate::math::box_corners([lo.to_array(), hi.to_array()]).map(|p| self.to_world(p)))
    }

    /// The world corners of the volume box [`Volume::box_corners`] would give for grid `grid`
    /// of `path`, read from the file's header and the grid's topology without decoding any
    /// voxel value (what framing a whole sequence needs); `None` when the grid holds only its
    /// background.
    ///
    /// # Errors
    /// Opening and decoding errors, [`Error::GridNotFound`], and [`Error::Unsupported`] for a
    /// grid whose transform is not affine.
    pub fn read_box_corners(
        path: impl AsRef<std::path::Path>,
        grid: &str,
    ) -> Result<Option<[DVec3; 8]>> {
        let path = path.as_ref();
        let extent = crate::input::GridFile::open(path)?.extent(grid)?;
        if !extent.transform.is_affine() {
            return Err(non_affine(path, &extent.transform, &extent.name));
        }
        let m = extent.transform.world_from_index;
        Ok(extent.value_box.map(|[lo, hi]| {
            let (lo, hi) = (lo.map(|v| (v - 1) as f64), hi.map(|v| (v + 1) as f64));
            crate::math::box_corners([lo, hi]).map(|p| {
                DVec3::from_array(
                    [0, 1, 2].map(|r| m[r][0] * p.x + m[r][1] * p.y + m[r][2] * p.z + m[r][3]),
                )
            })
        }))
    }

    /// The volume placed in its shot by the object transform `x` (world-from-object): its
    /// `world_from_index` becomes `x world_from_index`, so every world-space query, camera and
    /// box sees it where `x` puts it. Transforms compose: applying `a` then `b` is applying
    /// `b a`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `xform`) when the composed map fails the checks a
    /// grid's own transform passes (voxel size range, (nearly) parallel voxel axes, an inverse
    /// that is not finite, coordinates too large for the voxel size).
    pub fn with_xform(mut self, x: &crate::xform::Xform) -> Result<Self> {
        let w = self.world_from_index;
        let rows: [[f64; 4]; 3] = std::array::from_fn(|r| {
            [
                w.matrix3.x_axis[r],
                w.matrix3.y_axis[r],
                w.matrix3.z_axis[r],
                w.translation[r],
            ]
        });
        let composed = x.after(&rows);
        let grown = self
            .value_box
            .map(|[lo, hi]| [lo.map(|c| c - 1), hi.map(|c| c + 1)]);
        let (fwd, inv) = invert_affine(&composed, grown).map_err(|e| match e {
            Error::InvalidArgument { reason, .. } => Error::InvalidArgument {
                name: "xform".into(),
                reason: format!("the transformed grid cannot be traced: {reason}"),
            },
            other => other,
        })?;
        self.world_from_index = fwd;
        self.index_from_world = inv;
        self.xform = Some(match self.xform {
            Some(prev) => crate::xform::Xform::new(compose(&x.rows(), &prev.rows()))?,
            None => *x,
        });
        if let Some(m) = self.motion.take() {
            let field = m.field().clone().placed(x);
            let moved = crate::motion::Motion::new(*m.spec(), field, &self.tree, inv)?;
            self.motion = Some(std::sync::Arc::new(moved));
        }
        Ok(self)
    }

    /// The volume blurred over `spec`'s shutter by the velocity `field` (given in the grid's
    /// own world frame; an object transform already applied moves it too): every estimate
    /// through [`crate::estimate::estimate`] is then the shutter mean of the transmittance
    /// through `rho(x - S v(x) t / F)` (`crate::motion`).
    ///
    /// # Errors
    /// As [`crate::motion::Motion::new`]: a partial tree, a root tile, a reach too far to bound.
    pub fn with_motion(
        mut self,
        spec: crate::motion::MotionSpec,
        field: crate::motion::VelocityField,
    ) -> Result<Self> {
        let field = match &self.xform {
            Some(x) => field.placed(x),
            None => field,
        };
        let m = crate::motion::Motion::new(spec, field, &self.tree, self.index_from_world)?;
        self.motion = Some(std::sync::Arc::new(m));
        Ok(self)
    }

    /// [`Volume::with_motion`] for a volume decoded a part at a time: `self` is its shell (its
    /// topology, [`crate::vdb::LazyGrid::shell`]) and `leaf_range[i]` the `(max, min)` of leaf
    /// `i`'s values as a whole load bounds them ([`crate::motion::Motion::from_summary`]). The
    /// parts then share this motion ([`Volume::with_motion_of`]).
    ///
    /// # Errors
    /// As [`crate::motion::Motion::from_summary`].
    pub fn with_summarised_motion(
        mut self,
        spec: crate::motion::MotionSpec,
        field: crate::motion::VelocityField,
        leaf_range: &[(f32, f32)],
    ) -> Result<Self> {
        let field = match &self.xform {
            Some(x) => field.placed(x),
            None => field,
        };
        let m = crate::motion::Motion::from_summary(
            spec,
            field,
            &self.tree,
            leaf_range,
            self.index_from_world,
        )?;
        self.motion = Some(std::sync::Arc::new(m));
        Ok(self)
    }

    /// This volume (a part of the grid `whole` was made from, with the same placement) moving
    /// as `whole` moves: the one motion shared, not rebuilt from the part's leaves.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `velocity`) when the two are not placed alike.
    pub fn with_motion_of(mut self, whole: &Volume) -> Result<Self> {
        if self.index_from_world != whole.index_from_world {
            return Err(Error::InvalidArgument {
                name: "velocity".into(),
                reason: format!(
                    "a part of grid '{}' is placed unlike the grid it shares the motion of",
                    self.name
                ),
            });
        }
        self.motion.clone_from(&whole.motion);
        Ok(self)
    }

    /// The motion set by [`Volume::with_motion`], if any (a still one included).
    #[must_use]
    pub fn motion(&self) -> Option<&crate::motion::Motion> {
        self.motion.as_deref()
    }

    /// The motion when it moves anything: a non-still shutter and a field with some speed.
    #[must_use]
    pub fn moving(&self) -> Option<&crate::motion::Motion> {
        self.motion()
            .filter(|m| !m.spec().is_still() && m.field().speed_max() > 0.0)
    }

    /// The object transform applied by [`Volume::with_xform`] (composed), if any.
    #[must_use]
    pub fn xform(&self) -> Option<crate::xform::Xform> {
        self.xform
    }

    /// Extinction of the background, `density_scale * background`.
    #[must_use]
    pub fn mu_background(&self) -> f64 {
        crate::math::scaled(self.density_scale, f64::from(self.tree.background))
    }

    /// Bounds of every value, background included.
    #[must_use]
    pub fn bounds(&self) -> Bounds {
        self.tree.bounds
    }
}

/// See [`Volume::data_reach`].
fn data_reach(tree: &Tree, value_box: Option<[[i64; 3]; 2]>) -> f64 {
    let Some([lo, hi]) = value_box else {
        return 0.0;
    };
    let diagonal = (0..3)
        .map(|a| ((hi[a] - lo[a] + 3) as f64).powi(2))
        .sum::<f64>()
        .sqrt();
    let bg = tree.background;
    let tiles = |nodes: &[crate::tree::Internal]| -> f64 {
        nodes
            .iter()
            .map(|n| {
                (0..n.slots.len())
                    .filter(|&i| !n.has_child(i) && n.tile_value(i) != bg)
                    .count() as f64
            })
            .sum()
    };
    let root_tiles = tree
        .root
        .iter()
        .filter(|e| matches!(e.slot, RootSlot::Tile { value, .. } if value != bg))
        .count() as f64;
    let sides = (tree.leaves.len() as f64 + tiles(&tree.lowers)) * 10.0
        + tiles(&tree.uppers) * 130.0
        + root_tiles * 4098.0;
    diagonal.min(sides * 3f64.sqrt())
}

/// `a b` for 4x4 matrices.
fn compose(a: &[[f64; 4]; 4], b: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    std::array::from_fn(|r| std::array::from_fn(|c| (0..4).map(|k| a[r][k] * b[k][c]).sum()))
}

/// A grid whose transform umbra cannot trace (a frustum map), named with its file.
pub(crate) fn non_affine(path: &std::path::Path, t: &crate::input::Transform, grid: &str) -> Error {
    Error::Unsupported {
        path: path.to_path_buf(),
        what: format!(
            "{} (grid '{}')",
            crate::text::escape(&t.map),
            crate::text::escape(grid)
        ),
    }
}

fn value_box(tree: &Tree) -> Option<[[i64; 3]; 2]> {
    crate::tree::value_box_of(tree, tree.leaves.iter().map(|l| l.origin))
}

pub(crate) fn check_density_scale(density_scale: f64) -> Result<()> {
    if density_scale.is_finite() && density_scale >= 0.0 {
        return Ok(());
    }
    Err(Error::InvalidArgument {
        name: "density-scale".into(),
        reason: format!("{density_scale} is not a finite non-negative number"),
    })
}

/// The affine map of row-major 3x4 rows (column vectors) and its inverse, or an error when
/// it has no finite inverse.
/// Voxel edge lengths umbra traces, in world units: far below `1e-30` the determinant of the
/// map underflows (a `1e-150` voxel has determinant `1e-450`, i.e. 0 in `f64`), far above
/// `1e30` optical depths overflow for any density.
pub const VOXEL_SIZE_RANGE: (f64, f64) = (1e-30, 1e30);
/// The smallest voxel, relative to the largest world coordinate of the grid's box, that `f64`
/// resolves: `2^-36` leaves `2^16` representable values per voxel (52-bit mantissa), so ray
/// positions inside a voxel are exact to `1.5e-5` voxels. A unit voxel at `1e17` (where
/// consecutive doubles are 16 apart) is refused; a 1 mm voxel at 10 km is fine.
pub const MIN_VOXEL_PER_COORDINATE: f64 = 1.0 / (1u64 << 36) as f64;
/// `|det|` of the map with its columns normalised (the volume of a voxel relative to the
/// cube of its edges) below which the voxel axes are taken as parallel.
const MIN_NORMALISED_DETERMINANT: f64 = 1e-9;

/// Check `world = M index` for tracing and invert it: finite, each voxel edge (column length)
/// in [`VOXEL_SIZE_RANGE`], axes not (nearly) parallel, and voxels resolvable by `f64` at the
/// world coordinates of `index_box` (the volume box, `[lo, hi]` in index space). The inverse is
/// computed as `M^-1 = S^-1 N^-1` with `N = M S^-1` (`S` the edge lengths), which stays finite
/// where the determinant of `M` itself would underflow.
fn invert_affine(
    m: &[[f64; 4]; 3],
    index_box: Option<[[i64; 3]; 2]>,
) -> Result<(DAffine3, DAffine3)> {
    let bad = |reason: String| Error::InvalidArgument {
        name: "transform".into(),
        reason,
    };
    if !m.iter().flatten().all(|v| v.is_finite()) {
        return Err(bad(format!("non-finite entries in {m:?}")));
    }
    let col = |c: usize| DVec3::new(m[0][c], m[1][c], m[2][c]);
    let fwd = DAffine3 {
        matrix3: DMat3::from_cols(col(0), col(1), col(2)),
        translation: col(3),
    };
    let edges = [0, 1, 2].map(|c| col(c).length());
    let (lo, hi) = VOXEL_SIZE_RANGE;
    for (axis, &e) in ["x", "y", "z"].iter().zip(&edges) {
        if !(lo..=hi).contains(&e) {
            return Err(bad(format!(
                "voxel size {} along index {axis} is outside the range umbra traces ({lo:e} to \
                 {hi:e} world units){}",
                crate::math::short(e),
                if e == 0.0 {
                    ": the voxels have no volume"
                } else {
                    ""
                }
            )));
        }
    }
    let n = DMat3::from_cols(col(0) / edges[0], col(1) / edges[1], col(2) / edges[2]);
    let det_n = n.determinant();
    if det_n.is_nan() || det_n.abs() < MIN_NORMALISED_DETERMINANT {
        return Err(bad(format!(
            "the voxel axes are (nearly) parallel (normalised determinant {}): the voxels have \
             no volume and the map cannot be inverted",
            crate::math::short(det_n)
        )));
    }
    let inv_n = n.inverse();
    let s_inv = DMat3::from_diagonal(DVec3::from(edges.map(|e| 1.0 / e)));
    let inv_m = s_inv * inv_n;
    let inv = DAffine3 {
        matrix3: inv_m,
        translation: -(inv_m * fwd.translation),
    };
    if !inv.is_finite() {
        return Err(bad("the inverse map is not finite".into()));
    }
    if let Some([blo, bhi]) = index_box {
        let mut far = fwd.translation.abs().max_element();
        for k in 0..8 {
            let p = DVec3::new(
                if k & 4 == 0 { blo[0] } else { bhi[0] + 1 } as f64,
                if k & 2 == 0 { blo[1] } else { bhi[1] + 1 } as f64,
                if k & 1 == 0 { blo[2] } else { bhi[2] + 1 } as f64,
            );
            far = far.max(fwd.transform_point3(p).abs().max_element());
        }
        let voxel = edges[0].min(edges[1]).min(edges[2]);
        let need = far * MIN_VOXEL_PER_COORDINATE;
        if voxel < need {
            return Err(bad(format!(
                "voxel size {} is too small for f64 to resolve at world coordinates up to {}: \
                 there a voxel must be at least {} (move the grid nearer the origin or use \
                 larger voxels)",
                crate::math::short(voxel),
                crate::math::short(far),
                crate::math::short(need)
            )));
        }
    }
    Ok((fwd, inv))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn singular_and_non_finite_maps_are_refused() {
        let mut m = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 0.0],
        ];
        assert!(invert_affine(&m, None).is_err());
        m[2][2] = 5e-324;
        assert!(
            invert_affine(&m, None).is_err(),
            "subnormal scale: inverse overflows"
        );
        m[2][2] = f64::NAN;
        assert!(invert_affine(&m, None).is_err());
    }

    fn reason(m: &[[f64; 4]; 3], index_box: Option<[[i64; 3]; 2]>) -> String {
        match invert_affine(m, index_box) {
            Err(Error::InvalidArgument { reason, .. }) => reason,
            other => panic!("expected a refusal, got {other:?}"),
        }
    }

    #[test]
    fn ill_conditioned_maps_say_which_condition() {
        let diag = |h: f64, t: f64| [[h, 0.0, 0.0, t], [0.0, h, 0.0, t], [0.0, 0.0, h, t]];
        let unit_box = Some([[0; 3], [7; 3]]);
        let r = reason(&diag(1e-150, 0.0), unit_box);
        assert!(
            r.contains("voxel size 1e-150") && !r.contains("determinant"),
            "{r}"
        );
        assert!(reason(&diag(1e31, 0.0), unit_box).contains("voxel size 1e31"));
        let r = reason(&diag(1.0, 1e17), unit_box);
        assert!(r.contains("too small for f64") && r.contains("1e17"), "{r}");
        let mut parallel = diag(1.0, 0.0);
        parallel[0][1] = 1.0;
        parallel[1][1] = 1e-12;
        parallel[2][2] = 1.0;
        assert!(reason(&parallel, unit_box).contains("parallel"));
        // Resolvable: 1 mm voxels 10 km away, unit voxels over the whole i32 range, and tiny
        // voxels near the origin (the inverse is finite even where det M underflows).
        assert!(invert_affine(&diag(1e-3, 1e4), unit_box).is_ok());
        assert!(
            invert_affine(&diag(1.0, 0.0), Some([[-(1 << 31); 3], [(1 << 31) - 1; 3]])).is_ok()
        );
        let (_, inv) = invert_affine(&diag(1e-29, 0.0), unit_box).expect("tiny voxels");
        assert!((inv.matrix3.x_axis.x - 1e29).abs() < 1e15);
    }

    #[test]
    fn inverse_affine_round_trips() {
        let m = [
            [0.1, 0.02, 0.0, 3.0],
            [-0.03, 0.2, 0.01, -1.0],
            [0.0, 0.05, 0.3, 7.0],
        ];
        let (fwd, inv) = invert_affine(&m, None).expect("invertible");
        let p = DVec3::new(1.5, -2.0, 9.0);
        let w = DVec3::from_array(
            [0, 1, 2].map(|r| m[r][0] * p.x + m[r][1] * p.y + m[r][2] * p.z + m[r][3]),
        );
        assert!((fwd.transform_point3(p) - w).length() < 1e-12);
        assert!((inv.transform_point3(w) - p).length() < 1e-12, "{w}");
    }
}

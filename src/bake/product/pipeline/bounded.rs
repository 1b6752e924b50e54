//! A bake in parts under a memory budget: [`BakeJob::plan_bounded`] sizes the parts from the
//! grid's topology (the sweep's regions, or runs of image rows on the ray path) and
//! [`BakeJob::trace_bounded`] bakes them, the whole bake's map bit for bit.

use super::{BakeJob, Product, Traced};
use crate::bake::Camera;
use crate::error::{Error, Result};
use crate::progress::{Progress, Work};
use crate::scene::Scene;

impl BakeJob {
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
    /// decoding the leaves its pixel rays touch onto a copy of the topology. A blurred map of a
    /// grid file goes by rows too, its shell set moving first (`moving.rs`: the velocity whole,
    /// the bounds from per-leaf ranges). Scene files, colour maps and a stage's blurred volume
    /// load whole.
    ///
    /// # Errors
    /// Output and settings errors; [`Error::InvalidArgument`] (name `max-memory`) when the
    /// budget is below the least a part needs (for the ray path an estimate: a run of rows
    /// whose rays touch more leaves than a part holds is baked as one part all the same);
    /// loading errors of the topology.
    pub fn plan_bounded(&self) -> Result<Option<BoundedPlan>> {
        let Some((budget, implied)) = self.budget() else {
            return Ok(None);
        };
        if self.settings.soft.is_some() {
            // A light with extent: every receiver's rays cross the whole grid (plan_map refuses
            // an explicit budget).
            return Ok(None);
        }
        self.check_outputs()?;
        self.settings.validate()?;
        let kind = self.source.kind();
        if kind.is_scene_file() || self.sigma_t().is_some() || (self.moving() && kind.is_stage()) {
            // Scenes, colour maps and a stage's blurred volume (its velocity field may be
            // another file's) load whole.
            return Ok(None);
        }
        let file = crate::input::GridFile::open(self.source.path())?;
        let Some(mut lazy) = file.lazy(&self.source.options().grid)? else {
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
        let shell = self.volume_of(lazy.take_shell())?;
        // A moving grid: its velocity loaded whole and its blurred bounds built from the
        // leaves' ranges, read a region at a time within what the budget leaves beside the
        // topology, the velocity and the process (`moving.rs`).
        let offsets = (leaves + 1) * 8;
        let (shell, motion) = match self.moving_shell(&lazy, shell, |velocity| {
            let per_region = topology + head_bytes + offsets + velocity + PROCESS_SLACK;
            budget.saturating_sub(per_region).max(MIN_SUMMARY_CHUNK)
        })? {
            Ok(m) => (m.shell, Some((m.held, m.building))),
            Err(still) => (still, None),
        };
        let (motion_held, motion_building) = motion.unwrap_or((0, 0));
        let shell = Scene::from_volume(shell);
        let (camera, depth_shift) = match self.camera {
            Some(c) => c.covering(&shell.box_corners()?),
            None => (Camera::frame(&self.view, &shell.box_corners()?)?, 0.0),
        };
        let image = camera.pixels() * (1 + self.depth_images()) * 12;
        // The whole grid, the image and the process itself.
        let whole = loaded + image + PROCESS_SLACK + motion_held;
        if whole <= budget {
            return Ok(None);
        }
        // Exact trilinear maps the sweep takes go in tree order (the sweep's own order);
        // every other map by runs of image rows on the ray path.
        let sweep = match shell.fogs().first() {
            // A blurred map goes by rows on the ray path (the sweep reads a still grid).
            _ if motion.is_some() => false,
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
        let samples_image = camera.pixels() * (1 + self.depth_images()) * 8 * (samples as u64 - 1);
        let Some(topo) = shell.fogs().first().map(|f| f.volume().tree()) else {
            return Ok(None);
        };
        // Held throughout: the topology (in the shell volume), the image and the process.
        let held = topology + offsets + image + PROCESS_SLACK + motion_held;
        let opening =
            topology + head_bytes + 2 * offsets + PROCESS_SLACK + motion_held + motion_building;
        let z = Sizes {
            budget,
            whole,
            held,
            opening,
            loaded,
            leaves,
            samples_image,
        };
        let Some((sweep, group_leaves, part_bytes)) =
            self.parts(topo, &z, sweep, samples, implied)?
        else {
            return Ok(None);
        };
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

    /// The memory budget a bake keeps to and whether it is the implied one: `--max-memory`, or
    /// without it [`IMPLIED_BUDGET`] for an exact map the sweep takes of an input of
    /// [`IMPLIED_MIN_FILE`] or more on disk (the cheap first test); `None` loads whole.
    fn budget(&self) -> Option<(u64, bool)> {
        match self.max_memory {
            Some(b) => Some((b, false)),
            None if self.product == Product::Map
                && self.is_exact_sweep()
                && file_len(self.source.path()) >= IMPLIED_MIN_FILE =>
            {
                Some((IMPLIED_BUDGET, true))
            }
            None => None,
        }
    }

    /// The depth images the map holds besides T (slices or given depths).
    fn depth_images(&self) -> u64 {
        match &self.settings.depths {
            crate::bake::Depths::None => 0,
            crate::bake::Depths::Slices(k) => *k as u64,
            crate::bake::Depths::At(d) => d.len() as u64,
        }
    }

    /// How the parts go, for sizes `z`: `(by the sweep, leaves per run of rows, bytes per
    /// region)`. The sweep's regions when it takes the map (a random march whose `samples` do
    /// not fit beside a part goes by rows on the ray path instead: the same estimate to the
    /// kernel's f32 positions, docs/loading.md), else runs of rows. `None` when the least part
    /// passes an implied budget (the grid loads whole).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `max-memory`) when it passes a given budget.
    fn parts(
        &self,
        topo: &crate::tree::Tree,
        z: &Sizes,
        sweep: bool,
        samples: usize,
        implied: bool,
    ) -> Result<Option<(bool, usize, u64)>> {
        let mut sweep = sweep;
        let (least, what, group_leaves, part_bytes) = if sweep {
            let p = sweep_part(topo, z);
            if samples > 1 && z.budget < p.0 {
                sweep = false;
                ray_part(topo, z)
            } else {
                p
            }
        } else {
            ray_part(topo, z)
        };
        if z.budget < least && implied {
            return Ok(None);
        }
        if z.budget < least {
            return Err(Error::InvalidArgument {
                name: "max-memory".into(),
                reason: format!(
                    "{} is below what baking {} needs: at least {} in parts (its topology, the \
                     image, {what}; opening it takes {}; the whole grid and the image need {})",
                    mib(z.budget),
                    self.source.path().display(),
                    mib(least),
                    mib(z.opening),
                    mib(z.whole)
                ),
            });
        }
        Ok(Some((sweep, group_leaves, part_bytes)))
    }

    /// Bake a `BoundedPlan`: the map the whole-grid bake would make, bit for bit, holding a
    /// part of the grid at a time. The sweep reports the bad voxels of the leaves its parts
    /// decoded (each leaf once: every leaf of a map that frames the whole grid) and of the
    /// tiles; the ray path those of the tiles only (its runs overlap).
    ///
    /// # Errors
    /// As [`BakeJob::run`].
    pub(super) fn trace_bounded(
        &self,
        plan: BoundedPlan,
        progress: &dyn Progress,
    ) -> Result<Traced> {
        progress.start(&Work {
            units: plan.camera.pixels(),
            what: "baking in parts",
            unit: Some("px"),
        });
        let volume_of = |g: crate::vdb::Grid| self.volume_of(g);
        let Some(shell) = plan.shell.fogs().first().map(crate::scene::Fog::volume) else {
            return Err(Error::Invalid {
                path: self.source.path().to_path_buf(),
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
                        self.source.path().display()
                    ),
                });
            };
            (map, streamed.sanitized)
        } else {
            // A moving grid's parts share the shell's motion (its bounds are the whole grid's).
            let load = |ids: &[u32]| {
                self.volume_of(plan.lazy.load_from(shell.tree(), ids)?)?
                    .with_motion_of(shell)
            };
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

/// The least bytes of leaf values a moving grid's summary pass decodes at a time, whatever
/// the budget (a budget too small for the parts is refused after it, by `parts`).
const MIN_SUMMARY_CHUNK: u64 = 4 << 20;

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

/// A size in MiB, as the refusals word it.
fn mib(b: u64) -> String {
    crate::math::size(b)
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

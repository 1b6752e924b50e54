//! Where a scene can hold density, as world spheres in two levels, for receivers toward a
//! light with extent answered without sampling ([`super::SoftLight::answer_each`], every
//! product's one path): a receiver whose light's whole cone (every direction toward the
//! light, as far as its segments run) misses every sphere meets no density, so `T = 1`
//! exactly; one whose cone only grazes a few voxels has a bound on every direction's optical
//! depth.
//!
//! **Blocks.** Per fog volume: the non-zero values of every leaf, as one box per `4^3` octant
//! around the voxels that hold them, every lower-node tile whose value is not
//! zero, every non-zero upper-node tile, as index boxes grown by one voxel on each side (the
//! reach of a trilinear lookup, and one more), grouped by lower node; a solid is its box. Each
//! block and each group is bounded by the world sphere around its transformed box.
//!
//! **Voxels.** A cone that meets an octant's box may still pass between its voxels (a wisp at
//! a cloud's edge, a cone that grazes it): each octant keeps the mask of its non-zero voxels
//! and their largest `|value|`, and such a cone is tested against each voxel's own box `[v -
//! 1, v + 1]` (what a trilinear lookup reads it from, grown by [`REACH_MARGIN`]). Missing all
//! of them proves `T = 1` where the rule-of-three count would otherwise trace.
//!
//! **Grazing cones** ([`Occupancy::optical_bound`]). A cone that meets a voxel's box but stays
//! outside the inner box `[v - (1 - e), v + (1 - e)]` (for the thinnest of the depths
//! [`SHELLS`]) reads that voxel with a trilinear weight `prod_k (1 - |p_k - v_k|) <= e`
//! everywhere, along a chord no longer than the box's world diameter `2 r`: the voxel adds at
//! most `mu |value| e 2 r` to any direction's optical depth. The sum `B` over every voxel the
//! cone meets bounds every direction's `tau`, so `e^-B <= T(w) <= 1` for every direction `w`
//! of the light, not only the ones drawn.
//!
//! **When nothing is proven.** A volume whose background is not zero (density everywhere in
//! its box), with a non-zero root tile, or moving (motion blur moves density), makes
//! [`Occupancy::misses`] always false: every receiver is sampled.

use crate::scene::Scene;
use crate::volume::Volume;
use glam::{DAffine3, DMat3, DVec3};

/// A world sphere and a world box, both around the same place.
#[derive(Debug, Clone, Copy)]
struct Sphere {
    centre: DVec3,
    radius: f64,
    lo: DVec3,
    hi: DVec3,
}

impl Sphere {
    /// The sphere and box around the world points `corners`.
    fn around(corners: &[DVec3]) -> Self {
        let lo = corners.iter().fold(DVec3::INFINITY, |a, b| a.min(*b));
        let hi = corners.iter().fold(DVec3::NEG_INFINITY, |a, b| a.max(*b));
        let centre = (lo + hi) / 2.0;
        let radius = corners
            .iter()
            .map(|c| (*c - centre).length())
            .fold(0.0, f64::max);
        Self {
            centre,
            radius,
            lo,
            hi,
        }
    }

    /// The sphere and box around `parts`.
    fn of_parts(parts: &[Self]) -> Self {
        let lo = parts.iter().fold(DVec3::INFINITY, |a, p| a.min(p.lo));
        let hi = parts.iter().fold(DVec3::NEG_INFINITY, |a, p| a.max(p.hi));
        let centre = (lo + hi) / 2.0;
        let radius = parts
            .iter()
            .map(|p| (p.centre - centre).length() + p.radius)
            .fold(0.0, f64::max);
        Self {
            centre,
            radius,
            lo,
            hi,
        }
    }
}

/// A group of blocks (one lower node's, one `32^3` brick of it, an upper tile, a solid) and its
/// bounding sphere: its blocks and the groups inside it.
#[derive(Debug, Clone)]
struct Group {
    bound: Sphere,
    parts: Vec<Group>,
    blocks: Vec<Block>,
}

/// One block: its sphere and box, and for a leaf's octant its non-zero voxels.
#[derive(Debug, Clone, Copy)]
struct Block {
    bound: Sphere,
    voxels: Option<Voxels>,
}

/// The non-zero voxels of a leaf's `4^3` octant: bit `16 x + 4 y + z` of `mask` for voxel
/// `origin + (x, y, z)` (index space of fog volume `volume`), and the largest `|value|` among
/// them (NaN if one is NaN).
#[derive(Debug, Clone, Copy)]
struct Voxels {
    origin: [i32; 3],
    mask: u64,
    volume: u32,
    most: f32,
}

/// Where density can be (module docs); `None`: anywhere.
#[derive(Debug, Clone)]
pub struct Occupancy {
    groups: Option<Vec<Group>>,
    /// Each fog volume's index-to-world map (for its voxels' boxes).
    xforms: Vec<Frame>,
}

/// The world sphere and box around the index box `[lo, hi]` of `vol`.
fn sphere(vol: &Volume, lo: DVec3, hi: DVec3) -> Sphere {
    let corners: Vec<DVec3> = (0..8)
        .map(|k| {
            vol.to_world(DVec3::new(
                if k & 1 == 0 { lo.x } else { hi.x },
                if k & 2 == 0 { lo.y } else { hi.y },
                if k & 4 == 0 { lo.z } else { hi.z },
            ))
        })
        .collect();
    Sphere::around(&corners)
}

/// Whether a node's values are all zero (an unknown or empty bound is not).
fn zero(b: crate::tree::Bounds) -> bool {
    b.min == 0.0 && b.max == 0.0
}

/// The index box of the `edge`-voxel block at `origin`, grown by one voxel and one more.
fn grown(origin: [i32; 3], edge: f64) -> (DVec3, DVec3) {
    let o = DVec3::new(
        f64::from(origin[0]),
        f64::from(origin[1]),
        f64::from(origin[2]),
    );
    (o - 2.0, o + edge + 2.0)
}

/// Voxels added around a trilinear lookup's reach, for the rounding of world-to-index
/// transforms (relative `1e-16`, far below it at any coordinate a tree holds).
const REACH_MARGIN: f64 = 1e-3;

/// The boxes around a leaf's non-zero values (an unloaded leaf's NaN included), one per
/// `4^3` octant that holds any: the index box `[v_lo - 1, v_hi + 1]` of those voxels (what a
/// trilinear lookup reads them from), grown by [`REACH_MARGIN`]. A wisp at a cloud's edge is then a box a few voxels wide, not its leaf's.
fn octant_boxes(origin: [i32; 3], values: &[f32; 512], out: &mut Vec<Boxed>) {
    for oct in 0..8usize {
        let o = [4 * (oct >> 2), 4 * ((oct >> 1) & 1), 4 * (oct & 1)];
        let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
        let mut mask = 0u64;
        let mut most = 0.0f32;
        for x in o[0]..o[0] + 4 {
            for y in o[1]..o[1] + 4 {
                for z in o[2]..o[2] + 4 {
                    // `leaf_offset`'s layout; NaN is not zero.
                    let v = values[(x << 6) | (y << 3) | z];
                    if v != 0.0 {
                        // NaN stays NaN (`max` would drop it).
                        most = if v.is_nan() || most.is_nan() {
                            f32::NAN
                        } else {
                            most.max(v.abs())
                        };
                        lo = [lo[0].min(x), lo[1].min(y), lo[2].min(z)];
                        hi = [hi[0].max(x), hi[1].max(y), hi[2].max(z)];
                        mask |= 1 << (16 * (x - o[0]) + 4 * (y - o[1]) + (z - o[2]));
                    }
                }
            }
        }
        if lo[0] == usize::MAX {
            continue;
        }
        let at = |k: usize, v: usize| f64::from(origin[k]) + v as f64;
        let l = DVec3::new(at(0, lo[0]), at(1, lo[1]), at(2, lo[2]));
        let h = DVec3::new(at(0, hi[0] + 1), at(1, hi[1] + 1), at(2, hi[2] + 1));
        // A trilinear lookup at `p` reads voxel `v` only for `v - 1 < p < v + 1` (a nearest
        // one within half a voxel): the voxels' boxes grown by one (`h` is already `v_hi +
        // 1`), and a thousandth of a voxel for the rounding of transforms.
        let corner = [0, 1, 2].map(|k| origin[k] + o[k] as i32);
        out.push((
            l - (1.0 + REACH_MARGIN),
            h + REACH_MARGIN,
            Some((corner, mask, most)),
        ));
    }
}

/// An index box and, for a leaf's octant, its first voxel and non-zero voxels' mask.
type Boxed = (DVec3, DVec3, Option<([i32; 3], u64, f32)>);

/// The groups of one volume (fog volume number `id`), `None` when it may hold density anywhere.
fn volume_groups(vol: &Volume, id: u32) -> Option<Vec<Group>> {
    let tree = vol.tree();
    if tree.background() != 0.0 || vol.motion().is_some() {
        return None;
    }
    let root_tiles = tree
        .root()
        .iter()
        .any(|e| matches!(e.slot, crate::tree::RootSlot::Tile { value, .. } if value != 0.0));
    if root_tiles {
        return None;
    }
    let mut groups = Vec::new();
    let bound = |boxes: &[Boxed]| {
        let lo = boxes.iter().fold(DVec3::INFINITY, |a, b| a.min(b.0));
        let hi = boxes.iter().fold(DVec3::NEG_INFINITY, |a, b| a.max(b.1));
        (lo, hi)
    };
    let group = |boxes: Vec<Boxed>| -> Option<Group> {
        let (lo, hi) = bound(&boxes);
        (!boxes.is_empty()).then(|| Group {
            bound: sphere(vol, lo, hi),
            parts: Vec::new(),
            blocks: boxes
                .iter()
                .map(|(l, h, v)| Block {
                    bound: sphere(vol, *l, *h),
                    voxels: v.map(|(origin, mask, most)| Voxels {
                        origin,
                        mask,
                        volume: id,
                        most,
                    }),
                })
                .collect(),
        })
    };
    for lower in tree.lowers() {
        // The lower node's 64 bricks of 4^3 leaves (32^3 voxels), each a group.
        let mut bricks: Vec<Vec<Boxed>> = vec![Vec::new(); 64];
        for n in 0..4096usize {
            let at = [
                lower.origin[0] + 8 * (n >> 8) as i32,
                lower.origin[1] + 8 * ((n >> 4) & 15) as i32,
                lower.origin[2] + 8 * (n & 15) as i32,
            ];
            let brick = &mut bricks[((n >> 10) << 4) | (((n >> 6) & 3) << 2) | ((n >> 2) & 3)];
            if lower.has_child(n) {
                let leaf = &tree.leaves()[lower.slots[n] as usize];
                if !zero(leaf.bounds) {
                    octant_boxes(at, tree.values_of(leaf), brick);
                }
            } else if lower.tile_value(n) != 0.0 {
                let (lo, hi) = grown(at, 8.0);
                brick.push((lo, hi, None));
            }
        }
        let parts: Vec<Group> = bricks.into_iter().filter_map(group).collect();
        if parts.is_empty() {
            continue;
        }
        let bounds: Vec<Sphere> = parts.iter().map(|g| g.bound).collect();
        groups.push(Group {
            bound: Sphere::of_parts(&bounds),
            parts,
            blocks: Vec::new(),
        });
    }
    for upper in tree.uppers() {
        for n in 0..32768usize {
            if !upper.has_child(n) && upper.tile_value(n) != 0.0 {
                let at = [
                    upper.origin[0] + 128 * (n >> 10) as i32,
                    upper.origin[1] + 128 * ((n >> 5) & 31) as i32,
                    upper.origin[2] + 128 * (n & 31) as i32,
                ];
                let (lo, hi) = grown(at, 128.0);
                groups.extend(group(vec![(lo, hi, None)]));
            }
        }
    }
    Some(groups)
}

impl Occupancy {
    /// Where `scene` can hold density.
    #[must_use]
    pub fn of(scene: &Scene) -> Self {
        let mut groups = Vec::new();
        let mut xforms = Vec::new();
        for (id, f) in scene.fogs().iter().enumerate() {
            let vol = f.volume();
            let frame = Frame::of(vol, f.sigma());
            xforms.push(frame);
            // A volume without extinction (a density scale or sigma of 0) holds no density.
            if frame.mu == 0.0 {
                continue;
            }
            match volume_groups(vol, id as u32) {
                Some(g) => groups.extend(g),
                None => {
                    return Self {
                        groups: None,
                        xforms,
                    }
                }
            }
        }
        for s in scene.solids() {
            let Ok(c) = s.box_corners() else {
                return Self {
                    groups: None,
                    xforms,
                };
            };
            let bound = Sphere::around(&c);
            groups.push(Group {
                bound,
                parts: Vec::new(),
                blocks: vec![Block {
                    bound,
                    voxels: None,
                }],
            });
        }
        Self {
            groups: Some(groups),
            xforms,
        }
    }

    /// Whether every segment of the light's reach from a receiver (its whole cone, as long as
    /// its segments may run: [`crate::light::SoftLight::reach`]) provably misses every block:
    /// the cone misses every block's sphere. Every direction of the light, not the ones drawn.
    #[must_use]
    pub fn misses(&self, reach: &super::Reach) -> bool {
        self.optical_bound(reach, 0.0) == Some(0.0)
    }

    /// An upper bound `B` on the optical depth of every segment of the light's reach from a
    /// receiver (its whole cone), when that bound is at most `limit`: 0 when the cone misses
    /// every block ([`Occupancy::misses`]); else the sum over the voxels whose boxes it meets
    /// of [`Cone::voxel_bound`]; `None` when the bound is above `limit`, or the cone meets a
    /// tile, a solid or a NaN voxel, or nothing is proven for this scene. Every direction `w`
    /// of the cone then has `|T(w) - 1| <= e^B - 1`, and so has their mean.
    #[must_use]
    pub fn optical_bound(&self, reach: &super::Reach, limit: f64) -> Option<f64> {
        let groups = self.groups.as_ref()?;
        let cone = Cone::new(reach.apex, reach.axis, reach.half, reach.length);
        // The angular test holds for any half-angle (it compares directions from the apex).
        if !(cone.length.is_finite() && cone.apex.is_finite() && cone.half.is_finite()) {
            return None;
        }
        let mut sum = 0.0;
        for g in groups {
            sum += cone.group_bound(g, &self.xforms, limit - sum)?;
        }
        (sum <= limit).then_some(sum)
    }
}

/// A fog volume's index-to-world map and the world half-extent `|M| h` of a voxel's box
/// `[v - 1, v + 1]` grown by [`REACH_MARGIN`] (`h` its index half-edge, `|M|` the entrywise
/// absolute matrix): the box `centre +- |M| h` holds the image of every corner.
#[derive(Debug, Clone, Copy)]
struct Frame {
    xf: DAffine3,
    half: DVec3,
    /// The world half-extents of the shells' inner boxes `[v - (1 - e), v + (1 - e)]` grown
    /// by [`REACH_MARGIN`], one per `e` of [`SHELLS`].
    inner: [DVec3; SHELLS.len()],
    /// `mu` per unit value: the largest `sigma` times the density scale.
    mu: f64,
}

/// The depths `e` (voxels) of the shells a grazing cone is bounded by ([`Cone::voxel_bound`]),
/// increasing.
const SHELLS: [f64; 8] = [2e-3, 5e-3, 1e-2, 2e-2, 5e-2, 0.1, 0.2, 0.4];

impl Frame {
    fn of(vol: &Volume, sigma: [f64; 3]) -> Self {
        let xf = vol.world_from_index();
        let m = xf.matrix3;
        let abs = DMat3::from_cols(m.x_axis.abs(), m.y_axis.abs(), m.z_axis.abs());
        let s = sigma.iter().copied().fold(0.0f64, f64::max);
        Self {
            xf,
            half: abs * DVec3::splat(1.0 + REACH_MARGIN),
            inner: SHELLS.map(|e| abs * DVec3::splat(1.0 - e + REACH_MARGIN)),
            mu: crate::math::scaled(s, vol.density_scale()),
        }
    }

    /// The world box (and sphere) around voxel `v`'s index box of half-edge given by `half`.
    fn voxel_box(&self, v: [i32; 3], half: DVec3) -> Sphere {
        let c = DVec3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]));
        let centre = self.xf.transform_point3(c);
        Sphere {
            centre,
            radius: half.length(),
            lo: centre - half,
            hi: centre + half,
        }
    }
}

/// The cone around a receiver's rays, with the cosine and sine of its half-angle widened by
/// `1e-9` (a margin for rounding).
#[derive(Debug, Clone, Copy)]
struct Cone {
    apex: DVec3,
    axis: DVec3,
    half: f64,
    length: f64,
    cos: f64,
    sin: f64,
}

impl Cone {
    fn new(apex: DVec3, axis: DVec3, half: f64, length: f64) -> Self {
        let (sin, cos) = (half + 1e-9).sin_cos();
        Self {
            apex,
            axis,
            half,
            length,
            cos,
            sin,
        }
    }

    /// [`Occupancy::optical_bound`] over the group `g`, `None` beyond `limit`.
    fn group_bound(&self, g: &Group, xforms: &[Frame], limit: f64) -> Option<f64> {
        if self.misses(g.bound) {
            return Some(0.0);
        }
        let mut sum = 0.0;
        for p in &g.parts {
            sum += self.group_bound(p, xforms, limit - sum)?;
        }
        for b in &g.blocks {
            if self.misses(b.bound) {
                continue;
            }
            // A tile or a solid the cone meets: no bound.
            sum += self.voxels_bound(b.voxels?, xforms, limit - sum)?;
        }
        (sum <= limit).then_some(sum)
    }

    /// The optical depth a segment of the cone can gather from the voxels of `v`: per voxel
    /// whose box `[v - 1, v + 1]` the cone meets, `mu |value| e d` ([`Cone::voxel_bound`]);
    /// `None` beyond `limit`.
    fn voxels_bound(&self, v: Voxels, xforms: &[Frame], limit: f64) -> Option<f64> {
        let xf = xforms.get(v.volume as usize)?;
        let mu = crate::math::scaled(xf.mu, f64::from(v.most));
        let mut sum = 0.0;
        for b in (0..64).filter(|b| v.mask >> b & 1 == 1) {
            let at = [b >> 4, (b >> 2) & 3, b & 3];
            let voxel = [0, 1, 2].map(|k| v.origin[k] + at[k]);
            let full = xf.voxel_box(voxel, xf.half);
            if self.misses(full) {
                continue;
            }
            if limit <= 0.0 {
                return None;
            }
            sum += self.voxel_bound(xf, voxel, full.radius, mu)?;
            // NaN (a NaN voxel) is beyond any limit.
            if sum.is_nan() || sum > limit {
                return None;
            }
        }
        Some(sum)
    }

    /// A bound on what voxel `voxel` (`mu` its largest extinction, `radius` the half-diagonal
    /// of the world box around its box) adds to the optical depth of any segment of the cone,
    /// when the cone stays in the shell `1 - e <= max_k |p_k - v_k| <= 1` of its box (index
    /// space) for the thinnest `e` of [`SHELLS`]: a trilinear lookup at `p` weighs voxel `v` by
    /// `prod_k (1 - |p_k - v_k|) <= 1 - max_k |p_k - v_k| <= e`, and a segment crosses the box
    /// within its diameter, so the voxel adds at most `mu e 2 radius`. `None` when the cone
    /// reaches inside every shell.
    fn voxel_bound(&self, xf: &Frame, voxel: [i32; 3], radius: f64, mu: f64) -> Option<f64> {
        let k = (0..SHELLS.len()).find(|&k| self.misses(xf.voxel_box(voxel, xf.inner[k])))?;
        let b = mu * SHELLS[k] * 2.0 * radius;
        b.is_finite().then_some(b)
    }

    /// Whether no point of the cone within `length` of its apex is in the sphere `s`: the
    /// angle between the axis and the sphere's centre is more than the half-angle `h` plus the
    /// sphere's angular radius `b = asin(r / d)`. Without trigonometry: for `h + b < pi`, that
    /// is `cos(angle) < cos(h + b)`, i.e. `v . axis < cos(h) sqrt(d^2 - r^2) - sin(h) r`; and
    /// `h + b >= pi` (never a miss) only when `h >= pi / 2` and `r / d >= sin(h)`.
    fn misses(&self, s: Sphere) -> bool {
        let v = s.centre - self.apex;
        let dist = v.length();
        if !dist.is_finite() || dist <= s.radius {
            return false;
        }
        if dist - s.radius > self.length {
            return true;
        }
        let wide = self.half + 1e-9;
        if wide >= std::f64::consts::PI
            || (wide >= std::f64::consts::FRAC_PI_2 && s.radius >= self.sin * dist)
        {
            return false;
        }
        let edge = self.cos * ((dist - s.radius) * (dist + s.radius)).sqrt() - self.sin * s.radius;
        v.dot(self.axis) < edge || self.misses_box(s.lo, s.hi)
    }

    /// Whether the cone misses the world box `[lo, hi]`, for a cone narrower than a half-space:
    /// every point of the cone within `s` of the apex is within `s sin(h)` of its axis segment
    /// `[apex, apex + length axis]`, so a cone that reaches the box's farthest corner at `s`
    /// lies, near the box, within the segment grown by `g = s sin(h)`; the segment missing the
    /// box grown by `g` on every side (a slab test) proves it. Much tighter than the sphere for
    /// a thin cone (a sun) beside a small box.
    fn misses_box(&self, lo: DVec3, hi: DVec3) -> bool {
        if self.half + 1e-9 >= std::f64::consts::FRAC_PI_2 || !(lo.is_finite() && hi.is_finite()) {
            return false;
        }
        let far = (0..8)
            .map(|k| {
                let c = DVec3::new(
                    if k & 1 == 0 { lo.x } else { hi.x },
                    if k & 2 == 0 { lo.y } else { hi.y },
                    if k & 4 == 0 { lo.z } else { hi.z },
                );
                (c - self.apex).length()
            })
            .fold(0.0, f64::max);
        let reach = far.min(self.length);
        // Grown by the cone's reach and a relative margin for rounding.
        let g = reach * self.sin + 1e-9 * (far + lo.abs().max(hi.abs()).max_element());
        let (lo, hi) = (lo - g, hi + g);
        let (mut t0, mut t1) = (0.0f64, reach);
        for k in 0..3 {
            let (o, d) = (self.apex[k], self.axis[k]);
            if d == 0.0 {
                if o < lo[k] || o > hi[k] {
                    return true;
                }
                continue;
            }
            let (a, b) = ((lo[k] - o) / d, (hi[k] - o) / d);
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        t0 > t1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scene of one volume whose only non-zero voxels are `voxels` (value 1), voxels of
    /// half a world unit, moved off the origin.
    fn voxels(voxels: &[[i32; 3]]) -> Scene {
        let mut b = crate::tree::TreeBuilder::new(0.0);
        for v in voxels {
            b.set(*v, 1.0);
        }
        let xf = [
            [0.5, 0.0, 0.0, 1.0],
            [0.0, 0.5, 0.0, -2.0],
            [0.0, 0.0, 0.5, 0.25],
        ];
        let vol = Volume::from_tree("v".into(), b.build(), xf, 1.0).expect("volume");
        Scene::from_volume(vol)
    }

    #[test]
    fn a_cone_between_the_voxels_of_one_octant_is_proven_clear() {
        // Voxels (0,0,0) and (3,3,3): one octant, whose box [-1, 4]^3 holds the line x = 3,
        // y = 0 along z, which misses both voxels' boxes [-1, 1]^3 and [2, 4]^3.
        let scene = voxels(&[[0, 0, 0], [3, 3, 3]]);
        let occ = Occupancy::of(&scene);
        let vol = scene.single().expect("one volume");
        let world = |p: [f64; 3]| vol.to_world(DVec3::from_array(p));
        let reach = |at: [f64; 3], half: f64| crate::light::Reach {
            apex: world(at),
            axis: DVec3::Z,
            half,
            length: 100.0,
        };
        // Below the voxels, looking up the z axis through the octant.
        assert!(occ.misses(&reach([3.0, 0.0, -20.0], 1e-3)));
        assert!(occ.misses(&reach([0.0, 3.0, -20.0], 1e-3)));
        // Through a voxel's box, or wide enough to reach one: sampled.
        assert!(!occ.misses(&reach([3.0, 2.5, -20.0], 1e-3)));
        assert!(!occ.misses(&reach([0.5, 0.0, -20.0], 1e-3)));
        assert!(!occ.misses(&reach([3.0, 0.0, -20.0], 0.12)));
        // The margin: a line just outside a voxel's reach is clear, one just inside is not.
        assert!(occ.misses(&reach([1.0 + 2e-3, 0.0, -20.0], 1e-9)));
        assert!(!occ.misses(&reach([1.0 - 1e-3, 0.0, -20.0], 1e-9)));
    }

    #[test]
    fn a_cone_in_a_voxels_outer_shell_is_bounded_above_its_optical_depth() {
        // One voxel of value 3 at the origin; cones along z at index x = 0.99 (inside the
        // voxel's reach [-1, 1], a trilinear weight of at most 0.01 there).
        let mut b = crate::tree::TreeBuilder::new(0.0);
        b.set([0, 0, 0], 3.0);
        let xf = [
            [0.5, 0.0, 0.0, 1.0],
            [0.0, 0.5, 0.0, -2.0],
            [0.0, 0.0, 0.5, 0.25],
        ];
        let vol = Volume::from_tree("v".into(), b.build(), xf, 2.0).expect("volume");
        let scene = Scene::from_volume(vol.clone());
        let occ = Occupancy::of(&scene);
        let world = |p: [f64; 3]| vol.to_world(DVec3::from_array(p));
        let reach = |x: f64, half: f64| crate::light::Reach {
            apex: world([x, 0.0, -20.0]),
            axis: DVec3::Z,
            half,
            length: 100.0,
        };
        let exact = |x: f64, dx: f64| {
            let ray = crate::ray::Ray::new(
                world([x, 0.0, -20.0]),
                DVec3::new(dx, 0.0, 1.0).normalize(),
                0.0,
                100.0,
            )
            .expect("ray");
            crate::regular::optical_depth(&vol, &ray, crate::volume::Interp::Trilinear)
                .expect("tau")
                .tau
        };
        // Not proven clear, but bounded: above every direction's optical depth (the axis and
        // both edges of the cone), and small.
        let half = 1e-4;
        assert!(!occ.misses(&reach(0.99, half)));
        let bound = occ.optical_bound(&reach(0.99, half), 1.0).expect("a bound");
        for dx in [-half, 0.0, half] {
            let tau = exact(0.99, dx);
            assert!(tau > 0.0 && tau <= bound, "tau {tau}, bound {bound}");
        }
        // The truth is 6 x 0.01 x 0.5 = 0.03 (mu, the weight, the integral of the tent along
        // z); the bound takes the next shell (0.02) and the box's diagonal for the chord.
        assert!(bound < 10.0 * exact(0.99, 0.0), "{bound}");
        // A limit below the bound gives none; a cone through the voxel has none; one outside
        // its reach is clear.
        assert_eq!(occ.optical_bound(&reach(0.99, half), bound / 2.0), None);
        assert_eq!(occ.optical_bound(&reach(0.3, half), 1.0), None);
        assert_eq!(occ.optical_bound(&reach(1.01, half), 1.0), Some(0.0));
        // With a density scale of 0 nothing anywhere has extinction: clear, even through it.
        let none = Volume::from_tree("v".into(), vol.tree().clone(), xf, 0.0).expect("volume");
        let occ = Occupancy::of(&Scene::from_volume(none));
        assert_eq!(occ.optical_bound(&reach(0.3, half), 1.0), Some(0.0));
        assert!(occ.misses(&reach(0.0, half)));
    }

    #[test]
    fn a_cone_misses_what_is_beside_or_beyond_it() {
        let cone = Cone::new(DVec3::ZERO, DVec3::Y, 0.1, 10.0);
        let s = |x: f64, y: f64, r: f64| Sphere {
            centre: DVec3::new(x, y, 0.0),
            radius: r,
            lo: DVec3::NEG_INFINITY,
            hi: DVec3::INFINITY,
        };
        assert!(!cone.misses(s(0.0, 5.0, 0.1)));
        assert!(cone.misses(s(3.0, 5.0, 0.1)));
        assert!(!cone.misses(s(0.8, 5.0, 0.4)));
        assert!(cone.misses(s(0.0, 12.0, 1.0)));
        assert!(!cone.misses(s(0.0, 0.0, 0.01)));
        assert!(cone.misses(s(0.0, -5.0, 1.0)));
        // Against the angular form, on spheres all around the apex and cones of every width.
        for half in [1e-6, 0.01, 0.3, 1.2, 1.6, 2.5, 3.1] {
            let cone = Cone::new(DVec3::ZERO, DVec3::Y, half, 1e9);
            for k in 0..2000 {
                let a = f64::from(k) * 0.618_033_988_75 * std::f64::consts::TAU;
                let b = (f64::from(k) / 2000.0 * 2.0 - 1.0).acos();
                let c = DVec3::new(b.sin() * a.cos(), b.cos(), b.sin() * a.sin()) * 10.0;
                let r = 0.01 + f64::from(k % 7) * 1.3;
                let sphere = Sphere {
                    centre: c,
                    radius: r,
                    lo: DVec3::NEG_INFINITY,
                    hi: DVec3::INFINITY,
                };
                let apart = b;
                let want = r < 10.0 && apart > half + (r / 10.0).asin() + 2e-9;
                let near = (apart - half - (r / 10.0).min(1.0).asin()).abs() < 1e-8;
                if !near {
                    assert_eq!(cone.misses(sphere), want, "half {half}, k {k}");
                }
            }
        }
    }

    #[test]
    fn a_thin_cone_misses_a_box_only_when_no_point_of_the_box_is_in_it() {
        // Boxes around a thin cone: whenever the box test says "misses", no point of a fine
        // grid over the box lies in the cone; and it does prove boxes beside the axis.
        let axis = DVec3::new(0.3, -1.0, 0.2).normalize();
        let mut proven = 0;
        for half in [0.0046, 0.035, 0.07, 0.5] {
            let cone = Cone::new(DVec3::new(1.0, 2.0, 3.0), axis, half, 80.0);
            for k in 0..400 {
                let f = f64::from(k);
                let along = (f * 0.173).fract() * 90.0;
                let side = DVec3::new(
                    (f * 0.311).fract() - 0.5,
                    (f * 0.419).fract() - 0.5,
                    (f * 0.577).fract() - 0.5,
                ) * 8.0;
                let lo = cone.apex + axis * along + side;
                let hi = lo + DVec3::splat(0.5 + (f * 0.127).fract() * 2.0);
                if !cone.misses_box(lo, hi) {
                    continue;
                }
                proven += 1;
                for i in 0..=8 {
                    for j in 0..=8 {
                        for l in 0..=8 {
                            let p = lo
                                + (hi - lo) * DVec3::new(f64::from(i), f64::from(j), f64::from(l))
                                    / 8.0;
                            let v = p - cone.apex;
                            let inside = v.length() <= cone.length
                                && v.normalize().dot(axis).clamp(-1.0, 1.0).acos() <= half;
                            assert!(!inside, "half {half}, box {k}: {p} is in the cone");
                        }
                    }
                }
            }
        }
        assert!(proven > 100, "{proven} boxes proven");
    }
}

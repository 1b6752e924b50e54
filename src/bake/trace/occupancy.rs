//! Where a scene can hold density, as world spheres in two levels, for a soft map's receivers
//! answered without sampling (`trace/soft.rs`): a receiver whose light's whole cone (every
//! direction toward the light, as far as its segments run) misses every sphere meets no
//! density, so `T = 1` exactly.
//!
//! **Blocks.** Per fog volume: every leaf and every lower-node tile whose values are not all
//! zero, every non-zero upper-node tile, as index boxes grown by one voxel on each side (the
//! reach of a trilinear lookup, and one more), grouped by lower node; a solid is its box. Each
//! block and each group is bounded by the world sphere around its transformed box.
//!
//! **When nothing is proven.** A volume whose background is not zero (density everywhere in
//! its box), with a non-zero root tile, or moving (motion blur moves density), makes
//! [`Occupancy::misses`] always false: every receiver is sampled.

use crate::scene::Scene;
use crate::volume::Volume;
use glam::DVec3;

/// A world sphere.
#[derive(Debug, Clone, Copy)]
struct Sphere {
    centre: DVec3,
    radius: f64,
}

/// A group of blocks (one lower node's, an upper tile, a solid) and its bounding sphere.
#[derive(Debug, Clone)]
struct Group {
    bound: Sphere,
    blocks: Vec<Sphere>,
}

/// Where density can be (module docs); `None`: anywhere.
#[derive(Debug, Clone)]
pub(crate) struct Occupancy {
    groups: Option<Vec<Group>>,
}

/// The world sphere around the index box `[lo, hi]` of `vol`.
fn sphere(vol: &Volume, lo: DVec3, hi: DVec3) -> Sphere {
    let centre = vol.to_world((lo + hi) / 2.0);
    let radius = (0..8)
        .map(|k| {
            let c = DVec3::new(
                if k & 1 == 0 { lo.x } else { hi.x },
                if k & 2 == 0 { lo.y } else { hi.y },
                if k & 4 == 0 { lo.z } else { hi.z },
            );
            (vol.to_world(c) - centre).length()
        })
        .fold(0.0, f64::max);
    Sphere { centre, radius }
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

/// The groups of one volume, `None` when it may hold density anywhere.
fn volume_groups(vol: &Volume) -> Option<Vec<Group>> {
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
    let group = |boxes: Vec<(DVec3, DVec3)>| -> Option<Group> {
        let lo = boxes.iter().fold(DVec3::INFINITY, |a, b| a.min(b.0));
        let hi = boxes.iter().fold(DVec3::NEG_INFINITY, |a, b| a.max(b.1));
        (!boxes.is_empty()).then(|| Group {
            bound: sphere(vol, lo, hi),
            blocks: boxes.iter().map(|(l, h)| sphere(vol, *l, *h)).collect(),
        })
    };
    for lower in tree.lowers() {
        let mut boxes = Vec::new();
        for n in 0..4096usize {
            let at = [
                lower.origin[0] + 8 * (n >> 8) as i32,
                lower.origin[1] + 8 * ((n >> 4) & 15) as i32,
                lower.origin[2] + 8 * (n & 15) as i32,
            ];
            let empty = if lower.has_child(n) {
                let leaf = &tree.leaves()[lower.slots[n] as usize];
                zero(leaf.bounds)
            } else {
                lower.tile_value(n) == 0.0
            };
            if !empty {
                boxes.push(grown(at, 8.0));
            }
        }
        groups.extend(group(boxes));
    }
    for upper in tree.uppers() {
        for n in 0..32768usize {
            if !upper.has_child(n) && upper.tile_value(n) != 0.0 {
                let at = [
                    upper.origin[0] + 128 * (n >> 10) as i32,
                    upper.origin[1] + 128 * ((n >> 5) & 31) as i32,
                    upper.origin[2] + 128 * (n & 31) as i32,
                ];
                groups.extend(group(vec![grown(at, 128.0)]));
            }
        }
    }
    Some(groups)
}

impl Occupancy {
    /// Where `scene` can hold density.
    pub(crate) fn of(scene: &Scene) -> Self {
        let mut groups = Vec::new();
        for f in scene.fogs() {
            match volume_groups(f.volume()) {
                Some(g) => groups.extend(g),
                None => return Self { groups: None },
            }
        }
        for s in scene.solids() {
            let Ok(c) = s.box_corners() else {
                return Self { groups: None };
            };
            let lo = c.iter().fold(DVec3::INFINITY, |a, b| a.min(*b));
            let hi = c.iter().fold(DVec3::NEG_INFINITY, |a, b| a.max(*b));
            let bound = Sphere {
                centre: (lo + hi) / 2.0,
                radius: (hi - lo).length() / 2.0,
            };
            groups.push(Group {
                bound,
                blocks: vec![bound],
            });
        }
        Self {
            groups: Some(groups),
        }
    }

    /// Whether every segment of the light's reach from a receiver (its whole cone, as long as
    /// its segments may run: [`crate::light::SoftLight::reach`]) provably misses every block:
    /// the cone misses every block's sphere. Every direction of the light, not the ones drawn.
    pub(crate) fn misses(&self, reach: &crate::light::Reach) -> bool {
        let Some(groups) = &self.groups else {
            return false;
        };
        let cone = Cone {
            apex: reach.apex,
            axis: reach.axis,
            half: reach.half,
            length: reach.length,
        };
        // The angular test holds for any half-angle (it compares directions from the apex).
        if !(cone.length.is_finite() && cone.apex.is_finite() && cone.half.is_finite()) {
            return false;
        }
        groups
            .iter()
            .all(|g| cone.misses(g.bound) || g.blocks.iter().all(|b| cone.misses(*b)))
    }
}

/// The cone around a receiver's rays.
#[derive(Debug, Clone, Copy)]
struct Cone {
    apex: DVec3,
    axis: DVec3,
    half: f64,
    length: f64,
}

impl Cone {
    /// Whether no point of the cone within `length` of its apex is in the sphere `s`.
    fn misses(&self, s: Sphere) -> bool {
        let v = s.centre - self.apex;
        let dist = v.length();
        if !dist.is_finite() || dist <= s.radius {
            return false;
        }
        if dist - s.radius > self.length {
            return true;
        }
        let apart = (v.dot(self.axis) / dist).clamp(-1.0, 1.0).acos();
        apart > self.half + (s.radius / dist).asin() + 1e-9
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cone_misses_what_is_beside_or_beyond_it() {
        let cone = Cone {
            apex: DVec3::ZERO,
            axis: DVec3::Y,
            half: 0.1,
            length: 10.0,
        };
        let s = |x: f64, y: f64, r: f64| Sphere {
            centre: DVec3::new(x, y, 0.0),
            radius: r,
        };
        assert!(!cone.misses(s(0.0, 5.0, 0.1)));
        assert!(cone.misses(s(3.0, 5.0, 0.1)));
        assert!(!cone.misses(s(0.8, 5.0, 0.4)));
        assert!(cone.misses(s(0.0, 12.0, 1.0)));
        assert!(!cone.misses(s(0.0, 0.0, 0.01)));
        assert!(cone.misses(s(0.0, -5.0, 1.0)));
    }
}

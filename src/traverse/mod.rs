//! Walking a ray through the tree: a uniform-grid DDA ([`dda`]) and the hierarchical DDA
//! ([`walk`]) built from it, which visits only the parts of the ray where the density can differ
//! from the background and reports each as a [`Segment`] with a majorant and a minorant.

mod dda;
mod hdda;

pub(crate) use dda::Dda;
pub use dda::{dda, Cells};
pub use hdda::{lookup_ray, walk, Granularity, Walk};
pub(crate) use hdda::{touched_blocks, walk_nodes};

/// A piece of a ray `[t_min, t_max]` (world units) inside one node or tile, with bounds on the
/// extinction `mu_t = scale * value` any lookup of the chosen interpolation can return there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Start, world units along the ray.
    pub t_min: f64,
    /// End, world units along the ray.
    pub t_max: f64,
    /// Minorant: `mu_t >= mu_min` everywhere in the segment.
    pub mu_min: f64,
    /// Majorant: `mu_t <= mu_maj` everywhere in the segment.
    pub mu_maj: f64,
    /// Tree level of the node that produced it: 1 leaf or 8^3 tile, 2 lower node or 128^3 tile,
    /// 3 upper node, 4096^3 tile or empty root cell.
    pub level: u8,
}

impl Segment {
    /// Length in world units.
    #[must_use]
    pub fn length(&self) -> f64 {
        self.t_max - self.t_min
    }
    /// True when the extinction is known to be constant (`mu_min == mu_maj`): the optical depth
    /// is `mu * length` in closed form and no lookup is needed.
    #[must_use]
    pub fn is_constant(&self) -> bool {
        self.mu_min == self.mu_maj
    }
}

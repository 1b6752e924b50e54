//! A lower bound on the optical depth of every segment of a light's cone from a receiver:
//! the proof that answers a receiver in umbra without sampling (issue 69).
//!
//! **The bound.** A direction `w` of the cone (within `half` of the unit `axis`) has its point
//! `x + t w` at most `rho(t) = 2 t sin(half / 2)` from the axis point `x + t a`, since
//! `|w - a| = 2 sin(theta / 2)`. So over `t` in `[t0, t1]` every direction's points lie in the
//! axis segment grown by `rho(t1)`; in index space, in the box `B` of the segment's image grown
//! by `rho(t1) |row_i(M)|` on axis `i` (`M` the index-from-world matrix). A trilinear
//! lookup is multilinear over each cell `[c, c + 1]`, so its least value over `B`'s part in a
//! cell is at one of that part's 8 corners; `m(B)` is the least over the cells `B` meets.
//! Every direction then has `tau(w) >= sum over steps of mu (t1 - t0) m(B)`, `mu` the
//! channel's `sigma` times the density scale; a step whose box leaves the volume box (where the
//! walk stops reading) adds 0. Values are sanitised (never negative); a NaN counts as 0.
//!
//! **Where it holds.** Every segment must run at least as far as the march: a sun's segments
//! run until they leave every volume's box, so the march runs to [`super::Reach::length`]; a
//! sphere light's end on the sphere, at least `d - r` from a receiver outside it. A solid only
//! lowers `T`, so it is left out. Not proven (`None`): a moving volume (its density is a blend
//! over the shutter), a partly loaded tree, nearest lookups (piecewise constant, not
//! multilinear), or a cone wider than a right angle.

use super::Reach;
use crate::scene::Scene;
use crate::tree::{Accessor, Window};
use glam::{DAffine3, DVec3};

/// One fog volume's march: its index map and the world length each step covers.
struct Fog<'s> {
    tree: &'s crate::tree::Tree,
    index_from_world: DAffine3,
    /// `|row_i(M)|`: the index half-extent on axis `i` of a world ball of radius 1.
    rows: DVec3,
    /// The volume box, index space: a step whose box leaves it adds nothing.
    lo: DVec3,
    hi: DVec3,
    /// `mu` per unit value, per channel: `sigma[c]` times the density scale.
    mu: [f64; 3],
}

/// Every fog volume of a scene, ready to bound optical depth from below.
pub struct Umbra<'s> {
    fogs: Vec<Fog<'s>>,
    channels: usize,
}

/// The most voxels a step's box may span on an axis: a wider box (a wide cone far from its
/// apex) adds 0 rather than read hundreds of voxels.
const MOST_SPAN: i64 = 6;

/// The march's step along the axis, voxels.
const STEP: f64 = 0.5;

impl<'s> Umbra<'s> {
    /// The bound's view of `scene` read with `interp`; `None` when nothing can be proven for
    /// it (a moving volume, a partly loaded tree, nearest lookups).
    #[must_use]
    pub fn of(scene: &'s Scene, interp: crate::Interp) -> Option<Self> {
        if interp != crate::Interp::Trilinear {
            return None;
        }
        let mut fogs = Vec::new();
        for f in scene.fogs() {
            let vol = f.volume();
            if vol.motion().is_some() || !vol.tree().is_complete() {
                return None;
            }
            let Some((lo, hi)) = vol.box_index() else {
                continue;
            };
            let index_from_world = vol.index_from_world();
            let m = index_from_world.matrix3.transpose();
            let rows = DVec3::new(m.x_axis.length(), m.y_axis.length(), m.z_axis.length());
            let mu = f
                .sigma()
                .map(|s| crate::math::scaled(s, vol.density_scale()));
            if !rows.is_finite() || mu.iter().any(|m| !m.is_finite()) {
                return None;
            }
            fogs.push(Fog {
                tree: vol.tree(),
                index_from_world,
                rows,
                lo,
                hi,
                mu,
            });
        }
        Some(Self {
            fogs,
            channels: scene.channels(),
        })
    }

    /// Per channel, a lower bound on the optical depth of every direction of `reach`'s cone
    /// over its first `shortest` (module docs), when the least channel's reaches `need`;
    /// `None` when it does not (the march stops as soon as it does).
    #[must_use]
    pub fn depth_at_least(&self, reach: &Reach, shortest: f64, need: f64) -> Option<[f64; 3]> {
        self.lower_depth(reach, shortest, need)
            .filter(|tau| self.least(tau) >= need)
    }

    /// Per channel, a lower bound on the optical depth of every direction of `reach`'s cone
    /// over its first `shortest`, its march stopped once the least channel's reaches `stop`
    /// (module docs); `None` when nothing is proven for this cone (wider than a right angle,
    /// not finite).
    #[must_use]
    pub fn lower_depth(&self, reach: &Reach, shortest: f64, stop: f64) -> Option<[f64; 3]> {
        if !(reach.half < std::f64::consts::FRAC_PI_2
            && shortest.is_finite()
            && shortest > 0.0
            && reach.apex.is_finite()
            && reach.axis.is_finite())
        {
            return None;
        }
        let spread = 2.0 * (reach.half / 2.0).sin() * (1.0 + 1e-9) + 1e-12;
        let mut tau = [0.0f64; 3];
        for f in &self.fogs {
            let got = f.depth(reach, shortest, spread, stop - self.least(&tau));
            for (t, mu) in tau.iter_mut().zip(f.mu) {
                *t += mu * got;
            }
            if self.least(&tau) >= stop {
                break;
            }
        }
        Some(tau)
    }

    /// The least of the scene's channels of `tau`.
    fn least(&self, tau: &[f64; 3]) -> f64 {
        tau[..self.channels]
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min)
    }
}

impl Fog<'_> {
    /// The least value integral `sum (t1 - t0) m(B)` over the cone's first `shortest`, stopped
    /// once the least channel's `mu` times it reaches `need`.
    fn depth(&self, reach: &Reach, shortest: f64, spread: f64, need: f64) -> f64 {
        let o = self.index_from_world.transform_point3(reach.apex);
        let d = self.index_from_world.transform_vector3(reach.axis);
        let per_world = d.length();
        let mu = self.mu.iter().copied().fold(f64::INFINITY, f64::min);
        if !(per_world > 0.0 && per_world.is_finite()) {
            return 0.0;
        }
        // STEP voxels of the axis a step; only where the grown axis meets the volume box.
        let dt = STEP / per_world;
        let grow = self.rows * (spread * shortest) + DVec3::splat(1e-9);
        let Some((t_in, t_out)) = crate::ray::clip_box(o, d, self.lo - grow, self.hi + grow) else {
            return 0.0;
        };
        let (start, end) = (t_in.max(0.0), t_out.min(shortest));
        let mut sum = 0.0;
        let mut acc = Accessor::new(self.tree);
        let mut window = Window::default();
        let mut t0 = start;
        while t0 < end {
            let t1 = (t0 + dt).min(end);
            let h = self.rows * (spread * t1) + DVec3::splat(1e-9);
            let (p0, p1) = (o + d * t0, o + d * t1);
            let (lo, hi) = (p0.min(p1) - h, p0.max(p1) + h);
            if lo.cmpge(self.lo).all() && hi.cmple(self.hi).all() {
                sum += (t1 - t0) * least_value(&mut acc, &mut window, lo, hi);
                if mu * sum >= need {
                    return sum;
                }
            }
            t0 = t1;
        }
        sum
    }
}

/// The least trilinear value over the index box `[lo, hi]`: over each cell `[c, c + 1]` it
/// meets, a trilinear function is multilinear, so its least value over the box's part in
/// that cell is at one of that part's 8 corners. 0 for a box wider than [`MOST_SPAN`] cells
/// on an axis; a NaN voxel counts as 0.
fn least_value(acc: &mut Accessor<'_>, window: &mut Window, lo: DVec3, hi: DVec3) -> f64 {
    let a = lo.floor();
    let b = hi.floor();
    if (b - a).max_element() >= MOST_SPAN as f64 || !a.is_finite() || !b.is_finite() {
        return 0.0;
    }
    let (a, b) = (a.as_i64vec3(), b.as_i64vec3());
    // The box's lattice of corners, copied once (a cell shares its corners with its
    // neighbours): `b - a + 2` a side.
    let n = (b - a + 2).as_uvec3().to_array().map(|c| c as usize);
    window.fill(acc, a.to_array(), n);
    // NaN and negative values read as 0 (`max` returns the number).
    let value = |i: usize, j: usize, k: usize| f64::from(window.at([i, j, k]).max(0.0));
    let mut least = f64::INFINITY;
    for i in 0..n[0] - 1 {
        for j in 0..n[1] - 1 {
            for k in 0..n[2] - 1 {
                let c = (a + glam::I64Vec3::new(i as i64, j as i64, k as i64)).as_dvec3();
                let u0 = (lo - c).max(DVec3::ZERO);
                let u1 = (hi - c).min(DVec3::ONE);
                let v: [f64; 8] =
                    std::array::from_fn(|m| value(i + (m & 1), j + (m >> 1 & 1), k + (m >> 2)));
                least = least.min(cell_least(&v, u0, u1));
                if least <= 0.0 {
                    return 0.0;
                }
            }
        }
    }
    least
}

/// The least value over `[u0, u1]` (inside the unit cell) of the trilinear interpolation of
/// the cell's corner values `v` (corner `n` at `(n & 1, n >> 1 & 1, n >> 2)`): the least of
/// its values at the sub-box's 8 corners.
fn cell_least(v: &[f64; 8], u0: DVec3, u1: DVec3) -> f64 {
    let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
    let mut least = f64::INFINITY;
    for x in [u0.x, u1.x] {
        let e = [
            lerp(v[0], v[1], x),
            lerp(v[2], v[3], x),
            lerp(v[4], v[5], x),
            lerp(v[6], v[7], x),
        ];
        for y in [u0.y, u1.y] {
            let (f0, f1) = (lerp(e[0], e[1], y), lerp(e[2], e[3], y));
            for z in [u0.z, u1.z] {
                least = least.min(lerp(f0, f1, z));
            }
        }
    }
    least
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::{Estimator, Options};
    use crate::ray::Ray;
    use crate::Volume;

    /// A 24^3 block of smoothly varying density (0.05..1.95, with a hole of zeros) under a
    /// rotated, scaled, moved index map.
    fn cloud() -> Scene {
        let mut b = crate::tree::TreeBuilder::new(0.0);
        for i in 0..24i32 {
            for j in 0..24i32 {
                for k in 0..24i32 {
                    let (x, y, z) = (f64::from(i), f64::from(j), f64::from(k));
                    let v = 1.0 + 0.95 * (0.7 * x + 0.3 * y).sin() * (0.5 * z - 0.2 * x).cos();
                    let hole = (i - 12).abs() < 2 && (k - 8).abs() < 2;
                    b.set([i, j, k], if hole { 0.0 } else { v as f32 });
                }
            }
        }
        let (c, s) = (0.8f64, 0.6f64);
        let xf = [
            [0.5 * c, -0.5 * s, 0.0, 1.0],
            [0.5 * s, 0.5 * c, 0.0, -2.0],
            [0.0, 0.0, 0.4, 0.25],
        ];
        let vol = Volume::from_tree("v".into(), b.build(), xf, 1.0).expect("volume");
        Scene::from_volume(vol)
    }

    /// A unit direction within `half` of `axis`: at `frac` of the half-angle, azimuth `phi`.
    fn within(axis: DVec3, half: f64, frac: f64, phi: f64) -> DVec3 {
        let u = axis.any_orthonormal_vector();
        let v = axis.cross(u);
        let th = half * frac;
        (axis * th.cos() + (u * phi.cos() + v * phi.sin()) * th.sin()).normalize()
    }

    #[test]
    fn every_direction_of_the_cone_is_at_least_as_deep_as_the_bound_and_the_bound_is_tight() {
        let scene = cloud();
        let umbra = Umbra::of(&scene, crate::Interp::Trilinear).expect("provable");
        let vol = scene.single().expect("one volume");
        let inside = vol.to_world(DVec3::new(12.0, 12.0, 3.5));
        let below = vol.to_world(DVec3::new(10.0, 11.0, -30.0));
        let (mut checked, mut tight) = (0, 0);
        for (apex, axis) in [
            (inside, DVec3::new(0.1, 0.2, 1.0).normalize()),
            (below, DVec3::new(0.05, -0.02, 1.0).normalize()),
            (inside, DVec3::new(1.0, 0.3, 0.2).normalize()),
        ] {
            for half in [1e-9, 4.6e-3, 0.035, 0.2] {
                let reach = Reach {
                    apex,
                    axis,
                    half,
                    length: 100.0,
                };
                let bound = umbra
                    .lower_depth(&reach, 100.0, f64::INFINITY)
                    .expect("bound")[0];
                let mut least = f64::INFINITY;
                for n in 0..64 {
                    let frac = if n % 4 == 0 { 1.0 } else { f64::from(n) / 64.0 };
                    let w = within(axis, half, frac, f64::from(n) * 2.4);
                    let ray = Ray::new(apex, w, 0.0, 100.0).expect("ray");
                    let e = crate::scene::estimate(
                        &scene,
                        &ray,
                        0,
                        &Estimator::REGULAR,
                        &Options::default(),
                    )
                    .expect("estimate");
                    let tau = e.tau.expect("exact")[0];
                    assert!(
                        tau >= bound * (1.0 - 1e-9),
                        "direction {n} of half {half}: tau {tau} below the bound {bound}"
                    );
                    least = least.min(tau);
                    checked += 1;
                }
                // A bound is of use only if it is near the truth for a thin cone.
                if half < 0.01 && bound > 0.8 * least {
                    tight += 1;
                }
            }
        }
        assert_eq!(checked, 3 * 4 * 64);
        assert!(tight >= 4, "{tight} thin cones bounded within 20%");
    }

    #[test]
    fn nothing_is_proven_for_nearest_lookups_wide_cones_or_a_segment_that_ends_at_once() {
        let scene = cloud();
        assert!(Umbra::of(&scene, crate::Interp::Nearest).is_none());
        let umbra = Umbra::of(&scene, crate::Interp::Trilinear).expect("provable");
        let vol = scene.single().expect("one volume");
        let reach = Reach {
            apex: vol.to_world(DVec3::new(12.0, 12.0, 3.5)),
            axis: DVec3::Z,
            half: 1.6,
            length: 100.0,
        };
        assert!(umbra.lower_depth(&reach, 100.0, f64::INFINITY).is_none());
        let thin = Reach {
            half: 1e-3,
            ..reach
        };
        assert!(umbra.lower_depth(&thin, 0.0, f64::INFINITY).is_none());
        assert!(umbra.depth_at_least(&thin, 100.0, 1e6).is_none());
        let deep = umbra
            .lower_depth(&thin, 100.0, f64::INFINITY)
            .expect("bound")[0];
        assert!(deep > 1.0, "{deep}");
        // Stopped once deep enough: at least what was asked, at most the whole march.
        let part = umbra
            .depth_at_least(&thin, 100.0, 1.0)
            .expect("deep enough")[0];
        assert!((1.0..=deep).contains(&part), "{part} of {deep}");
    }
}

//! Exact transmittance volumes toward a sun through the sweep, a layer of voxel centres at a
//! time (issue 69).
//!
//! Voxel `c`'s value is `T = exp(-tau)` along its ray toward the light. Toward a sun every ray
//! is parallel: the rays ending at one layer of voxel centres (index coordinate `k` along the
//! axis `a` the light's index-space direction moves most along) are a lattice,
//! `q0 + i e_b + j e_c + t d` with `e_b`, `e_c` the layer's two index axes and `d` the light's
//! lookup-space direction, each starting `S` world units before its voxel (`S` the world
//! diagonal of the volume box, so every start lies outside it) and ending at the voxel. The
//! sweep ([`crate::bake::trace::sweep::tau_lattice`]) integrates that lattice block by block
//! (each block's `9^3` corners read once for every ray of the layer that crosses it, the lane
//! kernel's exact integral of the trilinear field), where a ray per voxel walks the tree from
//! each voxel. The segment beyond the box holds no density (the sweep takes only trees with
//! nothing outside lower nodes), so it is the segment [`crate::Light::ray_from`] traces.
//!
//! Each layer's image is the rectangle of its leaves (in slabs of 8 layers, a row of leaves
//! along `a`); rays of inactive voxels in it are traced and dropped. A voxel's value is the
//! sweep's: within the kernel's f32 positions of the ray walk's (docs/performance.md, 1e-6
//! relative), the same whatever the thread count.

use crate::bake::trace::sweep::{tau_lattice, Lattice};
use crate::error::{Error, Result};
use crate::light::Light;
use crate::tree::bit;
use crate::vdb::LeafOut;
use crate::volume::Volume;
use glam::DVec3;
use std::collections::BTreeMap;

/// Most rays a volume's layers may trace per 100 voxels written: a dense volume's rectangles
/// hold about one ray per voxel; a sparse cloud's twice as many (the Houdini smoke: 2.0 M rays
/// for 1.05 M voxels, 2.9 s against 1.9 s by rays), and it goes by rays.
const MAX_WASTE_PERCENT: u64 = 125;

/// Exact trilinear T of every voxel of `leaves` toward the sun `light`, a layer of voxel
/// centres per sweep (module docs); `(rays, lookups)`, or `None` when the sweep cannot take
/// the volume or the light (then the caller traces a ray per voxel).
///
/// # Errors
/// A NaN optical depth (naming the voxel's ray).
pub(super) fn by_layers(
    vol: &Volume,
    light: &Light,
    leaves: &mut [LeafOut],
    progress: &dyn crate::progress::Progress,
) -> Result<Option<(u64, u64)>> {
    let Light::Directional { dir } = *light else {
        return Ok(None);
    };
    let (Some(travel), Some((lo, hi))) = (
        crate::math::normalise(DVec3::from_array(dir)),
        vol.box_index(),
    ) else {
        return Ok(None);
    };
    let d = vol.to_index_dir(travel);
    if !d.is_finite() {
        return Ok(None);
    }
    let a = (0..3)
        .max_by(|&x, &y| d[x].abs().total_cmp(&d[y].abs()))
        .unwrap_or(0);
    let (b, c) = ((a + 1) % 3, (a + 2) % 3);
    // Longer than any segment from a voxel to the box's far side.
    let span = (vol.to_world(hi + 1.0) - vol.to_world(lo - 1.0)).length()
        + (vol.to_world(DVec3::ZERO) - vol.to_world(DVec3::ONE)).length();
    if !(span.is_finite() && span > 0.0) {
        return Ok(None);
    }
    // Leaves in slabs of 8 layers along `a`.
    let mut slabs: BTreeMap<i32, Vec<usize>> = BTreeMap::new();
    for (n, leaf) in leaves.iter().enumerate() {
        slabs.entry(leaf.origin[a]).or_default().push(n);
    }
    // Each slab's layers trace the rectangle of its leaves: refused (a ray per voxel instead)
    // where those rectangles hold many more rays than voxels (a sparse cloud's slabs).
    let voxels: u64 = leaves
        .iter()
        .map(|l| u64::from(l.active.iter().map(|w| w.count_ones()).sum::<u32>()))
        .sum();
    let traced: u64 = slabs
        .values()
        .map(|m| {
            let side = |k: usize| {
                let lo = m
                    .iter()
                    .map(|&n| i64::from(leaves[n].origin[k]))
                    .min()
                    .unwrap_or(0);
                let hi = m
                    .iter()
                    .map(|&n| i64::from(leaves[n].origin[k]))
                    .max()
                    .unwrap_or(0);
                u64::try_from(hi - lo + 8).unwrap_or(u64::MAX)
            };
            side(b).saturating_mul(side(c)).saturating_mul(8)
        })
        .fold(0u64, u64::saturating_add);
    if traced.saturating_mul(100) > MAX_WASTE_PERCENT.saturating_mul(voxels) {
        return Ok(None);
    }
    let rows_for = |h: u32| crate::bake::trace::band_rows(h, rayon::current_num_threads());
    let (mut rays, mut lookups) = (0u64, 0u64);
    for (&k0, members) in &slabs {
        let lo_b = members.iter().map(|&n| leaves[n].origin[b]).min();
        let hi_b = members.iter().map(|&n| leaves[n].origin[b]).max();
        let lo_c = members.iter().map(|&n| leaves[n].origin[c]).min();
        let hi_c = members.iter().map(|&n| leaves[n].origin[c]).max();
        let (Some(b0), Some(b1), Some(c0), Some(c1)) = (lo_b, hi_b, lo_c, hi_c) else {
            continue;
        };
        let (Ok(width), Ok(height)) = (
            u32::try_from(i64::from(b1) - i64::from(b0) + 8),
            u32::try_from(i64::from(c1) - i64::from(c0) + 8),
        ) else {
            return Ok(None);
        };
        for layer in 0..8 {
            let k = i64::from(k0) + layer;
            let mut first = DVec3::ZERO;
            first[a] = k as f64;
            first[b] = f64::from(b0);
            first[c] = f64::from(c0);
            let (mut qx, mut qy) = (DVec3::ZERO, DVec3::ZERO);
            qx[b] = 1.0;
            qy[c] = 1.0;
            let lattice = Lattice {
                q0: (first - d * span).to_array(),
                qx: qx.to_array(),
                qy: qy.to_array(),
                d: d.to_array(),
                t_max: span,
                width,
                height,
            };
            let Some((tau, spent)) = tau_lattice(vol, &lattice, rows_for(height))? else {
                return Ok(None);
            };
            lookups += spent;
            rays += u64::from(width) * u64::from(height);
            let mut done = 0u64;
            for &n in members {
                let leaf = &mut leaves[n];
                // The leaf's 64 voxels in this layer.
                for uv in 0..64usize {
                    let mut ijk = [0usize; 3];
                    (ijk[a], ijk[b], ijk[c]) = (layer as usize, uv >> 3, uv & 7);
                    let v = (ijk[0] << 6) | (ijk[1] << 3) | ijk[2];
                    if !bit(&leaf.active, v) {
                        continue;
                    }
                    let i = (leaf.origin[b] - b0) as usize + ijk[b];
                    let j = (leaf.origin[c] - c0) as usize + ijk[c];
                    let t = tau[j * width as usize + i];
                    if t.is_nan() {
                        let mut p = DVec3::ZERO;
                        p[a] = k as f64;
                        p[b] = f64::from(b0) + i as f64;
                        p[c] = f64::from(c0) + j as f64;
                        let ray = light.ray_from(vol, vol.to_world(p).to_array())?;
                        return Err(Error::nan_on_ray("optical depth", &ray));
                    }
                    leaf.values[v] = (-t).exp() as f32;
                    done += 1;
                }
            }
            progress.advance(done);
        }
    }
    Ok(Some((rays, lookups)))
}

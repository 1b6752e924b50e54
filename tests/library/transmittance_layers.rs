//! Transmittance volumes toward a sun through the sweep, a layer of voxel centres at a time
//! (issue 69): a dense volume's voxels against their own rays walked one by one, on 1 and 2
//! threads; a sparse cloud, whose layers would trace twice its voxels, still goes by rays.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::vdb_writer::{Grid, Leaf, VdbFile};
use umbra::bake::{transmittance_leaves, Sharing};
use umbra::estimate::{Estimator, Options};
use umbra::regular::optical_depth;
use umbra::{Interp, Light, Volume};

/// A dense 24 x 32 x 16 block of varying density (every voxel active), leaves at negative and
/// positive origins.
fn dense(dir: &std::path::Path) -> Volume {
    let mut leaves = Vec::new();
    for i in [-8, 0, 8] {
        for j in [-16, -8, 0, 8] {
            for k in [0, 8] {
                leaves.push(Leaf::from_fn([i, j, k], |v| {
                    let p = [i + v[0] as i32, j + v[1] as i32, k + v[2] as i32].map(f64::from);
                    0.3 + 0.25 * (0.41 * p[0]).sin() * (0.23 * p[1]).cos() + 0.02 * p[2]
                }));
            }
        }
    }
    let p = dir.join("dense.vdb");
    VdbFile::new(vec![Grid::fog("density", leaves)]).write(&p);
    Volume::load(&p, "density", 1.5).unwrap()
}

fn volume(
    vol: &Volume,
    light: &Light,
    threads: usize,
) -> (Vec<umbra::internals::vdb::LeafOut>, Sharing) {
    let (leaves, stats) = transmittance_leaves(
        vol,
        light,
        &Estimator::REGULAR,
        &Options::default(),
        threads,
        &|_| {},
    )
    .unwrap();
    (leaves, stats.sharing)
}

#[test]
fn a_dense_volume_toward_a_sun_is_swept_layer_by_layer_and_matches_each_voxels_ray() {
    let dir = tempfile::tempdir().unwrap();
    let vol = dense(dir.path());
    // Off every lattice step (so not shared by lines), along each axis in turn.
    for d in [
        [0.413_579_246_8, -1.0, 0.271_939_182_5],
        [-1.0, 0.328_309_886_2, 0.141_421_356_2],
        [0.2, 0.377_964_473, 1.0],
    ] {
        let light = Light::Directional { dir: d };
        let (one, sharing) = volume(&vol, &light, 1);
        assert_eq!(sharing, Sharing::Layers, "{d:?}");
        let (two, _) = volume(&vol, &light, 2);
        let mut checked = 0;
        for (a, b) in one.iter().zip(&two) {
            assert_eq!(a.origin, b.origin);
            for n in 0..512 {
                assert_eq!(a.values[n].to_bits(), b.values[n].to_bits(), "threads");
                let ijk = [n >> 6, (n >> 3) & 7, n & 7];
                let p = [0, 1, 2].map(|k| f64::from(a.origin[k]) + ijk[k] as f64);
                let at = vol.to_world(umbra::glam::DVec3::from_array(p)).to_array();
                let r = light.ray_from(&vol, at).unwrap();
                let want = optical_depth(&vol, &r, Interp::Trilinear)
                    .unwrap()
                    .transmittance();
                let got = f64::from(a.values[n]);
                // The sweep's kernel against the f64 walk, then f32.
                assert!(
                    (got - want).abs() <= 2e-6 * want + 1e-7,
                    "{d:?} voxel {p:?}: {got} vs {want}"
                );
                checked += 1;
            }
        }
        assert_eq!(checked, 24 * 32 * 16);
    }
}

#[test]
fn a_sparse_cloud_still_goes_by_rays() {
    let vol = Volume::load("data/cloud.vdb", "density", 1.0).unwrap();
    let light = Light::Directional {
        dir: [0.413_579_246_8, -1.0, 0.271_939_182_5],
    };
    let (_, sharing) = volume(&vol, &light, 2);
    assert_eq!(sharing, Sharing::Rays);
}

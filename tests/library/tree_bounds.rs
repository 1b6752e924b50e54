//! Node bounds are what the estimators trust as majorants and minorants, so they are checked
//! against brute force: every leaf's nearest bounds and halo bounds equal the min/max over its
//! 8^3 voxels and its 10^3 grown box read voxel by voxel; internal nodes' bounds contain every
//! random nearest and trilinear sample taken inside them.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use rand::{Rng, SeedableRng};
use std::path::PathBuf;
use umbra::internals::tree::{Accessor, Bounds, Tree};

fn corpus(file: &str) -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus")
        .join(file);
    if p.exists() {
        Some(p)
    } else {
        assert!(
            std::env::var("UMBRA_SKIP_CORPUS").as_deref() == Ok("1"),
            "{} is missing",
            p.display()
        );
        None
    }
}

fn brute(tree: &Tree, lo: [i32; 3], hi: [i32; 3]) -> Bounds {
    let mut b = Bounds::EMPTY;
    for x in lo[0]..=hi[0] {
        for y in lo[1]..=hi[1] {
            for z in lo[2]..=hi[2] {
                b.include(tree.value([x, y, z]));
            }
        }
    }
    b
}

const FILES: &[(&str, &str)] = &[
    ("gen/tiles_mixed.vdb", "density"),
    ("gen/fog_nonzero_background.vdb", "density"),
    ("gen/sphere_levelset.vdb", "ls_sphere"),
    ("gen/extreme_thick_1e6.vdb", "density"),
    ("gen/tiles_root_level.vdb", "density"),
];

#[test]
fn leaf_bounds_and_halos_equal_brute_force() {
    let mut leaves = 0;
    for &(file, grid) in FILES {
        let Some(path) = corpus(file) else { return };
        let g = umbra::internals::vdb::load_grid(&path, grid).unwrap();
        let t = &g.tree;
        // Every leaf of small grids, a stride of the big ones.
        let step = (t.leaves().len() / 400).max(1);
        for leaf in t.leaves().iter().step_by(step) {
            let o = leaf.origin;
            let own = brute(t, o, o.map(|c| c + 7));
            let halo = brute(t, o, o.map(|c| c + 8));
            assert_eq!(leaf.bounds, own, "{file}: leaf {o:?} bounds");
            assert_eq!(leaf.halo, halo, "{file}: leaf {o:?} halo");
            leaves += 1;
        }
    }
    assert!(leaves > 500, "only {leaves} leaves checked");
}

fn inside(b: Bounds, v: f32) -> bool {
    v.is_nan() || (b.min <= v && v <= b.max)
}

#[test]
fn samples_inside_internal_nodes_respect_their_bounds() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    let mut samples = 0;
    for &(file, grid) in FILES {
        let Some(path) = corpus(file) else { return };
        let g = umbra::internals::vdb::load_grid(&path, grid).unwrap();
        let t = &g.tree;
        let mut acc = Accessor::new(t);
        for (nodes, dim) in [(&t.lowers(), 128.0), (&t.uppers(), 4096.0)] {
            for node in nodes.iter() {
                for _ in 0..2000 {
                    // Nearest region [o - 0.5, o + dim - 0.5); trilinear (dual) region [o, o + dim).
                    let u = [rng.gen::<f64>(), rng.gen::<f64>(), rng.gen::<f64>()];
                    let p = [0, 1, 2].map(|a| f64::from(node.origin[a]) - 0.5 + u[a] * dim);
                    let q = [0, 1, 2].map(|a| f64::from(node.origin[a]) + u[a] * dim);
                    let n = acc.nearest(p);
                    let l = acc.trilinear(q);
                    assert!(
                        inside(node.bounds, n),
                        "{file}: nearest {n} at {p:?} outside {:?}",
                        node.bounds
                    );
                    assert!(
                        inside(node.halo, l),
                        "{file}: trilinear {l} at {q:?} outside {:?}",
                        node.halo
                    );
                    samples += 1;
                }
                assert!(node.bounds.min >= node.halo.min && node.bounds.max <= node.halo.max);
            }
        }
        assert!(inside(t.bounds(), t.background()));
    }
    assert!(samples > 10_000);
}

#[test]
fn tile_slot_halos_equal_brute_force() {
    let mut checked = 0;
    for &(file, grid) in FILES {
        let Some(path) = corpus(file) else { return };
        let g = umbra::internals::vdb::load_grid(&path, grid).unwrap();
        let t = &g.tree;
        for node in t.lowers() {
            for s in (0..4096).step_by(37) {
                if node.has_child(s) {
                    continue;
                }
                let l = [(s >> 8) as i32, ((s >> 4) & 15) as i32, (s & 15) as i32];
                let o = [0, 1, 2].map(|a| node.origin[a] + 8 * l[a]);
                assert_eq!(
                    node.tile_halo[s],
                    brute(t, o, o.map(|c| c + 8)),
                    "{file}: tile {o:?}"
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 1000, "{checked}");
}

#[test]
fn accessor_agrees_with_uncached_lookup_along_random_walks() {
    let Some(path) = corpus("gen/tiles_mixed.vdb") else {
        return;
    };
    let g = umbra::internals::vdb::load_grid(&path, "density").unwrap();
    let t = &g.tree;
    let mut acc = Accessor::new(t);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
    let mut p = [0i32; 3];
    for _ in 0..200_000 {
        let a = rng.gen_range(0..3);
        p[a] += rng.gen_range(-9..=9);
        if rng.gen_bool(0.001) {
            p = [
                rng.gen_range(-300..600),
                rng.gen_range(-300..600),
                rng.gen_range(-300..600),
            ];
        }
        assert_eq!(acc.value(p).to_bits(), t.value(p).to_bits(), "at {p:?}");
    }
}

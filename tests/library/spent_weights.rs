//! Ratio-type walks whose weight is spent stop (issue 58): a thick voxel under a huge majorant
//! made ratio and residual-ratio tracking walk on at the majorant's rate long after their
//! weight had underflowed (15 million lookups where delta tracking took 12,491). Now a weight
//! below the smallest normal `f64` is 0 and ends the walk, and a weight below a millionth after
//! a thousand collisions plays its factors by Russian roulette, which keeps the estimate
//! unbiased (`roulette_keeps_ratio_tracking_unbiased` in `src/estimate/null_collision.rs`).

use umbra::estimate::{estimate, Estimator, Options};
use umbra::internals::tree::TreeBuilder;
use umbra::{Interp, Ray, Volume};

fn unit_map() -> [[f64; 4]; 3] {
    [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
    ]
}

/// A 32^3 block of zeros (active) with one voxel of `hot` at `(16, 16, 16)`, density scale 5.
fn thick_voxel(hot: f32) -> Volume {
    let mut b = TreeBuilder::new(0.0);
    for i in 0..32 {
        for j in 0..32 {
            for k in 0..32 {
                b.set([i, j, k], 0.0);
            }
        }
    }
    b.set([16, 16, 16], hot);
    Volume::from_tree("density".into(), b.build(), unit_map(), 5.0).unwrap()
}

fn run(
    vol: &Volume,
    ray: &Ray,
    name: &str,
    samples: u32,
    interp: Interp,
) -> umbra::estimate::Estimate {
    let opts = Options {
        interp,
        samples,
        seed: 3,
        ..Options::default()
    };
    estimate(vol, ray, 0, &Estimator::from_name(name).unwrap(), &opts).unwrap()
}

#[test]
fn a_thick_voxel_costs_ratio_tracking_about_what_it_costs_delta_tracking() {
    let vol = thick_voxel(3e7);
    for y in [16.0, 16.5, 16.25] {
        let ray = Ray::between([0.0, y, y], [31.0, y, y]).unwrap();
        for interp in [Interp::Trilinear, Interp::Nearest] {
            let exact = run(&vol, &ray, "regular", 1, interp).value;
            let delta = run(&vol, &ray, "track-length", 16, interp);
            assert_eq!(delta.capped, 0);
            for name in ["ratio", "residual-ratio", "next-flight"] {
                let e = run(&vol, &ray, name, 16, interp);
                assert_eq!(e.capped, 0, "{name} y {y} {interp:?}: capped");
                assert!(
                    e.lookups <= 20 * delta.lookups.max(16),
                    "{name} y {y} {interp:?}: {} lookups, track-length {}",
                    e.lookups,
                    delta.lookups
                );
                if exact == 0.0 {
                    // exp(-millions): every sample is 0.
                    assert_eq!(e.value, 0.0, "{name} y {y} {interp:?}");
                }
            }
        }
    }
}

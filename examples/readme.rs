//! The README's Rust example, verbatim (`tests/library/readme.rs` holds the README to this file, and
//! runs it): exact and stochastic transmittance through the sample cloud.

use umbra::estimate::{estimate, Estimator, Options};
use umbra::{Light, Ray, Volume};

fn main() -> Result<(), umbra::Error> {
    let vol = Volume::load("data/cloud.vdb", "density", 1.0)?; // file, grid, density scale
                                                               // Exact transmittance along a segment (ray id 0).
    let ray = Ray::between([-2.0, 1.5, 0.0], [2.0, 1.5, 0.0])?;
    let exact = estimate(&vol, &ray, 0, &Estimator::REGULAR, &Options::default())?;
    println!("T = {}, tau = {:?}", exact.value, exact.tau);
    // Toward a sun travelling along (-1, -1, 0), with ratio tracking and 256 samples.
    let sun = Light::Directional {
        dir: [-1.0, -1.0, 0.0],
    };
    let to_sun = sun.ray_from(&vol, [0.0, 1.5, 0.0])?;
    let opts = Options {
        samples: 256,
        seed: 7,
        ..Options::default()
    };
    let e = estimate(&vol, &to_sun, 0, &Estimator::from_name("ratio")?, &opts)?;
    println!("T = {} +- {}", e.value, e.std_err);
    Ok(())
}

//! Full bakes through the library (`umbra::bake::bake`): a 256x256 orthographic transmittance
//! map of the sample cloud (`data/cloud.vdb`, density scale 4, light along (0.6, -0.35, -1)),
//! exact regular tracking (trilinear) in object order (the sweep, what a bake uses) and in ray
//! order (`Order::Rays`, one HDDA walk per pixel), and ray marching (Riemann, 1 voxel), on 1
//! thread and on every core; and the same exact map seen from a point light at (6, 9, 8)
//! (perspective), in object order and in ray order. The parallel speed-up is the ratio of the
//! thread counts; criterion reports maps/s.
//! Run: `cargo bench --ignore-rust-version --bench bake`.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use std::path::PathBuf;
use std::time::Duration;
use umbra::bake::{bake, BakeSettings, Camera, Order, Projection, View};
use umbra::estimate::{Estimator, Options};
use umbra::Volume;

fn bench_bake(c: &mut Criterion) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb");
    let vol = Volume::load(&path, "density", 4.0).unwrap();
    let view = View {
        projection: Projection::Ortho,
        light_dir: Some([0.6, -0.35, -1.0]),
        light_pos: None,
        fov_deg: None,
        res: Some(umbra::bake::Resolution::Exact(256, 256)),
        up: None,
        frame_box: None,
    };
    let camera = Camera::frame(&view, &vol.box_corners().unwrap()).unwrap();
    let persp = View {
        projection: Projection::Perspective,
        light_dir: None,
        light_pos: Some([6.0, 9.0, 8.0]),
        ..view
    };
    let pinhole = Camera::frame(&persp, &vol.box_corners().unwrap()).unwrap();
    let cores = rayon::current_num_threads();
    let mut g = c.benchmark_group("bake_256x256");
    g.sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(4));
    for (name, est, order, camera) in [
        ("regular", Estimator::REGULAR, Order::Auto, &camera),
        ("regular_rays", Estimator::REGULAR, Order::Rays, &camera),
        (
            "riemann_1vox",
            Estimator::with_params("riemann", &[("step", 1.0)]).unwrap(),
            Order::Auto,
            &camera,
        ),
        ("regular_persp", Estimator::REGULAR, Order::Auto, &pinhole),
        (
            "regular_persp_rays",
            Estimator::REGULAR,
            Order::Rays,
            &pinhole,
        ),
    ] {
        for threads in [1, cores] {
            let mut s = BakeSettings::new(est, Options::default());
            s.threads = threads;
            s.order = order;
            g.bench_function(format!("{name}/{threads}_threads"), |b| {
                b.iter(|| bake(&vol, camera, &s, &|_| {}).unwrap().stats.lookups);
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench_bake);
criterion_main!(benches);

//! `MapSummary`: what a baked map is as data (the map part of `bake --json`, the Python
//! module's camera dict) and the way back to the same EXR file from it and the pixels.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;
use umbra::bake::{
    BakeJob, BakeSettings, Camera, Channel, MapSummary, Projection, Resolution, View,
};
use umbra::estimate::{Estimator, Options};

fn cloud() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb")
}

fn job(out: PathBuf, est: Estimator, spp: u32, std_err: bool) -> BakeJob {
    BakeJob {
        source: umbra::input::Source::new(
            cloud(),
            umbra::input::SourceOptions {
                grid: "density".into(),
                density_scale: 1.5,
                ..umbra::input::SourceOptions::default()
            },
        ),
        view: View {
            projection: Projection::Ortho,
            light_dir: Some([-1.0, -1.0, 0.2]),
            res: Some(Resolution::Exact(40, 24)),
            ..View::default()
        },
        camera: None,
        settings: BakeSettings {
            std_err,
            ..BakeSettings::new(
                est,
                Options {
                    samples: spp,
                    seed: 5,
                    ..Options::default()
                },
            )
        },
        output: out,
        preview: None,
        overwrite: false,
        max_memory: None,
        layout: umbra::bake::ExrLayout::default(),
        product: umbra::bake::Product::Map,
        key: None,
    }
}

#[test]
fn summary_and_pixels_write_the_same_exr() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (Estimator::REGULAR, 1, false),
        (
            Estimator::with_params("riemann", &[("step", 0.5)]).unwrap(),
            1,
            false,
        ),
        (Estimator::from_name("ratio").unwrap(), 4, true),
    ];
    for (n, (est, spp, err)) in cases.into_iter().enumerate() {
        let out = dir.path().join(format!("m{n}.exr"));
        let j = job(out.clone(), est, spp, err);
        let report = j.run(&|_| {}).unwrap();
        // Through JSON and back, as the Python module carries it.
        let summary = MapSummary::new(&report.map, &report.provenance);
        let text = serde_json::to_string(&summary).unwrap();
        let back: MapSummary = serde_json::from_str(&text).unwrap();
        assert_eq!(back, summary);
        let (map, prov) = back
            .to_map(report.map.t.clone(), report.map.std_err.clone(), None)
            .unwrap();
        let again = dir.path().join(format!("again{n}.exr"));
        umbra::bake::write_exr(&again, &map, &prov, false).unwrap();
        assert_eq!(
            std::fs::read(&again).unwrap(),
            std::fs::read(&out).unwrap(),
            "{est}"
        );
        // The camera rebuilds bit for bit (what its rays are made of).
        assert_eq!(summary.camera().unwrap().spec(), report.map.camera.spec());
        // In memory, on the loaded scene: the same map.
        let scene = j.source.load().unwrap();
        let camera = Camera::frame(&j.view, &scene.box_corners().unwrap()).unwrap();
        let mem = j.bake_in_memory(&scene, camera, &|_| {}).unwrap();
        assert_eq!(mem.map.t, report.map.t);
        assert_eq!(mem.provenance, report.provenance);
    }
}

#[test]
fn summaries_that_do_not_hold_together_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m.exr");
    let report = job(out, Estimator::REGULAR, 1, false).run(&|_| {}).unwrap();
    let s = MapSummary::new(&report.map, &report.provenance);
    let t = report.map.t.clone();
    let msg = |r: umbra::Result<_>| match r {
        Err(e) => e.to_string(),
        Ok(_) => panic!("accepted"),
    };
    // Pixels of another size, a standard error the summary does not list, colour.
    assert!(msg(s.to_map(t[1..].to_vec(), None, None)).contains("'image'"));
    assert!(msg(s.to_map(t.clone(), Some(t.clone()), None)).contains("stderr"));
    let ch = || Channel {
        t: t.clone(),
        ..Channel::default()
    };
    assert!(msg(s.to_map(t.clone(), None, Some(Box::new([ch(), ch()])))).contains("grey"));
    // An estimator that does not exist, a parameter it does not take, a broken camera.
    let mut bad = s.clone();
    bad.estimator = "nope".into();
    bad.estimator_params = serde_json::json!({"name": "nope"});
    assert!(msg(bad.to_map(t.clone(), None, None)).contains("nope"));
    let mut bad = s.clone();
    bad.estimator_params = serde_json::json!({"name": "regular", "step": 2});
    assert!(msg(bad.to_map(t.clone(), None, None)).contains("step"));
    let mut bad = s.clone();
    bad.camera.step_x = [0.0; 3];
    assert!(msg(bad.to_map(t.clone(), None, None)).contains("'camera'"));
    let mut bad = s.clone();
    bad.depths = vec![1.0];
    assert!(msg(bad.to_map(t, None, None)).contains("slices"));
}

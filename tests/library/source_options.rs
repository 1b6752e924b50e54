//! Issue 59: what is read is decided once. A `Source` decides its kind when it is made; the
//! read options are one set, flattened into a bake's options, a job's `[bake]`, its
//! `[[inputs]]` and `[[positions]]` entries (as overrides) and Python's keywords; a job's type
//! error in a flattened key keeps its line and column.

use std::path::Path;
use umbra::batch::parse_job;
use umbra::input::{InputKind, Source, SourceOptions};
use umbra::request::{BakeOptions, EstimatorOptions, TraceOptions};

fn job_error(text: &str) -> String {
    match parse_job(Path::new("/tmp/job.toml"), text) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn a_source_decides_its_kind_when_made() {
    let s = Source::new("a/shot.USDA", SourceOptions::default());
    assert_eq!(s.kind(), InputKind::Stage { package: false });
    assert_eq!(s.at("b/scene.toml").kind(), InputKind::Scene);
    // Stage options only for a stage, named.
    let bad = Source::new(
        "cloud.vdb",
        SourceOptions {
            field: Some("density".into()),
            ..SourceOptions::default()
        },
    );
    let e = bad.check().unwrap_err();
    assert!(
        matches!(e, umbra::Error::InvalidArgument { ref name, .. } if name == "field"),
        "{e}"
    );
    assert!(e.to_string().contains("cloud.vdb is not one"), "{e}");
    // A stage's frame must be finite.
    let stage = Source::new(
        "s.usda",
        SourceOptions {
            frame: Some(f64::NAN),
            ..SourceOptions::default()
        },
    );
    assert!(stage.check().unwrap_err().to_string().contains("frame"));
}

#[test]
fn every_key_of_the_flattened_sets_reads_back_and_unknown_keys_are_refused() {
    // A bake's options: the read, estimator and parameter keys in one flat object.
    let o = BakeOptions::from_json(
        r#"{"grid": "smoke", "density_scale": 2.5, "interp": "nearest", "velocity": "v",
            "spp": 8, "estimator": "ratio", "step": 0.5, "light_dir": [0, -1, 0], "tile": 16}"#,
    )
    .unwrap();
    assert_eq!(
        (
            o.source.grid.as_str(),
            o.source.density_scale,
            o.source.velocity.as_deref()
        ),
        ("smoke", 2.5, Some("v"))
    );
    assert_eq!(
        (o.estimator.samples, o.estimator.estimator.as_str()),
        (8, "ratio")
    );
    assert_eq!(o.params.step, Some(0.5));
    assert_eq!(o.light.light_dir, Some([0.0, -1.0, 0.0]));
    // Serialised back flat: every key once, so a round trip is the identity.
    let text = serde_json::to_string(&o).unwrap();
    assert_eq!(BakeOptions::from_json(&text).unwrap(), o);
    for bad in [r#"{"tiles": 1}"#, r#"{"sampels": 1}"#, r#"{"density": 1}"#] {
        let e = BakeOptions::from_json(bad).unwrap_err().to_string();
        assert!(e.contains("unknown field"), "{bad}: {e}");
    }
    // A set read alone refuses the other sets' keys.
    assert!(EstimatorOptions::from_json(r#"{"grid": "d"}"#).is_err());
    assert!(TraceOptions::from_json(r#"{"grid": "d", "spp": 2, "step": 1}"#).is_ok());
    assert!(TraceOptions::from_json(r#"{"tile": 2}"#).is_err());
}

#[test]
fn overrides_take_aliases_and_name_bad_keys() {
    let base = BakeOptions {
        estimator: EstimatorOptions {
            samples: 8,
            ..EstimatorOptions::default()
        },
        ..BakeOptions::default()
    };
    let keys = |j: &str| -> serde_json::Map<String, serde_json::Value> {
        serde_json::from_str(j).unwrap()
    };
    // An alias over the canonical key [bake] holds: the override wins, even at the default.
    let o = base.with_overrides(&keys(r#"{"spp": 64}"#)).unwrap();
    assert_eq!(o.estimator.samples, 64);
    let o = base
        .with_overrides(&keys(r#"{"samples": 3, "density_scale": 4}"#))
        .unwrap();
    assert_eq!((o.estimator.samples, o.source.density_scale), (3, 4.0));
    let e = base
        .with_overrides(&keys(r#"{"samples": "many"}"#))
        .unwrap_err();
    assert!(
        matches!(e, umbra::Error::InvalidArgument { ref name, .. } if name == "samples"),
        "{e}"
    );
}

#[test]
fn a_bad_key_of_a_flattened_set_keeps_its_line_and_column() {
    // `samples` is the estimator set's, flattened into [bake]: serde reports it at [bake]'s
    // header; the job's error still points at the key.
    let text =
        "[bake]\nlight_dir = [0, -1, 0]\nsamples = \"many\"\n\n[[inputs]]\nfile = \"a.vdb\"\n";
    let e = job_error(text);
    assert!(e.contains("line 3, column 1"), "{e}");
    assert!(e.contains("bake.samples"), "{e}");
    let e = job_error("[bake]\ngrid = \"d\"\ndensity_scale = \"thick\"\n");
    assert!(
        e.contains("line 3, column 1") && e.contains("bake.density_scale"),
        "{e}"
    );
    // An unknown key is named with its place too.
    let e = job_error("[bake]\n\n  tiles = 4\n");
    assert!(
        e.contains("line 3, column 3") && e.contains("bake.tiles"),
        "{e}"
    );
}

#[test]
fn inputs_and_positions_entries_take_read_keys_as_overrides() {
    let dir = tempfile::tempdir().unwrap();
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb");
    for name in ["a.vdb", "b.vdb"] {
        std::fs::copy(&data, dir.path().join(name)).unwrap();
    }
    let job = format!(
        "output = \"{out}/{{stem}}.exr\"\n[bake]\nlight_dir = [0, -1, 0]\ndensity_scale = 2\n\
         [[inputs]]\nfile = \"a.vdb\"\ndensity_scale = 5\ninterp = \"nearest\"\n\
         [[inputs]]\nfile = \"b.vdb\"\n",
        out = dir.path().display(),
    );
    let j = parse_job(&dir.path().join("job.toml"), &job).unwrap();
    let scales: Vec<f64> = j
        .tasks
        .iter()
        .map(|t| t.source.options().density_scale)
        .collect();
    assert_eq!(scales, [5.0, 2.0]);
    assert_eq!(j.tasks[0].source.options().interp, umbra::Interp::Nearest);
    // A key that is no read key, a frame, a light: refused by name.
    for (extra, key) in [
        ("tile = 4", "inputs[0].tile"),
        ("frame = 3", "inputs[0].frame"),
        ("light = \"sun\"", "inputs[0].light"),
        ("density_scale = \"x\"", "inputs[0].density_scale"),
    ] {
        let text = format!(
            "output = \"o.exr\"\n[bake]\nlight_dir = [0, -1, 0]\n[[inputs]]\nfile = \"a.vdb\"\n{extra}\n"
        );
        let e = job_error(&text);
        assert!(e.contains(key), "{extra}: {e}");
    }
    // A positions entry: read and estimator keys over [bake]'s, xform refused.
    for (extra, key) in [
        (
            "xform = [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]",
            "positions[0].xform",
        ),
        ("tile = 4", "positions[0].tile"),
        ("samples = -1", "positions[0].samples"),
    ] {
        let text = format!(
            "[[positions]]\nusd = \"s.usda\"\nprim = \"/World/p\"\nusd_out = \"o.usda\"\n{extra}\n"
        );
        let e = job_error(&text);
        assert!(e.contains(key), "{extra}: {e}");
    }
}

//! openusd 0.8 probe (branch usd08): time-sampled asset paths in .usda, linear interpolation
//! of whole-number samples, value clips and layer offsets. `usd08_probe DIR`.
use openusd::sdf::Value;
use openusd::usd::{Stage, TimeCode};

fn get(stage: &Stage, attr: &str, t: f64) -> String {
    match stage.attribute(attr) {
        Ok(a) => match a.get_at::<Value>(TimeCode::new(t)) {
            Ok(Some(v)) => format!("{v:?}"),
            Ok(None) => "None".into(),
            Err(e) => format!("ERR {e:#}"),
        },
        Err(e) => format!("ERR {e:#}"),
    }
}

fn open(dir: &str, f: &str) -> Option<Stage> {
    match Stage::open(&format!("{dir}/{f}")) {
        Ok(s) => Some(s),
        Err(e) => {
            println!("{f}: open ERR {e:#}");
            None
        }
    }
}

fn main() {
    let dir = std::env::args().nth(1).unwrap_or_else(|| ".".into());
    if let Some(s) = open(&dir, "tsasset.usda") {
        for t in [1.0, 1.5, 2.0] {
            println!("(a) filePath @ {t}: {}", get(&s, "/Vol/density.filePath", t));
        }
    }
    if let Some(s) = open(&dir, "rot.usda") {
        for t in [1.0, 1.5, 2.0] {
            println!(
                "(b) rotateZ @ {t}: {}   float f: {}",
                get(&s, "/X.xformOp:rotateZ", t),
                get(&s, "/X.f", t)
            );
        }
    }
    if let Some(s) = open(&dir, "clips.usda") {
        for t in [0.0, 5.0, 10.0] {
            println!("(c) clip v @ {t}: {}", get(&s, "/P.v", t));
        }
    }
    if let Some(s) = open(&dir, "offs.usda") {
        for t in [5.0, 10.0, 15.0] {
            println!("(d) sublayer offset=5 /Q.v @ {t}: {}", get(&s, "/Q.v", t));
        }
        for t in [0.0, 10.0, 20.0] {
            println!("(d) reference scale=2 /Refd.v @ {t}: {}", get(&s, "/Refd.v", t));
        }
    }
}

//! `umbra info SHOT.usd`: what umbra reads of a USD stage at a time code: its volumes (prim,
//! asset, grid, placement, options, and the grid's own one-line report) and its lights (type,
//! how umbra traces them, shadow enable and which volumes their shadow link includes).

use anyhow::{bail, Context, Result};
use serde_json::{json, Value};
use std::io::Write;
use std::path::Path;
use umbra::usd::StageLight;

/// The stage's report as JSON (what `--json` prints; the text form is drawn from it).
fn report(file: &Path, stage: &StageArgs) -> Result<Value> {
    if stage.light.is_some() {
        bail!("invalid argument '--light': info lists every light of the stage");
    }
    let sel = stage.selection();
    let shot = umbra::usd::read(file, &sel).map_err(crate::common::flag_error)?;
    let lights = umbra::usd::lights_at(file, Some(shot.time))?;
    let mut volumes = Vec::new();
    for v in &shot.volumes {
        let opened = v.asset.open()?;
        let grid = umbra::info::FileInfo::read(opened.path(), Some(&v.grid))
            .with_context(|| format!("{}: reading {}", v.prim, v.asset.display()))?;
        let m: Vec<f64> = v.xform.rows().iter().flatten().copied().collect();
        volumes.push(json!({
            "prim": v.prim,
            "field": v.field_prim,
            "asset": v.asset.display(),
            "grid": v.grid,
            "xform": m,
            "density_scale": v.density_scale,
            "sigma_t": v.sigma_t,
            "kind": if v.solid { "solid" } else { "fog" },
            "info": grid.grids.first(),
        }));
    }
    let lights: Vec<Value> = lights.lights.iter().map(light).collect();
    Ok(json!({
        "stage": file.display().to_string(),
        "time": shot.time,
        "up": shot.up,
        "volumes": volumes,
        "lights": lights,
    }))
}

fn light(l: &StageLight) -> Value {
    // The emitter's own JSON: its kind and its fields (with the schema fallbacks applied).
    let traced = l
        .emitter
        .as_ref()
        .and_then(|e| serde_json::to_value(e).ok())
        .unwrap_or(Value::Null);
    let rules: serde_json::Map<String, Value> = l
        .shadow
        .link
        .rules
        .iter()
        .map(|(p, r)| (p.clone(), json!(r.token())))
        .collect();
    json!({
        "prim": l.prim,
        "type": l.type_name,
        "traced": traced,
        "refused": l.refused,
        "shadow": {
            "enable": l.shadow.enabled,
            "linked": l.shadow.linked,
            "unlinked": l.shadow.unlinked,
            "link": rules,
            "error": l.shadow.unreadable,
        },
    })
}

/// A light's shadow line: off, or the volumes its shadow link includes and leaves out.
fn shadow_line(s: &Value) -> String {
    if let Some(e) = s["error"].as_str() {
        return format!(
            "shadow controls unreadable: {}",
            umbra::internals::text::escape(e)
        );
    }
    if s["enable"].as_bool() == Some(false) {
        return "shadows off (inputs:shadow:enable = false)".into();
    }
    let list = |v: &Value| -> Vec<String> {
        v.as_array()
            .map_or(Vec::new(), |a| a.iter().map(text).collect())
    };
    let (linked, unlinked) = (list(&s["linked"]), list(&s["unlinked"]));
    let mut line = format!(
        "shadow link: {}",
        if linked.is_empty() {
            "no volume".to_string()
        } else {
            linked.join(", ")
        }
    );
    if !unlinked.is_empty() {
        line += &format!(" (leaves out {})", unlinked.join(", "));
    }
    line
}

/// Print the stage's report (text, or JSON with `json`).
pub fn print(file: &Path, stage: &StageArgs, json: bool) -> Result<()> {
    let r = report(file, stage)?;
    let mut out = std::io::stdout().lock();
    if json {
        serde_json::to_writer_pretty(&mut out, &r).context("writing JSON")?;
        writeln!(out)?;
        return Ok(());
    }
    let vols = r["volumes"].as_array().map_or(&[][..], Vec::as_slice);
    let lights = r["lights"].as_array().map_or(&[][..], Vec::as_slice);
    let up = if r["up"][2].as_f64() == Some(1.0) {
        "+Z"
    } else {
        "+Y"
    };
    writeln!(
        out,
        "{} at time {} (up {up}): {} volume{}, {} light{}",
        file.display(),
        n(&r["time"]),
        vols.len(),
        if vols.len() == 1 { "" } else { "s" },
        lights.len(),
        if lights.len() == 1 { "" } else { "s" }
    )?;
    for v in vols {
        let g = &v["info"];
        writeln!(
            out,
            "  {}: {} grid '{}' ({}, density scale {}), {} active voxels, values {} .. {}",
            text(&v["prim"]),
            text(&v["asset"]),
            text(&v["grid"]),
            text(&v["kind"]),
            n(&v["density_scale"]),
            g["active_voxels"],
            n(&g["value_min"]),
            n(&g["value_max"])
        )?;
        let m: Vec<String> = v["xform"]
            .as_array()
            .map_or(Vec::new(), |a| a.iter().map(n).collect());
        writeln!(out, "    xform {}", m.join(","))?;
    }
    for l in lights {
        let how = match (&l["traced"], l["refused"].as_str()) {
            (_, Some(why)) => format!(
                "refused when chosen: {}",
                umbra::internals::text::escape(why)
            ),
            (Value::Object(o), None) => traced_line(o),
            _ => "not traced by umbra".into(),
        };
        writeln!(
            out,
            "  light {} ({}): {how}",
            text(&l["prim"]),
            text(&l["type"])
        )?;
        writeln!(out, "    {}", shadow_line(&l["shadow"]))?;
    }
    Ok(())
}

/// How a traced light is drawn: its kind, its size and where it is.
fn traced_line(map: &serde_json::Map<String, Value>) -> String {
    let o = |k: &str| map.get(k).unwrap_or(&Value::Null);
    let at = vector(o("pos"));
    match o("kind").as_str().unwrap_or_default() {
        "directional" => match n(o("angle")).as_str() {
            "0" => format!("a sun travelling along {} (a point)", vector(o("dir"))),
            a => format!(
                "a sun travelling along {}, {a} degrees across",
                vector(o("dir"))
            ),
        },
        "sphere" => format!("a sphere of radius {} at {at}", n(o("radius"))),
        "disk" => format!(
            "a disk of radius {} at {at} (one-sided, along -Z)",
            n(o("radius"))
        ),
        "rect" => format!(
            "a {} x {} rect at {at} (one-sided, along -Z)",
            n(o("width")),
            n(o("height"))
        ),
        "cylinder" if o("radius").as_f64() == Some(0.0) => {
            format!("a line of length {} at {at}", n(o("length")))
        }
        "cylinder" => format!(
            "a cylinder of radius {} and length {} at {at}",
            n(o("radius")),
            n(o("length"))
        ),
        _ => format!("a point at {at}"),
    }
}

fn text(v: &Value) -> String {
    v.as_str().map_or_else(|| v.to_string(), str::to_string)
}

/// A number as `info` prints numbers (6 significant digits); other values as they are.
fn n(v: &Value) -> String {
    v.as_f64().map_or_else(|| text(v), crate::common::num)
}

fn vector(v: &Value) -> String {
    let parts: Vec<String> = v
        .as_array()
        .map_or(Vec::new(), |a| a.iter().map(n).collect());
    format!("({})", parts.join(", "))
}

/// What `umbra info` reads of a USD stage input (`--frame`, `--volume`, `--field`, `--light`):
/// the listing's own selection (the tracing commands read these keys with the rest of
/// [`umbra::input::SourceOptions`]).
#[derive(Debug, Clone, clap::Args)]
pub struct StageArgs {
    /// USD stage inputs: the time code to read (default: the stage's startTimeCode).
    #[arg(long, allow_negative_numbers = true)]
    pub frame: Option<f64>,
    /// USD stage inputs: a Volume prim to trace, by path (repeatable; default: every active,
    /// visible Volume).
    #[arg(long, value_name = "PRIM")]
    pub volume: Vec<String>,
    /// USD stage inputs: the field a Volume's density is (field:NAME; default density).
    #[arg(long, value_name = "NAME")]
    pub field: Option<String>,
    /// USD stage inputs: the UsdLux light, by prim path or name (default: the stage's only
    /// light).
    #[arg(long, value_name = "PRIM")]
    pub light: Option<String>,
}

impl StageArgs {
    /// The stage keys as read options (the rest at their defaults).
    pub fn options(&self) -> umbra::input::SourceOptions {
        umbra::input::SourceOptions {
            frame: self.frame,
            volume: (!self.volume.is_empty()).then(|| self.volume.clone()),
            field: self.field.clone(),
            light: self.light.clone(),
            ..umbra::input::SourceOptions::default()
        }
    }

    /// The library's selection.
    pub fn selection(&self) -> umbra::usd::Selection {
        umbra::usd::Selection {
            time: self.frame,
            volumes: self.volume.clone(),
            field: self.field.clone().unwrap_or_else(|| "density".into()),
            light: None,
            velocity: None,
        }
    }
}

//! What a map says about itself (`umbra info MAP.exr`, a transmittance `.vdb`): its size and
//! channels, the `umbra:*` attributes it was baked with (source file, grid, light, estimator,
//! camera, seed, ...), its batch key ([`crate::batch::TaskKey`]) when a job baked it, and
//! whether it is stale against its inputs today (each file the key names: unchanged, changed or
//! gone). A foreign EXR is described by its size and channels, as not baked by umbra.

use crate::batch::{FileId, TaskKey};
use crate::error::{Error, Result};
use serde::Serialize;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The first four bytes of an OpenEXR file.
pub const EXR_MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];

/// Whether `path` starts as an OpenEXR file does (unreadable files are not).
#[must_use]
pub fn is_exr(path: &Path) -> bool {
    let mut magic = [0u8; 4];
    std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut magic))
        .is_ok()
        && magic == EXR_MAGIC
}

/// One file a map's key names, as it is today.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct InputToday {
    /// The file.
    pub path: PathBuf,
    /// `unchanged` (same content; a touched file too), `changed` or `missing`.
    pub state: &'static str,
}

/// A map (or transmittance volume) described from its header.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MapInfo {
    /// The file.
    pub path: PathBuf,
    /// `exr` or `vdb`.
    pub format: &'static str,
    /// Whether umbra baked it (its header holds `umbra:*` attributes).
    pub baked_by_umbra: bool,
    /// Size in pixels (an EXR; `None` for a volume).
    pub width: Option<u32>,
    /// Height in pixels.
    pub height: Option<u32>,
    /// Channels in file order (an EXR).
    pub channels: Vec<String>,
    /// Whether it is a deep EXR.
    pub deep: bool,
    /// The `umbra:*` attributes without their prefix (the key apart), as JSON values.
    pub attributes: BTreeMap<String, Value>,
    /// The batch key it carries (a map a job baked), if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub key: Option<TaskKey>,
    /// Every file the key names, as it is today.
    pub inputs: Vec<InputToday>,
    /// Whether a file it was baked from changed since (`None`: no key to tell).
    pub stale: Option<bool>,
}

impl MapInfo {
    /// Describe the map at `path`: an EXR's first part's header, or a `.vdb`'s first grid's
    /// metadata; each file its key names is compared with the key's identity of it (hashed
    /// only when its size or time differ).
    ///
    /// # Errors
    /// [`Error::Io`] when the file cannot be read; [`Error::InvalidArgument`] when an EXR's
    /// header cannot be parsed; as [`crate::vdb::Archive::open`] for a `.vdb`.
    pub fn read(path: &Path) -> Result<Self> {
        let mut info = if is_exr(path) {
            exr_info(path)?
        } else {
            vdb_info(path)?
        };
        if let Some(k) = info
            .attributes
            .remove("key")
            .and_then(|v| v.as_str().and_then(TaskKey::from_text))
        {
            info.inputs = k.files.iter().map(today).collect();
            info.stale = Some(info.inputs.iter().any(|i| i.state != "unchanged"));
            info.key = Some(k);
        }
        info.baked_by_umbra = !info.attributes.is_empty() || info.key.is_some();
        Ok(info)
    }
}

/// A file a key names, today.
fn today(f: &FileId) -> InputToday {
    let state = match FileId::of(&f.path, Some(f), false) {
        Err(_) => "missing",
        Ok(now) if now.same_content(f) => "unchanged",
        Ok(_) => "changed",
    };
    InputToday {
        path: f.path.clone(),
        state,
    }
}

/// An EXR attribute as JSON: text as a string, numbers as numbers, a `v3d` as three numbers,
/// anything else as its debug text.
fn attribute_json(v: &exr::meta::attribute::AttributeValue) -> Value {
    use exr::meta::attribute::AttributeValue as A;
    match v {
        A::Text(t) => Value::from(t.to_string()),
        A::F64(x) => Value::from(*x),
        A::F32(x) => Value::from(f64::from(*x)),
        A::I32(x) => Value::from(*x),
        A::Custom { kind, bytes } if kind == "v3d" && bytes.len() == 24 => {
            let c: Vec<f64> = bytes
                .chunks_exact(8)
                .map(|b| f64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
                .collect();
            Value::from(c)
        }
        other => Value::from(format!("{other:?}")),
    }
}

fn exr_info(path: &Path) -> Result<MapInfo> {
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| match e {
        exr::error::Error::Io(err) => Error::Io {
            path: path.to_path_buf(),
            err,
        },
        e => Error::InvalidArgument {
            name: path.display().to_string(),
            reason: format!("not a readable OpenEXR file: {e}"),
        },
    })?;
    let mut info = MapInfo::unread(path, "exr");
    if let Some(h) = meta.headers.first() {
        info.width = u32::try_from(h.layer_size.0).ok();
        info.height = u32::try_from(h.layer_size.1).ok();
        info.channels = h.channels.list.iter().map(|c| c.name.to_string()).collect();
        info.deep = h.deep;
        for (k, v) in &h.own_attributes.other {
            if let Some(name) = k.to_string().strip_prefix("umbra:") {
                info.attributes.insert(name.to_string(), attribute_json(v));
            }
        }
    }
    Ok(info)
}

impl MapInfo {
    /// What is known of `path` (a file of `format`) before its header is read: nothing.
    fn unread(path: &Path, format: &'static str) -> Self {
        Self {
            path: path.to_path_buf(),
            format,
            baked_by_umbra: false,
            width: None,
            height: None,
            channels: Vec::new(),
            deep: false,
            attributes: BTreeMap::new(),
            key: None,
            inputs: Vec::new(),
            stale: None,
        }
    }
}

fn vdb_info(path: &Path) -> Result<MapInfo> {
    let archive = crate::vdb::Archive::open(path)?;
    let mut info = MapInfo::unread(path, "vdb");
    if let Some(gd) = archive.grids.first() {
        let header = archive.header(gd)?;
        for (k, v) in &header.metadata {
            let Some(name) = k.strip_prefix("umbra:") else {
                continue;
            };
            if let crate::vdb::MetaValue::String(s) = v {
                info.attributes
                    .insert(name.to_string(), Value::from(s.clone()));
            }
        }
        info.channels.push(gd.display_name.clone());
    }
    Ok(info)
}

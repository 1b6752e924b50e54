//! Task keys: everything that decides a task's bytes, written into its output, so a re-run
//! bakes exactly the tasks whose key changed (or whose output is missing or unreadable).
//!
//! A [`TaskKey`] holds the output format's version, the task's whole request in canonical form
//! (the request's options after defaults, serialized by serde, without the keys that cannot
//! change a byte: [`NOT_IN_KEY`]), the camera a shared or fixed framing gives it, and the
//! identity of every file it reads ([`FileId`]: size, modification time, xxh3-64 of the
//! content). A map carries it as the EXR header attribute `umbra:key`, a transmittance volume
//! as the grid's `umbra:key` metadata, a positions task's per-frame file as its `key` member;
//! each is written with the output, atomically. [`Stored::read`] reads it back.
//!
//! A file whose size and time match the recorded ones is taken as unchanged without reading
//! it (unless [`KeyCheck::verify`]); one whose size or time differ is hashed, and a touched
//! but identical file is no change.

use super::{BatchError, Job, Task};
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};
use std::io::Read;
use std::path::{Path, PathBuf};

/// The version of the bytes umbra writes for a task's output (maps, transmittance volumes,
/// positions files): raised when the same request writes different bytes, so older outputs
/// are baked again.
pub const FORMAT_VERSION: u32 = 1;

/// The EXR attribute, `.vdb` grid metadata entry and per-frame file member holding the key.
pub const KEY_ATTRIBUTE: &str = "umbra:key";

/// Request keys that cannot change an output's bytes, so are not in the key: threads, the
/// overwrite flag, the memory budget (a bake in parts is the same bit for bit), the framing
/// (its camera is in the key) and the job's USD layer (rebuilt from the maps after each run).
pub const NOT_IN_KEY: &[&str] = &["threads", "force", "max_memory", "framing", "usd_out"];

/// The request keys that say which light a task is baked toward.
pub(super) const LIGHT_KEYS: &[&str] = &[
    "light_dir",
    "light_pos",
    "light",
    "light_angle",
    "light_radius",
    "light_samples",
];

/// A file's identity as a key records it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FileId {
    /// The file as the task names it.
    pub path: PathBuf,
    /// Size in bytes.
    pub size: u64,
    /// Modification time, nanoseconds since the Unix epoch.
    pub mtime_ns: i64,
    /// xxh3-64 of the content, 16 hex digits.
    pub xxh3: String,
}

impl FileId {
    /// The identity of `path` now. When `recorded` (an earlier identity of the same file)
    /// has the same size and time and `verify` is off, its hash is taken without reading the
    /// file; otherwise the file is hashed.
    ///
    /// # Errors
    /// [`crate::error::Error::Io`] when the file cannot be read.
    pub fn of(path: &Path, recorded: Option<&FileId>, verify: bool) -> crate::error::Result<Self> {
        let io = |err| crate::error::Error::Io {
            path: path.to_path_buf(),
            err,
        };
        let meta = std::fs::metadata(path).map_err(io)?;
        let mtime_ns = meta
            .modified()
            .ok()
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .and_then(|d| i64::try_from(d.as_nanos()).ok())
            .unwrap_or(0);
        let size = meta.len();
        let xxh3 = match recorded {
            Some(r) if !verify && r.size == size && r.mtime_ns == mtime_ns => r.xxh3.clone(),
            _ => hash_file(path)?,
        };
        Ok(Self {
            path: path.to_path_buf(),
            size,
            mtime_ns,
            xxh3,
        })
    }

    /// Whether two identities are of the same content (size and hash; not the time).
    #[must_use]
    pub fn same_content(&self, other: &Self) -> bool {
        self.size == other.size && self.xxh3 == other.xxh3
    }
}

/// The xxh3-64 of a file's content, 16 hex digits, read in 1 MiB pieces.
///
/// # Errors
/// [`crate::error::Error::Io`] when the file cannot be read.
pub fn hash_file(path: &Path) -> crate::error::Result<String> {
    use std::hash::Hasher;
    let io = |err| crate::error::Error::Io {
        path: path.to_path_buf(),
        err,
    };
    let mut f = std::fs::File::open(path).map_err(io)?;
    let mut h = twox_hash::XxHash3_64::with_seed(0);
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f.read(&mut buf).map_err(io)?;
        if n == 0 {
            break;
        }
        h.write(&buf[..n]);
    }
    Ok(format!("{:016x}", h.finish()))
}

/// Everything that decides a task's bytes (module docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TaskKey {
    /// The output's kind and format version, e.g. `map/1`.
    pub format: String,
    /// The request in canonical form: every option after defaults by its library name (the
    /// light, the frame, the grid and the input's own keys among them), without
    /// [`NOT_IN_KEY`]; `input` the file the task reads.
    pub request: Map<String, Value>,
    /// The camera a shared or fixed framing gives the task (`None`: framed by the bake from
    /// its own input and options).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<Value>,
    /// Every file the task reads: its input and, for a scene or a stage, the grid files its
    /// volumes name at the task's frame.
    pub files: Vec<FileId>,
}

impl TaskKey {
    /// The key as JSON text in ASCII (`\uXXXX` escapes), which an EXR text attribute keeps.
    #[must_use]
    pub fn to_text(&self) -> String {
        let json = serde_json::to_string(self).unwrap_or_default();
        let mut out = String::with_capacity(json.len());
        for c in json.chars() {
            if c.is_ascii() {
                out.push(c);
            } else {
                let mut units = [0u16; 2];
                for u in c.encode_utf16(&mut units) {
                    out.push_str(&format!("\\u{u:04x}"));
                }
            }
        }
        out
    }

    /// A key read back from its text (`None`: not a key).
    #[must_use]
    pub fn from_text(text: &str) -> Option<Self> {
        serde_json::from_str(text).ok()
    }

    /// What a held frame shares with the frame it holds: the key without the frame and the
    /// input's name, its files by content (size and xxh3-64, in order), not by path. Two tasks
    /// with the same signature ask for the same bytes but for the map's source file and key
    /// (the request, light, camera and every file's content are the same), so one bake serves
    /// both ([`crate::batch::run`]).
    #[must_use]
    pub fn hold_signature(&self) -> String {
        let mut request = self.request.clone();
        request.remove("frame");
        request.remove("input");
        let files: Vec<(u64, &str)> = self
            .files
            .iter()
            .map(|f| (f.size, f.xxh3.as_str()))
            .collect();
        serde_json::json!({
            "format": self.format,
            "request": request,
            "camera": self.camera,
            "files": files,
        })
        .to_string()
    }

    /// The recorded file identity for `path`, if any.
    fn file(&self, path: &Path) -> Option<&FileId> {
        self.files.iter().find(|f| f.path == path)
    }

    /// The request keys whose value differs between `self` (recorded) and `now`, in order.
    fn changed_keys(&self, now: &Self) -> Vec<String> {
        let mut keys: Vec<&String> = self.request.keys().chain(now.request.keys()).collect();
        keys.sort_unstable();
        keys.dedup();
        keys.into_iter()
            .filter(|k| self.request.get(*k) != now.request.get(*k))
            .cloned()
            .collect()
    }

    /// The files whose content differs (or that one key has and the other has not).
    fn changed_files(&self, now: &Self) -> Vec<PathBuf> {
        let mut out: Vec<PathBuf> = now
            .files
            .iter()
            .filter(|f| self.file(&f.path).is_none_or(|r| !r.same_content(f)))
            .map(|f| f.path.clone())
            .collect();
        out.extend(
            self.files
                .iter()
                .filter(|f| now.file(&f.path).is_none())
                .map(|f| f.path.clone()),
        );
        out
    }
}

/// What an output holds of its key.
#[derive(Debug, Clone, PartialEq)]
pub enum Stored {
    /// There is no output.
    Missing,
    /// The output is there but cannot be read as its format (the reason).
    Unreadable(String),
    /// The output is readable but carries no key (baked by an older umbra, or by hand).
    Unkeyed,
    /// The key the output carries.
    Key(Box<TaskKey>),
}

impl Stored {
    /// Read the key an output carries: an EXR's `umbra:key` attribute, a `.vdb`'s first
    /// grid's `umbra:key` metadata, a `.json` per-frame file's `key` member.
    #[must_use]
    pub fn read(output: &Path) -> Self {
        if !output.is_file() {
            return Self::Missing;
        }
        let ext = output
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        let text = match ext.as_deref() {
            Some("vdb") => vdb_key(output),
            Some("json") => json_key(output),
            _ => exr_key(output),
        };
        match text {
            Err(reason) => Self::Unreadable(reason),
            Ok(None) => Self::Unkeyed,
            Ok(Some(t)) => TaskKey::from_text(&t).map_or(Self::Unkeyed, |k| Self::Key(Box::new(k))),
        }
    }

    /// The key, if the output has one.
    #[must_use]
    pub fn key(&self) -> Option<&TaskKey> {
        match self {
            Self::Key(k) => Some(k),
            _ => None,
        }
    }
}

/// An EXR's `umbra:key` attribute (its header only is read).
fn exr_key(path: &Path) -> Result<Option<String>, String> {
    let meta = exr::meta::MetaData::read_from_file(path, false).map_err(|e| e.to_string())?;
    Ok(meta.headers.iter().find_map(|h| {
        match h
            .own_attributes
            .other
            .get(&exr::meta::attribute::Text::from(KEY_ATTRIBUTE))
        {
            Some(exr::meta::attribute::AttributeValue::Text(t)) => Some(t.to_string()),
            _ => None,
        }
    }))
}

/// A `.vdb`'s first grid's `umbra:key` metadata.
fn vdb_key(path: &Path) -> Result<Option<String>, String> {
    let archive = crate::vdb::Archive::open(path).map_err(|e| e.to_string())?;
    let Some(gd) = archive.grids.first() else {
        return Ok(None);
    };
    let header = archive.header(gd).map_err(|e| e.to_string())?;
    Ok(header.metadata.iter().find_map(|(k, v)| match v {
        crate::vdb::MetaValue::String(s) if k == KEY_ATTRIBUTE => Some(s.clone()),
        _ => None,
    }))
}

/// A per-frame file's `key` member (the key itself, as JSON).
fn json_key(path: &Path) -> Result<Option<String>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| e.to_string())?;
    let v: Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
    Ok(v.get("key").map(Value::to_string))
}

/// How a run or a status checks keys.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct KeyCheck {
    /// Take an output without a key (an older umbra's, or one made by hand) as up to date.
    pub keep_unkeyed: bool,
    /// Hash every file a task reads, even when its size and time match the recorded ones
    /// (finds a re-simulated file of the same size and time; reads every input).
    pub verify: bool,
}

/// One reason a task's output is stale.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Change {
    /// The output format's version differs (`was`, `now`).
    Format(String, String),
    /// Settings of the job changed, by key (`bake.density_scale`, `inputs[0].grid`).
    Settings(Vec<String>),
    /// The light changed (its name).
    Light(String),
    /// Files the task reads changed (their names).
    Input(Vec<String>),
    /// The shared or fixed camera changed (a frame of the sequence that frames it moved).
    Camera,
}

impl std::fmt::Display for Change {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Format(was, now) => write!(f, "output format changed: {was} -> {now}"),
            Self::Settings(k) => write!(f, "settings changed: {}", k.join(", ")),
            Self::Light(l) => write!(f, "light {l} changed"),
            Self::Input(names) => write!(f, "input changed: {}", names.join(", ")),
            Self::Camera => write!(f, "camera changed (the frames that frame it)"),
        }
    }
}

/// Why a task is baked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Stale {
    /// `force`.
    Forced,
    /// Its output is not there.
    Missing,
    /// Its output cannot be read (why).
    Unreadable(String),
    /// Its output carries no key.
    Unkeyed,
    /// Its key changed.
    Changed(Vec<Change>),
    /// Its key cannot be computed (a file it reads cannot be read: the bake says why).
    Unknown(String),
}

impl std::fmt::Display for Stale {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Forced => write!(f, "forced"),
            Self::Missing => write!(f, "output missing"),
            Self::Unreadable(e) => write!(f, "output unreadable: {e}"),
            Self::Unkeyed => write!(f, "output has no key (an older umbra's, or made by hand)"),
            Self::Changed(c) => {
                let parts: Vec<String> = c.iter().map(ToString::to_string).collect();
                write!(f, "{}", parts.join("; "))
            }
            Self::Unknown(e) => write!(f, "inputs unreadable: {e}"),
        }
    }
}

/// Whether a task is up to date, and its key now.
#[derive(Debug, Clone)]
pub struct Freshness {
    /// `None`: up to date. Else why it is baked.
    pub stale: Option<Stale>,
    /// The task's key now (written into its output when it is baked); `None` when a file it
    /// reads cannot be read.
    pub key: Option<TaskKey>,
}

impl Freshness {
    /// The reason as logged: why it is baked, or `up to date`.
    #[must_use]
    pub fn reason(&self) -> String {
        self.stale
            .as_ref()
            .map_or_else(|| "up to date".to_string(), ToString::to_string)
    }
}

/// The canonical form of a request's options: serialized after defaults, without
/// [`NOT_IN_KEY`].
pub(super) fn canonical(options: &crate::request::BakeOptions) -> Map<String, Value> {
    let mut m = match serde_json::to_value(options) {
        Ok(Value::Object(m)) => m,
        _ => Map::new(),
    };
    for k in NOT_IN_KEY {
        m.remove(*k);
    }
    m
}

/// The identities of `files` now, reusing `recorded`'s hashes where size and time match.
pub(super) fn identify(
    files: &[PathBuf],
    recorded: Option<&TaskKey>,
    check: KeyCheck,
) -> crate::error::Result<Vec<FileId>> {
    files
        .iter()
        .map(|p| FileId::of(p, recorded.and_then(|r| r.file(p)), check.verify))
        .collect()
}

/// Compare `stored` with the key now (`now`, or the error computing it).
pub(super) fn compare(
    stored: &Stored,
    now: Result<TaskKey, String>,
    check: KeyCheck,
    name: &dyn Fn(&str) -> Change,
) -> Freshness {
    let key = match now {
        Ok(k) => k,
        Err(e) => {
            return Freshness {
                stale: Some(Stale::Unknown(e)),
                key: None,
            }
        }
    };
    let stale = match stored {
        Stored::Missing => Some(Stale::Missing),
        Stored::Unreadable(e) => Some(Stale::Unreadable(e.clone())),
        Stored::Unkeyed => (!check.keep_unkeyed).then_some(Stale::Unkeyed),
        Stored::Key(old) => {
            let changes = changes(old, &key, name);
            (!changes.is_empty()).then_some(Stale::Changed(changes))
        }
    };
    Freshness {
        stale,
        key: Some(key),
    }
}

/// What differs between the recorded key `old` and `now`, named by `name`.
fn changes(old: &TaskKey, now: &TaskKey, name: &dyn Fn(&str) -> Change) -> Vec<Change> {
    let mut out = Vec::new();
    if old.format != now.format {
        out.push(Change::Format(old.format.clone(), now.format.clone()));
    }
    let mut settings = Vec::new();
    for k in old.changed_keys(now) {
        match name(&k) {
            Change::Settings(mut s) => settings.append(&mut s),
            c if !out.contains(&c) => out.push(c),
            _ => {}
        }
    }
    if !settings.is_empty() {
        out.insert(
            usize::from(old.format != now.format),
            Change::Settings(settings),
        );
    }
    let files = old.changed_files(now);
    if !files.is_empty() {
        let names = files
            .iter()
            .map(|p| {
                p.file_name().map_or_else(
                    || p.display().to_string(),
                    |n| n.to_string_lossy().into_owned(),
                )
            })
            .collect();
        out.push(Change::Input(names));
    }
    if old.camera != now.camera {
        out.push(Change::Camera);
    }
    out
}

impl Job {
    /// The format of this job's outputs in a key: `map/N` or `volume/N`.
    fn format(&self) -> String {
        let kind = if self.volume { "volume" } else { "map" };
        format!("{kind}/{FORMAT_VERSION}")
    }

    /// The key of `task` now ([`TaskKey`]), reusing `recorded`'s hashes of files whose size
    /// and time match (unless `check.verify`). Needs the shared cameras
    /// ([`Job::share_cameras_cached`]) for a job of shared framing.
    ///
    /// # Errors
    /// [`BatchError::Task`] when the files the task reads cannot be listed or read.
    pub fn task_key(
        &self,
        task: &Task,
        recorded: Option<&TaskKey>,
        check: KeyCheck,
    ) -> Result<TaskKey, BatchError> {
        let request = self.request(task, 0);
        let mut m = canonical(&request.options);
        m.insert(
            "input".into(),
            Value::from(task.input.display().to_string()),
        );
        m.insert("frame".into(), task.frame.map_or(Value::Null, Value::from));
        let files = task.source.files()?;
        let camera = if self.volume {
            None
        } else {
            self.camera.or_else(|| {
                self.shared
                    .get()
                    .and_then(|s| s.get(&(task.sequence, task.light.clone())))
                    .copied()
            })
        };
        Ok(TaskKey {
            format: self.format(),
            request: m,
            camera: camera.and_then(|c| serde_json::to_value(c).ok()),
            files: identify(&files, recorded, check)?,
        })
    }

    /// Whether `task`'s output is up to date against its key now, and that key (module docs).
    #[must_use]
    pub fn freshness(&self, task: &Task, check: KeyCheck) -> Freshness {
        let stored = Stored::read(&task.output);
        let now = self
            .task_key(task, stored.key(), check)
            .map_err(|e| e.to_string());
        compare(&stored, now, check, &|k| self.name_change(task, k))
    }

    /// A changed request key of `task`, named as the job file says it: a light key as the
    /// light; the keys an `[[inputs]]` entry may carry as `inputs[I].KEY` when the entry's
    /// value is the task's, else `bake.KEY`.
    fn name_change(&self, task: &Task, key: &str) -> Change {
        if LIGHT_KEYS.contains(&key) {
            return Change::Light(task.light.clone());
        }
        if key == "input" {
            return Change::Input(vec![task.input.display().to_string()]);
        }
        let own = match key {
            "grid" => task.grid != self.grid,
            "density_scale" => {
                task.density_scale.to_bits() != self.options.source.density_scale.to_bits()
            }
            "levelset" => task.levelset != self.options.source.levelset,
            "xform" => task.xform != self.options.source.xform,
            _ => false,
        };
        let name = if own {
            format!("inputs[{}].{key}", task.sequence)
        } else if key == "frame" {
            "frame".to_string()
        } else {
            format!("bake.{key}")
        };
        Change::Settings(vec![name])
    }
}

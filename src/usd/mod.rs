//! USD stages as inputs: the volumes and lights of a shot at one time code.
//!
//! A shot is a USD stage (`.usd`, `.usda`, `.usdc`, `.usdz`), read with the pure-Rust
//! [`openusd`] crate (0.8, with `openusd-schemas`' `XformOp` for the ops; it declares Rust 1.96,
//! so a 1.95 toolchain builds it with `--ignore-rust-version`; composition, time samples, value
//! clips, layer offsets, xformOps, the three formats). What umbra reads of it, at time code `t`:
//!
//! - **Volumes**: every active, visible `Volume` prim (or the prims named). Its density is the
//!   `OpenVDBAsset` its `field:density` relationship targets (another field by name): the
//!   asset's `filePath` at `t` (held, not interpolated), anchored to the layer that authors it
//!   (relative paths through sublayers and references; inside a `.usdz` a relative path names
//!   a member of the package, `shot.usdz[cloud.0002.vdb]`), the grid its `fieldName` names and,
//!   where several grids share the name, its `fieldIndex` (`density[1]`). The prim's
//!   local-to-world matrix at `t` places it: every xformOp, parents, `!invert!`,
//!   `!resetXformStack!`. USD's matrices act on row vectors (`p' = p M`); umbra's
//!   [`Xform`] acts on column vectors, so the volume's world-from-object is `M^T`.
//!   Optional attributes `umbra:densityScale` (a number), `umbra:sigmaT` (a number or a
//!   `color3f`) and `umbra:kind` (`"fog"`/`"solid"`) are the scene file's options.
//! - **Lights**: a `DistantLight` is a directional light travelling along its world `-Z` axis
//!   (`d = -(M_20, M_21, M_22)`, the third row of `M`, normalised); a `SphereLight`,
//!   `DiskLight`, `RectLight` or `CylinderLight` is a point light at its world origin
//!   (`(M_30, M_31, M_32)`). Other light types are listed but refused by name when chosen.
//! - **Shadows**: each light's `inputs:shadow:enable` and the membership of its
//!   `collection:shadowLink` ([`Link`], USD's `CollectionAPI` rules; everything when
//!   unauthored), on [`StageLight::shadow`]. A read toward a light ([`Selection::light`])
//!   keeps only the volumes its link includes and refuses a light with shadows off, so every
//!   product that loads the scene toward a light honours both.
//! - **Up**: the stage's `upAxis` (`Y` when unauthored), a map's default up.
//!
//! Nothing here decodes a voxel: [`Shot`] says which grid of which file goes where, and the
//! scene loader decodes only those grids (`scene::file`).

#[cfg(feature = "usd")]
mod clips;
mod emitter;
mod link;
#[cfg(feature = "usd")]
mod read;

use crate::error::{Error, Result};
use crate::xform::Xform;
use std::path::{Path, PathBuf};

pub use emitter::Emitter;
pub use link::{Link, Rule};
#[cfg(feature = "usd")]
pub use read::{lights_at, points_at, points_layer, read, shadow_layer};

/// The points of a `Points` or `PointInstancer` prim at a time code, in world space.
#[derive(Debug, Clone, PartialEq)]
pub struct StagePoints {
    /// The prim's path.
    pub prim: String,
    /// `Points` or `PointInstancer`.
    pub type_name: String,
    /// The time code read.
    pub time: f64,
    /// `points` (or `positions`) through the prim's local-to-world matrix, in authored order.
    pub positions: Vec<[f64; 3]>,
}

/// One baked map of a stage light, for the layer that hands maps back to the shot
/// ([`shadow_layer`]).
#[derive(Debug, Clone, PartialEq)]
pub struct ShadowSample {
    /// The light prim.
    pub light: String,
    /// The time code the map was baked at.
    pub time: f64,
    /// The map, as the layer names it (relative to the layer's directory when it is below it).
    pub map: String,
    /// The map's camera as OpenEXR's `worldToNDC`, a column-vector 4x4 (`[X, Y, Z, w] = M [p,
    /// 1]`, NDC `(X/w, Y/w)` in `[0, 1]^2` from the top-left corner). The layer stores it in
    /// USD's row-vector convention, `M^T`.
    pub world_to_ndc: [[f64; 4]; 4],
}

/// How `layer` (a `.usda` file to be written) names `map`: relative (`./maps/sun.0001.exr`)
/// when the map is in the layer's directory or below it, absolute otherwise.
#[must_use]
pub fn asset_name(layer: &Path, map: &Path) -> String {
    let abs = |p: &Path| std::path::absolute(p).map_or_else(|_| p.to_path_buf(), |a| lexical(&a));
    let (l, m) = (abs(layer), abs(map));
    let dir = l.parent().unwrap_or(Path::new("/"));
    match m.strip_prefix(dir) {
        Ok(rel) => format!("./{}", rel.display()),
        Err(_) => m.display().to_string(),
    }
}

/// What to read of a stage: the time code, which volumes, which field.
#[derive(Debug, Clone, PartialEq)]
pub struct Selection {
    /// Time code (`--frame`); `None`: the stage's `startTimeCode` (0 when unauthored).
    pub time: Option<f64>,
    /// `Volume` prims by path (`--volume`, repeatable); empty: every active, visible one.
    pub volumes: Vec<String>,
    /// The field relationship to follow (`field:<name>`; `--field`, default `density`).
    pub field: String,
    /// The light the volumes are read toward (a prim path, or a name as [`Shot::light`]
    /// takes it): only the volumes its `collection:shadowLink` includes are read, and a light
    /// whose shadows are off (`inputs:shadow:enable = false`) is refused. `None`: every
    /// selected volume (a bake toward light-dir / light-pos, a listing).
    pub light: Option<String>,
    /// Motion blur: the field relationship of each volume's velocity (`field:<name>`, as
    /// `--velocity` names it for a stage: `velocity`, `vel`); `None`: none read.
    pub velocity: Option<String>,
}

impl Selection {
    /// What a source's read options `o` read of a stage: `frame`, `volume`, `field` (default
    /// `density`), and `light`, whose shadow link picks the volumes (the velocity field is the
    /// motion's: `None` here).
    #[must_use]
    pub fn of(o: &crate::input::SourceOptions) -> Self {
        Self {
            time: o.frame,
            volumes: o.volume.clone().unwrap_or_default(),
            field: o.field.clone().unwrap_or_else(|| "density".into()),
            light: o.light.clone(),
            velocity: None,
        }
    }
}

impl Default for Selection {
    fn default() -> Self {
        Self {
            time: None,
            volumes: Vec::new(),
            field: "density".into(),
            light: None,
            velocity: None,
        }
    }
}

/// Where an asset's bytes are: a file, or a member of a `.usdz` package.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Asset {
    /// A file on disk.
    File(PathBuf),
    /// A member of a `.usdz` package (stored uncompressed, as the format requires).
    Packaged {
        /// The `.usdz` file.
        package: PathBuf,
        /// The member's path inside it.
        member: String,
    },
}

impl Asset {
    /// The asset as USD spells a resolved path: the file, or `package.usdz[member]`.
    #[must_use]
    pub fn display(&self) -> String {
        match self {
            Self::File(p) => p.display().to_string(),
            Self::Packaged { package, member } => format!("{}[{member}]", package.display()),
        }
    }
}

/// An asset ready to read: its file, and the scratch copy that holds a packaged member
/// (removed when this is dropped).
#[derive(Debug)]
pub struct Opened {
    path: PathBuf,
    _scratch: Option<crate::output::Scratch>,
}

impl Opened {
    /// The file to read.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Asset {
    /// A file to read the asset from: the file itself, or a scratch copy of a packaged member.
    ///
    /// # Errors
    /// [`Error::Io`] when the package cannot be read, [`Error::Stage`] naming the package when
    /// it is not a zip archive or has no such member, [`Error::Output`] when the scratch copy
    /// cannot be written.
    pub fn open(&self) -> Result<Opened> {
        match self {
            Self::File(p) => Ok(Opened {
                path: p.clone(),
                _scratch: None,
            }),
            Self::Packaged { package, member } => {
                let scratch = read::extract(package, member)?;
                Ok(Opened {
                    path: scratch.path().to_path_buf(),
                    _scratch: Some(scratch),
                })
            }
        }
    }
}

/// One volume of a shot: which grid of which asset, and how it is placed and scaled.
#[derive(Debug, Clone, PartialEq)]
pub struct StageVolume {
    /// The `Volume` prim's path.
    pub prim: String,
    /// The field asset prim's path (`OpenVDBAsset`).
    pub field_prim: String,
    /// The `filePath` as authored (for messages).
    pub authored: String,
    /// Where its bytes are.
    pub asset: Asset,
    /// The grid (`fieldName`, with `[fieldIndex]` when the index is not 0).
    pub grid: String,
    /// World from object at the time code (the prim's local-to-world, transposed).
    pub xform: Xform,
    /// `umbra:densityScale` (1 when unauthored).
    pub density_scale: f64,
    /// `umbra:sigmaT`: `None` when unauthored, three equal numbers for a grey one.
    pub sigma_t: Option<[f64; 3]>,
    /// Whether the colour was authored as a colour (it makes the scene RGB).
    pub rgb: bool,
    /// `umbra:kind = "solid"`: a level set traced as an opaque occluder.
    pub solid: bool,
    /// The velocity field's asset and grid (`field:<Selection::velocity>`), when asked for.
    pub velocity: Option<(Asset, String)>,
}

impl StageVolume {
    /// Its extinction per unit value when it is one grey fog, as a product made from one
    /// density grid needs it (a transmittance volume, an estimator comparison):
    /// `mu_t = densityScale x sigmaT x value`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `volume`) for a colour `umbra:sigmaT` or a solid.
    pub fn grey_scale(&self) -> Result<f64> {
        let refuse = |what: &str| Error::InvalidArgument {
            name: "volume".into(),
            reason: format!(
                "{} is {what}; this product is made from one grey density grid (bake a map \
                 for the whole shot)",
                self.prim
            ),
        };
        if self.solid {
            return Err(refuse("a solid (umbra:kind = \"solid\")"));
        }
        match self.sigma_t {
            Some(_) if self.rgb => Err(refuse("coloured (umbra:sigmaT is a color3f)")),
            Some(s) => Ok(self.density_scale * s[0]),
            None => Ok(self.density_scale),
        }
    }

    /// The `.vdb` file its grid is read from.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `volume`) for an asset packaged in a `.usdz`.
    pub fn file(&self) -> Result<&Path> {
        match &self.asset {
            Asset::File(p) => Ok(p),
            Asset::Packaged { .. } => Err(Error::InvalidArgument {
                name: "volume".into(),
                reason: format!(
                    "{}'s density is packaged inside {}: unpack the package to make a \
                     transmittance volume from it",
                    self.prim,
                    self.asset.display()
                ),
            }),
        }
    }
}

/// One UsdLux light of a stage.
#[derive(Debug, Clone, PartialEq)]
pub struct StageLight {
    /// Prim path.
    pub prim: String,
    /// Its schema type (`DistantLight`, `SphereLight`, `DomeLight`, ...).
    pub type_name: String,
    /// How umbra traces it; `None` for a type umbra does not trace (a dome, a portal, a
    /// geometry light).
    pub emitter: Option<Emitter>,
    /// Why a light of a type umbra traces cannot be traced (a shaped or textured light, a
    /// size out of range, an attribute that cannot be read): it is refused with this when it
    /// is chosen; the stage's other lights still read.
    pub refused: Option<String>,
    /// Its shadow controls (UsdLux `ShadowAPI`, `LightAPI`).
    pub shadow: Shadow,
}

/// A light's shadow controls, at the time code read.
#[derive(Debug, Clone, PartialEq)]
pub struct Shadow {
    /// `inputs:shadow:enable` (`true` when unauthored): `false`, the light casts no shadows
    /// and umbra bakes nothing toward it.
    pub enabled: bool,
    /// The membership of its `collection:shadowLink` ([`Link`]; every prim when unauthored).
    pub link: Link,
    /// The stage's active, visible `Volume` prims the link includes, in stage order.
    pub linked: Vec<String>,
    /// Those it leaves out.
    pub unlinked: Vec<String>,
    /// Why the controls could not be read (a path-expression collection, a bad value): the
    /// light is refused with this when it is chosen; the stage's other lights still read.
    pub unreadable: Option<String>,
}

impl Default for Shadow {
    fn default() -> Self {
        Self {
            enabled: true,
            link: Link::everything(),
            linked: Vec::new(),
            unlinked: Vec::new(),
            unreadable: None,
        }
    }
}

impl StageLight {
    /// The prim's name (the last path element), what a batch job names the light by.
    #[must_use]
    pub fn name(&self) -> &str {
        self.prim.rsplit('/').next().unwrap_or(&self.prim)
    }
}

/// What a stage holds at one time code.
#[derive(Debug, Clone, PartialEq)]
pub struct Shot {
    /// The stage file.
    pub path: PathBuf,
    /// The time code read.
    pub time: f64,
    /// The stage's up axis as a unit vector (`upAxis`: Y or Z).
    pub up: [f64; 3],
    /// The volumes selected, in stage order.
    pub volumes: Vec<StageVolume>,
    /// Every light of the stage, in stage order.
    pub lights: Vec<StageLight>,
    /// The stage's `timeCodesPerSecond` (else `framesPerSecond`, else 24): what a shutter in
    /// frames is converted to seconds with when no `--fps` is given.
    pub fps: f64,
}

impl Shot {
    /// The light `name` (a prim path, or a prim name when exactly one light has it), or the
    /// stage's only light when `name` is `None`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `light`) when no light, several lights (listing them)
    /// or an unknown name is found; [`Error::Stage`] when the light's type is not one umbra
    /// traces or its shadows are off (`inputs:shadow:enable = false`).
    pub fn light(&self, name: Option<&str>) -> Result<(&StageLight, Emitter)> {
        let listed = || {
            if self.lights.is_empty() {
                "the stage has no lights".to_string()
            } else {
                format!(
                    "its lights: {}",
                    self.lights
                        .iter()
                        .map(|l| format!("{} ({})", l.prim, l.type_name))
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            }
        };
        let chosen = match name {
            Some(n) => {
                let hits: Vec<&StageLight> = self
                    .lights
                    .iter()
                    .filter(|l| l.prim == n || l.name() == n)
                    .collect();
                match hits.as_slice() {
                    [one] => *one,
                    [] => {
                        return Err(self.which(format!(
                            "no light '{}' in {} at time {} ({})",
                            crate::text::escape(n),
                            self.path.display(),
                            self.time,
                            listed()
                        )))
                    }
                    _ => {
                        return Err(self.which(format!(
                            "several lights of {} are called '{}': name one by its path ({})",
                            self.path.display(),
                            crate::text::escape(n),
                            listed()
                        )))
                    }
                }
            }
            None => match self.lights.as_slice() {
                [one] => one,
                _ => {
                    return Err(self.which(format!(
                        "which light of {} at time {}? name one, or give light-dir or \
                         light-pos ({})",
                        self.path.display(),
                        self.time,
                        listed()
                    )))
                }
            },
        };
        if let Some(reason) = chosen
            .refused
            .as_ref()
            .or(chosen.shadow.unreadable.as_ref())
        {
            return Err(Error::Stage {
                path: self.path.clone(),
                reason: reason.clone(),
            });
        }
        if !chosen.shadow.enabled {
            return Err(self.err(format!(
                "{}: inputs:shadow:enable is false: the light casts no shadows, so there is no \
                 transmittance toward it to bake or query",
                chosen.prim
            )));
        }
        match chosen.emitter {
            Some(e) => Ok((chosen, e)),
            None => Err(self.err(format!(
                "{} is a {}: umbra traces DistantLight, SphereLight, DiskLight, RectLight \
                 and CylinderLight",
                chosen.prim, chosen.type_name
            ))),
        }
    }

    /// The volumes of `names` the shadow link of the light `light` includes (as
    /// [`Shot::light`] names it), in their order: what a bake or query toward that light reads.
    ///
    /// # Errors
    /// As [`Shot::light`] (an unknown light, one umbra does not trace, one whose shadows are
    /// off); [`Error::Stage`] when the link includes none of `names`: nothing casts the light's
    /// shadows, its transmittance is 1 everywhere, and umbra makes no map of it.
    pub fn linked(&self, light: &str, names: Vec<String>) -> Result<Vec<String>> {
        let (l, _) = self.light(Some(light))?;
        let (kept, left): (Vec<String>, Vec<String>) =
            names.into_iter().partition(|v| l.shadow.link.includes(v));
        if kept.is_empty() {
            return Err(self.err(format!(
                "{}: its collection:shadowLink includes none of the volumes ({}): nothing casts \
                 its shadows (T = 1 everywhere), so there is nothing to bake or query",
                l.prim,
                left.join(", ")
            )));
        }
        Ok(kept)
    }

    /// The shot's one volume, for a product made from one density grid.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (name `volume`) listing the volumes when there are several.
    pub fn single_volume(&self) -> Result<&StageVolume> {
        match self.volumes.as_slice() {
            [one] => Ok(one),
            many => Err(Error::InvalidArgument {
                name: "volume".into(),
                reason: format!(
                    "{} has {} volumes at time {} ({}): this product is made from one density \
                     grid; name one",
                    self.path.display(),
                    many.len(),
                    self.time,
                    many.iter()
                        .map(|v| v.prim.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            }),
        }
    }

    /// A light choice the caller has to make: an argument error naming `light`, which each
    /// front end spells its own way (`--light`, `light=`).
    fn which(&self, reason: String) -> Error {
        Error::InvalidArgument {
            name: "light".into(),
            reason,
        }
    }

    fn err(&self, reason: String) -> Error {
        Error::Stage {
            path: self.path.clone(),
            reason: format!("at time {}: {reason}", self.time),
        }
    }
}

/// Normalise a `/`-separated relative path lexically (`a/./b/../c` -> `a/c`); `None` when it
/// climbs above its start.
fn normalise_member(p: &str) -> Option<String> {
    let mut out: Vec<&str> = Vec::new();
    for part in p.split('/') {
        match part {
            "" | "." => {}
            ".." => {
                out.pop()?;
            }
            x => out.push(x),
        }
    }
    Some(out.join("/"))
}

/// Split USD's package-relative form `outer[inner]` (the last `[`; the path must end in `]`).
fn split_packaged(s: &str) -> Option<(&str, &str)> {
    let body = s.strip_suffix(']')?;
    let i = body.find('[')?;
    Some((&body[..i], &body[i + 1..]))
}

/// Resolve an authored asset path against the identifier of the layer that authored it (a
/// file path, or `package.usdz[inner/layer.usdc]`), as USD's default resolver does: absolute
/// paths stand, relative ones are anchored to the layer's directory; inside a package they
/// name a member of the package.
#[must_use]
pub fn resolve_asset(authored: &str, layer: &str) -> Asset {
    if let Some((outer, inner)) = split_packaged(authored) {
        let package = resolve_asset(outer, layer);
        let package = match package {
            Asset::File(p) => p,
            Asset::Packaged { package, .. } => package,
        };
        return Asset::Packaged {
            package,
            member: normalise_member(inner).unwrap_or_else(|| inner.to_string()),
        };
    }
    let path = Path::new(authored);
    if path.is_absolute() {
        return Asset::File(path.to_path_buf());
    }
    let is_package = |l: &str| crate::input::is_package(Path::new(l));
    // A package's root layer is named by the package itself.
    let packaged = split_packaged(layer).or_else(|| is_package(layer).then_some((layer, "")));
    if let Some((outer, inner)) = packaged {
        let dir = inner.rsplit_once('/').map_or("", |(d, _)| d);
        let joined = if dir.is_empty() {
            authored.to_string()
        } else {
            format!("{dir}/{authored}")
        };
        if let Some(member) = normalise_member(&joined) {
            return Asset::Packaged {
                package: PathBuf::from(outer),
                member,
            };
        }
        // Climbs out of the package: the package counts as a directory.
        return Asset::File(lexical(&Path::new(outer).join(joined)));
    }
    let dir = Path::new(layer).parent().unwrap_or(Path::new(""));
    Asset::File(lexical(&dir.join(authored)))
}

/// `a/./b/../c` -> `a/c`, without touching the file system.
fn lexical(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            std::path::Component::CurDir => {}
            std::path::Component::ParentDir => {
                if !out.pop() {
                    out.push("..");
                }
            }
            other => out.push(other),
        }
    }
    out
}

#[cfg(not(feature = "usd"))]
mod read {
    use super::{Error, Path, Result};
    pub(super) fn extract(package: &Path, _member: &str) -> Result<crate::output::Scratch> {
        Err(Error::Unsupported {
            path: package.to_path_buf(),
            what: "USD packages (this umbra was built without the \"usd\" feature)".into(),
        })
    }
}

/// The error for a stage when umbra is built without USD support.
#[cfg(not(feature = "usd"))]
pub fn read(path: &Path, _sel: &Selection) -> Result<Shot> {
    Err(Error::Unsupported {
        path: path.to_path_buf(),
        what: "USD stages (this umbra was built without the \"usd\" feature)".into(),
    })
}

/// The error for a stage when umbra is built without USD support.
#[cfg(not(feature = "usd"))]
pub fn points_at(path: &Path, _prim: &str, _time: Option<f64>) -> Result<StagePoints> {
    read(path, &Selection::default()).map(|_| StagePoints {
        prim: String::new(),
        type_name: String::new(),
        time: 0.0,
        positions: Vec::new(),
    })
}

/// The error for a points layer when umbra is built without USD support.
#[cfg(not(feature = "usd"))]
pub fn points_layer(
    _prim: &str,
    _light: &str,
    _samples: &[(f64, Vec<f32>)],
    _errors: Option<&[(f64, Vec<f32>)]>,
) -> Result<String> {
    Err(Error::Unsupported {
        path: PathBuf::from("usd-out"),
        what: "USD layers (this umbra was built without the \"usd\" feature)".into(),
    })
}

/// The error for a stage when umbra is built without USD support.
#[cfg(not(feature = "usd"))]
pub fn lights_at(path: &Path, _time: Option<f64>) -> Result<Shot> {
    read(path, &Selection::default())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn assets_resolve_as_usd_anchors_them() {
        let f = |a: &str, l: &str| resolve_asset(a, l);
        assert_eq!(
            f("./cloud.vdb", "/shots/a/shot.usda"),
            Asset::File("/shots/a/cloud.vdb".into())
        );
        assert_eq!(
            f("../caches/c.vdb", "/shots/a/layers/fx.usdc"),
            Asset::File("/shots/a/caches/c.vdb".into())
        );
        assert_eq!(
            f("/abs/c.vdb", "/shots/a/shot.usda"),
            Asset::File("/abs/c.vdb".into())
        );
        assert_eq!(
            f("./cloud.0002.vdb", "/s/shot.usdz[shot.usdc]"),
            Asset::Packaged {
                package: "/s/shot.usdz".into(),
                member: "cloud.0002.vdb".into()
            }
        );
        assert_eq!(
            f("vdb/c.vdb", "/s/shot.usdz[0/shot.usdc]"),
            Asset::Packaged {
                package: "/s/shot.usdz".into(),
                member: "0/vdb/c.vdb".into()
            }
        );
        assert_eq!(
            f("../../c.vdb", "/s/shot.usdz[0/shot.usdc]"),
            Asset::File("/s/c.vdb".into())
        );
        assert_eq!(
            f("./pkg.usdz[0/c.vdb]", "/s/shot.usda"),
            Asset::Packaged {
                package: "/s/pkg.usdz".into(),
                member: "0/c.vdb".into()
            }
        );
        assert_eq!(
            f("0/cloud.vdb", "/s/shot.usdz"),
            Asset::Packaged {
                package: "/s/shot.usdz".into(),
                member: "0/cloud.vdb".into()
            }
        );
    }
}

//! Encoding baked maps: OpenEXR with every attribute needed to use the map, and an 8-bit PNG
//! preview. Files are written through [`crate::output`] (atomic, all outputs of one bake
//! together).

use crate::bake::camera::Projection;
use crate::bake::encode::layout::{mip_levels, ExrLayout};
use crate::bake::map::Map;
use crate::error::{Error, Result};
use crate::output::{commit_all, stage, write_atomic};
use exr::meta::attribute::{AttributeValue, Text};
use exr::prelude::{
    AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes, Levels,
    SmallVec, SpecificChannels, Vec2, WritableImage,
};
use std::io::Write;
use std::path::Path;

fn output_err(path: &Path, reason: impl Into<String>) -> Error {
    Error::Output {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// Where a map came from, for the EXR attributes.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Provenance {
    /// Source `.vdb` file as given.
    pub source_file: String,
    /// Grid name.
    pub grid: String,
    /// `mu_t = density_scale x value`.
    pub density_scale: f64,
    /// Light direction as given (direction the light travels).
    pub light_dir: Option<[f64; 3]>,
    /// Light position as given.
    pub light_pos: Option<[f64; 3]>,
    /// The object transform the volume was placed with (`--xform`), row-major.
    pub xform: Option<[[f64; 4]; 4]>,
    /// The extinction colour given with the input (`--sigma-t`), if any.
    pub sigma_t: Option<[f64; 3]>,
    /// A batch task's key (`umbra::batch::TaskKey` as text): the `umbra:key` attribute.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub key: Option<String>,
}

/// An EXR text attribute: characters outside Latin-1 become `?`.
fn text(s: &str) -> AttributeValue {
    let s: String = s
        .chars()
        .map(|c| if u32::from(c) < 256 { c } else { '?' })
        .collect();
    AttributeValue::Text(Text::new_or_none(&s).unwrap_or_default())
}

/// OpenEXR `v3d` (three little-endian f64).
fn v3d(v: [f64; 3]) -> AttributeValue {
    AttributeValue::Custom {
        kind: Text::from("v3d"),
        bytes: v.iter().flat_map(|c| c.to_le_bytes()).collect(),
    }
}

/// A column-vector 4x4 as OpenEXR's row-vector `m44f` (the transpose, row-major).
pub(crate) fn m44f(m: [[f64; 4]; 4]) -> [f32; 16] {
    std::array::from_fn(|k| m[k % 4][k / 4] as f32)
}

/// Write `map` to `path` as a single-part scanline OpenEXR (ZIP, increasing line order) with
/// f32 channels `T`, `T.stderr` (if baked) and `sliceNN.T` per depth (a colour map: `R`, `G`,
/// `B`, `R.stderr`, ..., `sliceNN.R`, ...), the standard
/// `worldToCamera` / `worldToNDC` matrices and `umbra:*` attributes: `camera_kind`,
/// `camera_origin`, `camera_step_x`, `camera_step_y`, `camera_direction` (v3d), `camera_t_max`
/// (double), `light_dir` / `light_pos` (v3d, as given), `xform` (text: the 16 numbers of
/// `--xform`, row-major, round-tripping f64), `fov_deg` (perspective), `estimator`,
/// `estimator_params` (JSON), `interp`, `spp`, `target_error`, `max_spp`, `mean_spp`, `seed`
/// (decimal text), `density_scale`, `source_file`, `grid`, `depth.NN` (double per slice),
/// `ray_ids`, `colour_walk` (a stochastic colour map). Same map, same bytes.
///
/// # Errors
/// [`Error::Output`] as [`write_atomic`], or if the encoder fails.
pub fn write_exr(path: &Path, map: &Map, prov: &Provenance, overwrite: bool) -> Result<()> {
    write_exr_as(path, map, prov, &ExrLayout::SCANLINES, overwrite)
}

/// [`write_exr`] in `layout`: scanlines, or tiles of `n x n` pixels (the same channels and
/// attributes; OpenEXR's `tiles` attribute says the tile size and level mode), with
/// box-filtered round-down mip levels of every channel when `layout.mipmap`
/// ([`crate::bake::mip_levels`]).
///
/// # Errors
/// [`Error::InvalidArgument`] for a layout [`ExrLayout::validate`] refuses; as [`write_exr`].
pub fn write_exr_as(
    path: &Path,
    map: &Map,
    prov: &Provenance,
    layout: &ExrLayout,
    overwrite: bool,
) -> Result<()> {
    layout.validate()?;
    let bytes = encode_exr(map, prov, layout).map_err(|e| output_err(path, e))?;
    write_atomic(path, overwrite, |w| {
        w.write_all(&bytes).map_err(|e| format!("writing: {e}"))
    })
}

/// Write the map to `exr` and, if given, its preview to `png`, all or nothing: both are
/// encoded and written to temporary files first, and renamed into place only when both
/// succeeded.
///
/// # Errors
/// [`Error::Output`] for either file (as [`write_atomic`]); then neither was written.
pub fn write_map(
    exr: &Path,
    png: Option<&Path>,
    map: &Map,
    prov: &Provenance,
    layout: &ExrLayout,
    overwrite: bool,
) -> Result<()> {
    commit_all(stage_map(exr, png, map, prov, layout, overwrite)?)
}

/// [`write_map`] staged, not committed: the map and its preview as temporary files beside
/// their targets, for [`crate::output::commit_all`] with the other outputs of a bake.
///
/// # Errors
/// As [`write_map`]; nothing is staged on error.
pub(crate) fn stage_map(
    exr: &Path,
    png: Option<&Path>,
    map: &Map,
    prov: &Provenance,
    layout: &ExrLayout,
    overwrite: bool,
) -> Result<Vec<crate::output::Staged>> {
    if png.is_some_and(|p| crate::output::same_file(p, exr)) {
        return Err(output_err(exr, "the preview and the map are the same file"));
    }
    layout.validate()?;
    let bytes = encode_exr(map, prov, layout).map_err(|e| output_err(exr, e))?;
    stage_with_preview(exr, &bytes, png, map, overwrite)
}

/// Stage `bytes` for `path` and, if given, `map`'s PNG preview for `png` (committed together
/// by the caller).
///
/// # Errors
/// As [`write_map`]; nothing is staged on error.
pub(crate) fn stage_with_preview(
    path: &Path,
    bytes: &[u8],
    png: Option<&Path>,
    map: &Map,
    overwrite: bool,
) -> Result<Vec<crate::output::Staged>> {
    if png.is_some_and(|p| crate::output::same_file(p, path)) {
        return Err(output_err(
            path,
            "the preview and the map are the same file",
        ));
    }
    let mut staged = vec![stage(path, overwrite, |w| {
        w.write_all(bytes).map_err(|e| format!("writing: {e}"))
    })?];
    if let Some(p) = png {
        let px = preview_pixels(map);
        staged.push(stage(p, overwrite, |w| encode_png(w, map, &px))?);
    }
    Ok(staged)
}

/// The EXR file's bytes (see [`write_exr`] and [`write_exr_as`]).
fn encode_exr(
    map: &Map,
    prov: &Provenance,
    layout: &ExrLayout,
) -> std::result::Result<Vec<u8>, String> {
    encode_exr_with(map, prov, layout, Vec::new(), Vec::new())
}

/// Whether the EXR encoder compresses its chunks in parallel for a bake on `threads` threads
/// (0: all cores): the `exr` crate's pool has a thread per core, so only when the bake may use
/// them all. The chunks are compressed alike and written in line order either way: the same
/// bytes.
fn compress_in_parallel(threads: usize) -> bool {
    threads == 0 || std::thread::available_parallelism().is_ok_and(|n| threads >= n.get())
}

/// [`encode_exr`] with more channels (one value per pixel each; scanline and tiled layouts,
/// not mip levels) and more header attributes.
pub(crate) fn encode_exr_with(
    map: &Map,
    prov: &Provenance,
    layout: &ExrLayout,
    planes: Vec<(String, Vec<f32>)>,
    attrs: Vec<(String, AttributeValue)>,
) -> std::result::Result<Vec<u8>, String> {
    if layout.mipmap && !planes.is_empty() {
        return Err("extra channels are written without mip levels".into());
    }
    let c = &map.camera;
    let size = (c.width as usize, c.height as usize);
    // An omnidirectional map has no image plane: `envmap` instead of the camera matrices.
    let omni = crate::bake::camera::is_omni(c.kind);
    let mut a = LayerAttributes {
        world_to_camera: (!omni).then(|| m44f(c.world_to_camera())),
        world_to_normalized_device: (!omni).then(|| m44f(c.world_to_ndc())),
        environment_map: envmap(c.kind),
        software_name: Some(Text::from(concat!("umbra ", env!("CARGO_PKG_VERSION")))),
        comments: Some(Text::from(
            "T = exp(-tau) along each pixel's ray; see the umbra:* attributes",
        )),
        ..LayerAttributes::default()
    };
    for (k, v) in umbra_attributes(map, prov).into_iter().chain(attrs) {
        a.other.insert(Text::from(k.as_str()), v);
    }
    let enc = Encoding {
        compression: exr::compression::Compression::ZIP16,
        blocks: match layout.tile {
            Some(n) => exr::image::Blocks::Tiles(Vec2(n as usize, n as usize)),
            None => exr::image::Blocks::ScanLines,
        },
        line_order: exr::meta::attribute::LineOrder::Increasing,
    };
    let parallel = compress_in_parallel(map.settings.threads);
    let mut buf = std::io::Cursor::new(Vec::new());
    // Each layout is its own image type; they encode alike.
    macro_rules! encode {
        ($image:expr) => {{
            let writer = $image.write();
            if parallel {
                writer.to_buffered(&mut buf)
            } else {
                writer.non_parallel().to_buffered(&mut buf)
            }
        }};
    }
    let encoded = if layout.mipmap {
        // Every channel with its levels (the list as below, each a `Levels::Mip`).
        let mut list: SmallVec<[AnyChannel<Levels<FlatSamples>>; 4]> = SmallVec::new();
        for (name, data) in channel_planes(map) {
            let levels = mip_levels(data, size.0, size.1)
                .into_iter()
                .map(FlatSamples::F32)
                .collect();
            list.push(AnyChannel::new(
                name,
                Levels::Mip {
                    rounding_mode: exr::math::RoundingMode::Down,
                    level_data: levels,
                },
            ));
        }
        let image = Image::from_layer(Layer::new(size, a, enc, AnyChannels::sort(list)));
        encode!(image)
    } else if map.std_err.is_none()
        && map.slices.is_empty()
        && map.color.is_none()
        && planes.is_empty()
    {
        // The common single-channel map is read straight from `map.t` (no copy of the image).
        let width = size.0;
        let channels = SpecificChannels::build()
            .with_channel("T")
            .with_pixel_fn(|p: Vec2<usize>| (map.t[p.y() * width + p.x()],));
        let image = Image::from_layer(Layer::new(size, a, enc, channels));
        encode!(image)
    } else {
        let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
        for (name, data) in channel_planes(map) {
            list.push(AnyChannel::new(name, FlatSamples::F32(data.to_vec())));
        }
        for (name, data) in planes {
            let name =
                Text::new_or_none(name.as_str()).ok_or("a channel name that is not ASCII")?;
            list.push(AnyChannel::new(name, FlatSamples::F32(data)));
        }
        let image = Image::from_layer(Layer::new(size, a, enc, AnyChannels::sort(list)));
        encode!(image)
    };
    encoded.map_err(|e| format!("OpenEXR encoder: {e}"))?;
    let mut bytes = buf.into_inner();
    sort_attributes(&mut bytes)?;
    Ok(bytes)
}

/// OpenEXR's `envmap` of an omnidirectional map (`None` for others).
pub(crate) fn envmap(kind: Projection) -> Option<exr::meta::attribute::EnvironmentMap> {
    match kind {
        Projection::Cube => Some(exr::meta::attribute::EnvironmentMap::Cube),
        Projection::LatLong => Some(exr::meta::attribute::EnvironmentMap::LatitudeLongitude),
        _ => None,
    }
}

/// The `umbra:*` header attributes of a map (camera, estimator, provenance, slice depths), by
/// full name: what flat and deep maps both carry.
pub(crate) fn umbra_attributes(map: &Map, prov: &Provenance) -> Vec<(String, AttributeValue)> {
    let c = &map.camera;
    let s = &map.settings;
    let kind = match c.kind {
        Projection::Ortho => "ortho",
        Projection::Perspective => "perspective",
        Projection::Cube => "cube",
        Projection::LatLong => "latlong",
    };
    let mut attrs: Vec<(String, AttributeValue)> = vec![
        ("camera_kind".into(), text(kind)),
        ("camera_origin".into(), v3d(c.origin)),
        ("camera_step_x".into(), v3d(c.step_x)),
        ("camera_step_y".into(), v3d(c.step_y)),
        ("camera_direction".into(), v3d(c.direction)),
        ("camera_t_max".into(), AttributeValue::F64(c.t_max)),
        ("estimator".into(), text(s.estimator.name())),
        (
            "estimator_params".into(),
            text(&serde_json::to_string(&s.estimator).unwrap_or_default()),
        ),
        (
            "interp".into(),
            text(&format!("{:?}", s.options.interp).to_lowercase()),
        ),
        // A deterministic estimator takes one sample whatever `--spp` says.
        (
            "spp".into(),
            AttributeValue::I32(clamp_i32(if s.estimator.is_deterministic() {
                1
            } else {
                u64::from(s.options.samples)
            })),
        ),
        (
            "max_spp".into(),
            AttributeValue::I32(clamp_i32(u64::from(s.max_spp))),
        ),
        (
            "mean_spp".into(),
            AttributeValue::F64(map.stats.samples as f64 / map.stats.rays.max(1) as f64),
        ),
        ("seed".into(), text(&s.options.seed.to_string())),
        (
            "density_scale".into(),
            AttributeValue::F64(prov.density_scale),
        ),
        ("source_file".into(), text(&prov.source_file)),
        ("grid".into(), text(&prov.grid)),
        (
            "ray_ids".into(),
            text(if s.soft.is_some() {
                "pixel (i, j): T is query --at <receiver> --ray-id j*W+i toward the light, slice k's receiver ray id (64+k)*W*H+j*W+i"
            } else {
                "pixel (i, j): T uses ray id j*W+i, adaptive batch b ray id b*W*H+j*W+i, slice k ray id (64+k)*W*H+j*W+i"
            }),
        ),
    ];
    if let Some(d) = prov.light_dir {
        attrs.push(("light_dir".into(), v3d(d)));
    }
    if let Some(x) = prov.xform {
        let v: Vec<String> = x.iter().flatten().map(|c| format!("{c:?}")).collect();
        attrs.push(("xform".into(), text(&v.join(","))));
    }
    if let Some(p) = prov.light_pos {
        attrs.push(("light_pos".into(), v3d(p)));
    }
    if let Some(s) = prov.sigma_t {
        attrs.push(("sigma_t".into(), v3d(s)));
    }
    if let Some(k) = &prov.key {
        attrs.push(("key".into(), text(k)));
    }
    if map.channels() == 3 && !s.estimator.is_deterministic() {
        attrs.push(("colour_walk".into(), text(s.options.colour_walk.name())));
    }
    if crate::bake::camera::is_omni(c.kind) {
        // The map's axes in the world (module `camera::omni`): X_m = -right, Y_m = up,
        // Z_m = forward.
        let r = c.right();
        attrs.push((
            "omni_x".into(),
            v3d([-r[0] + 0.0, -r[1] + 0.0, -r[2] + 0.0]),
        ));
        attrs.push(("omni_y".into(), v3d(c.up())));
        attrs.push(("omni_z".into(), v3d(c.forward())));
    }
    if let Some((h, _)) = c.fov_deg() {
        attrs.push(("fov_deg".into(), AttributeValue::F64(h)));
    }
    if let Some(e) = s.target_error {
        attrs.push(("target_error".into(), AttributeValue::F64(e)));
    }
    for (k, d) in map.depths.iter().enumerate() {
        attrs.push((format!("depth.{k:02}"), AttributeValue::F64(*d)));
    }
    if let Some(soft) = &s.soft {
        attrs.extend(soft_attributes(soft, &map.stats));
    }
    attrs
        .into_iter()
        .map(|(k, v)| (format!("umbra:{k}"), v))
        .collect()
}

/// A soft map's attributes (docs/lights.md): the receiver, the light's extent and directions,
/// the receivers sampled, and the ray ids (replacing the hard map's `ray_ids`).
fn soft_attributes(
    soft: &crate::bake::SoftMap,
    stats: &crate::bake::BakeStats,
) -> Vec<(String, AttributeValue)> {
    let mut attrs = vec![
        ("receiver".into(), text(&soft.receiver.to_string())),
        ("light_extent".into(), text(&soft.light.extent.to_string())),
        (
            "light_samples".into(),
            AttributeValue::I32(clamp_i32(u64::from(soft.light.samples))),
        ),
    ];
    if let Some([sampled, all]) = stats.light_sampled {
        attrs.push((
            "light_sampled_fraction".into(),
            AttributeValue::F64(sampled as f64 / all.max(1) as f64),
        ));
    }
    if let Some(e) = soft.light.target {
        attrs.push(("light_target_error".into(), AttributeValue::F64(e)));
    }
    if let Some(b) = stats.light_bounded {
        attrs.push(("light_bounded".into(), AttributeValue::I32(clamp_i32(b))));
    }
    if let Some(d) = stats.light_directions {
        attrs.push(("light_directions_mean".into(), AttributeValue::F64(d.mean)));
        attrs.push((
            "light_directions_p99".into(),
            AttributeValue::I32(clamp_i32(d.p99)),
        ));
        attrs.push((
            "light_capped".into(),
            AttributeValue::I32(clamp_i32(d.capped)),
        ));
    }
    attrs
}

/// Every channel of `map` with its name: `T` (or `R`, `G`, `B`), each followed by its
/// `.stderr` and `sliceNN` channels.
fn channel_planes(map: &Map) -> Vec<(Text, &[f32])> {
    let names =
        crate::bake::map::channel_names(map.channels(), map.std_err.is_some(), map.slices.len());
    let mut planes: Vec<&[f32]> = Vec::with_capacity(names.len());
    for c in 0..map.channels() {
        let (t, err, slices) = map.channel(c);
        planes.push(t);
        planes.extend(err);
        planes.extend(slices.iter().map(Vec::as_slice));
    }
    names
        .iter()
        .map(|n| Text::new_or_none(n.as_str()).unwrap_or_default())
        .zip(planes)
        .collect()
}

/// Put the attributes of a single-part OpenEXR header in name order, as the OpenEXR library
/// itself writes them (the exr crate keeps custom attributes in a `HashMap`, whose order
/// changes from run to run). The header keeps its length, so the offset table stays valid.
fn sort_attributes(bytes: &mut [u8]) -> std::result::Result<(), String> {
    let bad = || "OpenEXR encoder produced an unreadable header".to_string();
    let nul = |from: usize| {
        bytes
            .get(from..)
            .and_then(|b| b.iter().position(|&c| c == 0))
            .map(|p| from + p)
    };
    let start = 8; // magic number and version
    let mut pos = start;
    let mut attrs: Vec<(Vec<u8>, std::ops::Range<usize>)> = Vec::new();
    loop {
        let name_end = nul(pos).ok_or_else(bad)?;
        if name_end == pos {
            break;
        }
        let type_end = nul(name_end + 1).ok_or_else(bad)?;
        let size = bytes
            .get(type_end + 1..type_end + 5)
            .and_then(|b| <[u8; 4]>::try_from(b).ok())
            .map(i32::from_le_bytes)
            .and_then(|v| usize::try_from(v).ok())
            .ok_or_else(bad)?;
        let end = type_end + 5 + size;
        if end > bytes.len() {
            return Err(bad());
        }
        attrs.push((bytes[pos..name_end].to_vec(), pos..end));
        pos = end;
    }
    attrs.sort_by(|a, b| a.0.cmp(&b.0));
    let sorted: Vec<u8> = attrs
        .iter()
        .flat_map(|(_, r)| bytes[r.clone()].to_vec())
        .collect();
    bytes[start..pos].copy_from_slice(&sorted);
    Ok(())
}

fn clamp_i32(v: u64) -> i32 {
    i32::try_from(v).unwrap_or(i32::MAX)
}

/// Write `map.t` as an 8-bit grayscale PNG (an RGB PNG of `R`, `G`, `B` for a colour map):
/// `round(255 clamp(T, 0, 1))` per pixel and channel (linear, no gamma; black is opaque, white
/// fully transparent), row 0 at the top.
///
/// # Errors
/// [`Error::Output`] as [`write_atomic`], or if the encoder fails.
pub fn write_png(path: &Path, map: &Map, overwrite: bool) -> Result<()> {
    let px = preview_pixels(map);
    write_atomic(path, overwrite, |w| encode_png(w, map, &px))
}

/// The preview's 8-bit values: grey, or interleaved R, G, B for a colour map.
fn preview_pixels(map: &Map) -> Vec<u8> {
    let q = |t: f32| {
        let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
        (t * 255.0).round() as u8
    };
    match &map.color {
        None => map.t.iter().map(|&t| q(t)).collect(),
        Some(gb) => map
            .t
            .iter()
            .zip(&gb[0].t)
            .zip(&gb[1].t)
            .flat_map(|((&r, &g), &b)| [q(r), q(g), q(b)])
            .collect(),
    }
}

fn encode_png(w: &mut impl Write, map: &Map, bytes: &[u8]) -> std::result::Result<(), String> {
    let mut enc = png::Encoder::new(&mut *w, map.camera.width, map.camera.height);
    enc.set_color(if map.color.is_some() {
        png::ColorType::Rgb
    } else {
        png::ColorType::Grayscale
    });
    enc.set_depth(png::BitDepth::Eight);
    let mut pw = enc
        .write_header()
        .map_err(|e| format!("PNG encoder: {e}"))?;
    pw.write_image_data(bytes)
        .map_err(|e| format!("PNG encoder: {e}"))?;
    pw.finish().map_err(|e| format!("PNG encoder: {e}"))?;
    w.flush().map_err(|e| format!("writing: {e}"))
}

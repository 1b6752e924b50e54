//! Planning a request ([`BakeRequest::plan`]'s steps): a USD stage's light, camera and up
//! axis put into the options; a transmittance volume's job; a map's job (view, settings,
//! product, outputs).

use crate::bake::{
    BakeJob, BakeSettings, Depths, ExrLayout, Product, View, VolumeJob, DEFAULT_DEEP_ERROR,
    DEFAULT_OUT_GRID,
};
use crate::error::{Error, Result};
use crate::input::{Source, SourceOptions};

use super::{bad, is_volume_output, BakeRequest};

/// A transmittance volume's motion on a stage: the velocity field of its volume `v` (its grid
/// in its own file) at the stage's rate `fps` unless fps was given.
fn stage_motion(
    motion: Option<crate::motion::MotionRequest>,
    v: &crate::usd::StageVolume,
    fps: f64,
) -> Result<Option<crate::motion::MotionRequest>> {
    let (Some(mut m), Some((asset, grid))) = (motion.clone(), &v.velocity) else {
        return Ok(motion);
    };
    let crate::usd::Asset::File(f) = asset else {
        return Err(bad(
            "velocity",
            format!("{} is packaged: unpack it to read it", asset.display()),
        ));
    };
    m.velocity.clone_from(grid);
    m.file = Some(f.clone());
    if !m.fps_given {
        m.spec = m.spec.with_fps(fps)?;
    }
    Ok(Some(m))
}

impl BakeRequest {
    /// The stage's part of a request: options that only a USD stage reads are refused for
    /// other inputs; for a stage without light-dir, light-pos or camera, the light named by
    /// `light` (or the stage's only light) at `frame` becomes light-dir (a `DistantLight`) or
    /// light-pos (a local light), and the stage's up axis the map's default up (unless it is
    /// parallel to the light). `None`: nothing to change.
    pub(super) fn with_stage_light(&self) -> Result<Option<Self>> {
        let o = &self.options;
        let s = &o.source;
        let source = self.source();
        source.check()?;
        if !source.kind().is_stage() {
            if o.usd_out.is_some() {
                return Err(bad("usd-out", source.not_a_stage()));
            }
            return Ok(None);
        }
        let explicit = o.light.light_dir.is_some() || o.light.light_pos.is_some();
        if let Some(u) = &o.usd_out {
            if explicit {
                return Err(bad(
                    "usd-out",
                    "puts the map on its stage light: bake from the stage's light (light), not \
                     light-dir / light-pos",
                ));
            }
            if o.camera.is_some() {
                // A reused camera fixes the view; the layer still needs the light it belongs
                // to, named (or the stage's only one), checked before any work.
                crate::usd::lights_at(&self.input, s.frame)?.light(s.light.as_deref())?;
            }
            if !crate::input::is_usda_layer(u) {
                return Err(bad(
                    "usd-out",
                    format!("{} is not a .usda layer", u.display()),
                ));
            }
        }
        if s.light.is_some() && explicit {
            return Err(bad(
                "light",
                "give a stage light or light-dir / light-pos, not both",
            ));
        }
        if s.light.is_some() && o.camera.is_some() && o.usd_out.is_none() {
            return Err(bad(
                "light",
                "a reused camera fixes the view: the light only names the prim a --usd-out \
                 layer puts the map on (give usd-out, or drop light)",
            ));
        }
        if explicit || o.camera.is_some() {
            return Ok(None);
        }
        let shot = crate::usd::lights_at(&self.input, s.frame)?;
        let (light, emitter) = shot.light(s.light.as_deref())?;
        let mut options = o.clone();
        // The light by its path: the scene is read toward it (its shadow link).
        options.source.light = Some(light.prim.clone());
        // Neither was given (`explicit` is false): the stage light gives one of them.
        let lamp = crate::Light::from(emitter);
        options.light.light_dir = lamp.direction();
        options.light.light_pos = lamp.position();
        let dir = options.light.light_dir;
        // A transmittance volume has no view, so no up.
        if options.up.is_none() && !is_volume_output(&self.output) {
            let u = shot.up;
            let parallel =
                dir.is_some_and(|d| (d[0] * u[0] + d[1] * u[1] + d[2] * u[2]).abs() > 0.999);
            if !parallel {
                options.up = Some(u);
            }
        }
        Ok(Some(Self {
            input: self.input.clone(),
            output: self.output.clone(),
            options,
        }))
    }

    pub(super) fn plan_volume(&self) -> Result<VolumeJob> {
        let o = &self.options;
        // A stage's one volume: its grid, placement and scale (the stage places it: no xform,
        // no grid; density-scale applies on top, as for scenes).
        let source = self.source();
        let stage = if source.kind().is_stage() {
            if let Some(k) = [
                ("xform", o.source.xform.is_some()),
                ("grid", o.source.grid != "density"),
            ]
            .iter()
            .find(|(_, g)| *g)
            {
                return Err(bad(
                    k.0,
                    "the stage places its volumes and names their grids (volume, field)",
                ));
            }
            let motion = o.motion()?;
            let sel = crate::usd::Selection {
                velocity: motion.as_ref().map(|m| m.velocity.clone()),
                ..crate::usd::Selection::of(source.options())
            };
            let shot = crate::usd::read(&self.input, &sel)?;
            let v = shot.single_volume()?;
            let motion = stage_motion(motion, v, shot.fps)?;
            Some((
                v.file()?.to_path_buf(),
                v.grid.clone(),
                o.source.density_scale * v.grey_scale()?,
                v.xform,
                motion,
            ))
        } else {
            None
        };
        if source.kind().is_scene_file() {
            return Err(bad(
                "output",
                format!(
                    "a transmittance volume (.vdb) is made from one density grid; {} is a scene \
                     file",
                    self.input.display()
                ),
            ));
        }
        let light = match (o.light.light(), o.light.light_dir) {
            (Some(light), _) => light,
            (None, None) => {
                return Err(bad(
                    "light-dir",
                    "no light: give the direction the light travels (a sun) or light-pos (a \
                     point light)",
                ))
            }
            (None, Some(_)) => {
                return Err(bad(
                    "light-pos",
                    "a transmittance volume is lit by one light: give light-dir or light-pos, \
                     not both",
                ))
            }
        };
        let (estimator, options) = o.resolve_estimator()?;
        let (source, motion) = match stage {
            // The stage's volume, as a grid file read with the stage's grid, scale and
            // placement.
            Some((file, grid, density_scale, xform, m)) => {
                let read = SourceOptions {
                    grid,
                    density_scale,
                    xform: Some(xform.rows().iter().flatten().copied().collect()),
                    frame: None,
                    volume: None,
                    field: None,
                    light: None,
                    ..o.source.clone()
                };
                (Source::new(file, read), m)
            }
            None => {
                source.xform()?;
                (source, o.motion()?)
            }
        };
        // A light with extent: the flags', or a stage light's own (its keys checked against
        // it).
        let soft = self.soft_light()?;
        Ok(VolumeJob {
            source,
            light,
            soft,
            estimator,
            options,
            threads: o.threads,
            output: self.output.clone(),
            out_grid: o
                .out_grid
                .clone()
                .unwrap_or_else(|| DEFAULT_OUT_GRID.to_string()),
            half: o.half,
            overwrite: o.force,
            motion,
            key: None,
        })
    }

    pub(super) fn plan_map(&self) -> Result<BakeJob> {
        let o = &self.options;
        if let Some(r) = o.res {
            r.check().map_err(|e| match e {
                Error::InvalidArgument { reason, .. } => bad("res", reason),
                other => other,
            })?;
        }
        let (view, camera) = match &o.camera {
            Some(source) => {
                let fixed = [
                    ("light-dir", o.light.light_dir.is_some()),
                    ("light-pos", o.light.light_pos.is_some()),
                    ("ortho", o.ortho),
                    ("fov", o.fov.is_some()),
                    ("up", o.up.is_some()),
                    ("frame-box", o.frame_box.is_some()),
                    ("omni", o.omni.is_some()),
                ];
                if let Some((k, _)) = fixed.iter().find(|(_, set)| *set) {
                    return Err(bad(
                        k,
                        "a reused camera fixes the whole view: give camera or the light and \
                         framing options, not both",
                    ));
                }
                let view = View {
                    res: o.res,
                    ..View::default()
                };
                (view, Some(source.read(o.res)?))
            }
            None => (o.view()?, None),
        };
        let depths = match (o.slices, &o.depths) {
            (Some(_), Some(_)) => return Err(bad("slices", "give slices or depths, not both")),
            (Some(k), None) => Depths::Slices(k),
            (None, Some(d)) => Depths::At(d.clone()),
            (None, None) => Depths::None,
        };
        if let Some(s) = o.source.sigma_t {
            crate::scene::check_sigma(s)?;
        }
        let (estimator, options) = o.resolve_estimator()?;
        let settings = BakeSettings {
            target_error: o.target_error,
            max_spp: o.max_spp,
            depths,
            std_err: o.stderr,
            threads: o.threads,
            order: o.order,
            soft: self.soft_map()?,
            ..BakeSettings::new(estimator, options)
        };
        settings.validate()?;
        let layout = ExrLayout {
            tile: o.tile,
            mipmap: o.mipmap,
        };
        layout.validate()?;
        let format = o
            .deep_format
            .as_deref()
            .map(str::parse::<crate::bake::DeepFormat>)
            .transpose()?;
        let product = match (format, o.deep, o.deep_error) {
            (Some(_), _, Some(_)) => {
                return Err(bad(
                    "deep-error",
                    "bounds Lokovic-Veach deep samples; a deep format reports the error it \
                     reaches instead (umbra:deep_max_error)",
                ))
            }
            (Some(format), _, None) => Product::Fixed { format },
            (None, false, Some(_)) => {
                return Err(bad("deep-error", "applies to deep maps: add deep"))
            }
            (None, false, None) => Product::Map,
            (None, true, e) => {
                let max_error = e.unwrap_or(DEFAULT_DEEP_ERROR);
                crate::bake::check_deep_error(max_error)?;
                Product::Deep { max_error }
            }
        };
        let source = self.source();
        source.xform()?;
        o.motion()?;
        Ok(BakeJob {
            source,
            view,
            camera,
            settings,
            output: self.output.clone(),
            preview: o.preview.clone(),
            overwrite: o.force,
            layout,
            max_memory: o.max_memory()?,
            product,
            key: None,
        })
    }

    /// A map toward a light with extent ([`crate::bake::SoftMap`]): the light's extent and
    /// the texels' receiver, checked; `None` for a point light (zero extent included), which
    /// refuses `receiver-depth`.
    fn soft_map(&self) -> Result<Option<crate::bake::SoftMap>> {
        let o = &self.options;
        let soft = self.soft_light()?;
        if let Some(d) = o.receiver_depth {
            if !(d.is_finite() && d >= 0.0) {
                return Err(bad(
                    "receiver-depth",
                    format!("{d} is not a finite distance >= 0 along the texel's ray"),
                ));
            }
            if soft.is_none() {
                return Err(bad(
                    "receiver-depth",
                    "places the receiver of a map toward a light with extent (light-angle, \
                     light-radius > 0); a point light's T at a depth is a slice (depths)",
                ));
            }
        }
        let Some(light) = soft else {
            return Ok(None);
        };
        if o.deep_error.is_some() {
            return Err(bad(
                "deep-error",
                "bounds the fit of a transmittance that never rises with depth; a deep map \
                 toward a light with extent stores T_L at its receivers as it is (docs/lights.md)",
            ));
        }
        if o.max_memory.is_some() {
            return Err(bad(
                "max-memory",
                "a map toward a light with extent reads the whole grid (every receiver's rays \
                 cross it): drop max-memory",
            ));
        }
        let receiver = match o.receiver_depth {
            Some(d) => crate::bake::Receiver::Depth(d),
            None => crate::bake::Receiver::BoxExit,
        };
        // A map's `target-error` is the error bar each receiver's count is chosen to reach.
        let light = light.with_target(o.target_error, "target-error")?;
        Ok(Some(crate::bake::SoftMap { light, receiver }))
    }

    /// The light with extent a bake (a map or a transmittance volume) is made toward: the
    /// flags' (`light-angle`, `light-radius`); toward a stage's light
    /// ([`BakeRequest::with_stage_light`] put its centre in `light-dir` / `light-pos` and its
    /// path in `light`), the stage light's own extent (a distant light's `inputs:angle`, 0.53
    /// degrees when unauthored, a sphere's radius, a disk, rect or cylinder), which the flags
    /// override ([`crate::light::LightOptions::soft_of_stage`]). `None`: a point.
    ///
    /// # Errors
    /// As [`crate::light::LightOptions::soft`]; reading the stage light.
    pub(super) fn soft_light(&self) -> Result<Option<crate::light::SoftLight>> {
        let o = &self.options;
        let from_stage = o.source.light.as_deref().filter(|_| {
            self.source().kind().is_stage()
                && (o.light.light_dir.is_some() || o.light.light_pos.is_some())
        });
        let Some(name) = from_stage else {
            return o.light.soft();
        };
        let shot = crate::usd::lights_at(&self.input, o.source.frame)?;
        let (_, emitter) = shot.light(Some(name))?;
        o.light.soft_of_stage(emitter)
    }
}

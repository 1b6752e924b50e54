//! The native `Volume`: a loaded grid, scene or stage and the Python methods on it.

use crate::errors::*;
use crate::motion::SceneRef;
use crate::native::*;
use crate::trace::*;
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray2};
use pyo3::prelude::*;
use std::path::PathBuf;
use umbra::bake::{BakeJob, Camera};
use umbra::request::{BakeOptions, BakePlan, BakeRequest, TraceOptions};
use umbra::scene::Scene;
use umbra::{Interp, Light, Ray};

impl NativeVolume {
    /// This volume's transmittance volume as the options (the Python keywords, JSON text) ask
    /// for it, written to `output` (or a name only, in memory): the request's plan, checked
    /// as the CLI checks it, and the loaded grid.
    pub(crate) fn volume_plan(
        &self,
        py: Python<'_>,
        options: &str,
        output: PathBuf,
    ) -> PyResult<(SceneRef<'_>, umbra::bake::VolumeJob)> {
        let request = self.request(options, output)?;
        let plan = request.plan().map_err(py_err)?;
        let BakePlan::Volume(job) = plan else {
            return Err(arg(
                "path",
                "a transmittance volume is written to a .vdb file",
            ));
        };
        self.single("transmittance volume")?;
        Ok((self.scene_for(py, request.options.source)?, *job))
    }

    /// A transmittance volume's warnings as the CLI prints them: `FILE: warning`.
    pub(crate) fn volume_warnings(&self, w: &[umbra::bake::Warning]) -> Vec<String> {
        w.iter()
            .map(|w| format!("{}: {w}", self.source.path().display()))
            .collect()
    }
}

#[pymethods]
impl NativeVolume {
    /// Load grid `grid` of the `.vdb` file `path` (whole).
    #[staticmethod]
    #[pyo3(signature = (path, grid, density_scale, interp, xform))]
    fn open(
        py: Python<'_>,
        path: PathBuf,
        grid: String,
        density_scale: f64,
        interp: &str,
        xform: Option<Vec<f64>>,
    ) -> PyResult<Self> {
        let source = Self::source(path.clone(), grid, density_scale, interp, xform)?;
        if source.kind().is_scene_file() {
            return Err(arg(
                "path",
                format!(
                    "{} is a scene file: load it with umbra.Volume.from_scene",
                    path.display()
                ),
            ));
        }
        Self::load(py, source)
    }

    /// Load the `.toml` scene file `path`.
    #[staticmethod]
    #[pyo3(signature = (path, density_scale, interp, xform))]
    fn open_scene(
        py: Python<'_>,
        path: PathBuf,
        density_scale: f64,
        interp: &str,
        xform: Option<Vec<f64>>,
    ) -> PyResult<Self> {
        let source = Self::source(path.clone(), "density".into(), density_scale, interp, xform)?;
        if !source.kind().is_scene_file() {
            return Err(arg(
                "path",
                format!(
                    "{} is not a scene file (.toml): load a grid with umbra.Volume",
                    path.display()
                ),
            ));
        }
        Self::load(py, source)
    }

    /// Load the volumes of the USD stage `path` at time code `time` (default: its start);
    /// toward `light`, only those its shadow link includes.
    #[staticmethod]
    #[pyo3(signature = (path, time, volumes, field, density_scale, interp, xform, light=None))]
    #[allow(clippy::too_many_arguments)]
    fn open_stage(
        py: Python<'_>,
        path: PathBuf,
        time: Option<f64>,
        volumes: Vec<String>,
        field: String,
        density_scale: f64,
        interp: &str,
        xform: Option<Vec<f64>>,
        light: Option<String>,
    ) -> PyResult<Self> {
        let mut source =
            Self::source(path.clone(), "density".into(), density_scale, interp, xform)?;
        if !source.kind().is_stage() {
            return Err(arg(
                "path",
                format!(
                    "{} is not a USD stage (.usd, .usda, .usdc, .usdz)",
                    path.display()
                ),
            ));
        }
        let o = source.options_mut();
        o.frame = time;
        o.volume = (!volumes.is_empty()).then_some(volumes);
        o.field = Some(field);
        o.light = light;
        Self::load(py, source)
    }

    /// What the bad-voxel policy changed, as warning lines.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }

    #[getter]
    fn path(&self) -> PathBuf {
        self.source.path().to_path_buf()
    }

    #[getter]
    fn grid(&self) -> String {
        self.scene.grid_names()
    }

    #[getter]
    fn density_scale(&self) -> f64 {
        self.source.options().density_scale
    }

    #[getter]
    fn interp(&self) -> &'static str {
        match self.source.options().interp {
            Interp::Nearest => "nearest",
            Interp::Trilinear => "trilinear",
        }
    }

    #[getter]
    fn channels(&self) -> usize {
        self.scene.channels()
    }

    /// World-from-index, 4x4 row-major (the translation in the last column).
    fn world_from_index(&self) -> PyResult<[[f64; 4]; 4]> {
        let r = self.single("world_from_index")?.world_from_index_rows();
        Ok([r[0], r[1], r[2], [0.0, 0.0, 0.0, 1.0]])
    }

    /// Inclusive index box of the active voxels (tiles count as the voxels they cover).
    fn index_bbox(&self) -> PyResult<Option<[[i32; 3]; 2]>> {
        self.single("index_bbox")?;
        Ok(self.stats().first().and_then(|s| s.index_bbox))
    }

    /// Active voxels (over every volume of a scene).
    fn active_voxels(&self) -> u64 {
        self.stats().iter().map(|s| s.active_voxels).sum()
    }

    /// World box of the active voxel centres (the index box's corners in world space; a
    /// scene: over its volumes).
    fn world_bbox(&self) -> Option<[[f64; 3]; 2]> {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for (f, s) in self.scene.fogs().iter().zip(self.stats()) {
            let Some(b) = s.index_bbox else {
                continue;
            };
            let b = b.map(|c| c.map(f64::from));
            for p in umbra::internals::math::box_corners(b) {
                let w = f.volume().to_world(p).to_array();
                for a in 0..3 {
                    lo[a] = lo[a].min(w[a]);
                    hi[a] = hi[a].max(w[a]);
                }
            }
        }
        (lo[0] <= hi[0]).then_some([lo, hi])
    }

    /// Transmittance along the segments `origins[n] -> ends[n]` (ray id `ray_id + n`).
    fn trace<'py>(
        &self,
        py: Python<'py>,
        origins: PyReadonlyArray2<'py, f64>,
        ends: PyReadonlyArray2<'py, f64>,
        options: &str,
        ray_id: u64,
        threads: usize,
    ) -> PyResult<TraceOut<'py>> {
        let (o, e) = (points(&origins)?, points(&ends)?);
        if o.len() != e.len() {
            return Err(arg(
                "ends",
                format!("{} origins but {} ends", o.len(), e.len()),
            ));
        }
        drop((origins, ends));
        let n = o.len();
        let ray_of = |row: usize| Ray::between(o[row], e[row]).map_err(|e| e.to_string());
        self.run(py, n, ray_of, options, ray_id, threads)
    }

    /// Transmittance from each point toward a light (`query --at`), ray id `ray_id + n`.
    #[allow(clippy::too_many_arguments)]
    fn trace_to_light<'py>(
        &self,
        py: Python<'py>,
        points_: PyReadonlyArray2<'py, f64>,
        light_dir: Option<[f64; 3]>,
        light_pos: Option<[f64; 3]>,
        extent: (Option<f64>, Option<f64>, Option<u32>),
        options: &str,
        ray_id: u64,
        threads: usize,
    ) -> PyResult<TraceOut<'py>> {
        let (light_angle, light_radius, light_samples) = extent;
        let given = umbra::request::LightOptions {
            light_dir,
            light_pos,
            light_angle,
            light_radius,
            light_samples,
            // The per-point calls take the default cap on directions per receiver.
            light_max_samples: None,
        };
        // A light with extent: each point's mean over the light (`query --at`).
        if let Some(soft) = given.soft().map_err(py_err)? {
            let p = points(&points_)?;
            drop(points_);
            return self.run_soft(py, &soft, &p, options, ray_id, threads);
        }
        let light = match given.light() {
            Some(light) => light,
            None => {
                return Err(arg(
                    "light_dir",
                    "give light_dir=(dx, dy, dz) or light_pos=(x, y, z), one of them",
                ))
            }
        };
        let o = TraceOptions::from_json(options).map_err(py_err)?;
        o.estimator.motion(&o.source).map_err(py_err)?;
        let traced = self.scene_for(py, o.source)?;
        let scene = &*traced;
        // A direction that is no direction fails the call, not each row.
        if let Light::Directional { .. } = light {
            light.ray_from_scene(scene, [0.0; 3]).map_err(py_err)?;
        }
        let p = points(&points_)?;
        drop(points_);
        let n = p.len();
        let ray_of = |row: usize| {
            light
                .ray_from_scene(scene, p[row])
                .map_err(|e| cli_worded(e).to_string())
        };
        self.run(py, n, ray_of, options, ray_id, threads)
    }

    /// T toward a light at every active voxel (`umbra bake ... -o OUT.vdb`, in memory):
    /// the voxels' index coordinates and values in output order (leaves by origin, voxels by
    /// offset).
    fn transmittance_volume<'py>(
        &self,
        py: Python<'py>,
        options: &str,
    ) -> PyResult<VolumeOut<'py>> {
        let (scene, job) = self.volume_plan(py, options, PathBuf::from("memory.vdb"))?;
        let vol = scene
            .single()
            .ok_or_else(|| arg("velocity", "one volume"))?;
        let (ijk, t, stats) = py
            .detach(|| -> umbra::Result<_> {
                let (leaves, stats) = job.leaves(vol, &|_| {})?;
                let voxels = usize::try_from(stats.voxels).unwrap_or(0);
                let (mut ijk, mut t) = (Vec::with_capacity(voxels * 3), Vec::with_capacity(voxels));
                for l in &leaves {
                    for (n, &v) in l.values.iter().enumerate() {
                        if umbra::internals::tree::bit(&l.active, n) {
                            ijk.extend_from_slice(&[
                                l.origin[0] + (n >> 6) as i32,
                                l.origin[1] + ((n >> 3) & 7) as i32,
                                l.origin[2] + (n & 7) as i32,
                            ]);
                            t.push(v);
                        }
                    }
                }
                Ok((ijk, t, stats))
            })
            .map_err(py_err)?;
        let n = t.len();
        let warnings = self.volume_warnings(&umbra::bake::volume_warnings(&vol.sanitized()));
        Ok((
            PyArray1::from_vec(py, ijk).reshape([n, 3])?,
            PyArray1::from_vec(py, t),
            stats_json(&stats)?,
            warnings,
        ))
    }

    /// Write the transmittance volume `umbra bake FILE ... -o PATH` writes for this volume
    /// (its file, grid, density scale and `xform` recorded): `(stats JSON, warnings)`.
    fn write_transmittance_volume(
        &self,
        py: Python<'_>,
        path: PathBuf,
        options: &str,
    ) -> PyResult<(String, Vec<String>)> {
        let (scene, job) = self.volume_plan(py, options, path)?;
        let vol = scene
            .single()
            .ok_or_else(|| arg("velocity", "one volume"))?;
        let report = py.detach(|| job.run_on(vol, &|_| {})).map_err(py_err)?;
        Ok((
            stats_json(&report.stats)?,
            self.volume_warnings(&report.warnings),
        ))
    }

    /// Bake a transmittance map (`umbra bake`, in memory) as the options (the Python
    /// keywords, JSON text) ask.
    fn bake<'py>(&self, py: Python<'py>, options: &str) -> PyResult<BakeOut<'py>> {
        let request = self.request(options, PathBuf::new())?;
        let threads = request.options.threads;
        request.options.motion().map_err(py_err)?;
        let scene = self.scene_for(py, request.options.source.clone())?;
        let scene = &*scene;
        let report = py
            .detach(|| -> umbra::Result<_> {
                let (job, camera) = self.map_plan(&request, scene)?;
                on_threads(threads, || job.bake_in_memory(scene, camera, &|_| {}))?
            })
            .map_err(py_err)?;
        let map = &report.map;
        let json = summary_json(&report)?;
        let c = map.channels();
        let mut t = Vec::with_capacity(map.t.len() * c);
        let mut e = map
            .std_err
            .as_ref()
            .map(|_| Vec::with_capacity(map.t.len() * c));
        for ch in 0..c {
            let (tc, ec, _) = map.channel(ch);
            t.extend_from_slice(tc);
            if let (Some(e), Some(ec)) = (e.as_mut(), ec) {
                e.extend_from_slice(ec);
            }
        }
        let warnings = report.warnings.iter().map(ToString::to_string).collect();
        Ok((
            PyArray1::from_vec(py, t),
            e.map(|e| PyArray1::from_vec(py, e)),
            json,
            warnings,
        ))
    }

    /// Write the deep map `umbra bake FILE ... --deep [--deep-error E] -o PATH` writes for
    /// this volume (its file, grid, density scale and `xform` recorded), byte for byte:
    /// `(summary JSON, deep stats JSON, warnings)`.
    fn write_deep_map(
        &self,
        py: Python<'_>,
        path: PathBuf,
        options: &str,
    ) -> PyResult<(String, String, Vec<String>)> {
        let mut request = self.request(options, path)?;
        request.options.deep = request.options.deep_format.is_none();
        let threads = request.options.threads;
        request.options.motion().map_err(py_err)?;
        let scene = self.scene_for(py, request.options.source.clone())?;
        let scene = &*scene;
        // The CLI's order: the request is planned (a camera file read), the outputs checked,
        // then the camera framed.
        let report = py
            .detach(|| -> umbra::Result<_> {
                if let BakePlan::Map(job) = request.plan()? {
                    job.check_outputs()?;
                }
                let (job, camera) = self.map_plan(&request, scene)?;
                on_threads(threads, || job.run_loaded(scene, camera, &|_| {}))?
            })
            .map_err(py_err)?;
        let deep = match (report.deep.as_ref(), report.fixed.as_ref()) {
            (Some(d), _) => deep_json(d),
            (None, Some(f)) => {
                serde_json::to_value(f).map_err(|e| raise(Class::Other, e.to_string()))?
            }
            _ => return Err(raise(Class::Other, "the bake made no deep map".into())),
        };
        let warnings = report.warnings.iter().map(ToString::to_string).collect();
        Ok((summary_json(&report)?, deep.to_string(), warnings))
    }
}

impl NativeVolume {
    /// This volume's request: the Python keywords' options (JSON text), with what the volume
    /// was loaded with (file, grid, density scale, interpolation, `xform`) recorded.
    pub(crate) fn request(&self, options: &str, output: PathBuf) -> PyResult<BakeRequest> {
        let mut o = BakeOptions::from_json(options).map_err(py_err)?;
        let loaded = self.source.options();
        o.source.grid.clone_from(&loaded.grid);
        o.source.density_scale = loaded.density_scale;
        o.source.interp = loaded.interp;
        o.source.xform.clone_from(&loaded.xform);
        Ok(BakeRequest {
            input: self.source.path().to_path_buf(),
            output,
            options: o,
        })
    }

    /// The map of a request on this volume (traced as `scene`, [`NativeVolume::scene_for`]):
    /// its fixed camera, or the one its view frames.
    pub(crate) fn map_plan(
        &self,
        request: &BakeRequest,
        scene: &Scene,
    ) -> umbra::Result<(BakeJob, Camera)> {
        let BakePlan::Map(job) = request.plan()? else {
            return Err(umbra::Error::InvalidArgument {
                name: "output".into(),
                reason: "a map is written to an EXR file".into(),
            });
        };
        let camera = match job.camera {
            Some(c) => c,
            None => Camera::frame(&job.view, &scene.box_corners()?)?,
        };
        Ok((*job, camera))
    }
}

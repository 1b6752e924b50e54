//! The deep products of a bake ([`Product::Deep`], [`Product::Fixed`]): traced from the flat
//! map, encoded; toward a light with extent, the soft deep map (`product/soft_deep.rs`).

use super::{BakeJob, Product, Traced};
use crate::bake::{bake_scene, BakeSettings, Camera};
use crate::error::{Error, Result};
use crate::progress::{Progress, Silent};
use crate::scene::Scene;

impl BakeJob {
    /// A deep product ([`Product::Deep`] or [`Product::Fixed`]) of `scene` seen by `camera`,
    /// encoded. The flat map is traced first: with regular tracking as asked, and a
    /// stochastic estimator's with the [`crate::bake::STOCHASTIC_DEPTHS`] slices its deep
    /// function comes from (removed from the written map); then the deep pass. `progress`
    /// counts both as [`BakeJob::work`] says.
    pub(super) fn deep_product(
        &self,
        scene: &Scene,
        camera: Camera,
        progress: &dyn Progress,
    ) -> Result<Traced> {
        if self.settings.soft.is_some() {
            return self.soft_deep(scene, camera, progress);
        }
        let exact = self.settings.estimator == crate::estimate::Estimator::REGULAR;
        let (camera, settings) = self.aimed(scene, camera);
        let mut map = if exact {
            bake_scene(scene, &camera, &settings, &Silent)?
        } else {
            let settings = BakeSettings {
                depths: crate::bake::Depths::Slices(crate::bake::STOCHASTIC_DEPTHS),
                ..settings
            };
            bake_scene(scene, &camera, &settings, progress)?
        };
        let (deep, fixed) = match self.product {
            Product::Deep { max_error } => (
                Some(crate::bake::bake_deep(scene, &map, max_error, progress)?),
                None,
            ),
            Product::Fixed { format } => (
                None,
                Some(crate::bake::bake_fixed(scene, &map, format, progress)?),
            ),
            Product::Map => (None, None),
        };
        map.settings.depths = crate::bake::Depths::None;
        map.depths.clear();
        map.slices.clear();
        if let Some(gb) = &mut map.color {
            for ch in gb.iter_mut() {
                ch.slices.clear();
            }
        }
        let mut report = self.describe(map, scene, camera);
        let bytes = if let Some(deep) = deep {
            let attrs = crate::bake::deep_attributes(&report.map, &report.provenance, &deep.stats);
            report.deep = Some(deep.stats);
            Some(crate::bake::encode_deep_exr(&deep.image, &attrs))
        } else if let Some(fixed) = fixed {
            let attrs = crate::bake::product::fixed_map::fixed_attributes(&fixed.stats);
            report.fixed = Some(fixed.stats);
            let bytes = crate::bake::encode::exr::encode_exr_with(
                &report.map,
                &report.provenance,
                &self.layout,
                fixed.planes,
                attrs,
            )
            .map_err(|e| Error::Output {
                path: self.output.clone(),
                reason: e,
            })?;
            Some(bytes)
        } else {
            None
        };
        Ok(Traced { report, bytes })
    }

    /// A deep map toward a light with extent: `T_L` at the receivers of
    /// [`crate::bake::soft_deep_depths`] as the flat map's slices, stored as they are.
    fn soft_deep(&self, scene: &Scene, camera: Camera, progress: &dyn Progress) -> Result<Traced> {
        let (camera, settings) = self.aimed(scene, camera);
        let settings = BakeSettings {
            depths: crate::bake::Depths::At(crate::bake::soft_deep_depths(&camera)),
            ..settings
        };
        let mut map = bake_scene(scene, &camera, &settings, progress)?;
        let deep = crate::bake::soft_deep_image(&map)?;
        map.settings.depths = crate::bake::Depths::None;
        map.depths.clear();
        map.slices.clear();
        let mut report = self.describe(map, scene, camera);
        let attrs = crate::bake::soft_deep_attributes(&report.map, &report.provenance, &deep.stats);
        report.deep = Some(deep.stats);
        Ok(Traced {
            report,
            bytes: Some(crate::bake::encode_deep_exr(&deep.image, &attrs)),
        })
    }
}

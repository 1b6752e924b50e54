//! Shared by the bake tests: reading a baked EXR back with the exr crate, rebuilding pixel rays
//! from its header attributes alone, and small volumes and settings.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use exr::prelude::{ReadChannels, ReadLayers};
use std::collections::HashMap;
use std::path::Path;
use umbra::bake::{BakeSettings, Projection, Provenance, View};
use umbra::estimate::{Estimator, Options};
use umbra::internals::tree::TreeBuilder;
use umbra::{Interp, Ray, Volume};

/// An EXR read back: channels by name and the attributes of its one layer.
pub struct Exr {
    pub w: usize,
    pub h: usize,
    pub ch: HashMap<String, Vec<f32>>,
    pub attrs: exr::meta::header::LayerAttributes,
}

pub fn read_exr(p: &Path) -> Exr {
    let img = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_file(p)
        .unwrap();
    let layer = &img.layer_data[0];
    let ch = layer
        .channel_data
        .list
        .iter()
        .map(|c| (c.name.to_string(), c.sample_data.values_as_f32().collect()))
        .collect();
    Exr {
        w: layer.size.0,
        h: layer.size.1,
        ch,
        attrs: layer.attributes.clone(),
    }
}

impl Exr {
    pub fn attr(&self, k: &str) -> &exr::meta::attribute::AttributeValue {
        let key = exr::meta::attribute::Text::from(format!("umbra:{k}").as_str());
        self.attrs
            .other
            .get(&key)
            .unwrap_or_else(|| panic!("no umbra:{k}"))
    }
    pub fn v3d(&self, k: &str) -> [f64; 3] {
        match self.attr(k) {
            exr::meta::attribute::AttributeValue::Custom { kind, bytes } => {
                assert_eq!(kind.to_string(), "v3d");
                std::array::from_fn(|a| {
                    f64::from_le_bytes(bytes[8 * a..8 * a + 8].try_into().unwrap())
                })
            }
            other => panic!("umbra:{k} is {other:?}"),
        }
    }
    pub fn text(&self, k: &str) -> String {
        match self.attr(k) {
            exr::meta::attribute::AttributeValue::Text(t) => t.to_string(),
            other => panic!("umbra:{k} is {other:?}"),
        }
    }
    pub fn f64(&self, k: &str) -> f64 {
        match self.attr(k) {
            exr::meta::attribute::AttributeValue::F64(v) => *v,
            other => panic!("umbra:{k} is {other:?}"),
        }
    }
    /// Pixel (i, j)'s ray, rebuilt from the header attributes alone.
    pub fn ray(&self, i: usize, j: usize) -> Ray {
        let (o, sx, sy, d) = (
            self.v3d("camera_origin"),
            self.v3d("camera_step_x"),
            self.v3d("camera_step_y"),
            self.v3d("camera_direction"),
        );
        let off: [f64; 3] = std::array::from_fn(|a| i as f64 * sx[a] + j as f64 * sy[a]);
        let t_max = self.f64("camera_t_max");
        if self.text("camera_kind") == "perspective" {
            Ray::new(o, std::array::from_fn(|a| d[a] + off[a]), 0.0, t_max).unwrap()
        } else {
            Ray::new(std::array::from_fn(|a| o[a] + off[a]), d, 0.0, t_max).unwrap()
        }
    }
}

pub fn prov(vol: &Volume) -> Provenance {
    Provenance {
        xform: None,
        sigma_t: None,
        source_file: "memory".into(),
        grid: vol.name().to_string(),
        density_scale: vol.density_scale(),
        light_dir: None,
        light_pos: None,
        key: None,
    }
}

pub fn regular(interp: Interp) -> BakeSettings {
    BakeSettings::new(
        Estimator::REGULAR,
        Options {
            interp,
            ..Options::default()
        },
    )
}

pub fn ortho(dir: [f64; 3], w: u32, h: u32) -> View {
    View {
        projection: Projection::Ortho,
        light_dir: Some(dir),
        light_pos: None,
        fov_deg: None,
        res: Some(umbra::bake::Resolution::Exact(w, h)),
        up: None,
        frame_box: None,
    }
}

/// A 128^3 tile of value 2 (voxel 0.1, offset), background 0.25, density scale 0.5: nearest
/// lookups see mu = 1 inside the index box [-0.5, 127.5]^3 and 0.125 everywhere else.
pub fn box_volume() -> Volume {
    let mut b = TreeBuilder::new(0.25);
    b.tile([0, 0, 0], 7, 2.0);
    let m = [
        [0.1, 0.0, 0.0, -3.0],
        [0.0, 0.1, 0.0, 1.0],
        [0.0, 0.0, 0.1, 0.5],
    ];
    Volume::from_tree("box".into(), b.build(), m, 0.5).unwrap()
}

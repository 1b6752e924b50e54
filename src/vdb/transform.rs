//! Grid transforms. OpenVDB stores a map type name and the map's parameters; umbra turns every
//! affine map into one `world_from_index` matrix in f64 and keeps frustum maps as a named,
//! untraceable map.
//!
//! Convention: column vectors, `p_world = M * [i, j, k, 1]^T`, stored row-major, so the
//! translation is the last column. (OpenVDB prints the transpose: it uses row vectors.)

use super::bytes::ByteReader;
use crate::error::{DecodeError, DecodeResult};
use serde::Serialize;

/// Parameters of an OpenVDB `NonlinearFrustumMap`, kept for reporting.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrustumParams {
    /// Index-space bounding box of the frustum, `[min, max]`.
    pub bbox: [[f64; 3]; 2],
    /// Ratio of the near to the far face width.
    pub taper: f64,
    /// Depth of the frustum in the secondary map's units.
    pub depth: f64,
    /// The secondary affine map, column-vector convention, row-major.
    pub second: [[f64; 4]; 4],
}

/// The index-to-world transform of a grid.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Transform {
    /// OpenVDB map type name, e.g. `UniformScaleMap`, `AffineMap`, `NonlinearFrustumMap`.
    pub map: String,
    /// `world_from_index` for affine maps (column vectors, row-major).
    pub world_from_index: [[f64; 4]; 4],
    /// Set for `NonlinearFrustumMap`, which is not affine: `world_from_index` is then only the
    /// secondary map and tracing refuses the grid.
    pub frustum: Option<FrustumParams>,
}

const IDENTITY: [[f64; 4]; 4] = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

impl Transform {
    /// An affine transform from a matrix.
    #[must_use]
    pub fn affine(map: &str, world_from_index: [[f64; 4]; 4]) -> Self {
        Self {
            map: map.to_string(),
            world_from_index,
            frustum: None,
        }
    }

    /// True if the map is affine (everything but the frustum map).
    #[must_use]
    pub fn is_affine(&self) -> bool {
        self.frustum.is_none()
    }

    /// Voxel size as OpenVDB defines it for affine maps: the world length of each index axis,
    /// `|M e_x|, |M e_y|, |M e_z|`.
    #[must_use]
    pub fn voxel_size(&self) -> [f64; 3] {
        let m = &self.world_from_index;
        let col = |c: usize| (m[0][c] * m[0][c] + m[1][c] * m[1][c] + m[2][c] * m[2][c]).sqrt();
        [col(0), col(1), col(2)]
    }

    /// Map an index-space point to world space.
    #[must_use]
    pub fn index_to_world(&self, p: [f64; 3]) -> [f64; 3] {
        let m = &self.world_from_index;
        let r = |row: usize| m[row][0] * p[0] + m[row][1] * p[1] + m[row][2] * p[2] + m[row][3];
        [r(0), r(1), r(2)]
    }
}

fn scale_translate(name: &str, s: [f64; 3], t: [f64; 3]) -> Transform {
    let mut m = IDENTITY;
    for a in 0..3 {
        m[a][a] = s[a];
        m[a][3] = t[a];
    }
    Transform::affine(name, m)
}

/// OpenVDB stores `Mat4d` row by row in its row-vector convention; transpose to column vectors.
fn read_mat4_transposed(r: &mut ByteReader<'_>) -> DecodeResult<[[f64; 4]; 4]> {
    let mut rows = [[0.0; 4]; 4];
    for v in rows.iter_mut().flatten() {
        *v = r.f64("affine matrix")?;
    }
    Ok(std::array::from_fn(|i| std::array::from_fn(|j| rows[j][i])))
}

/// Read a transform: the map type name, then the map's parameters.
pub(crate) fn read_transform(r: &mut ByteReader<'_>) -> DecodeResult<Transform> {
    let name = r.string("transform map type")?;
    let t = match name.as_str() {
        "UniformScaleMap" | "ScaleMap" => {
            // scale, voxel size, inverse scale, inverse scale squared, inverse twice scale
            let s = r.vec3d("scale")?;
            r.skip(4 * 24, "scale map")?;
            scale_translate(&name, s, [0.0; 3])
        }
        "UniformScaleTranslateMap" | "ScaleTranslateMap" => {
            let t = r.vec3d("translation")?;
            let s = r.vec3d("scale")?;
            r.skip(4 * 24, "scale-translate map")?;
            scale_translate(&name, s, t)
        }
        "TranslationMap" => {
            let t = r.vec3d("translation")?;
            scale_translate(&name, [1.0; 3], t)
        }
        "AffineMap" | "UnitaryMap" => Transform::affine(&name, read_mat4_transposed(r)?),
        "NonlinearFrustumMap" => {
            let bbox = [r.vec3d("frustum bbox")?, r.vec3d("frustum bbox")?];
            let taper = r.f64("frustum taper")?;
            let depth = r.f64("frustum depth")?;
            let second_name = r.string("frustum second map type")?;
            if second_name != "AffineMap" {
                return Err(DecodeError::unsupported(format!(
                    "NonlinearFrustumMap with a {} secondary map",
                    crate::text::escape(&second_name)
                )));
            }
            let second = read_mat4_transposed(r)?;
            Transform {
                map: name,
                world_from_index: second,
                frustum: Some(FrustumParams {
                    bbox,
                    taper,
                    depth,
                    second,
                }),
            }
        }
        other => {
            return Err(DecodeError::unsupported(format!(
                "transform map '{}'",
                crate::text::escape(other)
            )))
        }
    };
    // Singular, non-finite or ill-conditioned maps are read as stored (`info` reports them);
    // `Volume::from_tree` refuses them for tracing, saying which condition fails.
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scale_translate_maps_index_to_world() {
        let t = scale_translate("ScaleTranslateMap", [0.1, 0.05, 0.2], [1.0, 2.0, 3.0]);
        assert_eq!(t.index_to_world([10.0, 20.0, 5.0]), [2.0, 3.0, 4.0]);
        let v = t.voxel_size();
        assert!((v[0] - 0.1).abs() < 1e-15 && (v[1] - 0.05).abs() < 1e-15);
    }

    #[test]
    fn affine_matrix_is_transposed_from_row_vectors() {
        // OpenVDB row-vector matrix with translation (5,6,7) in the last row.
        let mut bytes = Vec::new();
        let name = b"AffineMap";
        bytes.extend_from_slice(&(name.len() as u32).to_le_bytes());
        bytes.extend_from_slice(name);
        let rows = [
            [2.0, 0.0, 0.0, 0.0],
            [0.0, 3.0, 0.0, 0.0],
            [0.0, 0.0, 4.0, 0.0],
            [5.0, 6.0, 7.0, 1.0],
        ];
        for v in rows.iter().flatten() {
            bytes.extend_from_slice(&f64::to_le_bytes(*v));
        }
        let t = read_transform(&mut ByteReader::new(&bytes, 0));
        let t = t.ok().filter(Transform::is_affine);
        assert_eq!(
            t.map(|t| t.index_to_world([1.0, 1.0, 1.0])),
            Some([7.0, 9.0, 11.0])
        );
    }

    #[test]
    fn singular_maps_are_read_as_stored() {
        // A zero scale is read (info reports it); tracing refuses it in `Volume::from_tree`.
        let mut bytes = Vec::new();
        let name = b"ScaleMap";
        bytes.extend_from_slice(&(name.len() as u32).to_le_bytes());
        bytes.extend_from_slice(name);
        bytes.extend_from_slice(&[0u8; 120]);
        let t = read_transform(&mut ByteReader::new(&bytes, 0)).expect("read as stored");
        assert_eq!(t.world_from_index[0][0], 0.0);
    }
}

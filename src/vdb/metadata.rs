//! OpenVDB metadata maps (`MetaMap`): a u32 count, then per entry a name string, a type-name
//! string, a u32 byte size and the value bytes. Known types are decoded; unknown types are kept
//! as their byte size so nothing is silently misread.

use super::bytes::ByteReader;
use crate::error::DecodeResult;
use serde::Serialize;

/// One decoded metadata value.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum MetaValue {
    /// `string`
    String(String),
    /// `bool`
    Bool(bool),
    /// `int32` or `int64`
    Int(i64),
    /// `float` or `double`
    Float(f64),
    /// `vec3i`
    Vec3i([i32; 3]),
    /// `vec3s` or `vec3d`
    Vec3d([f64; 3]),
    /// Any other type: its OpenVDB type name and byte size.
    Other {
        /// OpenVDB type name.
        type_name: String,
        /// Size of the stored value in bytes.
        bytes: usize,
    },
}

/// An ordered list of metadata entries, as stored.
pub type MetaMap = Vec<(String, MetaValue)>;

/// Read a `MetaMap`.
pub(crate) fn read_meta_map(r: &mut ByteReader<'_>) -> DecodeResult<MetaMap> {
    read_grid_meta_map(r).map(|(m, _)| m)
}

/// OpenVDB's type name of the per-leaf table it writes as `file_delayed_load`.
pub(crate) const DELAYED_LOAD_TYPE: &str = "__delayedload";

/// Read a grid's `MetaMap`, and the raw value of its `__delayedload` entry if it has one
/// (OpenVDB >= 6.1 writes per-leaf compressed sizes there; see `decode::offsets_from_table`).
pub(crate) fn read_grid_meta_map(
    r: &mut ByteReader<'_>,
) -> DecodeResult<(MetaMap, Option<Vec<u8>>)> {
    let count = r.u32("metadata count")?;
    let mut out = Vec::new();
    let mut delayed = None;
    for _ in 0..count {
        let name = r.string("metadata name")?;
        let type_name = r.string("metadata type")?;
        let size = r.u32("metadata size")? as usize;
        let bytes = r.take(size, "metadata value")?;
        if type_name == DELAYED_LOAD_TYPE {
            delayed = Some(bytes.to_vec());
        }
        out.push((name, decode_value(&type_name, bytes)));
    }
    Ok((out, delayed))
}

fn decode_value(type_name: &str, b: &[u8]) -> MetaValue {
    let f32_at = |i: usize| f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    let i32_at = |i: usize| i32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    let f64_at = |i: usize| {
        let mut a = [0u8; 8];
        a.copy_from_slice(&b[i..i + 8]);
        f64::from_le_bytes(a)
    };
    match (type_name, b.len()) {
        ("string", _) => MetaValue::String(String::from_utf8_lossy(b).into_owned()),
        ("bool", 1) => MetaValue::Bool(b[0] != 0),
        ("int32", 4) => MetaValue::Int(i64::from(i32_at(0))),
        ("int64", 8) => {
            let mut a = [0u8; 8];
            a.copy_from_slice(b);
            MetaValue::Int(i64::from_le_bytes(a))
        }
        ("float", 4) => MetaValue::Float(f64::from(f32_at(0))),
        ("double", 8) => MetaValue::Float(f64_at(0)),
        ("vec3i", 12) => MetaValue::Vec3i([i32_at(0), i32_at(4), i32_at(8)]),
        ("vec3s", 12) => MetaValue::Vec3d([
            f64::from(f32_at(0)),
            f64::from(f32_at(4)),
            f64::from(f32_at(8)),
        ]),
        ("vec3d", 24) => MetaValue::Vec3d([f64_at(0), f64_at(8), f64_at(16)]),
        _ => MetaValue::Other {
            type_name: type_name.to_string(),
            bytes: b.len(),
        },
    }
}

/// Look up a string entry by name.
pub(crate) fn meta_string<'m>(meta: &'m MetaMap, key: &str) -> Option<&'m str> {
    meta.iter().find_map(|(k, v)| match v {
        MetaValue::String(s) if k == key => Some(s.as_str()),
        _ => None,
    })
}

/// Look up a bool entry by name.
pub(crate) fn meta_bool(meta: &MetaMap, key: &str) -> Option<bool> {
    meta.iter().find_map(|(k, v)| match v {
        MetaValue::Bool(b) if k == key => Some(*b),
        _ => None,
    })
}

/// Look up an integer entry by name.
pub(crate) fn meta_int(meta: &MetaMap, key: &str) -> Option<i64> {
    meta.iter().find_map(|(k, v)| match v {
        MetaValue::Int(i) if k == key => Some(*i),
        _ => None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_known_types_and_keeps_unknown_sizes() {
        let mut bytes = Vec::new();
        let mut put = |name: &str, ty: &str, val: &[u8]| {
            for s in [name, ty] {
                bytes.extend_from_slice(&(s.len() as u32).to_le_bytes());
                bytes.extend_from_slice(s.as_bytes());
            }
            bytes.extend_from_slice(&(val.len() as u32).to_le_bytes());
            bytes.extend_from_slice(val);
        };
        put("class", "string", b"fog volume");
        put("n", "int64", &7i64.to_le_bytes());
        put("odd", "mat4d", &[0u8; 128]);
        let mut all = 3u32.to_le_bytes().to_vec();
        all.extend_from_slice(&bytes);
        let mut r = ByteReader::new(&all, 0);
        let m = read_meta_map(&mut r).ok().unwrap_or_default();
        assert_eq!(meta_string(&m, "class"), Some("fog volume"));
        assert_eq!(meta_int(&m, "n"), Some(7));
        assert_eq!(
            m[2].1,
            MetaValue::Other {
                type_name: "mat4d".into(),
                bytes: 128
            }
        );
    }
}

//! Encoding a map: OpenEXR files (scanline, tiled with mip levels, deep), the PNG preview, the
//! map's description as data (`summary`), and fitting a transmittance function into deep
//! samples (`deep_fit`). Encoding reads a finished [`crate::bake::Map`] or profile and writes
//! bytes; it traces nothing.

pub(crate) mod deep_exr;
pub(crate) mod deep_fit;
pub(crate) mod exr;
pub(crate) mod fixed;
pub(crate) mod layout;
pub(crate) mod summary;

//! Blosc decompression through c-blosc (the library OpenVDB itself writes with), via the
//! `blosc-src` crate: two FFI calls, each guarded so that the C code never reads or writes outside
//! the Rust buffers it is given (with the AVX2 kernel and `memory`'s `malloc_trim`, umbra's only
//! `unsafe`).
#![allow(unsafe_code)]

use crate::error::{DecodeError, DecodeResult};

/// `BLOSC_MIN_HEADER_LENGTH`: bytes c-blosc reads to learn a buffer's sizes.
const BLOSC_HEADER: usize = 16;

/// Decompress one blosc chunk that must expand to exactly `out.len()` bytes, into `out`.
pub(crate) fn decompress_into(src: &[u8], out: &mut [u8]) -> DecodeResult<()> {
    let expected = out.len();
    if src.len() < BLOSC_HEADER {
        return Err(DecodeError::invalid(format!(
            "blosc chunk of {} bytes is shorter than its 16-byte header",
            src.len()
        )));
    }
    let mut nbytes: usize = 0;
    // SAFETY: `src` is a live slice of `src.len()` bytes; blosc_cbuffer_validate reads at most
    // that many bytes and writes one usize through the valid pointer `&mut nbytes`.
    let ok =
        unsafe { blosc_src::blosc_cbuffer_validate(src.as_ptr().cast(), src.len(), &mut nbytes) };
    if ok != 0 {
        return Err(DecodeError::invalid("blosc chunk header is corrupt"));
    }
    if nbytes != expected {
        return Err(DecodeError::invalid(format!(
            "blosc chunk expands to {nbytes} bytes, expected {expected}"
        )));
    }
    // SAFETY: validate() above checked that `src` holds a complete blosc buffer of its stated
    // compressed size; `out` has exactly `expected` writable bytes and the context API is
    // documented never to write more than `destsize`. One internal thread, no global state.
    let n = unsafe {
        blosc_src::blosc_decompress_ctx(src.as_ptr().cast(), out.as_mut_ptr().cast(), out.len(), 1)
    };
    if usize::try_from(n).ok() != Some(expected) {
        return Err(DecodeError::invalid(format!(
            "blosc decompression failed (returned {n}, expected {expected} bytes)"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn garbage_is_an_error_not_a_crash() {
        let junk: Vec<u8> = (0..200u32).map(|i| (i * 37 % 251) as u8).collect();
        let mut out = [0u8; 64];
        assert!(decompress_into(&junk, &mut out).is_err());
        assert!(decompress_into(&junk[..5], &mut out).is_err());
    }
}

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
    decompress_on(src, out, 1)
}

/// As [`decompress_into`], the chunk's blocks shared among `threads` threads of c-blosc's own
/// (started and joined by this call; the bytes are the same whatever the count).
pub(crate) fn decompress_on(src: &[u8], out: &mut [u8], threads: usize) -> DecodeResult<()> {
    let threads = i32::try_from(threads.max(1)).unwrap_or(1);
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
    // documented never to write more than `destsize`. Its threads are its own (a context per
    // call), no global state.
    let n = unsafe {
        blosc_src::blosc_decompress_ctx(
            src.as_ptr().cast(),
            out.as_mut_ptr().cast(),
            out.len(),
            threads,
        )
    };
    if usize::try_from(n).ok() != Some(expected) {
        return Err(DecodeError::invalid(format!(
            "blosc decompression failed (returned {n}, expected {expected} bytes)"
        )));
    }
    Ok(())
}

/// `src` compressed as one blosc chunk (LZ4, byte shuffle of 4-byte words) in blocks of
/// `block` bytes: what NanoVDB and OpenVDB write, for tests of the readers.
#[cfg(test)]
pub(crate) fn compress_for_tests(src: &[u8], block: usize) -> Vec<u8> {
    let mut out = vec![0u8; src.len() + 16 + 64];
    // SAFETY: `src` and `out` are live slices of the lengths passed; c-blosc writes at most
    // `destsize` bytes and reads `nbytes`; the compressor name is a NUL-terminated literal.
    let n = unsafe {
        blosc_src::blosc_compress_ctx(
            5,
            1,
            4,
            src.len(),
            src.as_ptr().cast(),
            out.as_mut_ptr().cast(),
            out.len(),
            c"lz4".as_ptr(),
            block,
            1,
        )
    };
    out.truncate(usize::try_from(n).expect("blosc compression failed"));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A chunk's blocks decompressed on several of c-blosc's threads are the bytes one
    /// thread gives, and the source's.
    #[test]
    fn threads_give_the_bytes_one_thread_gives() {
        let src: Vec<u8> = (0..1u32 << 18)
            .flat_map(|i| ((i % 1000) as f32 * 0.37 + (i / 7) as f32).to_le_bytes())
            .collect();
        let packed = compress_for_tests(&src, 16 << 10);
        assert!(packed.len() < src.len(), "not compressed");
        for threads in [1, 2, 4, 7] {
            let mut out = vec![0u8; src.len()];
            decompress_on(&packed, &mut out, threads).unwrap();
            assert!(out == src, "{threads} threads");
        }
        let mut short = vec![0u8; src.len() - 1];
        assert!(decompress_on(&packed, &mut short, 2).is_err());
    }

    #[test]
    fn garbage_is_an_error_not_a_crash() {
        let junk: Vec<u8> = (0..200u32).map(|i| (i * 37 % 251) as u8).collect();
        let mut out = [0u8; 64];
        assert!(decompress_into(&junk, &mut out).is_err());
        assert!(decompress_into(&junk[..5], &mut out).is_err());
    }
}

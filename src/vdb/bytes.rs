//! A bounds-checked little-endian reader over a byte slice. Every length read from a file is
//! checked against the bytes that remain *before* anything is allocated, so a corrupt length can
//! never trigger an allocation larger than the file can justify.

use crate::error::{DecodeError, DecodeResult};

/// Cursor over an in-memory byte slice; `base` is the absolute file offset of `data[0]`, used only
/// to make error messages point at the right byte of the file.
#[derive(Debug, Clone)]
pub(crate) struct ByteReader<'a> {
    data: &'a [u8],
    pos: usize,
    base: u64,
}

impl<'a> ByteReader<'a> {
    /// A reader over `data`, whose first byte sits at file offset `base`.
    pub(crate) fn new(data: &'a [u8], base: u64) -> Self {
        Self { data, pos: 0, base }
    }

    /// Absolute file offset of the next byte.
    pub(crate) fn offset(&self) -> u64 {
        self.base + self.pos as u64
    }

    /// Bytes left to read.
    pub(crate) fn remaining(&self) -> usize {
        self.data.len() - self.pos
    }

    /// Take the next `n` bytes, or fail with a truncation error naming `what`.
    pub(crate) fn take(&mut self, n: usize, what: &str) -> DecodeResult<&'a [u8]> {
        if n > self.remaining() {
            return Err(DecodeError::Truncated {
                msg: format!(
                    "truncated: {what} needs {n} bytes at offset {}",
                    self.offset()
                ),
                need: self.offset().saturating_add(n as u64),
            });
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    /// Skip `n` bytes.
    pub(crate) fn skip(&mut self, n: usize, what: &str) -> DecodeResult<()> {
        self.take(n, what).map(|_| ())
    }

    fn array<const N: usize>(&mut self, what: &str) -> DecodeResult<[u8; N]> {
        let s = self.take(N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    pub(crate) fn u8(&mut self, what: &str) -> DecodeResult<u8> {
        Ok(self.array::<1>(what)?[0])
    }
    pub(crate) fn u32(&mut self, what: &str) -> DecodeResult<u32> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }
    pub(crate) fn i32(&mut self, what: &str) -> DecodeResult<i32> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }
    pub(crate) fn i64(&mut self, what: &str) -> DecodeResult<i64> {
        Ok(i64::from_le_bytes(self.array(what)?))
    }
    pub(crate) fn f64(&mut self, what: &str) -> DecodeResult<f64> {
        Ok(f64::from_le_bytes(self.array(what)?))
    }
    pub(crate) fn vec3d(&mut self, what: &str) -> DecodeResult<[f64; 3]> {
        Ok([self.f64(what)?, self.f64(what)?, self.f64(what)?])
    }
    pub(crate) fn vec3i(&mut self, what: &str) -> DecodeResult<[i32; 3]> {
        Ok([self.i32(what)?, self.i32(what)?, self.i32(what)?])
    }

    /// An OpenVDB string: u32 length, then that many bytes (not NUL-terminated). Bytes that are
    /// not UTF-8 are replaced, so a corrupt name still yields a printable error.
    pub(crate) fn string(&mut self, what: &str) -> DecodeResult<String> {
        let len = self.u32(what)? as usize;
        let bytes = self.take(len, what)?;
        Ok(String::from_utf8_lossy(bytes).into_owned())
    }

    /// Read `words` little-endian u64 words (a node mask) into `out`.
    pub(crate) fn u64_words(&mut self, out: &mut [u64], what: &str) -> DecodeResult<()> {
        let s = self.take(out.len() * 8, what)?;
        for (w, chunk) in out.iter_mut().zip(s.chunks_exact(8)) {
            let mut a = [0u8; 8];
            a.copy_from_slice(chunk);
            *w = u64::from_le_bytes(a);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_little_endian_and_reports_truncation_offset() {
        let bytes = [1u8, 0, 0, 0, 2, 0];
        let mut r = ByteReader::new(&bytes, 100);
        assert_eq!(r.u32("a").ok(), Some(1));
        assert_eq!(r.offset(), 104);
        let err = r.u32("field b").err();
        match err {
            Some(DecodeError::Truncated { msg: m, need }) => {
                assert!(m.contains("field b") && m.contains("offset 104"), "{m}");
                assert_eq!(need, 108);
            }
            other => panic!("unexpected {other:?}"),
        }
    }

    #[test]
    fn string_length_is_checked_before_allocating() {
        // Length 0xFFFF_FFFF with 2 bytes behind it must fail, not allocate 4 GiB.
        let bytes = [0xFF, 0xFF, 0xFF, 0xFF, b'a', b'b'];
        let mut r = ByteReader::new(&bytes, 0);
        assert!(r.string("name").is_err());
    }
}

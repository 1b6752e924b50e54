//! Little-endian reads at absolute offsets of a byte buffer, each checked against its length:
//! a NanoVDB grid is a flat buffer addressed by offsets, so every field read is one bounds check
//! and never a panic.

use crate::error::{DecodeError, DecodeResult};

/// A buffer read at checked offsets.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Bytes<'a> {
    data: &'a [u8],
}

impl<'a> Bytes<'a> {
    pub(crate) fn new(data: &'a [u8]) -> Self {
        Self { data }
    }

    /// Length in bytes.
    pub(crate) fn len(&self) -> u64 {
        self.data.len() as u64
    }

    /// `n` bytes at `at`, or an error naming the range when they are not all in the buffer.
    pub(crate) fn slice(&self, at: u64, n: u64) -> DecodeResult<&'a [u8]> {
        let end = at.checked_add(n);
        let range = end
            .filter(|&e| e <= self.len())
            .and_then(|e| Some(usize::try_from(at).ok()?..usize::try_from(e).ok()?));
        match range {
            Some(r) => Ok(&self.data[r]),
            None => Err(DecodeError::Truncated {
                msg: format!(
                    "{n} bytes at byte {at} run past the end of a buffer of {} bytes",
                    self.len()
                ),
                need: end.unwrap_or(u64::MAX),
            }),
        }
    }

    fn array<const N: usize>(&self, at: u64) -> DecodeResult<[u8; N]> {
        let s = self.slice(at, N as u64)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    pub(crate) fn u8(&self, at: u64) -> DecodeResult<u8> {
        Ok(self.array::<1>(at)?[0])
    }
    pub(crate) fn u16(&self, at: u64) -> DecodeResult<u16> {
        self.array(at).map(u16::from_le_bytes)
    }
    pub(crate) fn u32(&self, at: u64) -> DecodeResult<u32> {
        self.array(at).map(u32::from_le_bytes)
    }
    pub(crate) fn i32(&self, at: u64) -> DecodeResult<i32> {
        self.array(at).map(i32::from_le_bytes)
    }
    pub(crate) fn u64(&self, at: u64) -> DecodeResult<u64> {
        self.array(at).map(u64::from_le_bytes)
    }
    pub(crate) fn i64(&self, at: u64) -> DecodeResult<i64> {
        self.array(at).map(i64::from_le_bytes)
    }
    pub(crate) fn f32(&self, at: u64) -> DecodeResult<f32> {
        self.array(at).map(f32::from_le_bytes)
    }
    pub(crate) fn f64(&self, at: u64) -> DecodeResult<f64> {
        self.array(at).map(f64::from_le_bytes)
    }
    pub(crate) fn vec3i(&self, at: u64) -> DecodeResult<[i32; 3]> {
        Ok([self.i32(at)?, self.i32(at + 4)?, self.i32(at + 8)?])
    }
    pub(crate) fn vec3d(&self, at: u64) -> DecodeResult<[f64; 3]> {
        Ok([self.f64(at)?, self.f64(at + 8)?, self.f64(at + 16)?])
    }
    /// 8 u64 words (a leaf's 512-bit mask) at `at`.
    pub(crate) fn words<const N: usize>(&self, at: u64) -> DecodeResult<[u64; N]> {
        let s = self.slice(at, 8 * N as u64)?;
        let mut w = [0u64; N];
        for (x, c) in w.iter_mut().zip(s.chunks_exact(8)) {
            let mut a = [0u8; 8];
            a.copy_from_slice(c);
            *x = u64::from_le_bytes(a);
        }
        Ok(w)
    }
    /// `n` u64 words at `at`, into a boxed slice (an internal node's mask).
    pub(crate) fn word_slice(&self, at: u64, n: usize) -> DecodeResult<Box<[u64]>> {
        let s = self.slice(at, 8 * n as u64)?;
        Ok(s.chunks_exact(8)
            .map(|c| {
                let mut a = [0u8; 8];
                a.copy_from_slice(c);
                u64::from_le_bytes(a)
            })
            .collect())
    }
}

/// A reason as an invalid-data error.
pub(crate) fn invalid(msg: impl Into<String>) -> DecodeError {
    DecodeError::invalid(msg)
}

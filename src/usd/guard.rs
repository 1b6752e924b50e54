//! A guard in front of the crate (`.usdc`) reader: every count the reader sizes a buffer from
//! is checked against the bytes that could hold it before the reader sees the layer.
//!
//! openusd 0.6 trusts a crate file's counts: it allocates `count x size` before it reads, so
//! one flipped byte in a size field asks for terabytes, and an allocation failure aborts the
//! process (it cannot be caught). A value that contains itself (a dictionary entry pointing
//! back at its dictionary) recurses until the stack overflows, which aborts too. This module
//! walks the layer's structure as the format lays it out (Pixar's crate file, versions
//! 0.4-0.12) and refuses, with a message, any layer where the reader would allocate more than
//! its data can fill or recurse without end:
//!
//! - the bootstrap header, the table of contents and every section inside the file;
//! - each LZ4 block (`u64` compressed size, a chunk-count byte, the block): its true
//!   decompressed length `d` is measured by walking the block's sequences (no output is
//!   written), and the count the reader sizes its buffer from must fit in `d`. For
//!   integer-coded arrays of `n` values the encoding has a 4-byte common value and 2 bits of
//!   code per value, so `4 + ceil(n/4) <= d`; for value reps `8n <= d`; for tokens the
//!   uncompressed size `<= d`;
//! - every value the fields reach (arrays, vectors, list ops, dictionaries, time samples,
//!   recursively): `count x element size <= bytes left in the file`, nesting at most
//!   [`MAX_DEPTH`], no value inside itself.
//!
//! The walk is linear in the file and allocates only what the file holds (the value reps).
//! It refuses nothing the format allows: layers usd-core writes pass it (tests check every
//! value type).

use std::collections::HashSet;

/// Deepest nesting of dictionaries and time samples followed.
pub(super) const MAX_DEPTH: usize = 64;

const MAGIC: &[u8; 8] = b"PXR-USDC";

/// The bit layout of a value rep: array, inlined, compressed, 8 bits of type, 48 of payload.
const ARRAY: u64 = 1 << 63;
const INLINED: u64 = 1 << 62;
const COMPRESSED: u64 = 1 << 61;
const PAYLOAD: u64 = (1 << 48) - 1;

/// Check the crate file `b`. `Err` says what is wrong, for an error naming the layer.
pub(super) fn check(b: &[u8]) -> Result<(), String> {
    if b.len() < 88 || &b[..8] != MAGIC {
        return Err("not a USD crate file (too short, or no PXR-USDC header)".into());
    }
    let ver = (b[8], b[9], b[10]);
    if ver < (0, 4, 0) {
        // Such files are refused by the reader itself before any value is read.
        return Ok(());
    }
    let mut c = Crate {
        b,
        ver,
        done: HashSet::new(),
        active: HashSet::new(),
    };
    c.sections()
}

struct Crate<'a> {
    b: &'a [u8],
    ver: (u8, u8, u8),
    /// Value reps whose walk finished.
    done: HashSet<u64>,
    /// Value reps on the walk's stack (one met again contains itself).
    active: HashSet<u64>,
}

struct Section {
    name: String,
    start: u64,
}

impl Crate<'_> {
    fn len(&self) -> u64 {
        self.b.len() as u64
    }

    fn bytes(&self, at: u64, n: u64, what: &str) -> Result<&[u8], String> {
        let end = at
            .checked_add(n)
            .filter(|&e| e <= self.len())
            .ok_or_else(|| format!("{what} at byte {at} runs past the end of the file"))?;
        // Both ends are within the slice, so they fit in usize.
        Ok(&self.b[at as usize..end as usize])
    }

    fn u64_at(&self, at: u64, what: &str) -> Result<u64, String> {
        let s = self.bytes(at, 8, what)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(s);
        Ok(u64::from_le_bytes(a))
    }

    fn u32_at(&self, at: u64, what: &str) -> Result<u64, String> {
        let s = self.bytes(at, 4, what)?;
        let mut a = [0u8; 4];
        a.copy_from_slice(s);
        Ok(u64::from(u32::from_le_bytes(a)))
    }

    /// `count` elements of `size` bytes from `at` are inside the file; the end.
    fn fits(&self, at: u64, count: u64, size: u64, what: &str) -> Result<u64, String> {
        let room = self.len().saturating_sub(at);
        match count.checked_mul(size) {
            Some(n) if n <= room => Ok(at + n),
            _ => Err(format!(
                "{what} at byte {at} claims {count} elements, more than the file's remaining \
                 {room} bytes can hold"
            )),
        }
    }

    /// An LZ4 block at `at`: its end, its decompressed length and its raw LZ4 bytes (after
    /// the chunk-count byte; empty for an empty block).
    fn block(&self, at: u64, what: &str) -> Result<(u64, u64, &[u8]), String> {
        let n = self.u64_at(at, what)?;
        let data = self.bytes(at + 8, n, what)?;
        let end = at + 8 + n;
        match data.split_first() {
            None => Ok((end, 0, data)),
            Some((0, block)) => match lz4_len(block) {
                Some(d) => Ok((end, d as u64, block)),
                None => Err(format!("{what} at byte {at}: a corrupt LZ4 block")),
            },
            Some(_) => Err(format!(
                "{what} at byte {at}: chunked LZ4 blocks (over 2 GiB of data) are not supported"
            )),
        }
    }

    /// `n` integer-coded values in the LZ4 block at `at`; the block's end.
    fn ints(&self, at: u64, n: u64, what: &str) -> Result<u64, String> {
        let (end, d, _) = self.block(at, what)?;
        let least = if n == 0 { 0 } else { 4 + n.div_ceil(4) };
        if least > d {
            return Err(format!(
                "{what} at byte {at} claims {n} values, more than its {d} decompressed bytes \
                 can code"
            ));
        }
        Ok(end)
    }

    fn sections(&mut self) -> Result<(), String> {
        let toc = self.u64_at(16, "the table of contents offset")?;
        let n = self.u64_at(toc, "the table of contents")?;
        if n == 0 || n >= 64 {
            return Err(format!("the table of contents claims {n} sections"));
        }
        self.fits(toc + 8, n, 32, "the table of contents")?;
        let mut sections = Vec::new();
        for i in 0..n {
            let at = toc + 8 + 32 * i;
            let raw = self.bytes(at, 16, "a section name")?;
            let name = raw.split(|&c| c == 0).next().unwrap_or(raw);
            let start = self.u64_at(at + 16, "a section")?;
            let size = self.u64_at(at + 24, "a section")?;
            let name = String::from_utf8_lossy(name).into_owned();
            self.fits(start, size, 1, &format!("section {name}"))?;
            sections.push(Section { name, start });
        }
        let find = |n: &str| sections.iter().find(|s| s.name == n).map(|s| s.start);
        if let Some(at) = find("TOKENS") {
            let size = self.u64_at(at + 8, "TOKENS")?;
            let (_, d, _) = self.block(at + 16, "TOKENS")?;
            if size > d {
                return Err(format!(
                    "TOKENS claims {size} bytes of tokens, more than its {d} decompressed bytes"
                ));
            }
        }
        if let Some(at) = find("STRINGS") {
            let n = self.u64_at(at, "STRINGS")?;
            self.fits(at + 8, n, 4, "STRINGS")?;
        }
        if let Some(at) = find("FIELDSETS") {
            let n = self.u64_at(at, "FIELDSETS")?;
            self.ints(at + 8, n, "FIELDSETS")?;
        }
        if let Some(at) = find("PATHS") {
            let paths = self.u64_at(at, "PATHS")?;
            let n = self.u64_at(at + 8, "PATHS")?;
            if paths > n {
                return Err(format!("PATHS claims {paths} paths but codes {n}"));
            }
            let mut end = at + 16;
            for _ in 0..3 {
                end = self.ints(end, n, "PATHS")?;
            }
        }
        if let Some(at) = find("SPECS") {
            let n = self.u64_at(at, "SPECS")?;
            let mut end = at + 8;
            for _ in 0..3 {
                end = self.ints(end, n, "SPECS")?;
            }
        }
        if let Some(at) = find("FIELDS") {
            let n = self.u64_at(at, "FIELDS")?;
            let end = self.ints(at + 8, n, "FIELDS")?;
            for rep in self.reps(end, n)? {
                self.value(rep, 0)?;
            }
        }
        Ok(())
    }

    /// The `n` value reps of the FIELDS section, decompressed from the block at `at`.
    fn reps(&self, at: u64, n: u64) -> Result<Vec<u64>, String> {
        let (_, d, block) = self.block(at, "FIELDS")?;
        if n.checked_mul(8).is_none_or(|b| b > d) {
            return Err(format!(
                "FIELDS claims {n} values, more than its {d} decompressed bytes hold"
            ));
        }
        if d == 0 {
            return Ok(Vec::new());
        }
        // `d` is what the block truly decompresses to, and at most 255 times the block.
        let mut out = vec![0u8; d as usize];
        lz4_flex::block::decompress_into(block, &mut out)
            .map_err(|e| format!("FIELDS at byte {at}: a corrupt LZ4 block ({e})"))?;
        Ok(out
            .chunks_exact(8)
            .take(n as usize)
            .map(|c| {
                let mut a = [0u8; 8];
                a.copy_from_slice(c);
                u64::from_le_bytes(a)
            })
            .collect())
    }

    /// Walk one value rep.
    fn value(&mut self, rep: u64, depth: usize) -> Result<(), String> {
        // An inlined value is read from the rep itself, except that the reader takes the
        // payload of an inlined array or payload list op as a position in the file.
        let inlined = rep & INLINED != 0 && rep & ARRAY == 0 && (rep >> 48) & 0xFF != 55;
        if inlined || self.done.contains(&rep) {
            return Ok(());
        }
        if depth > MAX_DEPTH {
            return Err(format!("values nested deeper than {MAX_DEPTH}"));
        }
        if !self.active.insert(rep) {
            return Err(format!("a value at byte {} contains itself", rep & PAYLOAD));
        }
        self.walk(rep, depth)?;
        self.active.remove(&rep);
        self.done.insert(rep);
        Ok(())
    }

    fn walk(&mut self, rep: u64, depth: usize) -> Result<(), String> {
        let ty = (rep >> 48) & 0xFF;
        let at = rep & PAYLOAD;
        if rep & ARRAY != 0 {
            return self.array(ty, rep & COMPRESSED != 0, at);
        }
        match ty {
            // StringVector, TokenVector, PathVector: u32 indices.
            50 | 41 | 40 => {
                let n = self.u64_at(at, "a vector")?;
                self.fits(at + 8, n, 4, "a vector").map(drop)
            }
            // DoubleVector: a double array.
            48 => self.array(9, rep & COMPRESSED != 0, at),
            // LayerOffsetVector (two doubles each), VariantSelectionMap and Relocates (pairs
            // of u32 indices).
            49 | 45 | 58 => {
                let n = self.u64_at(at, "a vector")?;
                let size = if ty == 49 { 16 } else { 8 };
                self.fits(at + 8, n, size, "a vector").map(drop)
            }
            32..=39 | 54 | 55 => self.list_op(ty, at, depth),
            31 => self.dictionary(at, depth).map(drop),
            46 => self.time_samples(at, depth),
            // Everything else is a fixed-size read.
            _ => Ok(()),
        }
    }

    fn array(&self, ty: u64, compressed: bool, at: u64) -> Result<(), String> {
        // An empty array is written at position 0. (openusd 0.6 reads an empty string or
        // asset array from the header there, a count so large the allocation's size
        // overflows: a panic the reader's caller catches, never an abort.)
        if at == 0 {
            return Ok(());
        }
        // String, asset-path and path-expression arrays: a u64 count of string indices.
        if matches!(ty, 10 | 12 | 57) {
            let n = self.u64_at(at, "an array")?;
            return self.fits(at + 8, n, 4, "an array").map(drop);
        }
        let mut p = at;
        if self.ver < (0, 5, 0) {
            p += 4;
        }
        let n = if self.ver < (0, 7, 0) {
            p += 4;
            self.u32_at(p - 4, "an array")?
        } else {
            p += 8;
            self.u64_at(p - 8, "an array")?
        };
        let ints = matches!(ty, 3..=6) && self.ver >= (0, 5, 0);
        let floats = matches!(ty, 7..=9 | 56) && self.ver >= (0, 6, 0);
        if compressed && n >= 4 && ints {
            return self.ints(p, n, "an integer array").map(drop);
        }
        if compressed && n >= 4 && floats {
            let code = self.bytes(p, 1, "a float array")?[0];
            return match code {
                b'i' => self.ints(p + 1, n, "a float array").map(drop),
                b't' => {
                    let lut = self.u32_at(p + 1, "a float array table")?;
                    let end = self.fits(p + 5, lut, element_size(ty), "a float array table")?;
                    self.ints(end, n, "a float array").map(drop)
                }
                // The reader refuses other codes before it allocates.
                _ => Ok(()),
            };
        }
        self.fits(p, n, element_size(ty), "an array").map(drop)
    }

    fn list_op(&mut self, ty: u64, at: u64, depth: usize) -> Result<(), String> {
        let header = self.bytes(at, 1, "a list op")?[0];
        let mut p = at + 1;
        // The lists in the order they are stored: explicit, added, prepended, appended,
        // deleted, ordered.
        for bit in [1 << 1, 1 << 2, 1 << 5, 1 << 6, 1 << 3, 1 << 4] {
            if header & bit == 0 {
                continue;
            }
            let n = self.u64_at(p, "a list op")?;
            p += 8;
            p = match ty {
                // References: string, path, layer offset, then a dictionary each.
                35 => {
                    self.fits(p, n, 32, "a list of references")?;
                    for _ in 0..n {
                        p = self.dictionary(p + 24, depth + 1)?;
                    }
                    p
                }
                // Payloads: string and path indices (and a layer offset since 0.8).
                55 => {
                    let size = if self.ver >= (0, 8, 0) { 24 } else { 8 };
                    self.fits(p, n, size, "a list of payloads")?
                }
                37 | 39 => self.fits(p, n, 8, "a list op")?,
                _ => self.fits(p, n, 4, "a list op")?,
            };
        }
        Ok(())
    }

    /// A dictionary at `at`: a count, then entries (a u32 key, a relative jump to a value
    /// rep) chained through the jumps; the position after the last rep.
    fn dictionary(&mut self, at: u64, depth: usize) -> Result<u64, String> {
        if depth > MAX_DEPTH {
            return Err(format!("values nested deeper than {MAX_DEPTH}"));
        }
        let n = self.u64_at(at, "a dictionary")?;
        // Each entry takes at least 20 bytes; a longer chain repeats itself.
        self.fits(at + 8, n, 20, "a dictionary")?;
        let mut p = at + 8;
        for _ in 0..n {
            let rep_at = self.jump(p + 4, "a dictionary entry")?;
            let rep = self.u64_at(rep_at, "a dictionary entry")?;
            if (rep >> 48) & 0xFF == 0 {
                // The reader refuses an invalid type before it reads the value.
                return Ok(rep_at + 8);
            }
            self.value(rep, depth + 1)?;
            p = rep_at + 8;
        }
        Ok(p)
    }

    /// The target of the relative jump stored at `at` (an `i64` counted from `at`).
    fn jump(&self, at: u64, what: &str) -> Result<u64, String> {
        let off = self.u64_at(at, what)? as i64;
        at.checked_add_signed(off)
            .filter(|&t| t < self.len())
            .ok_or_else(|| format!("{what} at byte {at} jumps outside the file"))
    }

    fn time_samples(&mut self, at: u64, depth: usize) -> Result<(), String> {
        let times_at = self.jump(at, "time samples")?;
        let times = self.u64_at(times_at, "time samples")?;
        self.value(times, depth + 1)?;
        let count_at = self.jump(times_at + 8, "time samples")?;
        let n = self.u64_at(count_at, "time samples")?;
        self.fits(count_at + 8, n, 8, "time samples")?;
        for i in 0..n {
            let rep = self.u64_at(count_at + 8 + 8 * i, "time samples")?;
            self.value(rep, depth + 1)?;
        }
        Ok(())
    }
}

/// Bytes per element of an uncompressed array of value type `ty` (1 for a type the reader
/// does not read as an array).
fn element_size(ty: u64) -> u64 {
    match ty {
        7 => 2,
        3 | 4 | 8 | 11 | 21 => 4,
        5 | 6 | 9 | 56 | 20 | 22 | 18 | 29 => 8,
        25 => 6,
        24 | 26 => 12,
        17 | 19 | 28 | 30 => 16,
        23 => 24,
        13 | 16 | 27 => 32,
        14 => 72,
        15 => 128,
        _ => 1,
    }
}

/// The decompressed length of a raw LZ4 block, from its sequences (no output is written);
/// `None` when the block is malformed (a sequence runs past the end, a match reaches before
/// the start).
fn lz4_len(src: &[u8]) -> Option<usize> {
    let extend = |i: &mut usize, n: &mut usize| -> Option<()> {
        loop {
            let b = *src.get(*i)?;
            *i += 1;
            *n = n.checked_add(usize::from(b))?;
            if b != 255 {
                return Some(());
            }
        }
    };
    let (mut i, mut out) = (0usize, 0usize);
    loop {
        let token = *src.get(i)?;
        i += 1;
        let mut lit = usize::from(token >> 4);
        if lit == 15 {
            extend(&mut i, &mut lit)?;
        }
        i = i.checked_add(lit).filter(|&e| e <= src.len())?;
        out = out.checked_add(lit)?;
        if i == src.len() {
            return Some(out);
        }
        let off = usize::from(u16::from_le_bytes([*src.get(i)?, *src.get(i + 1)?]));
        i += 2;
        if off == 0 || off > out {
            return None;
        }
        let mut ml = usize::from(token & 15);
        if ml == 15 {
            extend(&mut i, &mut ml)?;
        }
        out = out.checked_add(ml + 4)?;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lz4_lengths_are_what_the_blocks_decompress_to() {
        let mut samples: Vec<Vec<u8>> = vec![
            Vec::new(),
            b"a".to_vec(),
            vec![0; 100_000],
            (0..5000u32).flat_map(u32::to_le_bytes).collect(),
        ];
        let mut x = 1u64;
        samples.push(
            (0..3000)
                .map(|_| {
                    x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
                    (x >> 60) as u8
                })
                .collect(),
        );
        for s in samples {
            let block = lz4_flex::block::compress(&s);
            assert_eq!(lz4_len(&block), Some(s.len()));
            // A cut block is malformed, never longer.
            if block.len() > 2 {
                let cut = lz4_len(&block[..block.len() / 2]);
                assert!(cut.is_none() || cut < Some(s.len()), "{cut:?}");
            }
        }
        // A match reaching before the start.
        assert_eq!(lz4_len(&[0x10, b'a', 5, 0]), None);
    }

    #[test]
    fn element_sizes_follow_the_value_types() {
        // half 2, vec2h 4, vec3h 6, quath 8, vec4h 8, float 4, matrix4d 128.
        let got: Vec<u64> = [7, 21, 25, 18, 29, 8, 15, 14]
            .iter()
            .map(|&t| element_size(t))
            .collect();
        assert_eq!(got, [2, 4, 6, 8, 8, 4, 128, 72]);
    }

    #[test]
    fn headers_that_lie_are_refused() {
        assert!(check(b"PXR-USDC").is_err());
        let mut b = vec![0u8; 200];
        b[..8].copy_from_slice(MAGIC);
        b[8..11].copy_from_slice(&[0, 8, 0]);
        b[16..24].copy_from_slice(&1000u64.to_le_bytes());
        assert!(check(&b).unwrap_err().contains("past the end"));
        b[16..24].copy_from_slice(&88u64.to_le_bytes());
        b[88..96].copy_from_slice(&1u64.to_le_bytes());
        b[96..102].copy_from_slice(b"TOKENS");
        b[112..120].copy_from_slice(&150u64.to_le_bytes());
        b[120..128].copy_from_slice(&10u64.to_le_bytes());
        // TOKENS: count 0, size 2^40, an empty block.
        b[158..166].copy_from_slice(&(1u64 << 40).to_le_bytes());
        let e = check(&b).unwrap_err();
        assert!(e.contains("TOKENS"), "{e}");
    }
}

#![allow(clippy::unwrap_used, clippy::expect_used)]
//! The deep scanline OpenEXR writer (`bake::write_deep_exr`), read back by OpenImageIO (Debian
//! `openimageio-tools`): `iinfo -v` reports a deep ZIPS file with our attributes, and every
//! sample of every pixel `oiiotool --dumpdata` prints (shortest round-trip decimals) is the f32
//! written, bit for bit. The chunk sizes are checked by parsing the file here: zlib wins on
//! smooth data, raw bytes are stored when it does not. Without the tools the tests fail unless
//! `UMBRA_SKIP_OIIO=1`.

use crate::common;

use exr::meta::attribute::{AttributeValue, Text};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::path::Path;
use umbra::bake::{write_deep_exr, DeepAttributes, DeepImage};
use umbra::Error;

/// One sample: `(channel, value)` per channel, in channel-name order.
type Sample = Vec<(String, f32)>;

/// A deep image as given to `DeepImage::new`, kept to compare with what is read back.
#[derive(Clone)]
struct Case {
    w: u32,
    h: u32,
    channels: Vec<String>,
    counts: Vec<u32>,
    data: Vec<Vec<f32>>,
}

impl Case {
    /// `counts`, and channel `c`'s value of sample `s` of pixel `p` from `value(c, p, s)`.
    fn new(
        w: u32,
        h: u32,
        channels: &[&str],
        counts: Vec<u32>,
        mut value: impl FnMut(usize, usize, u32) -> f32,
    ) -> Self {
        let data = (0..channels.len())
            .map(|c| {
                let mut plane = Vec::new();
                for (p, &n) in counts.iter().enumerate() {
                    for s in 0..n {
                        plane.push(value(c, p, s));
                    }
                }
                plane
            })
            .collect();
        Self {
            w,
            h,
            channels: channels.iter().map(|c| (*c).to_string()).collect(),
            counts,
            data,
        }
    }

    fn image(&self) -> DeepImage {
        DeepImage::new(
            self.w,
            self.h,
            self.channels.clone(),
            self.counts.clone(),
            self.data.clone(),
        )
        .unwrap()
    }

    /// Per pixel (row-major) its samples, each `(channel, value)` in channel-name order.
    fn expected(&self) -> Vec<Vec<Sample>> {
        let mut order: Vec<usize> = (0..self.channels.len()).collect();
        order.sort_by(|&a, &b| self.channels[a].as_bytes().cmp(self.channels[b].as_bytes()));
        let mut first = 0usize;
        self.counts
            .iter()
            .map(|&n| {
                let px = (first..first + n as usize)
                    .map(|i| {
                        order
                            .iter()
                            .map(|&c| (self.channels[c].clone(), self.data[c][i]))
                            .collect()
                    })
                    .collect();
                first += n as usize;
                px
            })
            .collect()
    }
}

fn write(path: &Path, case: &Case) {
    write_deep_exr(path, &case.image(), &Default::default(), false).unwrap();
}

fn tool(name: &str, args: &[&str]) -> Option<String> {
    common::oiio_tool(name, args)
}

fn dump(path: &Path, w: u32, h: u32) -> Option<Vec<Vec<Sample>>> {
    common::deep_dump(path, w as usize, h as usize)
}

/// OIIO reads back exactly `case`: every pixel's sample count and every sample's bits.
fn check_read_back(path: &Path, case: &Case) {
    let Some(got) = dump(path, case.w, case.h) else {
        return;
    };
    let want = case.expected();
    for (p, (g, e)) in got.iter().zip(&want).enumerate() {
        let (x, y) = (p % case.w as usize, p / case.w as usize);
        assert_eq!(g.len(), e.len(), "pixel ({x}, {y}) sample count");
        for (s, (gs, es)) in g.iter().zip(e).enumerate() {
            let names = |v: &[(String, f32)]| v.iter().map(|c| c.0.clone()).collect::<Vec<_>>();
            assert_eq!(names(gs), names(es), "pixel ({x}, {y}) sample {s} channels");
            for ((c, gv), (_, ev)) in gs.iter().zip(es) {
                let same = gv.to_bits() == ev.to_bits() || (gv.is_nan() && ev.is_nan());
                assert!(
                    same,
                    "pixel ({x}, {y}) sample {s} {c}: read {gv:e}, wrote {ev:e}"
                );
            }
        }
    }
}

/// `iinfo -v` of the file, checked for what every deep file of ours says.
fn info(path: &Path, case: &Case) -> Option<String> {
    let text = tool("iinfo", &["-v", path.to_str().unwrap()])?;
    let mut sorted = case.channels.clone();
    sorted.sort();
    let max = case.counts.iter().max().unwrap();
    let nch = case.channels.len();
    for want in [
        format!(
            "{} x {:>4}, {nch} channel, deep float openexr",
            case.w, case.h
        ),
        format!("channel list: {}", sorted.join(", ")),
        "compression: \"zips\"".to_string(),
        format!("openexr:chunkCount: {}", case.h),
        format!("openexr:maxSamplesPerPixel: {max}"),
    ] {
        assert!(text.contains(&want), "iinfo -v lacks {want:?}:\n{text}");
    }
    Some(text)
}

/// One chunk as stored: y, packed offset-table size, packed and unpacked sample-data sizes.
#[derive(Debug)]
struct Chunk {
    y: i32,
    table: u64,
    packed: u64,
    unpacked: u64,
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

/// Version field and chunks of a single-part deep scanline file, parsed here.
fn layout(path: &Path, h: u32) -> (u32, Vec<Chunk>) {
    let b = std::fs::read(path).unwrap();
    assert_eq!(b[..4], [0x76, 0x2f, 0x31, 0x01]);
    let version = u32_at(&b, 4);
    let mut at = 8;
    let mut names = Vec::new();
    while b[at] != 0 {
        let name_end = at + b[at..].iter().position(|&c| c == 0).unwrap();
        let kind_end = name_end + 1 + b[name_end + 1..].iter().position(|&c| c == 0).unwrap();
        let size = u32_at(&b, kind_end + 1) as usize;
        names.push(String::from_utf8(b[at..name_end].to_vec()).unwrap());
        at = kind_end + 5 + size;
    }
    let mut sorted = names.clone();
    sorted.sort();
    assert_eq!(names, sorted, "attributes in name order");
    at += 1;
    let mut chunks = Vec::new();
    let mut expect = at + 8 * h as usize;
    for k in 0..h as usize {
        let off = u64_at(&b, at + 8 * k) as usize;
        assert_eq!(off, expect, "chunk {k} offset");
        let c = Chunk {
            y: u32_at(&b, off) as i32,
            table: u64_at(&b, off + 4),
            packed: u64_at(&b, off + 12),
            unpacked: u64_at(&b, off + 20),
        };
        expect = off + 28 + (c.table + c.packed) as usize;
        chunks.push(c);
    }
    assert_eq!(expect, b.len(), "the last chunk ends the file");
    (version, chunks)
}

#[test]
fn small_image_reads_back_sample_for_sample() {
    // 7 x 5, 0..=4 samples per pixel, row 2 without samples; channels given out of order.
    let (w, h) = (7u32, 5u32);
    let counts: Vec<u32> = (0..w * h)
        .map(|p| if p / w == 2 { 0 } else { (p * 3 + p / w) % 5 })
        .collect();
    let case = Case::new(w, h, &["ZBack", "A", "Z"], counts, |c, p, s| match c {
        0 => 10.0 + p as f32 * 0.37 + s as f32 * 1.1 + 0.05, // ZBack
        1 => 1.0 / (3.0 + p as f32 + s as f32 * 0.25),       // A
        _ => 10.0 + p as f32 * 0.37 + s as f32 * 1.1,        // Z
    });
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("small.exr");
    write(&f, &case);
    info(&f, &case);
    check_read_back(&f, &case);
    let (version, chunks) = layout(&f, h);
    assert_eq!(version, 2 | 0x800);
    for (y, c) in chunks.iter().enumerate() {
        assert_eq!(c.y, y as i32);
        let n: u32 = case.counts[y * w as usize..(y + 1) * w as usize]
            .iter()
            .sum();
        assert_eq!(c.unpacked, u64::from(n) * 3 * 4, "line {y}");
        if n == 0 {
            assert_eq!((c.packed, c.unpacked), (0, 0), "line {y}");
        }
    }
}

#[test]
fn large_image_compresses_and_reads_back() {
    let (w, h) = (300u32, 200u32);
    let mut rng = Pcg64::seed_from_u64(7);
    let counts: Vec<u32> = (0..w * h).map(|_| rng.gen_range(0..=6)).collect();
    let case = Case::new(w, h, &["A", "Z", "ZBack"], counts, |c, p, s| {
        let z = 1.0 + (p % 300) as f32 * 0.5 + s as f32;
        match c {
            0 => 0.25,
            1 => z,
            _ => z + 0.5,
        }
    });
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("large.exr");
    write(&f, &case);
    let (_, chunks) = layout(&f, h);
    for c in &chunks {
        assert!(
            c.table < u64::from(w) * 4,
            "zlib wins on the offset table: {c:?}"
        );
        assert!(c.packed < c.unpacked, "zlib wins on the samples: {c:?}");
    }
    info(&f, &case);
    check_read_back(&f, &case);
}

#[test]
fn incompressible_data_is_stored_raw_and_reads_back() {
    // Random finite floats (every bit pattern but NaN and infinity): zlib cannot win.
    let (w, h) = (64u32, 9u32);
    let mut rng = Pcg64::seed_from_u64(11);
    let counts: Vec<u32> = (0..w * h).map(|_| rng.gen_range(1..=6)).collect();
    let case = Case::new(w, h, &["A", "Z"], counts, |_, _, _| loop {
        let v = f32::from_bits(rng.gen());
        if v.is_finite() {
            break v;
        }
    });
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("noise.exr");
    write(&f, &case);
    let (_, chunks) = layout(&f, h);
    for c in &chunks {
        assert_eq!(c.packed, c.unpacked, "raw samples: {c:?}");
    }
    info(&f, &case);
    check_read_back(&f, &case);
}

#[test]
fn edge_cases_read_back() {
    let dir = tempfile::tempdir().unwrap();
    // No samples at all.
    let empty = Case::new(3, 2, &["Z"], vec![0; 6], |_, _, _| 0.0);
    // One column: a 4-byte offset table that zlib cannot shrink, stored raw; special values.
    let special = [
        -0.0,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::MAX,
        f32::MIN_POSITIVE,
        1e-45,
        0.1,
        16_777_215.0,
    ];
    let column = Case::new(1, 4, &["A"], vec![2, 0, 5, 1], |_, p, s| {
        special[(p * 3 + s as usize) % special.len()]
    });
    // A channel name longer than 31 bytes: the long-names bit.
    let long = "a.channel.name.longer.than.thirty.one.bytes";
    let named = Case::new(2, 2, &[long, "B"], vec![1, 2, 0, 1], |c, p, s| {
        (c * 100 + p * 10) as f32 + s as f32
    });
    for (k, case) in [empty, column, named].iter().enumerate() {
        let f = dir.path().join(format!("edge{k}.exr"));
        write(&f, case);
        let (version, chunks) = layout(&f, case.h);
        let long_names = case.channels.iter().any(|c| c.len() > 31);
        assert_eq!(version, 2 | 0x800 | if long_names { 0x400 } else { 0 });
        if case.w == 1 {
            assert!(chunks.iter().all(|c| c.table == 4), "{chunks:?}");
        }
        info(&f, case);
        check_read_back(&f, case);
    }
}

#[test]
fn attributes_reach_the_header() {
    let case = Case::new(2, 1, &["A"], vec![1, 1], |_, p, _| p as f32);
    let mut attrs = DeepAttributes {
        part_name: "shadow".into(),
        ..DeepAttributes::default()
    };
    let v3d: Vec<u8> = [1.5f64, -2.0, 0.1]
        .iter()
        .flat_map(|c| c.to_le_bytes())
        .collect();
    let m: [f32; 16] = std::array::from_fn(|k| k as f32 + 0.5);
    attrs.extra = vec![
        (
            "umbra:note".into(),
            AttributeValue::Text(Text::from("hello deep")),
        ),
        ("umbra:scale".into(), AttributeValue::F64(0.125)),
        (
            "umbra:dir".into(),
            AttributeValue::Custom {
                kind: Text::from("v3d"),
                bytes: v3d.into(),
            },
        ),
        ("worldToCamera".into(), AttributeValue::Matrix4x4(m)),
    ];
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("attrs.exr");
    write_deep_exr(&f, &case.image(), &attrs, false).unwrap();
    check_read_back(&f, &case);
    let Some(text) = info(&f, &case) else {
        return;
    };
    for want in [
        "oiio:subimagename: \"shadow\"",
        "umbra:note: \"hello deep\"",
        "umbra:scale: 0.125",
        "umbra:dir: 1.5, -2, 0.1",
        "worldtocamera: 0.5, 1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5, 8.5, 9.5, 10.5, 11.5, 12.5, 13.5, 14.5, 15.5",
    ] {
        assert!(
            text.to_lowercase().contains(&want.to_lowercase()),
            "iinfo -v lacks {want:?}:\n{text}"
        );
    }
    // Reserved or repeated names are refused, and nothing is written.
    for extra in [
        vec![("chunkCount".to_string(), AttributeValue::I32(3))],
        vec![
            ("x".to_string(), AttributeValue::I32(1)),
            ("x".to_string(), AttributeValue::I32(2)),
        ],
        vec![(String::new(), AttributeValue::I32(1))],
    ] {
        let bad = DeepAttributes {
            extra,
            ..DeepAttributes::default()
        };
        let g = dir.path().join("bad.exr");
        let e = write_deep_exr(&g, &case.image(), &bad, false).unwrap_err();
        assert!(
            matches!(&e, Error::InvalidArgument { name, .. } if name == "deep"),
            "{e}"
        );
        assert!(!g.exists());
    }
}

#[test]
fn same_image_same_bytes_and_no_silent_overwrite() {
    let mut rng = Pcg64::seed_from_u64(3);
    let counts: Vec<u32> = (0..40 * 30).map(|_| rng.gen_range(0..=3)).collect();
    let case = Case::new(40, 30, &["Z", "A"], counts, |c, p, s| {
        (c + p) as f32 * 0.5 + s as f32
    });
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a.exr"), dir.path().join("b.exr"));
    write(&a, &case);
    write(&b, &case);
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    let e = write_deep_exr(&a, &case.image(), &Default::default(), false).unwrap_err();
    assert!(matches!(e, Error::Exists { .. }), "{e}");
    write_deep_exr(&a, &case.image(), &Default::default(), true).unwrap();
    // OpenEXR's own writer (through oiiotool) stores the same samples.
    let c = dir.path().join("c.exr");
    if tool(
        "oiiotool",
        &[a.to_str().unwrap(), "-o", c.to_str().unwrap()],
    )
    .is_some()
    {
        check_read_back(&c, &case);
    }
}

#[test]
fn bad_sizes_are_refused() {
    let ch = |n: &[&str]| n.iter().map(|c| (*c).to_string()).collect::<Vec<_>>();
    let bad: Vec<(&str, umbra::Result<DeepImage>)> = vec![
        (
            "zero width",
            DeepImage::new(0, 1, ch(&["A"]), vec![], vec![vec![]]),
        ),
        (
            "zero height",
            DeepImage::new(1, 0, ch(&["A"]), vec![], vec![vec![]]),
        ),
        (
            "width over i32",
            DeepImage::new(1 << 31, 1, ch(&["A"]), vec![], vec![vec![]]),
        ),
        (
            "counts short",
            DeepImage::new(2, 2, ch(&["A"]), vec![0; 3], vec![vec![]]),
        ),
        (
            "counts long",
            DeepImage::new(2, 2, ch(&["A"]), vec![0; 5], vec![vec![]]),
        ),
        (
            "too few samples",
            DeepImage::new(2, 1, ch(&["A"]), vec![1, 2], vec![vec![0.0; 2]]),
        ),
        (
            "too many samples",
            DeepImage::new(2, 1, ch(&["A"]), vec![1, 2], vec![vec![0.0; 4]]),
        ),
        (
            "one plane short",
            DeepImage::new(1, 1, ch(&["A", "Z"]), vec![1], vec![vec![0.0], vec![]]),
        ),
        (
            "planes != channels",
            DeepImage::new(1, 1, ch(&["A", "Z"]), vec![1], vec![vec![0.0]]),
        ),
        ("no channels", DeepImage::new(1, 1, vec![], vec![0], vec![])),
        (
            "empty name",
            DeepImage::new(1, 1, ch(&[""]), vec![0], vec![vec![]]),
        ),
        (
            "non-ASCII name",
            DeepImage::new(1, 1, ch(&["Ä"]), vec![0], vec![vec![]]),
        ),
        (
            "NUL in name",
            DeepImage::new(1, 1, ch(&["A\0"]), vec![0], vec![vec![]]),
        ),
        (
            "256-byte name",
            DeepImage::new(1, 1, vec!["x".repeat(256)], vec![0], vec![vec![]]),
        ),
        (
            "repeated name",
            DeepImage::new(1, 1, ch(&["A", "A"]), vec![0], vec![vec![], vec![]]),
        ),
        (
            "row over i32 samples",
            DeepImage::new(2, 1, ch(&["A"]), vec![u32::MAX, 1], vec![vec![]]),
        ),
    ];
    for (what, r) in bad {
        match r {
            Err(Error::InvalidArgument { name, reason }) => {
                assert_eq!(name, "deep", "{what}: {reason}");
            }
            other => panic!("{what}: {other:?}"),
        }
    }
    // The largest name and a 1 x 1 image are fine.
    let ok = DeepImage::new(1, 1, vec!["x".repeat(255)], vec![1], vec![vec![2.0]]).unwrap();
    assert_eq!(ok.max_samples_per_pixel(), 1);
}

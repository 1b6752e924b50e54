//! How a map's OpenEXR file is laid out: scanlines (the default), or square tiles that a
//! renderer pages in one at a time, optionally with mip levels it filters between.
//!
//! Mip levels follow OpenEXR's `MIPMAP_LEVELS` with `ROUND_DOWN`: level `l` is
//! `max(1, floor(W / 2^l)) x max(1, floor(H / 2^l))`, down to 1 x 1, so there are
//! `floor(log2(max(W, H))) + 1` levels. Each level pixel is the **box filter** of level 0 over
//! its footprint: pixel `(i, j)` of a `w x h` level covers `[i W / w, (i + 1) W / w) x
//! [j H / h, (j + 1) H / h)` in level-0 pixels, and its value is the area-weighted mean of the
//! level-0 values there,
//!
//! `T_l(i, j) = sum_{x, y} a_x(i) b_y(j) T_0(x, y)`, with `a_x(i) = |[x, x+1) ∩ [i W/w, (i+1) W/w)| w / W`
//!
//! (and `b` likewise along y). The mean of transmittance is what a lookup filtering a shadow
//! map over an area wants (percentage-closer filtering of a binary visibility is its special
//! case), and it keeps every level's mean equal to level 0's. For power-of-two sizes it is the
//! plain mean of each `2^l x 2^l` block.

use crate::error::{Error, Result};

/// Largest tile side accepted (`--tile`): OpenEXR allows more, no reader pages such tiles.
pub const MAX_TILE: u32 = 4096;

/// The layout of a map's EXR file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct ExrLayout {
    /// `Some(n)`: `n x n` tiles; `None`: scanlines.
    pub tile: Option<u32>,
    /// Also write box-filtered mip levels (round-down); needs tiles.
    pub mipmap: bool,
}

impl ExrLayout {
    /// Scanlines, one level: the default.
    pub const SCANLINES: Self = Self {
        tile: None,
        mipmap: false,
    };

    /// Check the layout: a tile side in `1..=MAX_TILE`, mip levels only with tiles.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `tile` or `mipmap`.
    pub fn validate(&self) -> Result<()> {
        if let Some(n) = self.tile {
            if n == 0 || n > MAX_TILE {
                return Err(Error::InvalidArgument {
                    name: "tile".into(),
                    reason: format!("{n}: a tile side from 1 to {MAX_TILE} pixels"),
                });
            }
        } else if self.mipmap {
            return Err(Error::InvalidArgument {
                name: "mipmap".into(),
                reason: "mip levels are stored in tiles: give a tile size too".into(),
            });
        }
        Ok(())
    }
}

/// The sizes of the round-down mip levels of a `w x h` image, level 0 first.
#[must_use]
pub fn mip_sizes(w: usize, h: usize) -> Vec<(usize, usize)> {
    let mut out = vec![(w, h)];
    let mut l = 1u32;
    while out.last().is_some_and(|&(a, b)| a > 1 || b > 1) {
        let size = |n: usize| (n >> l).max(1);
        out.push((size(w), size(h)));
        l += 1;
    }
    out
}

/// The area weights of the level-0 pixels under each of `n` level pixels spanning `full`
/// level-0 pixels: per level pixel, `(first level-0 pixel, weights summing to 1)`.
fn footprints(full: usize, n: usize) -> Vec<(usize, Vec<f64>)> {
    // Positions in units of 1/n level-0 pixels, so every boundary is an integer.
    (0..n)
        .map(|i| {
            let (lo, hi) = (i * full, (i + 1) * full);
            let first = lo / n;
            let last = (hi - 1) / n;
            let weights = (first..=last)
                .map(|x| {
                    let a = (x * n).max(lo);
                    let b = ((x + 1) * n).min(hi);
                    (b - a) as f64 / full as f64
                })
                .collect();
            (first, weights)
        })
        .collect()
}

/// The mip levels of the `w x h` image `t` (row 0 at the top), level 0 (a copy of `t`) first:
/// see the module docs for the filter. Sums are taken in f64 and rounded once to f32.
#[must_use]
pub fn mip_levels(t: &[f32], w: usize, h: usize) -> Vec<Vec<f32>> {
    let sizes = mip_sizes(w, h);
    let mut out = Vec::with_capacity(sizes.len());
    out.push(t.to_vec());
    for &(lw, lh) in &sizes[1..] {
        let fx = footprints(w, lw);
        let fy = footprints(h, lh);
        // Along x first (every level-0 row), then along y.
        let mut rows = vec![0.0f64; lw * h];
        for y in 0..h {
            let src = &t[y * w..(y + 1) * w];
            for (i, (first, wts)) in fx.iter().enumerate() {
                rows[y * lw + i] = wts
                    .iter()
                    .zip(&src[*first..])
                    .map(|(a, v)| a * f64::from(*v))
                    .sum();
            }
        }
        let mut level = vec![0.0f32; lw * lh];
        for (j, (first, wts)) in fy.iter().enumerate() {
            for i in 0..lw {
                let v: f64 = wts
                    .iter()
                    .enumerate()
                    .map(|(k, b)| b * rows[(first + k) * lw + i])
                    .sum();
                level[j * lw + i] = v as f32;
            }
        }
        out.push(level);
    }
    out
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn sizes_round_down_to_one_by_one() {
        assert_eq!(mip_sizes(1, 1), vec![(1, 1)]);
        assert_eq!(
            mip_sizes(100, 70),
            vec![
                (100, 70),
                (50, 35),
                (25, 17),
                (12, 8),
                (6, 4),
                (3, 2),
                (1, 1)
            ]
        );
        assert_eq!(mip_sizes(8, 1), vec![(8, 1), (4, 1), (2, 1), (1, 1)]);
        assert_eq!(mip_sizes(5, 3).len(), 3); // floor(log2 5) + 1
    }

    #[test]
    fn power_of_two_levels_are_block_means() {
        let (w, h) = (8, 4);
        let t: Vec<f32> = (0..w * h).map(|k| (k * 7 % 11) as f32 / 10.0).collect();
        let levels = mip_levels(&t, w, h);
        assert_eq!(levels.len(), 4);
        assert_eq!(levels[0], t);
        for (l, level) in levels.iter().enumerate().skip(1) {
            let (lw, lh) = mip_sizes(w, h)[l];
            let (bw, bh) = (w / lw, h / lh);
            for j in 0..lh {
                for i in 0..lw {
                    let mut s = 0.0f64;
                    for y in j * bh..(j + 1) * bh {
                        for x in i * bw..(i + 1) * bw {
                            s += f64::from(t[y * w + x]);
                        }
                    }
                    let want = (s / (bw * bh) as f64) as f32;
                    assert!(
                        (level[j * lw + i] - want).abs() <= 1e-7,
                        "level {l} ({i}, {j})"
                    );
                }
            }
        }
    }

    #[test]
    fn odd_sizes_keep_the_mean_and_constants() {
        let (w, h) = (13, 7);
        let t: Vec<f32> = (0..w * h).map(|k| ((k * 37) % 17) as f32 / 16.0).collect();
        let mean0: f64 = t.iter().map(|v| f64::from(*v)).sum::<f64>() / (w * h) as f64;
        for (l, level) in mip_levels(&t, w, h).iter().enumerate() {
            let mean: f64 = level.iter().map(|v| f64::from(*v)).sum::<f64>() / level.len() as f64;
            assert!((mean - mean0).abs() < 1e-6, "level {l}: {mean} vs {mean0}");
            assert!(level.iter().all(|v| (0.0..=1.0).contains(v)));
        }
        let c = vec![0.25f32; w * h];
        for level in mip_levels(&c, w, h) {
            assert!(level.iter().all(|v| (*v - 0.25).abs() < 1e-7));
        }
    }

    #[test]
    fn layouts_are_validated() {
        assert!(ExrLayout::SCANLINES.validate().is_ok());
        let tiled = |tile, mipmap| ExrLayout { tile, mipmap }.validate();
        assert!(tiled(Some(64), true).is_ok());
        assert!(tiled(Some(1), false).is_ok());
        assert!(tiled(Some(0), false)
            .unwrap_err()
            .to_string()
            .contains("'tile'"));
        assert!(tiled(Some(MAX_TILE + 1), false).is_err());
        // Mip levels without tiles name the option given (each front end respells it).
        let e = tiled(None, true).unwrap_err();
        assert!(e.to_string().contains("'mipmap'") && e.to_string().contains("tile size"));
    }
}

//! Sequence and output patterns: the frame tokens of input patterns (`####`, `$F4`, `%04d`)
//! and the placeholders of output patterns (`{light}`, `{stem}`, `{frame:04}`).

/// Expand a sequence pattern for one frame: `#...#` (zero-padded to the number of `#`),
/// `$F` / `$FN` (padded to N) or printf's `%d` / `%0Nd` (padded to N). `None` when the pattern
/// has no frame token.
#[must_use]
pub fn expand_pattern(pattern: &str, frame: i64) -> Option<String> {
    let (start, len, pad) = frame_token(pattern)?;
    let n = pad.min(MAX_FRAME_PAD);
    Some(format!(
        "{}{frame:0n$}{}",
        &pattern[..start],
        &pattern[start + len..]
    ))
}

/// The first frame token of a pattern: its byte offset, its length and the padding it asks
/// for (a huge `N` saturates). `####` wins over `$F`, which wins over `%0Nd`.
fn frame_token(pattern: &str) -> Option<(usize, usize, usize)> {
    let digits_after = |at: usize| -> String {
        pattern[at..]
            .chars()
            .take_while(char::is_ascii_digit)
            .collect()
    };
    let pad_of = |d: &str| {
        if d.is_empty() {
            0
        } else {
            d.parse::<usize>().unwrap_or(usize::MAX)
        }
    };
    if let Some(start) = pattern.find('#') {
        let n = pattern[start..].chars().take_while(|&c| c == '#').count();
        return Some((start, n, n));
    }
    if let Some(start) = pattern.find("$F") {
        let d = digits_after(start + 2);
        return Some((start, 2 + d.len(), pad_of(&d)));
    }
    let mut from = 0;
    while let Some(off) = pattern[from..].find('%') {
        let start = from + off;
        let d = digits_after(start + 1);
        if pattern[start + 1 + d.len()..].starts_with('d') && (d.is_empty() || d.starts_with('0')) {
            return Some((start, 2 + d.len(), pad_of(&d)));
        }
        from = start + 1;
    }
    None
}

/// Widest frame-number padding accepted (`####`, `$FN`, `{frame:0N}`).
pub const MAX_FRAME_PAD: usize = 32;
/// Most frames one `[[inputs]]` sequence may expand to.
pub const MAX_FRAMES: i64 = 1_000_000;

/// The padding a sequence pattern asks for (`None` without a frame token; a huge `N`
/// saturates).
pub(super) fn pattern_pad(pattern: &str) -> Option<usize> {
    frame_token(pattern).map(|(_, _, pad)| pad)
}

/// Fill an output pattern: `{light}`, `{stem}`, `{frame}`, `{frame:0N}`.
///
/// # Errors
/// An unknown placeholder, or `{frame}` for an input that has no frame.
pub fn fill_output(
    pattern: &str,
    light: &str,
    stem: &str,
    frame: Option<i64>,
) -> Result<String, String> {
    let mut out = String::new();
    let mut rest = pattern;
    while let Some(open) = rest.find('{') {
        out.push_str(&rest[..open]);
        let close = rest[open..]
            .find('}')
            .ok_or_else(|| format!("unclosed '{{' in '{pattern}'"))?
            + open;
        let key = &rest[open + 1..close];
        match key {
            "light" => out.push_str(light),
            "stem" => out.push_str(stem),
            _ if key == "frame" || key.starts_with("frame:") => {
                let f = frame.ok_or_else(|| {
                    format!("'{{{key}}}' but input '{stem}' is not from a sequence")
                })?;
                let width = match key.strip_prefix("frame:") {
                    None => 0,
                    Some(w) => w
                        .parse::<usize>()
                        .ok()
                        .filter(|&w| w <= MAX_FRAME_PAD)
                        .ok_or_else(|| {
                            format!(
                                "'{{{key}}}': expected {{frame:0N}} with N at most {MAX_FRAME_PAD}"
                            )
                        })?,
                };
                out.push_str(&format!("{f:0width$}"));
            }
            _ => {
                return Err(format!(
                    "unknown placeholder '{{{key}}}' (known: {{light}}, {{stem}}, {{frame}}, {{frame:04}})"
                ))
            }
        }
        rest = &rest[close + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

//! Text from files and users, made safe to print: names in VDB files are arbitrary bytes, and a
//! grid called `"\x1b]0;pwned\x07"` must not retitle the user's terminal or split a one-line
//! error message.

use std::borrow::Cow;

/// `s` with every control character (C0, DEL, C1: ESC, BEL, newline, ...) written as `\xNN`
/// (`\u{NNNN}` above 0xff), and backslashes left as they are. Borrowed when nothing changes.
#[must_use]
pub fn escape(s: &str) -> Cow<'_, str> {
    if !s.chars().any(char::is_control) {
        return Cow::Borrowed(s);
    }
    let mut out = String::with_capacity(s.len() + 8);
    for c in s.chars() {
        if c.is_control() {
            let n = u32::from(c);
            if n <= 0xff {
                out.push_str(&format!("\\x{n:02x}"));
            } else {
                out.push_str(&format!("\\u{{{n:04x}}}"));
            }
        } else {
            out.push(c);
        }
    }
    Cow::Owned(out)
}

#[cfg(test)]
mod tests {
    use super::escape;

    #[test]
    fn control_characters_are_escaped_and_others_kept() {
        assert_eq!(escape("density"), "density");
        assert!(matches!(escape("density"), std::borrow::Cow::Borrowed(_)));
        assert_eq!(escape("d\x1b[31m\x07"), "d\\x1b[31m\\x07");
        assert_eq!(escape("a\nb\tc"), "a\\x0ab\\x09c");
        assert_eq!(escape("\u{9b}x"), "\\x9bx");
        assert_eq!(escape("dichte \u{1e}1 \u{e9}"), "dichte \\x1e1 \u{e9}");
    }
}

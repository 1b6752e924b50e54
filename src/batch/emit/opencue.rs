//! OpenCue job specs: the `cjsl-1.15` XML `opencue-pyoutline` writes (`serialize_simple`,
//! commands run as given) for a job of one `Render` layer whose frames are the job's tasks.
//!
//! OpenCue hands a layer's frames out in chunks of `chunk` consecutive frames and, before a
//! chunk runs, replaces `#IFRAME#` (its first frame), `#FRAME_START#` and `#FRAME_END#` (its
//! first and last) in the command, which RQD runs through a shell. So frame `I` is task `I`
//! (`--plan`'s numbering), the range is `0-(N-1)`, and a chunk runs
//! `umbra batch JOB --task #FRAME_START#-#FRAME_END#`. The tokens stay bare words, as
//! OpenCue's own submitters write them.
//!
//! cuebot replaces its placeholders (`#IFRAME#`, `#ZFRAME#`, `#FRAME#`, `#LAYER#`, `#JOB#`,
//! ...) anywhere in the command, whatever surrounds them, so no path is written into it: the
//! umbra binary and the job file travel in the layer's environment (`UMBRA`, `UMBRA_JOB`),
//! which cuebot hands to RQD unchanged, and the command reads them as `"$UMBRA"` and
//! `"$UMBRA_JOB"` (double-quoted: the shell expands them once, spaces and quotes intact).

use super::{job_name, token};
use crate::batch::Job;
use std::fmt::Write as _;
use std::path::Path;

/// Who a job is for: the `show`, `shot` and `user` (and the user's numeric id, which RQD runs
/// the frames as) the spec carries. Names are non-empty and made of ASCII letters, digits, `.`,
/// `_` and `-` (the spec's `NMTOKEN`s, and what cuebot builds job names from).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CueIdentity {
    show: String,
    shot: String,
    user: String,
    uid: Option<u32>,
}

impl CueIdentity {
    /// Validate the names.
    ///
    /// # Errors
    /// [`crate::error::Error::InvalidArgument`] naming `show`, `shot` or `user` when one is empty or
    /// holds another character.
    pub fn new(show: &str, shot: &str, user: &str, uid: Option<u32>) -> crate::error::Result<Self> {
        for (name, value) in [("show", show), ("shot", shot), ("user", user)] {
            let ok = !value.is_empty()
                && value
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || "._-".contains(c));
            if !ok {
                return Err(crate::error::Error::InvalidArgument {
                    name: name.into(),
                    reason: format!(
                        "{value:?}: an OpenCue {name} is made of ASCII letters, digits, '.', '_' \
                         and '-'"
                    ),
                });
            }
        }
        Ok(Self {
            show: show.into(),
            shot: shot.into(),
            user: user.into(),
            uid,
        })
    }
}

/// `s` as XML character data (`&`, `<`, `>` and `"` escaped); `None` when it holds a
/// character XML 1.0 cannot carry (a control character other than tab, newline and carriage
/// return, U+FFFE, U+FFFF).
fn xml(s: &str) -> Option<String> {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\t' | '\n' | '\r' => out.push(c),
            c if (c as u32) < 0x20 || c == '\u{FFFE}' || c == '\u{FFFF}' => return None,
            c => out.push(c),
        }
    }
    Some(out)
}

/// The job's OpenCue spec: one layer `bake` over frames `0-(N-1)` (frame `I` is task `I`) in
/// chunks of `chunk` tasks, each running the umbra at `exe`; `cores` the job's thread count
/// (`threadable` when it uses every core it is given); pyoutline's defaults for the rest
/// (priority 1, 2 retries, not paused, no auto-eat, service `shell`). The layer's environment
/// carries the two paths; no e-mail address.
///
/// # Errors
/// [`crate::error::Error::InvalidArgument`] when `chunk` is 0; [`crate::error::Error::Unsupported`] when the
/// command holds a character XML cannot carry.
pub fn opencue(
    job: &Job,
    exe: &Path,
    chunk: usize,
    id: &CueIdentity,
) -> crate::error::Result<String> {
    if chunk == 0 {
        return Err(crate::error::Error::InvalidArgument {
            name: "chunk".into(),
            reason: "give N >= 1 job tasks per farm task".into(),
        });
    }
    let frames = if chunk > 1 {
        "#FRAME_START#-#FRAME_END#"
    } else {
        "#IFRAME#"
    };
    let cmd = format!("\"$UMBRA\" batch \"$UMBRA_JOB\" --quiet --task {frames}");
    let control = || crate::error::Error::Unsupported {
        path: job.path.clone(),
        what: "a control character in the umbra binary's or the job file's path: an OpenCue \
               spec (XML 1.0) cannot carry it"
            .into(),
    };
    let exe_xml = xml(&exe.display().to_string()).ok_or_else(control)?;
    let job_xml = xml(&job.path.display().to_string()).ok_or_else(control)?;
    let mut s = String::from(
        "<?xml version=\"1.0\"?>\n<!DOCTYPE spec PUBLIC \"SPI Cue  Specification Language\" \
         \"http://localhost:8080/spcue/dtd/cjsl-1.15.dtd\">\n<spec>\n",
    );
    // Infallible: writing to a String.
    let _ = writeln!(s, "  <show>{}</show>", id.show);
    let _ = writeln!(s, "  <shot>{}</shot>", id.shot);
    let _ = writeln!(s, "  <user>{}</user>", id.user);
    if let Some(uid) = id.uid {
        let _ = writeln!(s, "  <uid>{uid}</uid>");
    }
    let _ = writeln!(
        s,
        "  <job name=\"umbra_{}\">\n    <paused>False</paused>\n    <priority>1</priority>\n    \
         <maxretries>2</maxretries>\n    <autoeat>False</autoeat>\n    <env/>\n    <layers>\n      \
         <layer name=\"bake\" type=\"Render\">",
        token(&job_name(job))
    );
    let _ = writeln!(s, "        <cmd>{cmd}</cmd>");
    let _ = writeln!(
        s,
        "        <range>0-{}</range>",
        job.task_count().saturating_sub(1)
    );
    let _ = writeln!(s, "        <chunk>{chunk}</chunk>");
    if job.options.threads > 0 {
        let _ = writeln!(s, "        <cores>{}.0</cores>", job.options.threads);
    } else {
        s.push_str("        <threadable>True</threadable>\n");
    }
    let _ = writeln!(
        s,
        "        <env>\n          <key name=\"UMBRA\">{exe_xml}</key>\n          \
         <key name=\"UMBRA_JOB\">{job_xml}</key>\n        </env>"
    );
    s.push_str(
        "        <services>\n          <service>shell</service>\n        \
         </services>\n        <outputs/>\n      </layer>\n    </layers>\n  </job>\n  \
         <depends/>\n</spec>\n",
    );
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_outside_nmtoken_are_refused() {
        assert!(CueIdentity::new("show", "sh010", "td", Some(1000)).is_ok());
        for (show, shot, user) in [("", "s", "u"), ("a b", "s", "u"), ("s", "<x>", "u")] {
            assert!(CueIdentity::new(show, shot, user, None).is_err());
        }
    }

    #[test]
    fn xml_escapes_markup_and_refuses_control_characters() {
        assert_eq!(xml("a<b>&\"c'").as_deref(), Some("a&lt;b&gt;&amp;&quot;c'"));
        assert_eq!(xml("a\u{1}b"), None);
        assert_eq!(xml("é\n").as_deref(), Some("é\n"));
    }
}

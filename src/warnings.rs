//! Which warnings a run prints: each once, none whose code the user allowed (`--allow W0101`,
//! or all of them with `-q`). Errors are always printed. The run's other global switches live
//! here too: `-v` (notes on what each step did and how long it took) and `--strict` (warning
//! W0801 becomes an error).

use std::sync::{Mutex, OnceLock, PoisonError};

use kin_compiler::Diagnostic;

/// The code of the data warning: rows outside a declared range (spec/cli.md).
pub const OUTSIDE_RANGE: &str = "W0801";

/// The code of the warning about a `// kin: allow` comment naming no warning kin has.
pub const UNKNOWN_CODE: &str = "W0803";

/// Every warning code kin has (spec/cli.md, "Warnings").
pub const KNOWN: [&str; 4] = [
    "W0101",
    OUTSIDE_RANGE,
    crate::load::OTHER_TEXT,
    UNKNOWN_CODE,
];

/// Codes allowed by `// kin: allow` comments in the models this run read.
static MODEL_ALLOWED: Mutex<Vec<String>> = Mutex::new(Vec::new());

/// The `// kin: allow W0101, W0801` comments of a model's `source`: their codes are allowed
/// for the rest of the run (as with `--allow`), and each code kin does not have, or an error
/// code, is returned as warning W0803 located at it. A comment keeps the attribute out of the
/// grammar, so every tool that reads `.kin` files (the formatter keeps comments) passes it on
/// unchanged. The codes end at the first word that does not look like one (`// kin: allow
/// W0101 the spare input` explains itself).
pub fn directives(source: &str) -> Vec<Diagnostic> {
    let mut found = Vec::new();
    let mut line_start = 0;
    for line in source.split_inclusive('\n') {
        if let Some(codes_at) = allow_comment(line) {
            let codes = &line[codes_at..];
            for (at, token) in words(codes) {
                if !token.starts_with(['W', 'w', 'E', 'e']) {
                    break;
                }
                let span = kin_compiler::Span::new(
                    line_start + codes_at + at,
                    line_start + codes_at + at + token.len(),
                );
                match parse_code(token) {
                    Ok(code) if KNOWN.contains(&code.as_str()) => {
                        let mut allowed = MODEL_ALLOWED.lock().unwrap_or_else(PoisonError::into_inner);
                        if !allowed.contains(&code) {
                            allowed.push(code);
                        }
                    }
                    Ok(code) => found.push(
                        Diagnostic::warning(
                            UNKNOWN_CODE,
                            format!("`{code}` is not a warning kin has: this `kin: allow` allows nothing"),
                            span,
                        )
                        .with_label("unknown warning code")
                        .with_help(format!("the warning codes are {}", KNOWN.join(", "))),
                    ),
                    Err(why) => found.push(
                        Diagnostic::warning(UNKNOWN_CODE, why, span)
                            .with_label("not a warning code")
                            .with_help(format!("the warning codes are {}", KNOWN.join(", "))),
                    ),
                }
            }
        }
        line_start += line.len();
    }
    found
}

/// The byte offset in `line` where the codes of a `// kin: allow` comment start.
fn allow_comment(line: &str) -> Option<usize> {
    let slash = line.find("//")? + 2;
    let comment = &line[slash..];
    let after_space = comment.trim_start();
    let rest = after_space.strip_prefix("kin:")?;
    let rest_trimmed = rest.trim_start();
    let codes = rest_trimmed.strip_prefix("allow")?;
    if !codes.starts_with(char::is_whitespace) {
        return None;
    }
    Some(line.len() - codes.len())
}

/// The words of `text` separated by blanks or commas, each with its byte offset.
fn words(text: &str) -> Vec<(usize, &str)> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, c) in text
        .char_indices()
        .chain(std::iter::once((text.len(), ' ')))
    {
        if c == ',' || c.is_whitespace() {
            if let Some(s) = start.take() {
                out.push((s, &text[s..i]));
            }
        } else if start.is_none() {
            start = Some(i);
        }
    }
    out
}

/// What the command line said, set once at start-up.
struct Allowed {
    codes: Vec<String>,
    all: bool,
    verbose: bool,
    strict: bool,
}

static ALLOWED: OnceLock<Allowed> = OnceLock::new();

/// The global switches of a run (`--allow`, `-q`, `-v`, `--strict`).
pub struct Switches {
    pub allow: Vec<String>,
    pub quiet: bool,
    pub verbose: bool,
    pub strict: bool,
}

/// Records the global switches for the rest of the run.
pub fn set(s: Switches) {
    let _ = ALLOWED.set(Allowed {
        codes: s.allow,
        all: s.quiet,
        verbose: s.verbose,
        strict: s.strict,
    });
}

/// `-q`: no warnings and no progress bars.
pub fn quiet() -> bool {
    ALLOWED.get().is_some_and(|a| a.all)
}

/// `--strict`: a pose outside a declared range is an error, not warning W0801.
pub fn strict() -> bool {
    ALLOWED.get().is_some_and(|a| a.strict)
}

/// `-v`: whether [`note`] prints.
pub fn verbose() -> bool {
    ALLOWED.get().is_some_and(|a| a.verbose)
}

/// With `-v`, a line on standard error about what a step did (`kin: read … in 12 ms`).
pub fn note(message: &str) {
    if verbose() {
        eprintln!("kin: {message}");
    }
}

/// `message` with the time since `start`, in the unit that reads best.
pub fn timed(message: &str, start: std::time::Instant) -> String {
    let s = start.elapsed().as_secs_f64();
    if s < 1.0 {
        format!("{message} in {:.1} ms", s * 1e3)
    } else {
        format!("{message} in {s:.2} s")
    }
}

/// A byte count as people read it (`1.5 MiB`).
pub fn bytes(n: u64) -> String {
    const UNITS: [&str; 4] = ["bytes", "KiB", "MiB", "GiB"];
    let mut v = n as f64;
    let mut unit = 0;
    while v >= 1024.0 && unit + 1 < UNITS.len() {
        v /= 1024.0;
        unit += 1;
    }
    if unit == 0 {
        format!("{n} bytes")
    } else {
        format!("{v:.1} {}", UNITS[unit])
    }
}

/// Hides a progress bar with `-q` (indicatif already hides it when standard error is not a
/// terminal).
pub fn hush(bar: &indicatif::ProgressBar) {
    if quiet() {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
}

/// A spinner with the elapsed time for a step that may take more than a second (`what` names
/// it); drawn on a terminal only, not with `-q`. Finish it with `finish_and_clear`.
pub fn spinner(what: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new_spinner();
    hush(&bar);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} {msg} ({elapsed})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
    );
    bar.set_message(what.to_string());
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    *ACTIVE.lock().unwrap_or_else(PoisonError::into_inner) = Some(bar.clone());
    bar
}

/// Whether warnings of `code` are silenced.
pub fn allowed(code: &str) -> bool {
    ALLOWED
        .get()
        .is_some_and(|a| a.all || a.codes.iter().any(|c| c.eq_ignore_ascii_case(code)))
        || MODEL_ALLOWED
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .iter()
            .any(|c| c == code)
}

/// True the first time a run meets this warning (`key` says what and where), false after:
/// a command that reads its files or compiles its model twice (`kin diagnose --apply`
/// refits) says each thing once.
pub fn first_time(key: String) -> bool {
    static SAID: Mutex<Vec<String>> = Mutex::new(Vec::new());
    let mut said = SAID.lock().unwrap_or_else(PoisonError::into_inner);
    if said.contains(&key) {
        false
    } else {
        said.push(key);
        true
    }
}

/// The diagnostics a run prints of `diagnostics` (of the file `path`): every error; a warning
/// once per run, unless its code is allowed. (The renderer itself stays free of this state:
/// the fuzz targets build it on its own.)
pub fn shown(path: &str, diagnostics: &[Diagnostic]) -> Vec<Diagnostic> {
    diagnostics
        .iter()
        .filter(|d| {
            d.is_error()
                || (!allowed(d.code)
                    && first_time(format!(
                        "{path} {} {} {:?}",
                        d.code,
                        d.message,
                        d.primary_span()
                    )))
        })
        .cloned()
        .collect()
}

/// As [`shown`], for a JSON report: every error and every warning not allowed.
pub fn kept(diagnostics: &[Diagnostic]) -> Vec<Diagnostic> {
    diagnostics
        .iter()
        .filter(|d| d.is_error() || !allowed(d.code))
        .cloned()
        .collect()
}

/// Prints a warning of `code` on standard error, once per run, unless it is allowed (above a
/// spinner that is turning, not through it).
pub fn say(code: &str, message: &str) {
    if !allowed(code) && first_time(format!("{code} {message}")) {
        let line = format!("warning[{code}]: {message}");
        match active() {
            Some(bar) => bar.suspend(|| eprintln!("{line}")),
            None => eprintln!("{line}"),
        }
    }
}

/// The spinner last started by [`spinner`], so that a warning printed meanwhile is not drawn
/// through it.
static ACTIVE: Mutex<Option<indicatif::ProgressBar>> = Mutex::new(None);

fn active() -> Option<indicatif::ProgressBar> {
    ACTIVE
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .clone()
        .filter(|b| !b.is_finished())
}

/// `--allow`'s value: a warning code such as `W0101` (errors cannot be allowed).
pub fn parse_code(text: &str) -> Result<String, String> {
    let t = text.trim();
    let ok =
        t.len() == 5 && t.starts_with(['W', 'w']) && t[1..].chars().all(|c| c.is_ascii_digit());
    if ok {
        Ok(t.to_ascii_uppercase())
    } else if t.starts_with(['E', 'e']) {
        Err(format!("`{t}` is an error code: errors cannot be allowed"))
    } else {
        Err(format!("`{t}` is not a warning code such as W0101"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn allow_comments_allow_known_codes_and_flag_the_rest() {
        let src =
            "machine m { // kin: allow W0802, w9999 E0601 because\n  // kin: allowed W0101\n}\n";
        let found = directives(src);
        let at: Vec<&str> = found
            .iter()
            .map(|d| &src[d.primary_span().start..d.primary_span().end])
            .collect();
        assert_eq!(at, ["w9999", "E0601"]);
        assert!(found
            .iter()
            .all(|d| d.code == UNKNOWN_CODE && !d.is_error()));
        assert!(allowed("W0802"));
        // `allowed` (not `allow`) is no attribute.
        assert!(!allowed("W0101"));
        assert_eq!(words(" a, b  c,"), [(1, "a"), (4, "b"), (7, "c")]);
    }

    #[test]
    fn byte_counts_read_as_binary_multiples() {
        assert_eq!(bytes(0), "0 bytes");
        assert_eq!(bytes(1023), "1023 bytes");
        assert_eq!(bytes(1536), "1.5 KiB");
        assert_eq!(bytes(3 << 20), "3.0 MiB");
    }

    #[test]
    fn codes_are_warning_codes() {
        assert_eq!(parse_code("w0101"), Ok("W0101".into()));
        assert!(parse_code("E0601")
            .unwrap_err()
            .contains("cannot be allowed"));
        for bad in ["", "W01", "W01011", "X0101", "W01a1"] {
            assert!(parse_code(bad).is_err(), "{bad}");
        }
    }
}

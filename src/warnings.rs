//! Which warnings a run prints: each once, none whose code the user allowed (`--allow W0101`,
//! or all of them with `-q`). Errors are always printed.

use std::sync::{Mutex, OnceLock, PoisonError};

use kin_compiler::Diagnostic;

/// The code of the data warning: rows outside a declared range (spec/cli.md).
pub const OUTSIDE_RANGE: &str = "W0801";

/// What the command line said, set once at start-up.
struct Allowed {
    codes: Vec<String>,
    all: bool,
}

static ALLOWED: OnceLock<Allowed> = OnceLock::new();

/// Records `--allow` and `-q` for the rest of the run.
pub fn set(codes: Vec<String>, quiet: bool) {
    let _ = ALLOWED.set(Allowed { codes, all: quiet });
}

/// Whether warnings of `code` are silenced.
pub fn allowed(code: &str) -> bool {
    ALLOWED
        .get()
        .is_some_and(|a| a.all || a.codes.iter().any(|c| c.eq_ignore_ascii_case(code)))
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

/// Prints a warning of `code` on standard error, once per run, unless it is allowed.
pub fn say(code: &str, message: &str) {
    if !allowed(code) && first_time(format!("{code} {message}")) {
        eprintln!("warning[{code}]: {message}");
    }
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

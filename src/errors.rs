//! Errors as one JSON document when `--format json` was asked for (spec/json.md, "Errors"):
//! a program that reads standard output as JSON gets a document whether the command succeeded
//! or not. The human messages still go to standard error; the places that print an error also
//! record it here, with its location when it has one.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, PoisonError};

use serde::Serialize;

/// One error of the document.
#[derive(Debug, Clone, Serialize, PartialEq, Eq)]
pub struct JsonError {
    /// A diagnostic's code (`E0601`) for a `.kin` file, otherwise what kind of problem:
    /// `usage`, `io`, `data`, `fit` or `failed` (spec/json.md).
    pub code: String,
    pub message: String,
    pub file: Option<String>,
    /// 1-based line and column (in characters) where the file has one.
    pub line: Option<usize>,
    pub column: Option<usize>,
}

/// The document printed on standard output when a command asked for JSON fails.
#[derive(Debug, Serialize)]
pub struct ErrorDocument {
    pub ok: bool,
    pub exit_code: u8,
    pub errors: Vec<JsonError>,
}

static JSON: AtomicBool = AtomicBool::new(false);
static PRINTED: AtomicBool = AtomicBool::new(false);
static ERRORS: Mutex<Vec<JsonError>> = Mutex::new(Vec::new());

/// Whether this run answers in JSON (`--format json`).
pub fn set_json(on: bool) {
    JSON.store(on, Ordering::Relaxed);
}

/// The command printed its own document on standard output (`kin check --format json` does so
/// for a model with errors): no second document is printed.
pub fn document_printed() {
    PRINTED.store(true, Ordering::Relaxed);
}

/// Records an error for the JSON document (printing it is the caller's business).
pub fn record(
    code: &str,
    message: impl Into<String>,
    file: Option<&Path>,
    at: Option<(usize, usize)>,
) {
    if !JSON.load(Ordering::Relaxed) {
        return;
    }
    let e = JsonError {
        code: code.to_string(),
        message: message.into(),
        file: file.map(|p| p.display().to_string()),
        line: at.map(|a| a.0),
        column: at.map(|a| a.1),
    };
    ERRORS
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .push(e);
}

/// The document for a run that ends with `exit_code`, if one is due: JSON asked for, a
/// failure, and no document printed by the command itself. Errors nobody recorded (a message
/// only on standard error) are summed up as one `failed` entry rather than left out.
pub fn document(exit_code: u8) -> Option<ErrorDocument> {
    if exit_code == 0 || !JSON.load(Ordering::Relaxed) || PRINTED.load(Ordering::Relaxed) {
        return None;
    }
    let mut errors = std::mem::take(&mut *ERRORS.lock().unwrap_or_else(PoisonError::into_inner));
    if errors.is_empty() {
        errors.push(JsonError {
            code: "failed".into(),
            message: "the command failed; standard error says why".into(),
            file: None,
            line: None,
            column: None,
        });
    }
    Some(ErrorDocument {
        ok: false,
        exit_code,
        errors,
    })
}

/// Prints [`document`] on standard output, if one is due.
pub fn finish(exit_code: u8) {
    if let Some(doc) = document(exit_code) {
        match serde_json::to_string_pretty(&doc) {
            Ok(s) => println!("{s}"),
            Err(e) => eprintln!("error: {e}"),
        }
    }
}

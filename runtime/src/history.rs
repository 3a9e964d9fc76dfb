//! The fit history kept next to a model (`MODEL.kin.history.jsonl`, one JSON object per fit):
//! how the error fell as the model was revised.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use thiserror::Error;

#[derive(Debug, Error)]
pub enum HistoryError {
    #[error("cannot read the fit history `{path}`: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write the fit history `{path}`: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}, line {line}: not a history entry: {source}")]
    Parse {
        path: PathBuf,
        line: usize,
        source: serde_json::Error,
    },
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FileRms {
    pub path: String,
    pub rms: f64,
}

/// One fit of one revision of a model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Entry {
    /// Seconds since the Unix epoch.
    pub time: u64,
    pub model_hash: String,
    pub parameters: usize,
    pub rows: usize,
    pub sigma: f64,
    pub rms: f64,
    pub error_unit: String,
    pub files: Vec<FileRms>,
}

pub fn path_for(model: &Path) -> PathBuf {
    let mut p = model.as_os_str().to_owned();
    p.push(".history.jsonl");
    PathBuf::from(p)
}

/// Every entry so far (none if there is no history yet).
pub fn read(model: &Path) -> Result<Vec<Entry>, HistoryError> {
    let path = path_for(model);
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(source) => return Err(HistoryError::Read { path, source }),
    };
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            serde_json::from_str(l).map_err(|source| HistoryError::Parse {
                path: path.clone(),
                line: i + 1,
                source,
            })
        })
        .collect()
}

pub fn append(model: &Path, entry: &Entry) -> Result<(), HistoryError> {
    let path = path_for(model);
    let line = serde_json::to_string(entry).map_err(|e| HistoryError::Write {
        path: path.clone(),
        source: std::io::Error::other(e),
    })?;
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(|source| HistoryError::Write {
            path: path.clone(),
            source,
        })?;
    writeln!(f, "{line}").map_err(|source| HistoryError::Write { path, source })
}

/// The last fit of a *different* revision than `hash`, and of the same files: what "before"
/// means when the model changed.
pub fn previous_revision<'a>(entries: &'a [Entry], hash: &str) -> Option<&'a Entry> {
    let last_same = entries.iter().rposition(|e| e.model_hash == hash);
    let upto = match last_same {
        // Refitting the same revision: compare with the revision before it.
        Some(i) if i + 1 == entries.len() => &entries[..i],
        _ => entries,
    };
    upto.iter().rev().find(|e| e.model_hash != hash)
}

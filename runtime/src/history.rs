//! The fit history kept next to a model (`MODEL.kin.history.jsonl`, one JSON object per fit):
//! how the error fell as the model was revised.

use std::io::{Read, Write};
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
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FileRms {
    pub path: String,
    /// NaN when the fit could not tell (written as `null`).
    #[serde(deserialize_with = "nan_if_null")]
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
    /// σ̂ and the residual RMS; NaN or infinite ones are written as `null` (JSON has neither)
    /// and read back as NaN, so one degenerate fit does not make the history unreadable.
    #[serde(deserialize_with = "nan_if_null")]
    pub sigma: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub rms: f64,
    pub error_unit: String,
    pub files: Vec<FileRms>,
    /// The model's text at this revision, kept when `kin diagnose --apply` replaced it, so the
    /// revision can be restored.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<String>,
}

fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// What a history file holds: its entries, and the lines that are not entries (a damaged or
/// hand-edited file), skipped so that every other entry is kept.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct History {
    pub entries: Vec<Entry>,
    /// 1-based numbers of the lines skipped.
    pub damaged: Vec<usize>,
    pub path: PathBuf,
}

impl History {
    /// One sentence naming the damaged lines, if any (for a warning).
    pub fn damage(&self) -> Option<String> {
        if self.damaged.is_empty() {
            return None;
        }
        let lines: Vec<String> = self.damaged.iter().map(|l| l.to_string()).collect();
        let (noun, verb) = if lines.len() == 1 {
            ("line", "is")
        } else {
            ("lines", "are")
        };
        Some(format!(
            "{}: {noun} {} {verb} not history entries and {verb} skipped; the other {} entries are kept",
            self.path.display(),
            lines.join(", "),
            self.entries.len()
        ))
    }
}

pub fn path_for(model: &Path) -> PathBuf {
    let mut p = model.as_os_str().to_owned();
    p.push(".history.jsonl");
    PathBuf::from(p)
}

/// Every entry so far (none if there is no history yet). A line that is not an entry is
/// skipped and named in [`History::damaged`]; only a file that cannot be read is an error.
pub fn read(model: &Path) -> Result<History, HistoryError> {
    let path = path_for(model);
    let mut file = match std::fs::File::open(&path) {
        Ok(f) => f,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Ok(History {
                path,
                ..History::default()
            })
        }
        Err(source) => return Err(HistoryError::Read { path, source }),
    };
    // Shared with other readers, excluded while a record is appended: no half line is read.
    let mut bytes = Vec::new();
    file.lock_shared()
        .and_then(|()| file.read_to_end(&mut bytes))
        .map_err(|source| HistoryError::Read {
            path: path.clone(),
            source,
        })?;
    drop(file);
    Ok(parse(&bytes, path))
}

fn parse(bytes: &[u8], path: PathBuf) -> History {
    let mut history = History {
        path,
        ..History::default()
    };
    for (i, line) in bytes.split(|&b| b == b'\n').enumerate() {
        if line.iter().all(u8::is_ascii_whitespace) {
            continue;
        }
        match serde_json::from_slice(line) {
            Ok(e) => history.entries.push(e),
            Err(_) => history.damaged.push(i + 1),
        }
    }
    history
}

/// Appends one entry: the whole line goes out in one `write` to a file opened for appending,
/// under an exclusive advisory lock, so concurrent fits never interleave their records.
pub fn append(model: &Path, entry: &Entry) -> Result<(), HistoryError> {
    let path = path_for(model);
    let mut line = serde_json::to_string(entry).map_err(|e| HistoryError::Write {
        path: path.clone(),
        source: std::io::Error::other(e),
    })?;
    line.push('\n');
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(|source| HistoryError::Write {
            path: path.clone(),
            source,
        })?;
    f.lock()
        .and_then(|()| f.write_all(line.as_bytes()))
        .and_then(|()| f.sync_data())
        .map_err(|source| HistoryError::Write { path, source })
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

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(sigma: f64) -> Entry {
        Entry {
            time: 1,
            model_hash: "h".into(),
            parameters: 3,
            rows: 10,
            sigma,
            rms: sigma,
            error_unit: "um".into(),
            files: vec![FileRms {
                path: "a.csv".into(),
                rms: sigma,
            }],
            source: None,
        }
    }

    #[test]
    fn a_non_finite_sigma_reads_back_as_nan() {
        let dir = tempfile::tempdir().unwrap();
        let model = dir.path().join("m.kin");
        append(&model, &entry(f64::INFINITY)).unwrap();
        append(&model, &entry(0.5)).unwrap();
        let h = read(&model).unwrap();
        assert!(h.damaged.is_empty(), "{h:?}");
        assert_eq!(h.entries.len(), 2);
        assert!(h.entries[0].sigma.is_nan() && h.entries[0].files[0].rms.is_nan());
        assert_eq!(h.entries[1], entry(0.5));
    }

    #[test]
    fn damaged_lines_are_skipped_and_named() {
        let good = serde_json::to_string(&entry(0.5)).unwrap();
        let text = format!("{good}\n{{\"time\": 3, \"mod\n\n{good}\nnot json\n{good}");
        let h = parse(text.as_bytes(), PathBuf::from("m.kin.history.jsonl"));
        assert_eq!(h.entries.len(), 3);
        assert_eq!(h.damaged, vec![2, 5]);
        let said = h.damage().unwrap();
        assert!(said.contains("lines 2, 5 are not"), "{said}");
    }
}

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
    #[error("cannot read the data file `{path}` to key the fit history on it: {source}")]
    Data {
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
    /// Hash of the file's contents ([`content_hash`]); absent in records written before it was
    /// kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hash: Option<String>,
    /// The RMS of the file's residuals in each display unit (µm for positions and lengths,
    /// µrad for rotations), whatever the rows were weighted by: a fit that estimates each
    /// file's σ states `rms` as a ratio to its own σ̂, which two fits do not share. Absent in
    /// records written before it was kept.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub units: Vec<UnitRms>,
}

/// A file's residual RMS over its rows of one display unit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UnitRms {
    pub unit: String,
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
    /// What the fit was made from besides the model: the data files' paths and contents and the
    /// unit of σ̂ (a stated noise changes it), hashed ([`data_key`]). Fits are compared only
    /// when this is the same. Absent in records written before it was kept: those are read and
    /// shown, but compared with nothing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub data_hash: Option<String>,
    /// Residuals of this fit binned along each variable, so that a later report can show each
    /// round's residuals as they were (bounded: [`MAX_BINS`] bins per component and variable).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub binned: Vec<Binned>,
}

/// At most this many bins per component and variable in a record's [`Binned`] residuals.
pub const MAX_BINS: usize = 16;

/// The residuals of one component along one variable, in equal-width bins of its range.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Binned {
    /// Error component (`ex` … `erz`, `dL`) and its display unit.
    pub component: String,
    pub unit: String,
    /// Axis, input or `time`, and the unit of its values.
    pub variable: String,
    pub variable_unit: String,
    /// Per bin: its centre, number of rows, mean residual and RMS residual.
    pub bins: Vec<Bin>,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Bin {
    #[serde(deserialize_with = "nan_if_null")]
    pub at: f64,
    pub rows: usize,
    #[serde(deserialize_with = "nan_if_null")]
    pub mean: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub rms: f64,
}

/// FNV-1a (64 bit) of bytes, continued from `h` (start with [`FNV_START`]).
fn fnv(mut h: u64, bytes: &[u8]) -> u64 {
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x100000001b3);
    }
    h
}

const FNV_START: u64 = 0xcbf29ce484222325;

/// A hash of a file's contents, read in blocks (a data file may be large): the same data under
/// the same name give the same hash, and an edited file a different one.
pub fn content_hash(path: &Path) -> Result<String, HistoryError> {
    let err = |source| HistoryError::Data {
        path: path.to_path_buf(),
        source,
    };
    let mut f = std::fs::File::open(path).map_err(err)?;
    let mut buf = vec![0u8; 1 << 16];
    let mut h = FNV_START;
    loop {
        let n = f.read(&mut buf).map_err(err)?;
        if n == 0 {
            break;
        }
        h = fnv(h, buf.get(..n).unwrap_or(&[]));
    }
    Ok(format!("{h:016x}"))
}

/// The key that says two fits were made of the same data: every file's path and content hash,
/// in order, and how the rows were weighted (`weighting`: at least the unit σ̂ is in).
pub fn data_key(files: &[FileRms], weighting: &str) -> Option<String> {
    let mut h = FNV_START;
    for f in files {
        h = fnv(h, f.path.as_bytes());
        h = fnv(h, &[0]);
        h = fnv(h, f.hash.as_ref()?.as_bytes());
        h = fnv(h, &[0]);
    }
    h = fnv(h, weighting.as_bytes());
    Some(format!("{h:016x}"))
}

/// How a new fit relates to the history before it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Relation<'a> {
    /// No earlier record.
    First,
    /// The last fit of the same data was of this same model: nothing changed.
    Unchanged(&'a Entry),
    /// The last fit of the same data was of another revision of the model: compare with it.
    Revised(&'a Entry),
    /// No earlier fit of these data (or of data that can be told to be the same): nothing to
    /// compare with.
    NewData,
}

/// How a fit of `model_hash` on the data `data_hash` relates to `entries`: only fits of the
/// same data are compared.
pub fn relation<'a>(
    entries: &'a [Entry],
    model_hash: &str,
    data_hash: Option<&str>,
) -> Relation<'a> {
    if entries.is_empty() {
        return Relation::First;
    }
    let same_data = data_hash.and_then(|d| {
        entries
            .iter()
            .rev()
            .find(|e| e.data_hash.as_deref() == Some(d))
    });
    match same_data {
        Some(e) if e.model_hash == model_hash => Relation::Unchanged(e),
        Some(e) => Relation::Revised(e),
        None => Relation::NewData,
    }
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
                hash: Some("0123".into()),
                units: Vec::new(),
            }],
            source: None,
            data_hash: Some("d".into()),
            binned: Vec::new(),
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

    #[test]
    fn only_fits_of_the_same_data_are_compared() {
        let mut a = entry(2.0);
        a.model_hash = "m1".into();
        let mut b = entry(1.0);
        b.model_hash = "m2".into();
        b.data_hash = Some("other".into());
        let h = vec![a.clone(), b];
        assert_eq!(relation(&h, "m2", Some("d")), Relation::Revised(&a));
        assert_eq!(relation(&h, "m1", Some("d")), Relation::Unchanged(&a));
        assert_eq!(relation(&h, "m2", Some("new")), Relation::NewData);
        assert_eq!(relation(&h, "m2", None), Relation::NewData);
        assert_eq!(relation(&[], "m2", Some("d")), Relation::First);
    }

    #[test]
    fn records_without_a_data_hash_still_read() {
        let old = r#"{"time":1,"model_hash":"h","parameters":3,"rows":10,"sigma":0.5,"rms":0.5,"error_unit":"um","files":[{"path":"a.csv","rms":0.5}]}"#;
        let h = parse(old.as_bytes(), PathBuf::from("m.kin.history.jsonl"));
        assert!(h.damaged.is_empty());
        assert_eq!(h.entries[0].data_hash, None);
        assert_eq!(h.entries[0].files[0].hash, None);
        assert_eq!(relation(&h.entries, "h", Some("d")), Relation::NewData);
        assert_eq!(data_key(&h.entries[0].files, "um"), None);
    }

    #[test]
    fn the_data_key_follows_contents_and_paths() {
        let f = |path: &str, hash: &str| FileRms {
            path: path.into(),
            rms: 1.0,
            hash: Some(hash.into()),
            units: Vec::new(),
        };
        let k = data_key(&[f("a.csv", "1")], "um");
        assert_eq!(k, data_key(&[f("a.csv", "1")], "um"));
        assert_ne!(k, data_key(&[f("a.csv", "2")], "um"));
        assert_ne!(k, data_key(&[f("b.csv", "1")], "um"));
        assert_ne!(k, data_key(&[f("a.csv", "1")], "σ (stated)"));
    }
}

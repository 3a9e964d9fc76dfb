//! What the fit history keeps of one fit (`MACHINE.history.jsonl`): its figures, the data it
//! was made of (paths and content hashes, so only fits of the same data are compared), and its
//! residuals binned along every variable, so the report can show each round as it was.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock, PoisonError};

use kin_data::history::{self, Bin, Binned, Entry, FileRms, MAX_BINS};
use kin_estimate::fit::report::FitReport;

use crate::fit::Fitted;

/// A data file's content hash (or why it could not be read), taken once per command.
type Hash = Arc<OnceLock<Result<String, String>>>;

/// The content hashes of this command's data files, by path. The hash (FNV-1a, one byte after
/// another: 0.23 s for a 231 MB file, and another function would change every recorded one)
/// is started on a thread of its own when the fit starts ([`hash_ahead`]), so that it runs
/// beside the fit instead of after it; a command that records several fits of the same files
/// (`kin diagnose --apply`) hashes them once.
fn hashes() -> &'static Mutex<HashMap<PathBuf, Hash>> {
    static HASHES: OnceLock<Mutex<HashMap<PathBuf, Hash>>> = OnceLock::new();
    HASHES.get_or_init(Mutex::default)
}

/// The slot of `path`'s hash: new (and to be filled by the caller) or already there.
fn slot(path: &Path) -> (Hash, bool) {
    let mut map = hashes().lock().unwrap_or_else(PoisonError::into_inner);
    match map.get(path) {
        Some(h) => (h.clone(), false),
        None => {
            let h = Hash::default();
            map.insert(path.to_path_buf(), h.clone());
            (h, true)
        }
    }
}

fn compute(path: &Path) -> Result<String, String> {
    history::content_hash(path).map_err(|e| e.to_string())
}

/// Starts hashing `paths` on a background thread (each file once per command): the history
/// record of the fit then finds the hashes done, or waits for the one still being taken.
pub fn hash_ahead(paths: &[PathBuf]) {
    let mut mine = Vec::new();
    for p in paths {
        let (h, new) = slot(p);
        if new {
            mine.push((p.clone(), h));
        }
    }
    if mine.is_empty() {
        return;
    }
    let spawned = std::thread::Builder::new()
        .name("kin-hash".into())
        .spawn(move || {
            for (p, h) in mine {
                h.get_or_init(|| compute(&p));
            }
        });
    // Without a thread, the record hashes each file when it needs it.
    drop(spawned);
}

/// The content hash of `path`: the one [`hash_ahead`] took (waiting for it if it is still
/// being taken), or taken now.
fn content_hash(path: &Path) -> Result<String, String> {
    let (h, _) = slot(path);
    // A thread that is hashing this file holds its `OnceLock`: `get_or_init` waits for it.
    h.get_or_init(|| compute(path)).clone()
}

/// The history record of `fitted`; `replaced` is the model's text when this revision is being
/// replaced (`--apply`). A data file that cannot be read again leaves the record without a data
/// key (compared with nothing), with a warning.
pub fn entry(fitted: &Fitted, replaced: Option<&str>) -> Entry {
    let r = &fitted.report;
    let files: Vec<FileRms> = r
        .files
        .iter()
        .zip(&fitted.files)
        .map(|(f, d)| FileRms {
            path: f.path.clone(),
            rms: f.rms,
            hash: content_hash(&d.path)
                .map_err(|e| eprintln!("warning: {e}"))
                .ok(),
            units: by_unit(f),
        })
        .collect();
    Entry {
        time: std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0),
        model_hash: r.model_hash.clone(),
        parameters: r.coefficients.iter().filter(|c| c.kept).count(),
        rows: r.rows,
        sigma: r.sigma,
        rms: r.rms,
        error_unit: crate::fit::sigma_unit(r),
        data_hash: history::data_key(&files, &weighting(r)),
        files,
        source: replaced.map(str::to_string),
        binned: binned(fitted),
    }
}

/// A file's residual RMS per display unit, from its components' RMS and rows.
fn by_unit(f: &kin_estimate::fit::report::FileSummary) -> Vec<history::UnitRms> {
    let mut out: Vec<(String, f64, usize)> = Vec::new();
    for c in &f.components {
        let at = match out.iter().position(|(u, _, _)| *u == c.unit) {
            Some(i) => i,
            None => {
                out.push((c.unit.clone(), 0.0, 0));
                out.len() - 1
            }
        };
        if let Some(u) = out.get_mut(at) {
            u.1 += c.rms * c.rms * c.rows as f64;
            u.2 += c.rows;
        }
    }
    out.into_iter()
        .filter(|(_, _, rows)| *rows > 0)
        .map(|(unit, sum, rows)| history::UnitRms {
            unit,
            rms: (sum / rows as f64).sqrt(),
        })
        .collect()
}

/// What the rows were weighted by, and how many were fitted (a `--holdout` fits part of the
/// files): fits weighted differently, or of other rows, are not compared.
fn weighting(r: &FitReport) -> String {
    let weights = match &r.weights {
        Some(w) => format!(
            "stated noise {:?} {} {:?} {}",
            w.position, w.error_unit, w.rotation, w.tilt_unit
        ),
        None => format!("unit weights {} {}", r.error_unit, r.tilt_unit),
    };
    format!("{weights}; {} rows", r.rows)
}

/// The fit's residuals (display units) binned along every axis, input and time, per component:
/// [`MAX_BINS`] equal-width bins over the values the rows take. Empty when FIT.json's residuals
/// were left out for size.
pub fn binned(fitted: &Fitted) -> Vec<Binned> {
    let m = &fitted.compiled.machine;
    let r = &fitted.report;
    let vars = crate::report::along(m);
    // Each residual with the values of every variable at its row.
    let rows: Vec<Vec<usize>> = fitted
        .files
        .iter()
        .map(|d| d.observations.rows().line.clone())
        .collect();
    let mut placed: Vec<(&str, Vec<f64>, f64)> = Vec::with_capacity(r.residuals.len());
    for res in &r.residuals {
        let (Some(d), Some(lines)) = (
            fitted.files.get(res.file as usize),
            rows.get(res.file as usize),
        ) else {
            continue;
        };
        // Lines ascend within a file: the row is found by bisection.
        let Ok(row) = lines.binary_search(&(res.line as usize)) else {
            continue;
        };
        let values = vars
            .iter()
            .map(|(_, v)| crate::report::value(&d.observations, row, *v))
            .collect();
        placed.push((res.component.as_str(), values, res.residual));
    }
    let mut components: Vec<&str> = placed.iter().map(|p| p.0).collect();
    components.sort_unstable();
    components.dedup();
    let mut out = Vec::new();
    for c in components {
        let unit = if c.starts_with("er") {
            &r.tilt_unit
        } else {
            &r.error_unit
        };
        for (k, (name, var)) in vars.iter().enumerate() {
            let vu = crate::report::var_unit(m, *var);
            let pts: Vec<(f64, f64)> = placed
                .iter()
                .filter(|p| p.0 == c)
                .filter_map(|p| p.1.get(k).map(|x| (vu.from_si(*x), p.2)))
                .filter(|(x, _)| x.is_finite())
                .collect();
            if let Some(bins) = bin(&pts) {
                out.push(Binned {
                    component: c.to_string(),
                    unit: unit.clone(),
                    variable: name.clone(),
                    variable_unit: vu.name.clone(),
                    bins,
                });
            }
        }
    }
    out
}

/// Equal-width bins of `(x, residual)` over the range of x; `None` when x does not vary.
fn bin(pts: &[(f64, f64)]) -> Option<Vec<Bin>> {
    let (lo, hi) = pts
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (x, _)| {
            (lo.min(*x), hi.max(*x))
        });
    // No points (lo = ∞) or one value: nothing to bin (x is finite here).
    if hi <= lo {
        return None;
    }
    let width = (hi - lo) / MAX_BINS as f64;
    let mut sums = [(0usize, 0.0f64, 0.0f64); MAX_BINS];
    for (x, y) in pts {
        // The top of the range belongs to the last bin.
        let k = (((x - lo) / width) as usize).min(MAX_BINS - 1);
        if let Some(s) = sums.get_mut(k) {
            s.0 += 1;
            s.1 += y;
            s.2 += y * y;
        }
    }
    Some(
        sums.iter()
            .enumerate()
            .filter(|(_, s)| s.0 > 0)
            .map(|(k, s)| Bin {
                at: round(lo + (k as f64 + 0.5) * width),
                rows: s.0,
                mean: round(s.1 / s.0 as f64),
                rms: round((s.2 / s.0 as f64).sqrt()),
            })
            .collect(),
    )
}

/// Four significant digits: what a plot can show, at a third of the record's size.
fn round(v: f64) -> f64 {
    format!("{v:.3e}").parse().unwrap_or(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_cover_the_range_and_hold_every_point() {
        let pts: Vec<(f64, f64)> = (0..=100)
            .map(|i| (i as f64, if i < 50 { 1.0 } else { -1.0 }))
            .collect();
        let b = bin(&pts).unwrap();
        assert_eq!(b.len(), MAX_BINS);
        assert_eq!(b.iter().map(|b| b.rows).sum::<usize>(), 101);
        assert!((b[0].mean - 1.0).abs() < 1e-12 && (b[MAX_BINS - 1].mean + 1.0).abs() < 1e-12);
        assert!(bin(&[(1.0, 2.0), (1.0, 3.0)]).is_none());
        assert!(bin(&[]).is_none());
    }

    /// A hash taken ahead is the file's content hash; a file that cannot be read gives its
    /// reason; a path never started is hashed when asked.
    #[test]
    fn hashes_taken_ahead_are_the_content_hashes() {
        let dir = std::env::temp_dir().join(format!("kin-rounds-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let a = dir.join("a.csv");
        let b = dir.join("b.csv");
        std::fs::write(&a, "X[mm],ex[um]\n1,2\n".repeat(5000)).unwrap();
        std::fs::write(&b, "X[mm],ex[um]\n3,4\n").unwrap();
        let missing = dir.join("missing.csv");
        hash_ahead(&[a.clone(), missing.clone()]);
        assert_eq!(content_hash(&a), Ok(history::content_hash(&a).unwrap()));
        assert!(content_hash(&missing).is_err());
        assert_eq!(content_hash(&b), Ok(history::content_hash(&b).unwrap()));
        assert_ne!(content_hash(&a), content_hash(&b));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

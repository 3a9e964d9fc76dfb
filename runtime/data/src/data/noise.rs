//! A file's stated noise (spec/data.md, "The instrument's noise"): comment lines before the
//! header of the form `# noise: 0.1 um` (positions and lengths) and `# noise-tilt: 2 urad`
//! (rotations). Only a comment whose text starts with the key and a colon is read this way;
//! every other comment stays a comment (`# noise 0.2um` from `kin simulate` among them).

use std::path::{Path, PathBuf};

use kin_compiler::units::{Dim, Unit};
use thiserror::Error;

/// The σs a file states for its own rows, SI.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StatedNoise {
    /// Positions and lengths, m.
    pub position: Option<f64>,
    /// Rotations, rad.
    pub rotation: Option<f64>,
}

impl StatedNoise {
    pub fn is_empty(&self) -> bool {
        self.position.is_none() && self.rotation.is_none()
    }
}

#[derive(Debug, Error, PartialEq)]
pub enum NoiseHeaderError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: IoText,
    },
    #[error("{}, line {line}, column {column}: {message}", path.display())]
    Value {
        path: PathBuf,
        line: usize,
        column: usize,
        message: String,
    },
}

/// An I/O error as text (comparable in tests).
#[derive(Debug, Error, PartialEq)]
#[error("{0}")]
pub struct IoText(String);

/// The keys, the dimension of their value and what they set.
const KEYS: [(&str, Dim, bool); 2] = [
    ("noise-tilt", Dim::ANGLE, true),
    ("noise", Dim::LENGTH, false),
];

/// Reads the stated noise from the comments before the header of the file at `path` (only
/// those lines are read: a file of gigabytes costs its first lines).
pub fn stated_noise(path: &Path) -> Result<StatedNoise, NoiseHeaderError> {
    use std::io::BufRead;
    let io = |e: std::io::Error| NoiseHeaderError::Io {
        path: path.to_path_buf(),
        source: IoText(e.to_string()),
    };
    let mut reader = std::io::BufReader::new(std::fs::File::open(path).map_err(io)?);
    let mut head = String::new();
    let mut line = Vec::new();
    loop {
        line.clear();
        if reader.read_until(b'\n', &mut line).map_err(io)? == 0 {
            break;
        }
        // A bad byte is the table reader's to report, with its place.
        let text = String::from_utf8_lossy(&line);
        head.push_str(&text);
        let t = text.trim_start_matches('\u{feff}').trim_start();
        if !(t.is_empty() || t.starts_with('#')) {
            break;
        }
    }
    parse(path, &head)
}

/// [`stated_noise`] of a file's text.
pub fn parse(path: &Path, text: &str) -> Result<StatedNoise, NoiseHeaderError> {
    let mut out = StatedNoise::default();
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    for (i, line) in text.lines().enumerate() {
        let t = line.trim_start();
        if t.is_empty() {
            continue;
        }
        let Some(comment) = t.strip_prefix('#') else {
            // The header: the noise is stated above it.
            break;
        };
        let body = comment.trim_start();
        let Some((key, dim, tilt, value)) = KEYS.iter().find_map(|&(key, dim, tilt)| {
            let rest = body.strip_prefix(key)?.trim_start();
            Some((key, dim, tilt, rest.strip_prefix(':')?))
        }) else {
            continue;
        };
        // The column (1-based, in characters) where the value starts.
        let start = line.len() - value.trim_start().len();
        let column = line[..start].chars().count() + 1;
        let bad = |message: String| NoiseHeaderError::Value {
            path: path.to_path_buf(),
            line: i + 1,
            column,
            message,
        };
        let si = quantity(value.trim(), dim).map_err(|m| bad(format!("`{key}:` {m}")))?;
        if !(si.is_finite() && si > 0.0) {
            return Err(bad(format!(
                "`{key}:` `{}` is not a standard deviation above 0",
                value.trim()
            )));
        }
        let slot = if tilt {
            &mut out.rotation
        } else {
            &mut out.position
        };
        if slot.is_some() {
            return Err(bad(format!("`{key}:` is stated twice")));
        }
        *slot = Some(si);
    }
    Ok(out)
}

/// A number and its unit (`0.1 um`, `0.1um`) in SI, of dimension `dim`.
fn quantity(text: &str, dim: Dim) -> Result<f64, String> {
    let split = text
        .find(|c: char| {
            !(c.is_ascii_digit() || c == '.' || c == '-' || c == '+' || c == 'e' || c == 'E')
        })
        .unwrap_or(text.len());
    let (num, unit) = text.split_at(split);
    let value: f64 = num
        .parse()
        .map_err(|_| format!("`{text}` does not start with a number"))?;
    let unit = Unit::parse(unit.trim()).map_err(|e| format!("{e} in `{text}`"))?;
    if unit.dim != dim {
        return Err(format!(
            "`{text}` is {}, expected {}",
            unit.dim.describe(),
            dim.describe()
        ));
    }
    Ok(unit.as_difference().to_si(value))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> Result<StatedNoise, NoiseHeaderError> {
        parse(Path::new("f.csv"), text)
    }

    #[test]
    fn the_noise_above_the_header_is_read_in_si() {
        let n = read("# laser\n# noise: 0.1 um\n#noise-tilt:2urad\nX[mm],ex[um]\n1,2\n");
        let n = n.unwrap_or_else(|e| panic!("{e}"));
        assert!(n.position.is_some_and(|v| (v - 1e-7).abs() < 1e-20));
        assert!(n.rotation.is_some_and(|v| (v - 2e-6).abs() < 1e-19));
    }

    #[test]
    fn other_comments_and_lines_below_the_header_are_not_read() {
        // `kin simulate` writes `# noise 0.2um (positions), …` (no colon): a comment.
        let n = read("# noise 0.2um (positions), 0 (rotations)\nX[mm],ex[um]\n# noise: 1 um\n");
        assert_eq!(n, Ok(StatedNoise::default()));
    }

    #[test]
    fn a_bad_value_is_located() {
        let e = read("# a\n# noise: 0.1 urad\nX[mm]\n");
        assert!(
            matches!(
                &e,
                Err(NoiseHeaderError::Value {
                    line: 2,
                    column: 10,
                    ..
                })
            ),
            "{e:?}"
        );
        let e = read("# noise: 0 um\nX[mm]\n");
        assert!(
            matches!(&e, Err(NoiseHeaderError::Value { line: 1, .. })),
            "{e:?}"
        );
        let e = read("# noise: 1 um\n# noise: 2 um\nX[mm]\n");
        assert!(
            matches!(&e, Err(NoiseHeaderError::Value { line: 2, .. })),
            "{e:?}"
        );
        let e = read("# noise: fast\nX[mm]\n");
        assert!(
            matches!(
                &e,
                Err(NoiseHeaderError::Value {
                    line: 1,
                    column: 10,
                    ..
                })
            ),
            "{e:?}"
        );
    }
}

//! Option values checked as the command line is parsed: every number a command takes is
//! validated here, once, so a NaN, an infinity, a negative or an out-of-range value stops with a
//! message naming the option and what it accepts (clap prefixes the option's name; exit 2)
//! instead of being ignored or reaching code that would misbehave on it.

use std::path::PathBuf;

use kin_compiler::units::Dim;

/// At most this many poses for `kin simulate --sample` and `kin bench --poses`: every pose is
/// held in memory with its axes, directions and inputs (some 100 bytes for a five-axis machine),
/// so 10⁸ is already ~10 GB — more than that is a typo, not a measurement plan.
pub const MAX_POSES: usize = 100_000_000;

/// At most this many seconds per figure of `kin bench` (a day is a generous upper bound; beyond
/// it the timer's arithmetic would overflow before anything useful was measured).
pub const MAX_SECONDS: f64 = 86_400.0;

/// At most this many rounds of `kin demo`: each adds one effect, and the bundled data hide two.
pub const MAX_ROUNDS: usize = 100;

/// A finite number for which `ok` holds; otherwise a message ending with what is `allowed`.
fn number(text: &str, allowed: &str, ok: impl Fn(f64) -> bool) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && ok(v) => Ok(v),
        Ok(v) if v.is_finite() => Err(format!("{v} is outside the allowed range: {allowed}")),
        Ok(_) => Err(format!("`{text}` is not a finite number: {allowed}")),
        Err(_) => Err(format!("`{text}` is not a number: {allowed}")),
    }
}

/// A fraction strictly between 0 and 1 (`--holdout`).
pub fn fraction(text: &str) -> Result<f64, String> {
    number(text, "a fraction with 0 < F < 1", |v| v > 0.0 && v < 1.0)
}

/// A significance level strictly between 0 and 1 (`--stepwise`, `--enter`, `--alpha`).
pub fn level(text: &str) -> Result<f64, String> {
    number(text, "a significance level with 0 < α < 1", |v| {
        v > 0.0 && v < 1.0
    })
}

/// The rank decision's relative tolerance (`--tolerance`): above zero and below one, since a
/// direction is unseen when its singular value is below T times the largest (at 1 or more no
/// direction could be seen).
pub fn tolerance(text: &str) -> Result<f64, String> {
    number(text, "a tolerance with 0 < T < 1", |v| v > 0.0 && v < 1.0)
}

/// Seconds per figure of `kin bench`: finite, above zero, at most a day.
pub fn seconds(text: &str) -> Result<f64, String> {
    number(text, &format!("0 < S ≤ {MAX_SECONDS}"), |v| {
        v > 0.0 && v <= MAX_SECONDS
    })
}

fn count(text: &str, min: usize, max: usize) -> Result<usize, String> {
    let n: usize = text
        .trim()
        .parse()
        .map_err(|_| format!("`{text}` is not a whole number from {min} to {max}"))?;
    if (min..=max).contains(&n) {
        Ok(n)
    } else {
        Err(format!(
            "{n} is outside the allowed range: {min} ≤ N ≤ {max}"
        ))
    }
}

/// A number of poses (`kin simulate --sample`, `kin bench --poses`): 1 to [`MAX_POSES`].
pub fn poses(text: &str) -> Result<usize, String> {
    count(text, 1, MAX_POSES)
}

/// Threads of a fit (`kin fit --threads`): 1 to 256.
pub fn threads(text: &str) -> Result<usize, String> {
    count(text, 1, 256)
}

/// The number of rounds of `kin demo`: 0 (fit and diagnose only) to [`MAX_ROUNDS`].
pub fn rounds(text: &str) -> Result<usize, String> {
    count(text, 0, MAX_ROUNDS)
}

/// A standard deviation with its unit, as written and in SI.
#[derive(Debug, Clone, PartialEq)]
pub struct Spread {
    pub text: String,
    pub si: f64,
}

/// `--noise Q` (every file) or `--noise FILE=Q` (one data file's positions and lengths).
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseArg {
    pub file: Option<PathBuf>,
    pub spread: Spread,
}

/// A `--noise` value: a σ above 0, for every file or, as `FILE=Q`, for one (the last `=`
/// separates them: a quantity holds none).
pub fn noise_arg(text: &str) -> Result<NoiseArg, String> {
    match text.rsplit_once('=') {
        Some((file, q)) if !file.is_empty() => Ok(NoiseArg {
            file: Some(PathBuf::from(file)),
            spread: stated_length_noise(q)?,
        }),
        _ => Ok(NoiseArg {
            file: None,
            spread: stated_length_noise(text.trim_start_matches('='))?,
        }),
    }
}

/// `--noise FILE=Q` values: each file with its σ.
pub type FileNoise = Vec<(PathBuf, Spread)>;

/// The σ for every file (at most one) and the per-file ones of repeated `--noise`.
pub fn split_noise(args: Vec<NoiseArg>) -> Result<(Option<Spread>, FileNoise), String> {
    let mut all = None;
    let mut files = Vec::new();
    for a in args {
        match a.file {
            Some(f) => files.push((f, a.spread)),
            None if all.is_some() => {
                return Err("--noise for every file is given twice".into());
            }
            None => all = Some(a.spread),
        }
    }
    Ok((all, files))
}

/// A positive duration with its unit, e.g. `1min`, `30 s` (`kin simulate --every`).
pub fn duration(text: &str) -> Result<Spread, String> {
    let s = spread(text, Dim::TIME)?;
    if s.si > 0.0 {
        Ok(s)
    } else {
        Err(format!(
            "`{text}`: expected a positive duration, e.g. `1min`"
        ))
    }
}

fn spread(text: &str, dim: Dim) -> Result<Spread, String> {
    let si = crate::load::quantity(text, dim)?;
    if !si.is_finite() {
        return Err(format!("`{text}` is not finite"));
    }
    if si < 0.0 {
        return Err(format!("`{text}` is negative: a standard deviation is ≥ 0"));
    }
    Ok(Spread {
        text: text.to_string(),
        si,
    })
}

/// A circle's nominal radius: a length above 0 and at most 10 km (`kin iso230-4 --radius`).
pub fn radius(text: &str) -> Result<f64, String> {
    let v = crate::load::quantity(text, Dim::LENGTH)?;
    if v.is_finite() && v > 0.0 && v <= 1e4 {
        Ok(v)
    } else {
        Err(format!("`{text}`: a radius is above 0 and at most 10 km"))
    }
}

/// A confidence level in percent, 0 < L < 100 (`--ellipsoid 95`), as a fraction.
pub fn percent(text: &str) -> Result<f64, String> {
    number(text, "a level in percent with 0 < L < 100", |v| {
        v > 0.0 && v < 100.0
    })
    .map(|v| v / 100.0)
}

/// A point `x,y,z` of three lengths, each in mm unless it names its unit (`--sphere 0,0,50`,
/// `--sphere 0mm,0mm,2in`).
pub fn point(text: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = text.split(',').collect();
    let [x, y, z] = parts.as_slice() else {
        return Err(format!("`{text}`: expected three lengths x,y,z"));
    };
    let mut out = [0.0; 3];
    for (slot, part) in out.iter_mut().zip([x, y, z]) {
        let part = part.trim();
        let with_unit = if part.ends_with(|c: char| c.is_ascii_digit() || c == '.') {
            format!("{part}mm")
        } else {
            part.to_string()
        };
        let v = crate::load::quantity(&with_unit, Dim::LENGTH)?;
        if !v.is_finite() || v.abs() > 1e4 {
            return Err(format!("`{part}` is not a length within 10 km"));
        }
        *slot = v;
    }
    Ok(out)
}

/// A length standard deviation, finite and ≥ 0 (`--noise 0.3um`, `--artifact-shift`,
/// `--artifact-length`).
pub fn length_spread(text: &str) -> Result<Spread, String> {
    spread(text, Dim::LENGTH)
}

/// An angle standard deviation, finite and ≥ 0 (`--noise-tilt 1urad`, `--artifact-rotation`).
pub fn angle_spread(text: &str) -> Result<Spread, String> {
    spread(text, Dim::ANGLE)
}

/// A stated instrument noise must be above zero: the residuals are divided by it.
fn stated(spread: Spread) -> Result<Spread, String> {
    if spread.si > 0.0 {
        Ok(spread)
    } else {
        Err(format!("`{}` is zero: a stated noise is > 0", spread.text))
    }
}

/// The instrument's noise on positions and lengths, > 0 (`kin diagnose --noise`).
pub fn stated_length_noise(text: &str) -> Result<Spread, String> {
    stated(length_spread(text)?)
}

/// The instrument's noise on rotations, > 0 (`kin diagnose --noise-tilt`).
pub fn stated_angle_noise(text: &str) -> Result<Spread, String> {
    stated(angle_spread(text)?)
}

/// How the measurement files of a command are read (`--ignore`, `--delimiter`).
#[derive(Clone, Debug, Default)]
pub struct DataOptions {
    /// Columns to skip unread.
    pub ignore: Vec<String>,
    /// The field separator, when not detected from the header.
    pub delimiter: Option<u8>,
    /// Threads reading each file (`kin fit --threads`); every core when `None`.
    pub threads: Option<usize>,
}

impl DataOptions {
    /// The reader's options; `poses`: observed columns may be absent.
    pub fn read(&self, poses: bool) -> kin_data::data::ReadOptions {
        kin_data::data::ReadOptions {
            poses,
            ignore: self.ignore.clone(),
            delimiter: self.delimiter,
            series: false,
            threads: self.threads,
        }
    }
}

/// `--delimiter`: `,`, `;`, `tab` (or a tab character) — the separators spec/data.md allows.
pub fn delimiter(text: &str) -> Result<u8, String> {
    match text {
        "," | "comma" => Ok(b','),
        ";" | "semicolon" => Ok(b';'),
        // A tab character, or `\t` as typed in a shell.
        "\t" | "\\t" | "tab" => Ok(b'\t'),
        _ => Err(format!(
            "`{text}` is not a separator kin reads: `,`, `;` or `tab` (spec/data.md)"
        )),
    }
}

/// `--color`: whether diagnostics on standard error are coloured.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Color {
    /// Colour only when standard error is a terminal and `NO_COLOR` is unset or empty.
    #[default]
    Auto,
    Always,
    Never,
}

impl Color {
    pub fn enabled(self) -> bool {
        use std::io::IsTerminal;
        match self {
            Color::Always => true,
            Color::Never => false,
            Color::Auto => {
                !no_color(std::env::var_os("NO_COLOR")) && std::io::stderr().is_terminal()
            }
        }
    }
}

/// The `NO_COLOR` convention (no-color.org): present and not empty turns automatic colour off;
/// an explicit `--color always` still wins, as the convention asks.
fn no_color(value: Option<std::ffi::OsString>) -> bool {
    value.is_some_and(|v| !v.is_empty())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delimiters_are_the_three_the_format_allows() {
        assert_eq!(delimiter(","), Ok(b','));
        assert_eq!(delimiter(";"), Ok(b';'));
        assert_eq!(delimiter("tab"), Ok(b'\t'));
        assert_eq!(delimiter("\t"), Ok(b'\t'));
        assert_eq!(delimiter("\\t"), Ok(b'\t'));
        for bad in ["", "|", ",,", " "] {
            assert!(delimiter(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn no_color_counts_only_when_set_and_not_empty() {
        assert!(!no_color(None));
        assert!(!no_color(Some("".into())));
        assert!(no_color(Some("1".into())));
        assert!(no_color(Some("0".into())));
    }

    #[test]
    fn fractions_and_levels_exclude_their_ends_and_non_numbers() {
        for bad in [
            "NaN", "nan", "inf", "-inf", "-0.5", "0", "1", "1.5", "x", "",
        ] {
            assert!(fraction(bad).is_err(), "{bad}");
            assert!(level(bad).is_err(), "{bad}");
        }
        assert_eq!(fraction("0.25"), Ok(0.25));
        assert_eq!(level("1e-4"), Ok(1e-4));
    }

    #[test]
    fn counts_are_bounded() {
        assert!(poses("18446744073709551615").is_err());
        assert!(poses("100000001").is_err());
        assert!(poses("0").is_err());
        assert!(poses("-3").is_err());
        assert_eq!(poses("100000000"), Ok(MAX_POSES));
        assert_eq!(rounds("0"), Ok(0));
        assert!(rounds("101").is_err());
    }

    #[test]
    fn tolerances_and_seconds_are_finite_and_positive() {
        for bad in ["NaN", "inf", "0", "-1e-10"] {
            assert!(tolerance(bad).is_err(), "{bad}");
            assert!(seconds(bad).is_err(), "{bad}");
        }
        assert!(seconds("1e300").is_err());
        assert_eq!(tolerance("1e-10"), Ok(1e-10));
        assert!(tolerance("1").is_err());
    }

    #[test]
    fn spreads_are_finite_non_negative_and_of_their_dimension() {
        assert!(length_spread("-0.3um").is_err());
        assert!(length_spread("1e400um").is_err());
        assert!(length_spread("NaN um").is_err());
        assert!(length_spread("1urad").is_err());
        assert!(angle_spread("1um").is_err());
        let s = length_spread("0.3um").map(|s| s.si);
        assert!(matches!(s, Ok(v) if (v - 3e-7).abs() < 1e-18));
        assert_eq!(angle_spread("0urad").map(|s| s.si), Ok(0.0));
        // A bare number is refused with the unit it needs, not as "empty unit".
        let bare = length_spread("0.3").map(|s| s.si);
        assert!(
            matches!(&bare, Err(e) if e.contains("has no unit") && e.contains("`0.3um`")),
            "{bare:?}"
        );
    }
}

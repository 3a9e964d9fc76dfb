//! Physical dimensions and units: parsing unit text, conversion to SI, and dimension algebra.
//!
//! Unit text is a product of atoms with integer powers: `um/m/K`, `urad/N`, `mm^2`, `1/s`.
//! Division binds left to right (`um/m/K` is `um / (m · K)`), as it is read aloud. Every unit
//! has a canonical name: factors of the same atom merged, positive powers first, then each
//! negative power as `/atom^n`, with `u` for the micro prefix.

use std::fmt;
use std::ops::{Div, Mul};
use std::str::FromStr;

use serde::{Deserialize, Serialize};
use thiserror::Error;

/// Exponents of the base dimensions. Angle is a base dimension on purpose: it lets the checker
/// tell a rotation error from a translation error (a `urad` is not a `um/m` here).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Dim {
    pub length: i8,
    pub angle: i8,
    pub time: i8,
    pub temperature: i8,
    pub force: i8,
}

/// A unit: a dimension, the factor to SI, and (absolute temperatures only) the offset to SI.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Unit {
    /// Canonical text, e.g. `um/m/K`.
    pub name: String,
    pub dim: Dim,
    pub scale: f64,
    pub offset: f64,
}

/// Why unit text could not be read. Offsets are byte offsets into the text, so a caller can
/// turn them into a span inside a larger source.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum UnitError {
    #[error("empty unit")]
    Empty,
    #[error("unknown unit `{name}`")]
    UnknownAtom { name: String, offset: usize },
    #[error("expected {expected}, found `{found}`")]
    Unexpected {
        expected: &'static str,
        found: String,
        offset: usize,
    },
    #[error("expected {expected} at the end of the unit")]
    UnexpectedEnd { expected: &'static str },
    #[error("exponent `{text}` is out of range")]
    ExponentRange { text: String, offset: usize },
}

/// Names of the base dimensions, in field order, with their SI unit.
const BASES: [(&str, &str); 5] = [
    ("length", "m"),
    ("angle", "rad"),
    ("time", "s"),
    ("temperature", "K"),
    ("force", "N"),
];

impl Dim {
    pub const DIMENSIONLESS: Dim = Dim {
        length: 0,
        angle: 0,
        time: 0,
        temperature: 0,
        force: 0,
    };
    pub const LENGTH: Dim = Dim {
        length: 1,
        ..Dim::DIMENSIONLESS
    };
    pub const ANGLE: Dim = Dim {
        angle: 1,
        ..Dim::DIMENSIONLESS
    };
    pub const TIME: Dim = Dim {
        time: 1,
        ..Dim::DIMENSIONLESS
    };
    pub const TEMPERATURE: Dim = Dim {
        temperature: 1,
        ..Dim::DIMENSIONLESS
    };
    pub const FORCE: Dim = Dim {
        force: 1,
        ..Dim::DIMENSIONLESS
    };
    /// Angular speed (a spindle's speed): angle per time.
    pub const SPEED: Dim = Dim {
        angle: 1,
        time: -1,
        ..Dim::DIMENSIONLESS
    };
    /// Linear speed (an axis' feed rate): length per time.
    pub const VELOCITY: Dim = Dim {
        length: 1,
        time: -1,
        ..Dim::DIMENSIONLESS
    };
    /// Power (a heat source, a motor's electrical power): force times length per time.
    pub const POWER: Dim = Dim {
        length: 1,
        time: -1,
        force: 1,
        ..Dim::DIMENSIONLESS
    };

    fn exponents(self) -> [i8; 5] {
        [
            self.length,
            self.angle,
            self.time,
            self.temperature,
            self.force,
        ]
    }

    fn from_exponents(e: [i8; 5]) -> Dim {
        Dim {
            length: e[0],
            angle: e[1],
            time: e[2],
            temperature: e[3],
            force: e[4],
        }
    }

    fn zip(self, other: Dim, f: impl Fn(i8, i8) -> i8) -> Dim {
        let (a, b) = (self.exponents(), other.exponents());
        Dim::from_exponents(std::array::from_fn(|i| f(a[i], b[i])))
    }

    pub fn is_dimensionless(self) -> bool {
        self == Dim::DIMENSIONLESS
    }

    /// Saturates rather than wraps: no real unit comes near ±127, and a saturated exponent still
    /// compares unequal to any sensible dimension, so the checker reports it instead of crashing.
    pub fn powi(self, n: i32) -> Dim {
        let e = self.exponents();
        Dim::from_exponents(e.map(|x| saturate(i32::from(x).saturating_mul(n))))
    }

    /// Human text for diagnostics: `length`, `angle/force`, `length^2`, `1/time`,
    /// `dimensionless`.
    pub fn describe(self) -> String {
        if self.is_dimensionless() {
            return "dimensionless".to_string();
        }
        let parts = self
            .exponents()
            .into_iter()
            .zip(BASES)
            .map(|(e, (name, _))| (name, i32::from(e)));
        render(parts)
    }
}

fn saturate(x: i32) -> i8 {
    i8::try_from(x).unwrap_or(if x < 0 { i8::MIN } else { i8::MAX })
}

/// Writes `a*b^2/c/d^3` from named powers; zero powers are left out, and a quotient with no
/// numerator starts with `1`.
fn render<'a>(parts: impl Iterator<Item = (&'a str, i32)> + Clone) -> String {
    let mut text = String::new();
    for (name, e) in parts.clone().filter(|&(_, e)| e > 0) {
        if !text.is_empty() {
            text.push('*');
        }
        push_power(&mut text, name, e);
    }
    if text.is_empty() {
        text.push('1');
    }
    for (name, e) in parts.filter(|&(_, e)| e < 0) {
        text.push('/');
        push_power(&mut text, name, e.saturating_neg());
    }
    text
}

fn push_power(text: &mut String, name: &str, e: i32) {
    text.push_str(name);
    if e != 1 {
        text.push('^');
        text.push_str(&e.to_string());
    }
}

impl Mul for Dim {
    type Output = Dim;
    fn mul(self, other: Dim) -> Dim {
        self.zip(other, i8::saturating_add)
    }
}

impl Div for Dim {
    type Output = Dim;
    fn div(self, other: Dim) -> Dim {
        self.zip(other, i8::saturating_sub)
    }
}

impl fmt::Display for Dim {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.describe())
    }
}

struct Atom {
    name: &'static str,
    dim: Dim,
    scale: f64,
}

const fn atom(name: &'static str, dim: Dim, scale: f64) -> Atom {
    Atom { name, dim, scale }
}

const ATOMS: [Atom; 21] = [
    atom("nm", Dim::LENGTH, 1e-9),
    atom("um", Dim::LENGTH, 1e-6),
    atom("mm", Dim::LENGTH, 1e-3),
    atom("m", Dim::LENGTH, 1.0),
    atom("urad", Dim::ANGLE, 1e-6),
    atom("mrad", Dim::ANGLE, 1e-3),
    atom("rad", Dim::ANGLE, 1.0),
    atom("deg", Dim::ANGLE, std::f64::consts::PI / 180.0),
    atom("arcsec", Dim::ANGLE, std::f64::consts::PI / 648_000.0),
    atom("s", Dim::TIME, 1.0),
    atom("min", Dim::TIME, 60.0),
    atom("h", Dim::TIME, 3600.0),
    atom("degC", Dim::TEMPERATURE, 1.0),
    atom("K", Dim::TEMPERATURE, 1.0),
    atom("N", Dim::FORCE, 1.0),
    atom("kN", Dim::FORCE, 1000.0),
    // One revolution is 2π rad, so `rev/min` and `rpm` are the same speed.
    atom("rev", Dim::ANGLE, std::f64::consts::TAU),
    atom("rpm", Dim::SPEED, std::f64::consts::TAU / 60.0),
    atom("W", Dim::POWER, 1.0),
    atom("kW", Dim::POWER, 1000.0),
    atom("1", Dim::DIMENSIONLESS, 1.0),
];

/// Offset from Celsius to kelvin; applies only to `degC` standing alone as an absolute
/// temperature, since a difference of 1 degC is a difference of 1 K.
const CELSIUS_OFFSET: f64 = 273.15;

/// Looked up by name so the table can be reordered safely.
fn is_celsius(index: usize) -> bool {
    ATOMS.get(index).is_some_and(|a| a.name == "degC")
}

/// Both the micro sign (U+00B5) and the Greek mu (U+03BC) are typed for "micro"; both mean `u`.
fn canonical_atom_name(name: &str) -> Option<usize> {
    let ascii;
    let name = match name
        .strip_prefix('\u{b5}')
        .or_else(|| name.strip_prefix('\u{3bc}'))
    {
        Some(rest) => {
            ascii = format!("u{rest}");
            ascii.as_str()
        }
        None => name,
    };
    ATOMS.iter().position(|a| a.name == name)
}

/// A unit as parsed: atoms (indices into `ATOMS`) with merged integer powers, in order of first
/// appearance. The name, dimension and scale all derive from this.
#[derive(Debug, Clone, Default, PartialEq)]
struct Factors(Vec<(usize, i32)>);

impl Factors {
    fn push(&mut self, atom: usize, power: i32) {
        if ATOMS.get(atom).is_some_and(|a| a.name == "1") {
            return;
        }
        match self.0.iter_mut().find(|(a, _)| *a == atom) {
            Some((_, p)) => *p = p.saturating_add(power),
            None => self.0.push((atom, power)),
        }
    }

    fn extend(&mut self, other: &Factors, sign: i32) {
        for &(a, p) in &other.0 {
            self.push(a, p.saturating_mul(sign));
        }
    }

    fn name(&self) -> String {
        render(
            self.0
                .iter()
                .filter_map(|&(a, p)| ATOMS.get(a).map(|atom| (atom.name, p))),
        )
    }

    /// Judged on what the canonical name shows (zero powers vanish from it), so that a name
    /// always reads back as the same unit.
    fn is_absolute_celsius(&self) -> bool {
        let mut shown = self.0.iter().filter(|(_, p)| *p != 0);
        matches!((shown.next(), shown.next()), (Some(&(a, 1)), None) if is_celsius(a))
    }

    /// Numerator and denominator are multiplied separately and divided once, so `um/m` gives
    /// exactly `1e-6` rather than accumulating a rounding per factor.
    fn to_unit(&self) -> Unit {
        let mut dim = Dim::DIMENSIONLESS;
        let (mut num, mut den) = (1.0_f64, 1.0_f64);
        for &(a, p) in &self.0 {
            let Some(atom) = ATOMS.get(a) else { continue };
            dim = dim * atom.dim.powi(p);
            if p > 0 {
                num *= atom.scale.powi(p);
            } else {
                den *= atom.scale.powi(p.saturating_neg());
            }
        }
        let offset = if self.is_absolute_celsius() {
            CELSIUS_OFFSET
        } else {
            0.0
        };
        Unit {
            name: self.name(),
            dim,
            scale: num / den,
            offset,
        }
    }
}

/// Recursive descent over `factor (('*' | '/') factor)*`, `factor = atom ('^' integer)?`.
struct Parser<'a> {
    text: &'a str,
    pos: usize,
}

impl<'a> Parser<'a> {
    fn rest(&self) -> &'a str {
        self.text.get(self.pos..).unwrap_or("")
    }

    fn skip_space(&mut self) {
        let rest = self.rest();
        self.pos += rest.len() - rest.trim_start().len();
    }

    fn peek(&self) -> Option<char> {
        self.rest().chars().next()
    }

    /// The offending token for a message: a run of letters/digits, or one character.
    fn found(&self) -> String {
        let rest = self.rest();
        let word: String = rest.chars().take_while(|c| c.is_alphanumeric()).collect();
        if word.is_empty() {
            rest.chars().next().map(String::from).unwrap_or_default()
        } else {
            word
        }
    }

    fn unexpected(&self, expected: &'static str) -> UnitError {
        if self.rest().is_empty() {
            UnitError::UnexpectedEnd { expected }
        } else {
            UnitError::Unexpected {
                expected,
                found: self.found(),
                offset: self.pos,
            }
        }
    }

    fn parse(mut self) -> Result<Factors, UnitError> {
        self.skip_space();
        if self.rest().is_empty() {
            return Err(UnitError::Empty);
        }
        let mut factors = Factors::default();
        let (atom, power) = self.factor()?;
        factors.push(atom, power);
        loop {
            self.skip_space();
            let sign = match self.peek() {
                None => return Ok(factors),
                Some('*') => 1,
                Some('/') => -1,
                Some(_) => return Err(self.unexpected("`*`, `/` or `^`")),
            };
            self.pos += 1;
            self.skip_space();
            let (atom, power) = self.factor()?;
            factors.push(atom, power.saturating_mul(sign));
        }
    }

    fn factor(&mut self) -> Result<(usize, i32), UnitError> {
        let start = self.pos;
        let rest = self.rest();
        let len: usize = rest
            .chars()
            .take_while(|&c| c.is_alphabetic() || c == '1')
            .map(char::len_utf8)
            .sum();
        if len == 0 {
            return Err(self.unexpected("a unit"));
        }
        let name = rest.get(..len).unwrap_or("");
        let atom = canonical_atom_name(name).ok_or_else(|| UnitError::UnknownAtom {
            name: name.to_string(),
            offset: start,
        })?;
        self.pos += len;
        self.skip_space();
        if self.peek() != Some('^') {
            return Ok((atom, 1));
        }
        self.pos += 1;
        self.skip_space();
        let exp_start = self.pos;
        let rest = self.rest();
        let sign_len = usize::from(rest.starts_with(['-', '+']));
        let digits = rest
            .get(sign_len..)
            .unwrap_or("")
            .bytes()
            .take_while(u8::is_ascii_digit)
            .count();
        if digits == 0 {
            return Err(self.unexpected("an integer exponent"));
        }
        let text = rest.get(..sign_len + digits).unwrap_or("");
        self.pos += sign_len + digits;
        // Powers beyond ±127 cannot be held by `Dim` and mean nothing physically.
        let power = text.parse::<i8>().map_err(|_| UnitError::ExponentRange {
            text: text.to_string(),
            offset: exp_start,
        })?;
        Ok((atom, i32::from(power)))
    }
}

impl Unit {
    /// Canonical names of the atoms unit text is built from, for "did you mean" suggestions.
    pub(crate) const ATOM_NAMES: [&'static str; 21] = {
        let mut names = [""; 21];
        let mut i = 0;
        while i < ATOMS.len() {
            names[i] = ATOMS[i].name;
            i += 1;
        }
        names
    };

    /// Reads unit text such as `um/m/K`. `degC` alone is an absolute temperature (offset
    /// 273.15 K); inside a compound it is a difference.
    pub fn parse(text: &str) -> Result<Unit, UnitError> {
        Parser { text, pos: 0 }.parse().map(|f| f.to_unit())
    }

    /// One atom by name (`mm`, `µm`, `degC`, …), as `parse` would read it alone.
    pub fn atom(name: &str) -> Option<Unit> {
        let index = canonical_atom_name(name)?;
        let mut factors = Factors::default();
        factors.push(index, 1);
        Some(factors.to_unit())
    }

    /// The SI unit of a dimension, named from the base units: `m`, `rad`, `m/K`, `1`.
    pub fn si(dim: Dim) -> Unit {
        let name = if dim.is_dimensionless() {
            "1".to_string()
        } else {
            render(
                dim.exponents()
                    .into_iter()
                    .zip(BASES)
                    .map(|(e, (_, unit))| (unit, i32::from(e))),
            )
        };
        Unit {
            name,
            dim,
            scale: 1.0,
            offset: 0.0,
        }
    }

    pub fn dimensionless() -> Unit {
        Unit::si(Dim::DIMENSIONLESS)
    }

    pub fn to_si(&self, value: f64) -> f64 {
        value * self.scale + self.offset
    }

    pub fn from_si(&self, value: f64) -> f64 {
        (value - self.offset) / self.scale
    }

    /// The same unit read as a difference (a temperature rise): the offset dropped.
    pub fn as_difference(&self) -> Unit {
        Unit {
            offset: 0.0,
            ..self.clone()
        }
    }

    /// The same unit read as an absolute quantity: `degC` regains its offset, whether or not it
    /// was stored as a difference; every other unit is unchanged.
    pub fn as_absolute(&self) -> Unit {
        match Unit::parse(&self.name) {
            Ok(parsed) if parsed.dim == self.dim && parsed.scale == self.scale => Unit {
                offset: parsed.offset,
                ..self.clone()
            },
            _ => self.clone(),
        }
    }

    /// Products and quotients are differences: an offset never survives them.
    pub fn mul(&self, other: &Unit) -> Unit {
        self.combine(other, 1)
    }

    pub fn div(&self, other: &Unit) -> Unit {
        self.combine(other, -1)
    }

    pub fn powi(&self, n: i32) -> Unit {
        let name = match self.factors() {
            Some(f) => {
                let mut out = Factors::default();
                out.extend(&f, n);
                out.name()
            }
            None => format!("({})^{n}", self.name),
        };
        Unit {
            name,
            dim: self.dim.powi(n),
            scale: self.scale.powi(n),
            offset: 0.0,
        }
    }

    fn combine(&self, other: &Unit, sign: i32) -> Unit {
        let name = match (self.factors(), other.factors()) {
            (Some(a), Some(b)) => {
                let mut out = a;
                out.extend(&b, sign);
                out.name()
            }
            // A hand-built unit whose name is not unit text: keep its text readable.
            _ => format!(
                "{}{}({})",
                self.name,
                if sign > 0 { '*' } else { '/' },
                other.name
            ),
        };
        let (dim, scale) = if sign > 0 {
            (self.dim * other.dim, self.scale * other.scale)
        } else {
            (self.dim / other.dim, self.scale / other.scale)
        };
        Unit {
            name,
            dim,
            scale,
            offset: 0.0,
        }
    }

    /// The factor list behind a canonical name; `None` for a hand-built name that is not unit
    /// text (the fields are public).
    fn factors(&self) -> Option<Factors> {
        Parser {
            text: &self.name,
            pos: 0,
        }
        .parse()
        .ok()
    }
}

impl fmt::Display for Unit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name)
    }
}

impl FromStr for Unit {
    type Err = UnitError;
    fn from_str(text: &str) -> Result<Unit, UnitError> {
        Unit::parse(text)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(text: &str) -> Unit {
        Unit::parse(text).unwrap_or_else(|e| panic!("`{text}` should parse: {e}"))
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-12 * a.abs().max(b.abs())
    }

    #[test]
    fn the_atoms_are_the_unit_words_of_the_syntax() {
        assert_eq!(Unit::ATOM_NAMES, kin_syntax::syntax::UNIT_WORDS);
    }

    #[test]
    fn atoms_convert_to_si() {
        let cases = [
            ("nm", 1e-9),
            ("um", 1e-6),
            ("µm", 1e-6),
            ("μm", 1e-6),
            ("mm", 1e-3),
            ("m", 1.0),
            ("urad", 1e-6),
            ("mrad", 1e-3),
            ("rad", 1.0),
            ("deg", std::f64::consts::PI / 180.0),
            ("arcsec", 4.84813681109536e-6),
            ("s", 1.0),
            ("min", 60.0),
            ("h", 3600.0),
            ("K", 1.0),
            ("N", 1.0),
            ("kN", 1000.0),
            ("rev", std::f64::consts::TAU),
            ("rpm", 0.10471975511965977),
            ("W", 1.0),
            ("kW", 1000.0),
            ("1", 1.0),
        ];
        for (text, scale) in cases {
            let u = unit(text);
            assert!(close(u.to_si(1.0), scale), "{text}: {}", u.to_si(1.0));
            assert!(close(u.from_si(scale), 1.0), "{text}");
        }
        assert_eq!(unit("µm").name, "um");
    }

    #[test]
    fn numbers_other_than_one_are_rejected() {
        assert!(Unit::parse("25.4").is_err());
        assert!(Unit::parse("2").is_err());
    }

    #[test]
    fn every_atom_name_parses_alone() {
        for name in Unit::ATOM_NAMES {
            let u = Unit::atom(name).unwrap_or_else(|| panic!("{name}"));
            assert_eq!(u, unit(name));
            assert_eq!(u.name, name);
        }
        assert!(Unit::atom("inch").is_none());
        assert!(Unit::atom("um/m").is_none());
    }

    #[test]
    fn dimensions_of_atoms() {
        assert_eq!(unit("mm").dim, Dim::LENGTH);
        assert_eq!(unit("arcsec").dim, Dim::ANGLE);
        assert_eq!(unit("h").dim, Dim::TIME);
        assert_eq!(unit("degC").dim, Dim::TEMPERATURE);
        assert_eq!(unit("kN").dim, Dim::FORCE);
        assert_eq!(unit("1").dim, Dim::DIMENSIONLESS);
        assert_eq!(unit("rpm").dim, Dim::SPEED);
        assert_eq!(unit("rev/min").dim, Dim::SPEED);
        assert!(close(unit("rev/min").scale, unit("rpm").scale));
        assert_eq!(unit("kW").dim, unit("N*m/s").dim);
        assert_eq!(unit("mm/min").dim, Dim::VELOCITY);
    }

    #[test]
    fn compounds() {
        let u = unit("um/m/K");
        assert_eq!(u.name, "um/m/K");
        assert_eq!(u.dim, Dim::TEMPERATURE.powi(-1));
        assert!(close(u.scale, 1e-6));

        let u = unit("urad/N");
        assert_eq!(u.dim, Dim::ANGLE / Dim::FORCE);
        assert!(close(u.scale, 1e-6));

        let u = unit("mm^2");
        assert_eq!(u.dim.length, 2);
        assert!(close(u.to_si(3.0), 3e-6));

        let u = unit(" um / m ");
        assert_eq!(u.name, "um/m");
        assert!(u.dim.is_dimensionless());

        let u = unit("K^-1");
        assert_eq!(u.name, "1/K");
        assert_eq!(u.dim.temperature, -1);

        let u = unit("N*m");
        assert_eq!(u.name, "N*m");
        assert_eq!(u.dim, Dim::FORCE * Dim::LENGTH);

        let u = unit("mm*mm/mm^3");
        assert_eq!(u.name, "1/mm");
        assert!(close(u.scale, 1e3));

        let u = unit("1/min");
        assert_eq!(u.name, "1/min");
        assert!(close(u.to_si(60.0), 1.0));

        let u = unit("m/m");
        assert_eq!(u.name, "1");
    }

    #[test]
    fn canonical_names_reparse_to_the_same_unit() {
        for text in [
            "um/m/K",
            "mm^2",
            "1/s",
            "urad/N",
            "kN*mm^-2/h",
            "degC",
            "m^2/s^2",
        ] {
            let u = unit(text);
            assert_eq!(unit(&u.name), u, "{text} -> {}", u.name);
        }
    }

    #[test]
    fn celsius_alone_is_absolute_in_compounds_a_difference() {
        let c = unit("degC");
        assert!(close(c.to_si(20.0), 293.15));
        assert!(close(c.from_si(273.15), 0.0));
        let rise = c.as_difference();
        assert!(close(rise.to_si(20.0), 20.0));
        assert_eq!(rise.as_absolute(), c);

        let k = unit("K");
        assert_eq!(k.to_si(293.15), 293.15);
        assert_eq!(k.as_absolute(), k);

        let per = unit("um/m/degC");
        assert_eq!(per.offset, 0.0);
        assert!(close(per.to_si(11.5), 11.5e-6));

        assert_eq!(unit("degC^1").offset, CELSIUS_OFFSET);
        assert_eq!(unit("degC^2").offset, 0.0);
        assert_eq!(unit("mm^0/degC^-1").offset, CELSIUS_OFFSET);
        assert_eq!(unit("mm").as_absolute(), unit("mm"));
    }

    #[test]
    fn errors() {
        assert_eq!(Unit::parse(""), Err(UnitError::Empty));
        assert_eq!(Unit::parse("   "), Err(UnitError::Empty));
        assert_eq!(
            Unit::parse("um/furlong"),
            Err(UnitError::UnknownAtom {
                name: "furlong".into(),
                offset: 3
            })
        );
        assert!(matches!(
            Unit::parse("mm^"),
            Err(UnitError::UnexpectedEnd { .. })
        ));
        assert!(matches!(
            Unit::parse("mm^x"),
            Err(UnitError::Unexpected { offset: 3, .. })
        ));
        assert!(matches!(
            Unit::parse("mm m"),
            Err(UnitError::Unexpected { offset: 3, .. })
        ));
        assert!(matches!(
            Unit::parse("mm/"),
            Err(UnitError::UnexpectedEnd { .. })
        ));
        assert!(matches!(
            Unit::parse("mm^300"),
            Err(UnitError::ExponentRange { .. })
        ));
        assert!(matches!(
            Unit::parse("(mm)"),
            Err(UnitError::Unexpected { .. })
        ));
        assert_eq!(
            Unit::parse("um/furlong").map_err(|e| e.to_string()),
            Err("unknown unit `furlong`".to_string())
        );
    }

    #[test]
    fn algebra() {
        let um = unit("um");
        let m = unit("m");
        let k = unit("K");
        let u = um.div(&m).div(&k);
        assert_eq!(u, unit("um/m/K"));
        let area = unit("mm").powi(2);
        assert_eq!(area, unit("mm^2"));
        assert_eq!(unit("s").powi(-1).name, "1/s");
        assert_eq!(unit("s").powi(0), Unit::dimensionless());
        let back = u.mul(&k);
        assert_eq!(back.name, "um/m");
        assert!(close(back.scale, 1e-6));
        // An offset never survives a product.
        assert_eq!(unit("degC").mul(&Unit::dimensionless()).offset, 0.0);
    }

    #[test]
    fn si_units() {
        assert_eq!(Unit::si(Dim::LENGTH).name, "m");
        assert_eq!(Unit::si(Dim::ANGLE).name, "rad");
        assert_eq!(Unit::si(Dim::LENGTH / Dim::TEMPERATURE).name, "m/K");
        assert_eq!(Unit::si(Dim::DIMENSIONLESS).name, "1");
        assert_eq!(Unit::si(Dim::TIME.powi(-1)).name, "1/s");
        let u = Unit::si(Dim::LENGTH * Dim::FORCE);
        assert_eq!(u.name, "m*N");
        assert_eq!(unit(&u.name), u);
    }

    #[test]
    fn describe() {
        assert_eq!(Dim::LENGTH.describe(), "length");
        assert_eq!(Dim::ANGLE.describe(), "angle");
        assert_eq!(
            (Dim::LENGTH / Dim::TEMPERATURE).describe(),
            "length/temperature"
        );
        assert_eq!(Dim::DIMENSIONLESS.describe(), "dimensionless");
        assert_eq!(Dim::LENGTH.powi(2).describe(), "length^2");
        assert_eq!(Dim::TIME.powi(-1).to_string(), "1/time");
        assert_eq!((Dim::ANGLE / Dim::FORCE).describe(), "angle/force");
    }

    #[test]
    fn dim_arithmetic_saturates_instead_of_overflowing() {
        let big = Dim::LENGTH.powi(1000);
        assert_eq!(big.length, i8::MAX);
        assert_eq!((big * big).length, i8::MAX);
        assert_eq!(Dim::LENGTH.powi(-1000).length, i8::MIN);
    }

    proptest::proptest! {
        #[test]
        fn parsing_never_panics_and_names_are_canonical(text in "\\PC{0,12}") {
            if let Ok(u) = Unit::parse(&text) {
                let again = Unit::parse(&u.name);
                proptest::prop_assert_eq!(again, Ok(u));
            }
        }

        #[test]
        fn unit_like_text_round_trips(
            atoms in proptest::collection::vec((0..ATOMS.len(), -3i32..4, proptest::bool::ANY), 1..5)
        ) {
            let mut text = String::new();
            for (i, &(a, p, div)) in atoms.iter().enumerate() {
                if i > 0 {
                    text.push(if div { '/' } else { '*' });
                }
                text.push_str(Unit::ATOM_NAMES[a]);
                text.push_str(&format!("^{p}"));
            }
            let u = Unit::parse(&text).map_err(|e| proptest::test_runner::TestCaseError::fail(e.to_string()))?;
            proptest::prop_assert_eq!(Unit::parse(&u.name), Ok(u.clone()));
            proptest::prop_assert!(u.scale.is_finite() && u.scale > 0.0);
        }
    }
}

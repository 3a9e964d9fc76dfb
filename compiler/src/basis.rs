//! Families of dimensionless basis functions of one state variable (thesis chapter 3,
//! §3.2.2–3.2.5).
//!
//! A parametric error is `Σ β_l p_l(x)` (eq. 3.1); this module supplies the known functions
//! `p_l`. Conventions shared by every family:
//!
//! * Every function is **dimensionless**: the coefficient β carries the unit of the error.
//! * No family contains the constant function, except [`Basis::Const`] which is nothing else.
//!   Constants are one separate term so that the identifiability checker sees each offset once
//!   (the thesis counts "3 − 1 + 5 × 1 = 7 parameters" for a quadratic spline with five knots:
//!   the constant is not among them).
//! * The variable `x` is in SI (m, rad, or an input's SI unit). Ranged families work in the
//!   normalised variable `s = (x − lo)/(hi − lo)`, which is in `[0, 1]` over the declared range;
//!   outside the range the polynomial pieces simply continue (extrapolation, no clamping), so a
//!   slightly out-of-range observation gets a sensible value rather than a kink.
//! * Everything that needs a solve or a quadrature (detrending lines, once-per-revolution terms,
//!   periodic continuity corrections) is computed once by the validating constructors and stored
//!   in the enum; [`Basis::eval`] only does arithmetic, `floor`, `sin` and `cos`, in a fixed order,
//!   so that the Cranelift JIT can reproduce it bit for bit and fold the stored numbers as
//!   constants.
//!
//! Sizes ([`Basis::size`]), with `d` the degree, `c` the continuity order and `m` the number of
//! interior knots:
//!
//! | family                      | size                          |
//! |-----------------------------|-------------------------------|
//! | `Const`, `Linear`, `Sign`   | 1                             |
//! | `Legendre`                  | `d`                           |
//! | `Spline`, no detrend        | `d + m(d − c)`                |
//! | `Spline`, `Detrend::Line`   | `d − 1 + m(d − c)` (`s¹` is dropped) |
//! | `Spline`, `Detrend::OncePerRev` | `d + m(d − c)` (minus any function numerically in span{cos, sin}) |
//! | `Fourier`                   | `2 × harmonics`               |
//! | `Periodic`                  | `(m + 1)(d − c) − 1`          |

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::ir::NonLinear;

/// How [`Basis::eval`] obtains `sin h·x, cos h·x` of one harmonic `h` of a Fourier basis
/// ([`harmonic_step`]). The generated code follows the same steps, so both engines agree bit
/// for bit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Harmonic {
    /// `h = 1`: the fundamental, `sin x, cos x` from one `sincos`.
    Fundamental,
    /// `sin(h·x), cos(h·x)` of the rounded product `h·x`, from one `sincos` of its own.
    Direct,
    /// The sum of two angles already obtained, by `angle_sum`.
    Sum(HarmonicOperand, HarmonicOperand),
}

/// An angle a [`Harmonic::Sum`] adds: the fundamental, or the harmonic at an index of the list.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HarmonicOperand {
    Fundamental,
    Listed(usize),
}

/// How harmonic `harmonics[i]` is obtained: by angle addition from the fundamental and the
/// listed harmonics below it where one step does it (`2h` from `h`, `h + 1` from `h` and the
/// fundamental), else by its own `sincos`. A basis of harmonics `1..k` thus costs one `sincos`
/// instead of `k`, and `(90, 180)` one instead of two. Each angle addition rounds a few times;
/// along a chain of them the error in harmonic `h` grows at most about linearly in `h` (an
/// error in an angle is multiplied by the number of times it is added), about `h` units in the
/// last place — the same order as what rounding the argument `h·x` alone costs a direct
/// `sincos`, whose angle is off by up to `h·|x|` half-units.
///
/// Operands always have a smaller harmonic, so evaluating the list in increasing harmonic order
/// finds every operand ready. An index out of range reads as [`Harmonic::Direct`].
pub fn harmonic_step(harmonics: &[u32], i: usize) -> Harmonic {
    let Some(&h) = harmonics.get(i) else {
        return Harmonic::Direct;
    };
    let listed = |k: u32| harmonics.iter().position(|&g| g == k);
    match h {
        // Harmonic 0 (which no valid basis holds) would be its own operand.
        0 => return Harmonic::Direct,
        1 => return Harmonic::Fundamental,
        _ => {}
    }
    if h % 2 == 0 {
        if h == 2 {
            return Harmonic::Sum(HarmonicOperand::Fundamental, HarmonicOperand::Fundamental);
        }
        if let Some(j) = listed(h / 2) {
            return Harmonic::Sum(HarmonicOperand::Listed(j), HarmonicOperand::Listed(j));
        }
    }
    match listed(h - 1) {
        Some(j) => Harmonic::Sum(HarmonicOperand::Listed(j), HarmonicOperand::Fundamental),
        None => Harmonic::Direct,
    }
}

/// `sin(a + b), cos(a + b)` from `(sin a, cos a)` and `(sin b, cos b)`, in this order of
/// operations (the generated code performs the same).
pub(crate) fn angle_sum(a: (f64, f64), b: (f64, f64)) -> (f64, f64) {
    let (sa, ca) = a;
    let (sb, cb) = b;
    (sa * cb + ca * sb, ca * cb - sa * sb)
}

/// The indices of `harmonics` in increasing harmonic order (the list holds no duplicate,
/// [`Basis::fourier`]). Allocates nothing: each step looks for the next larger harmonic.
fn increasing(harmonics: &[u32]) -> impl Iterator<Item = usize> + '_ {
    let mut last: Option<u32> = None;
    std::iter::from_fn(move || {
        let (i, &h) = harmonics
            .iter()
            .enumerate()
            .filter(|&(_, &h)| last.is_none_or(|l| h > l))
            .min_by_key(|&(_, &h)| h)?;
        last = Some(h);
        Some(i)
    })
}

/// `cos(h x), sin(h x)` of every harmonic into `out` (pairs in list order), obtained as
/// [`harmonic_step`] says. A short `out` receives a prefix; an operand whose pair did not fit
/// is recomputed.
fn fourier_values(harmonics: &[u32], x: f64, out: &mut [f64]) {
    let mut fundamental: Option<(f64, f64)> = None;
    for i in increasing(harmonics) {
        let (s, c) = harmonic_value(harmonics, i, x, &mut fundamental, out);
        if let Some(pair) = out.get_mut(2 * i..2 * i + 2) {
            pair[0] = c;
            pair[1] = s;
        } else if let Some(o) = out.get_mut(2 * i) {
            *o = c;
        }
    }
}

/// `(sin, cos)` of harmonic `harmonics[i]`, reading its operands from `out` where their pairs
/// are (already written: operands have smaller harmonics) and recomputing them otherwise.
fn harmonic_value(
    harmonics: &[u32],
    i: usize,
    x: f64,
    fundamental: &mut Option<(f64, f64)>,
    out: &[f64],
) -> (f64, f64) {
    let operand = |o: HarmonicOperand, fundamental: &mut Option<(f64, f64)>| match o {
        HarmonicOperand::Fundamental => *fundamental.get_or_insert_with(|| libm::sincos(x)),
        HarmonicOperand::Listed(j) => match out.get(2 * j..2 * j + 2) {
            Some(pair) => (pair[1], pair[0]),
            None => harmonic_value(harmonics, j, x, fundamental, out),
        },
    };
    match harmonic_step(harmonics, i) {
        Harmonic::Fundamental => operand(HarmonicOperand::Fundamental, fundamental),
        Harmonic::Direct => {
            let h = harmonics.get(i).copied().unwrap_or(0);
            libm::sincos(f64::from(h) * x)
        }
        Harmonic::Sum(a, b) => {
            let a = operand(a, fundamental);
            let b = operand(b, fundamental);
            angle_sum(a, b)
        }
    }
}

/// Highest polynomial degree accepted. The thesis warns that degrees above 2 "should be avoided"
/// and above 3 are numerically suspect in the truncated power form; 5 leaves room without
/// inviting ill-conditioned fits.
pub(crate) const MAX_DEGREE: u32 = 5;

/// Most interior knots in one basis. The thesis uses 2–5 (11 in its largest example); the bound
/// keeps construction-time quadrature cheap and rejects runaway `knots 1e9` before it allocates.
pub(crate) const MAX_KNOTS: usize = 100;

/// A detrended function whose residual energy is below this fraction of the energy of the
/// function it came from is numerically inside the removed subspace: it would be a duplicate
/// regressor, so it is dropped (relative norm 1e-10, far below any genuine shape).
const DROP_RELATIVE_ENERGY: f64 = 1e-20;

/// Total number of quadrature panels for a once-per-revolution projection. With panels at most
/// 1 rad wide the 8-point rule is exact to rounding; ranges beyond ~4000 rad get wider panels and
/// degrade gracefully instead of making construction arbitrarily slow.
const ONCE_PER_REV_PANEL_BUDGET: usize = 4096;

/// Why a basis could not be built. Every constructor input that is not a valid model maps to one
/// of these; none panics.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum BasisError {
    #[error("{what} must be a finite number, got {value}")]
    NotFinite { what: &'static str, value: f64 },
    #[error("the range must have lo < hi, got {lo} .. {hi}")]
    EmptyRange { lo: f64, hi: f64 },
    #[error("the range {lo} .. {hi} is too wide to represent")]
    RangeTooWide { lo: f64, hi: f64 },
    #[error(
        "knot {index} is at {value}, outside the open interval (0, 1) of the normalised range"
    )]
    KnotOutside { index: usize, value: f64 },
    #[error("knots must be strictly increasing, but knot {index} ({value}) does not exceed the one before")]
    KnotsNotIncreasing { index: usize, value: f64 },
    #[error("{count} knots requested, at most {max} are supported")]
    TooManyKnots { count: usize, max: usize },
    #[error("degree {degree} is outside 1 ..= {max}")]
    Degree { degree: u32, max: u32 },
    #[error("continuity order {smooth} must satisfy -1 <= smooth < degree ({degree})")]
    Smooth { smooth: i32, degree: u32 },
    #[error("the wavelength must be positive, got {value}")]
    Wavelength { value: f64 },
    #[error("a Fourier basis needs at least one harmonic")]
    NoHarmonics,
    #[error("harmonic 0 is the constant; use `const` instead")]
    ZeroHarmonic,
    #[error("harmonic {harmonic} is listed twice")]
    DuplicateHarmonic { harmonic: u32 },
    #[error("the range {lo} .. {hi} is too short to separate a once-per-revolution term")]
    ArcTooShort { lo: f64, hi: f64 },
    #[error("these settings leave no basis function (e.g. a straight line with the line removed)")]
    Empty,
}

/// What is removed from every function of a [`Basis::Spline`] (thesis §3.2.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Detrend {
    None,
    /// Straightness: no least-squares line over the range (eq. 3.4–3.8).
    Line,
    /// Revolute cross errors: no least-squares `cos x`, `sin x` over the range (eq. 3.9–3.10).
    OncePerRev,
}

/// The wavelength τ of a [`Basis::Periodic`], in the SI unit of its variable.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Wavelength {
    Fixed(f64),
    /// Read from the non-linear parameter vector at evaluation time, so a fit can move it.
    Fitted(NonLinear),
}

/// A candidate function of a piecewise polynomial in `u` (`s` or `w`): `u^power` without a knot,
/// or the truncated power `(u − knot)_+^power` of eq. 3.3 (knot in normalised units).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Power {
    pub knot: Option<f64>,
    pub power: u32,
}

/// One function of a [`Basis::Spline`]: `g(s) − trend`, where the trend is
/// * `Detrend::None`: nothing (`trend` is `[0, 0]` and unused);
/// * `Detrend::Line`: `trend[0] + trend[1]·s`;
/// * `Detrend::OncePerRev`: `trend[0]·cos(x − m) + trend[1]·sin(x − m)`, `m = lo + (hi − lo)/2`
///   (see `once_per_rev_fit` for why the midpoint).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SplineFunction {
    pub g: Power,
    pub trend: [f64; 2],
}

/// One function of a [`Basis::Periodic`]: `v(w) = g(w) − Σ_{c'=1}^{c+1} alpha[c'−1]·w^{c'}`
/// (eq. 3.12).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PeriodicFunction {
    pub g: Power,
    pub alpha: Vec<f64>,
}

/// A family of dimensionless functions of one variable. Build through the validating
/// constructors ([`Basis::spline`] etc.); `Const` and `Sign` need no parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Basis {
    /// The constant 1.
    Const,
    /// `2s − 1`: Legendre P1 over the range, i.e. a centred line.
    Linear { lo: f64, hi: f64 },
    /// `P1(2s − 1) … P_degree(2s − 1)`: orthogonal over the range.
    Legendre { lo: f64, hi: f64, degree: u32 },
    /// Truncated power piecewise polynomial in `s` (eq. 3.2–3.3), optionally detrended.
    /// `knots` are interior knots in `s`, `smooth` the continuity order `c` (−1: jumps allowed).
    Spline {
        lo: f64,
        hi: f64,
        knots: Vec<f64>,
        degree: u32,
        smooth: i32,
        detrend: Detrend,
        functions: Vec<SplineFunction>,
    },
    /// `cos(h x), sin(h x)` for each harmonic `h`, `x` in rad; with a wavelength λ (a variable
    /// that is not an angle), `cos(2π h x/λ), sin(2π h x/λ)`: the harmonics of a fundamental
    /// of period λ (eq. 3.11 written as its Fourier series).
    Fourier {
        harmonics: Vec<u32>,
        #[serde(default)]
        wavelength: Option<Wavelength>,
    },
    /// Periodic piecewise polynomial of the wavelength fraction `w` (eq. 3.11–3.15).
    Periodic {
        wavelength: Wavelength,
        phase: f64,
        knots: Vec<f64>,
        degree: u32,
        smooth: i32,
        functions: Vec<PeriodicFunction>,
    },
    /// The variable itself; used with `Var::Direction` (±1) for backlash (§3.2.5).
    Sign,
}

impl Basis {
    /// `2s − 1` over `[lo, hi]`.
    pub fn linear(lo: f64, hi: f64) -> Result<Basis, BasisError> {
        check_range(lo, hi)?;
        Ok(Basis::Linear { lo, hi })
    }

    /// Legendre polynomials P1..P_degree over `[lo, hi]`.
    pub(crate) fn legendre(lo: f64, hi: f64, degree: u32) -> Result<Basis, BasisError> {
        check_range(lo, hi)?;
        check_degree(degree)?;
        Ok(Basis::Legendre { lo, hi, degree })
    }

    /// A piecewise polynomial over `[lo, hi]` with interior `knots` (normalised, in (0, 1)),
    /// `degree` d and continuity order `smooth` c, detrended as asked.
    pub fn spline(
        lo: f64,
        hi: f64,
        knots: Vec<f64>,
        degree: u32,
        smooth: i32,
        detrend: Detrend,
    ) -> Result<Basis, BasisError> {
        check_range(lo, hi)?;
        check_knots(&knots)?;
        check_degree(degree)?;
        check_smooth(smooth, degree)?;
        // s¹ is exactly a line, so straightness removes it entirely; skip it rather than rely on
        // the numerical drop below.
        let first_power = if detrend == Detrend::Line { 2 } else { 1 };
        let candidates = truncated_power_basis(&knots, degree, smooth, first_power);
        let breaks = breakpoints(&knots);
        let mut functions = Vec::with_capacity(candidates.len());
        for g in candidates {
            let trend = match detrend {
                Detrend::None => [0.0, 0.0],
                Detrend::Line => least_squares_line(g, &breaks),
                Detrend::OncePerRev => once_per_rev_fit(g, &breaks, hi - lo)
                    .ok_or(BasisError::ArcTooShort { lo, hi })?,
            };
            let f = SplineFunction { g, trend };
            if detrend == Detrend::None || !in_removed_span(&f, detrend, &breaks, hi - lo) {
                functions.push(f);
            }
        }
        if functions.is_empty() {
            return Err(BasisError::Empty);
        }
        Ok(Basis::Spline {
            lo,
            hi,
            knots,
            degree,
            smooth,
            detrend,
            functions,
        })
    }

    /// Harmonics `h` of an angle: `cos(h x), sin(h x)` per entry, in the given order.
    pub fn fourier(harmonics: Vec<u32>) -> Result<Basis, BasisError> {
        if harmonics.is_empty() {
            return Err(BasisError::NoHarmonics);
        }
        if harmonics.contains(&0) {
            return Err(BasisError::ZeroHarmonic);
        }
        let mut sorted = harmonics.clone();
        sorted.sort_unstable();
        if let Some(w) = sorted.windows(2).find(|w| w[0] == w[1]) {
            return Err(BasisError::DuplicateHarmonic { harmonic: w[0] });
        }
        Ok(Basis::Fourier {
            harmonics,
            wavelength: None,
        })
    }

    /// Harmonics `h` of a fundamental of wavelength λ (SI unit of the variable):
    /// `cos(2π h x/λ), sin(2π h x/λ)` per entry, in the given order.
    pub fn fourier_along(harmonics: Vec<u32>, wavelength: Wavelength) -> Result<Basis, BasisError> {
        if let Wavelength::Fixed(tau) = wavelength {
            check_finite("the wavelength", tau)?;
            if tau <= 0.0 {
                return Err(BasisError::Wavelength { value: tau });
            }
        }
        let Basis::Fourier { harmonics, .. } = Basis::fourier(harmonics)? else {
            return Err(BasisError::NoHarmonics);
        };
        Ok(Basis::Fourier {
            harmonics,
            wavelength: Some(wavelength),
        })
    }

    /// A periodic term of wavelength τ and phase φ (in the variable's SI unit), built from a
    /// piecewise polynomial in the wavelength fraction `w` with interior `knots` in (0, 1),
    /// `degree` d and continuity order `smooth` c, also across the period boundary.
    pub fn periodic(
        wavelength: Wavelength,
        phase: f64,
        knots: Vec<f64>,
        degree: u32,
        smooth: i32,
    ) -> Result<Basis, BasisError> {
        if let Wavelength::Fixed(tau) = wavelength {
            check_finite("the wavelength", tau)?;
            if tau <= 0.0 {
                return Err(BasisError::Wavelength { value: tau });
            }
        }
        check_finite("the phase", phase)?;
        check_knots(&knots)?;
        check_degree(degree)?;
        check_smooth(smooth, degree)?;
        let functions: Vec<PeriodicFunction> = periodic_candidates(&knots, degree, smooth)
            .into_iter()
            .map(|g| PeriodicFunction {
                g,
                alpha: periodic_alphas(g, smooth),
            })
            .collect();
        if functions.is_empty() {
            return Err(BasisError::Empty);
        }
        Ok(Basis::Periodic {
            wavelength,
            phase,
            knots,
            degree,
            smooth,
            functions,
        })
    }

    /// Number of functions, i.e. of coefficients this factor contributes.
    pub fn size(&self) -> usize {
        match self {
            Basis::Const | Basis::Linear { .. } | Basis::Sign => 1,
            Basis::Legendre { degree, .. } => *degree as usize,
            Basis::Spline { functions, .. } => functions.len(),
            Basis::Fourier { harmonics, .. } => 2 * harmonics.len(),
            Basis::Periodic { functions, .. } => functions.len(),
        }
    }

    /// Writes the `size()` function values at `x` into `out[..size()]`.
    ///
    /// `nonlinear` is the machine's non-linear parameter vector (read for a fitted wavelength).
    /// Never fails and never allocates: a short `out` receives a prefix, a missing non-linear
    /// parameter reads as NaN, and a non-positive fitted wavelength simply yields NaN/garbage
    /// values (the optimiser must keep τ > 0).
    pub fn eval(&self, x: f64, nonlinear: &[f64], out: &mut [f64]) {
        match self {
            Basis::Const => fill(out, 1.0),
            Basis::Sign => fill(out, x),
            Basis::Linear { lo, hi } => fill(out, 2.0 * normalise(x, *lo, *hi) - 1.0),
            Basis::Legendre { lo, hi, degree } => {
                legendre_values(2.0 * normalise(x, *lo, *hi) - 1.0, *degree, out)
            }
            Basis::Spline {
                lo,
                hi,
                detrend,
                functions,
                ..
            } => {
                let s = normalise(x, *lo, *hi);
                match detrend {
                    Detrend::None => {
                        for (o, f) in out.iter_mut().zip(functions) {
                            *o = f.g.value(s);
                        }
                    }
                    Detrend::Line => {
                        for (o, f) in out.iter_mut().zip(functions) {
                            *o = f.g.value(s) - (f.trend[0] + f.trend[1] * s);
                        }
                    }
                    Detrend::OncePerRev => {
                        let u = x - midpoint(*lo, *hi);
                        let (c, sn) = (libm::cos(u), libm::sin(u));
                        for (o, f) in out.iter_mut().zip(functions) {
                            *o = f.g.value(s) - f.trend[0] * c - f.trend[1] * sn;
                        }
                    }
                }
            }
            Basis::Fourier {
                harmonics,
                wavelength,
            } => {
                // The fundamental's angle: x itself (rad), or 2π x/λ.
                let x = match wavelength {
                    None => x,
                    Some(w) => std::f64::consts::TAU * x / wavelength_value(w, nonlinear),
                };
                fourier_values(harmonics, x, out);
            }
            Basis::Periodic {
                wavelength,
                phase,
                functions,
                ..
            } => {
                let w = wavelength_fraction(x, wavelength_value(wavelength, nonlinear), *phase);
                for (o, f) in out.iter_mut().zip(functions) {
                    *o = periodic_value(f, w);
                }
            }
        }
    }

    /// A short description of function `i` for reports, e.g. `s^2`, `(s-0.25)+^2`, `cos 2x`,
    /// `per((w-0.5)+^2)`. Out-of-range indices give `?`.
    pub fn label(&self, i: usize) -> String {
        if i >= self.size() {
            return "?".to_string();
        }
        match self {
            Basis::Const => "1".to_string(),
            Basis::Sign => "sign".to_string(),
            Basis::Linear { .. } => "2s-1".to_string(),
            Basis::Legendre { .. } => format!("P{}(2s-1)", i + 1),
            Basis::Spline {
                detrend, functions, ..
            } => {
                let Some(f) = functions.get(i) else {
                    return "?".to_string();
                };
                let g = f.g.label('s');
                match detrend {
                    Detrend::None => g,
                    Detrend::Line => format!("{g} - line"),
                    Detrend::OncePerRev => format!("{g} - rev1"),
                }
            }
            Basis::Fourier {
                harmonics,
                wavelength,
            } => {
                let Some(h) = harmonics.get(i / 2) else {
                    return "?".to_string();
                };
                let f = if i.is_multiple_of(2) { "cos" } else { "sin" };
                let x = if wavelength.is_some() {
                    "(2πx/λ)"
                } else {
                    "x"
                };
                if *h == 1 {
                    format!("{f} {x}")
                } else {
                    format!("{f} {h}{x}")
                }
            }
            Basis::Periodic { functions, .. } => match functions.get(i) {
                Some(f) => format!("per({})", f.g.label('w')),
                None => "?".to_string(),
            },
        }
    }
}

/// `count` interior knots equally spaced over the range: normalised positions `k/(count+1)`,
/// `k = 1..=count` (the thesis' default placement, §3.2.2).
pub(crate) fn equally_spaced_knots(count: usize) -> Result<Vec<f64>, BasisError> {
    if count > MAX_KNOTS {
        return Err(BasisError::TooManyKnots {
            count,
            max: MAX_KNOTS,
        });
    }
    let n = (count + 1) as f64;
    Ok((1..=count).map(|k| k as f64 / n).collect())
}

impl Power {
    /// `u^l` or `(u − t)_+^l` (eq. 3.3). The truncated power is 0 for `u ≤ t` — including the
    /// step `l = 0`, which is why this selects instead of raising `max(u − t, 0)` to the power.
    pub fn value(self, u: f64) -> f64 {
        match self.knot {
            None => ipow(u, self.power),
            Some(t) => {
                if u > t {
                    ipow(u - t, self.power)
                } else {
                    0.0
                }
            }
        }
    }

    /// `j`-th derivative at `u` (the right-hand one at a knot, which is all the periodic
    /// continuity conditions need at `u = 0` and `u = 1`, both away from interior knots).
    fn derivative(self, j: u32, u: f64) -> f64 {
        if j > self.power {
            return 0.0;
        }
        let scale = falling_factorial(self.power, j);
        let p = Power {
            knot: self.knot,
            power: self.power - j,
        };
        scale * p.value(u)
    }

    fn label(self, var: char) -> String {
        match self.knot {
            None => format!("{var}^{}", self.power),
            Some(t) => format!("({var}-{})+^{}", short_number(t), self.power),
        }
    }
}

/// The truncated power basis of eq. 3.2 without the constant and with the continuity
/// restrictions applied by omitting terms (the text after eq. 3.3): `u^l` for
/// `l = first_power..=d`, then for every knot `(u − t_k)_+^l` for `l = c+1..=d`. A term
/// `(u − t_k)_+^l` lets derivative `l` jump at `t_k`, so keeping only `l > c` makes derivatives
/// `0..=c` continuous.
fn truncated_power_basis(knots: &[f64], degree: u32, smooth: i32, first_power: u32) -> Vec<Power> {
    let first_knot_power = u32::try_from(smooth + 1).unwrap_or(0);
    let plain = (first_power..=degree).map(|power| Power { knot: None, power });
    let truncated = knots.iter().flat_map(|&t| {
        (first_knot_power..=degree).map(move |power| Power {
            knot: Some(t),
            power,
        })
    });
    plain.chain(truncated).collect()
}

/// The least-squares line `α1 + α2·x` through `g` over the range (eq. 3.5–3.8), returned as
/// `[a0, a1]` of `a0 + a1·s`.
///
/// Because `x = lo + (hi − lo)·s` is affine, lines in `x` and in `s` are the same set and the
/// integral criterion (eq. 3.5) differs only by the factor `hi − lo`, so the minimiser is the
/// same; working on `s ∈ [0, 1]` keeps eq. 3.8 well conditioned for any range. There the Gram
/// matrix is `[[1, 1/2], [1/2, 1/3]]` with inverse `[[4, −6], [−6, 12]]`. The moments are
/// computed by 8-point Gauss–Legendre per knot interval, exact for polynomials of degree ≤ 15.
fn least_squares_line(g: Power, breaks: &[f64]) -> [f64; 2] {
    let i0 = integrate_pieces(breaks, 1, |s| g.value(s));
    let i1 = integrate_pieces(breaks, 1, |s| g.value(s) * s);
    [4.0 * i0 - 6.0 * i1, 12.0 * i1 - 6.0 * i0]
}

/// The least-squares once-per-revolution term of `g` over the range (eq. 3.9–3.10), returned as
/// `[b_c, b_s]` of `b_c·cos(x − m) + b_s·sin(x − m)` with `m` the midpoint of the range.
///
/// This is the solution of the 2×2 normal equations of eq. 3.9 written in a rotated basis of the
/// same span, `cos(x − m) = cos m·cos x + sin m·sin x` and `sin(x − m) = cos m·sin x − sin m·cos x`.
/// About the midpoint one is even and the other odd, so their Gram matrix is diagonal and the
/// solve is two divisions — well conditioned even on a short arc, where `cos x` and `sin x`
/// themselves are nearly collinear. The equivalent thesis coefficients are
/// `α1 = b_c cos m − b_s sin m`, `α2 = b_c sin m + b_s cos m`; for a 2π range (`m = π` from
/// `[0, 2π]`) they reduce to eq. 3.10, `α = (1/π) ∫ g·(cos x, sin x) dx`.
///
/// The integrals are taken over `s ∈ [0, 1]` (the common factor `hi − lo` cancels) with
/// composite 8-point Gauss–Legendre: one group of panels per knot interval, so `g` is a
/// polynomial on every panel, and panels at most 1 rad wide within [`ONCE_PER_REV_PANEL_BUDGET`].
/// Returns `None` when the arc is so short that `sin(x − m)` vanishes numerically.
fn once_per_rev_fit(g: Power, breaks: &[f64], length: f64) -> Option<[f64; 2]> {
    let panels = panels_per_interval(breaks, length);
    let angle = |s: f64| (s - 0.5) * length;
    let gc = integrate_pieces(breaks, panels, |s| sq(libm::cos(angle(s))));
    let gs = integrate_pieces(breaks, panels, |s| sq(libm::sin(angle(s))));
    let rc = integrate_pieces(breaks, panels, |s| g.value(s) * libm::cos(angle(s)));
    let rs = integrate_pieces(breaks, panels, |s| g.value(s) * libm::sin(angle(s)));
    if !(gc.is_normal() && gs.is_normal()) {
        return None;
    }
    let b = [rc / gc, rs / gs];
    (b[0].is_finite() && b[1].is_finite()).then_some(b)
}

/// Whether a detrended spline function is numerically zero, i.e. its candidate `g` lies in the
/// removed span (a line, or cos/sin) and would be a duplicate regressor.
fn in_removed_span(f: &SplineFunction, detrend: Detrend, breaks: &[f64], length: f64) -> bool {
    let panels = match detrend {
        Detrend::OncePerRev => panels_per_interval(breaks, length),
        Detrend::None | Detrend::Line => 1,
    };
    let residual = |s: f64| match detrend {
        Detrend::None => f.g.value(s),
        Detrend::Line => f.g.value(s) - (f.trend[0] + f.trend[1] * s),
        Detrend::OncePerRev => {
            let u = (s - 0.5) * length;
            f.g.value(s) - f.trend[0] * libm::cos(u) - f.trend[1] * libm::sin(u)
        }
    };
    let energy = integrate_pieces(breaks, panels, |s| sq(f.g.value(s)));
    let left = integrate_pieces(breaks, panels, |s| sq(residual(s)));
    left <= DROP_RELATIVE_ENERGY * energy
}

/// A wavelength's value in SI: fixed, or read from the non-linear parameters (NaN if missing).
fn wavelength_value(w: &Wavelength, nonlinear: &[f64]) -> f64 {
    match w {
        Wavelength::Fixed(t) => *t,
        Wavelength::Fitted(p) => nonlinear.get(p.index).copied().unwrap_or(f64::NAN),
    }
}

/// The wavelength fraction `w ∈ [0, 1)` of eq. 3.13: `w = y − ⌊y⌋`, `y = (x − φ)/τ`.
///
/// The recursive definition `w(x) = w(x + τ)` is exactly the fractional part. Rounding can make
/// `y − ⌊y⌋` equal 1 for a tiny negative `y`; that point is the start of the next period, so it
/// maps to 0 (eq. 3.13's `φ ≤ x < φ + τ` keeps `w < 1`). Precision is that of `y`: fine while
/// `|x/τ|` stays far below 2^52.
pub(crate) fn wavelength_fraction(x: f64, tau: f64, phase: f64) -> f64 {
    let y = (x - phase) / tau;
    let w = y - libm::floor(y);
    if w >= 1.0 {
        0.0
    } else {
        w
    }
}

/// `v(w) = g(w) − Σ_{c'=1}^{c+1} α_{c'} w^{c'}` (eq. 3.12), the sum by Horner's rule
/// `w·(α1 + w·(α2 + …))` so the JIT can reproduce it operation for operation.
fn periodic_value(f: &PeriodicFunction, w: f64) -> f64 {
    let mut acc = 0.0;
    for a in f.alpha.iter().rev() {
        acc = acc * w + a;
    }
    f.g.value(w) - acc * w
}

/// The candidates `g` periodised by eq. 3.12: `{w^l : l = c+2..=d} ∪ {(w − t_k)_+^l : l = c+1..=d}`.
///
/// Why these and why the size is `(m + 1)(d − c) − 1`. Let `S` be the piecewise polynomials of
/// degree `d` on `[0, 1]` with the `m` knots, `C^c` at the knots, without constants: by eq. 3.2
/// its basis is `w^1..w^d` plus `(w − t_k)_+^l`, `l = c+1..=d`, so `dim S = d + m(d − c)`. The
/// periodisation `P: g ↦ v` of [`periodic_alphas`] is linear on `S`. Its kernel is exactly
/// `K = span{w^1..w^{c+1}}`: `P(g) = 0` means `g = Σ α_{c'} w^{c'}` ∈ K; conversely for
/// `g = w^{c'}` with `c' ≤ c+1` the right-hand side of the continuity system is column `c'` of
/// its (invertible) matrix, so `α = e_{c'}` and `v = 0`. By rank–nullity `dim P(S) = d + m(d − c)
/// − (c + 1) = (m + 1)(d − c) − 1`, and the listed candidates, being `S`'s basis minus a basis of
/// `K`, span a complement of `K`; hence their images are linearly independent and span `P(S)`.
/// This matches the count of periodic splines with `m + 1` knots on the circle (the period
/// boundary is a knot): `(m + 1)(d + 1) − (m + 1)(c + 1)` minus the constant. Every candidate
/// vanishes at `w = 0` (`l ≥ 1` for the powers, `t_k > 0` for the truncated ones), and so does
/// the correction, so no `v` contains a constant: `v(0) = 0`.
fn periodic_candidates(knots: &[f64], degree: u32, smooth: i32) -> Vec<Power> {
    let first_power = u32::try_from(smooth + 2).unwrap_or(1);
    truncated_power_basis(knots, degree, smooth, first_power)
}

/// The correction coefficients `α_1..α_{c+1}` of eq. 3.12 that make `v` and its derivatives
/// `0..=c` continuous across the period boundary, `v^{(j)}(1) = v^{(j)}(0)` for `j = 0..=c`
/// (eq. 3.14–3.15 generalised).
///
/// Derivation. `v^{(j)}(w) = g^{(j)}(w) − Σ_{c'} α_{c'} D^j w^{c'}`, so the conditions read
///
/// `Σ_{c'=1}^{c+1} α_{c'} [D^j w^{c'}(1) − D^j w^{c'}(0)] = g^{(j)}(1) − g^{(j)}(0)`,  `j = 0..=c`.
///
/// `D^j w^{c'}(1) = c'!/(c' − j)!` (0 if `j > c'`) and `D^j w^{c'}(0) = j!` if `c' = j`, else 0.
/// So the matrix entry is `M[j][c'] = c'!/(c' − j)! − [c' = j]·j!`: row 0 is all ones; for
/// `j ≥ 1` the entries with `c' ≤ j` vanish (at `c' = j` the two terms cancel), leaving an upper
/// triangular matrix with diagonal `M[j][j+1] = (j + 1)!`, always invertible; back substitution
/// solves it exactly. For `c = 1`:
///
/// `[[1, 1], [0, 2]]·[α1, α2]ᵀ = [g(1) − g(0), g'(1) − g'(0)]ᵀ`.
///
/// The thesis prints `[[1, 1], [1, 2]]` (eq. 3.15, from eq. 3.14's second line
/// `g'(0) = g'(1) − α1 − 2α2`). That is a transcription slip: `v'(0) = g'(0) − α1`, not `g'(0)`,
/// because `d/dw(α1·w) = α1` at `w = 0` as much as at `w = 1`; the `α1` cancels between the two
/// sides. With the printed matrix `v'` would jump by `α1` at every period boundary.
fn periodic_alphas(g: Power, smooth: i32) -> Vec<f64> {
    let Ok(n) = u32::try_from(smooth + 1) else {
        return Vec::new();
    };
    // Row j, column k ↔ c' = k + 1.
    let entry = |j: u32, k: u32| periodic_matrix_entry(j, k + 1);
    let rhs = |j: u32| g.derivative(j, 1.0) - g.derivative(j, 0.0);
    let mut alpha = vec![0.0; n as usize];
    for j in (0..n).rev() {
        let mut r = rhs(j);
        for k in j + 1..n {
            r -= entry(j, k) * alpha.get(k as usize).copied().unwrap_or(0.0);
        }
        if let Some(a) = alpha.get_mut(j as usize) {
            *a = r / entry(j, j);
        }
    }
    alpha
}

/// `M[j][c'] = D^j w^{c'}(1) − D^j w^{c'}(0) = c'!/(c' − j)! − [c' = j]·j!`, the matrix of the
/// periodic continuity system derived at [`periodic_alphas`]. Zero below the diagonal
/// `c' = j + 1`, which is what lets that function back-substitute.
fn periodic_matrix_entry(j: u32, c: u32) -> f64 {
    let at_zero = if c == j { falling_factorial(j, j) } else { 0.0 };
    falling_factorial(c, j) - at_zero
}

/// Legendre polynomials `P1(u)..P_degree(u)` by Bonnet's recurrence
/// `(n+1) P_{n+1} = (2n+1) u P_n − n P_{n−1}`: stable on [−1, 1] and cheap.
fn legendre_values(u: f64, degree: u32, out: &mut [f64]) {
    let mut previous = 1.0;
    let mut current = u;
    for (n, o) in out.iter_mut().take(degree as usize).enumerate() {
        *o = current;
        let n = (n + 1) as f64;
        let next = ((2.0 * n + 1.0) * u * current - n * previous) / (n + 1.0);
        previous = current;
        current = next;
    }
}

fn normalise(x: f64, lo: f64, hi: f64) -> f64 {
    (x - lo) / (hi - lo)
}

/// Written as `lo + (hi − lo)/2` because `lo + hi` can overflow where `hi − lo` (validated) cannot.
fn midpoint(lo: f64, hi: f64) -> f64 {
    lo + 0.5 * (hi - lo)
}

fn fill(out: &mut [f64], v: f64) {
    if let Some(o) = out.first_mut() {
        *o = v;
    }
}

/// `u^n` as `((1·u)·u)…`: a fixed sequence of multiplications the JIT reproduces exactly
/// (`powi` leaves the order to LLVM).
fn ipow(u: f64, n: u32) -> f64 {
    let mut r = 1.0;
    for _ in 0..n {
        r *= u;
    }
    r
}

/// `n!/(n − j)!` (0 when `j > n`).
fn falling_factorial(n: u32, j: u32) -> f64 {
    if j > n {
        return 0.0;
    }
    (n - j + 1..=n).map(f64::from).product()
}

fn sq(v: f64) -> f64 {
    v * v
}

/// `0, t_1, …, t_m, 1`: the pieces on which a spline is one polynomial.
fn breakpoints(knots: &[f64]) -> Vec<f64> {
    let mut b = Vec::with_capacity(knots.len() + 2);
    b.push(0.0);
    b.extend_from_slice(knots);
    b.push(1.0);
    b
}

/// Panels per knot interval so that each is at most 1 rad wide on an arc of `length` rad,
/// within the total budget.
fn panels_per_interval(breaks: &[f64], length: f64) -> usize {
    let intervals = breaks.len().saturating_sub(1).max(1);
    let cap = (ONCE_PER_REV_PANEL_BUDGET / intervals).max(1);
    // `as` saturates; `length` is validated finite and positive.
    (libm::ceil(length) as usize).clamp(1, cap)
}

/// Nodes and weights of 8-point Gauss–Legendre on [−1, 1] (exact for degree ≤ 15).
const GAUSS_8: [(f64, f64); 4] = [
    (0.183_434_642_495_649_8, 0.362_683_783_378_362),
    (0.525_532_409_916_329, 0.313_706_645_877_887_3),
    (0.796_666_477_413_626_7, 0.222_381_034_453_374_5),
    (0.960_289_856_497_536_3, 0.101_228_536_290_376_3),
];

/// `∫ f` over `[breaks[0], breaks[last]]`, split at every break and each piece into `panels`
/// equal panels of 8-point Gauss–Legendre.
fn integrate_pieces(breaks: &[f64], panels: usize, mut f: impl FnMut(f64) -> f64) -> f64 {
    let mut total = 0.0;
    for piece in breaks.windows(2) {
        let (a, b) = (piece[0], piece[1]);
        let width = (b - a) / panels as f64;
        for p in 0..panels {
            let lo = a + width * p as f64;
            let mid = lo + 0.5 * width;
            let half = 0.5 * width;
            let mut sum = 0.0;
            for (node, weight) in GAUSS_8 {
                sum += weight * (f(mid - half * node) + f(mid + half * node));
            }
            total += sum * half;
        }
    }
    total
}

/// Up to four decimals without trailing zeros, for labels (`0.25`, `0.3333`).
fn short_number(v: f64) -> String {
    let s = format!("{v:.4}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

fn check_finite(what: &'static str, value: f64) -> Result<(), BasisError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(BasisError::NotFinite { what, value })
    }
}

fn check_range(lo: f64, hi: f64) -> Result<(), BasisError> {
    check_finite("the lower end of the range", lo)?;
    check_finite("the upper end of the range", hi)?;
    if lo >= hi {
        return Err(BasisError::EmptyRange { lo, hi });
    }
    if !(hi - lo).is_finite() {
        return Err(BasisError::RangeTooWide { lo, hi });
    }
    Ok(())
}

fn check_knots(knots: &[f64]) -> Result<(), BasisError> {
    if knots.len() > MAX_KNOTS {
        return Err(BasisError::TooManyKnots {
            count: knots.len(),
            max: MAX_KNOTS,
        });
    }
    for (index, &value) in knots.iter().enumerate() {
        check_finite("a knot", value)?;
        if value <= 0.0 || value >= 1.0 {
            return Err(BasisError::KnotOutside { index, value });
        }
        if index > 0 && knots.get(index - 1).is_some_and(|&before| value <= before) {
            return Err(BasisError::KnotsNotIncreasing { index, value });
        }
    }
    Ok(())
}

fn check_degree(degree: u32) -> Result<(), BasisError> {
    if degree == 0 || degree > MAX_DEGREE {
        return Err(BasisError::Degree {
            degree,
            max: MAX_DEGREE,
        });
    }
    Ok(())
}

fn check_smooth(smooth: i32, degree: u32) -> Result<(), BasisError> {
    if smooth < -1 || i64::from(smooth) >= i64::from(degree) {
        return Err(BasisError::Smooth { smooth, degree });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::f64::consts::PI;

    /// xorshift64*: reproducible random cases without a dependency.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
        }
        fn uniform(&mut self) -> f64 {
            (self.next() >> 11) as f64 / (1u64 << 53) as f64
        }
        fn below(&mut self, n: u64) -> u64 {
            self.next() % n
        }
        /// Sorted knots in (0, 1) at least `gap` apart from each other and from 0 and 1.
        fn knots(&mut self, count: usize, gap: f64) -> Vec<f64> {
            loop {
                let mut k: Vec<f64> = (0..count).map(|_| self.uniform()).collect();
                k.sort_by(f64::total_cmp);
                let mut all = vec![0.0];
                all.extend(&k);
                all.push(1.0);
                if all.windows(2).all(|w| w[1] - w[0] >= gap) {
                    return k;
                }
            }
        }
    }

    fn values(b: &Basis, x: f64, nonlinear: &[f64]) -> Vec<f64> {
        let mut out = vec![f64::NAN; b.size()];
        b.eval(x, nonlinear, &mut out);
        out
    }

    /// Gauss–Legendre nodes by Newton's method: an independent rule for checking the
    /// constructors' quadrature.
    fn gauss_nodes(n: usize) -> Vec<(f64, f64)> {
        (0..n)
            .map(|i| {
                let mut x = (PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
                let mut dp = 0.0;
                for _ in 0..100 {
                    let (mut p0, mut p1) = (1.0, x);
                    for k in 2..=n {
                        let k = k as f64;
                        let p2 = ((2.0 * k - 1.0) * x * p1 - (k - 1.0) * p0) / k;
                        p0 = p1;
                        p1 = p2;
                    }
                    dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                    x -= p1 / dp;
                }
                (x, 2.0 / ((1.0 - x * x) * dp * dp))
            })
            .collect()
    }

    /// ∫ f over [a, b] split at `cuts`, 40 panels of 16-point Gauss per piece.
    fn integrate(a: f64, b: f64, cuts: &[f64], f: impl Fn(f64) -> f64) -> f64 {
        let nodes = gauss_nodes(16);
        let mut pts = vec![a];
        pts.extend(cuts.iter().copied().filter(|c| *c > a && *c < b));
        pts.push(b);
        let mut total = 0.0;
        for w in pts.windows(2) {
            let panels = 40;
            let h = (w[1] - w[0]) / panels as f64;
            for p in 0..panels {
                let mid = w[0] + h * (p as f64 + 0.5);
                for &(x, wt) in &nodes {
                    total += wt * f(mid + 0.5 * h * x) * 0.5 * h;
                }
            }
        }
        total
    }

    /// Monomial coefficients of the polynomial through `(u_i, f_i)` (Vandermonde solve with
    /// partial pivoting).
    fn poly_fit(us: &[f64], fs: &[f64]) -> Vec<f64> {
        let n = us.len();
        let mut a: Vec<Vec<f64>> = us
            .iter()
            .zip(fs)
            .map(|(&u, &f)| {
                let mut row: Vec<f64> = (0..n).map(|j| u.powi(j as i32)).collect();
                row.push(f);
                row
            })
            .collect();
        for col in 0..n {
            let piv = (col..n)
                .max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))
                .unwrap();
            a.swap(col, piv);
            let pivot_row = a[col].clone();
            for (r, row) in a.iter_mut().enumerate() {
                if r != col {
                    let factor = row[col] / pivot_row[col];
                    for (v, p) in row.iter_mut().zip(&pivot_row).skip(col) {
                        *v -= factor * p;
                    }
                }
            }
        }
        (0..n).map(|i| a[i][n] / a[i][i]).collect()
    }

    /// Local polynomial coefficients (in `u = (pos − at)/h`) of function `i` just left and just
    /// right of `at`, from `n` samples on each side; `eval_at(pos)` evaluates the basis.
    fn one_sided(
        eval_at: &dyn Fn(f64) -> Vec<f64>,
        at: f64,
        h: f64,
        n: usize,
        i: usize,
    ) -> (Vec<f64>, Vec<f64>) {
        let us: Vec<f64> = (1..=n).map(|k| k as f64).collect();
        let left_u: Vec<f64> = us.iter().map(|u| -u).collect();
        let left_f: Vec<f64> = left_u.iter().map(|u| eval_at(at + u * h)[i]).collect();
        let right_f: Vec<f64> = us.iter().map(|u| eval_at(at + u * h)[i]).collect();
        (poly_fit(&left_u, &left_f), poly_fit(&us, &right_f))
    }

    /// Linear independence of the sampled functions: Gram–Schmidt (applied twice, for
    /// stability) on the normalised sample columns. Returns the smallest relative residual norm,
    /// i.e. how far each function is from the span of the ones before it: ~1e-15 for a dependent
    /// set, and it does not square the conditioning as a Gram-matrix Cholesky would.
    fn min_independence(b: &Basis, xs: &[f64], nonlinear: &[f64]) -> f64 {
        let samples: Vec<Vec<f64>> = xs.iter().map(|&x| values(b, x, nonlinear)).collect();
        let mut done: Vec<Vec<f64>> = Vec::new();
        let mut min = f64::INFINITY;
        for i in 0..b.size() {
            let mut col: Vec<f64> = samples.iter().map(|s| s[i]).collect();
            let norm = col.iter().map(|v| v * v).sum::<f64>().sqrt();
            col.iter_mut().for_each(|v| *v /= norm);
            for _ in 0..2 {
                for q in &done {
                    let dot: f64 = q.iter().zip(&col).map(|(a, b)| a * b).sum();
                    col.iter_mut().zip(q).for_each(|(v, q)| *v -= dot * q);
                }
            }
            let left = col.iter().map(|v| v * v).sum::<f64>().sqrt();
            min = min.min(left);
            col.iter_mut().for_each(|v| *v /= left);
            done.push(col);
        }
        min
    }

    #[test]
    fn gauss_8_is_exact_to_degree_15() {
        for k in 0..=15 {
            let exact = 1.0 / (k as f64 + 1.0);
            let got = integrate_pieces(&[0.0, 1.0], 1, |s| s.powi(k));
            assert!((got - exact).abs() < 1e-15, "degree {k}: {got} vs {exact}");
        }
    }

    #[test]
    fn spline_hand_values() {
        let b = Basis::spline(0.0, 2.0, vec![0.5], 2, 1, Detrend::None).unwrap();
        assert_eq!(b.size(), 3);
        let v = values(&b, 1.5, &[]);
        assert_eq!(v, vec![0.75, 0.5625, 0.0625]);
        assert_eq!(b.label(0), "s^1");
        assert_eq!(b.label(2), "(s-0.5)+^2");
        assert_eq!(b.label(3), "?");
        // Left of the knot the truncated power is exactly 0; beyond the range it extrapolates.
        assert_eq!(values(&b, 0.5, &[])[2], 0.0);
        assert_eq!(values(&b, 3.0, &[]), vec![1.5, 2.25, 1.0]);
    }

    #[test]
    fn spline_sizes_follow_the_thesis_count() {
        let knots = equally_spaced_knots(5).unwrap();
        assert_eq!(
            knots,
            vec![1.0 / 6.0, 2.0 / 6.0, 3.0 / 6.0, 4.0 / 6.0, 5.0 / 6.0]
        );
        // Quadratic, C¹, five knots: 3 − 1 + 5 × 1 = 7 (§3.2.2).
        let b = Basis::spline(0.0, 0.6, knots.clone(), 2, 1, Detrend::None).unwrap();
        assert_eq!(b.size(), 7);
        let b = Basis::spline(0.0, 0.6, knots.clone(), 2, 1, Detrend::Line).unwrap();
        assert_eq!(b.size(), 6);
        let b = Basis::spline(0.0, 2.0 * PI, knots.clone(), 2, 1, Detrend::OncePerRev).unwrap();
        assert_eq!(b.size(), 7);
        let b = Basis::spline(0.0, 1.0, knots, 3, -1, Detrend::None).unwrap();
        assert_eq!(b.size(), 3 + 5 * 4);
        // A step basis: c = −1 with degree 1 has (s−t)+^0 steps.
        let b = Basis::spline(0.0, 1.0, vec![0.5], 1, -1, Detrend::None).unwrap();
        assert_eq!(b.size(), 3);
        assert_eq!(values(&b, 0.75, &[]), vec![0.75, 1.0, 0.25]);
        assert_eq!(values(&b, 0.5, &[]), vec![0.5, 0.0, 0.0]);
        assert_eq!(b.label(1), "(s-0.5)+^0");
    }

    #[test]
    fn spline_continuity_and_jumps_at_knots() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        for case in 0..200 {
            let degree = 1 + rng.below(u64::from(MAX_DEGREE)) as u32;
            let smooth = rng.below(u64::from(degree) + 1) as i32 - 1;
            let m = 1 + rng.below(4) as usize;
            let knots = rng.knots(m, 0.08);
            let (lo, hi) = (-0.4 + rng.uniform(), 0.7 + rng.uniform());
            let detrend = if case % 2 == 0 {
                Detrend::None
            } else {
                Detrend::Line
            };
            let b = Basis::spline(lo, hi, knots.clone(), degree, smooth, detrend);
            let Ok(b) = b else {
                // Only degree 1, no knots, with the line removed is empty; m ≥ 1 here.
                panic!("valid spline rejected: {b:?}");
            };
            let Basis::Spline { functions, .. } = &b else {
                unreachable!()
            };
            let eval_at = |s: f64| values(&b, lo + s * (hi - lo), &[]);
            for (k, &t) in knots.iter().enumerate() {
                let prev = if k == 0 { 0.0 } else { knots[k - 1] };
                let next = knots.get(k + 1).copied().unwrap_or(1.0);
                let n = degree as usize + 1;
                let h = 0.5 * (t - prev).min(next - t) / n as f64;
                for (i, f) in functions.iter().enumerate() {
                    let (left, right) = one_sided(&eval_at, t, h, n, i);
                    for j in 0..=smooth.max(-1) {
                        let j = j as usize;
                        assert!(
                            (left[j] - right[j]).abs() < 1e-8,
                            "case {case}: fn {i} derivative {j} jumps at {t}: {left:?} vs {right:?}"
                        );
                    }
                    let jump = right[(smooth + 1) as usize] - left[(smooth + 1) as usize];
                    let expected = if f.g.knot == Some(t) && f.g.power == (smooth + 1) as u32 {
                        h.powi(smooth + 1)
                    } else {
                        0.0
                    };
                    let scale = h.powi(smooth + 1);
                    assert!(
                        (jump - expected).abs() < 1e-6 * scale.max(1e-12) + 1e-9,
                        "case {case}: fn {i} ({}) derivative {} jump {jump} expected {expected}",
                        b.label(i),
                        smooth + 1
                    );
                }
            }
        }
    }

    #[test]
    fn straightness_has_no_line() {
        let mut rng = Rng(42);
        for _ in 0..60 {
            let degree = 1 + rng.below(u64::from(MAX_DEGREE)) as u32;
            let smooth = rng.below(u64::from(degree) + 1) as i32 - 1;
            let m = rng.below(5) as usize;
            let knots = rng.knots(m, 0.03);
            let (lo, hi) = (-0.4 + 0.1 * rng.uniform(), 0.2 * rng.uniform());
            let b = Basis::spline(lo, hi, knots.clone(), degree, smooth, Detrend::Line);
            let expected = degree as usize - 1 + m * (degree as i32 - smooth) as usize;
            if expected == 0 {
                assert_eq!(b, Err(BasisError::Empty));
                continue;
            }
            let b = b.unwrap();
            assert_eq!(b.size(), expected);
            let Basis::Spline { functions, .. } = &b else {
                unreachable!()
            };
            let cuts: Vec<f64> = knots.iter().map(|t| lo + t * (hi - lo)).collect();
            for (i, f) in functions.iter().enumerate() {
                let p = |x: f64| values(&b, x, &[])[i];
                let norm = integrate(lo, hi, &cuts, |x| p(x) * p(x)).sqrt();
                let x_norm = integrate(lo, hi, &cuts, |x| x * x).sqrt();
                let len = (hi - lo).sqrt();
                let i0 = integrate(lo, hi, &cuts, p);
                let i1 = integrate(lo, hi, &cuts, |x| p(x) * x);
                let g = f.g;
                let g_norm = integrate(lo, hi, &cuts, |x| sq(g.value((x - lo) / (hi - lo)))).sqrt();
                assert!(norm > 1e-3 * g_norm, "{} vanished", b.label(i));
                assert!(
                    i0.abs() <= 1e-12 * norm * len,
                    "∫p = {i0} for {}",
                    b.label(i)
                );
                assert!(
                    i1.abs() <= 1e-12 * norm * x_norm,
                    "∫px = {i1} for {}",
                    b.label(i)
                );
            }
        }
    }

    #[test]
    fn degree_one_straightness_without_knots_is_empty() {
        assert_eq!(
            Basis::spline(0.0, 1.0, vec![], 1, 0, Detrend::Line),
            Err(BasisError::Empty)
        );
        // With one knot only the kink survives.
        let b = Basis::spline(0.0, 1.0, vec![0.5], 1, 0, Detrend::Line).unwrap();
        assert_eq!(b.size(), 1);
        assert_eq!(b.label(0), "(s-0.5)+^1 - line");
    }

    fn check_once_per_rev(lo: f64, hi: f64, knots: Vec<f64>, degree: u32, smooth: i32) {
        let b = Basis::spline(lo, hi, knots.clone(), degree, smooth, Detrend::OncePerRev).unwrap();
        let m = knots.len();
        assert_eq!(
            b.size(),
            degree as usize + m * (degree as i32 - smooth) as usize
        );
        let cuts: Vec<f64> = knots.iter().map(|t| lo + t * (hi - lo)).collect();
        let cn = integrate(lo, hi, &[], |x| x.cos() * x.cos()).sqrt();
        let sn = integrate(lo, hi, &[], |x| x.sin() * x.sin()).sqrt();
        for i in 0..b.size() {
            let p = |x: f64| values(&b, x, &[])[i];
            let norm = integrate(lo, hi, &cuts, |x| p(x) * p(x)).sqrt();
            let ic = integrate(lo, hi, &cuts, |x| p(x) * x.cos());
            let is = integrate(lo, hi, &cuts, |x| p(x) * x.sin());
            assert!(norm > 1e-9, "{} vanished", b.label(i));
            assert!(
                ic.abs() <= 1e-12 * norm * cn,
                "∫p cos = {ic} for {}",
                b.label(i)
            );
            assert!(
                is.abs() <= 1e-12 * norm * sn,
                "∫p sin = {is} for {}",
                b.label(i)
            );
        }
    }

    #[test]
    fn once_per_rev_is_removed_over_full_and_partial_ranges() {
        check_once_per_rev(0.0, 2.0 * PI, vec![0.25, 0.5, 0.75], 2, 1);
        check_once_per_rev(-PI, PI, vec![0.3], 3, 0);
        check_once_per_rev(0.3, 1.9, vec![0.2, 0.7], 2, -1);
        check_once_per_rev(1.0, 1.3, vec![], 4, 2);
        check_once_per_rev(-20.0, 25.0, vec![0.1, 0.5, 0.9], 5, 3);
    }

    #[test]
    fn once_per_rev_over_two_pi_matches_eq_3_10() {
        let b = Basis::spline(0.0, 2.0 * PI, vec![0.4], 2, 1, Detrend::OncePerRev).unwrap();
        let Basis::Spline { functions, .. } = &b else {
            unreachable!()
        };
        let m = PI;
        for f in functions {
            let g = |x: f64| f.g.value(x / (2.0 * PI));
            let cuts = [0.4 * 2.0 * PI];
            let a1 = integrate(0.0, 2.0 * PI, &cuts, |x| g(x) * x.cos()) / PI;
            let a2 = integrate(0.0, 2.0 * PI, &cuts, |x| g(x) * x.sin()) / PI;
            let [bc, bs] = f.trend;
            let (alpha1, alpha2) = (bc * m.cos() - bs * m.sin(), bc * m.sin() + bs * m.cos());
            assert!((alpha1 - a1).abs() < 1e-13, "{alpha1} vs {a1}");
            assert!((alpha2 - a2).abs() < 1e-13, "{alpha2} vs {a2}");
        }
    }

    #[test]
    fn legendre_is_orthogonal_over_the_range() {
        let (lo, hi) = (-0.4, 0.35);
        let b = Basis::legendre(lo, hi, 5).unwrap();
        assert_eq!(b.size(), 5);
        for i in 0..5 {
            let pi = |x: f64| values(&b, x, &[])[i];
            let mean = integrate(lo, hi, &[], pi);
            assert!(mean.abs() < 1e-14, "P{} has a constant part {mean}", i + 1);
            for j in 0..5 {
                let pj = |x: f64| values(&b, x, &[])[j];
                let got = integrate(lo, hi, &[], |x| pi(x) * pj(x));
                let want = if i == j {
                    (hi - lo) / (2.0 * i as f64 + 3.0)
                } else {
                    0.0
                };
                assert!(
                    (got - want).abs() < 1e-14,
                    "<P{}, P{}> = {got}",
                    i + 1,
                    j + 1
                );
            }
        }
        // Known value: P2(u) = (3u² − 1)/2 at s = 1 (u = 1) is 1, at the centre −1/2.
        assert!((values(&b, hi, &[])[1] - 1.0).abs() < 1e-15);
        assert!((values(&b, lo + 0.5 * (hi - lo), &[])[1] + 0.5).abs() < 1e-15);
        let l = Basis::linear(lo, hi).unwrap();
        assert_eq!(values(&l, lo, &[]), vec![-1.0]);
        assert_eq!(values(&l, hi, &[]), vec![1.0]);
        assert_eq!(b.label(1), "P2(2s-1)");
    }

    #[test]
    fn fourier_along_a_wavelength() {
        let b = Basis::fourier_along(vec![1, 2], Wavelength::Fixed(0.02)).unwrap();
        let mut out = [0.0; 4];
        // A quarter of the fundamental: cos, sin of π/2 and of π.
        b.eval(0.005, &[], &mut out);
        let want = [0.0, 1.0, -1.0, 0.0];
        for (o, w) in out.iter().zip(want) {
            assert!((o - w).abs() < 1e-12, "{out:?}");
        }
        let fitted =
            Basis::fourier_along(vec![1], Wavelength::Fitted(NonLinear { index: 0 })).unwrap();
        let mut a = [0.0; 2];
        fitted.eval(0.005, &[0.04], &mut a);
        assert!((a[1] - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12);
        assert_eq!(b.label(3), "sin 2(2πx/λ)");
        assert_eq!(
            Basis::fourier_along(vec![1], Wavelength::Fixed(0.0)),
            Err(BasisError::Wavelength { value: 0.0 })
        );
        assert_eq!(
            Basis::fourier_along(vec![], Wavelength::Fixed(1.0)),
            Err(BasisError::NoHarmonics)
        );
    }

    #[test]
    fn fourier_values() {
        let b = Basis::fourier(vec![1, 3]).unwrap();
        assert_eq!(b.size(), 4);
        let x = 0.7;
        let v = values(&b, x, &[]);
        let want = [x.cos(), x.sin(), (3.0 * x).cos(), (3.0 * x).sin()];
        for (a, w) in v.iter().zip(want) {
            assert!((a - w).abs() < 1e-15);
        }
        assert_eq!(b.label(0), "cos x");
        assert_eq!(b.label(3), "sin 3x");
        assert_eq!(Basis::fourier(vec![]), Err(BasisError::NoHarmonics));
        assert_eq!(Basis::fourier(vec![2, 0]), Err(BasisError::ZeroHarmonic));
        assert_eq!(
            Basis::fourier(vec![2, 5, 2]),
            Err(BasisError::DuplicateHarmonic { harmonic: 2 })
        );
    }

    #[test]
    fn harmonics_by_angle_addition() {
        use HarmonicOperand::{Fundamental as F, Listed as L};
        let steps = |h: &[u32]| {
            (0..h.len())
                .map(|i| harmonic_step(h, i))
                .collect::<Vec<_>>()
        };
        assert_eq!(
            steps(&[2, 3, 4]),
            [
                Harmonic::Sum(F, F),
                Harmonic::Sum(L(0), F),
                Harmonic::Sum(L(0), L(0))
            ]
        );
        assert_eq!(
            steps(&[180, 1, 90]),
            [
                Harmonic::Sum(L(2), L(2)),
                Harmonic::Fundamental,
                Harmonic::Direct
            ]
        );
        assert_eq!(steps(&[5, 7]), [Harmonic::Direct, Harmonic::Direct]);
        assert_eq!(harmonic_step(&[0], 0), Harmonic::Direct);
        // Against each harmonic's own sincos: within a few units in the last place per unit of
        // harmonic, over a wide range of angles (a continuous axis turns many times).
        let lists: [&[u32]; 3] = [
            &[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16],
            &[180, 3, 90, 2, 1],
            &[2, 4, 8, 16, 32, 64],
        ];
        for list in lists {
            let b = Basis::fourier(list.to_vec()).unwrap();
            for x in [0.0, 1e-9, 0.3, -2.5, 3.1, 6.2, 100.0, -1234.5] {
                let v = values(&b, x, &[]);
                for (pair, &h) in v.chunks(2).zip(list) {
                    let (s, c) = libm::sincos(f64::from(h) * x);
                    // The direct value's own argument is off by up to h·|x|/2 ulp of 1.
                    let tol = f64::EPSILON * f64::from(h) * (4.0 + x.abs());
                    assert!(
                        (pair[0] - c).abs() <= tol && (pair[1] - s).abs() <= tol,
                        "h {h} at {x}: {pair:?} vs ({c}, {s})"
                    );
                }
                // A short output receives the prefix of the full one, bit for bit.
                for len in 0..v.len() {
                    let mut short = vec![f64::NAN; len];
                    b.eval(x, &[], &mut short);
                    assert_eq!(
                        short.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                        v[..len].iter().map(|v| v.to_bits()).collect::<Vec<_>>()
                    );
                }
            }
        }
    }

    #[test]
    fn const_and_sign() {
        assert_eq!(values(&Basis::Const, 3.0, &[]), vec![1.0]);
        assert_eq!(values(&Basis::Sign, -1.0, &[]), vec![-1.0]);
        assert_eq!(Basis::Sign.label(0), "sign");
    }

    #[test]
    fn periodic_alphas_for_c1_d2_match_the_derivation() {
        // g = (w − t)+²: g(1) − g(0) = (1 − t)², g'(1) − g'(0) = 2(1 − t).
        // [[1, 1], [0, 2]] α = rhs ⇒ α2 = 1 − t, α1 = (1 − t)² − (1 − t) = −t(1 − t).
        let b = Basis::periodic(Wavelength::Fixed(0.0254), 0.0, vec![0.3, 0.6], 2, 1).unwrap();
        let Basis::Periodic { functions, .. } = &b else {
            unreachable!()
        };
        assert_eq!(functions.len(), 2);
        for (f, t) in functions.iter().zip([0.3, 0.6]) {
            assert_eq!(
                f.g,
                Power {
                    knot: Some(t),
                    power: 2
                }
            );
            assert!((f.alpha[0] + t * (1.0 - t)).abs() < 1e-15);
            assert!((f.alpha[1] - (1.0 - t)).abs() < 1e-15);
        }
        // w³ with c = 1: α1 + α2 = 1, 2α2 = 3.
        let b = Basis::periodic(Wavelength::Fixed(1.0), 0.0, vec![], 3, 1).unwrap();
        let Basis::Periodic { functions, .. } = &b else {
            unreachable!()
        };
        assert_eq!(functions.len(), 1);
        assert_eq!(functions[0].alpha, vec![-0.5, 1.5]);
    }

    #[test]
    fn thesis_printed_matrix_would_break_slope_continuity() {
        // Solving eq. 3.15 as printed, [[1, 1], [1, 2]], for g = (w − 0.5)+².
        let (r0, r1) = (0.25, 1.0);
        let a2 = r1 - r0; // from [[1,1],[1,2]]: α1 + α2 = r0, α1 + 2α2 = r1
        let a1 = r0 - a2;
        let dv = |w: f64| 2.0 * (w - 0.5).max(0.0) - a1 - 2.0 * a2 * w;
        assert!((dv(1.0) - dv(0.0)).abs() > 0.1);
        // The derived [[1, 1], [0, 2]] closes it.
        let f = PeriodicFunction {
            g: Power {
                knot: Some(0.5),
                power: 2,
            },
            alpha: periodic_alphas(
                Power {
                    knot: Some(0.5),
                    power: 2,
                },
                1,
            ),
        };
        let dv = |w: f64| 2.0 * (w - 0.5).max(0.0) - f.alpha[0] - 2.0 * f.alpha[1] * w;
        assert!((dv(1.0) - dv(0.0)).abs() < 1e-15);
    }

    #[test]
    fn periodisation_matrix_is_upper_triangular() {
        // Back substitution in `periodic_alphas` reads only c' ≥ j + 1: the rest must vanish.
        for c in 0..MAX_DEGREE {
            for j in 0..=c {
                for col in 1..=j {
                    assert_eq!(periodic_matrix_entry(j, col), 0.0, "M[{j}][{col}]");
                }
                assert_eq!(
                    periodic_matrix_entry(j, j + 1),
                    falling_factorial(j + 1, j + 1)
                );
            }
        }
        // c = 1: [[1, 1], [0, 2]], not the printed [[1, 1], [1, 2]].
        let m: Vec<f64> = [(0, 1), (0, 2), (1, 1), (1, 2)]
            .iter()
            .map(|&(j, c)| periodic_matrix_entry(j, c))
            .collect();
        assert_eq!(m, vec![1.0, 1.0, 0.0, 2.0]);
    }

    #[test]
    fn periodic_terms_are_periodic_smooth_and_independent() {
        let mut rng = Rng(7);
        let mut checked = 0;
        for case in 0..150 {
            let degree = 1 + rng.below(u64::from(MAX_DEGREE)) as u32;
            let smooth = rng.below(u64::from(degree) + 1) as i32 - 1;
            let m = rng.below(4) as usize;
            let knots = rng.knots(m, 0.08);
            let tau = 0.001 + 0.05 * rng.uniform();
            let phase = 0.02 * (rng.uniform() - 0.5);
            let fitted = case % 3 == 0;
            let wavelength = if fitted {
                Wavelength::Fitted(NonLinear { index: 1 })
            } else {
                Wavelength::Fixed(tau)
            };
            let nonlinear = [f64::NAN, tau];
            let b = Basis::periodic(wavelength, phase, knots.clone(), degree, smooth);
            let size = (m + 1) * (degree as i32 - smooth) as usize - 1;
            if size == 0 {
                assert_eq!(b, Err(BasisError::Empty));
                continue;
            }
            let b = b.unwrap();
            assert_eq!(b.size(), size, "case {case}");
            checked += 1;
            let eval_at = |x: f64| values(&b, x, &nonlinear);

            // Vanishes at w = 0, i.e. at x = φ + kτ.
            assert!(eval_at(phase).iter().all(|v| *v == 0.0), "case {case}");

            // v(x) = v(x + τ), away from discontinuities.
            for _ in 0..20 {
                let mut w = rng.uniform();
                if std::iter::once(0.0)
                    .chain(knots.iter().copied())
                    .any(|t| (w - t).abs() < 1e-6)
                {
                    w += 2e-6;
                }
                let x = phase + tau * (w + rng.below(7) as f64 - 3.0);
                let (a, c) = (eval_at(x), eval_at(x + tau));
                for (p, q) in a.iter().zip(&c) {
                    assert!((p - q).abs() < 1e-9, "case {case}: {p} vs {q}");
                }
            }

            // Continuity of derivatives 0..=c across the period boundary x = φ + τ and at the
            // interior knots (in local units u = Δw/h).
            let n = degree as usize + 1;
            // The period boundary (w = 1 ≡ 0), with room up to the nearest knot on either side.
            let first = knots.first().copied().unwrap_or(1.0);
            let last = knots.last().copied().unwrap_or(0.0);
            let mut points = vec![(1.0, first.min(1.0 - last))];
            for (k, &t) in knots.iter().enumerate() {
                let prev = if k == 0 { 0.0 } else { knots[k - 1] };
                let next = knots.get(k + 1).copied().unwrap_or(1.0);
                points.push((t, (t - prev).min(next - t)));
            }
            for (w_at, room) in points {
                let h = 0.5 * room.min(0.2) / n as f64;
                let eval_w = |dw: f64| eval_at(phase + tau * dw);
                for i in 0..b.size() {
                    let (left, right) = one_sided(&eval_w, w_at, h, n, i);
                    for j in 0..=smooth.max(-1) {
                        let j = j as usize;
                        assert!(
                            (left[j] - right[j]).abs() < 1e-7,
                            "case {case}: {} derivative {j} jumps at w = {w_at}: {left:?} vs {right:?}",
                            b.label(i)
                        );
                    }
                }
            }

            // Linearly independent on a fine grid over one period.
            let xs: Vec<f64> = (0..3000)
                .map(|k| phase + tau * (k as f64 + 0.5) / 3000.0)
                .collect();
            let independence = min_independence(&b, &xs, &nonlinear);
            assert!(independence > 1e-9, "case {case}: residual {independence}");
        }
        assert!(checked > 100);
    }

    #[test]
    fn periodic_size_and_labels() {
        let b =
            Basis::periodic(Wavelength::Fixed(0.0254), 0.0, vec![0.25, 0.5, 0.75], 2, 1).unwrap();
        assert_eq!(b.size(), 3); // (3 + 1)(2 − 1) − 1
        assert_eq!(b.label(0), "per((w-0.25)+^2)");
        let b = Basis::periodic(Wavelength::Fixed(1.0), 0.0, vec![1.0 / 3.0], 3, 0).unwrap();
        assert_eq!(b.size(), 5); // (1 + 1)(3 − 0) − 1: w², w³, (w−t)+^1..3
        assert_eq!(b.label(0), "per(w^2)");
        assert_eq!(b.label(2), "per((w-0.3333)+^1)");
        assert_eq!(
            Basis::periodic(Wavelength::Fixed(1.0), 0.0, vec![], 2, 1),
            Err(BasisError::Empty)
        );
    }

    #[test]
    fn periodic_fitted_wavelength_reads_the_parameter() {
        let wl = Wavelength::Fitted(NonLinear { index: 0 });
        let b = Basis::periodic(wl, 0.0, vec![0.5], 2, 1).unwrap();
        let fixed = Basis::periodic(Wavelength::Fixed(0.5), 0.0, vec![0.5], 2, 1).unwrap();
        assert_eq!(values(&b, 0.3, &[0.5]), values(&fixed, 0.3, &[]));
        // A missing parameter is NaN, not a panic.
        assert!(values(&b, 0.3, &[]).iter().all(|v| v.is_nan()));
    }

    #[test]
    fn wavelength_fraction_stays_in_unit_interval() {
        assert_eq!(wavelength_fraction(-1e-300, 1.0, 0.0), 0.0);
        assert_eq!(wavelength_fraction(2.5, 1.0, 0.0), 0.5);
        assert_eq!(wavelength_fraction(-0.25, 1.0, 0.0), 0.75);
        assert_eq!(wavelength_fraction(1.0, 0.5, 0.25), 0.5);
    }

    #[test]
    fn constructors_reject_invalid_models() {
        use BasisError as E;
        assert!(matches!(Basis::linear(1.0, 1.0), Err(E::EmptyRange { .. })));
        assert!(matches!(
            Basis::linear(f64::NAN, 1.0),
            Err(E::NotFinite { .. })
        ));
        assert!(matches!(
            Basis::linear(-f64::MAX, f64::MAX),
            Err(E::RangeTooWide { .. })
        ));
        assert!(matches!(
            Basis::legendre(0.0, 1.0, 0),
            Err(E::Degree { .. })
        ));
        assert!(matches!(
            Basis::legendre(0.0, 1.0, 6),
            Err(E::Degree { .. })
        ));
        let sp = |knots: Vec<f64>, d, c| Basis::spline(0.0, 1.0, knots, d, c, Detrend::None);
        assert!(matches!(sp(vec![0.0], 2, 1), Err(E::KnotOutside { .. })));
        assert!(matches!(sp(vec![1.0], 2, 1), Err(E::KnotOutside { .. })));
        assert!(matches!(
            sp(vec![0.5, 0.5], 2, 1),
            Err(E::KnotsNotIncreasing { index: 1, .. })
        ));
        assert!(matches!(
            sp(vec![0.6, 0.5], 2, 1),
            Err(E::KnotsNotIncreasing { .. })
        ));
        assert!(matches!(sp(vec![f64::NAN], 2, 1), Err(E::NotFinite { .. })));
        assert!(matches!(sp(vec![], 2, 2), Err(E::Smooth { .. })));
        assert!(matches!(sp(vec![], 2, -2), Err(E::Smooth { .. })));
        assert!(matches!(
            sp(vec![0.5; MAX_KNOTS + 1], 2, 1),
            Err(E::TooManyKnots { .. })
        ));
        assert!(matches!(
            equally_spaced_knots(MAX_KNOTS + 1),
            Err(E::TooManyKnots { .. })
        ));
        let per = |tau| Basis::periodic(Wavelength::Fixed(tau), 0.0, vec![0.5], 2, 1);
        assert!(matches!(per(0.0), Err(E::Wavelength { .. })));
        assert!(matches!(per(-1.0), Err(E::Wavelength { .. })));
        assert!(matches!(per(f64::INFINITY), Err(E::NotFinite { .. })));
        assert!(matches!(
            Basis::periodic(Wavelength::Fixed(1.0), f64::NAN, vec![], 2, 0),
            Err(E::NotFinite { .. })
        ));
    }

    fn any_f64() -> impl Strategy<Value = f64> {
        prop_oneof![
            Just(f64::NAN),
            Just(f64::INFINITY),
            Just(f64::NEG_INFINITY),
            Just(0.0),
            Just(-0.0),
            Just(f64::MAX),
            Just(f64::MIN_POSITIVE),
            Just(1e-300),
            -10.0..10.0f64,
            0.0..1.0f64,
            any::<f64>(),
        ]
    }

    fn check_eval(b: &Basis, x: f64, nl: &[f64]) {
        let mut out = vec![0.0; b.size() + 2];
        b.eval(x, nl, &mut out);
        let mut short = vec![0.0; b.size() / 2];
        b.eval(x, nl, &mut short);
        b.eval(x, nl, &mut []);
        for i in 0..=b.size() {
            let _ = b.label(i);
        }
        assert!(b.size() > 0);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]

        #[test]
        fn constructors_never_panic(
            lo in any_f64(), hi in any_f64(), x in any_f64(),
            knots in proptest::collection::vec(any_f64(), 0..5),
            degree in prop_oneof![0u32..8, any::<u32>()],
            smooth in prop_oneof![-3i32..7, any::<i32>()],
            detrend in prop_oneof![Just(Detrend::None), Just(Detrend::Line), Just(Detrend::OncePerRev)],
            harmonics in proptest::collection::vec(prop_oneof![0u32..6, any::<u32>()], 0..4),
            nl in proptest::collection::vec(any_f64(), 0..3),
            index in 0usize..4,
            count in prop_oneof![0usize..10, any::<usize>()],
        ) {
            let _ = equally_spaced_knots(count);
            if let Ok(b) = Basis::linear(lo, hi) { check_eval(&b, x, &nl); }
            if let Ok(b) = Basis::legendre(lo, hi, degree) { check_eval(&b, x, &nl); }
            if let Ok(b) = Basis::spline(lo, hi, knots.clone(), degree, smooth, detrend) {
                check_eval(&b, x, &nl);
            }
            if let Ok(b) = Basis::fourier(harmonics) { check_eval(&b, x, &nl); }
            if let Ok(b) = Basis::periodic(Wavelength::Fixed(hi), lo, knots.clone(), degree, smooth) {
                check_eval(&b, x, &nl);
            }
            let fitted = Wavelength::Fitted(NonLinear { index });
            if let Ok(b) = Basis::periodic(fitted, lo, knots, degree, smooth) {
                check_eval(&b, x, &nl);
            }
        }

        #[test]
        fn sorted_random_knots_build(
            mut knots in proptest::collection::vec(0.001..0.999f64, 0..6),
            degree in 1u32..=MAX_DEGREE,
            lo in -1.0..1.0f64, len in 1e-6..100.0f64,
        ) {
            knots.sort_by(f64::total_cmp);
            knots.dedup();
            for detrend in [Detrend::None, Detrend::Line, Detrend::OncePerRev] {
                for smooth in -1..degree as i32 {
                    let b = Basis::spline(lo, lo + len, knots.clone(), degree, smooth, detrend);
                    match b {
                        Ok(b) => {
                            let v = values(&b, lo + 0.3 * len, &[]);
                            prop_assert!(v.iter().all(|v| v.is_finite()));
                        }
                        Err(e) => prop_assert_eq!(e, BasisError::Empty),
                    }
                }
            }
        }
    }
}

use super::*;
use proptest::prelude::*;
use std::f64::consts::PI;

const UM: f64 = 1e-6;

fn run_of(samples: Vec<Sample>) -> CircularRun {
    CircularRun {
        samples,
        setup: Setup::default(),
        deviation_unit: Unit::parse("um").unwrap_or_else(|e| panic!("{e}")),
    }
}

/// `n` samples a full turn apart, counter-clockwise or clockwise, radial deviation `d(θ)`.
fn trace(n: usize, ccw: bool, run: &str, d: impl Fn(f64) -> f64) -> Vec<Sample> {
    (0..n)
        .map(|i| {
            let t = 2.0 * PI * i as f64 / n as f64;
            let t = if ccw { t } else { 2.0 * PI - t };
            Sample {
                angle: t,
                deviation: d(t),
                ccw,
                run: run.into(),
                line: i + 2,
            }
        })
        .collect()
}

fn eval(samples: Vec<Sample>) -> Evaluation {
    evaluate(&run_of(samples), Path::new("t.csv")).unwrap_or_else(|e| panic!("{e}"))
}

fn close(what: &str, ours: f64, truth: f64, tol: f64) {
    assert!(
        (ours - truth).abs() <= tol,
        "{what}: {ours:e}, expected {truth:e} (±{tol:e})"
    );
}

/// An oval (a second harmonic, as a squareness gives) on an offset circle of the wrong radius,
/// and the clockwise path a constant 1.5 µm outside the counter-clockwise one: every figure is
/// known in closed form.
#[test]
fn figures_of_a_known_path() {
    let (a, b, c, g, k) = (4.0 * UM, -2.5 * UM, 1.2 * UM, 3.0 * UM, 1.5 * UM);
    let shape = move |t: f64| c + a * t.cos() + b * t.sin() + g / 2.0 * (2.0 * t).sin();
    let mut samples = trace(360, true, "1", shape);
    samples.extend(trace(360, false, "1", move |t| shape(t) + k));
    let e = eval(samples);
    assert_eq!(e.runs.len(), 1);
    let r = &e.runs[0];
    let ccw = r.ccw.as_ref().unwrap_or_else(|| panic!("ccw"));
    let cw = r.cw.as_ref().unwrap_or_else(|| panic!("cw"));
    let both = r.both.as_ref().unwrap_or_else(|| panic!("both"));
    for (name, f, radius) in [
        ("ccw", ccw, c),
        ("cw", cw, c + k),
        ("both", both, c + k / 2.0),
    ] {
        close(&format!("{name} centre x"), f.circle.centre[0], a, 1e-15);
        close(&format!("{name} centre y"), f.circle.centre[1], b, 1e-15);
        close(
            &format!("{name} radius"),
            f.circle.radius_error,
            radius,
            1e-15,
        );
    }
    // 1° sampling hits the oval's peaks at 45°, 135°, …: G is its full height.
    close("G ccw", ccw.g, g, 1e-15);
    close("G cw", cw.g, g, 1e-15);
    close("G both", both.g, g + k, 1e-15);
    close("H", r.h.unwrap_or(f64::NAN), k, 1e-15);
    // F about the instrument's centre: the largest of c + a cos + b sin + g/2 sin 2θ, brute force
    // on a fine grid (the samples are on a 1° grid, so take the samples' own values).
    let fmax = (0..360)
        .map(|i| shape(2.0 * PI * i as f64 / 360.0))
        .fold(f64::NEG_INFINITY, f64::max);
    close("F max ccw", ccw.f_max, fmax, 1e-18);
    close("F max cw", cw.f_max, fmax + k, 1e-18);
}

/// A path that is a true circle of radius R + e about (x0, y0), measured as the distance from
/// the instrument's centre at the origin minus R (what a ball bar reads): the least-squares
/// circle gives the centre and radius error to second order in the offset, and G vanishes.
#[test]
fn an_offset_circle_is_found_from_exact_distances() {
    let (r0, x0, y0, e) = (0.150, 12.0 * UM, -7.0 * UM, 3.0 * UM);
    let read = |t: f64| {
        let (x, y) = (x0 + (r0 + e) * t.cos(), y0 + (r0 + e) * t.sin());
        (x * x + y * y).sqrt() - r0
    };
    // The nominal angle the machine was told is the angle about the centre it really circles.
    let f = &eval(trace(720, true, "1", read)).runs[0];
    let c = f.ccw.as_ref().unwrap_or_else(|| panic!("ccw"));
    // Second order: |offset|² / R ≈ 1.3 nm.
    let tol = (x0 * x0 + y0 * y0) / r0;
    close("x0", c.circle.centre[0], x0, tol);
    close("y0", c.circle.centre[1], y0, tol);
    close("e", c.circle.radius_error, e, tol);
    assert!(c.g < tol, "G of a circle {:e}", c.g);
    assert!(f.cw.is_none() && f.both.is_none() && f.h.is_none());
}

#[test]
fn hysteresis_interpolates_between_the_other_paths_samples_and_skips_its_gaps() {
    let common = Circle {
        centre: [0.0, 0.0],
        radius_error: 0.0,
    };
    // A ramp of 1 µm per radian: the other path sampled at 10°, this one between its samples.
    let other: Vec<(f64, f64)> = (0..36)
        .map(|i| {
            let t = (i as f64 * 10.0).to_radians();
            (t, t * UM)
        })
        .collect();
    let this: Vec<(f64, f64)> = (0..35)
        .map(|i| {
            let t = (i as f64 * 10.0 + 5.0).to_radians();
            (t, t * UM + 0.25 * UM)
        })
        .collect();
    close(
        "H",
        hysteresis(&this, &other, common).unwrap_or(f64::NAN),
        0.25 * UM,
        1e-18,
    );
    // Only a quarter of the other path: the rest of this one has nothing to compare with.
    let quarter: Vec<(f64, f64)> = other.iter().copied().filter(|p| p.0 < 1.6).collect();
    let mut far = this.clone();
    far.push((3.0, 100.0 * UM));
    close(
        "H over the covered quarter",
        hysteresis(&far, &quarter, common).unwrap_or(f64::NAN),
        0.25 * UM,
        1e-18,
    );
}

#[test]
fn a_run_file_is_read_with_its_setup_and_units() {
    let text = "# ball bar, machine 7\n# radius: 150 mm\n# plane: X,Y\n# feed: 1000 mm/min\n\
                angle[deg];deviation[mm];direction;run\n0;0,0012;ccw;a\n90;-0,0004;cw;a\n";
    let r = read(text.as_bytes(), Path::new("t.csv")).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(r.setup.radius, Some(0.150));
    assert_eq!(r.setup.plane, Some(["X".to_string(), "Y".to_string()]));
    assert_eq!(r.setup.feed.as_deref(), Some("1000 mm/min"));
    assert_eq!(r.samples.len(), 2);
    close("angle", r.samples[1].angle, PI / 2.0, 1e-15);
    close("deviation", r.samples[0].deviation, 1.2 * UM, 1e-18);
    assert!(r.samples[0].ccw && !r.samples[1].ccw);
    assert_eq!(r.samples[0].run, "a");
}

#[test]
fn problems_are_located() {
    let cases: [(&str, &str); 6] = [
        ("angle,deviation\n0,1\n", "missing column: direction"),
        (
            "angle,deviation,direction,speed\n",
            "line 1, column 27: unknown column `speed`",
        ),
        (
            "angle,deviation,direction\n0,1,ccw\n10,x,ccw\n",
            "line 3, column 4: `x`: expected a number in um",
        ),
        (
            "angle,deviation,direction\n0,1,up\n",
            "line 2, column 5: `up`: expected ccw (or +1) or cw (or -1)",
        ),
        (
            "# radius: -3 mm\nangle,deviation,direction\n0,1,cw\n",
            "line 1: the radius",
        ),
        (
            "angle[mm],deviation,direction\n",
            "`mm` is not an angle unit",
        ),
    ];
    for (text, expected) in cases {
        match read(text.as_bytes(), Path::new("t.csv")) {
            Err(e) => {
                let shown = e.to_string();
                assert!(shown.contains(expected), "{text:?}: {shown}");
            }
            Ok(_) => panic!("{text:?} was accepted"),
        }
    }
    // Two samples, or three at one angle, do not determine a centre.
    let text = "angle,deviation,direction\n0,1,ccw\n0,2,ccw\n0,1,ccw\n";
    let r = read(text.as_bytes(), Path::new("t.csv")).unwrap_or_else(|e| panic!("{e}"));
    let e = evaluate(&r, Path::new("t.csv"))
        .err()
        .map(|e| e.to_string());
    assert!(
        e.as_deref()
            .is_some_and(|e| e.contains("line 2: run `1`, counter-clockwise")),
        "{e:?}"
    );
}

proptest! {
    /// G, and H, do not depend on where the instrument was centred nor on the bar's length:
    /// adding a centre offset and a radius error to every sample changes only the circle.
    #[test]
    fn g_and_h_ignore_the_setup(
        harmonics in proptest::collection::vec((-5.0f64..5.0, -5.0f64..5.0), 2..6),
        shift in (-20.0f64..20.0, -20.0f64..20.0, -50.0f64..50.0),
        n in 24usize..200,
    ) {
        let shape = |t: f64| -> f64 {
            harmonics.iter().enumerate().map(|(k, (p, q))| {
                let k = (k + 2) as f64;
                UM * (p * (k * t).cos() + q * (k * t).sin())
            }).sum()
        };
        let setup = |t: f64| UM * (shift.2 + shift.0 * t.cos() + shift.1 * t.sin());
        let mut plain = trace(n, true, "1", shape);
        plain.extend(trace(n, false, "1", |t| shape(t) + 0.3 * UM * (3.0 * t).cos()));
        let moved: Vec<Sample> = plain
            .iter()
            .map(|s| Sample { deviation: s.deviation + setup(s.angle), ..s.clone() })
            .collect();
        let (a, b) = (eval(plain), eval(moved));
        let (a, b) = (&a.runs[0], &b.runs[0]);
        let g = |r: &RunFigures| [
            r.ccw.as_ref().map_or(f64::NAN, |f| f.g),
            r.cw.as_ref().map_or(f64::NAN, |f| f.g),
            r.both.as_ref().map_or(f64::NAN, |f| f.g),
            r.h.unwrap_or(f64::NAN),
        ];
        for (x, y) in g(a).into_iter().zip(g(b)) {
            prop_assert!((x - y).abs() < 1e-13, "{x:e} vs {y:e}");
        }
    }
}

proptest! {
    /// Any bytes, and any file made of the format's own words, read and evaluate to figures or
    /// to located problems: never a panic, never a non-finite figure.
    #[test]
    fn no_input_panics(
        bytes in proptest::collection::vec(any::<u8>(), 0..200),
        cells in proptest::collection::vec(
            prop_oneof![
                Just("0".to_string()), Just("90".to_string()), Just("360".to_string()),
                Just("1e300".to_string()), Just("-0,5".to_string()), Just("nan".to_string()),
                Just("ccw".to_string()), Just("cw".to_string()), Just("+1".to_string()),
                Just("".to_string()), Just("\"a,b\"".to_string()), Just("x".to_string()),
                (-400.0f64..400.0).prop_map(|v| format!("{v}")),
            ],
            0..60,
        ),
        header in prop_oneof![
            Just("angle,deviation,direction"),
            Just("angle[rad];deviation[mm];direction;run"),
            Just("angle[deg],deviation[in],direction,run"),
            Just("# radius: 0\nangle,deviation,direction"),
        ],
    ) {
        let path = Path::new("p.csv");
        let _ = read(&bytes, path).map(|r| evaluate(&r, path));
        let width = header.lines().last().map_or(3, |h| h.split([',', ';']).count());
        let sep = if header.contains(';') { ";" } else { "," };
        let mut text = format!("{header}\n");
        for row in cells.chunks(width) {
            text.push_str(&row.join(sep));
            text.push('\n');
        }
        if let Ok(run) = read(text.as_bytes(), path) {
            if let Ok(e) = evaluate(&run, path) {
                for r in &e.runs {
                    for f in [&r.ccw, &r.cw, &r.both].into_iter().flatten() {
                        prop_assert!(f.g.is_finite() && f.g >= 0.0);
                        prop_assert!(f.circle.radius_error.is_finite());
                    }
                    prop_assert!(r.h.is_none_or(|h| h.is_finite() && h >= 0.0));
                }
            }
        }
    }
}

#[test]
fn bar_lengths_put_point_two_on_the_nominal_circle() {
    let sample = |angle: f64, ccw: bool, run: &str, deviation: f64| Sample {
        angle,
        deviation,
        ccw,
        run: run.into(),
        line: 2,
    };
    let samples = [
        sample(0.0, true, "a", 1.0 * UM),
        sample(PI / 2.0, false, "b", -2.0 * UM),
        sample(PI, true, "a", 0.5 * UM),
    ];
    let axis = |name: &str, length: bool, value: f64| PoseAxis {
        name: name.into(),
        length,
        value,
    };
    let centre = [
        axis("C", false, 0.1),
        axis("Y", true, 0.2),
        axis("X", true, 0.25),
    ];
    let plane = ["X".to_string(), "Y".to_string()];
    let bars =
        bar_lengths(&samples, &plane, 0.15, &centre, true).unwrap_or_else(|e| panic!("{e:?}"));
    assert_eq!(bars.runs, ["a", "b"]);
    let bar: Vec<usize> = bars.rows.iter().map(|r| r.bar).collect();
    assert_eq!(bar, [0, 1, 0]);
    let r = &bars.rows;
    // C stays at the centre; X is the plane's first axis, Y its second.
    close("C", r[1].point[0], 0.1, 0.0);
    close("X at 0", r[0].point[2], 0.4, 1e-15);
    close("Y at 0", r[0].point[1], 0.2, 1e-15);
    close("Y at 90°", r[1].point[1], 0.35, 1e-15);
    close("X at 180°", r[2].point[2], 0.1, 1e-15);
    // How each plane axis moved just before the point: counter-clockwise into 0° X rose to its
    // largest value and Y rose; clockwise into 90° X rose and Y rose to its largest; both fell
    // counter-clockwise into 180°.
    assert_eq!(r[0].positive, [true, true]);
    assert_eq!(r[1].positive, [true, true]);
    assert_eq!(r[2].positive, [false, false]);
    // A measuring machine's sign.
    close("dL", r[1].dl, 2.0 * UM, 0.0);
    let angle = [axis("X", true, 0.0), axis("Y", false, 0.0)];
    assert_eq!(
        bar_lengths(&samples, &plane, 0.15, &angle, false),
        Err(LengthsError::PlaneAxisNotLength)
    );
    assert_eq!(
        bar_lengths(&samples, &plane, 0.15, &centre[..2], false),
        Err(LengthsError::PlaneAxisMissing)
    );
}

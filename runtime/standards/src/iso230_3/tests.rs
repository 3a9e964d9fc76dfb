use super::*;

/// A vertical spindle warming for 4 h at constant speed then stopped for 2 h, sampled every
/// 5 min: every displacement the first-order response of one lumped heat capacity
/// (τ = 40 min), the axis tilting in the XZ plane by θ at steady state. Written as a run file
/// the way a data logger exports it, read back, evaluated against the closed forms.
#[test]
fn a_simulated_spindle_warm_up_gives_its_closed_form_figures() {
    let tau = 2400.0;
    let (on, total) = (4.0 * 3600.0, 6.0 * 3600.0);
    let l = 0.1; // sensors 100 mm apart along the spindle axis
    let (dz, dx, theta) = (-25e-6, 4e-6, 30e-6); // steady states: m, m, rad
    let w = |t: f64| {
        if t <= on {
            1.0 - (-t / tau).exp()
        } else {
            (1.0 - (-on / tau).exp()) * (-(t - on) / tau).exp()
        }
    };
    let mut csv = String::from(
        "# spindle 8000 rpm\n# separation: 100 mm\ntime[min],X1[um],X2[um],Y1[um],Y2[um],Z1[um],T_spindle[degC],T_room[degC]\n",
    );
    let mut t = 0.0;
    while t <= total + 1e-9 {
        let x1 = dx * w(t);
        let x2 = x1 + l * theta * w(t);
        csv += &format!(
            "{},{},{},{},{},{},{},{}\n",
            t / 60.0,
            x1 * 1e6,
            x2 * 1e6,
            0.5,
            0.5,
            dz * w(t) * 1e6,
            20.0 + 8.0 * w(t),
            20.0 + 0.2 * (t / 3600.0)
        );
        t += 300.0;
    }
    let run = read(csv.as_bytes(), Path::new("spindle.csv")).expect("reads");
    assert_eq!(run.separation, Some(0.1));
    let e = evaluate(&run);
    let peak = 1.0 - (-on / tau).exp();
    let z = e.displacements.iter().find(|c| c.name == "Z1").expect("Z1");
    assert!((z.drift - dz * peak).abs() < 1e-12, "{}", z.drift);
    assert!((z.drift_at - on).abs() < 1e-6);
    assert!((z.range - dz.abs() * peak).abs() < 1e-12);
    assert!((z.end - dz * w(total)).abs() < 1e-12);
    let x = e.tilts.iter().find(|t| t.pair == "X").expect("tilt X");
    assert!(
        (x.figures.drift - theta * peak).abs() < 1e-9,
        "{}",
        x.figures.drift
    );
    let y = e.tilts.iter().find(|t| t.pair == "Y").expect("tilt Y");
    assert_eq!(y.figures.range, 0.0);
    let ts = e
        .temperatures
        .iter()
        .find(|c| c.name == "T_spindle")
        .expect("T");
    assert!(
        (ts.drift - 8.0 * peak).abs() < 1e-9,
        "a rise, not an absolute value"
    );
    assert!((e.duration - total).abs() < 1e-6);
}

/// ETVE: with the machine at rest the displacement follows the room, a daily sinusoid of
/// amplitude A sampled at its peaks: the ETVE of each direction is 2A, the temperature range 2ΔT.
#[test]
fn the_etve_of_a_daily_cycle_is_its_peak_to_peak() {
    let mut csv = String::from("time[h];X[mm];Y[mm];Z[mm];T_air[K]\n");
    for k in 0..=96 {
        let t = k as f64 * 0.25;
        let s = (std::f64::consts::TAU * t / 24.0).sin();
        // decimal commas, as a spreadsheet in many locales writes them
        csv += &format!(
            "{};{};{};{};{}\n",
            t,
            0.003 * s,
            -0.001 * s,
            0.0,
            293.15 + 1.5 * s
        )
        .replace('.', ",");
    }
    let run = read(csv.as_bytes(), Path::new("etve.csv")).expect("reads");
    let e = evaluate(&run);
    let r = |n: &str| e.displacements.iter().find(|c| c.name == n).expect(n).range;
    assert!((r("X") - 6e-6).abs() < 1e-12, "{}", r("X"));
    assert!((r("Y") - 2e-6).abs() < 1e-12);
    assert_eq!(r("Z"), 0.0);
    assert!((e.temperatures[0].range - 3.0).abs() < 1e-9);
    assert!(e.tilts.is_empty());
}

#[test]
fn bad_files_are_refused_with_line_and_column() {
    let err = |s: &str| match read(s.as_bytes(), Path::new("t.csv")) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("accepted {s:?}"),
    };
    let e = err("time,X,Z\n0,1,2\n10,1,2\n5,1,2\n");
    assert!(
        e.contains("line 4, column 1") && e.contains("time order"),
        "{e}"
    );
    let e = err("time,X1,X2\n0,1,2\n");
    assert!(e.contains("separation"), "{e}");
    let e = err("time,X,W\n0,1,2\n");
    assert!(
        e.contains("line 1, column 8") && e.contains("unknown column `W`"),
        "{e}"
    );
    let e = err("time,X\n0,abc\n");
    assert!(e.contains("line 2, column 3"), "{e}");
    let e = err("# separation: -3 mm\ntime,X1,X2\n0,1,2\n");
    assert!(e.contains("line 1") && e.contains("positive length"), "{e}");
    let e = err("time[deg],X\n0,1\n");
    assert!(e.contains("time unit"), "{e}");
}

/// Absurd magnitudes are refused at their cell with the bound named, never printed as 300
/// digits or turned into a tilt of `inf` (both happened before the bounds).
#[test]
fn absurd_magnitudes_are_refused_with_the_bound() {
    let err = |s: &str| match read(s.as_bytes(), Path::new("t.csv")) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("accepted {s:?}"),
    };
    let e = err("time,X,Y\n0,0,0\n60,-1e308,1\n");
    assert!(
        e.contains("line 3, column 4") && e.contains("within ±1 m"),
        "{e}"
    );
    let e = err("time,X\n0,0\n1e300,1\n");
    assert!(
        e.contains("line 3, column 1") && e.contains("±1e10 s"),
        "{e}"
    );
    let e = err("time,X,T_room\n0,0,1e300\n");
    assert!(
        e.contains("line 2, column 5") && e.contains("10 000 K"),
        "{e}"
    );
    let e = err("# separation: 1e-300 mm\ntime,X1,X2\n0,0,0\n1,1,2\n");
    assert!(e.contains("line 1") && e.contains("1 um to 10 m"), "{e}");
    // The bounds leave a real test alone: a 1 mm drift over a day at 100 mm separation.
    let run = read(
        b"# separation: 100 mm\ntime[h],X1,X2,T_room\n0,0,0,20\n24,1000,1200,25\n",
        Path::new("t.csv"),
    );
    assert!(run.is_ok(), "{run:?}");
}

//! `kin report` end to end: fit the bundled example, write the HTML page (with a hand-made
//! diagnosis), check its sections and inline SVGs, and — where a Chromium is installed — render
//! it headless and check the screenshot. Without a browser the rendering check is skipped with a
//! printed line, so the test passes on a machine that has only the Rust toolchain.
//!
//! Set `KIN_REPORT_SCREENSHOT=/path/to.png` to keep the screenshot (e.g. as a CI artefact).

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use kin_diagnose::{Bin, Candidate, Diagnosis, Family, Finding, Region, Spectrum};

fn kin(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("kin runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// A scratch directory holding a copy of the example, so the fit history `kin fit` keeps next
/// to the model lands here and not in `examples/`.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kin-report-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    std::fs::copy(
        root.join("examples/bridge_cmm.kin"),
        dir.join("bridge_cmm.kin"),
    )
    .expect("copy model");
    std::fs::copy(
        root.join("examples/data/bridge_cmm_points.csv"),
        dir.join("points.csv"),
    )
    .expect("copy data");
    dir
}

fn fit(dir: &Path) {
    let out = kin(
        dir,
        &[
            "fit",
            "bridge_cmm.kin",
            "points.csv",
            "-o",
            "fit.json",
            "--color",
            "never",
        ],
    );
    assert!(out.status.success(), "kin fit: {}", text(&out.stderr));
}

/// A diagnosis as `kin diagnose` would write it, with one of everything the report shows.
fn diagnosis(model_hash: &str) -> Diagnosis {
    let wavelengths: Vec<f64> = (0..200).map(|i| 2.0 * 1.03f64.powi(i)).collect();
    let power: Vec<f64> = wavelengths
        .iter()
        .map(|w| 0.5 + 8.0 * (-((w / 25.4f64).ln()).powi(2) * 40.0).exp())
        .collect();
    let finding = |family, target: &str, text: &str, explained: f64, p: f64, significant| Finding {
        candidate: Candidate {
            family,
            target: target.into(),
            also: Vec::new(),
            text: text.into(),
            explanation: format!("{target} <explained> & so on"),
            no_path: None,
        },
        columns: 2,
        explained,
        f: 42.0,
        p,
        p_adjusted: (p * 30.0).min(1.0),
        significant,
        rms_after: 0.19,
        alternatives: Vec::new(),
        separation: None,
        bic: -100.0,
        plausibility: None,
        fitted: Vec::new(),
        contradicted: Vec::new(),
        same_effect_as: Vec::new(),
    };
    Diagnosis {
        machine: "bridge_cmm".into(),
        model_hash: model_hash.into(),
        sigma: 0.2,
        rms: 0.2,
        weighted: false,
        proposed: 0,
        dropped: Vec::new(),
        error_unit: "um".into(),
        alpha: 0.01,
        regions: vec![Region {
            component: "ex".into(),
            conditions: vec!["X > 420 mm".into()],
            ratio: 1.8,
            rows: 120,
            p: 1e-9,
            text: "ex residuals exceed 3σ for X > 420 mm".into(),
        }],
        // ex binned along an axis, an input and time, and nothing else: the overlay must land
        // on exactly those three plots.
        bins: [
            ("X", "mm", 100.0),
            ("T_room", "degC", 0.7),
            ("time", "min", 170.0),
        ]
        .iter()
        .flat_map(|&(variable, unit, width)| {
            (0..6).map(move |k| Bin {
                component: "ex".into(),
                variable: variable.into(),
                unit: unit.into(),
                lo: width * k as f64,
                hi: width * (k + 1) as f64,
                rows: 160,
                mean: 0.0,
                rms: 0.18 + 0.01 * k as f64,
                allowed: 0.2,
            })
        })
        .collect(),
        spectra: vec![Spectrum {
            component: "ex".into(),
            variable: "X".into(),
            unit: "mm".into(),
            wavelengths,
            power,
            peak_false_alarm: 1e-6,
        }],
        findings: vec![
            finding(
                Family::Periodic,
                "X.tx",
                "X.tx += periodic(X, wavelength 25.4 mm, knots 2)",
                0.31,
                1e-12,
                true,
            ),
            finding(
                Family::CrossCoupling,
                "Y.ty",
                "Y.ty += linear(X) * spline(Y, knots 3)",
                0.01,
                0.2,
                false,
            ),
        ],
        noise: Default::default(),
        outliers: Vec::new(),
    }
}

/// The `<svg>` elements of a page.
fn svgs(html: &str) -> Vec<&str> {
    html.match_indices("<svg")
        .filter_map(|(i, _)| {
            html.get(i..)
                .and_then(|rest| rest.find("</svg>").and_then(|j| rest.get(..j)))
        })
        .collect()
}

/// The `<svg>` whose title (or any other text) reads exactly `title`.
fn plot<'a>(html: &'a str, title: &str) -> Option<&'a str> {
    svgs(html).into_iter().find(|svg| {
        svg.split("<text").skip(1).any(|t| {
            t.split_once('>')
                .and_then(|(_, rest)| rest.split_once("</text>"))
                .is_some_and(|(text, _)| text.trim() == title)
        })
    })
}

/// The overlay of the diagnosis's binned RMS, in the report's orange.
const BINNED: &str = "stroke=\"#E69F00\"";

fn section<'a>(html: &'a str, id: &str) -> &'a str {
    let start = html
        .find(&format!("<section id=\"{id}\">"))
        .unwrap_or_else(|| panic!("no section {id}"));
    let rest = &html[start..];
    &rest[..rest.find("</section>").expect("section ends")]
}

#[test]
fn the_report_of_the_bundled_example_has_every_section_and_renders() {
    let dir = scratch("full");
    fit(&dir);
    let fitted: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("fit.json")).expect("fit.json"))
            .expect("json");
    let hash = fitted["model_hash"].as_str().expect("model hash");
    std::fs::write(
        dir.join("diagnose.json"),
        serde_json::to_string_pretty(&diagnosis(hash)).expect("json"),
    )
    .expect("write diagnosis");
    let out = kin(
        &dir,
        &[
            "report",
            "bridge_cmm.kin",
            "--fit",
            "fit.json",
            "--diagnose",
            "diagnose.json",
            "-o",
            "report.html",
            "--color",
            "never",
        ],
    );
    assert!(out.status.success(), "kin report: {}", text(&out.stderr));
    let html = std::fs::read_to_string(dir.join("report.html")).expect("report written");

    assert!(
        !html.contains("class=\"warn\""),
        "a consistent model, fit and diagnosis need no warning"
    );

    // Self-contained: no scripts, no external resources (the SVG namespace is a name, not a fetch).
    for bad in ["<script", "<link", "src=", "url(", "@import"] {
        assert!(!html.contains(bad), "the page must not contain `{bad}`");
    }
    assert_eq!(
        html.matches("http").count(),
        html.matches("xmlns=\"http://www.w3.org/2000/svg\"").count()
    );

    // Well-formed inline SVGs with finite coordinates; tables print a dash, never NaN.
    let opened = html.matches("<svg").count();
    assert_eq!(opened, html.matches("</svg>").count());
    assert!(
        !html.contains("NaN") && !html.contains("inf\""),
        "a non-finite number reached the page"
    );
    for svg in svgs(&html) {
        assert!(
            svg.contains("viewBox=") && svg.contains("<text"),
            "an SVG without axes: {}",
            &svg[..svg.len().min(200)]
        );
    }

    // The sections, each with its content.
    let summary = section(&html, "summary");
    assert!(summary.contains("σ̂") && summary.contains("points.csv") && summary.contains("3000"));
    let residuals = section(&html, "residuals");
    assert!(residuals.contains("<h2>Residuals along each axis, input and time</h2>"));
    // 3 components (ex ey ez) × (3 axes Y X Z, 2 inputs T_scale T_room, time), titled and
    // labelled with units.
    assert_eq!(residuals.matches("<svg").count(), 18);
    for label in [
        "ex along Y",
        "ez along Z",
        "X [mm]",
        "ey residual [um]",
        "±3σ̂",
    ] {
        assert!(residuals.contains(label), "residuals lack `{label}`");
    }
    for (title, x_label) in [
        ("ex along T_room", "T_room [degC]"),
        ("ey along T_scale", "T_scale [degC]"),
        ("ez along time", "time [min]"),
    ] {
        let svg = plot(residuals, title).unwrap_or_else(|| panic!("no plot `{title}`"));
        assert!(
            svg.contains(x_label),
            "`{title}` is not labelled `{x_label}`"
        );
    }
    assert!(
        !residuals.contains("all values are equal") && !residuals.contains("not in the data"),
        "every input and time vary in the bundled data"
    );
    assert!(
        residuals.contains("binned RMS"),
        "the diagnosis's bins are overlaid"
    );
    // The bins go exactly where the diagnosis put them: ex along X, T_room and time.
    for (title, binned) in [
        ("ex along X", true),
        ("ex along T_room", true),
        ("ex along time", true),
        ("ex along Y", false),
        ("ex along T_scale", false),
        ("ey along T_room", false),
        ("ez along time", false),
    ] {
        let svg = plot(residuals, title).unwrap_or_else(|| panic!("no plot `{title}`"));
        assert_eq!(svg.contains(BINNED), binned, "bins on `{title}`");
    }
    let spectrum = section(&html, "spectrum");
    assert_eq!(spectrum.matches("<svg").count(), 1);
    assert!(
        spectrum.contains("λ = 25.") && spectrum.contains("1.0e-6"),
        "the peak wavelength and its false-alarm probability are named"
    );
    let candidates = section(&html, "candidates");
    assert!(candidates.contains("<code>X.tx += periodic(X, wavelength 25.4 mm, knots 2)</code>"));
    assert!(
        candidates.contains("&lt;explained&gt; &amp; so on"),
        "candidate text is escaped"
    );
    assert!(candidates.contains("ex residuals exceed 3σ for X &gt; 420 mm"));
    assert!(candidates.contains("31.0 %") && candidates.contains("<span class=\"sig\">yes</span>"));
    let history = section(&html, "history");
    assert!(
        history.contains("<svg") && history.contains("class=\"current\""),
        "kin fit recorded this fit in the history"
    );
    let curves = section(&html, "curves");
    for title in [
        "Y.ty",
        "X.tx",
        "Z.rz",
        "lag of T_room [degC]",
        "Y.rx [urad]",
        "confidence band",
    ] {
        assert!(curves.contains(title), "curves lack `{title}`");
    }
    assert!(
        curves.matches("<svg").count() >= 18,
        "one plot per parametric error and variable"
    );
    assert!(
        curves.contains("moving +") && curves.contains("X = 600 mm"),
        "direction and coupling lines are labelled"
    );

    screenshot(&dir.join("report.html"), &dir);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn without_a_diagnosis_the_optional_sections_are_left_out() {
    let dir = scratch("plain");
    fit(&dir);
    // The data given explicitly, and the fit recorded elsewhere: FIT.json's own paths are not used.
    std::fs::rename(dir.join("points.csv"), dir.join("moved.csv")).expect("move data");
    let out = kin(
        &dir,
        &[
            "report",
            "bridge_cmm.kin",
            "--fit",
            "fit.json",
            "moved.csv",
            "-o",
            "plain.html",
            "--color",
            "never",
        ],
    );
    assert!(out.status.success(), "kin report: {}", text(&out.stderr));
    let html = std::fs::read_to_string(dir.join("plain.html")).expect("report written");
    assert!(!html.contains("id=\"spectrum\"") && !html.contains("id=\"candidates\""));
    assert_eq!(section(&html, "residuals").matches("<svg").count(), 18);
    assert_eq!(html.matches("<svg").count(), html.matches("</svg>").count());

    // Without any data file the residual plots give way to a note; the page is still written.
    std::fs::remove_file(dir.join("moved.csv")).expect("remove data");
    let out = kin(
        &dir,
        &[
            "report",
            "bridge_cmm.kin",
            "--fit",
            "fit.json",
            "-o",
            "nodata.html",
            "--color",
            "never",
        ],
    );
    assert!(out.status.success(), "kin report: {}", text(&out.stderr));
    let html = std::fs::read_to_string(dir.join("nodata.html")).expect("report written");
    assert!(
        html.contains("no positions for the residuals")
            && section(&html, "residuals").matches("<svg").count() == 0
    );
    assert!(section(&html, "curves").contains("<svg"));
    uncertainty_map_agrees_with_eval(&dir, &html);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The uncertainty map's smallest and largest values, at the positions the page names and with
/// the other variables at the values it names, are what `kin eval --uncertainty` gives there:
/// √(u_ex² + u_ey² + u_ez²).
fn uncertainty_map_agrees_with_eval(dir: &Path, html: &str) {
    let map = section(html, "uncertainty");
    assert_eq!(map.matches("<svg").count(), 1, "{map}");
    // "held at X = 1.0 mm, T_scale = 20.00 degC, …." from the paragraph.
    let held = map
        .split("held at ")
        .nth(1)
        .and_then(|t| t.split(". ").next())
        .expect("held values");
    let mut names = Vec::new();
    let mut values = Vec::new();
    for item in held.split(", ") {
        let (name, rest) = item.split_once(" = ").expect("name = value unit");
        let (value, unit) = rest.split_once(' ').expect("value unit");
        names.push(format!("{name}[{unit}]"));
        values.push(value.to_string());
        if unit == "mm" {
            // The map takes every axis as approached in its positive direction.
            names.push(format!("dir_{name}"));
            values.push("+1".into());
        }
    }
    // The rows of the extremes: value, then the two plane axes (X and Y of the bridge CMM).
    let cells = |label: &str| -> Vec<f64> {
        let row = map
            .split(&format!("<td class=\"l\">{label}</td>"))
            .nth(1)
            .expect(label);
        row.split("</tr>")
            .next()
            .expect("row")
            .split("<td>")
            .skip(1)
            .map(|c| {
                c.split("</td>")
                    .next()
                    .expect("cell")
                    .parse()
                    .expect("number")
            })
            .collect()
    };
    let header = map
        .split("<th class=\"l\"></th>")
        .nth(1)
        .expect("table header");
    let axes: Vec<&str> = header
        .split("<th>")
        .skip(2)
        .map(|h| h.split(' ').next().expect("axis"))
        .collect();
    let mut csv = format!(
        "{},{a}[mm],{b}[mm],dir_{a},dir_{b},time\n",
        names.join(","),
        a = axes[0],
        b = axes[1]
    );
    let extremes = [cells("smallest"), cells("largest")];
    for e in &extremes {
        csv.push_str(&format!("{},{},{},+1,+1,0\n", values.join(","), e[1], e[2]));
    }
    std::fs::write(dir.join("extremes.csv"), csv).expect("write");
    let out = kin(
        dir,
        &[
            "eval",
            "bridge_cmm.kin",
            "extremes.csv",
            "--params",
            "fit.json",
            "--uncertainty",
            "--components",
            "position",
            "-o",
            "extremes_u.csv",
        ],
    );
    assert!(out.status.success(), "kin eval: {}", text(&out.stderr));
    let written = std::fs::read_to_string(dir.join("extremes_u.csv")).expect("eval output");
    let mut lines = written.lines().filter(|l| !l.starts_with('#'));
    let head: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |n: &str| {
        head.iter()
            .position(|h| h.split('[').next() == Some(n))
            .expect(n)
    };
    for (line, e) in lines.zip(&extremes) {
        let c: Vec<f64> = line
            .split(',')
            .map(|v| v.parse().expect("number"))
            .collect();
        let u = (c[col("u_ex")].powi(2) + c[col("u_ey")].powi(2) + c[col("u_ez")].powi(2)).sqrt();
        assert!(
            (u - e[0]).abs() < 2e-3 * e[0],
            "eval gives {u}, the map {}",
            e[0]
        );
    }
    assert!(extremes[0][0] < extremes[1][0]);
}

/// The data with every cell of the column named `header` replaced by `value`.
fn set_column(csv: &str, header: &str, value: &str) -> String {
    let mut column = None;
    let mut out = String::new();
    for line in csv.lines() {
        let mut cells: Vec<&str> = line.split(',').collect();
        if line.starts_with('#') {
        } else if let Some(c) = column {
            cells[c] = value;
        } else {
            column = Some(cells.iter().position(|h| *h == header).expect("the column"));
        }
        out.push_str(&cells.join(","));
        out.push('\n');
    }
    out
}

#[test]
fn an_input_that_never_changes_gets_a_line_instead_of_plots() {
    let dir = scratch("constant");
    let data = std::fs::read_to_string(dir.join("points.csv")).expect("data");
    std::fs::write(
        dir.join("points.csv"),
        set_column(&data, "T_scale[degC]", "20"),
    )
    .expect("write data");
    fit(&dir);
    let out = kin(
        &dir,
        &[
            "report",
            "bridge_cmm.kin",
            "--fit",
            "fit.json",
            "-o",
            "constant.html",
            "--color",
            "never",
        ],
    );
    assert!(out.status.success(), "kin report: {}", text(&out.stderr));
    let html = std::fs::read_to_string(dir.join("constant.html")).expect("report written");
    let residuals = section(&html, "residuals");
    assert_eq!(
        residuals
            .matches("<code>T_scale</code>: all values are equal (20 degC in every row)")
            .count(),
        1,
        "one line for the constant input, not one per component"
    );
    for c in ["ex", "ey", "ez"] {
        assert!(plot(residuals, &format!("{c} along T_scale")).is_none());
        assert!(plot(residuals, &format!("{c} along T_room")).is_some());
        assert!(plot(residuals, &format!("{c} along time")).is_some());
    }
    // 3 components × (3 axes, T_room, time).
    assert_eq!(residuals.matches("<svg").count(), 15);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_missing_fit_report_is_a_usage_error() {
    let dir = scratch("missing");
    let out = kin(
        &dir,
        &[
            "report",
            "bridge_cmm.kin",
            "--fit",
            "nope.json",
            "-o",
            "r.html",
        ],
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("cannot read `nope.json`"),
        "{}",
        text(&out.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// A Chromium to render with: `/usr/bin/chromium`, or one of the usual names on `PATH`.
fn browser() -> Option<PathBuf> {
    let fixed = PathBuf::from("/usr/bin/chromium");
    if fixed.is_file() {
        return Some(fixed);
    }
    let path = std::env::var_os("PATH")?;
    [
        "chromium",
        "chromium-browser",
        "google-chrome",
        "google-chrome-stable",
    ]
    .iter()
    .flat_map(|name| std::env::split_paths(&path).map(move |d| d.join(name)))
    .find(|p| p.is_file())
}

/// Renders the page headless and checks the screenshot is a real picture of it.
fn screenshot(page: &Path, dir: &Path) {
    let Some(chromium) = browser() else {
        println!("browser check skipped: no chromium at /usr/bin/chromium or on PATH");
        return;
    };
    let png = dir.join("report.png");
    let profile = dir.join("chromium-profile");
    let page = page.canonicalize().expect("page path");
    let mut child = Command::new(&chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            &format!("--user-data-dir={}", profile.display()),
            &format!("--screenshot={}", png.display()),
            "--window-size=1280,4000",
            &format!("file://{}", page.display()),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("chromium starts");
    // A browser that hangs must not hang the test suite.
    let start = Instant::now();
    loop {
        match child.try_wait().expect("wait for chromium") {
            Some(_) => break,
            None if start.elapsed() > Duration::from_secs(180) => {
                let _ = child.kill();
                let _ = child.wait();
                panic!(
                    "{} did not finish the screenshot in 180 s",
                    chromium.display()
                );
            }
            None => std::thread::sleep(Duration::from_millis(100)),
        }
    }
    let bytes = std::fs::read(&png)
        .unwrap_or_else(|e| panic!("no screenshot from {}: {e}", chromium.display()));
    assert!(bytes.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG");
    // IHDR: width and height, big-endian, right after the signature and chunk header.
    let dim =
        |at: usize| u32::from_be_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    assert_eq!((dim(16), dim(20)), (1280, 4000));
    // A blank or error page compresses to a few kB; the report's plots do not.
    assert!(
        bytes.len() > 20_000,
        "screenshot is only {} bytes",
        bytes.len()
    );
    println!(
        "browser check: {} rendered the report, screenshot {} ({} bytes)",
        chromium.display(),
        png.display(),
        bytes.len()
    );
    if let Some(keep) = std::env::var_os("KIN_REPORT_SCREENSHOT") {
        std::fs::copy(&png, &keep).expect("keep the screenshot");
    }
}

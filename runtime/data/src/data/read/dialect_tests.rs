//! Files as spreadsheets and data-frame libraries write them: quoting, separators, decimal
//! commas, line ends, byte order marks and inch units.

use super::super::testing::machine;
use super::*;

fn read_points(text: &str, options: &ReadOptions) -> PointData {
    match read(text.as_bytes(), Path::new("t.csv"), &machine(), options) {
        Ok(Observations::Points(p)) => p,
        other => panic!("expected point data, got {other:?}"),
    }
}

fn points(text: &str) -> PointData {
    read_points(text, &ReadOptions::default())
}

fn problems(text: &str) -> Vec<Problem> {
    match read(
        text.as_bytes(),
        Path::new("t.csv"),
        &machine(),
        &ReadOptions::default(),
    ) {
        Err(ReadError::Invalid { problems, .. }) => problems,
        other => panic!("expected problems, got {other:?}"),
    }
}

fn assert_close(values: &[f64], expected: &[f64]) {
    assert_eq!(values.len(), expected.len(), "{values:?} vs {expected:?}");
    for (v, e) in values.iter().zip(expected) {
        let ok = (v.is_nan() && e.is_nan()) || (v - e).abs() <= 1e-12 * e.abs().max(1e-300);
        assert!(ok, "{values:?} vs {expected:?}");
    }
}

fn observed(p: &PointData, k: usize) -> &[f64] {
    p.observed[k].as_deref().unwrap_or_default()
}

/// Excel's "CSV UTF-8" in a locale with a decimal comma: a byte order mark, `;`, decimal commas,
/// CRLF, and quotes around a cell only when it holds the separator or a quote (here the header
/// was quoted by hand, as some macros and exporters do).
#[test]
fn excel_semicolon_decimal_comma_crlf_bom() {
    let text = "\u{feff}\"X[mm]\";\"Y [mm]\";\"Z[mm]\";C[deg];run;ex[um];ez[um]\r\n\
                12,5;0;-100;90;\"a;1\";1,25;\r\n\
                0;1,5e1;-100,0;0;b;-0,5;2\r\n";
    let p = points(text);
    assert_eq!(p.rows.line, vec![2, 3]);
    assert_close(&p.pose.axes[0], &[12.5e-3, 0.0]);
    assert_close(&p.pose.axes[1], &[0.0, 15e-3]);
    assert_close(&p.pose.axes[2], &[-0.1, -0.1]);
    assert_close(observed(&p, 0), &[1.25e-6, -0.5e-6]);
    assert_close(observed(&p, 2), &[f64::NAN, 2e-6]);
    let labels = p.rows.run.map(|r| r.labels).unwrap_or_default();
    assert_eq!(labels, ["a;1", "b"]);
}

#[test]
fn tab_separated_with_decimal_points_and_commas() {
    let p = points("X\tY\tZ\tC\tex\n1.5\t2,5\t0\t0\t3\n");
    assert_close(&p.pose.axes[0], &[1.5e-3]);
    assert_close(&p.pose.axes[1], &[2.5e-3]);
    assert_close(observed(&p, 0), &[3e-6]);
}

/// `DataFrame.to_csv(path)` with its defaults: the index as a first column without a name, `,`,
/// `\n`, NaN as an empty cell, quotes only around a cell holding a comma or a quote, floats in
/// Python's shortest form (`1e-06`).
#[test]
fn pandas_to_csv_defaults() {
    let text = ",X,Y,Z,C,run,ex,ey\n\
                0,0.0,0.0,-100.0,0.0,\"morning, 1\",1e-06,\n\
                1,250.5,0.0,-100.0,90.0,\"say \"\"hi\"\"\",-0.25,0.5\n";
    let p = points(text);
    assert_close(&p.pose.axes[0], &[0.0, 0.2505]);
    assert_close(observed(&p, 0), &[1e-12, -0.25e-6]);
    assert_close(observed(&p, 1), &[f64::NAN, 0.5e-6]);
    let labels = p.rows.run.map(|r| r.labels).unwrap_or_default();
    assert_eq!(labels, ["morning, 1", "say \"hi\""]);
}

#[test]
fn an_empty_name_elsewhere_than_first_is_still_an_error() {
    let ps = problems("X,,Y,Z,C,ex\n0,1,0,0,0,1\n");
    assert!(
        matches!(ps.as_slice(), [Problem::EmptyName { column: 3, .. }]),
        "{ps:?}"
    );
}

#[test]
fn inch_units() {
    let p = points("X[in],Y[mil],Z[mm],C,ex[uin],ey[µin]\n1,1000,0,0,100,1\n");
    assert_close(&p.pose.axes[0], &[0.0254]);
    assert_close(&p.pose.axes[1], &[0.0254]);
    assert_close(observed(&p, 0), &[2.54e-6]);
    assert_close(observed(&p, 1), &[2.54e-8]);
    let ps = problems("X[in],Y,Z,C,erx[mil]\n1,0,0,0,1\n");
    assert!(
        matches!(ps.as_slice(), [Problem::WrongDimension { column: 13, .. }]),
        "{ps:?}"
    );
}

#[test]
fn the_separator_can_be_given() {
    // A one-column-looking header: detection says comma, the caller knows better.
    let options = ReadOptions {
        delimiter: Some(b';'),
        poses: true,
        ..ReadOptions::default()
    };
    let text = "X;Y;Z;C\n1,5;0;0;0\n";
    let p = read_points(text, &options);
    assert_close(&p.pose.axes[0], &[1.5e-3]);
}

#[test]
fn quoting_mistakes_are_located() {
    let ps = problems("X,Y,Z,C,ex\n0,0,\"0,0,1\n0,0,0,0,\"1\"x\n");
    assert_eq!(
        ps,
        [
            Problem::UnclosedQuote { line: 2, column: 5 },
            Problem::AfterQuote {
                line: 3,
                column: 12,
                separator: "`,`"
            },
        ]
    );
    let text = format!("{}", ps[1]);
    assert!(text.contains("expected the separator `,`"), "{text}");
    let ps = problems("\"X,Y,Z,C,ex\n0,0,0,0,1\n");
    assert!(
        matches!(
            ps.first(),
            Some(Problem::UnclosedQuote { line: 1, column: 1 })
        ),
        "{ps:?}"
    );
}

#[test]
fn bad_cells_in_a_semicolon_file_name_row_and_column() {
    let ps = problems("X;Y;Z;C;ex\n0;1.234,5;0;0;\"1\"\n");
    assert_eq!(ps.len(), 1, "{ps:?}");
    let text = ps[0].to_string();
    assert!(
        text.starts_with("line 2, column 3 (`Y`): `1.234,5`: expected a number in mm"),
        "{text}"
    );
}

#[test]
fn a_decimal_comma_is_not_read_in_a_comma_file() {
    // `1,5` there is two cells; the count mismatch says so.
    let ps = problems("X,Y,Z,C,ex\n0,0,0,0,1,5\n");
    assert!(
        matches!(ps.as_slice(), [Problem::CellCount { found: 6, .. }]),
        "{ps:?}"
    );
}

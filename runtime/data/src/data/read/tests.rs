use std::path::PathBuf;

use kin_compiler::ir::Var;
use proptest::prelude::*;

use super::super::testing::machine;
use super::*;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn points(text: &str) -> PointData {
    match read_text(text, &machine()) {
        Ok(Observations::Points(p)) => p,
        other => panic!("expected point data, got {other:?}"),
    }
}

fn problems(text: &str) -> Vec<Problem> {
    problems_with(text, &ReadOptions::default())
}

fn problems_with(text: &str, options: &ReadOptions) -> Vec<Problem> {
    match read(text.as_bytes(), Path::new("t.csv"), &machine(), options) {
        Err(ReadError::Invalid { problems, .. }) => problems,
        other => panic!("expected problems, got {other:?}"),
    }
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * a.abs().max(b.abs()).max(1e-300)
}

fn assert_column(values: &[f64], expected: &[f64]) {
    assert_eq!(values.len(), expected.len(), "{values:?} vs {expected:?}");
    for (v, e) in values.iter().zip(expected) {
        assert!(
            (v.is_nan() && e.is_nan()) || close(*v, *e),
            "{values:?} vs {expected:?}"
        );
    }
}

const NAN: f64 = f64::NAN;

#[test]
fn fixture_points_convert_to_si() {
    let m = machine();
    let data = match read_file(&fixture("points_basic.csv"), &m, &ReadOptions::default()) {
        Ok(Observations::Points(p)) => p,
        other => panic!("{other:?}"),
    };
    assert_eq!(data.rows.line, vec![5, 8, 9]);
    assert_column(&data.pose.axes[0], &[0.0, 0.1, 0.2]);
    assert_column(&data.pose.axes[1], &[0.0, 0.0, 0.05]);
    assert_column(&data.pose.axes[2], &[-0.1, -0.1, -0.1]);
    let quarter = std::f64::consts::FRAC_PI_2;
    assert_column(&data.pose.axes[3], &[quarter, quarter, 0.0]);
    // An absolute temperature in degC by default: kelvin with the offset.
    assert_column(
        data.rows.inputs[0].as_deref().unwrap_or_default(),
        &[293.15, 293.65, 294.15],
    );
    assert!(data.rows.inputs[1].is_none() && data.rows.inputs[2].is_none());
    let [ex, ey, ez, erx, ery, erz] = &data.observed;
    assert_column(ex.as_deref().unwrap_or_default(), &[1.5e-6, -0.5e-6, 0.0]);
    assert_column(ey.as_deref().unwrap_or_default(), &[250e-9, NAN, 0.0]);
    assert_column(ez.as_deref().unwrap_or_default(), &[NAN, 2e-6, 0.0]);
    assert!(erx.is_none() && ery.is_none());
    let arcsec = std::f64::consts::PI / 648_000.0;
    assert_column(erz.as_deref().unwrap_or_default(), &[NAN, arcsec, 0.0]);
    assert_column(
        data.rows.time.as_deref().unwrap_or_default(),
        &[0.0, 90.0, 30.0],
    );
    let run = data.rows.run.as_ref();
    assert_eq!(run.map(|r| r.of_row.clone()), Some(vec![0, 0, 1]));
    assert_eq!(
        run.map(|r| r.labels.clone()),
        Some(vec!["a".into(), "b".into()])
    );
    assert_eq!(data.rows.tool, vec![0, 0, 0]);
    assert!(data.rows.tool_offset.is_none() && data.rows.artifact.is_none());
    assert!(close(data.value(Var::Axis(0), 1).unwrap_or(NAN), 0.1));
    assert!(close(data.value(Var::Input(0), 2).unwrap_or(NAN), 294.15));
    assert_eq!(data.value(Var::Input(1), 0), None);
    assert_eq!(data.value(Var::Direction(0), 0), None);
    assert_eq!(data.value(Var::Lag(0), 0), None);
    assert_eq!(data.value(Var::Axis(9), 0), None);
}

#[test]
fn fixture_lengths() {
    let m = machine();
    let data = match read_file(&fixture("lengths_ballbar.csv"), &m, &ReadOptions::default()) {
        Ok(Observations::Lengths(l)) => l,
        other => panic!("{other:?}"),
    };
    assert_eq!(data.len(), 3);
    assert_column(&data.poses[0].axes[0], &[0.0, 0.15, 0.0]);
    assert_column(&data.poses[1].axes[1], &[0.0, 0.15, 0.0]);
    assert_column(&data.dl, &[0.8e-6, -1.2e-6, 0.1e-6]);
    assert_column(
        data.poses[0].dir[0].as_deref().unwrap_or_default(),
        &[1.0, -1.0, 1.0],
    );
    assert_column(
        data.poses[1].dir[0].as_deref().unwrap_or_default(),
        &[-1.0, 1.0, 1.0],
    );
    assert!(data.poses[0].dir[1].is_none());
    assert_eq!(data.rows.tool, vec![1, 1, 0]);
    assert_eq!(data.rows.artifact_of(0), Some(0));
    assert_eq!(data.rows.artifact_of(2), None);
    assert_eq!(data.rows.run_of(2), 0);
    assert_eq!(data.value(Var::Direction(0), 1, 0), Some(-1.0));
    assert_eq!(data.value(Var::Axis(0), 2, 0), None);
}

#[test]
fn fixture_with_many_problems_reports_each_located() {
    let m = machine();
    let err = read_file(&fixture("points_bad.csv"), &m, &ReadOptions::default());
    let Err(ReadError::Invalid {
        path,
        problems,
        omitted,
    }) = err
    else {
        panic!("{err:?}")
    };
    assert!(path.ends_with("points_bad.csv"));
    assert_eq!(omitted, 0);
    let bad = |line, column, name: &str, text: &str, expected: &str| Problem::BadCell {
        line,
        column,
        name: name.into(),
        text: text.into(),
        expected: expected.into(),
    };
    let expected = vec![
        bad(4, 1, "X", "nan", "a finite number in mm"),
        bad(5, 9, "dir_X", "2", "+1 or -1"),
        Problem::UnknownTool {
            line: 6,
            column: 12,
            name: "tool".into(),
            text: "p3".into(),
            declared: vec!["probe".into(), "star".into()],
        },
        Problem::TimeOrder {
            line: 7,
            previous_line: 6,
            time: 1.0,
            previous: 3.0,
            unit: "s".into(),
            run: Some("r1".into()),
        },
        Problem::NothingObserved {
            line: 8,
            columns: vec!["ex".into(), "ey".into()],
        },
        Problem::CellCount {
            line: 9,
            found: 9,
            expected: 10,
        },
        bad(10, 18, "run", "", "a run label"),
        bad(11, 5, "Z", "3µ", "a number in mm"),
    ];
    assert_eq!(problems, expected);
    let text = ReadError::Invalid {
        path,
        problems,
        omitted,
    }
    .to_string();
    assert!(text.contains("8 problems"), "{text}");
    assert!(
        text.contains("line 6, column 12 (`tool`): unknown tool `p3`; declared tools: probe, star"),
        "{text}"
    );
    assert!(
        text.contains("line 4, column 1 (`X`): `nan`: expected a finite number in mm"),
        "{text}"
    );
    assert!(
        text.contains("line 10, column 18 (`run`): empty cell: expected a run label"),
        "{text}"
    );
}

#[test]
fn comments_blank_lines_crlf_and_spaces() {
    let text = "\u{feff}# c\n  # indented comment\n\n X , Y,Z,C , ex \r\n\t1 ,2, 3,4, 5 \r\n\r\n   \n# end\n";
    let p = points(text);
    assert_eq!(p.rows.line, vec![5]);
    assert_column(&p.pose.axes[0], &[1e-3]);
    assert_column(p.observed[0].as_deref().unwrap_or_default(), &[5e-6]);
}

#[test]
fn temperatures_absolute_and_rise() {
    let p = points("X,Y,Z,C,T_spindle[K],T_x,load,ex\n0,0,0,0,300,2.5,1.5,1\n");
    assert_column(p.rows.inputs[0].as_deref().unwrap_or_default(), &[300.0]);
    // A rise declared in degC has no offset.
    assert_column(p.rows.inputs[1].as_deref().unwrap_or_default(), &[2.5]);
    assert_column(p.rows.inputs[2].as_deref().unwrap_or_default(), &[1500.0]);
    let p = points("X,Y,Z,C,T_spindle[degC],T_x[K],load[N],ex\n0,0,0,0,-273.15,2.5,,1\n");
    assert_column(p.rows.inputs[0].as_deref().unwrap_or_default(), &[0.0]);
    assert_column(p.rows.inputs[1].as_deref().unwrap_or_default(), &[2.5]);
    assert_column(p.rows.inputs[2].as_deref().unwrap_or_default(), &[NAN]);
}

/// An absolute temperature below absolute zero is refused at its cell; a rise may be negative.
#[test]
fn an_absolute_temperature_below_absolute_zero_is_refused() {
    let found = problems("X,Y,Z,C,T_spindle[degC],T_x[K],load[N],ex\n0,0,0,0,-300,-2.5,,1\n");
    assert!(
        matches!(
            found.as_slice(),
            [Problem::BelowAbsoluteZero {
                line: 2,
                column: 9,
                ..
            }]
        ),
        "{found:?}"
    );
}

#[test]
fn tool_offsets_and_artifacts() {
    let p = points(
        "X,Y,Z,C,tool,tool_x,tool_y,tool_z[um],artifact,ez\n\
         0,0,0,0,star,1,2,3,plate,1\n\
         0,0,0,0,probe,,,,,1\n\
         0,0,0,0,star,,,,plate,1\n",
    );
    assert_eq!(p.rows.tool, vec![1, 0, 1]);
    assert_eq!(p.rows.tool_offset_of(0), Some([1e-3, 2e-3, 3e-6]));
    assert_eq!(p.rows.tool_offset_of(1), None);
    let artifact = p.rows.artifact.as_ref();
    assert_eq!(
        artifact.map(|a| a.of_row.clone()),
        Some(vec![Some(0), None, Some(0)])
    );
    assert_eq!(
        artifact.map(|a| a.labels.clone()),
        Some(vec!["plate".to_string()])
    );
}

#[test]
fn runs_may_interleave_each_in_time_order() {
    let p = points("X,Y,Z,C,run,time,ex\n0,0,0,0,a,0,1\n0,0,0,0,b,0,1\n0,0,0,0,a,5,1\n0,0,0,0,b,1,1\n0,0,0,0,a,5,1\n");
    assert_eq!(p.rows.run.map(|r| r.of_row), Some(vec![0, 1, 0, 1, 0]));
    // Without a run column the whole file is one run.
    let ps = problems("X,Y,Z,C,time[h],ex\n0,0,0,0,2,1\n0,0,0,0,1,1\n");
    assert_eq!(
        ps,
        vec![Problem::TimeOrder {
            line: 3,
            previous_line: 2,
            time: 1.0,
            previous: 2.0,
            unit: "h".into(),
            run: None
        }]
    );
}

#[test]
fn direction_spellings() {
    let p = points("X,Y,Z,C,dir_X,dir_C,ex\n0,0,0,0,+1,-1,1\n0,0,0,0,+,-,1\n0,0,0,0,1,\u{2212}1,1\n0,0,0,0,1.0,-1e0,1\n");
    assert_eq!(p.pose.dir[0], Some(vec![1.0, 1.0, 1.0, 1.0]));
    assert_eq!(p.pose.dir[3], Some(vec![-1.0, -1.0, -1.0, -1.0]));
    for bad in ["0", "", "+2", "up", "nan"] {
        let text = format!("X,Y,Z,C,dir_X,ex\n0,0,0,0,{bad},1\n");
        assert!(
            matches!(problems(&text).as_slice(), [Problem::BadCell { expected, .. }] if expected == "+1 or -1"),
            "{bad}"
        );
    }
}

#[test]
fn non_numbers_are_refused() {
    for bad in [
        "nan",
        "NaN",
        "inf",
        "-infinity",
        "1e999",
        "1,5",
        "0x10",
        "1.2.3",
        "--1",
        "1 2",
        "",
    ] {
        let text = format!("X,Y,Z,C,ex\n{bad},0,0,0,1\n");
        let ps = problems(&text);
        assert_eq!(ps.len(), 1, "{bad}: {ps:?}");
        let ok = match &ps[0] {
            // What Rust reads as a number but is not finite is named as such.
            Problem::BadCell { name, expected, .. } if bad.parse::<f64>().is_ok() => {
                name == "X" && expected == "a finite number in mm"
            }
            Problem::BadCell { name, expected, .. } => name == "X" && expected == "a number in mm",
            Problem::CellCount { .. } => bad.contains(','),
            _ => false,
        };
        assert!(ok, "{bad}: {ps:?}");
    }
    for good in ["1", "+1", "-1.5", ".5", "5.", "1e3", "1E-3", " 7 "] {
        let text = format!("X,Y,Z,C,ex\n{good},0,0,0,1\n");
        let p = points(&text);
        let expected: f64 = good.trim().parse().unwrap_or(NAN);
        assert_column(&p.pose.axes[0], &[expected * 1e-3]);
    }
}

#[test]
fn header_problems() {
    assert_eq!(problems(""), vec![Problem::NoHeader]);
    assert_eq!(problems("# only a comment\n\n"), vec![Problem::NoHeader]);
    assert_eq!(problems("X,Y,Z,C,ex\n# no rows\n"), vec![Problem::NoRows]);
    assert_eq!(
        problems("X,Y,ex\n0,0,1\n"),
        vec![Problem::MissingColumns {
            names: vec!["Z".into(), "C".into()]
        }]
    );
    assert_eq!(
        problems("X,Y,Z,C\n0,0,0,0\n"),
        vec![Problem::NoObservedColumn]
    );
    assert_eq!(
        problems("X,Y,Z,C,ex,wobble\n0,0,0,0,1,2\n"),
        vec![Problem::UnknownColumn {
            line: 1,
            column: 12,
            name: "wobble".into(),
            hint: None
        }]
    );
    assert_eq!(
        problems("X,Y,Z,C,ex,x,Ex\n0,0,0,0,1,2,3\n"),
        vec![
            Problem::UnknownColumn {
                line: 1,
                column: 12,
                name: "x".into(),
                hint: Some("did you mean `X`?".into())
            },
            Problem::UnknownColumn {
                line: 1,
                column: 14,
                name: "Ex".into(),
                hint: Some("did you mean `ex`?".into())
            }
        ]
    );
    assert_eq!(
        problems("X,Y,Z,C,ex,X[um]\n0,0,0,0,1,2\n"),
        vec![Problem::DuplicateColumn {
            line: 1,
            column: 12,
            name: "X".into(),
            first: 1
        }]
    );
    assert_eq!(
        problems("X[deg],Y,Z,C[mm],ex[urad],erx[um/m]\n0,0,0,0,1,2\n"),
        vec![
            Problem::WrongDimension {
                line: 1,
                column: 1,
                name: "X".into(),
                unit: "deg".into(),
                found: "angle".into(),
                expected: "length".into()
            },
            Problem::WrongDimension {
                line: 1,
                column: 12,
                name: "C".into(),
                unit: "mm".into(),
                found: "length".into(),
                expected: "angle".into()
            },
            Problem::WrongDimension {
                line: 1,
                column: 18,
                name: "ex".into(),
                unit: "urad".into(),
                found: "angle".into(),
                expected: "length".into()
            },
            Problem::WrongDimension {
                line: 1,
                column: 27,
                name: "erx".into(),
                unit: "um/m".into(),
                found: "dimensionless".into(),
                expected: "angle".into()
            },
        ]
    );
    assert_eq!(
        problems("X[furlong],Y,Z,C,ex\n0,0,0,0,1\n"),
        vec![Problem::BadUnit {
            line: 1,
            column: 1,
            name: "X".into(),
            error: UnitError::UnknownAtom {
                name: "furlong".into(),
                offset: 0
            }
        }]
    );
    assert_eq!(
        problems("X,Y,Z,C,ex,run[s]\n0,0,0,0,1,a\n"),
        vec![Problem::UnitNotAllowed {
            line: 1,
            column: 12,
            name: "run".into()
        }]
    );
    assert!(matches!(
        problems("X,Y,Z,C,ex,T_x[degC\n0,0,0,0,1,2\n").as_slice(),
        [Problem::BadName { column: 12, .. }]
    ));
    assert!(matches!(
        problems("X,Y,Z,C,ex,\n0,0,0,0,1,\n").as_slice(),
        [Problem::EmptyName { column: 12, .. }]
    ));
    assert_eq!(
        problems("X,Y,Z,C,ex,tool_x,tool_z\n0,0,0,0,1,2,3\n"),
        vec![Problem::IncompleteToolColumns {
            missing: vec!["tool_y".into()]
        }]
    );
}

#[test]
fn row_problems() {
    assert_eq!(
        problems("X,Y,Z,C,ex,tool_x,tool_y,tool_z\n0,0,0,0,1,1,,3\n"),
        vec![Problem::IncompleteToolOffset {
            line: 2,
            empty: vec!["tool_y".into()]
        }]
    );
    assert_eq!(
        problems("X,Y,Z,C,ex,ey\n0,0,0,0,,\n"),
        vec![Problem::NothingObserved {
            line: 2,
            columns: vec!["ex".into(), "ey".into()]
        }]
    );
    assert!(matches!(
        problems("X,Y,Z,C,ex,tool\n0,0,0,0,1,\n").as_slice(),
        [Problem::BadCell { expected, .. }] if expected == "a tool name"
    ));
    // An empty time cell cannot be ordered.
    assert!(matches!(
        problems("X,Y,Z,C,ex,time\n0,0,0,0,1,\n").as_slice(),
        [Problem::BadCell { expected, .. }] if expected == "a number in s"
    ));
    // Observed errors default to the machine's error unit.
    assert!(matches!(
        problems("X,Y,Z,C,ex\n0,0,0,0,x\n").as_slice(),
        [Problem::BadCell { expected, .. }] if expected == "a number in um"
    ));
}

#[test]
fn columns_count_characters_not_bytes() {
    let ps = problems("X,Y,Z,C,artifact,ex\n0,0,0,0,µµµ,oops\n");
    assert!(
        matches!(
            ps.as_slice(),
            [Problem::BadCell {
                column: 13,
                line: 2,
                ..
            }]
        ),
        "{ps:?}"
    );
}

#[test]
fn length_files() {
    let text = "X_1,Y_1,Z_1,C_1,X_2,Y_2,Z_2,C_2,dL,T_x\n0,0,0,0,1,1,1,0,1,\n";
    let Ok(Observations::Lengths(l)) = read_text(text, &machine()) else {
        panic!()
    };
    assert_column(&l.dl, &[1e-6]);
    assert_column(l.rows.inputs[1].as_deref().unwrap_or_default(), &[NAN]);
    // dL is required per row.
    let ps = problems("X_1,Y_1,Z_1,C_1,X_2,Y_2,Z_2,C_2,dL\n0,0,0,0,1,1,1,0,\n");
    assert!(matches!(ps.as_slice(), [Problem::BadCell { name, .. }] if name == "dL"));
    // Point-file names in a length file, with the reason.
    let ps = problems("X,Y_1,Z_1,C_1,X_2,Y_2,Z_2,C_2,dL,ex\n0,0,0,0,1,1,1,0,1,1\n");
    let hints: Vec<Option<String>> = ps
        .iter()
        .filter_map(|p| match p {
            Problem::UnknownColumn { hint, .. } => Some(hint.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(
        hints,
        vec![
            Some("a length file names each axis twice: `X_1` and `X_2`".into()),
            Some("a length file observes `dL`".into())
        ]
    );
    assert!(ps.contains(&Problem::MissingColumns {
        names: vec!["X_1".into()]
    }));
    let ps = problems("X,Y,Z,C,X_1,ex\n0,0,0,0,1,1\n");
    assert!(
        matches!(ps.as_slice(), [Problem::UnknownColumn { hint: Some(h), .. }] if h.contains("length file"))
    );
}

#[test]
fn ignored_columns_are_not_read() {
    let options = ReadOptions {
        ignore: vec!["operator".into(), "note".into()],
        ..ReadOptions::default()
    };
    let text = "X,Y,Z,C,operator,ex,note,note\n0,0,0,0,Ann,1,x,y\n";
    let Ok(Observations::Points(p)) = read(text.as_bytes(), Path::new("t"), &machine(), &options)
    else {
        panic!()
    };
    assert_eq!(p.len(), 1);
    // An ignored dL makes it a point file again.
    let options = ReadOptions {
        ignore: vec!["dL".into()],
        ..ReadOptions::default()
    };
    let ps = problems_with("X,Y,Z,C,dL\n0,0,0,0,1\n", &options);
    assert_eq!(ps, vec![Problem::NoObservedColumn]);
}

#[test]
fn pose_files_need_no_observations() {
    let options = ReadOptions {
        poses: true,
        ..ReadOptions::default()
    };
    let read_poses = |text: &str| read(text.as_bytes(), Path::new("p"), &machine(), &options);
    let Ok(Observations::Points(p)) = read_poses("X,Y,Z,C\n1,2,3,4\n") else {
        panic!()
    };
    assert_eq!(p.len(), 1);
    assert!(p.observed.iter().all(Option::is_none));
    let Ok(Observations::Points(p)) = read_poses("X,Y,Z,C,ex\n1,2,3,4,\n") else {
        panic!()
    };
    assert!(p.observed[0].as_ref().is_some_and(|v| v[0].is_nan()));
    let text = "X_1,Y_1,Z_1,C_1,X_2,Y_2,Z_2,C_2\n0,0,0,0,1,1,1,0\n";
    let Ok(Observations::Lengths(l)) = read_poses(text) else {
        panic!()
    };
    assert!(l.dl.len() == 1 && l.dl[0].is_nan());
    let text = "X_1,Y_1,Z_1,C_1,X_2,Y_2,Z_2,C_2,dL\n0,0,0,0,1,1,1,0,\n";
    assert!(matches!(read_poses(text), Ok(Observations::Lengths(_))));
    // Axes are still required, and the same text is no measurement file.
    let ps = problems_with("X,Y,Z\n1,2,3\n", &options);
    assert_eq!(
        ps,
        vec![Problem::MissingColumns {
            names: vec!["C".into()]
        }]
    );
    assert_eq!(
        problems("X,Y,Z,C\n1,2,3,4\n"),
        vec![Problem::NoObservedColumn]
    );
}

#[test]
fn invalid_utf8_is_located() {
    let mut bytes = b"X,Y,Z,C,ex\n0,0,0,\xc2\xb5,".to_vec();
    bytes.extend_from_slice(&[0xff, b'\n']);
    let err = read(&bytes, Path::new("t"), &machine(), &ReadOptions::default());
    let Err(ReadError::Invalid { problems, .. }) = err else {
        panic!()
    };
    assert_eq!(problems, vec![Problem::NotUtf8 { line: 2, column: 9 }]);
}

#[test]
fn problems_are_capped() {
    let mut text = String::from("X,Y,Z,C,ex\n");
    for _ in 0..50 {
        text.push_str("a,0,0,0,1\n");
    }
    let err = read_text(&text, &machine());
    let Err(ReadError::Invalid {
        problems, omitted, ..
    }) = err
    else {
        panic!()
    };
    assert_eq!(problems.len(), MAX_PROBLEMS);
    assert_eq!(omitted, 50 - MAX_PROBLEMS);
    let Some(Problem::BadCell { line, .. }) = problems.last() else {
        panic!()
    };
    assert_eq!(*line, 21);
}

#[test]
fn io_errors_name_the_path() {
    let err = read_file(
        Path::new("/nonexistent/x.csv"),
        &machine(),
        &ReadOptions::default(),
    );
    assert!(matches!(&err, Err(ReadError::Io { path, .. }) if path.ends_with("x.csv")));
}

/// The lines of `text` a reader must turn into rows: everything after the header that is
/// neither blank nor a comment. A byte-order mark opening the file is no part of its first line
/// (the reader drops it, as spreadsheet programs write one).
fn data_lines(text: &str) -> usize {
    text.strip_prefix('\u{feff}')
        .unwrap_or(text)
        .split('\n')
        .map(|l| l.strip_suffix('\r').unwrap_or(l))
        .filter(|l| !skipped(l))
        .count()
        .saturating_sub(1)
}

const VALID: &str = "# fixture\nX[mm],Y,Z,C[deg],T_spindle,T_x,dir_X,tool,run,time,artifact,tool_x,tool_y,tool_z,ex,ey[um],erz\n\
1,2,3,4,20,1,+1,probe,a,0,p,,,,1,2,3\n\
5,6,7,8,21,,-1,star,a,1,,1,2,3,,,4\n\
\n\
9,10,11,12,,2,+,probe,b,0,p,,,,0.5,,\n";

proptest! {
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = read(&bytes, Path::new("r"), &machine(), &ReadOptions::default());
    }

    #[test]
    fn random_text_never_panics(text in "[-+0-9a-zA-Z_\\[\\]/^#,. \t\r\nµ]{0,300}") {
        let _ = read_text(&text, &machine());
        let with_header = format!("X,Y,Z,C,tool,run,time,dir_X,ex\n{text}");
        let _ = read_text(&with_header, &machine());
    }

    /// Edits of a valid file either read with one row per data line, or fail with problems:
    /// nothing is dropped silently.
    #[test]
    fn mutations_never_panic_nor_drop_rows(
        edits in proptest::collection::vec((any::<prop::sample::Index>(), 0u8..4, any::<char>()), 1..6)
    ) {
        let mut text: Vec<char> = VALID.chars().collect();
        for (at, op, c) in edits {
            if text.is_empty() { break; }
            let i = at.index(text.len());
            match op {
                0 => { text.remove(i); }
                1 => text.insert(i, c),
                2 => text[i] = c,
                _ => text.insert(i, [',', '\n', '#', ' '][i % 4]),
            }
        }
        let text: String = text.into_iter().collect();
        match read_text(&text, &machine()) {
            Ok(obs) => {
                prop_assert_eq!(obs.len(), data_lines(&text));
                if let Observations::Points(p) = &obs {
                    for axis in &p.pose.axes {
                        prop_assert_eq!(axis.len(), p.len());
                        prop_assert!(axis.iter().all(|v| v.is_finite()));
                    }
                }
            }
            Err(ReadError::Invalid { problems, .. }) => prop_assert!(!problems.is_empty()),
            Err(e) => prop_assert!(false, "unexpected {e}"),
        }
    }
}

/// A mutation the property test found its oracle wrong on: a byte-order mark before the
/// opening comment leaves it a comment, so the file has its three rows.
#[test]
fn a_byte_order_mark_before_a_comment_keeps_every_row() {
    let text = format!("\u{feff}{VALID}");
    assert_eq!(data_lines(&text), 3);
    assert_eq!(points(&text).len(), 3);
}

#[test]
fn the_mutation_base_is_valid() {
    let p = points(VALID);
    assert_eq!(p.len(), 3);
    assert_eq!(p.rows.line, vec![3, 4, 6]);
}

/// Non-finite cells and magnitudes that would overflow a fit are stopped at the cell, with the
/// bound in the column's unit; the largest plausible values still read.
#[test]
fn absurd_magnitudes_are_rejected_at_the_cell() {
    let found = problems("X,Y,Z,C,ex\n1e160,0,0,0,1\n0,0,0,0,1e308\n0,0,0,0,inf\n0,0,0,0,1e400\n");
    assert_eq!(
        found,
        vec![
            Problem::Implausible {
                line: 2,
                column: 1,
                name: "X".into(),
                text: "1e160".into(),
                what: "axis position",
                limit: "1e7 mm".into(),
            },
            Problem::Implausible {
                line: 3,
                column: 9,
                name: "ex".into(),
                text: "1e308".into(),
                what: "error",
                limit: "1e6 um".into(),
            },
            Problem::BadCell {
                line: 4,
                column: 9,
                name: "ex".into(),
                text: "inf".into(),
                expected: "a finite number in um".into(),
            },
            Problem::BadCell {
                line: 5,
                column: 9,
                name: "ex".into(),
                text: "1e400".into(),
                expected: "a finite number in um".into(),
            },
        ]
    );
    assert!(found[1].to_string().contains(
        "line 3, column 9 (`ex`): `1e308` is beyond the largest plausible error, ±1e6 um"
    ));
    let p = points("X,Y,Z,C,ex\n1e7,0,0,0,1e6\n");
    assert_column(&p.pose.axes[0], &[MAX_POSITION]);
    // An error whose square underflows (data scaled by 1e-300 gave σ̂ = 0 and R² = NaN) is
    // refused; zero and the smallest meaningful error read.
    let found = problems("X,Y,Z,C,ex\n0,0,0,0,1e-300\n");
    assert!(
        matches!(&found[..], [Problem::Negligible { line: 2, column: 9, limit, .. }] if limit == "1e-94 um"),
        "{found:?}"
    );
    let p = points("X,Y,Z,C,ex,ey\n0,0,0,0,0,1e-94\n");
    assert_eq!(p.len(), 1);
    // An empty observed cell still means "not observed".
    let p = points("X,Y,Z,C,ex,ey\n0,0,0,0,,1\n");
    assert!(p.observed[0].as_ref().is_some_and(|v| v[0].is_nan()));
}

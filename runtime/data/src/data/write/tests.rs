use std::path::Path;

use proptest::prelude::*;

use super::super::testing::machine;
use super::super::{read, ExtraColumn, ExtraQuantity, Groups, ReadOptions};
use super::*;

const NAN: f64 = f64::NAN;

fn same(a: &[f64], b: &[f64]) -> bool {
    // Unit conversion on the way out and back may cost an ulp or two; nothing more.
    a.len() == b.len()
        && a.iter().zip(b).all(|(x, y)| {
            (x.is_nan() && y.is_nan()) || (x - y).abs() <= 4.0 * f64::EPSILON * x.abs().max(y.abs())
        })
}

fn same_opt(a: &Option<Vec<f64>>, b: &Option<Vec<f64>>) -> bool {
    match (a, b) {
        (Some(a), Some(b)) => same(a, b),
        (None, None) => true,
        _ => false,
    }
}

fn same_rows(a: &Rows, b: &Rows) -> bool {
    let offsets = match (&a.tool_offset, &b.tool_offset) {
        (Some(x), Some(y)) => x.iter().zip(y).all(|(x, y)| same(x, y)),
        (None, None) => true,
        _ => false,
    };
    same_opt(&a.time, &b.time)
        && a.run == b.run
        && a.artifact == b.artifact
        && a.tool == b.tool
        && offsets
        && a.inputs.len() == b.inputs.len()
        && a.inputs.iter().zip(&b.inputs).all(|(x, y)| same_opt(x, y))
}

fn same_pose(a: &Pose, b: &Pose) -> bool {
    a.axes.len() == b.axes.len()
        && a.axes.iter().zip(&b.axes).all(|(x, y)| same(x, y))
        && dirs(a) == dirs(b)
}

/// An empty `dir` list and a list of `None` both mean "no direction columns".
fn dirs(p: &Pose) -> Vec<Option<Vec<f64>>> {
    let mut d = p.dir.clone();
    d.resize(p.axes.len(), None);
    d
}

fn sample_points() -> PointData {
    PointData {
        rows: Rows {
            line: vec![0; 3],
            time: Some(vec![0.0, 60.0, 1.5]),
            run: Some(Groups {
                of_row: vec![0, 0, 1],
                labels: vec!["warm up".into(), "r#2".into()],
            }),
            artifact: Some(Groups {
                of_row: vec![Some(0), None, Some(0)],
                labels: vec!["hole plate".into()],
            }),
            tool: vec![0, 1, 1],
            tool_offset: Some([
                vec![0.01, NAN, 0.0],
                vec![0.02, NAN, 1e-9],
                vec![-0.2, NAN, 3.0],
            ]),
            inputs: vec![
                Some(vec![293.15, NAN, 300.0]),
                None,
                Some(vec![10.0, 20.0, NAN]),
            ],
        },
        pose: Pose {
            axes: vec![
                vec![0.1, 0.2, 0.3],
                vec![0.0, -0.0, 1e-12],
                vec![-0.4, 0.4, 123.456],
                vec![0.5, 1.0, 6.0],
            ],
            dir: vec![
                Some(vec![1.0, -1.0, 1.0]),
                None,
                None,
                Some(vec![-1.0, -1.0, 1.0]),
            ],
        },
        observed: [
            Some(vec![1e-6, NAN, 2.5e-7]),
            None,
            Some(vec![NAN, 3e-6, 1e-20]),
            None,
            None,
            Some(vec![1e-6, 2e-6, NAN]),
        ],
        absolute: None,
    }
}

fn write_to_string(data: &PointData, options: &WriteOptions) -> String {
    let mut out = Vec::new();
    if let Err(e) = write_points(&mut out, &machine(), data, options) {
        panic!("{e}");
    }
    String::from_utf8(out).unwrap_or_default()
}

#[test]
fn points_round_trip() {
    let data = sample_points();
    let options = WriteOptions {
        comments: vec!["simulated\nsecond line".into()],
        units: None,
        ..WriteOptions::default()
    };
    let text = write_to_string(&data, &options);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "# simulated");
    assert_eq!(lines[1], "# second line");
    assert_eq!(
        lines[2],
        "X[mm],Y[mm],Z[mm],C[deg],dir_X,dir_C,T_spindle[degC],load[kN],time[s],run,tool,\
         tool_x[mm],tool_y[mm],tool_z[mm],artifact,ex[um],ez[um],erz[urad]"
    );
    assert!(lines[3].starts_with("100,0,-400,"), "{}", lines[3]);
    assert!(
        lines[3].contains(",+1,-1,20,0.01,0,warm up,probe,10,20,-200,hole plate,1,,1"),
        "{}",
        lines[3]
    );
    let back = match read(
        text.as_bytes(),
        Path::new("w"),
        &machine(),
        &ReadOptions::default(),
    ) {
        Ok(Observations::Points(p)) => p,
        other => panic!("{other:?}\n{text}"),
    };
    assert_eq!(back.rows.line, vec![4, 5, 6]);
    assert!(same_rows(&back.rows, &data.rows), "{back:?}");
    assert!(same_pose(&back.pose, &data.pose), "{back:?}");
    for (a, b) in back.observed.iter().zip(&data.observed) {
        assert!(same_opt(a, b), "{a:?} {b:?}");
    }
}

#[test]
fn extra_columns_follow_the_observations_and_read_back_only_when_ignored() {
    let data = sample_points();
    let options = WriteOptions {
        extra: vec![
            ExtraColumn {
                name: "u_ex".into(),
                quantity: ExtraQuantity::Error,
                values: vec![2e-8, NAN, 3e-8],
            },
            ExtraColumn {
                name: "u_erz".into(),
                quantity: ExtraQuantity::Tilt,
                values: vec![1e-7, 1e-7, 1e-7],
            },
        ],
        ..WriteOptions::default()
    };
    let text = write_to_string(&data, &options);
    let header = text.lines().next().unwrap_or("");
    assert!(
        header.ends_with(",ex[um],ez[um],erz[urad],u_ex[um],u_erz[urad]"),
        "{header}"
    );
    assert!(
        text.lines()
            .nth(1)
            .is_some_and(|l| l.ends_with(",0.02,0.1")),
        "{text}"
    );
    assert!(
        text.lines().nth(2).is_some_and(|l| l.ends_with(",,0.1")),
        "{text}"
    );
    let plain = read(
        text.as_bytes(),
        Path::new("w"),
        &machine(),
        &ReadOptions::default(),
    );
    assert!(plain.is_err(), "unknown columns must not read silently");
    let ignoring = ReadOptions {
        ignore: vec!["u_ex".into(), "u_erz".into()],
        ..ReadOptions::default()
    };
    match read(text.as_bytes(), Path::new("w"), &machine(), &ignoring) {
        Ok(Observations::Points(p)) => {
            for (a, b) in p.observed.iter().zip(&data.observed) {
                assert!(same_opt(a, b), "{a:?} {b:?}");
            }
        }
        other => panic!("{other:?}\n{text}"),
    }
    let short = WriteOptions {
        extra: vec![ExtraColumn {
            name: "u_ex".into(),
            quantity: ExtraQuantity::Error,
            values: vec![1e-8],
        }],
        ..WriteOptions::default()
    };
    assert!(write_points(&mut Vec::new(), &machine(), &data, &short).is_err());
}

#[test]
fn lengths_round_trip_in_other_units() {
    let m = machine();
    let pose = |x: f64| Pose {
        axes: vec![vec![x, 0.0], vec![0.0, x], vec![0.0, 0.0], vec![0.0, 0.1]],
        dir: vec![],
    };
    let data = LengthData {
        rows: Rows {
            line: vec![0, 0],
            tool: vec![0, 0],
            inputs: vec![],
            ..Rows::default()
        },
        poses: [pose(0.0), pose(0.15)],
        dl: vec![1e-6, -2e-7],
    };
    let mut units = m.units.clone();
    units.length = Unit::parse("m").unwrap_or_else(|e| panic!("{e}"));
    units.error = Unit::parse("nm").unwrap_or_else(|e| panic!("{e}"));
    let options = WriteOptions {
        comments: vec![],
        units: Some(units),
        ..WriteOptions::default()
    };
    let mut out = Vec::new();
    if let Err(e) = write_lengths(&mut out, &m, &data, &options) {
        panic!("{e}");
    }
    let text = String::from_utf8(out).unwrap_or_default();
    assert!(
        text.starts_with("X_1[m],Y_1[m],Z_1[m],C_1[deg],X_2[m],"),
        "{text}"
    );
    assert!(text.contains(",dL[nm]\n"), "{text}");
    let back = match read(text.as_bytes(), Path::new("w"), &m, &ReadOptions::default()) {
        Ok(Observations::Lengths(l)) => l,
        other => panic!("{other:?}\n{text}"),
    };
    assert!(same(&back.dl, &data.dl));
    assert!(back.rows.inputs.iter().all(Option::is_none));
    for (a, b) in back.poses.iter().zip(&data.poses) {
        assert!(same(&a.axes[0], &b.axes[0]) && same(&a.axes[3], &b.axes[3]));
        assert!(a.dir.iter().all(Option::is_none));
    }
}

#[test]
fn write_file_writes_nothing_when_data_is_bad() {
    let dir = std::env::temp_dir().join(format!("kin-data-write-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join("bad.csv");
    let mut data = sample_points();
    data.pose.axes[0][1] = NAN;
    let r = write_file(
        &path,
        &machine(),
        &Observations::Points(data),
        &WriteOptions::default(),
    );
    assert!(matches!(r, Err(WriteError::Value { row: 1, .. })), "{r:?}");
    assert!(!path.exists());
    let good = Observations::Points(sample_points());
    let r = write_file(&path, &machine(), &good, &WriteOptions::default());
    assert!(r.is_ok(), "{r:?}");
    let back = super::super::read_file(&path, &machine(), &ReadOptions::default());
    assert!(
        matches!(back, Ok(Observations::Points(ref p)) if p.len() == 3),
        "{back:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

fn write_error(data: &PointData) -> WriteError {
    match write_points(Vec::new(), &machine(), data, &WriteOptions::default()) {
        Err(e) => e,
        Ok(()) => panic!("expected an error"),
    }
}

#[test]
fn unwritable_data_is_refused() {
    let mut d = sample_points();
    d.pose.dir[0] = Some(vec![1.0, 0.0, 1.0]);
    assert!(matches!(
        write_error(&d),
        WriteError::Value {
            row: 1,
            expected: "+1 or -1",
            ..
        }
    ));

    let mut d = sample_points();
    d.rows.tool[2] = 7;
    assert!(matches!(
        write_error(&d),
        WriteError::Tool {
            row: 2,
            index: 7,
            count: 2
        }
    ));

    for label in ["", " a", "a,b", "a\nb"] {
        let mut d = sample_points();
        if let Some(run) = d.rows.run.as_mut() {
            run.labels[0] = label.into();
        }
        assert!(
            matches!(write_error(&d), WriteError::Label { .. }),
            "{label:?}"
        );
    }

    let mut d = sample_points();
    d.observed = Default::default();
    assert!(matches!(write_error(&d), WriteError::NoObservedColumn));

    let mut d = sample_points();
    for o in d.observed.iter_mut().flatten() {
        o[1] = NAN;
    }
    assert!(matches!(
        write_error(&d),
        WriteError::NothingObserved { row: 1 }
    ));

    let mut d = sample_points();
    if let Some(t) = d.rows.tool_offset.as_mut() {
        t[1][0] = NAN;
    }
    assert!(matches!(
        write_error(&d),
        WriteError::IncompleteToolOffset { row: 0 }
    ));

    let mut d = sample_points();
    d.pose.axes[2].pop();
    assert!(matches!(
        write_error(&d),
        WriteError::RowCount {
            found: 2,
            rows: 3,
            ..
        }
    ));

    let mut d = sample_points();
    d.pose.axes.pop();
    assert!(matches!(
        write_error(&d),
        WriteError::AxisCount {
            found: 3,
            expected: 4
        }
    ));

    let mut d = sample_points();
    d.rows.inputs.push(None);
    d.rows.inputs.push(None);
    assert!(matches!(
        write_error(&d),
        WriteError::InputCount {
            found: 5,
            expected: 3
        }
    ));

    let mut d = sample_points();
    if let Some(a) = d.rows.artifact.as_mut() {
        a.of_row[0] = Some(3);
    }
    assert!(matches!(
        write_error(&d),
        WriteError::LabelId { row: 0, id: 3, .. }
    ));

    let mut d = sample_points();
    d.pose.axes[0][0] = f64::INFINITY;
    assert!(matches!(write_error(&d), WriteError::Value { row: 0, .. }));

    let empty = PointData {
        observed: [Some(vec![]), None, None, None, None, None],
        pose: Pose {
            axes: vec![vec![]; 4],
            dir: vec![],
        },
        ..PointData::default()
    };
    assert!(matches!(write_error(&empty), WriteError::NoRows));

    let mut units = machine().units;
    units.tilt = Unit::parse("um/m").unwrap_or_else(|e| panic!("{e}"));
    let r = write_points(
        Vec::new(),
        &machine(),
        &sample_points(),
        &WriteOptions {
            comments: vec![],
            units: Some(units),
            ..WriteOptions::default()
        },
    );
    assert!(matches!(
        r,
        Err(WriteError::WrongDimension {
            quantity: "tilts",
            ..
        })
    ));
}

proptest! {
    #[test]
    fn random_values_round_trip(
        rows in proptest::collection::vec(
            (proptest::array::uniform4(-2.0f64..2.0), proptest::array::uniform3(-1e-3f64..1e-3), 250.0f64..350.0),
            1..20,
        ),
        exponent in -12i32..3,
    ) {
        let scale = 10f64.powi(exponent);
        let n = rows.len();
        let mut data = PointData {
            rows: Rows { line: vec![0; n], tool: vec![0; n], inputs: vec![Some(vec![]), None, None], ..Rows::default() },
            pose: Pose { axes: vec![vec![]; 4], dir: vec![] },
            observed: [Some(vec![]), Some(vec![]), Some(vec![]), None, None, None],
            absolute: None,
        };
        for (axes, errors, t) in &rows {
            for (column, v) in data.pose.axes.iter_mut().zip(axes) {
                column.push(v * scale);
            }
            for (column, e) in data.observed.iter_mut().flatten().zip(errors) {
                column.push(e * scale);
            }
            if let Some(Some(ts)) = data.rows.inputs.first_mut() {
                ts.push(*t);
            }
        }
        let mut out = Vec::new();
        prop_assert!(write_points(&mut out, &machine(), &data, &WriteOptions::default()).is_ok());
        let back = read(&out, Path::new("p"), &machine(), &ReadOptions::default());
        let Ok(Observations::Points(back)) = back else {
            return Err(TestCaseError::fail(format!("{back:?}")));
        };
        prop_assert!(same_pose(&back.pose, &data.pose));
        prop_assert!(same_rows(&back.rows, &data.rows));
        for (a, b) in back.observed.iter().zip(&data.observed) {
            prop_assert!(same_opt(a, b));
        }
    }
}

#[test]
fn the_json_document_holds_what_the_file_holds() {
    // The file's text, read back cell by cell (no label of the sample holds a comma), against
    // the document built from the same columns: names, units, the numbers the digits read back
    // to, labels as strings, empty cells as null.
    let data = sample_points();
    let options = WriteOptions {
        comments: vec!["made here\nsecond line".into()],
        ..WriteOptions::default()
    };
    let text = write_to_string(&data, &options);
    let doc = measurements_json(&machine(), &Observations::Points(data), &options).expect("json");
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("# made here"));
    assert_eq!(lines.next(), Some("# second line"));
    assert_eq!(
        doc["comments"],
        serde_json::json!(["made here", "second line"])
    );
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let columns = doc["columns"].as_array().expect("columns");
    assert_eq!(columns.len(), header.len());
    let mut labels = 0;
    for (h, c) in header.iter().zip(columns) {
        match h.split_once('[') {
            Some((name, unit)) => {
                assert_eq!(c["name"], name);
                assert_eq!(c["unit"], unit.trim_end_matches(']'));
            }
            None => {
                assert_eq!(c["name"], *h);
                assert!(c["unit"].is_null());
            }
        }
    }
    let rows = doc["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 3);
    for (line, row) in lines.zip(rows) {
        for ((cell, value), h) in line
            .split(',')
            .zip(row.as_array().expect("row"))
            .zip(&header)
        {
            if cell.is_empty() {
                assert!(value.is_null(), "{h}: {value}");
            } else if ["tool", "run", "artifact"].contains(h) {
                assert_eq!(value.as_str(), Some(cell), "{h}");
                labels += 1;
            } else {
                let want: f64 = cell.parse().expect("a number");
                assert_eq!(
                    value.as_f64().map(f64::to_bits),
                    Some(want.to_bits()),
                    "{h}"
                );
            }
        }
    }
    assert!(labels >= 7, "{labels}");
}

#[test]
fn negative_zero_is_written_as_zero() {
    let mut buf = String::new();
    super::push_number(&mut buf, -0.0);
    buf.push(',');
    super::push_number(&mut buf, 0.0);
    buf.push(',');
    super::push_number(&mut buf, -1.5);
    assert_eq!(buf, "0,0,-1.5");
}

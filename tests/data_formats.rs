//! Measurement files as spreadsheets and pandas write them, read by the real binary
//! (spec/data.md): the same poses in three dialects give the same predictions, and a file that is
//! still wrong is refused with file, line and column.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn kin(args: &[&str]) -> Output {
    match Command::new(env!("CARGO_BIN_EXE_kin")).args(args).output() {
        Ok(out) => out,
        Err(e) => panic!("cannot run kin: {e}"),
    }
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn example(name: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("examples")
        .join(name)
        .display()
        .to_string()
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> String {
    let path = dir.join(name);
    if let Err(e) = std::fs::write(&path, bytes) {
        panic!("cannot write {}: {e}", path.display());
    }
    path.display().to_string()
}

fn eval(poses: &str) -> String {
    let out = kin(&["eval", &example("bridge_cmm.kin"), poses]);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    text(&out.stdout)
}

#[test]
fn spreadsheet_and_pandas_files_give_the_same_predictions() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let plain = write(
        dir.path(),
        "plain.csv",
        b"Y,X,Z,T_scale,T_room,dir_Y,time[min]\n100.5,20,-150,20.5,0.25,1,0\n700,600,0,19,1,-1,2.5\n",
    );
    let excel = write(
        dir.path(),
        "excel.csv",
        "\u{feff}\"Y [mm]\";\"X [mm]\";\"Z [in]\";T_scale;T_room;dir_Y;\"time [s]\"\r\n\
         100,5;20;-5,905511811023622;20,5;0,25;+1;0\r\n700;600;0;19;1;-1,0;150\r\n"
            .as_bytes(),
    );
    let pandas = write(
        dir.path(),
        "pandas.csv",
        b",Y,X,Z,T_scale,T_room,dir_Y,time\n0,100.5,20.0,-150.0,20.5,0.25,1,0.0\n1,700.0,600.0,0.0,19.0,1.0,-1,2.5\n",
    );
    let reference = eval(&plain);
    // The predictions' lines, after the comments naming the input file.
    let body = |s: &str| -> Vec<String> {
        s.lines()
            .filter(|l| !l.starts_with('#'))
            .map(str::to_string)
            .collect()
    };
    assert_eq!(body(&reference).len(), 3, "{reference}");
    // -150 mm is -5.905511811023622 in: equal to the last digit printed, not bit for bit.
    let close = |a: &str, b: &str| {
        let (a, b) = (body(a), body(b));
        a.len() == b.len()
            && a.iter().zip(&b).all(|(x, y)| {
                x.split(',').zip(y.split(',')).all(|(u, v)| {
                    u == v
                        || matches!((u.parse::<f64>(), v.parse::<f64>()),
                            (Ok(u), Ok(v)) if (u - v).abs() <= 1e-9 * u.abs().max(1.0))
                })
            })
    };
    let from_excel = eval(&excel);
    assert!(close(&reference, &from_excel), "{reference}\n{from_excel}");
    let from_pandas = eval(&pandas);
    assert_eq!(body(&reference), body(&from_pandas));
}

#[test]
fn a_file_still_wrong_names_file_line_column_and_what_was_expected() {
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let bad = write(
        dir.path(),
        "bad.csv",
        b"Y;X;Z;ex\r\n1;2;3;4\r\n1;2,5,1;3;4\r\n1;2;\"3;4\r\n",
    );
    let out = kin(&["fit", &example("bridge_cmm.kin"), &bad]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
    let err = text(&out.stderr);
    for expected in [
        "bad.csv`: 2 problems",
        "line 3, column 3 (`X`): `2,5,1`: expected a number in mm",
        "line 4, column 5: the quote opening this cell is not closed on its line",
        "spec/data.md",
    ] {
        assert!(err.contains(expected), "missing `{expected}` in:\n{err}");
    }
}

#[test]
fn iso230_2_prints_the_published_figures_and_refuses_bad_runs() {
    let run = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("runtime/standards/src/iso230_2/ecmc_fat_sat.csv")
        .display()
        .to_string();
    let out = kin(&["iso230-2", &run]);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    // The report prints B = 1.22e-05 mm, M = 2.77e-05 mm, A = 8.881e-05 mm; kin shows µm.
    let figure = |label: &str| -> Vec<String> {
        stdout
            .lines()
            .find(|l| l.starts_with(label))
            .map(|l| l.split_whitespace().map(str::to_string).collect())
            .unwrap_or_else(|| panic!("no `{label}` line in:\n{stdout}"))
    };
    assert!(
        figure("B  reversal").contains(&"0.0122".to_string()),
        "{stdout}"
    );
    assert!(
        figure("M  mean").contains(&"0.0277".to_string()),
        "{stdout}"
    );
    assert!(
        figure("A  accuracy").contains(&"0.0888".to_string()),
        "{stdout}"
    );
    let out = kin(&["iso230-2", &run, "--format", "json"]);
    let json: serde_json::Value =
        serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}"));
    let r = json["axis"]["r"].as_f64().unwrap_or(f64::NAN);
    assert!((r * 1e3 - 6.882e-05).abs() < 0.5e-8, "{r}");

    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let bad = write(
        dir.path(),
        "run.csv",
        b"target;deviation;direction;cycle\n0;1,5;+1;1\n0;2;sideways;1\n",
    );
    let out = kin(&["iso230-2", &bad]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
    let err = text(&out.stderr);
    assert!(
        err.contains("line 3, column 5: `sideways`: expected +1"),
        "{err}"
    );
    let out = kin(&[
        "iso230-2",
        &dir.path().join("missing.csv").display().to_string(),
    ]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
}

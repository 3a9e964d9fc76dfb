//! The reader in pieces: a file read on several threads gives what one thread gives (rows,
//! ids, values to the bit, problems in order, the cap and the count past it), wherever the
//! cuts fall.

use proptest::prelude::*;

use super::super::testing::machine;
use super::*;

/// All a read gives, as text: `Debug` prints every value (NaN and the sign of zero included)
/// and every problem.
fn outcome(text: &str, options: &ReadOptions, pieces: usize) -> String {
    match read_in(
        text.as_bytes(),
        Path::new("p.csv"),
        &machine(),
        options,
        pieces,
    ) {
        Ok(o) => format!("{o:?}"),
        Err(ReadError::Invalid {
            problems, omitted, ..
        }) => format!("{problems:#?} and {omitted} more"),
        Err(e) => format!("{e}"),
    }
}

/// The outcome of one piece, checked to be that of every number of pieces up to two more than
/// the file has lines (so every line end is a cut for some count, and some pieces are empty).
fn same_in_any_pieces(text: &str, options: &ReadOptions) -> String {
    let whole = outcome(text, options, 1);
    for pieces in 2..=text.lines().count() + 2 {
        assert_eq!(outcome(text, options, pieces), whole, "{pieces} pieces");
    }
    whole
}

/// Rows of a file with runs, times, tools, artifacts and directions; `bad` puts a problem of
/// some kind into some rows, spread over the file.
fn file(rows: usize, bad: bool) -> String {
    let mut text = String::from(
        "# a comment before the header\n\nX,Y,Z,C,run,time,tool,artifact,dir_X,ex,ey\n",
    );
    for i in 0..rows {
        // Runs interleave; a run first seen late gets its id late.
        let run = match i {
            _ if i > rows * 3 / 4 && i % 2 == 0 => "late".to_string(),
            _ => format!("r{}", i % 3),
        };
        let mut time = i as f64;
        let mut x = format!("{}.{}", i % 10, i * 7 % 1000);
        let mut cells = 11;
        let mut tool = if i % 5 == 0 { "star" } else { "probe" };
        let mut ex = format!("{}e-1", i % 17);
        let mut ey = "-0.25".to_string();
        if bad {
            match i % 23 {
                3 => x = "abc".into(),
                7 => cells = 10,
                11 => time = i as f64 - 9.0,
                13 => tool = "laser",
                17 => {
                    ex = String::new();
                    ey = " ".into();
                }
                19 => x = "1e400".into(),
                _ => {}
            }
        }
        let artifact = match i % 4 {
            0 => String::new(),
            k => format!("plate{}", (k + i / 10) % 5),
        };
        let dir = ["+1", "-1", "+", "\u{2212}1"][i % 4];
        let row = [
            x,
            format!("{}", -(i as f64) / 3.0),
            "0".into(),
            format!("{}", i % 360),
            run,
            format!("{time}"),
            tool.into(),
            artifact,
            dir.into(),
            ex,
            ey,
        ];
        text.push_str(&row[..cells].join(","));
        text.push_str(match i % 9 {
            2 => "\r\n",
            5 => "\n# a comment between rows\n",
            7 => "\n\n",
            _ => "\n",
        });
    }
    text
}

#[test]
fn a_valid_file_reads_the_same_in_any_pieces() {
    let text = file(60, false);
    let whole = same_in_any_pieces(&text, &ReadOptions::default());
    assert!(whole.starts_with("Points"), "{whole}");
    // The ids are the file's: a late label's id is the last one.
    let Ok(Observations::Points(p)) = read_in(
        text.as_bytes(),
        Path::new("p.csv"),
        &machine(),
        &ReadOptions::default(),
        7,
    ) else {
        panic!()
    };
    let runs = p.rows.run.expect("a run column");
    assert_eq!(runs.labels, ["r0", "r1", "r2", "late"]);
    assert_eq!(runs.of_row.get(58), Some(&3));
    assert_eq!(p.rows.line.len(), 60);
}

#[test]
fn problems_are_the_same_in_any_pieces_within_and_past_the_cap() {
    // A few problems, all listed; then more than the cap, with the count of the rest.
    for rows in [30, 200] {
        let whole = same_in_any_pieces(&file(rows, true), &ReadOptions::default());
        assert!(whole.contains("TimeOrder"), "{whole}");
        assert!(whole.contains("CellCount"), "{whole}");
        assert!(whole.contains("UnknownTool"), "{whole}");
        assert!(whole.contains("NothingObserved"), "{whole}");
        let more = whole.rsplit("and ").next().unwrap_or_default();
        assert_eq!(more != "0 more", rows == 200, "{whole}");
    }
}

/// A run's time order is checked against the latest time of the pieces before: the time the
/// row is out of order with is many lines (and pieces) back.
#[test]
fn time_order_is_checked_across_pieces() {
    let mut text = String::from("X,Y,Z,C,run,time,ex\n0,0,0,0,a,100,1\n");
    for i in 0..20 {
        text.push_str(&format!("0,0,0,0,b,{i},1\n"));
    }
    text.push_str("0,0,0,0,a,99,1\n0,0,0,0,a,100,1\n0,0,0,0,a,98,1\n");
    let whole = same_in_any_pieces(&text, &ReadOptions::default());
    let problems = problems_with(&text, 5);
    assert_eq!(problems.len(), 2, "{whole}");
    for (p, line) in problems.iter().zip([23, 25]) {
        assert!(
            matches!(p, Problem::TimeOrder { line: l, previous_line, .. } if *l == line && *previous_line == if line == 23 { 2 } else { 24 }),
            "{p:?}"
        );
    }
}

fn problems_with(text: &str, pieces: usize) -> Vec<Problem> {
    match read_in(
        text.as_bytes(),
        Path::new("p.csv"),
        &machine(),
        &ReadOptions::default(),
        pieces,
    ) {
        Err(ReadError::Invalid { problems, .. }) => problems,
        other => panic!("{other:?}"),
    }
}

#[test]
fn small_files_and_edge_cases_read_the_same_in_any_pieces() {
    for text in [
        "",
        "# only a comment\n",
        "X,Y,Z,C,ex",
        "X,Y,Z,C,ex\n",
        "X,Y,Z,C,ex\n1,2,3,4,5",
        "\u{feff}X,Y,Z,C,ex\r\n1,2,3,4,5\r\n",
        "X,Y,Z,C,ex\n1,2,3,4,5\n\n\n",
        "X,Y,Z,C,ex\n1,2,3,4\n1,2,3,4,5\n",
        "X,Y,Z,C,ex\n\"1\",2,3,4,5\n1,\"2,3,4,5\n",
        "X;Y;Z;C;ex\n1,5;2;3;4;5\n6;7;8;9;1,0\n",
        "X,Y,Z,C,tool,px,py,pz,target\n1,2,3,4,probe,1,2,3,a\n1,2,3,4,probe,1,2,3,b\n1,2,3,4,probe,1,2,3,a\n1,2,3,4,probe,1,2,3,\n",
        "X,Y,Z,C,T_spindle,T_x,ex\n1,2,3,4,-300,1,1\n1,2,3,4,20,1,1e-200\n",
    ] {
        same_in_any_pieces(text, &ReadOptions::default());
        same_in_any_pieces(
            text,
            &ReadOptions {
                poses: true,
                ..ReadOptions::default()
            },
        );
    }
}

/// The public reader picks its pieces from the size and the threads: a file of a few MiB is
/// read in several and gives what one thread gives.
#[test]
fn threads_change_nothing_in_a_large_file() {
    let text = file(40_000, false);
    assert!(text.len() > 2 * MIN_PIECE_BYTES);
    let read_on = |threads| {
        let options = ReadOptions {
            threads: Some(threads),
            ..ReadOptions::default()
        };
        let o = read(text.as_bytes(), Path::new("p.csv"), &machine(), &options);
        format!("{o:?}")
    };
    let one = read_on(1);
    assert!(one.starts_with("Ok(Points"));
    assert_eq!(read_on(3), one);
    let text = file(40_000, true);
    let read_on = |threads| {
        let options = ReadOptions {
            threads: Some(threads),
            ..ReadOptions::default()
        };
        let o = read(text.as_bytes(), Path::new("p.csv"), &machine(), &options);
        format!("{o:?}")
    };
    assert_eq!(read_on(4), read_on(1));
}

#[test]
fn pieces_end_at_line_ends_and_cover_the_text() {
    let text = "a\nbb\n\u{e9}\u{e9}\u{e9}\ncccc\nd";
    for pieces in 1..12 {
        let cut = split_pieces(text, pieces);
        assert_eq!(cut.concat(), text);
        assert!(cut.len() <= pieces);
        for p in cut.iter().rev().skip(1) {
            assert!(p.ends_with('\n'), "{cut:?}");
        }
        assert!(cut.iter().all(|p| !p.is_empty()));
    }
    assert_eq!(split_pieces("", 3), [""]);
}

proptest! {
    /// Random rows, good and bad, in random pieces.
    #[test]
    fn random_files_read_the_same_in_pieces(
        rows in proptest::collection::vec(0usize..12, 0..40),
        pieces in 2usize..9,
    ) {
        const ROWS: [&str; 12] = [
            "1,2,3,4,a,0,probe,,+1,1,2",
            "1.5e1,-2,3,4,b,1,star,p,-1,,2",
            "1,2,3,4,a,0.5,probe,q,+,1,",
            "x,2,3,4,a,3,probe,,+1,1,2",
            "1,2,3,4,c,2,probe,p,+1,,",
            "1,2,3",
            "# comment",
            "",
            "1,2,3,4,a,9,laser,,+1,1,2",
            " 1 , 2 ,3,4,\"b\",4,probe,r,-1,1,2\r",
            "1,2,3,4,a,1e99,probe,,2,1,2",
            "1,2,3,4,,5,probe,,+1,1,2",
        ];
        let mut text = String::from("X,Y,Z,C,run,time,tool,artifact,dir_X,ex,ey\n");
        for r in rows {
            text.push_str(ROWS[r]);
            text.push('\n');
        }
        let options = ReadOptions::default();
        prop_assert_eq!(outcome(&text, &options, pieces), outcome(&text, &options, 1));
    }

    /// Every text of the lexer's number pattern is one cell, taken for a number, which
    /// `f64::from_str` reads (the fast path parses only those).
    #[test]
    fn numbers_are_what_the_standard_parser_reads(
        text in "[+-]?([0-9]{1,25}(\\.[0-9]{0,25})?|\\.[0-9]{1,25})([eE][+-]?[0-9]{1,3})?",
    ) {
        let mut cells = Vec::new();
        split_cells(&text, &mut cells);
        prop_assert_eq!(cells.len(), 1);
        prop_assert!(cells.first().is_some_and(|c| c.number && c.end == text.len()));
        prop_assert!(text.parse::<f64>().is_ok());
    }
}

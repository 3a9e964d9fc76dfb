//! Load time of a one-million-row point file (3 axes + ex ey ez), the size a long automated
//! measurement campaign produces; the target is about 0.3 s in release mode. The same rows are
//! also read as a spreadsheet saves them (`;`, decimal comma, CRLF, quoted header) and with every
//! cell quoted, which take the general splitter instead of the comma lexer: the ratios to the
//! plain file are measured in the same run.

use std::fmt::Write as _;
use std::hint::black_box;
use std::path::PathBuf;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use kin_compiler::ir::Machine;
use kin_data::data::{read_file, Observations, ReadOptions};

const ROWS: usize = 1_000_000;

/// A 3-axis CMM: the reader only needs the axis names and the default units.
fn machine() -> Machine {
    let src = "machine bench {
        task measure
        units { length mm, error um }
        axis Y prismatic along y range 0 mm .. 1000 mm
        axis X prismatic along x range 0 mm .. 1000 mm
        axis Z prismatic along z range 0 mm .. 1000 mm
        tool chain {
            Y moving
            X moving
            Z moving
            tool probe
        }
    }";
    kin_compiler::compile(src)
        .compiled
        .expect("the bench machine compiles")
        .machine
}

/// How the benchmark file is written.
#[derive(Clone, Copy)]
enum Style {
    /// `,` and nothing quoted: the comma lexer's fast path.
    Plain,
    /// Excel in a decimal-comma locale: a byte order mark, `;`, decimal commas, CRLF.
    Spreadsheet,
    /// Every cell quoted (Python's `csv.QUOTE_ALL`).
    Quoted,
}

/// Positions on a grid with sub-micrometre digits and errors of a few micrometres, written the
/// way a CMM's export writes them.
fn generate(path: &PathBuf, style: Style) -> u64 {
    let mut text = String::with_capacity(ROWS * 64);
    text.push_str(match style {
        Style::Plain => "# generated for the load benchmark\nX,Y,Z,ex,ey,ez\n",
        Style::Spreadsheet => "\u{feff}\"X\";\"Y\";\"Z\";\"ex\";\"ey\";\"ez\"\r\n",
        Style::Quoted => "\"X\",\"Y\",\"Z\",\"ex\",\"ey\",\"ez\"\n",
    });
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut noise = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    for i in 0..ROWS {
        let x = (i % 100) as f64 * 8.0 + noise() * 1e-3;
        let y = (i / 100 % 100) as f64 * 6.0 + noise() * 1e-3;
        let z = -((i / 10_000) as f64) * 4.0 + noise() * 1e-3;
        let (ex, ey, ez) = (noise() * 5.0, noise() * 5.0, noise() * 5.0);
        let _ = match style {
            Style::Plain => writeln!(text, "{x:.4},{y:.4},{z:.4},{ex:.3},{ey:.3},{ez:.3}"),
            Style::Spreadsheet => {
                let row = format!("{x:.4};{y:.4};{z:.4};{ex:.3};{ey:.3};{ez:.3}\r\n");
                text.push_str(&row.replace('.', ","));
                Ok(())
            }
            Style::Quoted => writeln!(
                text,
                "\"{x:.4}\",\"{y:.4}\",\"{z:.4}\",\"{ex:.3}\",\"{ey:.3}\",\"{ez:.3}\""
            ),
        };
    }
    if let Err(e) = std::fs::write(path, &text) {
        panic!("cannot write {}: {e}", path.display());
    }
    text.len() as u64
}

fn load(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("kin-bench-data-{}", std::process::id()));
    if let Err(e) = std::fs::create_dir_all(&dir) {
        panic!("{e}");
    }
    let m = machine();
    let options = ReadOptions::default();
    let mut group = c.benchmark_group("data");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(10));
    for (style, name) in [
        (Style::Plain, "read 1M point rows"),
        (Style::Spreadsheet, "read 1M point rows, spreadsheet"),
        (Style::Quoted, "read 1M point rows, all quoted"),
    ] {
        let path = dir.join("points_1m.csv");
        let bytes = generate(&path, style);
        group.throughput(Throughput::Bytes(bytes));
        group.bench_function(name, |b| {
            b.iter(|| match read_file(black_box(&path), &m, &options) {
                Ok(Observations::Points(p)) => assert_eq!(p.len(), ROWS),
                Ok(_) => panic!("expected a point file"),
                Err(e) => panic!("{e}"),
            })
        });
    }
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, load);
criterion_main!(benches);

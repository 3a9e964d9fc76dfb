//! A fit that never holds its rows: the measurement files are read a block of rows at a time
//! ([`kin_data::data::chunks`]) in each pass, so memory is the triangle (columns²), one block,
//! and what the report keeps per row (the outliers, and every residual only up to
//! `MAX_RESIDUALS` rows).
//!
//! The rows reach the same accumulators in the same order as in [`super::fit`], so the
//! triangle, the solution, σ̂ and every statistic are the same numbers: on one thread for any
//! block size, on several when the blocks are [`CHUNK_ROWS`] long, the batches the held fit
//! splits over its threads (see `Team::batched`). Passes: one to collect
//! the artifact labels and check them (only for files with an `artifact` column), one for the
//! triangle, one for the residuals. A machine with fitted non-linear parameters (they iterate
//! over the rows) or with lags (a lag is integrated over a whole run) is fitted by
//! [`super::fit`] instead: see [`streamable`].

use std::path::PathBuf;

use kin_compiler::Compiled;

use super::design::{self, judge_artifacts, DataSet, FileStates, Layout, ThinArtifact};
use super::report::MAX_RESIDUALS;
use super::tally::Tally;
use super::team::{Each, Team};
use super::{
    influence, residual_pass, solve_reduced, thresholds, triangle, FitError, FitResult, Options,
    Progress, ResidualRow, Solved,
};
use kin_data::data::{self, Groups, Observations, ReadOptions};
use kin_model::engine::Evaluator;

/// Rows read from a file at a time.
pub const CHUNK_ROWS: usize = 1 << 16;

/// The files and how to read them.
struct Source<'a> {
    paths: &'a [PathBuf],
    read: &'a ReadOptions,
    /// Rows per block.
    chunk: usize,
}

/// Whether [`fit`] can fit this machine: nothing in it needs all rows at once.
pub fn streamable(compiled: &Compiled) -> bool {
    let m = &compiled.machine;
    m.lags.is_empty() && !m.nonlinear.iter().any(|p| p.fitted)
}

/// What a streamed fit returns besides the result: one entry per file, with the file's kind
/// and artifact labels but no rows, for the report (its summaries name files and artifacts).
pub struct Streamed {
    pub result: FitResult,
    pub files: Vec<DataSet>,
}

/// Fits the files at `paths`, reading each a block of rows at a time in every pass. No
/// validation files, no held-out rows, and unit weights (`options.noise` is not applied: a
/// stated noise needs every kind of row checked first): those go through [`super::fit`].
pub fn fit(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    paths: &[PathBuf],
    read: &ReadOptions,
    options: &Options,
    progress: Progress,
) -> Result<Streamed, FitError> {
    fit_in_chunks(compiled, engine, paths, read, options, CHUNK_ROWS, progress)
}

/// As [`fit`], reading `chunk` rows at a time.
pub fn fit_in_chunks(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    paths: &[PathBuf],
    read: &ReadOptions,
    options: &Options,
    chunk: usize,
    progress: Progress,
) -> Result<Streamed, FitError> {
    let m = &compiled.machine;
    let values: Vec<f64> = m.nonlinear.iter().map(|p| p.value).collect();
    let source = Source { paths, read, chunk };
    let files = skeletons(compiled, &source)?;
    let layout = Layout::new(m, &files);

    let mut rows = |each: &mut Each| each_batch(compiled, &source, &files, &values, each);
    Team::with(engine, options.threads, |team| {
        // Pass 1: the triangle of [X | y].
        let red = triangle(team, &layout, options, &mut *progress, &mut rows)?;
        let Solved {
            solution,
            selection,
            constrained,
            dof,
            sigma,
            r2,
        } = solve_reduced(compiled, &layout, &red, options)?;
        let (outlier_threshold, cook_threshold) =
            thresholds(red.rows, solution.rank, dof, options.outlier_alpha);

        // Pass 2: each block's residuals are tallied and dropped.
        let mut tally = Tally::new(
            files.len(),
            super::report::display_factors(m, &layout.weights),
            m.units.error.scale,
            outlier_threshold,
            cook_threshold,
        );
        let keep = red.rows <= MAX_RESIDUALS;
        let mut residuals: Vec<ResidualRow> = Vec::new();
        residual_pass(
            team,
            &layout,
            options,
            &solution,
            &mut *progress,
            &mut rows,
            |batch| {
                for r in batch.iter_mut() {
                    influence(r, sigma, solution.rank);
                    tally.add(r);
                }
                if keep {
                    residuals.append(batch);
                }
            },
        )?;
        Ok(FitResult {
            layout: layout.clone(),
            solution,
            rows: red.rows,
            sigma,
            r2,
            residuals,
            outlier_threshold,
            cook_threshold,
            constrained,
            validation: Vec::new(),
            selection,
            nonlinear: None,
            tally: Some(tally),
            components: None,
        })
    })
    .map(|result| Streamed { result, files })
}

/// One rowless [`DataSet`] per file, of its kind and with all its artifact labels; a file with
/// an `artifact` column is read through once for them and checked as [`super::design::check_artifacts`] does.
fn skeletons(compiled: &Compiled, source: &Source) -> Result<Vec<DataSet>, FitError> {
    let m = &compiled.machine;
    let mut out = Vec::with_capacity(source.paths.len());
    for path in source.paths {
        let mut blocks = data::chunks(path, m, source.read, source.chunk)?;
        let first = blocks.next().transpose()?.unwrap_or_else(empty_points);
        let mut skeleton = first.select(&[]);
        if first.rows().artifact.is_some() {
            let mut counts = ArtifactCounts::default();
            counts.add(&first);
            for block in blocks {
                counts.add(&block?);
            }
            let points = matches!(first, Observations::Points(_));
            set_labels(&mut skeleton, counts.check(path, points)?);
        }
        out.push(DataSet {
            path: path.clone(),
            observations: skeleton,
        });
    }
    Ok(out)
}

fn empty_points() -> Observations {
    Observations::Points(Default::default())
}

fn set_labels(o: &mut Observations, labels: Vec<String>) {
    let rows = match o {
        Observations::Points(p) => &mut p.rows,
        Observations::Lengths(l) => &mut l.rows,
    };
    rows.artifact = Some(Groups {
        of_row: Vec::new(),
        labels,
    });
}

/// Per artifact label of a point file: the rows, the first lines, the observed values and
/// whether a rotation is observed, added up block by block; the totals are judged as
/// [`super::design::check_artifacts`] judges a whole file, so the verdict and its wording are the same.
#[derive(Default)]
struct ArtifactCounts {
    labels: Vec<String>,
    seen: Vec<(ThinArtifact, bool)>,
}

impl ArtifactCounts {
    fn add(&mut self, block: &Observations) {
        let Some(groups) = &block.rows().artifact else {
            return;
        };
        // Ids are the whole file's: a block's labels are all those seen so far.
        self.labels.clone_from(&groups.labels);
        for label in groups.labels.iter().skip(self.seen.len()) {
            let t = ThinArtifact {
                label: label.clone(),
                lines: Vec::new(),
                rows: 0,
                values: 0,
            };
            self.seen.push((t, false));
        }
        let Observations::Points(p) = block else {
            // A length file's label adds one length error, fixed by any one row.
            return;
        };
        for (r, a) in groups.of_row.iter().enumerate() {
            let Some((t, rotations)) = a.and_then(|a| self.seen.get_mut(a as usize)) else {
                continue;
            };
            t.rows += 1;
            if t.lines.len() < 10 {
                t.lines.push(p.rows.line.get(r).copied().unwrap_or(0));
            }
            for (c, column) in p.observed.iter().enumerate() {
                if column
                    .as_ref()
                    .and_then(|v| v.get(r))
                    .is_some_and(|v| !v.is_nan())
                {
                    t.values += 1;
                    *rotations |= c >= 3;
                }
            }
        }
    }

    fn check(self, path: &std::path::Path, points: bool) -> Result<Vec<String>, FitError> {
        if points {
            judge_artifacts(&path.display().to_string(), self.seen)?;
        }
        Ok(self.labels)
    }
}

/// Calls `each` for every block of every file (see [`super::team::Batches`]), reading each
/// file a block at a time.
fn each_batch(
    compiled: &Compiled,
    source: &Source,
    files: &[DataSet],
    values: &[f64],
    each: &mut Each,
) -> Result<(), FitError> {
    let m = &compiled.machine;
    // `design::for_each_row` numbers files by their place in its slice: the block is put at
    // its file's place, between rowless stand-ins.
    let mut slots: Vec<DataSet> = files.to_vec();
    let mut states: Vec<FileStates> = files
        .iter()
        .map(|_| FileStates::Points(Default::default()))
        .collect();
    for (f, path) in source.paths.iter().enumerate() {
        for block in data::chunks(path, m, source.read, source.chunk)? {
            let block = block?;
            let one = [DataSet {
                path: path.clone(),
                observations: block,
            }];
            let mut st = design::states_with(m, &one, values)?;
            let [block] = one;
            if let (Some(slot), Some(s), Some(new)) =
                (slots.get_mut(f), states.get_mut(f), st.pop())
            {
                *slot = block;
                *s = new;
            }
            each(&slots, &states, 0..usize::MAX)?;
        }
        if let (Some(slot), Some(file)) = (slots.get_mut(f), files.get(f)) {
            *slot = file.clone();
        }
        if let Some(s) = states.get_mut(f) {
            *s = FileStates::Points(Default::default());
        }
    }
    Ok(())
}

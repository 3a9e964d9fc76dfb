//! The evaluators a pass over the rows runs on, one per thread, and the passes split over them.
//!
//! A pass that only accumulates (sums of products, a triangle per part merged afterwards) can
//! evaluate its rows on every core: the observations are split into
//! contiguous parts ([`design::for_each_row_parts`]), each evaluated by its own fork of the
//! caller's evaluator ([`Evaluator::fork`]: the JIT's code is shared, only values and scratch
//! are copied). The parts' results are combined in part order, so one thread count gives the
//! same bits on every run.

use kin_compiler::Compiled;

use super::design::{self, DataSet, FileStates, Layout, RowMeta};
use super::FitError;
use crate::engine::Evaluator;

/// `lead` evaluates the first part on the calling thread (and every pass that feeds something
/// sequential row by row); `rest`, forks of the caller's evaluator, the other parts.
pub(super) struct Team<'a, 'e> {
    pub lead: &'a mut dyn Evaluator,
    pub rest: &'a mut [Box<dyn Evaluator + Send + 'e>],
}

impl Team<'_, '_> {
    /// Runs `run` on a team of `threads` evaluators forked from `engine` (holding its values;
    /// `engine` itself is then not touched), or on `engine` alone (one thread, or an engine
    /// that cannot be forked; the passes then set its values).
    pub fn with<R>(
        engine: &mut dyn Evaluator,
        threads: usize,
        run: impl FnOnce(&mut Team) -> R,
    ) -> R {
        if threads > 1 {
            let forks: Option<Vec<_>> = (0..threads).map(|_| engine.fork()).collect();
            if let Some(mut forks) = forks {
                if let Some((lead, rest)) = forks.split_first_mut() {
                    return run(&mut Team {
                        lead: lead.as_mut(),
                        rest,
                    });
                }
            }
        }
        run(&mut Team {
            lead: engine,
            rest: &mut [],
        })
    }

    /// How many parts a pass is split into.
    pub fn parts(&self) -> usize {
        1 + self.rest.len()
    }

    /// [`at_values`] for every evaluator of the team.
    pub fn at_values(
        &mut self,
        compiled: &Compiled,
        files: &[DataSet],
        values: &[f64],
        noise: Option<design::Noise>,
    ) -> Result<(Vec<FileStates>, Layout), FitError> {
        for e in self.rest.iter_mut() {
            e.set_nonlinear(values)
                .map_err(|source| design::DesignError::Eval {
                    path: String::new(),
                    line: 0,
                    source,
                })?;
        }
        at_values(compiled, &mut *self.lead, files, values, noise)
    }

    /// One pass over the rows, part `t` of them into `parts[t]`.
    pub fn pass<A: Send>(
        &mut self,
        files: &[DataSet],
        states: &[FileStates],
        layout: &Layout,
        parts: &mut [A],
        row: impl Fn(&mut A, RowMeta, &[f64], f64) + Sync,
    ) -> Result<(), FitError> {
        design::for_each_row_parts(
            &mut *self.lead,
            self.rest,
            files,
            states,
            layout,
            0..usize::MAX,
            parts,
            row,
            &mut |_| {},
        )?;
        Ok(())
    }

    /// One pass over the rows of every batch `batches` gives, each batch split over the team
    /// (part `t` into `parts[t]`). After each batch, `settle(parts)`: the parts then hold
    /// that batch's rows, so a caller that takes them out in part order has every row in
    /// order while holding only a batch of them. `progress` hears the rows done so far.
    pub fn batched<A: Send>(
        &mut self,
        layout: &Layout,
        batches: &mut Batches,
        parts: &mut [A],
        row: impl Fn(&mut A, RowMeta, &[f64], f64) + Sync,
        mut settle: impl FnMut(&mut [A]),
        progress: &mut dyn FnMut(usize),
    ) -> Result<(), FitError> {
        let mut done = 0usize;
        batches(&mut |files, states, within| {
            let rows = design::for_each_row_parts(
                &mut *self.lead,
                self.rest,
                files,
                states,
                layout,
                within,
                parts,
                &row,
                &mut |d| progress(done + d),
            )?;
            done += rows;
            settle(parts);
            progress(done);
            Ok(())
        })
    }
}

/// A pass's rows a batch at a time: `batches(each)` calls `each(files, states, within)` for
/// every batch in turn, the rows of observations `within` of `files` (counted as
/// [`design::for_each_row_parts`] counts them). Rows held in memory come in batches of a
/// range of their observations, rows read from files a block at a time.
pub(super) type Batches<'a> = dyn FnMut(&mut Each) -> Result<(), FitError> + 'a;

/// What [`Batches`] calls for each batch.
pub(super) type Each<'a> =
    dyn FnMut(&[DataSet], &[FileStates], std::ops::Range<usize>) -> Result<(), FitError> + 'a;

/// The batches of rows held in memory: each file's observations `batch` at a time, in order
/// (the blocks a fit that reads the files `batch` rows at a time sees).
pub(super) fn held<'a>(
    files: &'a [DataSet],
    states: &'a [FileStates],
    batch: usize,
) -> impl FnMut(&mut Each) -> Result<(), FitError> + 'a {
    move |each| {
        let batch = batch.max(1);
        let mut from = 0;
        for st in states {
            let end = from + design::observations(std::slice::from_ref(st));
            while from < end {
                let to = from.saturating_add(batch).min(end);
                each(files, states, from..to)?;
                from = to;
            }
        }
        Ok(())
    }
}

/// The engine and the states set to the non-linear `values` (lags depend on time constants),
/// and the problem's columns.
pub(super) fn at_values(
    compiled: &Compiled,
    engine: &mut dyn Evaluator,
    files: &[DataSet],
    values: &[f64],
    noise: Option<design::Noise>,
) -> Result<(Vec<FileStates>, Layout), FitError> {
    let m = &compiled.machine;
    engine
        .set_nonlinear(values)
        .map_err(|source| design::DesignError::Eval {
            path: String::new(),
            line: 0,
            source,
        })?;
    Ok((
        design::states_with(m, files, values)?,
        Layout::new(m, files).weighted(m, noise),
    ))
}

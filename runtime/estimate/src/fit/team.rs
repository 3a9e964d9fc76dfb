//! The evaluators a pass over the rows runs on, one per thread, and the passes split over them.
//!
//! A pass that only accumulates (sums of products, a triangle per part merged afterwards) can
//! evaluate its rows on every core: the observations are split into
//! contiguous parts ([`design::for_each_row_parts`]), each evaluated by its own fork of the
//! caller's evaluator ([`Evaluator::fork`]: the JIT's code is shared, only values and scratch
//! are copied). The parts' results are combined in part order, so one thread count gives the
//! same bits on every run.

use std::sync::Arc;

use kin_compiler::ir::Machine;
use kin_compiler::Compiled;

use super::design::{self, DataSet, FileStates, Layout, RowMeta};
use super::{FitError, Options};
use kin_data::data::Observations;
use kin_model::engine::Evaluator;

/// `lead` evaluates the first part on the calling thread (and every pass that feeds something
/// sequential row by row); `rest`, forks of the caller's evaluator, the other parts.
pub(super) struct Team<'a, 'e> {
    pub lead: &'a mut dyn Evaluator,
    pub rest: &'a mut [Box<dyn Evaluator + Send + 'e>],
    /// The states of the latest [`Team::at_values`] and the values they are at: an optimiser
    /// moves one or two time constants at a time, and only the lags those drive need
    /// integrating again (building every state anew cost about as much as a tenth of a pass).
    states: Option<Cached>,
}

struct Cached {
    values: Vec<f64>,
    /// The files the states are of (their address and count): a team serves one problem.
    files: (usize, usize),
    states: Arc<Vec<FileStates>>,
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
                    return run(&mut Team::new(lead.as_mut(), rest));
                }
            }
        }
        run(&mut Team::alone(engine))
    }

    /// A team of `lead` on the calling thread and `rest` on threads of their own.
    pub fn new<'b, 'e>(
        lead: &'b mut dyn Evaluator,
        rest: &'b mut [Box<dyn Evaluator + Send + 'e>],
    ) -> Team<'b, 'e> {
        Team {
            lead,
            rest,
            states: None,
        }
    }

    /// A team of `engine` alone, on the calling thread.
    pub fn alone<'b, 'e>(engine: &'b mut dyn Evaluator) -> Team<'b, 'e> {
        Team::new(engine, &mut [])
    }

    /// How many parts a pass is split into.
    pub fn parts(&self) -> usize {
        1 + self.rest.len()
    }

    /// [`at_values`] for every evaluator of the team, the states shared (and kept, as the
    /// `states` field says, for the next values).
    pub(crate) fn at_values(
        &mut self,
        m: &Machine,
        files: &[DataSet],
        values: &[f64],
        options: &Options,
    ) -> Result<(Arc<Vec<FileStates>>, Layout), FitError> {
        for e in self.rest.iter_mut() {
            design::set_values(e.as_mut(), values)?;
        }
        design::set_values(self.lead, values)?;
        let key = (files.as_ptr() as usize, files.len());
        let states = match self.states.take() {
            Some(mut c) if c.files == key && c.values.len() == values.len() => {
                // A lag is integrated again when a parameter it reads moved (bit for bit).
                let moved = |li: usize| {
                    m.lags.get(li).is_some_and(|l| {
                        std::iter::once(l.tau.index)
                            .chain(l.tau2.map(|t| t.index))
                            .any(|i| {
                                values.get(i).map(|v| v.to_bits())
                                    != c.values.get(i).map(|v| v.to_bits())
                            })
                    })
                };
                // Shared only while an earlier caller still holds it: then copied once.
                let all = Arc::make_mut(&mut c.states);
                for (st, file) in all.iter_mut().zip(files) {
                    match (st, &file.observations) {
                        (FileStates::Points(s), Observations::Points(p)) => {
                            s.integrate_lags_where(m, &p.rows, values, moved);
                        }
                        (FileStates::Lengths(a, b), Observations::Lengths(l)) => {
                            a.integrate_lags_where(m, &l.rows, values, moved);
                            b.integrate_lags_where(m, &l.rows, values, moved);
                        }
                        // A file's states always have its kind (`design::states_with`).
                        _ => {}
                    }
                }
                c.values = values.to_vec();
                c
            }
            _ => Cached {
                values: values.to_vec(),
                files: key,
                states: Arc::new(design::states_with(m, files, values)?),
            },
        };
        let shared = Arc::clone(&states.states);
        self.states = Some(states);
        Ok((
            shared,
            Layout::new(m, files).weighted(m, options.noise, &options.file_noise),
        ))
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
    options: &Options,
) -> Result<(Vec<FileStates>, Layout), FitError> {
    let m = &compiled.machine;
    design::set_values(engine, values)?;
    Ok((
        design::states_with(m, files, values)?,
        Layout::new(m, files).weighted(m, options.noise, &options.file_noise),
    ))
}

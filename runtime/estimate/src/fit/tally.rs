//! The per-file residual statistics of a fit (RMS and largest residual per file and component,
//! outlier counts) and the outlying rows, accumulated one row at a time: a streamed fit keeps
//! these instead of every residual, and a fit holding its rows computes the same sums in the
//! same order, so both report the same numbers to the last bit.

use super::{ResidualRow, LENGTH};

/// A running sum of squares and largest magnitude of residuals in display units.
#[derive(Debug, Clone, Copy, Default)]
pub struct Sum {
    pub rows: usize,
    sumsq: f64,
    max: f64,
}

impl Sum {
    fn add(&mut self, v: f64) {
        self.rows += 1;
        self.sumsq += v * v;
        self.max = self.max.max(v.abs());
    }

    /// Root mean square; 0 without rows.
    pub fn rms(&self) -> f64 {
        if self.rows == 0 {
            0.0
        } else {
            (self.sumsq / self.rows as f64).sqrt()
        }
    }

    pub fn max(&self) -> f64 {
        self.max
    }
}

/// One file's rows.
#[derive(Debug, Clone, Default)]
pub struct FileTally {
    /// By component, `ex` … `erz` then the length (index [`LENGTH`]).
    pub components: [Sum; LENGTH as usize + 1],
    pub all: Sum,
    /// Rows whose |studentized residual| exceeds the outlier threshold.
    pub outliers: usize,
}

#[derive(Debug, Clone)]
pub struct Tally {
    files: Vec<FileTally>,
    all: Sum,
    outliers: Vec<ResidualRow>,
    /// Multiplies a residual of each component into its display unit (weights undone).
    display: [f64; LENGTH as usize + 1],
    /// Per file, its own factors when files weigh their rows by their own σs.
    file_display: Vec<[f64; LENGTH as usize + 1]>,
    /// Divides a residual into the unit of the overall figures, which mix kinds as σ̂ does.
    scale: f64,
    outlier_threshold: f64,
    cook_threshold: f64,
}

impl Tally {
    /// An empty tally of `files` files. Rows are kept as outliers when |studentized| exceeds
    /// `outlier_threshold` or Cook's distance exceeds `cook_threshold`.
    pub fn new(
        files: usize,
        display: [f64; LENGTH as usize + 1],
        scale: f64,
        outlier_threshold: f64,
        cook_threshold: f64,
    ) -> Tally {
        Tally {
            files: vec![FileTally::default(); files],
            all: Sum::default(),
            outliers: Vec::new(),
            display,
            file_display: Vec::new(),
            scale,
            outlier_threshold,
            cook_threshold,
        }
    }

    /// The tally of rows already held.
    pub fn of(
        rows: &[ResidualRow],
        files: usize,
        display: [f64; LENGTH as usize + 1],
        scale: f64,
        outlier_threshold: f64,
        cook_threshold: f64,
    ) -> Tally {
        let mut t = Tally::new(files, display, scale, outlier_threshold, cook_threshold);
        for r in rows {
            t.add(r);
        }
        t
    }

    /// The tally with each file's rows turned into display units by its own factors (a fit
    /// with σs per file); set before any row is added.
    pub fn with_file_display(mut self, file_display: Vec<[f64; LENGTH as usize + 1]>) -> Tally {
        self.file_display = file_display;
        self
    }

    pub fn add(&mut self, r: &ResidualRow) {
        let v = r.residual / self.scale;
        self.all.add(v);
        if let Some(f) = self.files.get_mut(r.meta.file as usize) {
            let c = r.meta.component as usize;
            let display = self
                .file_display
                .get(r.meta.file as usize)
                .unwrap_or(&self.display);
            if let (Some(sum), Some(d)) = (f.components.get_mut(c), display.get(c)) {
                sum.add(r.residual * d);
            }
            f.all.add(v);
            if r.studentized.abs() > self.outlier_threshold {
                f.outliers += 1;
            }
        }
        if r.studentized.abs() > self.outlier_threshold || r.cook > self.cook_threshold {
            self.outliers.push(*r);
        }
    }

    /// Every row.
    pub fn all(&self) -> &Sum {
        &self.all
    }

    pub fn file(&self, f: usize) -> Option<&FileTally> {
        self.files.get(f)
    }

    /// The outlying rows, in row order.
    pub fn outliers(&self) -> &[ResidualRow] {
        &self.outliers
    }
}

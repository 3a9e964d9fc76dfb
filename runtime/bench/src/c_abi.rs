//! The C ABI as an embedding program calls it: a model compiled by `kin_model_compile`, its
//! coefficients bound once (`kin_model_set_beta`), each pose evaluated by a call with a
//! `kin_state` that points into the sampled rows. Every `unsafe` of the bench is here.

use std::ffi::c_int;
use std::ptr::{null, null_mut};

use ::kin_model::interp::State;
use ::kin_model::jit::StateRows;
use kin_capi::{kin_model as c_model, kin_state, KIN_OK};

/// A model of the C ABI, freed when dropped.
pub(crate) struct CModel {
    raw: *mut c_model,
    coefficients: usize,
}

/// Why the C ABI could not be measured: the status of the call that failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Status(pub c_int);

fn ok(code: c_int) -> Result<(), Status> {
    if code == KIN_OK {
        Ok(())
    } else {
        Err(Status(code))
    }
}

impl CModel {
    /// Compiles `source` and binds `beta` to it.
    pub(crate) fn new(source: &str, beta: &[f64]) -> Result<CModel, Status> {
        let mut raw = null_mut();
        // SAFETY: `source` is valid for its length, `raw` for writing; no message buffer.
        ok(unsafe {
            kin_capi::kin_model_compile(
                source.as_ptr().cast(),
                source.len(),
                &mut raw,
                null_mut(),
                0,
            )
        })?;
        let model = CModel {
            raw,
            // SAFETY: a live model (compiled just above).
            coefficients: unsafe { kin_capi::kin_model_coefficients(raw) },
        };
        // SAFETY: a live model, used by nothing else, and `beta` valid for its length.
        ok(unsafe { kin_capi::kin_model_set_beta(model.raw, beta.as_ptr(), beta.len()) })?;
        Ok(model)
    }

    /// The error and Jacobian rows of the components `observed` selects (a bit per component,
    /// as in `kin_eval_jacobian_observed`) at `state`, with the bound coefficients.
    pub(crate) fn jacobian(
        &self,
        state: &kin_state,
        observed: u32,
        err: &mut [f64],
        jac: &mut [f64],
    ) -> Result<(), Status> {
        // SAFETY: a live model; `state` points into rows that outlive the call (`States`);
        // `err` and `jac` are valid for their lengths and overlap nothing the call reads.
        ok(unsafe {
            kin_capi::kin_eval_jacobian_observed(
                self.raw,
                state,
                null(),
                0,
                observed,
                err.as_mut_ptr(),
                err.len(),
                jac.as_mut_ptr(),
                jac.len(),
            )
        })
    }

    /// The six error components at `state`, with the bound coefficients.
    pub(crate) fn error(&self, state: &kin_state, err: &mut [f64; 6]) -> Result<(), Status> {
        // SAFETY: as in `jacobian`.
        ok(unsafe { kin_capi::kin_eval(self.raw, state, null(), 0, err.as_mut_ptr(), 6) })
    }

    pub(crate) fn coefficients(&self) -> usize {
        self.coefficients
    }
}

impl Drop for CModel {
    fn drop(&mut self) {
        // SAFETY: compiled by `new`, freed once, here.
        unsafe { kin_capi::kin_model_free(self.raw) };
    }
}

/// The `kin_state` of every row, pointing into `rows` (whose arrays must outlive its use).
pub(crate) fn states(rows: &StateRows) -> Vec<kin_state> {
    (0..rows.len()).map(|r| c_state(&rows.get(r))).collect()
}

/// The `kin_state` of a state, pointing into its slices (which must outlive its use).
pub fn c_state(s: &State) -> kin_state {
    kin_state {
        q: s.q.as_ptr(),
        n_q: s.q.len(),
        inputs: s.inputs.as_ptr(),
        n_inputs: s.inputs.len(),
        lags: s.lags.as_ptr(),
        n_lags: s.lags.len(),
        dirs: s.dirs.as_ptr(),
        n_dirs: s.dirs.len(),
        time: s.time,
        tool: s.tool,
    }
}

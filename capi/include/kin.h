/*
 * kin.h: the C ABI of the .kin runtime (crate `kin-capi`, library `libkin_capi`).
 *
 * Compile a .kin model from source, then evaluate the tool-location error of a multi-axis
 * machine (Soons 1993, eq. 2.24), its Jacobian with respect to the coefficients beta, and the
 * nominal tool location with its joint Jacobian, one state or many at a time.
 *
 * Conventions
 *  - Every function that can fail returns a status: KIN_OK (0) or a KIN_ERR_* code. The message
 *    of the last failure on the calling thread is available from kin_last_error().
 *  - Arrays come with their lengths. A NULL pointer is allowed only with a length of 0; every
 *    length is checked against the model; nothing is read or written outside the given lengths.
 *  - All quantities are SI: metres, radians, seconds, kelvin, newtons.
 *  - Evaluation (kin_eval*, kin_nominal_jacobian) takes a const model, allocates nothing on
 *    success and takes no lock: many threads may evaluate one model at once, each with its own
 *    buffers. kin_model_bind_params, kin_model_set_beta and kin_model_free must not run while
 *    another thread uses the model.
 *  - No panic of the Rust code crosses this boundary (KIN_ERR_PANIC instead).
 *  - Values are checked before evaluation (KIN_ERR_VALUE): joint positions, lag states and beta
 *    finite; inputs and time finite or NaN (not given); directions -1, 0, +1 or NaN (not given).
 *    A result that is not finite (values so large that it overflows) is KIN_ERR_VALUE too, never
 *    KIN_OK. On any failure the output buffers' contents are unspecified.
 *  - Output buffers may not overlap each other, an input array, the state or the rows struct
 *    (KIN_ERR_OVERLAP, checked by address before anything is written).
 *
 * Example: capi/examples/eval.c. Keep this file in step with capi/src/lib.rs (a test checks
 * that every function and status is declared here).
 */
#ifndef KIN_H
#define KIN_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Status codes. */
#define KIN_OK 0
#define KIN_ERR_POINTER 1 /* a pointer is NULL (with a non-zero length) or misaligned */
#define KIN_ERR_SIZE 2    /* a length does not match the model */
#define KIN_ERR_UTF8 3    /* a text is not UTF-8 */
#define KIN_ERR_COMPILE 4 /* the source does not compile: "line:column: error[CODE]: ..." lines */
#define KIN_ERR_PARAMS 5  /* a parameter text cannot be bound */
#define KIN_ERR_EVAL 6    /* the state cannot be evaluated (a value the model uses is NaN, bad tool) */
#define KIN_ERR_IO 7      /* a file cannot be read or written, or is not a saved model */
#define KIN_ERR_INDEX 8   /* an index (axis, name) is out of range */
#define KIN_ERR_PANIC 9   /* a bug in kin: please report the message */
#define KIN_ERR_VALUE 10  /* a value is not allowed (not finite, a direction not -1/0/+1), or the result overflows */
#define KIN_ERR_OVERLAP 11 /* output buffers overlap each other or an input */
#define KIN_ERR_RANGE 12   /* a commanded joint position is outside its axis's declared range */
#define KIN_ERR_MACHINE 13 /* no compensator for this machine: it measures, or has too many axes */
#define KIN_ERR_DIVERGES 14 /* the correction diverges: the model's errors are too large to linearise */

/* Most axes a compensator takes. */
#define KIN_COMPENSATOR_MAX_AXES 16

/* Which name kin_model_name() returns. */
#define KIN_NAME_AXIS 0
#define KIN_NAME_INPUT 1
#define KIN_NAME_TOOL 2
#define KIN_NAME_COEFFICIENT 3

/* A compiled model. */
typedef struct kin_model kin_model;

/* One observation state; arrays indexed like the machine's axes, inputs and lags. */
typedef struct kin_state {
    const double *q;      /* joint positions (m, rad), n_q = axes */
    size_t n_q;
    const double *inputs; /* input values, NaN where not given, n_inputs = inputs */
    size_t n_inputs;
    const double *lags;   /* lag states, n_lags = lags */
    size_t n_lags;
    const double *dirs;   /* direction of motion per axis: +1, 0, -1 or NaN, n_dirs = axes */
    size_t n_dirs;
    double time;          /* s, NaN where not given */
    size_t tool;          /* tool index, in declaration order */
} kin_state;

/* Many states, row-major: row r of q is q[r*axes .. (r+1)*axes], and so on. */
typedef struct kin_rows {
    size_t n_rows;
    const double *q;      /* n_q = n_rows * axes */
    size_t n_q;
    const double *inputs; /* n_inputs = n_rows * inputs */
    size_t n_inputs;
    const double *lags;   /* n_lags = n_rows * lags */
    size_t n_lags;
    const double *dirs;   /* n_dirs = n_rows * axes */
    size_t n_dirs;
    const double *time;   /* n_time = n_rows */
    size_t n_time;
    const size_t *tool;   /* n_tool = n_rows */
    size_t n_tool;
} kin_rows;

/* The library's version, e.g. "0.1.0" (static). */
const char *kin_version(void);

/* Copies this thread's last error message into buf (len bytes, NUL-terminated, truncated if
 * need be); returns its full length. buf may be NULL to ask for the length. */
size_t kin_last_error(char *buf, size_t len);

/* Compiles len bytes of .kin source (a machine, optionally followed by its params). On success
 * *out is the model; on failure *out is NULL and the message is written to err (err_len bytes;
 * err may be NULL). */
int kin_model_compile(const char *src, size_t len, kin_model **out, char *err, size_t err_len);

/* Binds a parameter text (params { ... }, len bytes) on top of the model's values; on failure
 * the model is unchanged. */
int kin_model_bind_params(kin_model *model, const char *src, size_t len, char *err, size_t err_len);

/* Saves the model (source, bound parameter texts, exact values) as JSON to path, atomically: a
 * temporary file in the same folder renamed over path, so a crash leaves the old file whole. */
int kin_model_save(const kin_model *model, const char *path);

/* Loads a saved model: the source is compiled again and the values restored exactly. */
int kin_model_load(const char *path, kin_model **out);

/* Frees a model (NULL is ignored). */
void kin_model_free(kin_model *model);

/* Counts (0 for a NULL model). */
size_t kin_model_axes(const kin_model *model);
size_t kin_model_inputs(const kin_model *model);
size_t kin_model_lags(const kin_model *model);
size_t kin_model_tools(const kin_model *model);
size_t kin_model_coefficients(const kin_model *model);

/* The declared range of an axis (m or rad; [0, 2 pi] for a continuous axis). */
int kin_model_axis_range(const kin_model *model, size_t axis, double *lo, double *hi);

/* A typical range of an input (SI): the declared one, or 18-22 degC for an absolute temperature,
 * 0-4 K for a temperature rise, 0-1000 N for a force, 0-1 otherwise. */
int kin_model_input_range(const kin_model *model, size_t input, double *lo, double *hi);

/* The input that lag state `lag` follows (in steady state the lag state equals its value);
 * KIN_ERR_INDEX for a warm-up's state (`warmup(time, ...)`), which follows no input and settles at 1. */
int kin_model_lag_input(const kin_model *model, size_t lag, size_t *input);

/* Copies the name of axis, input, tool or coefficient `index` (what = KIN_NAME_*) into buf as
 * kin_last_error does; returns its length, or (size_t)-1 when out of range. */
size_t kin_model_name(const kin_model *model, int what, size_t index, char *buf, size_t len);

/* The bound coefficient values (SI; zeros where none was bound), n_beta = coefficients. */
int kin_model_beta(const kin_model *model, double *beta, size_t n_beta);

/* Replaces the coefficient values (e.g. with a fit's); a value that is not finite is
 * KIN_ERR_VALUE and leaves the model's values as they were. */
int kin_model_set_beta(kin_model *model, const double *beta, size_t n_beta);

/* The tool-location error at a state for coefficients beta (n_beta = coefficients; beta NULL
 * and n_beta 0 for the model's bound values): err receives ex, ey, ez, erx, ery, erz with the
 * task's sign; n_err = 6. */
int kin_eval(const kin_model *model, const kin_state *state, const double *beta, size_t n_beta,
             double *err, size_t n_err);

/* The error and its Jacobian with respect to beta: jac (n_jac = 6 * coefficients) receives the
 * 6 x n matrix row-major (row r is error component r): err = fixed + jac * beta. */
int kin_eval_jacobian(const kin_model *model, const kin_state *state, const double *beta,
                      size_t n_beta, double *err, size_t n_err, double *jac, size_t n_jac);

/* kin_eval_jacobian of some components only: bit c of observed (1 .. 63) selects error component
 * c (bits 0-2 the position ex, ey, ez: observed = 7 for a tracker's positions; 63 the full
 * pose). err (n_err = the number of bits set) receives the selected components in order, jac
 * (n_jac = that times the coefficients) their Jacobian rows, row-major; code for those rows alone
 * does the work. KIN_ERR_VALUE for observed 0 or above 63, KIN_ERR_SIZE for other lengths. */
int kin_eval_jacobian_observed(const kin_model *model, const kin_state *state, const double *beta,
                               size_t n_beta, unsigned int observed, double *err, size_t n_err,
                               double *jac, size_t n_jac);

/* The nominal tool location in the workpiece frame: location (n_location = 12) receives the
 * position (3) and the rotation R(wr->tl) row-major (9); jac (n_jac = 6 * axes) the joint
 * Jacobian, entries 6j .. 6j+5 being (dp/dq_j, omega_j). */
int kin_nominal_jacobian(const kin_model *model, const kin_state *state, double *location,
                         size_t n_location, double *jac, size_t n_jac);

/* kin_eval_jacobian over rows->n_rows states: err (n_err = 6 * n_rows) receives 6 values per row,
 * jac (n_jac = 6 * coefficients * n_rows) one 6 x n block per row; with jac NULL and n_jac 0 only
 * the errors. Stops at the first row that cannot be evaluated (the message names it). */
int kin_eval_batch(const kin_model *model, const kin_rows *rows, const double *beta, size_t n_beta,
                   double *err, size_t n_err, double *jac, size_t n_jac);

/* kin_eval_batch of some components only, selected by observed as in kin_eval_jacobian_observed:
 * err (n_err = k * n_rows, k the bits set) receives k values per row, jac (n_jac = k *
 * coefficients * n_rows) one k x n block per row, each row what kin_eval_jacobian_observed gives
 * at that state; with jac NULL and n_jac 0 only the errors. Nothing is computed or stored for the
 * other components (observed = 7: a tracker's positions, half the work of full poses). */
int kin_eval_batch_observed(const kin_model *model, const kin_rows *rows, const double *beta,
                            size_t n_beta, unsigned int observed, double *err, size_t n_err,
                            double *jac, size_t n_jac);

/* A compiled compensation function (thesis section 2.3.5): the joint corrections that cancel a
 * positioning machine's predicted tool-location error, for a controller's servo cycle. */
typedef struct kin_compensator kin_compensator;

/* Makes the compensator of model with its bound values (it keeps its own copy of the model).
 * weights (n_weights = 6; NULL and 0 for every component, a rotation weighed as the fit weighs
 * it) weigh ex, ey, ez, erx, ery, erz in SI, 0 leaving a component out; iterations bounds the
 * linear solves per call (0: the default, 4). KIN_ERR_MACHINE for a measuring machine or more
 * than KIN_COMPENSATOR_MAX_AXES axes, KIN_ERR_VALUE for a weight that is neither 0 nor from
 * 1e-9 to 1e9, or weights all 0. Free with kin_compensator_free. */
int kin_compensator_new(const kin_model *model, const double *weights, size_t n_weights,
                        size_t iterations, kin_compensator **out);

/* As kin_compensator_new, with the axes the corrections may move: movable (n_movable = axes)
 * holds 1 for an axis that may move, 0 for one held at its commanded position; NULL and 0 give
 * kin_compensator_new's default, which moves every axis except under position weights alone
 * (erx, ery, erz weighed 0), where only the prismatic axes move (all of an arm's), as
 * `kin compensate --correct position` does. KIN_ERR_SIZE for a length other than the axes,
 * KIN_ERR_VALUE for a flag other than 0 or 1. */
int kin_compensator_new_axes(const kin_model *model, const double *weights, size_t n_weights,
                             size_t iterations, const unsigned char *movable, size_t n_movable,
                             kin_compensator **out);

/* Frees a compensator; NULL is ignored. Not while another thread uses it. */
void kin_compensator_free(kin_compensator *comp);

/* The correction of the commanded pose state: dq (n_dq = axes) receives what to add to the
 * commanded joint positions (m, rad); before and after (6 each, or NULL and 0) the predicted error
 * at the commanded pose and that of the compensated pose (what the joints cannot correct); rank
 * (or NULL) how many independent combinations of the weighted components the joints can move.
 * The first-order model's error at the moved pose, applied to the exact nominal kinematics, at
 * most `iterations` Gauss-Newton solves. KIN_ERR_RANGE for a command outside an axis's declared
 * range; KIN_ERR_DIVERGES when a Gauss-Newton step does not shrink against the one before (the
 * model's errors are too large for a linearised correction: apply none). Allocates nothing on success, takes no lock: many threads may call it at once. */
int kin_compensate(const kin_compensator *comp, const kin_state *state, double *dq, size_t n_dq,
                   double *before, size_t n_before, double *after, size_t n_after, size_t *rank);

#ifdef __cplusplus
}
#endif

#endif /* KIN_H */

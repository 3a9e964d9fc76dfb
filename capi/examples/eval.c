/*
 * eval.c: compile a .kin machine with the kin C ABI and evaluate it.
 *
 *   cc eval.c -I capi/include -L target/debug -lkin_capi -Wl,-rpath,target/debug -o eval
 *   ./eval examples/bridge_cmm.kin [examples/data/bridge_cmm_truth.params]
 *
 * Four states spread over the axis ranges and the inputs' typical ranges (lags in steady
 * state, directions alternating, the tools in turn) are evaluated with the bound parameter
 * values (the machine's own params block and the optional parameter file): the error, the error
 * with its beta-Jacobian, the nominal location, and all four again in one batch call. Every
 * number is printed with 17 significant digits, one record per line:
 *
 *   counts AXES INPUTS LAGS TOOLS COEFFICIENTS
 *   err K e0 .. e5            error at state K (kin_eval)
 *   jerr K e0 .. e5           error at state K (kin_eval_jacobian)
 *   jac K j0 .. j(6n-1)       its Jacobian, row-major
 *   nominal K p0 p1 p2        nominal tool position
 *   batch K e0 .. e5          error at state K (kin_eval_batch)
 *   pbatch K e0 e1 e2 j0 .. j(3n-1)
 *                             position rows at state K (kin_eval_batch_observed, observed 7):
 *                             the error's ex, ey, ez and their Jacobian rows
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "kin.h"

#define STATES 4

static char *read_file(const char *path, size_t *len) {
    FILE *f = fopen(path, "rb");
    if (!f) {
        perror(path);
        return NULL;
    }
    size_t cap = 1 << 16, n = 0;
    char *buf = malloc(cap);
    size_t got;
    while (buf && (got = fread(buf + n, 1, cap - n, f)) > 0) {
        n += got;
        if (n == cap) {
            char *bigger = realloc(buf, cap *= 2);
            if (!bigger) free(buf);
            buf = bigger;
        }
    }
    fclose(f);
    *len = n;
    return buf;
}

static void fail(const char *what, int status) {
    char message[1024];
    kin_last_error(message, sizeof message);
    fprintf(stderr, "%s failed (status %d): %s\n", what, status, message);
    exit(1);
}

static void print(const char *tag, size_t k, const double *v, size_t n) {
    printf("%s %zu", tag, k);
    for (size_t i = 0; i < n; i++) printf(" %.17g", v[i]);
    printf("\n");
}

int main(int argc, char **argv) {
    if (argc < 2 || argc > 3) {
        fprintf(stderr, "usage: %s MACHINE.kin [PARAMS]\n", argv[0]);
        return 2;
    }
    size_t len;
    char *src = read_file(argv[1], &len);
    if (!src) return 2;
    kin_model *model = NULL;
    char err[4096];
    int status = kin_model_compile(src, len, &model, err, sizeof err);
    free(src);
    if (status != KIN_OK) {
        fprintf(stderr, "%s:\n%s\n", argv[1], err);
        return 1;
    }
    if (argc == 3) {
        char *params = read_file(argv[2], &len);
        if (!params) return 2;
        status = kin_model_bind_params(model, params, len, err, sizeof err);
        free(params);
        if (status != KIN_OK) {
            fprintf(stderr, "%s:\n%s\n", argv[2], err);
            return 1;
        }
    }

    size_t axes = kin_model_axes(model), inputs = kin_model_inputs(model), lags = kin_model_lags(model);
    size_t tools = kin_model_tools(model), n = kin_model_coefficients(model);
    printf("counts %zu %zu %zu %zu %zu\n", axes, inputs, lags, tools, n);

    /* The states, row-major, as the batch call takes them. */
    double *q = calloc(STATES * axes + 1, sizeof(double));
    double *dirs = calloc(STATES * axes + 1, sizeof(double));
    double *in = calloc(STATES * inputs + 1, sizeof(double));
    double *lag = calloc(STATES * lags + 1, sizeof(double));
    double time[STATES];
    size_t tool[STATES];
    double *jac = calloc(6 * n + 1, sizeof(double));
    double *nominal_jac = calloc(6 * axes + 1, sizeof(double));
    if (!q || !dirs || !in || !lag || !jac || !nominal_jac) return 2;
    for (size_t k = 0; k < STATES; k++) {
        double t = (k + 1.0) / (STATES + 1.0);
        for (size_t a = 0; a < axes; a++) {
            double lo, hi;
            if ((status = kin_model_axis_range(model, a, &lo, &hi)) != KIN_OK) fail("kin_model_axis_range", status);
            q[k * axes + a] = lo + t * (hi - lo);
            dirs[k * axes + a] = (k + a) % 2 ? -1.0 : 1.0;
        }
        for (size_t i = 0; i < inputs; i++) {
            double lo, hi;
            if ((status = kin_model_input_range(model, i, &lo, &hi)) != KIN_OK) fail("kin_model_input_range", status);
            in[k * inputs + i] = lo + t * (hi - lo);
        }
        for (size_t l = 0; l < lags; l++) {
            size_t i;
            if ((status = kin_model_lag_input(model, l, &i)) != KIN_OK) fail("kin_model_lag_input", status);
            lag[k * lags + l] = in[k * inputs + i];
        }
        time[k] = 60.0 * k;
        tool[k] = k % tools;
    }

    for (size_t k = 0; k < STATES; k++) {
        kin_state s = {q + k * axes, axes, in + k * inputs, inputs, lag + k * lags, lags,
                       dirs + k * axes, axes, time[k], tool[k]};
        double e[6], location[12];
        /* NULL, 0: the bound coefficient values. */
        if ((status = kin_eval(model, &s, NULL, 0, e, 6)) != KIN_OK) fail("kin_eval", status);
        print("err", k, e, 6);
        if ((status = kin_eval_jacobian(model, &s, NULL, 0, e, 6, jac, 6 * n)) != KIN_OK) fail("kin_eval_jacobian", status);
        print("jerr", k, e, 6);
        print("jac", k, jac, 6 * n);
        if ((status = kin_nominal_jacobian(model, &s, location, 12, nominal_jac, 6 * axes)) != KIN_OK)
            fail("kin_nominal_jacobian", status);
        print("nominal", k, location, 3);
    }

    kin_rows rows = {STATES, q, STATES * axes, in, STATES * inputs, lag, STATES * lags,
                     dirs, STATES * axes, time, STATES, tool, STATES};
    double batch[6 * STATES];
    if ((status = kin_eval_batch(model, &rows, NULL, 0, batch, 6 * STATES, NULL, 0)) != KIN_OK)
        fail("kin_eval_batch", status);
    for (size_t k = 0; k < STATES; k++) print("batch", k, batch + 6 * k, 6);

    /* Position rows alone (a tracker's data): 3 errors and a 3 x n block per state. */
    double *pos = malloc(sizeof(double) * (3 + 3 * n) * STATES);
    if (!pos) return 1;
    double *pos_err = pos, *pos_jac = pos + 3 * STATES;
    if ((status = kin_eval_batch_observed(model, &rows, NULL, 0, 7, pos_err, 3 * STATES, pos_jac,
                                          3 * n * STATES)) != KIN_OK)
        fail("kin_eval_batch_observed", status);
    for (size_t k = 0; k < STATES; k++) {
        double *record = malloc(sizeof(double) * (3 + 3 * n));
        if (!record) return 1;
        memcpy(record, pos_err + 3 * k, 3 * sizeof(double));
        memcpy(record + 3, pos_jac + 3 * n * k, 3 * n * sizeof(double));
        print("pbatch", k, record, 3 + 3 * n);
        free(record);
    }
    free(pos);

    /* A wrong length is refused, not read past. */
    kin_state bad = {q, axes + 1, in, inputs, lag, lags, dirs, axes, 0.0, 0};
    double e[6];
    status = kin_eval(model, &bad, NULL, 0, e, 6);
    kin_last_error(err, sizeof err);
    fprintf(stderr, "a state with %zu axis positions: status %d, %s\n", axes + 1, status, err);

    free(q);
    free(dirs);
    free(in);
    free(lag);
    free(jac);
    free(nominal_jac);
    kin_model_free(model);
    return status == KIN_ERR_SIZE ? 0 : 1;
}

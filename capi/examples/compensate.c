/*
 * compensate.c: the compiled compensation function of the kin C ABI (thesis section 2.3.5).
 *
 *   cc compensate.c -I capi/include -L target/debug -lkin_capi -Wl,-rpath,target/debug -o compensate
 *   ./compensate examples/milling_5axis.kin
 *
 * The machine's coefficients are set to small values of both signs (beta_j = (j mod 7 - 3) um
 * or urad per unit), a compensator is made with the default weights and iterations, and four
 * commanded poses spread over the axis ranges (inputs over their typical ranges, directions
 * alternating, the tools in turn) are compensated. One record per line, 17 digits:
 *
 *   dq K d0 .. d(axes-1)      the joint corrections of pose K
 *   before K e0 .. e5         the predicted error at the commanded pose
 *   after K e0 .. e5          the predicted error of the compensated pose
 *   rank K r                  how many weighted components the joints can move
 *
 * and on standard error the statuses of a command outside its range and of an output that
 * overlaps the state.
 */
#include <stdio.h>
#include <stdlib.h>

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
    if (argc != 2) {
        fprintf(stderr, "usage: %s MACHINE.kin\n", argv[0]);
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
    size_t axes = kin_model_axes(model), inputs = kin_model_inputs(model), lags = kin_model_lags(model);
    size_t tools = kin_model_tools(model), n = kin_model_coefficients(model);
    double *beta = calloc(n + 1, sizeof(double));
    double *q = calloc(axes + 1, sizeof(double));
    double *dirs = calloc(axes + 1, sizeof(double));
    double *dq = calloc(axes + 1, sizeof(double));
    double *in = calloc(inputs + 1, sizeof(double));
    double *lag = calloc(lags + 1, sizeof(double));
    if (!beta || !q || !dirs || !dq || !in || !lag) return 2;
    for (size_t j = 0; j < n; j++) beta[j] = 1e-6 * ((double)(j % 7) - 3.0);
    if ((status = kin_model_set_beta(model, beta, n)) != KIN_OK) fail("kin_model_set_beta", status);

    kin_compensator *comp = NULL;
    if ((status = kin_compensator_new(model, NULL, 0, 0, &comp)) != KIN_OK) fail("kin_compensator_new", status);

    for (size_t k = 0; k < STATES; k++) {
        double t = (k + 1.0) / (STATES + 1.0);
        for (size_t a = 0; a < axes; a++) {
            double lo, hi;
            if ((status = kin_model_axis_range(model, a, &lo, &hi)) != KIN_OK) fail("kin_model_axis_range", status);
            q[a] = lo + t * (hi - lo);
            dirs[a] = (k + a) % 2 ? -1.0 : 1.0;
        }
        for (size_t i = 0; i < inputs; i++) {
            double lo, hi;
            if ((status = kin_model_input_range(model, i, &lo, &hi)) != KIN_OK) fail("kin_model_input_range", status);
            in[i] = lo + t * (hi - lo);
        }
        for (size_t l = 0; l < lags; l++) {
            size_t i;
            if ((status = kin_model_lag_input(model, l, &i)) != KIN_OK) fail("kin_model_lag_input", status);
            lag[l] = in[i];
        }
        kin_state s = {q, axes, in, inputs, lag, lags, dirs, axes, 60.0 * k, k % tools};
        double before[6], after[6];
        size_t rank = 0;
        if ((status = kin_compensate(comp, &s, dq, axes, before, 6, after, 6, &rank)) != KIN_OK)
            fail("kin_compensate", status);
        print("dq", k, dq, axes);
        print("before", k, before, 6);
        print("after", k, after, 6);
        printf("rank %zu %zu\n", k, rank);
    }

    /* A command past the end of the first axis's range is refused, and so is an output that
     * overlaps the commanded positions. */
    double lo, hi;
    if ((status = kin_model_axis_range(model, 0, &lo, &hi)) != KIN_OK) fail("kin_model_axis_range", status);
    kin_state s = {q, axes, in, inputs, lag, lags, dirs, axes, 0.0, 0};
    double keep = q[0];
    q[0] = hi + 0.5 * (hi - lo) + 1.0;
    status = kin_compensate(comp, &s, dq, axes, NULL, 0, NULL, 0, NULL);
    kin_last_error(err, sizeof err);
    fprintf(stderr, "outside the range: status %d, %s\n", status, err);
    q[0] = keep;
    status = kin_compensate(comp, &s, q, axes, NULL, 0, NULL, 0, NULL);
    kin_last_error(err, sizeof err);
    fprintf(stderr, "dq over q: status %d, %s\n", status, err);

    kin_compensator_free(comp);
    kin_model_free(model);
    free(beta);
    free(q);
    free(dirs);
    free(dq);
    free(in);
    free(lag);
    return 0;
}

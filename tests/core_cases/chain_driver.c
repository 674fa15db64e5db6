/* chain_driver.c -- a plain C host of the model core (models/core/, no Python): one run of the
 * RailCar chain from a file, its outputs to a file. tests/model_tests/core/test_core_sanitized.py builds it with
 * AddressSanitizer/UndefinedBehaviorSanitizer and from mutated copies of the core.
 *
 *   chain_driver INPUT OUTPUT
 *
 * INPUT, little-endian IEEE doubles (integers stored as doubles):
 *   n_config, n_grade, n_speed, n_steps,
 *   config[n_config]                     -- models/compiled.py's _config_values order
 *   grade_distances[n_grade], grades[n_grade],
 *   speed_distances[n_speed], speeds[n_speed],
 *   n_steps rows of 6: current_time, step_size, traction, brake, wind, payload
 * OUTPUT, little-endian doubles: (1 + steps done) rows of RC_CHAIN_OUTPUTS (rc_chain_outputs, the
 * names of models/compiled.py's OUTPUT_NAMES): at the start, then after each step.
 *
 * Exit status: 0 when every step ran; 1 for a bad command line, file or format; 2 when the
 * configuration is refused; 3 when a step is rejected (the rows before it are written). The
 * reason is on stderr; nothing else is printed.
 *
 * Build (with every .c file of models/core):
 *        gcc -std=c99 -O2 -ffp-contract=off -Wall -Wextra -Werror -pedantic -I models/core
 *        tests/core_cases/chain_driver.c models/core/[a-z]*.c -lm
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "railcar.h"

#define MAX_COUNT 100000000L     /* a sanity bound on every count in the header */

static int little_endian(void)
{
    const uint16_t one = 1;
    unsigned char b;
    memcpy(&b, &one, 1);
    return b == 1;
}

static void swap_doubles(double *x, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        unsigned char b[sizeof(double)], t;
        memcpy(b, &x[i], sizeof b);
        for (size_t j = 0; j < sizeof b / 2; j++) {
            t = b[j];
            b[j] = b[sizeof b - 1 - j];
            b[sizeof b - 1 - j] = t;
        }
        memcpy(&x[i], b, sizeof b);
    }
}

/* n doubles from f into x; 0 on success */
static int read_doubles(FILE *f, double *x, size_t n)
{
    if (n == 0)
        return 0;
    if (fread(x, sizeof(double), n, f) != n)
        return -1;
    if (!little_endian())
        swap_doubles(x, n);
    return 0;
}

static int write_doubles(FILE *f, double *x, size_t n)
{
    int ok;
    if (!little_endian())
        swap_doubles(x, n);
    ok = fwrite(x, sizeof(double), n, f) == n;
    if (!little_endian())
        swap_doubles(x, n);
    return ok ? 0 : -1;
}

/* a count from the header: a whole number in [lo, MAX_COUNT] */
static int count(double v, long lo, long *out)
{
    if (!(v >= (double)lo && v <= (double)MAX_COUNT) || v != (double)(long)v)
        return -1;
    *out = (long)v;
    return 0;
}

int main(int argc, char **argv)
{
    FILE *in = NULL, *out = NULL;
    double header[4], *data = NULL, row[RC_CHAIN_OUTPUTS];
    long n_config, n_grade, n_speed, n_steps, k;
    int status = 1;
    rc_chain_config cfg;
    rc_chain *chain = NULL;
    rc_error err;

    if (argc != 3) {
        fprintf(stderr, "usage: %s INPUT OUTPUT\n", argc > 0 ? argv[0] : "chain_driver");
        return 1;
    }
    if (!(in = fopen(argv[1], "rb"))) {
        fprintf(stderr, "cannot open %s\n", argv[1]);
        goto done;
    }
    if (read_doubles(in, header, 4) || count(header[0], 0, &n_config) || count(header[1], 1, &n_grade)
            || count(header[2], 0, &n_speed) || count(header[3], 0, &n_steps)) {
        fprintf(stderr, "%s: bad header (n_config, n_grade >= 1, n_speed, n_steps)\n", argv[1]);
        goto done;
    }
    size_t total = (size_t)n_config + 2 * (size_t)n_grade + 2 * (size_t)n_speed + 6 * (size_t)n_steps;
    if (!(data = malloc(total * sizeof(double)))) {
        fprintf(stderr, "out of memory for %zu values\n", total);
        goto done;
    }
    if (read_doubles(in, data, total) || fgetc(in) != EOF) {
        fprintf(stderr, "%s: expected exactly %zu values after the header\n", argv[1], total);
        goto done;
    }
    const double *config = data;
    const double *grade_d = config + n_config, *grade_g = grade_d + n_grade;
    const double *speed_d = grade_g + n_grade, *speed_v = speed_d + n_speed;
    const double *steps = speed_v + n_speed;

    memset(&cfg, 0, sizeof cfg);
    long expected = rc_chain_config_from_values(&cfg, config, n_config);
    if (expected) {
        fprintf(stderr, "the core takes %ld configuration values, got %ld\n", expected, n_config);
        goto done;
    }
    cfg.grade_distances = grade_d;
    cfg.grades = grade_g;
    cfg.grade_n = n_grade;
    cfg.speed_distances = n_speed ? speed_d : NULL;
    cfg.speeds = n_speed ? speed_v : NULL;
    cfg.speed_n = n_speed;
    if (!(chain = malloc(sizeof *chain))) {
        fprintf(stderr, "out of memory for the chain\n");
        goto done;
    }
    if (rc_chain_init(chain, &cfg, &err) != RC_OK) {
        fprintf(stderr, "configuration refused: %s\n", err.msg);
        free(chain);
        chain = NULL;
        status = 2;
        goto done;
    }
    if (!(out = fopen(argv[2], "wb"))) {
        fprintf(stderr, "cannot create %s\n", argv[2]);
        goto done;
    }
    rc_chain_outputs(chain, row);
    if (write_doubles(out, row, RC_CHAIN_OUTPUTS))
        goto write_error;
    for (k = 0; k < n_steps; k++) {
        const double *x = steps + 6 * k;
        if (rc_chain_step(chain, x[0], x[1], x[2], x[3], x[4], x[5], &err) != RC_OK) {
            fprintf(stderr, "step %ld rejected: %s\n", k, err.msg);
            status = 3;
            goto done;
        }
        rc_chain_outputs(chain, row);
        if (write_doubles(out, row, RC_CHAIN_OUTPUTS))
            goto write_error;
    }
    status = 0;
    goto done;
write_error:
    fprintf(stderr, "cannot write %s\n", argv[2]);
done:
    if (chain) {
        rc_chain_free(chain);
        free(chain);
    }
    free(data);
    if (in)
        fclose(in);
    if (out && fclose(out) != 0 && status == 0) {
        fprintf(stderr, "cannot write %s\n", argv[2]);
        status = 1;
    }
    return status;
}

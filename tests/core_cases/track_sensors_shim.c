/* track_sensors_shim.c -- test-only host of the C chain with track sensors (tests/
 * test_core_track_sensors.py builds it under -fsanitize=address,undefined): one run from stdin,
 * the outputs to stdout. No Python.
 *
 * stdin, native doubles: n_config, n_grade, n_steps, config[n_config] (models/compiled.py's
 * _config_values order), grade_distances[n_grade], grades[n_grade], then n_steps rows of
 * current_time, step_size, traction, brake, wind, payload.
 * stdout, native doubles: rc_chain_outputs at the start and after each step.
 * Exit status 0; 1 bad input; 2 configuration refused; 3 step rejected (message on stderr).
 */
#include <stdio.h>
#include <stdlib.h>

#include "railcar.h"

static int read_doubles(double *x, long n)
{
    return fread(x, sizeof(double), (size_t)n, stdin) == (size_t)n;
}

int main(void)
{
    double head[3];
    if (!read_doubles(head, 3) || head[0] < 1 || head[0] > 1000 || head[1] < 1 || head[1] > 1e6
            || head[2] < 0 || head[2] > 1e7)
        return 1;
    long nc = (long)head[0], ng = (long)head[1], ns = (long)head[2];
    double *buf = malloc(sizeof(double) * (size_t)(nc + 2 * ng + 6));
    rc_chain *c = malloc(sizeof *c);
    int status = 1;
    rc_chain_config cfg;
    rc_error err;
    double out[RC_CHAIN_OUTPUTS];
    if (!buf || !c || !read_doubles(buf, nc + 2 * ng))
        goto done;
    if (rc_chain_config_from_values(&cfg, buf, nc) != 0)
        goto done;
    cfg.grade_distances = buf + nc;
    cfg.grades = buf + nc + ng;
    cfg.grade_n = ng;
    cfg.speed_distances = cfg.speeds = NULL;
    cfg.speed_n = 0;
    if (rc_chain_init(c, &cfg, &err) != RC_OK) {
        fprintf(stderr, "%s\n", err.msg);
        status = 2;
        goto done;
    }
    rc_chain_outputs(c, out);
    fwrite(out, sizeof(double), RC_CHAIN_OUTPUTS, stdout);
    double *r = buf + nc + 2 * ng;
    status = 0;
    for (long k = 0; k < ns && status == 0; k++) {
        if (!read_doubles(r, 6)) {
            status = 1;
        } else if (rc_chain_step(c, r[0], r[1], r[2], r[3], r[4], r[5], &err) != RC_OK) {
            fprintf(stderr, "%s\n", err.msg);
            status = 3;
        } else {
            rc_chain_outputs(c, out);
            fwrite(out, sizeof(double), RC_CHAIN_OUTPUTS, stdout);
        }
    }
    rc_chain_free(c);
done:
    free(c);
    free(buf);
    return status;
}

/* ato_supervision_shim.c -- test-only: models/core/ato_supervision.c on flat op records for
 * ctypes (tests/model_tests/core/test_core_ato_supervision.py).
 *
 * An op record is SHIM_OP_SIZE doubles: kind, t, then ATO_N_ALL_INPUTS values:
 *   kind 0: ato_supervisor_init(mass = values[0])
 *   kind 1: ato_supervisor_check(t, values[0..9])
 *   kind 2: ato_supervisor_note_command(traction = values[0])
 *   kind 3: ato_supervisor_gate(t, values[0..16])
 * shim_apply writes SHIM_ROW_SIZE doubles per op (the result: the check's reason or the gate's
 * verdict; the verdict's subject and reason code; the state; the gate's values) and the verdict's text (SHIM_TEXT_SIZE characters per op).
 *
 * With -DATO_SUPERVISION_MAIN it is a program for the sanitizer run: `shim in out` reads op
 * records (little-endian doubles) from `in` and writes each op's row and text to `out`. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ato_supervision.h"

#define SHIM_OP_SIZE (2 + ATO_N_ALL_INPUTS)
#define SHIM_STATE_SIZE 21
#define SHIM_ROW_SIZE (3 + SHIM_STATE_SIZE + ATO_N_ALL_INPUTS)
#define SHIM_TEXT_SIZE ATO_TEXT_SIZE

int shim_sizes(int *op, int *row, int *text, int *supervisor)
{
    *op = SHIM_OP_SIZE;
    *row = SHIM_ROW_SIZE;
    *text = SHIM_TEXT_SIZE;
    *supervisor = (int)sizeof(ato_supervisor);
    return 0;
}

/* The state InputSupervisor and the controller's latch keep, as doubles */
static void state(const ato_supervisor *s, double *out)
{
    const double v[SHIM_STATE_SIZE] = {
        s->has_t_last, s->t_last, s->has_anchor, s->anchor_t, s->anchor_s, s->anchor_psd,
        s->travel, s->v_last, s->t_prev, s->sd_max, s->pushing, s->pushing_t, s->pushing_s,
        s->dead, s->dead_s, s->at_rest, s->at_rest_t, s->at_rest_s, s->latched,
        s->has_sane_since, s->sane_since};
    memcpy(out, v, sizeof v);
}

/* n op records through one supervisor (the first op should be kind 0); 0, or -1 - k for an
 * unknown kind at op k */
int shim_apply(ato_supervisor *s, const double *ops, long n, double *rows, char *texts)
{
    for (long k = 0; k < n; k++) {
        const double *op = ops + k * SHIM_OP_SIZE;
        double *row = rows + k * SHIM_ROW_SIZE;
        char *text = texts + k * SHIM_TEXT_SIZE;
        double t = op[1];
        const double *v = op + 2;
        const ato_problem *p = NULL;
        int code = 0;
        memset(row, 0, sizeof(double) * SHIM_ROW_SIZE);
        switch ((int)op[0]) {
        case 0:
            ato_supervisor_init(s, v[0]);
            break;
        case 1:
            code = (int)ato_supervisor_check(s, t, v);
            p = &s->problem;
            break;
        case 2:
            ato_supervisor_note_command(s, v[0]);
            break;
        case 3:
            code = (int)ato_supervisor_gate(s, t, v, row + 3 + SHIM_STATE_SIZE);
            p = &s->gate;
            break;
        default:
            return (int)(-1 - k);
        }
        row[0] = code;
        row[1] = p ? p->subject : ATO_SUBJECT_NONE;
        row[2] = p ? (double)p->reason : (double)ATO_SANE;
        state(s, row + 3);
        snprintf(text, SHIM_TEXT_SIZE, "%s", p ? p->text : "");
    }
    return 0;
}

const char *shim_subject_name(int subject) { return ato_subject_name(subject); }

#ifdef ATO_SUPERVISION_MAIN
int main(int argc, char **argv)
{
    if (argc != 3)
        return 1;
    FILE *in = fopen(argv[1], "rb");
    if (!in)
        return 1;
    fseek(in, 0, SEEK_END);
    long bytes = ftell(in);
    fseek(in, 0, SEEK_SET);
    long n = bytes / (long)(sizeof(double) * SHIM_OP_SIZE);
    double *ops = malloc(sizeof(double) * SHIM_OP_SIZE * (size_t)(n ? n : 1));
    double *rows = malloc(sizeof(double) * SHIM_ROW_SIZE * (size_t)(n ? n : 1));
    char *texts = malloc((size_t)SHIM_TEXT_SIZE * (size_t)(n ? n : 1));
    ato_supervisor *s = malloc(sizeof *s);
    int status = 0;
    if (!ops || !rows || !texts || !s ||
        fread(ops, sizeof(double) * SHIM_OP_SIZE, (size_t)n, in) != (size_t)n)
        status = 2;
    fclose(in);
    if (status == 0 && shim_apply(s, ops, n, rows, texts) != 0)
        status = 3;
    FILE *out = status == 0 ? fopen(argv[2], "wb") : NULL;
    if (status == 0 && !out)
        status = 1;
    if (out) {
        if (fwrite(rows, sizeof(double) * SHIM_ROW_SIZE, (size_t)n, out) != (size_t)n ||
            fwrite(texts, SHIM_TEXT_SIZE, (size_t)n, out) != (size_t)n)
            status = 1;
        fclose(out);
    }
    free(ops);
    free(rows);
    free(texts);
    free(s);
    return status;
}
#endif

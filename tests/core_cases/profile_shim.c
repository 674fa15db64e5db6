/* profile_shim.c -- test-only access to models/core/profile.c for tests/model_tests/core/test_core_profile.py.
 *
 * As a shared library (ctypes): shim_parse / shim_read_file run one parse or file read and copy
 * the outcome into the caller's buffers: distances and values (room for cap each), *n, the whole
 * message into msg (msgcap bytes, *msglen its length) and the cut rc_error copy into err.
 *
 * Built with -DPROFILE_SHIM_MAIN it is a program (the sanitizer run): stdin holds records
 *   int32 op, int64 len, len bytes
 * op 0/1: parse the bytes as a grade/speed profile named "src.csv"; op 2/3: read the file the
 * bytes name as a grade/speed profile, the harness's way; op 4/5: the same, the FMU's way
 * (param track.grade_profile / track.speed_profile, raw = the path). stdout, per record:
 *   int32 status, int64 n, n distances, n values (doubles), int64 message length, message.
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "profile.h"

static int copy_out(int status, rc_profile *p, double *d, double *v, long cap, long *n,
                    char *msg, long msgcap, long *msglen, char *err)
{
    *n = p->n;
    for (long k = 0; k < p->n && k < cap; k++) {
        d[k] = p->distances[k];
        v[k] = p->values[k];
    }
    *msglen = p->message ? (long)p->message_len : -1;
    if (msgcap > 0) {
        long m = *msglen < 0 ? 0 : (*msglen < msgcap - 1 ? *msglen : msgcap - 1);
        if (m > 0)
            memcpy(msg, p->message, (size_t)m);
        msg[m] = '\0';
    }
    memcpy(err, p->err.msg, RC_MSG_SIZE);
    rc_profile_free(p);
    return status;
}

/* kind 0/1: GradeProfile/SpeedProfile.from_csv_text; kind 2: parse_profile_csv with the
 * columns and options given */
int shim_parse(int kind, const char *text, long len, const char *source, const char *col0,
               const char *col1, int nonnegative, double max_abs, double *d, double *v, long cap,
               long *n, char *msg, long msgcap, long *msglen, char *err)
{
    rc_profile p;
    int status = kind == 2
        ? rc_profile_parse(text, (size_t)len, source, col0, col1, nonnegative, max_abs, &p)
        : rc_profile_parse_kind(text, (size_t)len, source, (rc_profile_kind)kind, &p);
    return copy_out(status, &p, d, v, cap, n, msg, msgcap, msglen, err);
}

int shim_read_file(const char *path, const char *param, const char *raw, int kind, double *d,
                   double *v, long cap, long *n, char *msg, long msgcap, long *msglen, char *err)
{
    rc_profile p;
    int status = rc_profile_read_file(path, param, raw, (rc_profile_kind)kind, &p);
    return copy_out(status, &p, d, v, cap, n, msg, msgcap, msglen, err);
}

int shim_msg_size(void) { return RC_MSG_SIZE; }

#ifdef PROFILE_SHIM_MAIN
int main(void)
{
    int32_t op;
    int64_t len;
    while (fread(&op, sizeof op, 1, stdin) == 1) {
        if (fread(&len, sizeof len, 1, stdin) != 1 || len < 0 || len > (1 << 26))
            return 1;
        char *text = malloc((size_t)len + 1);
        if (!text || fread(text, 1, (size_t)len, stdin) != (size_t)len)
            return 1;
        text[len] = '\0';
        rc_profile p;
        int32_t status;
        rc_profile_kind kind = (rc_profile_kind)(op & 1);
        if (op <= 1)
            status = rc_profile_parse_kind(text, (size_t)len, "src.csv", kind, &p);
        else if (op <= 3)
            status = rc_profile_read_file(text, NULL, NULL, kind, &p);
        else
            status = rc_profile_read_file(text, kind == RC_PROFILE_GRADE ? "track.grade_profile"
                                          : "track.speed_profile", text, kind, &p);
        int64_t n = p.n, mlen = p.message ? (int64_t)p.message_len : -1;
        fwrite(&status, sizeof status, 1, stdout);
        fwrite(&n, sizeof n, 1, stdout);
        if (n > 0) {
            fwrite(p.distances, sizeof(double), (size_t)n, stdout);
            fwrite(p.values, sizeof(double), (size_t)n, stdout);
        }
        fwrite(&mlen, sizeof mlen, 1, stdout);
        if (mlen > 0)
            fwrite(p.message, 1, (size_t)mlen, stdout);
        rc_profile_free(&p);
        rc_profile_free(&p);                     /* twice is safe */
        free(text);
    }
    return 0;
}
#endif

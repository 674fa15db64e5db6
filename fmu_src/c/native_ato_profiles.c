/* native_ato_profiles.c -- the native AtoController's profile files (native_ato.c builds the
 * model from what they give): the check of their names, span.grade_profile (read as RailCar
 * reads a grade profile), span.speed_limit_profile, and the line files line.profile and
 * line.speed_limit_profile (models/core/ato_line_profile.c parses them). Paths resolve as the
 * pythonfmu slave resolves them (glue_common.h's gc_resolve_profile_path: relative ones under
 * resources/); every refusal is Python's text, naming the parameter and the file.
 * See native_ato_profiles.h.
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "native_ato_profiles.h"
#include "profile.h"
#include "rc_common.h"
#include "track.h"

/* check_span_parameters' file-name check: a name the file system refuses names the parameter */
int nat_usable_name(GlueInstance *g, const nat_instance *m, int vr, char *msg) {
    const char *raw = nat_string_of(m, vr);
    char *path;
    struct stat st;
    int bad = 0, code = 0;
    if (!raw[0]) return 1;
    if (!(path = gc_resolve_profile_path(raw, g->resources)))
        return nat_refuse(msg, "out of memory");
    if (stat(path, &st) != 0) {
        code = errno;             /* pathlib's is_file() lets only these through */
        bad = code != ENOENT && code != ENOTDIR && code != EBADF && code != ELOOP;
    }
    free(path);
    if (!bad) return 1;
    {
        size_t chars = 0, cut = 0;
        const unsigned char *s = (const unsigned char *)raw;
        size_t i;
        for (i = 0; s[i]; i++)
            if ((s[i] & 0xC0) != 0x80) {
                if (chars == 60) cut = i;
                chars++;
            }
        if (chars <= 80)
            return nat_refuse(msg, "%s: cannot use '%s' as a file name: %s", NAT_VARS[vr].name, raw,
                              strerror(code));
        return nat_refuse(msg, "%s: cannot use '%.*s...(%lu characters)' as a file name: %s",
                          NAT_VARS[vr].name, (int)cut, raw, (unsigned long)chars, strerror(code));
    }
}

/* read_grade: the grade profile of span.grade_profile (level if empty), its integral ready */
int nat_read_grade(GlueInstance *g, nat_instance *m, char *msg) {
    static const double level = 0.0;
    const char *raw = nat_string_of(m, NAT_VR_SPAN_GRADE_PROFILE);
    const double *d = &level, *gr = &level;
    long n = 1;
    rc_profile prof;
    memset(&prof, 0, sizeof prof);
    if (raw[0]) {
        char *path = gc_resolve_profile_path(raw, g->resources);
        int status;
        if (!path) return nat_refuse(msg, "out of memory");
        status = rc_profile_read_file(path, "span.grade_profile", raw, RC_PROFILE_GRADE, &prof);
        free(path);
        if (status != RC_OK) {
            nat_refuse(msg, "%s", prof.message ? prof.message : prof.err.msg);
            rc_profile_free(&prof);
            return 0;
        }
        d = prof.distances;
        gr = prof.values;
        n = prof.n;
    }
    if (!(m->grade_block = malloc(3 * (size_t)n * sizeof(double)))) {
        rc_profile_free(&prof);
        return nat_refuse(msg, "out of memory");
    }
    memcpy(m->grade_block, d, (size_t)n * sizeof(double));
    memcpy(m->grade_block + n, gr, (size_t)n * sizeof(double));
    rc_profile_free(&prof);
    m->span.grade.n = (int)n;
    m->span.grade.distances = m->grade_block;
    m->span.grade.grades = m->grade_block + n;
    rc_grade_cumulate(m->grade_block, m->grade_block + n, n, m->grade_block + 2 * n);
    m->span.grade.cum = m->grade_block + 2 * n;
    return 1;
}

/* read_profile_text: the text of the file the parameter `param` (value raw) names, 1 with
   *text NULL for an empty raw; else 0 with Python's refusal in msg. *text and *where (str(path))
   malloc'd: the caller frees them. */
static int read_text(GlueInstance *g, const char *param, const char *raw, char **text,
                     size_t *len, char **where, char *msg) {
    rc_profile refusal;
    char *path;
    int status;
    *text = NULL;
    *where = NULL;
    *len = 0;
    if (!raw[0]) return 1;
    if (!(path = gc_resolve_profile_path(raw, g->resources)))
        return nat_refuse(msg, "out of memory");
    status = rc_profile_read_text(path, param, raw, text, len, where, &refusal);
    free(path);
    if (status == RC_OK) return 1;
    nat_refuse(msg, "%s", refusal.message ? refusal.message : refusal.err.msg);
    rc_profile_free(&refusal);
    return 0;
}

/* open_ato's limits: span.speed_limit_profile (parse_profile_csv with columns distance_m,
   speed_limit_mps, read by read_profile_text) or the one limit span.speed_limit */
int nat_read_limits(GlueInstance *g, nat_instance *m, int *from_profile, char *msg) {
    const char *raw = nat_string_of(m, NAT_VR_SPAN_SPEED_LIMIT_PROFILE);
    rc_profile lim;
    char *text, *where;
    size_t len;
    int status;
    *from_profile = raw[0] != '\0';
    if (!raw[0]) {
        if (!(m->limit_block = malloc(2 * sizeof(double)))) return nat_refuse(msg, "out of memory");
        m->limit_block[0] = 0.0;
        m->limit_block[1] = m->real[NAT_VR_SPAN_SPEED_LIMIT];
        m->span.n_limits = 1;
        m->span.limit_distances = m->limit_block;
        m->span.limit_speeds = m->limit_block + 1;
        return 1;
    }
    if (!read_text(g, "span.speed_limit_profile", raw, &text, &len, &where, msg)) return 0;
    status = rc_profile_parse(text, len, where, "distance_m", "speed_limit_mps", 0, INFINITY, &lim);
    free(text);
    free(where);
    if (status != RC_OK) {
        nat_refuse(msg, "span.speed_limit_profile: %s", lim.message ? lim.message : lim.err.msg);
        rc_profile_free(&lim);
        return 0;
    }
    if (!(m->limit_block = malloc(2 * (size_t)lim.n * sizeof(double)))) {
        rc_profile_free(&lim);
        return nat_refuse(msg, "out of memory");
    }
    memcpy(m->limit_block, lim.distances, (size_t)lim.n * sizeof(double));
    memcpy(m->limit_block + lim.n, lim.values, (size_t)lim.n * sizeof(double));
    m->span.n_limits = (int)lim.n;
    m->span.limit_distances = m->limit_block;
    m->span.limit_speeds = m->limit_block + lim.n;
    rc_profile_free(&lim);
    return 1;
}

/* read_line_profile and read_line_limits (open_line's files) */
int nat_read_line_files(GlueInstance *g, nat_instance *m, ato_line_row **rows, long *n_rows,
                        char **line_where, char *msg) {
    char *line_text = NULL, *lim_text = NULL, *lim_where = NULL;
    size_t line_len = 0, lim_len = 0;
    rc_profile refusal;
    int ok = 0;
    memset(&refusal, 0, sizeof refusal);
    *rows = NULL;
    *n_rows = 0;
    *line_where = NULL;
    if (!read_text(g, "line.profile", nat_string_of(m, NAT_VR_LINE_PROFILE), &line_text,
                   &line_len, line_where, msg) ||
        !read_text(g, "line.speed_limit_profile",
                   nat_string_of(m, NAT_VR_LINE_SPEED_LIMIT_PROFILE), &lim_text, &lim_len,
                   &lim_where, msg))
        goto done;
    if (!line_text && lim_text) {
        nat_refuse(msg, "line.speed_limit_profile: %s: given without line.profile (the spans it "
                   "limits)", lim_where);
        goto done;
    }
    if (line_text) {
        if (ato_line_profile_parse(line_text, line_len, *line_where, rows, n_rows, &refusal)
                != RC_OK)
            goto refused_parse;
        if (*n_rows >= INT_MAX / 8) {
            nat_refuse(msg, "line.profile: %s: out of memory (%ld spans)", *line_where, *n_rows);
            goto done;
        }
        if (lim_text && ato_line_limits_parse(lim_text, lim_len, lim_where, (int)*n_rows + 1,
                                              &m->line_limits, &refusal) != RC_OK)
            goto refused_parse;
    }
    ok = 1;
    goto done;
refused_parse:
    nat_refuse(msg, "%s", refusal.message ? refusal.message : refusal.err.msg);
done:
    rc_profile_free(&refusal);
    free(line_text);
    free(lim_text);
    free(lim_where);
    return ok;
}

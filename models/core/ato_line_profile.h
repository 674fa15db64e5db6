/* ato_line_profile.h -- the AtoController FMU's line files in C: fmu_src/ato_controller.py's
 * read_line_profile (line.profile: one row per span after the first) and read_line_limits
 * (line.speed_limit_profile: those spans' speed limits), with the same acceptance and
 * Python's ParameterError texts byte for byte, for the native AtoController (no Python).
 *
 * The text is what rc_profile_read_text (profile.h) gives, path its str(pathlib.Path); the rows
 * are read by rc_csv_rows (csv_number_rows: header, line breaks, stripping, float(), finite),
 * then each row is checked before the next is read, as the Python generator does. Messages
 * start "line.profile: PATH: line N: " / "line.speed_limit_profile: PATH: line N: ".
 * Units: distances [m], speeds [m/s], times [s], boarding [t].
 */
#ifndef RAILCAR_ATO_LINE_PROFILE_H
#define RAILCAR_ATO_LINE_PROFILE_H

#include <stddef.h>

#include "profile.h"

/* line.profile's columns, in order */
#define ATO_LINE_COLUMNS {"stop_m", "length_m", "schedule_s", "dwell_s", "boarding_t"}
#define ATO_LINE_LIMIT_COLUMNS {"span", "distance_m", "speed_limit_mps"}

/* One row of line.profile (LineRow): a span after the first and its 1-based file line */
typedef struct {
    double stop;             /* [m] > 0 */
    double length;           /* [m] 0 (stop) or >= stop */
    double schedule;         /* [s] > 0 */
    double dwell;            /* [s] > 0: the standstill at the station before the span */
    double boarding;         /* [t] boarding there (leaving: < 0) */
    long line;
} ato_line_row;

/* read_line_profile(text, path): RC_OK with *rows (malloc'd, the caller frees) and *n >= 1;
 * else RC_BAD_CONFIG, *rows NULL, the refusal in out (rc_profile_free it) */
int ato_line_profile_parse(const char *text, size_t len, const char *path, ato_line_row **rows,
                           long *n, rc_profile *out);

/* read_line_limits' {span: (distances, limits)} for spans 2 .. spans: span k's limits are
 * distances[first[k] .. first[k] + count[k]) (count[k] 0: the span has no rows); one block */
typedef struct {
    double *distances;       /* [m] from 0, increasing within a span */
    double *speeds;          /* [m/s] > 0 */
    long *first, *count;     /* spans + 1 each, by span number (0 and 1 unused) */
    int spans;
} ato_line_limits;

/* read_line_limits(text, path, spans): RC_OK (out filled; ato_line_limits_free it), or
 * RC_BAD_CONFIG with the refusal in err (rc_profile_free it) and nothing allocated in out */
int ato_line_limits_parse(const char *text, size_t len, const char *path, int spans,
                          ato_line_limits *out, rc_profile *err);
void ato_line_limits_free(ato_line_limits *l);

#endif

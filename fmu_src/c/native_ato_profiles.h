/* native_ato_profiles.h -- the profile files of the native AtoController
 * (native_ato_profiles.c), read into native_ato.c's instance while it builds. Each returns 1, or
 * 0 with Python's refusal in msg (NAT_MSG_SIZE chars); a parameter left empty reads nothing. */
#ifndef NATIVE_ATO_PROFILES_H
#define NATIVE_ATO_PROFILES_H

#include "native_ato.h"

/* check_span_parameters' check of the file name in String parameter vr: refused when the file
   system cannot use it (a missing file passes: its reader refuses it later) */
int nat_usable_name(GlueInstance *g, const nat_instance *m, int vr, char *msg);

/* span.grade_profile into m->grade_block and m->span.grade (its integral ready); level when
   the parameter is empty */
int nat_read_grade(GlueInstance *g, nat_instance *m, char *msg);

/* span 1's limits into m->limit_block and m->span: span.speed_limit_profile's rows
   (*from_profile 1), else the one limit span.speed_limit from 0 m (*from_profile 0) */
int nat_read_limits(GlueInstance *g, nat_instance *m, int *from_profile, char *msg);

/* line.profile's rows (*rows, *n_rows; none when it is empty) and line.speed_limit_profile's
   limits (m->line_limits). *rows and *line_where (line.profile's str(path), for messages) are
   malloc'd or NULL and the caller's to free, whether it returns 1 or 0 */
int nat_read_line_files(GlueInstance *g, nat_instance *m, ato_line_row **rows, long *n_rows,
                        char **line_where, char *msg);

#endif

/* native_state_read.c -- see native_state_read.h: the byte source and the two log messages of
 * reading a native FMU's state, one copy for native_state.c and native_ato_state.c. */
#include "native_state_read.h"

#define READER(r) ((const native_state_reader *)(r)->context)

/* rc_bytes_source's refused callback */
static void state_corrupt(rc_byte_source *r, const char *what) {
    glue_log(READER(r)->g, fmi2Error, "logStatusError", "%s: the FMU state is corrupt or of "
             "another build (%s)", READER(r)->function, what);
}

void native_state_source(rc_byte_source *r, native_state_reader *who, GlueInstance *g,
                         const char *function, const unsigned char *in, size_t n) {
    who->g = g;
    who->function = function;
    rc_bytes_source(r, in, n, state_corrupt, who);
}

int native_state_no_memory(rc_byte_source *r) {
    if (r->ok)
        glue_log(READER(r)->g, fmi2Error, "logStatusError", "%s: out of memory",
                 READER(r)->function);
    r->ok = 0;
    return 0;
}

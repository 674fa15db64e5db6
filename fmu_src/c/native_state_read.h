/* native_state_read.h -- what the readers of the native FMUs' states share (native_state.c for
 * RailCar and RailCarEstimator, native_ato_state.c for the AtoController): a byte source
 * (models/core/rc_bytes.h) whose refusals are logged for the instance, and the log of running
 * out of memory, so that both FMUs word a refused state alike (native_state_read.c). */
#ifndef NATIVE_STATE_READ_H
#define NATIVE_STATE_READ_H

#include <stddef.h>

#include "fmi2_glue.h"
#include "rc_bytes.h"

/* whose state a source reads: its context */
typedef struct {
    GlueInstance *g;
    const char *function;            /* the entry point, for messages ("fmi2SetFMUstate") */
} native_state_reader;

/* r over in[0 .. n - 1]; its first refusal is logged (fmi2Error, "logStatusError") as
   "<function>: the FMU state is corrupt or of another build (<what>)". who is r's context: it
   must outlive the reading */
void native_state_source(rc_byte_source *r, native_state_reader *who, GlueInstance *g,
                         const char *function, const unsigned char *in, size_t n);

/* logs "<function>: out of memory" (once per read: not when r is refused already) and stops the
   read (r refused, without the corrupt-state message); returns 0 */
int native_state_no_memory(rc_byte_source *r);

#endif

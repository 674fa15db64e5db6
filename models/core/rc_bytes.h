/* rc_bytes.h -- saved states as byte strings (the FMU states of the native FMUs and the core's
 * ato_line_state_*): one writer and one bounds-checked reader, so that every state's layout is
 * written and read by the same few lines.
 *
 * The writer either counts or writes (p NULL: counts), so one code path gives a state's size and
 * its bytes. The reader never reads past its end: a short read, or a caller's own check, refuses
 * the source once (rc_bytes_refuse), naming what was short or wrong ("<what>"), and every later
 * take is a no-op returning zeros. Numbers go in the machine's own representation (the callers
 * refuse another machine's or build's bytes by their own fingerprints). No allocation, no globals.
 */
#ifndef RAILCAR_RC_BYTES_H
#define RAILCAR_RC_BYTES_H

#include <stddef.h>
#include <stdint.h>

typedef struct {
    unsigned char *p;   /* where the bytes go; NULL: only count them */
    size_t n;           /* bytes written (or counted) so far */
} rc_byte_sink;

/* n bytes of data at the sink's end; returns where they went (NULL when only counting) */
unsigned char *rc_put(rc_byte_sink *s, const void *data, size_t n);
void rc_put_u32(rc_byte_sink *s, uint32_t v);
void rc_put_u64(rc_byte_sink *s, uint64_t v);
void rc_put_double(rc_byte_sink *s, double v);

typedef struct rc_byte_source rc_byte_source;

/* told the first problem of a source (what: e.g. "span count"); context is the source's */
typedef void rc_bytes_refused(rc_byte_source *r, const char *what);

struct rc_byte_source {
    const unsigned char *p, *end;   /* the next byte, one past the last */
    int ok;                         /* 0 once refused: nothing more is read */
    rc_bytes_refused *refused;      /* may be NULL */
    void *context;                  /* the caller's, for refused */
};

/* a source over in[0 .. size - 1], not refused */
void rc_bytes_source(rc_byte_source *r, const void *in, size_t size, rc_bytes_refused *refused,
                     void *context);
/* refuses r (refused is told `what` unless r was refused already); returns 0 */
int rc_bytes_refuse(rc_byte_source *r, const char *what);
/* the bytes not read yet */
size_t rc_bytes_left(const rc_byte_source *r);
/* n bytes into out: 1, or 0 (r refused with `what` when fewer are left; out untouched) */
int rc_take(rc_byte_source *r, void *out, size_t n, const char *what);
/* a number; 0 when r is or becomes refused */
uint32_t rc_take_u32(rc_byte_source *r, const char *what);
uint64_t rc_take_u64(rc_byte_source *r, const char *what);

#endif

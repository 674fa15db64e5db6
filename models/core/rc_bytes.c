/* rc_bytes.c -- the byte writer and reader of saved states; see rc_bytes.h. */
#include "rc_fp_contract.h"
#include "rc_bytes.h"

#include <string.h>

unsigned char *rc_put(rc_byte_sink *s, const void *data, size_t n)
{
    unsigned char *at = NULL;
    if (s->p != NULL) {
        at = s->p + s->n;
        if (n)
            memcpy(at, data, n);
    }
    s->n += n;
    return at;
}

void rc_put_u32(rc_byte_sink *s, uint32_t v) { rc_put(s, &v, sizeof v); }
void rc_put_u64(rc_byte_sink *s, uint64_t v) { rc_put(s, &v, sizeof v); }
void rc_put_double(rc_byte_sink *s, double v) { rc_put(s, &v, sizeof v); }

void rc_bytes_source(rc_byte_source *r, const void *in, size_t size, rc_bytes_refused *refused,
                     void *context)
{
    r->p = (const unsigned char *)in;
    r->end = r->p + size;
    r->ok = 1;
    r->refused = refused;
    r->context = context;
}

int rc_bytes_refuse(rc_byte_source *r, const char *what)
{
    if (r->ok && r->refused != NULL)
        r->refused(r, what);
    r->ok = 0;
    return 0;
}

size_t rc_bytes_left(const rc_byte_source *r)
{
    return (size_t)(r->end - r->p);
}

int rc_take(rc_byte_source *r, void *out, size_t n, const char *what)
{
    if (!r->ok)
        return 0;
    if (rc_bytes_left(r) < n)
        return rc_bytes_refuse(r, what);
    if (n)
        memcpy(out, r->p, n);
    r->p += n;
    return 1;
}

uint32_t rc_take_u32(rc_byte_source *r, const char *what)
{
    uint32_t v = 0;
    rc_take(r, &v, sizeof v, what);
    return v;
}

uint64_t rc_take_u64(rc_byte_source *r, const char *what)
{
    uint64_t v = 0;
    rc_take(r, &v, sizeof v, what);
    return v;
}

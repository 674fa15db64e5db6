/* native_state.c -- the model's part of an FMU state of the native FMUs (NATIVE_STATE_OPS, the
 * GlueStateOps of glue_common.h; the glue adds header, token, its own fields and checksum).
 *
 * What it holds, in this order (numbers in the machine's representation; the glue's header
 * refuses another byte order or other type sizes, the layout fingerprint another build):
 *   nvars, noutputs                            uint32 each
 *   every Real, every Integer, the start time  double[nvars], fmi2Integer[nvars], double
 *   every String                               uint64 length (UINT64_MAX: the start value) + bytes
 *   the outputs buffer                         double[noutputs]
 *   has a chain                                uint32; then, if so:
 *     the chain struct                         uint64 size + its bytes, every pointer zeroed
 *     its profile buffer                       uint64 count + double[count]
 *     has an estimator                         uint32; then, if so:
 *       filter has a speed profile             uint32
 *       the identifier's batch                 uint64 rows + double[4 rows], double[rows],
 *                                              int[rows]
 *       has a slope window (est.method 2)      uint32; then its struct (uint64 size + bytes,
 *                                              pointers zeroed) and v[size + 1], i[4 size],
 *                                              dts, w, c[size]
 * A chain copy is the struct's bytes with its pointers rebuilt: the owned buffers (profiles,
 * batch, slope window) are new allocations filled from the bytes, every pointer into the chain
 * itself points into the copy (the kind's offsets, native_common.h). Reading checks every count
 * against the bytes left and against the struct's own fields before allocating, so a corrupt
 * state is refused (logged), never read past its end; nothing changes until all of it is read.
 * The bytes are written and read with models/core/rc_bytes.h (the one byte writer and reader).
 * No globals; allocates only in get/set/serialize, never in a step.
 */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "estimator.h"
#include "native_common.h"
#include "native_state_read.h"
#include "noise.h"
#include "rc_bytes.h"
#include "track.h"

#define MODEL(g) ((native_instance *)(g)->model)
#define NO_STRING UINT64_MAX          /* a String at its start value (native_values.string NULL) */
#define MAX_POINTERS 32

/* ------------------------------------------------------------------------ the chain's pointers */

/* Offsets of every pointer of a chain of this kind (into itself or its owned buffers). */
static int chain_pointers(const native_chain_kind *k, size_t *at) {
    const native_profile_offsets *p = &k->profiles;
    int n = 0, i;
    at[n++] = k->at_cfg + p->grade_distances;
    at[n++] = k->at_cfg + p->grades;
    at[n++] = k->at_cfg + p->speed_distances;
    at[n++] = k->at_cfg + p->speeds;
    at[n++] = k->at_profiles;
    at[n++] = k->at_grade + offsetof(rc_grade_profile, distances);
    at[n++] = k->at_grade + offsetof(rc_grade_profile, grades);
    at[n++] = k->at_grade + offsetof(rc_grade_profile, cum);
    at[n++] = k->at_speed + offsetof(rc_speed_profile, distances);
    at[n++] = k->at_speed + offsetof(rc_speed_profile, speeds);
    at[n++] = k->at_est + offsetof(rc_estimator, grade);
    at[n++] = k->at_est + offsetof(rc_estimator, filter.grade);
    at[n++] = k->at_est + offsetof(rc_estimator, filter.speed);
    at[n++] = k->at_est + offsetof(rc_estimator, ident.batch_phi);
    at[n++] = k->at_est + offsetof(rc_estimator, ident.batch_y);
    at[n++] = k->at_est + offsetof(rc_estimator, ident.batch_contiguous);
    at[n++] = k->at_est + offsetof(rc_estimator, slope);
    for (i = 0; i < k->n_own_pointers; i++) at[n++] = k->own_pointers[i];
    return n;
}

static void zero_pointers(unsigned char *base, const size_t *at, int n) {
    int i;
    for (i = 0; i < n; i++) memset(base + at[i], 0, sizeof(void *));
}

static const size_t SLOPE_POINTERS[] = {
    offsetof(rc_slope_ls, v), offsetof(rc_slope_ls, i), offsetof(rc_slope_ls, dts),
    offsetof(rc_slope_ls, w), offsetof(rc_slope_ls, c)
};
#define N_SLOPE_POINTERS ((int)(sizeof SLOPE_POINTERS / sizeof SLOPE_POINTERS[0]))

#define AT(chain, offset, type) ((type *)(void *)((unsigned char *)(chain) + (offset)))

/* --------------------------------------------------------------------------------- writing */

static void emit_array(rc_byte_sink *s, const void *data, size_t count, size_t element) {
    rc_put_u64(s, count);
    rc_put(s, data, count * element);
}

static void emit_estimator(rc_byte_sink *s, const rc_estimator *e) {
    const rc_slope_ls *w = e->slope;
    size_t rows = (size_t)e->ident.cfg.batch_size;
    rc_put_u32(s, e->filter.speed != NULL);
    rc_put_u64(s, rows);
    rc_put(s, e->ident.batch_phi, 4 * rows * sizeof(double));
    rc_put(s, e->ident.batch_y, rows * sizeof(double));
    rc_put(s, e->ident.batch_contiguous, rows * sizeof(int));
    rc_put_u32(s, w != NULL);
    if (w) {
        size_t size = (size_t)w->size;
        unsigned char *copy;
        rc_put_u64(s, sizeof *w);
        if ((copy = rc_put(s, w, sizeof *w))) zero_pointers(copy, SLOPE_POINTERS, N_SLOPE_POINTERS);
        rc_put(s, w->v, (size + 1) * sizeof(double));
        rc_put(s, w->i, 4 * size * sizeof(double));
        rc_put(s, w->dts, size * sizeof(double));
        rc_put(s, w->w, size * sizeof(double));
        rc_put(s, w->c, size * sizeof(double));
    }
}

static void emit_chain(rc_byte_sink *s, const native_chain_kind *k, const void *chain) {
    size_t at[MAX_POINTERS];
    int n = chain_pointers(k, at);
    unsigned char *copy;
    const rc_grade_profile *grade = AT(chain, k->at_grade, const rc_grade_profile);
    const rc_speed_profile *speed = AT(chain, k->at_speed, const rc_speed_profile);
    rc_put_u64(s, k->chain_size);
    if ((copy = rc_put(s, chain, k->chain_size))) zero_pointers(copy, at, n);
    emit_array(s, *AT(chain, k->at_profiles, double *),
               3 * (size_t)grade->n + 2 * (size_t)speed->n, sizeof(double));
    rc_put_u32(s, k->has_estimator(chain) != 0);
    if (k->has_estimator(chain)) emit_estimator(s, AT(chain, k->at_est, const rc_estimator));
}

static void emit_model(rc_byte_sink *s, GlueInstance *g) {
    const native_instance *m = MODEL(g);
    const native_model *md = m->v.md;
    const native_chain_kind *k = NATIVE_BACKEND.kind;
    size_t nvars = (size_t)md->nvars;
    int vr;
    rc_put_u32(s, (uint32_t)md->nvars);
    rc_put_u32(s, (uint32_t)md->noutputs);
    rc_put(s, m->v.real, nvars * sizeof *m->v.real);
    rc_put(s, m->v.integer, nvars * sizeof *m->v.integer);
    rc_put(s, &m->v.start_time, sizeof m->v.start_time);
    for (vr = 0; vr < md->nvars; vr++) {
        const char *str = m->v.string[vr];
        rc_put_u64(s, str ? (uint64_t)strlen(str) : NO_STRING);
        if (str) rc_put(s, str, strlen(str));
    }
    rc_put(s, m->outputs, (size_t)md->noutputs * sizeof *m->outputs);
    rc_put_u32(s, k && m->chain);
    if (k && m->chain) emit_chain(s, k, m->chain);
}

static size_t state_size(GlueInstance *g) {
    rc_byte_sink s = {NULL, 0};
    emit_model(&s, g);
    return s.n;
}

static void state_write(GlueInstance *g, unsigned char *out) {
    rc_byte_sink s;
    s.p = out;
    s.n = 0;
    emit_model(&s, g);
}

/* --------------------------------------------------------------------------------- reading */

typedef rc_byte_source reader;

/* count elements of `element` bytes, allocated and read (count 0: NULL, fine); NULL logged when
   they are not all there or memory runs out */
static void *take_block(reader *r, size_t count, size_t element, const char *what) {
    void *block;
    if (!r->ok) return NULL;
    if (count > (size_t)(r->end - r->p) / element) {
        rc_bytes_refuse(r, what);
        return NULL;
    }
    if (!(block = malloc(count ? count * element : 1))) {
        native_state_no_memory(r);
        return NULL;
    }
    rc_take(r, block, count * element, what);
    return block;
}

static void free_slope(rc_slope_ls *w) {
    if (!w) return;
    free(w->v);
    free(w->i);
    free(w->dts);
    free(w->w);
    free(w->c);
    free(w);
}

/* Frees what a chain copy owns (all pointers of a copy are set or NULL). */
static void release_chain(const native_chain_kind *k, void *chain) {
    rc_estimator *e;
    if (!chain) return;
    e = AT(chain, k->at_est, rc_estimator);
    free(*AT(chain, k->at_profiles, double *));
    free(e->ident.batch_phi);
    free(e->ident.batch_y);
    free(e->ident.batch_contiguous);
    free_slope(e->slope);
    free(chain);
}

static int read_slope(reader *r, rc_estimator *e) {
    rc_slope_ls *w;
    size_t size;
    if (rc_take_u64(r, "slope window struct size") != sizeof *w)
        return r->ok ? rc_bytes_refuse(r, "slope window struct size") : 0;
    if (!(w = calloc(1, sizeof *w))) {
        return native_state_no_memory(r);
    }
    e->slope = w;                           /* released with the chain on failure */
    if (!rc_take(r, w, sizeof *w, "slope window")) return 0;
    zero_pointers((unsigned char *)w, SLOPE_POINTERS, N_SLOPE_POINTERS);
    if (w->size < 2 || w->len < 0 || w->len > w->size ||
        (size_t)w->size > (size_t)(r->end - r->p) / sizeof(double))
        return rc_bytes_refuse(r, "slope window size or length");
    size = (size_t)w->size;
    w->v = take_block(r, size + 1, sizeof(double), "slope window speeds");
    w->i = take_block(r, 4 * size, sizeof(double), "slope window intervals");
    w->dts = take_block(r, size, sizeof(double), "slope window steps");
    w->w = take_block(r, size, sizeof(double), "slope window weights");
    w->c = take_block(r, size, sizeof(double), "slope window coefficients");
    return r->ok;
}

static int read_estimator(reader *r, void *chain, const native_chain_kind *k) {
    rc_estimator *e = AT(chain, k->at_est, rc_estimator);
    const rc_grade_profile *grade = AT(chain, k->at_grade, rc_grade_profile);
    const rc_speed_profile *speed = AT(chain, k->at_speed, rc_speed_profile);
    uint32_t has_speed = rc_take_u32(r, "filter speed-profile flag");
    uint64_t rows = rc_take_u64(r, "identifier batch size");
    if (!r->ok) return 0;
    if (has_speed > 1 || (has_speed && speed->n < 1))
        return rc_bytes_refuse(r, "filter speed-profile flag");
    if (e->ident.cfg.batch_size < 1 || rows != (uint64_t)e->ident.cfg.batch_size ||
        e->ident.batch_len < 0 || e->ident.batch_len > e->ident.cfg.batch_size ||
        e->ident.window_len < 0 || e->ident.window_len > RC_LAG || e->ident.window_start < 0 ||
        e->ident.window_start >= RC_LAG || rows > (uint64_t)(r->end - r->p) / sizeof(double))
        return rc_bytes_refuse(r, "identifier batch or window counts");
    e->grade = grade;
    e->filter.grade = grade;
    e->filter.speed = has_speed ? speed : NULL;
    e->ident.batch_phi = take_block(r, 4 * (size_t)rows, sizeof(double), "identifier batch");
    e->ident.batch_y = take_block(r, (size_t)rows, sizeof(double), "identifier batch");
    e->ident.batch_contiguous = take_block(r, (size_t)rows, sizeof(int), "identifier batch");
    switch (rc_take_u32(r, "slope window flag")) {
    case 0: return r->ok;
    case 1: return read_slope(r, e);
    default: return rc_bytes_refuse(r, "slope window flag");
    }
}

/* A chain copy from the bytes: its struct, then its owned buffers; NULL logged. */
static void *read_chain(reader *r, const native_chain_kind *k) {
    size_t at[MAX_POINTERS], count;
    int n = chain_pointers(k, at);
    void *chain;
    double *profiles;
    rc_grade_profile *grade;
    rc_speed_profile *speed;
    const native_profile_offsets *p = &k->profiles;
    uint32_t has_est;
    if (rc_take_u64(r, "chain struct size") != k->chain_size) {
        if (r->ok) rc_bytes_refuse(r, "chain struct size");
        return NULL;
    }
    if (!(chain = malloc(k->chain_size))) {
        native_state_no_memory(r);
        return NULL;
    }
    if (!rc_take(r, chain, k->chain_size, "chain struct")) {
        free(chain);
        return NULL;
    }
    zero_pointers(chain, at, n);          /* from here on release_chain frees what is set */
    grade = AT(chain, k->at_grade, rc_grade_profile);
    speed = AT(chain, k->at_speed, rc_speed_profile);
    count = (size_t)rc_take_u64(r, "profile count");
    if (r->ok && (grade->n < 1 || speed->n < 0 || (size_t)grade->n > count ||
                  (size_t)speed->n > count ||
                  count != 3 * (size_t)grade->n + 2 * (size_t)speed->n ||
                  *AT(chain, k->at_cfg + p->grade_n, long) != grade->n ||
                  *AT(chain, k->at_cfg + p->speed_n, long) != speed->n))
        rc_bytes_refuse(r, "profile lengths");
    profiles = take_block(r, count, sizeof(double), "profiles");
    *AT(chain, k->at_profiles, double *) = profiles;
    if (!r->ok) {
        release_chain(k, chain);
        return NULL;
    }
    grade->distances = profiles;             /* rc_profiles_copy's layout of the buffer */
    grade->grades = profiles + grade->n;
    grade->cum = profiles + 2 * grade->n;
    speed->distances = speed->n ? profiles + 3 * grade->n : NULL;
    speed->speeds = speed->n ? profiles + 3 * grade->n + speed->n : NULL;
    *AT(chain, k->at_cfg + p->grade_distances, const double *) = grade->distances;
    *AT(chain, k->at_cfg + p->grades, const double *) = grade->grades;
    *AT(chain, k->at_cfg + p->speed_distances, const double *) = speed->distances;
    *AT(chain, k->at_cfg + p->speeds, const double *) = speed->speeds;
    has_est = rc_take_u32(r, "estimator flag");
    if (r->ok && has_est != (uint32_t)(k->has_estimator(chain) != 0))
        rc_bytes_refuse(r, "estimator flag");
    if (r->ok && has_est) read_estimator(r, chain, k);
    if (!r->ok) {
        release_chain(k, chain);
        return NULL;
    }
    k->link(chain);
    return chain;
}

/* What a read produces before it is committed */
typedef struct {
    double *real, *outputs, start_time;
    fmi2Integer *integer;
    char **string;
    void *chain;
} staged;

static void free_staged(const native_chain_kind *k, staged *st, int nvars) {
    int vr;
    if (st->string)
        for (vr = 0; vr < nvars; vr++) free(st->string[vr]);
    free(st->string);
    free(st->real);
    free(st->integer);
    free(st->outputs);
    if (k) release_chain(k, st->chain);
}

static int read_strings(reader *r, staged *st, int nvars) {
    int vr;
    if (!(st->string = calloc((size_t)nvars, sizeof *st->string))) {
        return native_state_no_memory(r);
    }
    for (vr = 0; vr < nvars && r->ok; vr++) {
        uint64_t len = rc_take_u64(r, "string length");
        char *copy;
        if (!r->ok || len == NO_STRING) continue;
        if (len > (uint64_t)(r->end - r->p)) return rc_bytes_refuse(r, "string length");
        if (!(copy = malloc((size_t)len + 1))) {
            return native_state_no_memory(r);
        }
        rc_take(r, copy, (size_t)len, "string");
        copy[len] = '\0';
        st->string[vr] = copy;
    }
    return r->ok;
}

static int state_read(GlueInstance *g, const char *function, const unsigned char *in, size_t n,
                      int commit) {
    native_instance *m = MODEL(g);
    const native_model *md = m->v.md;
    const native_chain_kind *k = NATIVE_BACKEND.kind;
    size_t nvars = (size_t)md->nvars;
    reader r;
    staged st;
    uint32_t has_chain;
    int vr;
    native_state_reader who;
    native_state_source(&r, &who, g, function, in, n);
    memset(&st, 0, sizeof st);
    if (rc_take_u32(&r, "variable count") != (uint32_t)md->nvars ||
        rc_take_u32(&r, "output count") != (uint32_t)md->noutputs) {
        if (r.ok) rc_bytes_refuse(&r, "variable or output count");
        return 0;
    }
    st.real = take_block(&r, nvars, sizeof *st.real, "Real values");
    st.integer = take_block(&r, nvars, sizeof *st.integer, "Integer values");
    rc_take(&r, &st.start_time, sizeof st.start_time, "start time");
    if (r.ok) read_strings(&r, &st, md->nvars);
    st.outputs = take_block(&r, (size_t)md->noutputs, sizeof *st.outputs, "outputs");
    has_chain = rc_take_u32(&r, "chain flag");
    if (r.ok && (has_chain > 1 || (has_chain && !k))) rc_bytes_refuse(&r, "chain flag");
    if (r.ok && has_chain) st.chain = read_chain(&r, k);
    if (r.ok && r.p != r.end) rc_bytes_refuse(&r, "bytes left over");
    if (!r.ok || !commit) {
        free_staged(k, &st, md->nvars);
        return r.ok;
    }
    /* all read: now the instance changes (no allocation, nothing can fail) */
    memcpy(m->v.real, st.real, nvars * sizeof *st.real);
    memcpy(m->v.integer, st.integer, nvars * sizeof *st.integer);
    m->v.start_time = st.start_time;
    for (vr = 0; vr < md->nvars; vr++) {
        char *old = m->v.string[vr];
        m->v.string[vr] = st.string[vr];
        st.string[vr] = old;                /* freed with the staging below */
    }
    memcpy(m->outputs, st.outputs, (size_t)md->noutputs * sizeof *st.outputs);
    if (m->chain) {
        k->free_chain(m->chain);
        free(m->chain);
    }
    m->chain = st.chain;
    st.chain = NULL;
    free_staged(k, &st, md->nvars);
    return 1;
}

/* --------------------------------------------------------------------------------- layout */

static void hash_size(uint32_t *h, size_t v) {
    int i;
    for (i = 0; i < 8; i++) {
        *h ^= (uint32_t)(v >> (8 * i)) & 0xffu;
        *h *= 16777619u;
    }
}

/* FNV-1a over every size and offset the bytes depend on: a build whose structs differ (another
   core version, another platform's type sizes) has another fingerprint. */
static uint32_t state_layout(void) {
    const native_chain_kind *k = NATIVE_BACKEND.kind;
    uint32_t h = 2166136261u;
    size_t at[MAX_POINTERS];
    int n, i;
    hash_size(&h, (size_t)NATIVE_BACKEND.md->nvars);
    hash_size(&h, (size_t)NATIVE_BACKEND.md->noutputs);
    hash_size(&h, sizeof(fmi2Integer));
    if (!k) return h;
    hash_size(&h, k->chain_size);
    hash_size(&h, k->config_size);
    hash_size(&h, sizeof(rc_estimator));
    hash_size(&h, sizeof(rc_slope_ls));
    hash_size(&h, sizeof(rc_stream));
    hash_size(&h, k->at_profiles);
    n = chain_pointers(k, at);
    for (i = 0; i < n; i++) hash_size(&h, at[i]);
    return h;
}

const GlueStateOps NATIVE_STATE_OPS = {state_size, state_write, state_read, state_layout};

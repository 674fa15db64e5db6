/* noise.c -- see noise.h. */
#include "rc_fp_contract.h"
#include "noise.h"

#include <math.h>

#include "ziggurat_tables.h"

typedef rc_u128 u128;

/* SeedSequence: entropy words hashed into a pool of four 32-bit words (arithmetic mod 2^32) */
#define SS_INIT_A 0x43b0d7e5u
#define SS_MULT_A 0x931e8875u
#define SS_INIT_B 0x8b51f9ddu
#define SS_MULT_B 0x58f38dedu
#define SS_MIX_L 0xca01f9ddu
#define SS_MIX_R 0x4973f715u

static uint32_t hashmix(uint32_t v, uint32_t *h)
{
    v ^= *h;
    *h *= SS_MULT_A;
    v *= *h;
    return v ^ (v >> 16);
}

static uint32_t mix(uint32_t x, uint32_t y)
{
    uint32_t r = SS_MIX_L * x - SS_MIX_R * y;
    return r ^ (r >> 16);
}

/* entropy: the seed's little-endian words, zero-padded to the pool size because a spawn key
 * follows, then the spawn key (child,) */
static void seed_words(uint64_t seed, uint32_t child, uint64_t out[4])
{
    uint32_t ent[6], pool[4], h = SS_INIT_A, w[8];
    int n = 0;
    ent[n++] = (uint32_t)seed;
    if (seed >> 32) ent[n++] = (uint32_t)(seed >> 32);
    while (n < 4) ent[n++] = 0;
    ent[n++] = child;
    for (int i = 0; i < 4; i++) pool[i] = hashmix(ent[i], &h);
    for (int src = 0; src < 4; src++)
        for (int dst = 0; dst < 4; dst++)
            if (src != dst) pool[dst] = mix(pool[dst], hashmix(pool[src], &h));
    for (int src = 4; src < n; src++)
        for (int dst = 0; dst < 4; dst++) pool[dst] = mix(pool[dst], hashmix(ent[src], &h));
    h = SS_INIT_B;                                   /* generate_state(4, uint64) */
    for (int i = 0; i < 8; i++) {
        uint32_t v = pool[i & 3] ^ h;
        h *= SS_MULT_B;
        v *= h;
        w[i] = v ^ (v >> 16);
    }
    for (int i = 0; i < 4; i++) out[i] = (uint64_t)w[2 * i] | ((uint64_t)w[2 * i + 1] << 32);
}

static const u128 PCG_MULT = ((u128)2549297995355413924ULL << 64) | 4865540595714422341ULL;

void rc_stream_seed(rc_stream *s, uint64_t seed, uint32_t child)
{
    uint64_t w[4];
    seed_words(seed, child, w);
    s->inc = ((((u128)w[2] << 64) | w[3]) << 1) | 1u;
    s->state = 0;
    s->state = s->state * PCG_MULT + s->inc;
    s->state += ((u128)w[0] << 64) | w[1];
    s->state = s->state * PCG_MULT + s->inc;
}

static uint64_t next_u64(rc_stream *s)
{
    s->state = s->state * PCG_MULT + s->inc;
    uint64_t v = (uint64_t)(s->state >> 64) ^ (uint64_t)s->state;
    unsigned rot = (unsigned)(s->state >> 122);
    return (v >> rot) | (v << ((-rot) & 63u));
}

static double next_double(rc_stream *s)
{
    return (double)(next_u64(s) >> 11) * (1.0 / 9007199254740992.0);   /* 53 bits, [0, 1) */
}

static const double ZIG_R = 0x1.d3bb48209ad33p+1;        /* the ziggurat's rightmost edge */
static const double ZIG_INV_R = 0x1.183aa6c20e8c1p-2;    /* 1 / ZIG_R, as a double */

double rc_stream_normal(rc_stream *s)
{
    for (;;) {
        uint64_t r = next_u64(s);
        int layer = (int)(r & 0xff);                      /* 8 bits: the layer */
        r >>= 8;
        int negative = (int)(r & 1);                      /* 1 bit: the sign */
        uint64_t mantissa = (r >> 1) & 0x000fffffffffffffULL;   /* 52 bits */
        double x = (double)mantissa * ZIGGURAT_WI[layer];
        if (negative) x = -x;
        if (mantissa < ZIGGURAT_KI[layer]) return x;      /* inside the layer's rectangle */
        if (layer == 0) {                                 /* the tail beyond ZIG_R */
            for (;;) {
                double xx = -ZIG_INV_R * log1p(-next_double(s));
                double yy = -log1p(-next_double(s));
                if (yy + yy > xx * xx) return ((mantissa >> 8) & 1) ? -(ZIG_R + xx) : ZIG_R + xx;
            }
        }
        if ((ZIGGURAT_FI[layer - 1] - ZIGGURAT_FI[layer]) * next_double(s) + ZIGGURAT_FI[layer]
            < exp(-0.5 * x * x))
            return x;                                     /* under the curve in the wedge */
    }
}

void rc_stream_fill(rc_stream *s, double *out, long n)
{
    for (long i = 0; i < n; i++) out[i] = rc_stream_normal(s);
}

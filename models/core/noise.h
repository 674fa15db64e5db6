/* noise.h -- seeded standard-normal streams, draw for draw those of models/plant/noise.py.
 *
 * numpy's SeedSequence(seed).spawn(k)[child] -> PCG64 -> Generator.standard_normal, written from
 * the published algorithms: SeedSequence (numpy's documented hash mixing after M. O'Neill's
 * seed_seq), PCG64 (O'Neill, "PCG: a family of simple fast space-efficient statistically good
 * algorithms for random number generation", 2014: 128-bit LCG, XSL-RR output) and the ziggurat
 * (Marsaglia & Tsang 2000; tables from gen_ziggurat.py). Same seed => bit-identical doubles, given
 * the same libm exp/log1p as numpy's (glibc here) and no fused multiply-add (-ffp-contract=off).
 * No globals, no allocation: the whole state is one struct.
 */
#ifndef RAILCAR_NOISE_H
#define RAILCAR_NOISE_H

#include <stdint.h>

/* 128-bit arithmetic: gcc and clang on 64-bit targets (MSVC would need a two-word version) */
__extension__ typedef unsigned __int128 rc_u128;

typedef struct {
    rc_u128 state, inc;        /* PCG64 */
} rc_stream;

/* The stream numpy gives SeedSequence(seed).spawn(n)[child] (any n > child): seed in
 * 0..2^64-1, child in 0..2^32-1. */
void rc_stream_seed(rc_stream *s, uint64_t seed, uint32_t child);

/* The next standard normal draw [-]. */
double rc_stream_normal(rc_stream *s);

/* n draws into out (what n calls of rc_stream_normal give). */
void rc_stream_fill(rc_stream *s, double *out, long n);

#endif

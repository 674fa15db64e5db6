/* rc_fp_contract.h -- no fused multiply-add, whatever the build's flags.
 *
 * The core is bit-identical to the Python reference only if every a * b + c rounds twice, as
 * Python does. Our builds pass -ffp-contract=off, but a user compiling a source FMU may not
 * (fmpy's `compile` ignores the build description's compilerOptions), and GCC contracts by
 * default wherever the target has FMA (aarch64 always; x86-64 with -mfma or -march=native).
 * GCC ignores the standard pragma, so it gets its own. Include this first in every .c file of
 * the core and the native glue. */
#ifndef RC_FP_CONTRACT_H
#define RC_FP_CONTRACT_H

#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#elif defined(_MSC_VER)
#pragma fp_contract(off)   /* MSVC before VS 2022 17.0 contracts under /arch:AVX2 (untested here) */
#endif

#endif

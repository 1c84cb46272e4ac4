/* Constants and small inline helpers every unit of the core uses (no functions to link). */
#ifndef CELLCTL_COMMON_H
#define CELLCTL_COMMON_H

#include "cellctl_core.h"

#define CC_LANES 16          /* uint16 lanes of one AVX2 vector; Dp is a multiple */
#define CC_GUARD 16          /* guard lanes before and after each stored path vector */
#define CC_LUT 64            /* rho tables cover indices 0..63 */
#define CC_PATH_INF 0xFFFFu  /* path cost of a disparity that does not exist */

#if defined(__x86_64__) || defined(__i386__)
#define CC_HAVE_X86 1
#else
#define CC_HAVE_X86 0
#endif

/* A fixed-point disparity (x16) rounded to the nearest whole pixel, halves up, for any sign. */
static inline int cc_whole_px(int d16)
{
    int v = d16 + CC_DISP_SCALE / 2;
    return v >= 0 ? v / CC_DISP_SCALE : -((-v + CC_DISP_SCALE - 1) / CC_DISP_SCALE);
}

/* v rounded up to a multiple of a. */
static inline size_t cc_round_up(size_t v, size_t a) { return (v + a - 1) / a * a; }

#endif

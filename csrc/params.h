/* params.c: the derived setup of a parameter set (rho tables, P2 table, kernels). */
#ifndef CELLCTL_PARAMS_H
#define CELLCTL_PARAMS_H

#include "common.h"

/* Everything the kernels need, derived once from the parameters. */
typedef struct cc_setup {
    cc_params p;
    int D, Dp;               /* disparity count and its padded count */
    int cmax;                /* largest fused cost */
    int use_avx2;
    int use_avx512;          /* the cost's AVX-512 kernel (byte popcount and 64-entry byte lookups) */
    uint8_t lut_census[CC_LUT];
    uint8_t lut_bt[CC_LUT];
    uint16_t p2_by_step[256];
} cc_setup;

/* CC_OK, or the cc_params_check error. */
int cc_setup_init(cc_setup *s, const cc_params *p);
/* The pair's pointers, size and strides, and the range against the width. */
int cc_check_images(const uint8_t *left, const uint8_t *right, int width, int height,
                    int stride_left, int stride_right, const cc_params *p);
int cc_cpu_has_avx2(void);
/* AVX-512 BW, VL, VBMI and BITALG: what the cost's AVX-512 kernel uses (256-bit vectors). */
int cc_cpu_has_avx512_lookup(void);

/* P2 for an intensity step |I(p) - I(p-r)| (from the table cc_setup_init fills). */
static inline int cc_p2_for_step(const cc_setup *s, int intensity, int prev_intensity)
{
    return s->p2_by_step[intensity > prev_intensity ? intensity - prev_intensity : prev_intensity - intensity];
}

#endif

/* postprocess.c: left-right check, fills, median and weighted median. */
#ifndef CELLCTL_POSTPROCESS_H
#define CELLCTL_POSTPROCESS_H

#include "weighted_median.h"

/* `scratch` holds cc_postprocess_scratch_bytes (one map and a histogram per thread). */
size_t cc_postprocess_scratch_bytes(const cc_params *p, int width, int height, int threads);
void cc_postprocess_maps(const cc_params *p, const int16_t *raw_left, const int16_t *raw_right,
                         const cc_wm_image *guide, int width, int height, int16_t *checked,
                         int16_t *filled, int16_t *disp, void *scratch, int threads);

#endif

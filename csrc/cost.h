/* cost.c: the fused Census + BT matching cost. */
#ifndef CELLCTL_COST_H
#define CELLCTL_COST_H

#include "frame.h"

/* Fused costs of pixels x0..x1-1 of row y, pixel x at out + (x - x0) * stride,
 * all disparities (Dp values, writing up to 32 bytes of slack past the last). */
void cc_cost_segment(const cc_setup *s, const cc_frame *f, int x0, int x1, int y, uint8_t *out, size_t stride);

#endif

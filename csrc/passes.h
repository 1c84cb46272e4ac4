/* passes.c: the three aggregation passes over the image (see aggregate.c for the plan). */
#ifndef CELLCTL_PASSES_H
#define CELLCTL_PASSES_H

#include "frame.h"
#include "workspace.h"

void cc_pass_vertical(const cc_setup *s, const cc_frame *f, cc_workspace *ws, int downward);
/* Horizontal paths, completing S row by row, and the selection of both views. */
void cc_pass_rows(const cc_setup *s, const cc_frame *f, cc_workspace *ws, int16_t *raw_left,
                  int16_t *raw_right, uint16_t *volume_out);

#endif

/* select.c: winner-takes-all of an aggregated row, left (sub-pixel) and right views. */
#ifndef CELLCTL_SELECT_H
#define CELLCTL_SELECT_H

#include "params.h"

size_t cc_select_tmp_bytes(const cc_setup *s, int width);
/* tmp: cc_select_tmp_bytes(s, width) bytes */
void cc_select_row(const cc_setup *s, const uint16_t *row, int stride, int width,
                   int16_t *left_out, int16_t *right_out, uint16_t *tmp);

#endif

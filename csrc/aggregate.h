/* aggregate.c: one step of a semi-global path, and the adaptive P2 table. */
#ifndef CELLCTL_AGGREGATE_H
#define CELLCTL_AGGREGATE_H

#include "params.h"

/* One row of path steps; arrays are indexed by the pixel's x (cost: x * cs; path vectors: x * vs, each
 * with its guard lanes; sums: x * Dp).  A step writes L to its path vector and acc_out = (acc_in or 0)
 * + L.  Vertical: pixel x continues from pixel x + dx of the previous row (`prev`, NULL on the first
 * row, and none outside the image); `grey`/`prev_grey` are the two rows' intensities (adaptive P2). */
typedef struct cc_path_rows {
    int width;
    const uint8_t *cost;
    size_t cs, vs;
    const uint8_t *grey, *prev_grey;
    const uint16_t *prev, *prev_min;
    uint16_t *out, *out_min;
    const uint16_t *acc_in;
    uint16_t *acc_out;
    int stream;              /* vertical, acc_in NULL: write acc_out past the caches (it is not read soon) */
} cc_path_rows;
void cc_path_vertical_row(const cc_setup *s, const cc_path_rows *r, int x0, int x1, int dx);
/* Horizontal: both directions along the row, through the two path vectors hpath[0..1]: acc_out =
 * acc_in + L(left to right), then acc_out += L(right to left). */
void cc_path_horizontal_row(const cc_setup *s, const cc_path_rows *r, uint16_t *hpath[2]);
/* P2 for every intensity step |I(p) - I(p-r)|: P2 * g / (g + step), never below P1
 * (constant P2 when g = 0); a table so the hot loops do no division. */
void cc_p2_table(const cc_params *p, uint16_t table[256]);

#endif

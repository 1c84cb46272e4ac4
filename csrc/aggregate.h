/* aggregate.c: one step of a semi-global path, and the adaptive P2 table. */
#ifndef CELLCTL_AGGREGATE_H
#define CELLCTL_AGGREGATE_H

#include "params.h"

/* L(p) from L(p-r) (NULL at a path's start); writes L to out and acc_out = (acc_in or 0) + L; returns min L. */
uint16_t cc_path_step(const cc_setup *s, const uint8_t *cost, const uint16_t *prev,
                      uint16_t prev_min, int p2, uint16_t *out,
                      const uint16_t *acc_in, uint16_t *acc_out);
/* P2 for every intensity step |I(p) - I(p-r)|: P2 * g / (g + step), never below P1
 * (constant P2 when g = 0); a table so the hot loops do no division. */
void cc_p2_table(const cc_params *p, uint16_t table[256]);

#endif

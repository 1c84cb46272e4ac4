/* frame.c: the two images prepared for the cost (census planes, BT image and bounds). */
#ifndef CELLCTL_FRAME_H
#define CELLCTL_FRAME_H

#include "params.h"

/* The right image is stored mirrored and padded per row so that, for a left
 * pixel x, the right pixels x - d of consecutive d are consecutive in memory. */
typedef struct cc_frame {
    int width, height;
    int nbytes;              /* census bytes per pixel */
    int pad, rstride;        /* mirrored right rows: index pad + (width-1-x) */
    uint8_t *lcen;           /* [nbytes][height][width] */
    uint8_t *lint, *lmin, *lmax;            /* [height][width]: the BT image and its bounds */
    uint8_t *lgrey;                         /* [height][width]: left intensities (adaptive P2) */
    uint8_t *rcen;           /* [nbytes][height][rstride] */
    uint8_t *rint, *rmin, *rmax;            /* [height][rstride]: the BT image and its bounds */
} cc_frame;

size_t cc_frame_bytes(const cc_setup *s, int width, int height);
int cc_frame_alloc(cc_frame *f, const cc_setup *s, int width, int height);
void cc_frame_free(cc_frame *f);
/* Per-thread scratch of cc_frame_prepare. */
size_t cc_frame_scratch_bytes(int width);
/* scratch: one slice of `slice` >= cc_frame_scratch_bytes(width) bytes per thread (the matcher
 * lends its per-thread scratch; pass 3 sets its path guards again after this). */
void cc_frame_prepare(cc_frame *f, const cc_setup *s, const uint8_t *left, int stride_left,
                      const uint8_t *right, int stride_right, int threads, uint8_t *scratch, size_t slice);
size_t cc_census_scratch_bytes(int width);
/* Census of row y as uint64 per pixel; scratch: cc_census_scratch_bytes(width) bytes. */
void cc_census_row(const uint8_t *img, int width, int height, int stride, int cw, int ch,
                   int y, uint64_t *out, uint8_t *scratch);

#endif

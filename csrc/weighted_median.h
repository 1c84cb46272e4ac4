/* weighted_median.c: the colour-weighted median of a disparity map at one pixel. */
#ifndef CELLCTL_WEIGHTED_MEDIAN_H
#define CELLCTL_WEIGHTED_MEDIAN_H

#include "common.h"

#define CC_WM_COLOURS (3 * 255 + 1)                                  /* summed channel differences */
#define CC_WM_SPACES (2 * CC_MAX_WM_RADIUS * CC_MAX_WM_RADIUS + 1)   /* squared distances */
#define CC_WM_SIDE (2 * CC_MAX_WM_RADIUS + 1)                        /* largest window side */
#define CC_WM_ROW (CC_WM_SIDE + 9)   /* a row of space_win: 8 lanes may be read past the window */
#define CC_WM_CHUNKS (CC_WM_SIDE * ((CC_WM_SIDE + 7) / 8))          /* 8-lane chunks of a window */
typedef struct cc_wm_tables {
    uint16_t colour[CC_WM_COLOURS];
    uint16_t space[CC_WM_SPACES];
    uint16_t gather_pad[2];   /* the vector kernel reads 32 bits at each 16-bit entry */
    /* space[dx^2 + dy^2] at [dy + R][dx + R] (R = CC_MAX_WM_RADIUS), 0 past dx = R: the vector
     * kernel loads a chunk's space weights instead of gathering them */
    uint32_t space_win[CC_WM_SIDE][CC_WM_ROW];
} cc_wm_tables;
typedef struct cc_wm_image {  /* the guide: 1 or 3 interleaved 8-bit channels */
    const uint8_t *data;
    int width, height, channels;
    size_t stride;
    const uint32_t *packed;   /* optional: channels packed per pixel (B | G << 8 | R << 16), 8 px slack */
    int use_avx2;             /* the vector kernel may read `packed` */
} cc_wm_image;
/* Pack row y of the guide into out[0..width) (grey counts as three equal channels). */
void cc_wm_pack_row(const cc_wm_image *g, int y, uint32_t *out);
typedef struct cc_wm_hist {   /* per thread */
    int64_t *value;           /* one entry per disparity level, kept zero between pixels (scalar kernel) */
    uint32_t *weight;
    uint32_t *win_weight;     /* the vector kernel's votes of one window: CC_WM_CHUNKS * 8 each */
    uint32_t *win_level;
} cc_wm_hist;
void cc_wm_tables_init(cc_wm_tables *t, float sigma_colour, float sigma_space);
size_t cc_wm_hist_bytes(int levels);
cc_wm_hist cc_wm_hist_at(void *base, int levels);
void cc_wm_hist_clear(cc_wm_hist *h, int levels);
#define CC_WM_NO_LEVEL 0xFFFF
/* Histogram level of a disparity: rounded to whole px, clamped to the range; CC_WM_NO_LEVEL if invalid.
 * Inline: it runs once per pixel and map. */
static inline int cc_wm_level(int v, int dmin, int levels)
{
    if (v == CC_INVALID)
        return CC_WM_NO_LEVEL;
    int b = cc_whole_px(v) - dmin;
    return b < 0 ? 0 : (b >= levels ? levels - 1 : b);
}
/* Weighted median at (x, y) of `map`, whose levels (cc_wm_level) are in `level`.  `run` (optional)
 * holds, per pixel, how many pixels from it to the right have its level: a window whose pixels all
 * have the centre's level keeps the centre's value without any weight being computed. */
int16_t cc_wm_pixel(const cc_wm_tables *t, const cc_wm_image *g, const int16_t *map,
                    const uint16_t *level, const uint16_t *run, int x, int y, int radius, cc_wm_hist *h);

#endif

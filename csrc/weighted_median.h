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
    /* The planar kernel (AVX2, no gather): the colour weights as bytes, looked up 32 at a time from
     * `colour_tables` 16-entry tables (0 when the weights reach index 127: then it is not used), with
     * colour[0] = 256 as 0 here (its high byte is added apart); and the space weights as 16-bit rows,
     * space[dx^2 + dy^2] at [dy + R][dx + R], 0 past dx = R. */
    int colour_tables;
    uint8_t colour_bytes[128];
    uint16_t space_row[CC_WM_SIDE][CC_WM_SIDE + 33];
} cc_wm_tables;
typedef struct cc_wm_image {  /* the guide: 1 or 3 interleaved 8-bit channels */
    const uint8_t *data;
    int width, height, channels;
    size_t stride;
    const uint32_t *packed;   /* optional: channels packed per pixel (B | G << 8 | R << 16), 8 px slack */
    const uint8_t *planes[3]; /* optional: the channels as planes [y][x] (grey: one), 32 bytes slack */
    int use_avx2;             /* the vector kernels may read `packed` or `planes` */
} cc_wm_image;
/* Pack row y of the guide into out[0..width) (grey counts as three equal channels). */
void cc_wm_pack_row(const cc_wm_image *g, int y, uint32_t *out);
/* Row y of the guide's channels into planes[c] + y * width (one plane for grey). */
void cc_wm_planes_row(const cc_wm_image *g, int y, uint8_t *const planes[3]);
/* The planar kernel's input is used for these tables: AVX2 and colour weights that end within 127. */
int cc_wm_planar_usable(const cc_wm_tables *t, int use_avx2);
typedef struct cc_wm_hist {   /* per thread */
    int64_t *value;           /* one entry per disparity level, kept zero between pixels (scalar kernel) */
    uint32_t *weight;
    uint32_t *win_weight;     /* CC_WM_CHUNKS * 8 each: the packed kernel's votes of one window (weights, */
    uint32_t *win_level;      /* levels); the planar kernel's 16-bit colour weights (win_weight) and the
                                 row kernel's colour weights of 32 centres x 32 offsets (win_level) */
    int guess;                /* the planar kernel's first guess of the median level: the last pixel's (-1: none);
                                 a guess only saves work, the result does not depend on it */
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
/* A map for the weighted median: its values, their levels (cc_wm_level; 32 entries of slack), and
 * optionally `run`: per pixel, how many pixels from it to the right have its level (a window whose
 * pixels all have the centre's level keeps the centre's value without any weight being computed);
 * and for the planar kernel `invalid`: 0xFF where the level is CC_WM_NO_LEVEL, else 0 (32 bytes of
 * slack). */
typedef struct cc_wm_map {
    const int16_t *value;
    const uint16_t *level;
    const uint16_t *run;
    const uint8_t *invalid;
} cc_wm_map;
/* Weighted median of row y of the map into out[0..width): the same values as cc_wm_pixel at every x. */
void cc_wm_row(const cc_wm_tables *t, const cc_wm_image *g, const cc_wm_map *m, int y, int radius, cc_wm_hist *h,
               int16_t *out);
/* Weighted median at (x, y) of the map. */
int16_t cc_wm_pixel(const cc_wm_tables *t, const cc_wm_image *g, const cc_wm_map *m, int x, int y, int radius,
                    cc_wm_hist *h);

#endif

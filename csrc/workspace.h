/* workspace.c: the buffers of one matcher for one image size. */
#ifndef CELLCTL_WORKSPACE_H
#define CELLCTL_WORKSPACE_H

#include "params.h"

typedef struct cc_workspace {
    int width, height, threads;
    uint16_t *volume;        /* aggregated cost S, [height][width][Dp] */
    uint8_t *costs;          /* matching cost C, [height][width][cstride] + slack: pass 1 computes it,
                                passes 2 and 3 read it (1 byte per cell instead of two recomputations) */
    size_t cstride;          /* Dp rounded up to 32: the cost kernel writes 32 lanes at a time */
    int stream;              /* the volume is far larger than the caches: pass 1 writes it past them */
    uint16_t *vpath;         /* vertical/diagonal paths: [paths][2 rows][width][vstride] */
    uint16_t *vmin;          /* their minima: [paths][2 rows][width] */
    size_t vstride;          /* Dp + 2 guards */
    uint8_t *scratch;        /* per thread: see cc_thread_scratch */
    size_t scratch_stride;
} cc_workspace;

/* Per-thread scratch of pass 3 and the selection. */
typedef struct cc_thread_scratch {
    uint16_t *sum_row;       /* [width][Dp] */
    uint16_t *hpath[2];      /* two pixels' path vectors with guards */
    uint16_t *select_tmp;    /* [width] */
} cc_thread_scratch;

/* Allocates every buffer (guards set); *bytes receives their size.  CC_OK or CC_ERR_NOMEM. */
int cc_workspace_alloc(cc_workspace *ws, const cc_setup *s, int width, int height, size_t *bytes);
void cc_workspace_free(cc_workspace *ws);
cc_thread_scratch cc_thread_scratch_at(const cc_setup *s, const cc_workspace *ws, int thread);

#endif

/* Aligned buffers and the thread count. */
#define _GNU_SOURCE
#include <omp.h>
#include <stdlib.h>
#include <sys/mman.h>

#include "memory.h"

#define CC_ALIGN 64
#define CC_HUGE (2u << 20)

void *cc_alloc(size_t bytes)
{
    void *p = NULL;
    if (bytes == 0)
        bytes = CC_ALIGN;
    size_t align = bytes >= CC_HUGE ? CC_HUGE : CC_ALIGN;
    if (posix_memalign(&p, align, bytes) != 0)
        return NULL;
#ifdef MADV_HUGEPAGE
    /* The volume is touched once per pass: fewer TLB misses and page faults. */
    if (align == CC_HUGE)
        madvise(p, bytes, MADV_HUGEPAGE);
#endif
    return p;
}

void cc_free(void *ptr) { free(ptr); }

int cc_thread_count(const cc_params *p)
{
    int n = p->threads > 0 ? p->threads : omp_get_max_threads();
    return n > 0 ? n : 1;
}

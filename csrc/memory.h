/* memory.c: aligned buffers (huge-page aligned when large) and the thread count. */
#ifndef CELLCTL_MEMORY_H
#define CELLCTL_MEMORY_H

#include "common.h"

void *cc_alloc(size_t bytes);
void cc_free(void *ptr);
/* Threads a call runs on: p->threads, or all OpenMP offers when 0. */
int cc_thread_count(const cc_params *p);

#endif

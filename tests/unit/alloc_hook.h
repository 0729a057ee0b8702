/*
 * alloc_hook.h - allocation failure on demand, for test_alloc_fail only
 * (alloc_hook.c is linked into that binary alone).
 *
 * alloc_hook.c defines malloc, calloc, realloc, free, aligned_alloc,
 * posix_memalign, strdup and strndup over the next definitions in the link
 * order (glibc's, or the sanitizer's when one is linked), so every
 * allocation in the process goes through it: arbor's own, and those of
 * libmicrohttpd, libpng, zlib and cJSON. Armed with n, the n-th allocation
 * from then on (counted over every thread) returns NULL, once; the others
 * succeed. It also counts the blocks alive, so that a test can tell that
 * an operation that failed gave back everything it took.
 */
#ifndef ARBOR_TEST_ALLOC_HOOK_H
#define ARBOR_TEST_ALLOC_HOOK_H

#include <stdbool.h>

/* The n-th allocation from now fails (n >= 1); 0 disarms. */
void alloc_hook_arm(long n);
/* Disarms; true when the armed allocation was reached (and failed). */
bool alloc_hook_disarm(void);
/* Allocations since the last arm. */
long alloc_hook_count(void);
/* Blocks allocated and not yet freed. */
long alloc_hook_live(void);
/* Where the failed allocation was called from, past the C library and a
 * sanitizer's runtime (the caller of the tsearch or fopen that allocated):
 * its shared object and the offset in it ("libmicrohttpd.so.12+0x1a2b3",
 * "test_alloc_fail+0x4c5d"), for addr2line; "" until one failed. */
const char *alloc_hook_failed_in(void);

#endif

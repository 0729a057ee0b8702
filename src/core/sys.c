/* sys.c - clock, core count, file identity and prefaulting (see
 * include/arbor/sys.h). */
#define _DEFAULT_SOURCE /* madvise */
#include <sys/mman.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "arbor/sys.h"

double arbor_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

int arbor_cpu_count(void)
{
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (int)n : 1;
}

/* FNV-1a over the fields that change when a file is replaced or rewritten. */
uint64_t arbor_file_stamp(const char *path)
{
    struct stat st;
    if (stat(path, &st) != 0)
        return 0;
    uint64_t fields[5] = {(uint64_t)st.st_dev, (uint64_t)st.st_ino, (uint64_t)st.st_size,
                          (uint64_t)st.st_mtim.tv_sec, (uint64_t)st.st_mtim.tv_nsec};
    uint64_t h = 14695981039346656037ull;
    for (int i = 0; i < 5; i++)
        for (int b = 0; b < 8; b++) {
            h ^= (fields[i] >> (8 * b)) & 0xff;
            h *= 1099511628211ull;
        }
    return h != 0 ? h : 1;
}

void arbor_prefault(void *p, size_t bytes)
{
#ifdef MADV_POPULATE_WRITE
    long page = sysconf(_SC_PAGESIZE);
    if (page <= 0)
        return;
    uintptr_t lo = ((uintptr_t)p + (uintptr_t)page - 1) & ~((uintptr_t)page - 1);
    uintptr_t hi = ((uintptr_t)p + bytes) & ~((uintptr_t)page - 1);
    if (hi > lo)
        (void)madvise((void *)lo, hi - lo, MADV_POPULATE_WRITE); /* a hint: failure leaves the faults to come */
#else
    (void)p;
    (void)bytes;
#endif
}

/*
 * alloc_hook.c - see alloc_hook.h. Linked into test_alloc_fail only.
 *
 * Each function forwards to the next definition of its name after this
 * executable's (dlsym RTLD_NEXT): glibc's allocator, or AddressSanitizer's
 * when the test is built with it, so that ASan still checks every block and
 * reports leaks at exit. dlsym may itself allocate before the next malloc
 * is known; those few blocks come from a static arena and are never freed,
 * as do the loader's when the unwinder is loaded (alloc_hook_init).
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <execinfo.h>
#include <errno.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "alloc_hook.h"

static void *(*next_malloc)(size_t);
static void *(*next_calloc)(size_t, size_t);
static void *(*next_realloc)(void *, size_t);
static void (*next_free)(void *);
static void *(*next_aligned_alloc)(size_t, size_t);
static int (*next_posix_memalign)(void **, size_t, size_t);

static atomic_bool armed;
static atomic_long count, fail_at, live;
static atomic_bool fired;
static void *_Atomic fail_site;
/* The failed allocation's stack (written once per arm, by the thread whose
 * allocation failed; read after disarming). */
static void *fail_stack[32];
static int fail_depth;

/* ---- bootstrap ---- */

static _Alignas(max_align_t) unsigned char arena[16384];
static atomic_size_t arena_used;
static atomic_bool resolving, loading_unwinder;

static bool in_arena(const void *p)
{
    return (const unsigned char *)p >= arena && (const unsigned char *)p < arena + sizeof arena;
}

static void *arena_alloc(size_t n)
{
    size_t size = (n + sizeof(max_align_t) - 1) / sizeof(max_align_t) * sizeof(max_align_t);
    size_t at = atomic_fetch_add(&arena_used, size);
    return at + size <= sizeof arena ? arena + at : NULL;
}

/* Whether an allocation comes from the arena: while dlsym looks up the
 * next allocator (`unresolved`: the one this call needs is not known yet),
 * and while the constructor loads the unwinder. */
static bool from_arena(bool unresolved)
{
    return (unresolved && atomic_load(&resolving)) || atomic_load(&loading_unwinder);
}

static void resolve(void)
{
    if (next_free != NULL)
        return;
    atomic_store(&resolving, true);
    next_malloc = (void *(*)(size_t))dlsym(RTLD_NEXT, "malloc");
    next_calloc = (void *(*)(size_t, size_t))dlsym(RTLD_NEXT, "calloc");
    next_realloc = (void *(*)(void *, size_t))dlsym(RTLD_NEXT, "realloc");
    next_aligned_alloc = (void *(*)(size_t, size_t))dlsym(RTLD_NEXT, "aligned_alloc");
    next_posix_memalign = (int (*)(void **, size_t, size_t))dlsym(RTLD_NEXT, "posix_memalign");
    next_free = (void (*)(void *))dlsym(RTLD_NEXT, "free");
    atomic_store(&resolving, false);
}

__attribute__((constructor)) static void alloc_hook_init(void)
{
    /* The first backtrace loads the unwinder (a dlopen of libgcc_s), which
     * allocates: here, not inside an allocation that fails, and from the
     * arena, because the loader keeps those blocks where LeakSanitizer does
     * not look and would report them as leaked. */
    atomic_store(&loading_unwinder, true);
    fail_depth = backtrace(fail_stack, 32);
    atomic_store(&loading_unwinder, false);
    resolve();
}

/* ---- the counter ---- */

/* Whether code at p is the C library's (a tsearch, an fopen) or a
 * sanitizer runtime's (which intercepts tsearch, strdup, ...). */
static bool in_runtime(void *p)
{
    Dl_info info;
    return !(dladdr(p, &info) != 0 && info.dli_fname != NULL && strstr(info.dli_fname, "libc.so") == NULL &&
             strstr(info.dli_fname, "san.so") == NULL);
}

/* The first frame of stack[0, depth), from `site` on, that is not the
 * runtime's (in_runtime): the program's code that allocated. NULL when
 * there is none. When the stack does not hold site (a thread just
 * starting, whose stack the unwinder cannot walk yet), site itself unless
 * it is the runtime's. */
static void *program_frame(void *const *stack, int depth, void *site)
{
    int i = 0;
    while (i < depth && stack[i] != site)
        i++;
    if (i == depth)
        return in_runtime(site) ? NULL : site;
    for (; i < depth; i++)
        if (!in_runtime(stack[i]))
            return stack[i];
    return NULL;
}

/* Whether this allocation is the one to fail; `site` is its caller. An
 * allocation no code of the program asked for (a sanitizer's runtime
 * starting a thread calls pthread_getattr_np, which allocates) is not
 * failed: the runtime takes that as a broken invariant and aborts, which no
 * program could handle. The next allocation fails instead. */
static bool should_fail(void *site)
{
    if (!atomic_load_explicit(&armed, memory_order_relaxed))
        return false;
    if (atomic_fetch_add(&count, 1) + 1 != atomic_load(&fail_at))
        return false;
    fail_depth = backtrace(fail_stack, 32);
    if (program_frame(fail_stack, fail_depth, site) == NULL) {
        atomic_fetch_add(&fail_at, 1);
        return false;
    }
    atomic_store(&fail_site, site);
    atomic_store(&fired, true);
    errno = ENOMEM; /* as the real allocators say it */
    return true;
}

static void *counted(void *p)
{
    if (p != NULL)
        atomic_fetch_add_explicit(&live, 1, memory_order_relaxed);
    return p;
}

void alloc_hook_arm(long n)
{
    atomic_store(&armed, false);
    atomic_store(&count, 0);
    atomic_store(&fired, false);
    atomic_store(&fail_site, NULL);
    atomic_store(&fail_at, n);
    atomic_store(&armed, n > 0);
}

bool alloc_hook_disarm(void)
{
    atomic_store(&armed, false);
    return atomic_load(&fired);
}

long alloc_hook_count(void)
{
    return atomic_load(&count);
}

long alloc_hook_live(void)
{
    return atomic_load(&live);
}

/* The caller of the failed allocation, or the first caller above it that is
 * the program's (program_frame). */
const char *alloc_hook_failed_in(void)
{
    static char name[256];
    Dl_info info;
    void *site = atomic_load(&fail_site);
    name[0] = '\0';
    if (site != NULL)
        site = program_frame(fail_stack, fail_depth, site);
    if (site != NULL && dladdr(site, &info) != 0 && info.dli_fname != NULL) {
        const char *base = strrchr(info.dli_fname, '/');
        snprintf(name, sizeof name, "%s+0x%zx", base != NULL ? base + 1 : info.dli_fname,
                 (size_t)((char *)site - (char *)info.dli_fbase));
    }
    return name;
}

/* ---- the allocator ---- */

static void *hooked_malloc(size_t n, void *site)
{
    if (from_arena(next_malloc == NULL))
        return arena_alloc(n);
    resolve();
    if (should_fail(site))
        return NULL;
    return counted(next_malloc(n));
}

void *malloc(size_t n)
{
    return hooked_malloc(n, __builtin_return_address(0));
}

void *calloc(size_t n, size_t size)
{
    if (from_arena(next_calloc == NULL)) {
        if (size != 0 && n > SIZE_MAX / size)
            return NULL;
        return arena_alloc(n * size); /* static storage: already zero */
    }
    resolve();
    if (should_fail(__builtin_return_address(0)))
        return NULL;
    return counted(next_calloc(n, size));
}

void *realloc(void *p, size_t n)
{
    void *site = __builtin_return_address(0);
    if (p == NULL || in_arena(p)) {
        void *q = hooked_malloc(n, site);
        if (q != NULL && p != NULL) {
            size_t avail = (size_t)(arena + sizeof arena - (unsigned char *)p);
            memcpy(q, p, n < avail ? n : avail);
        }
        return q;
    }
    resolve();
    if (n == 0) {
        /* glibc and ASan both free and return NULL here: a free, not an allocation. */
        void *q = next_realloc(p, 0);
        if (q == NULL)
            atomic_fetch_sub(&live, 1);
        return q;
    }
    if (should_fail(site))
        return NULL;
    return next_realloc(p, n);
}

void free(void *p)
{
    if (p == NULL || in_arena(p))
        return;
    resolve();
    atomic_fetch_sub_explicit(&live, 1, memory_order_relaxed);
    next_free(p);
}

void *aligned_alloc(size_t align, size_t n)
{
    resolve();
    if (should_fail(__builtin_return_address(0)))
        return NULL;
    return counted(next_aligned_alloc(align, n));
}

int posix_memalign(void **out, size_t align, size_t n)
{
    resolve();
    if (should_fail(__builtin_return_address(0)))
        return ENOMEM;
    int rc = next_posix_memalign(out, align, n);
    if (rc == 0)
        counted(*out);
    return rc;
}

/* Sanitizers allocate for these themselves, out of sight of malloc. */
char *strdup(const char *s)
{
    size_t n = strlen(s) + 1;
    char *d = hooked_malloc(n, __builtin_return_address(0));
    if (d != NULL)
        memcpy(d, s, n);
    return d;
}

char *strndup(const char *s, size_t max)
{
    size_t n = strnlen(s, max);
    char *d = hooked_malloc(n + 1, __builtin_return_address(0));
    if (d != NULL) {
        memcpy(d, s, n);
        d[n] = '\0';
    }
    return d;
}

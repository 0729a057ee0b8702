/*
 * fuzz_static.c - the static file resolver (static_resolve, src/server/
 * static.h) on arbitrary URL paths, against a web folder that holds traps:
 *
 *   web/index.html, web/app.js, web/sub/page.html
 *   web/in      -> sub         (a link that stays inside)
 *   web/out     -> ../outside  (a link to a folder outside)
 *   web/leak.js -> ../secret   (a link to a file outside)
 *   web/trap/index.html -> ../../secret (a folder whose index leaves)
 *   outside/secret.txt, secret
 *
 * Whatever the path, an answer must be a file or folder that lies inside
 * the web folder's real path once every link in it is followed: the check
 * realpath()s the answer itself and compares.
 */
#define _XOPEN_SOURCE 700 /* realpath, symlink */
#include <limits.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "fuzz.h"
#include "../../src/server/static.h"

static char web[256], web_real[PATH_MAX];

static void link_or_die(const char *target, const char *name)
{
    char path[PATH_MAX];
    snprintf(path, sizeof path, "%s/%s", web, name);
    FUZZ_CHECK(symlink(target, path) == 0, "cannot link %s", path);
}

static void setup(void)
{
    const char *root = fuzz_scratch();
    char path[PATH_MAX];
    snprintf(web, sizeof web, "%s/web", root);
    static const char *const dirs[] = {"web", "web/sub", "web/trap", "outside"};
    for (size_t i = 0; i < sizeof dirs / sizeof dirs[0]; i++) {
        snprintf(path, sizeof path, "%s/%s", root, dirs[i]);
        FUZZ_CHECK(mkdir(path, 0700) == 0, "cannot make %s", path);
    }
    static const char *const files[] = {"web/index.html", "web/app.js", "web/sub/page.html", "outside/secret.txt",
                                        "secret"};
    for (size_t i = 0; i < sizeof files / sizeof files[0]; i++)
        fuzz_write(files[i], "x", 1, 0);
    link_or_die("sub", "in");
    link_or_die("../outside", "out");
    link_or_die("../secret", "leak.js");
    link_or_die("../../secret", "trap/index.html");
    FUZZ_CHECK(realpath(web, web_real) != NULL, "no real path for %s", web);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (web[0] == '\0')
        setup();
    char *path = malloc(size + 1);
    FUZZ_CHECK(path != NULL, "out of memory");
    memcpy(path, data, size);
    path[size] = '\0';
    char out[PATH_MAX], real[PATH_MAX];
    if (static_resolve(web, path, out)) {
        /* What open() will reach: the answer with every link followed. A
         * name that does not exist is no escape (open fails: a 404). */
        if (realpath(out, real) != NULL) {
            size_t n = strlen(web_real);
            FUZZ_CHECK(strncmp(real, web_real, n) == 0 && (real[n] == '/' || real[n] == '\0'),
                       "'%s' resolved to %s, outside %s", path, real, web_real);
        }
    }
    free(path);
    return 0;
}

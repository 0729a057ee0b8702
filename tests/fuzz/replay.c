/*
 * replay.c - a fuzz target as an ordinary test program: runs
 * LLVMFuzzerTestOneInput on every file of the target's committed corpus
 * (FUZZ_CORPUS, compiled in; or the files and folders given as arguments)
 * and ends with Unity's summary line for tests/run.sh. An input passes when
 * the target returns; a check that fails, or a sanitizer report, aborts the
 * program, which tests/run.sh counts as a failure. This is how every crash
 * the fuzzers found stays fixed, under gcc and without libFuzzer.
 */
#define _XOPEN_SOURCE 700
#include <dirent.h>
#include <limits.h>
#include <string.h>
#include <sys/stat.h>

#include "fuzz.h"

static unsigned ran;

static void replay_file(const char *path)
{
    FILE *f = fopen(path, "rb");
    FUZZ_CHECK(f != NULL, "cannot read %s", path);
    size_t cap = 4096, n = 0, got;
    uint8_t *buf = malloc(cap);
    FUZZ_CHECK(buf != NULL, "out of memory");
    while ((got = fread(buf + n, 1, cap - n, f)) > 0) {
        n += got;
        if (n == cap) {
            buf = realloc(buf, cap *= 2);
            FUZZ_CHECK(buf != NULL, "out of memory");
        }
    }
    FUZZ_CHECK(!ferror(f), "cannot read %s", path);
    fclose(f);
    printf("%s:1:replay:RUN\n", path);
    fflush(stdout);
    LLVMFuzzerTestOneInput(buf, n);
    free(buf);
    printf("%s:1:replay:PASS\n", path);
    ran++;
}

static int by_name(const struct dirent **a, const struct dirent **b)
{
    return strcmp((*a)->d_name, (*b)->d_name);
}

static void replay(const char *path)
{
    struct stat st;
    FUZZ_CHECK(stat(path, &st) == 0, "no corpus at %s", path);
    if (!S_ISDIR(st.st_mode)) {
        replay_file(path);
        return;
    }
    struct dirent **names;
    int n = scandir(path, &names, NULL, by_name);
    FUZZ_CHECK(n >= 0, "cannot list %s", path);
    for (int i = 0; i < n; i++) {
        if (names[i]->d_name[0] != '.') {
            char file[PATH_MAX];
            snprintf(file, sizeof file, "%s/%s", path, names[i]->d_name);
            replay(file);
        }
        free(names[i]);
    }
    free(names);
}

int main(int argc, char **argv)
{
    if (argc < 2)
        replay(FUZZ_CORPUS);
    for (int i = 1; i < argc; i++)
        replay(argv[i]);
    FUZZ_CHECK(ran > 0, "the corpus is empty");
    printf("-----------------------\n%u Tests 0 Failures 0 Ignored\nOK\n", ran);
    return 0;
}

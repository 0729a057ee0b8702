/*
 * fuzz.h - what the libFuzzer targets of tests/fuzz share: a check that
 * aborts (so libFuzzer keeps the input as a crash), a private scratch
 * folder for targets that must go through files, and the invariants every
 * successfully loaded mesh must hold.
 *
 * Each target defines LLVMFuzzerTestOneInput. Built with clang's
 * -fsanitize=fuzzer it is a fuzzer (make fuzz); linked with replay.c it is
 * a program that replays its committed corpus, so make test (and its
 * sanitizer builds) run every regression input without clang.
 */
#ifndef ARBOR_FUZZ_H
#define ARBOR_FUZZ_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

#include "arbor/mesh.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define FUZZ_CHECK(cond, ...)                                                   \
    do {                                                                        \
        if (!(cond)) {                                                          \
            fprintf(stderr, "%s:%d: check failed: %s: ", __FILE__, __LINE__, #cond); \
            fprintf(stderr, __VA_ARGS__);                                       \
            fputc('\n', stderr);                                                \
            abort();                                                            \
        }                                                                       \
    } while (0)

/* A folder of this process's own, made at the first call and removed with
 * everything in it at exit. */
const char *fuzz_scratch(void);

/* Writes n bytes to scratch/name (replacing it) and returns its path (a
 * static buffer, valid until the next call). gz: gzip-compressed. */
const char *fuzz_write(const char *name, const void *data, size_t n, int gz);

/* Removes every file in the folder (not the folder). */
void fuzz_empty_dir(const char *dir);

/* What a loader's success promises: triangles, indices and materials in
 * range, finite vertices, bounds holding every vertex a triangle uses. */
void fuzz_check_mesh(const arbor_mesh *m);

#endif

/*
 * fuzz_ply.c - the PLY reader (ascii and binary of either byte order) on
 * arbitrary bytes. The first byte picks the path: 0 the bytes in memory
 * (arbor_load_ply_data), 1 NAME.ply.gz gzip-compressed, 2 the bytes
 * themselves as NAME.ply.gz (broken gzip), 3 NAME.ply from a file. A load
 * that succeeds must hold fuzz_check_mesh's invariants.
 */
#include "arbor/load.h"
#include "fuzz.h"

#define MAX_BYTES (1u << 20)

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    int mode = data[0] & 3;
    const char *bytes = (const char *)data + 1;
    size_t len = size - 1;
    arbor_mesh m;
    arbor_mesh_init(&m);
    arbor_err e;
    arbor_err_clear(&e);
    bool ok;
    if (mode == 0)
        ok = arbor_load_ply_data(bytes, len, "fuzz.ply", &m, &e);
    else if (mode == 3)
        ok = arbor_load_model_capped(fuzz_write("f.ply", bytes, len, 0), MAX_BYTES, &m, &e);
    else
        ok = arbor_load_model_capped(fuzz_write("f.ply.gz", bytes, len, mode == 1), MAX_BYTES, &m, &e);
    if (ok)
        fuzz_check_mesh(&m);
    else
        FUZZ_CHECK(m.ntris == 0 && m.verts == NULL && e.msg[0] != '\0', "a failed load left a mesh or no message");
    arbor_mesh_free(&m);
    return 0;
}

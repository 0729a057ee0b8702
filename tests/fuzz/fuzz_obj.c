/*
 * fuzz_obj.c - the OBJ and MTL readers on arbitrary bytes.
 *
 * The first byte picks the path into the reader; the rest is the file.
 * Text after a line "#mtl" is written to m.mtl in the scratch folder, the
 * model's folder, so "mtllib m.mtl" reaches the MTL reader (and "mtllib
 * ../x" its containment check):
 *   0: arbor_load_obj_text on the bytes in memory
 *   1: arbor_load_model on NAME.obj (the file path, as the daemon loads)
 *   2: the same through NAME.obj.gz, gzip-compressed
 *   3: the bytes themselves as NAME.obj.gz (broken and truncated gzip)
 * A load that succeeds must hold fuzz_check_mesh's invariants; one that
 * fails must leave the mesh empty and say why.
 */
#include <string.h>

#include "arbor/load.h"
#include "fuzz.h"

#define MAX_BYTES (1u << 20) /* the cap on file and inflated bytes: gzip bombs stop here */

static const char mtl_marker[] = "\n#mtl\n";

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    int mode = data[0] & 3;
    const char *text = (const char *)data + 1;
    size_t len = size - 1;
    const char *mtl = NULL;
    for (size_t i = 0; i + sizeof mtl_marker - 1 <= len; i++)
        if (memcmp(text + i, mtl_marker, sizeof mtl_marker - 1) == 0) {
            mtl = text + i + sizeof mtl_marker - 1;
            fuzz_write("m.mtl", mtl, (size_t)(text + len - mtl), 0);
            len = i + 1;
            break;
        }
    if (mtl == NULL)
        fuzz_write("m.mtl", "", 0, 0);

    arbor_mesh m;
    arbor_mesh_init(&m);
    arbor_err e;
    arbor_err_clear(&e);
    bool ok;
    if (mode == 0)
        ok = arbor_load_obj_text(text, len, "fuzz.obj", fuzz_scratch(), &m, &e);
    else if (mode == 1)
        ok = arbor_load_model_capped(fuzz_write("f.obj", text, len, 0), MAX_BYTES, &m, &e);
    else
        ok = arbor_load_model_capped(fuzz_write("f.obj.gz", text, len, mode == 2), MAX_BYTES, &m, &e);
    if (ok)
        fuzz_check_mesh(&m);
    else
        FUZZ_CHECK(m.ntris == 0 && m.verts == NULL && e.msg[0] != '\0', "a failed load left a mesh or no message");
    arbor_mesh_free(&m);
    return 0;
}

/* load.c - placeholder until the OBJ/PLY reader lands. */
#include "arbor/load.h"

bool arbor_load_model(const char *path, arbor_mesh *m, arbor_err *e)
{
    arbor_mesh_init(m);
    return arbor_fail(e, ARBOR_ERR_IO, "%s: loader not written yet", path);
}

bool arbor_load_obj_text(const char *text, size_t len, const char *name, const char *dir,
                         arbor_mesh *m, arbor_err *e)
{
    (void)text;
    (void)len;
    (void)dir;
    arbor_mesh_init(m);
    return arbor_fail(e, ARBOR_ERR_IO, "%s: loader not written yet", name);
}

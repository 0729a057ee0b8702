/*
 * load.c - loading a model file by its extension (arbor_load_model, see
 * include/arbor/load.h): reads the whole file, gunzipping .gz, up to the
 * caller's cap, and hands the buffer to the OBJ or PLY parser, with the
 * file's folder for material libraries.
 */
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "arbor/load.h"
#include "loader.h"

typedef enum { FORMAT_UNKNOWN, FORMAT_OBJ, FORMAT_PLY } model_format;

static bool has_suffix(const char *s, const char *suffix)
{
    size_t n = strlen(s), k = strlen(suffix);
    return n >= k && strcasecmp(s + n - k, suffix) == 0;
}

static model_format format_of(const char *path)
{
    bool gz = has_suffix(path, ".gz");
    if (has_suffix(path, gz ? ".obj.gz" : ".obj"))
        return FORMAT_OBJ;
    if (has_suffix(path, gz ? ".ply.gz" : ".ply"))
        return FORMAT_PLY;
    return FORMAT_UNKNOWN;
}

/* The folder part of path ("." when it has none); caller frees. */
static char *folder_of(const char *path)
{
    const char *slash = strrchr(path, '/');
    if (slash == NULL)
        return strdup(".");
    size_t n = slash == path ? 1 : (size_t)(slash - path);
    char *dir = malloc(n + 1);
    if (dir != NULL) {
        memcpy(dir, path, n);
        dir[n] = '\0';
    }
    return dir;
}

bool arbor_load_file(const char *path, size_t max_bytes, char **data, size_t *len, arbor_err *e)
{
    return loader_read_file(path, has_suffix(path, ".gz"), max_bytes ? max_bytes : ARBOR_LOAD_MAX_BYTES, data, len,
                            e);
}

bool arbor_load_model(const char *path, arbor_mesh *m, arbor_err *e)
{
    return arbor_load_model_capped(path, 0, m, e);
}

bool arbor_load_model_capped(const char *path, size_t max_bytes, arbor_mesh *m, arbor_err *e)
{
    arbor_mesh_init(m);
    model_format format = format_of(path);
    if (format == FORMAT_UNKNOWN)
        return arbor_fail(e, ARBOR_ERR_IO, "%s: unknown model format (expected .obj, .obj.gz, .ply or .ply.gz)", path);
    char *data;
    size_t len;
    if (!arbor_load_file(path, max_bytes, &data, &len, e))
        return false;
    bool ok;
    if (format == FORMAT_PLY) {
        ok = arbor_load_ply_data(data, len, path, m, e);
    } else {
        char *dir = folder_of(path);
        ok = dir != NULL ? arbor_load_obj_text(data, len, path, dir, m, e)
                         : arbor_fail(e, ARBOR_ERR_NOMEM, "%s: out of memory", path);
        free(dir);
    }
    free(data);
    return ok;
}

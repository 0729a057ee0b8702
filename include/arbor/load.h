/*
 * load.h - reading models from files: Wavefront OBJ (+ MTL materials) and
 * Stanford PLY, plain or gzip-compressed.
 *
 * The loaders fill a caller-owned arbor_mesh (freed with arbor_mesh_free).
 * On failure they return false with an error naming the file, the line (or
 * element) and the reason, and leave the mesh empty: a half-read mesh is
 * never reported as success. Problems that do not stop the load (a material
 * library that is missing or outside the model's folder) go to the mesh's
 * warnings.
 */
#ifndef ARBOR_LOAD_H
#define ARBOR_LOAD_H

#include <stdbool.h>
#include <stddef.h>

#include "arbor/err.h"
#include "arbor/mesh.h"

/* Loads path by its extension: .obj, .obj.gz, .ply, .ply.gz. */
bool arbor_load_model(const char *path, arbor_mesh *m, arbor_err *e);

/* Parses OBJ text already in memory. `name` is used in error messages; mtllib
 * paths resolve against dir (NULL: materials are not loaded). */
bool arbor_load_obj_text(const char *text, size_t len, const char *name, const char *dir,
                         arbor_mesh *m, arbor_err *e);

#endif

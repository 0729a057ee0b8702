/*
 * load.h - reading models from files: Wavefront OBJ (+ MTL materials) and
 * Stanford PLY, plain or gzip-compressed.
 *
 * The loaders fill a caller-owned arbor_mesh (freed with arbor_mesh_free).
 * On failure they return false with an error naming the file, the line (or
 * element) and the reason, and leave the mesh empty: a half-read mesh is
 * never reported as success. A model without any triangle is an error too.
 * Problems that do not stop the load (a material library that is missing or
 * outside the model's folder, a usemtl naming an undefined material) go to
 * the mesh's warnings. Triangles before any usemtl use material 0, the
 * default. Polygons are fan-triangulated from their first vertex.
 *
 * The text parsers read the whole buffer in one pass and are safe on
 * arbitrary bytes: they never read outside [text, text + len) and need no
 * terminating NUL.
 *
 * Work per file is bounded: a load reads at most max_bytes of file or, for
 * gzip, of decompressed data (a small .gz can inflate to gigabytes), and
 * fails naming the file and the limit beyond it.
 */
#ifndef ARBOR_LOAD_H
#define ARBOR_LOAD_H

#include <stdbool.h>
#include <stddef.h>

#include "arbor/err.h"
#include "arbor/mesh.h"

/* The cap arbor_load_model applies: 4 GiB of file or of decompressed data. */
#define ARBOR_LOAD_MAX_BYTES ((size_t)4 << 30)

/* Loads path by its extension: .obj, .obj.gz, .ply, .ply.gz, reading at
 * most ARBOR_LOAD_MAX_BYTES. Material libraries resolve against the model's
 * folder and may not leave it, following symbolic links (real paths). */
bool arbor_load_model(const char *path, arbor_mesh *m, arbor_err *e);

/* The same with the caller's cap on the bytes read (0: ARBOR_LOAD_MAX_BYTES);
 * a file or decompressed stream longer than max_bytes is an ARBOR_ERR_IO
 * error naming the file and the limit. */
bool arbor_load_model_capped(const char *path, size_t max_bytes, arbor_mesh *m, arbor_err *e);

/* The bytes a load parses: the whole file at path, gunzipped when its name
 * ends in .gz, at most max_bytes of them (0: ARBOR_LOAD_MAX_BYTES). *data is
 * malloc'd and the caller's to free; *len is its length. */
bool arbor_load_file(const char *path, size_t max_bytes, char **data, size_t *len, arbor_err *e);

/* Parses OBJ text already in memory. `name` is used in error messages; mtllib
 * paths resolve against dir (NULL: materials are not loaded). */
bool arbor_load_obj_text(const char *text, size_t len, const char *name, const char *dir,
                         arbor_mesh *m, arbor_err *e);

/* Parses a PLY file (ascii or binary, either byte order) already in memory;
 * `name` is used in error messages. */
bool arbor_load_ply_data(const char *data, size_t len, const char *name, arbor_mesh *m, arbor_err *e);

/* Parses the decimal number that starts exactly at p (an optional sign, digits
 * with an optional '.', an optional exponent; or inf, infinity, nan) without
 * reading at or past end. Returns the end of the number and stores it in
 * *out, rounded the way strtof rounds it; returns NULL when p does not start
 * a number. This is the loaders' number reader, exposed for its tests. */
const char *arbor_parse_float(const char *p, const char *end, float *out);

#endif

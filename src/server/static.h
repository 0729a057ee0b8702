/*
 * static.h - the static file resolver of static.c, private to src/server/
 * and exposed on its own so that it can be fuzzed without a connection
 * (tests/fuzz/fuzz_static.c).
 */
#ifndef ARBOR_SERVER_STATIC_H
#define ARBOR_SERVER_STATIC_H

#include <stdbool.h>

/* The real path of the file the URL path `path` names under the folder
 * web_dir (a directory names its index.html), in out (PATH_MAX bytes);
 * false when it names nothing inside that folder. A true answer always lies
 * inside web_dir's real path, whatever ".." or symbolic links path holds. */
bool static_resolve(const char *web_dir, const char *path, char *out);

#endif

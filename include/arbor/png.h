/*
 * png.h - encoding RGB8 images as PNG (libpng), to a file or to memory, and
 * decoding them back (the frames a daemon answers, for the client that
 * assembles regions into one image).
 *
 * Tuned for frames that are encoded once and sent at once: zlib level 1 and
 * the single UP filter (on rendered frames about as small as level 2-3 with
 * SUB, in about half the time; all filters at level 6 took 4-5x longer),
 * which keep a 1024x768 frame's encoding far shorter than its rendering. libpng's errors and warnings never print: errors come
 * back as an arbor_err, warnings are dropped.
 *
 * Images are width * height * 3 bytes, rows top to bottom. The memory
 * encoder returns a malloc'd buffer the caller frees with free().
 */
#ifndef ARBOR_PNG_H
#define ARBOR_PNG_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "arbor/err.h"

/* Writes the image to path whole or not at all: through a temporary file
 * beside it, renamed over path once complete, so a failed write leaves
 * whatever was at path untouched (and removes only the temporary file). A
 * file that is replaced keeps its permissions; a symbolic link keeps
 * pointing where it did, at the new image. Something at path that is not a
 * regular file (/dev/stdout, a FIFO) is written in place and never removed. */
bool arbor_png_write_file(const char *path, const uint8_t *rgb, int width, int height, arbor_err *e);
bool arbor_png_encode(const uint8_t *rgb, int width, int height, uint8_t **out, size_t *out_len, arbor_err *e);
/* Decodes a PNG held in memory into RGB8 (*rgb malloc'd, width * height * 3
 * bytes; gray, palette, alpha and 16-bit images are converted, alpha
 * dropped). Images wider or taller than max_side are refused before any
 * pixel memory is allocated. */
bool arbor_png_decode(const uint8_t *data, size_t len, int max_side, uint8_t **rgb, int *width, int *height,
                      arbor_err *e);

#endif

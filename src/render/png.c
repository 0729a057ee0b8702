/*
 * png.c - RGB8 images to PNG with libpng, to a FILE or a growing memory
 * buffer (see include/arbor/png.h).
 *
 * libpng reports errors by calling an error handler that must not return;
 * ours copies the message into the encoder's arbor_err and longjmps back to
 * encode(). Everything encode() changes after setjmp and reads after a
 * longjmp lives in the heap-side `png_sink` / libpng's own structs, not in
 * locals, so no local needs to be volatile.
 */
#include <errno.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/png.h"

#define PNG_ZLIB_LEVEL 1

/* Where encoded bytes go: a FILE, or a buffer that grows by doubling. */
typedef struct {
    FILE *file;
    uint8_t *data;
    size_t len, cap;
    arbor_err *err;
} png_sink;

static void on_error(png_structp png, png_const_charp msg)
{
    png_sink *sink = png_get_error_ptr(png);
    arbor_fail(sink->err, ARBOR_ERR_IO, "png: %s", msg);
    png_longjmp(png, 1);
}

static void on_warning(png_structp png, png_const_charp msg)
{
    (void)png;
    (void)msg;
}

static void write_memory(png_structp png, png_bytep bytes, size_t n)
{
    png_sink *sink = png_get_io_ptr(png);
    if (sink->len + n > sink->cap) {
        size_t cap = sink->cap ? sink->cap : 64 * 1024;
        while (cap < sink->len + n)
            cap *= 2;
        uint8_t *grown = realloc(sink->data, cap);
        if (grown == NULL)
            png_error(png, "out of memory for the encoded image");
        sink->data = grown;
        sink->cap = cap;
    }
    memcpy(sink->data + sink->len, bytes, n);
    sink->len += n;
}

static void flush_memory(png_structp png)
{
    (void)png;
}

static bool encode(const uint8_t *rgb, int width, int height, png_sink *sink)
{
    if (width < 1 || height < 1 || rgb == NULL)
        return arbor_fail(sink->err, ARBOR_ERR_INVALID, "png: no image to encode (%dx%d)", width, height);
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, sink, on_error, on_warning);
    png_infop info = png != NULL ? png_create_info_struct(png) : NULL;
    if (info == NULL) {
        png_destroy_write_struct(&png, NULL);
        return arbor_fail(sink->err, ARBOR_ERR_NOMEM, "png: out of memory");
    }
    if (setjmp(png_jmpbuf(png))) {
        png_destroy_write_struct(&png, &info);
        return false;
    }
    if (sink->file != NULL)
        png_init_io(png, sink->file);
    else
        png_set_write_fn(png, sink, write_memory, flush_memory);
    png_set_compression_level(png, PNG_ZLIB_LEVEL);
    png_set_filter(png, PNG_FILTER_TYPE_BASE, PNG_FILTER_UP);
    png_set_IHDR(png, info, (png_uint_32)width, (png_uint_32)height, 8, PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    for (int y = 0; y < height; y++)
        png_write_row(png, rgb + (size_t)y * (size_t)width * 3);
    png_write_end(png, info);
    png_destroy_write_struct(&png, &info);
    return true;
}

bool arbor_png_write_file(const char *path, const uint8_t *rgb, int width, int height, arbor_err *e)
{
    FILE *f = fopen(path, "wb");
    if (f == NULL)
        return arbor_fail(e, ARBOR_ERR_IO, "%s: cannot create: %s", path, strerror(errno));
    png_sink sink = {f, NULL, 0, 0, e};
    bool ok = encode(rgb, width, height, &sink);
    if (fclose(f) != 0 && ok)
        ok = arbor_fail(e, ARBOR_ERR_IO, "%s: cannot write: %s", path, strerror(errno));
    if (!ok)
        remove(path);
    return ok;
}

bool arbor_png_encode(const uint8_t *rgb, int width, int height, uint8_t **out, size_t *out_len, arbor_err *e)
{
    png_sink sink = {NULL, NULL, 0, 0, e};
    if (!encode(rgb, width, height, &sink)) {
        free(sink.data);
        return false;
    }
    *out = sink.data;
    *out_len = sink.len;
    return true;
}

/*
 * png.c - RGB8 images to PNG with libpng, to a FILE or a growing memory
 * buffer, and PNG in memory back to RGB8 (see include/arbor/png.h).
 *
 * libpng reports errors by calling an error handler that must not return;
 * ours copies the message into the encoder's arbor_err and longjmps back to
 * encode(). Everything encode() changes after setjmp and reads after a
 * longjmp lives in the heap-side `png_sink` / libpng's own structs, not in
 * locals, so no local needs to be volatile.
 *
 * Files are written whole or not at all (arbor_file_out, sys.h), so a
 * failed write (a full disk) neither leaves a partial image nor removes a
 * file that was there before.
 */
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "arbor/png.h"
#include "arbor/sys.h"

#define PNG_ZLIB_LEVEL 1

/* Where encoded bytes go: a FILE, or a buffer that grows by doubling. */
typedef struct {
    FILE *file;
    uint8_t *data;
    size_t len, cap;
    arbor_err *err;
    bool oom;       /* an allocation failed: libpng's error is then NOMEM, not IO */
} png_sink;

static void on_error(png_structp png, png_const_charp msg)
{
    png_sink *sink = png_get_error_ptr(png);
    arbor_fail(sink->err, sink->oom ? ARBOR_ERR_NOMEM : ARBOR_ERR_IO, "png: %s", msg);
    png_longjmp(png, 1);
}

/* libpng's and its zlib stream's allocations, so that running out of
 * memory is told apart from a failed write. */
static png_voidp png_alloc(png_structp png, png_alloc_size_t n)
{
    void *p = malloc(n);
    if (p == NULL)
        ((png_sink *)png_get_mem_ptr(png))->oom = true;
    return p;
}

static void png_free_mem(png_structp png, png_voidp p)
{
    (void)png;
    free(p);
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
        if (grown == NULL) {
            sink->oom = true;
            png_error(png, "out of memory for the encoded image");
        }
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
    png_structp png = png_create_write_struct_2(PNG_LIBPNG_VER_STRING, sink, on_error, on_warning, sink, png_alloc,
                                                png_free_mem);
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

/* A libpng failure to write shows up in the stream's error flag (libpng
 * then reports only "Write Error"), so the file's close gives the system's
 * reason (arbor_file_out_close). */
bool arbor_png_write_file(const char *path, const uint8_t *rgb, int width, int height, arbor_err *e)
{
    arbor_file_out out;
    if (!arbor_file_out_open(&out, path, e))
        return false;
    png_sink sink = {out.f, NULL, 0, 0, e, false};
    bool encoded = encode(rgb, width, height, &sink);
    return arbor_file_out_close(&out, encoded, e) && encoded;
}

bool arbor_png_encode(const uint8_t *rgb, int width, int height, uint8_t **out, size_t *out_len, arbor_err *e)
{
    png_sink sink = {NULL, NULL, 0, 0, e, false};
    if (!encode(rgb, width, height, &sink)) {
        free(sink.data);
        return false;
    }
    *out = sink.data;
    *out_len = sink.len;
    return true;
}

/* Decoding goes through libpng's simplified API, which converts every
 * colour type and depth to the one format asked for and reports errors in
 * the image's message rather than by longjmp. */
bool arbor_png_decode(const uint8_t *data, size_t len, int max_side, uint8_t **rgb, int *width, int *height,
                      arbor_err *e)
{
    png_image img;
    memset(&img, 0, sizeof img);
    img.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_memory(&img, data, len))
        return arbor_fail(e, ARBOR_ERR_PARSE, "png: %s", img.message);
    if (img.width < 1 || img.height < 1 || img.width > (png_uint_32)max_side || img.height > (png_uint_32)max_side) {
        png_image_free(&img);
        return arbor_fail(e, ARBOR_ERR_PARSE, "png: a %ux%u image is over the limit of %d pixels a side",
                          (unsigned)img.width, (unsigned)img.height, max_side);
    }
    img.format = PNG_FORMAT_RGB;
    uint8_t *out = malloc(PNG_IMAGE_SIZE(img));
    if (out == NULL) {
        png_image_free(&img);
        return arbor_fail(e, ARBOR_ERR_NOMEM, "png: out of memory for a %ux%u image", (unsigned)img.width,
                          (unsigned)img.height);
    }
    if (!png_image_finish_read(&img, NULL, out, 0, NULL)) {
        free(out);
        return arbor_fail(e, ARBOR_ERR_PARSE, "png: %s", img.message);
    }
    *rgb = out;
    *width = (int)img.width;
    *height = (int)img.height;
    return true;
}

/*
 * test_png.c - PNG encoding: images read back by libpng (from memory and
 * from a file) have the size and the pixels written; errors come back as
 * arbor_err.
 */
#include <png.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "arbor/png.h"
#include "support.h"
#include "unity.h"

void setUp(void) {}
void tearDown(void) {}

/* A test card: gradients plus noise, so every filter and zlib path matters. */
static uint8_t *test_card(int w, int h)
{
    uint8_t *rgb = malloc((size_t)w * h * 3);
    test_rng g;
    test_rng_seed(&g, 7);
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            uint8_t *p = rgb + 3 * ((size_t)y * w + x);
            p[0] = (uint8_t)(x * 255 / (w > 1 ? w - 1 : 1));
            p[1] = (uint8_t)(y * 255 / (h > 1 ? h - 1 : 1));
            p[2] = (uint8_t)(test_rng_u32(&g) & 0xff);
        }
    return rgb;
}

/* Decodes with libpng's simplified API; NULL when libpng refuses. */
static uint8_t *decode(png_image *img)
{
    img->format = PNG_FORMAT_RGB;
    uint8_t *out = malloc(PNG_IMAGE_SIZE(*img));
    if (!png_image_finish_read(img, NULL, out, 0, NULL)) {
        free(out);
        return NULL;
    }
    return out;
}

static void test_memory_round_trip(void)
{
    const int w = 37, h = 23;
    uint8_t *rgb = test_card(w, h), *png = NULL;
    size_t len = 0;
    arbor_err e;
    TEST_ASSERT_TRUE(arbor_png_encode(rgb, w, h, &png, &len, &e));
    TEST_ASSERT_TRUE(len > 8);
    TEST_ASSERT_EQUAL_MEMORY("\x89PNG\r\n\x1a\n", png, 8);
    png_image img;
    memset(&img, 0, sizeof img);
    img.version = PNG_IMAGE_VERSION;
    TEST_ASSERT_TRUE(png_image_begin_read_from_memory(&img, png, len));
    TEST_ASSERT_EQUAL_UINT32(w, img.width);
    TEST_ASSERT_EQUAL_UINT32(h, img.height);
    uint8_t *back = decode(&img);
    TEST_ASSERT_NOT_NULL(back);
    TEST_ASSERT_EQUAL_MEMORY(rgb, back, (size_t)w * h * 3);
    free(back);
    free(png);
    free(rgb);
}

static void test_file_round_trip_and_one_pixel(void)
{
    char path[] = "/tmp/arbor_test_png_XXXXXX";
    int fd = mkstemp(path);
    TEST_ASSERT_TRUE(fd >= 0);
    close(fd);
    const int sizes[2][2] = {{1, 1}, {300, 200}};
    for (int k = 0; k < 2; k++) {
        int w = sizes[k][0], h = sizes[k][1];
        uint8_t *rgb = test_card(w, h);
        arbor_err e;
        TEST_ASSERT_TRUE(arbor_png_write_file(path, rgb, w, h, &e));
        png_image img;
        memset(&img, 0, sizeof img);
        img.version = PNG_IMAGE_VERSION;
        TEST_ASSERT_TRUE(png_image_begin_read_from_file(&img, path));
        TEST_ASSERT_EQUAL_UINT32(w, img.width);
        TEST_ASSERT_EQUAL_UINT32(h, img.height);
        uint8_t *back = decode(&img);
        TEST_ASSERT_NOT_NULL(back);
        TEST_ASSERT_EQUAL_MEMORY(rgb, back, (size_t)w * h * 3);
        free(back);
        free(rgb);
    }
    unlink(path);
}

static void test_errors_are_reported_not_printed(void)
{
    uint8_t px[3] = {1, 2, 3}, *png = NULL;
    size_t len;
    arbor_err e;
    TEST_ASSERT_FALSE(arbor_png_write_file("/nonexistent-dir/x.png", px, 1, 1, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_IO, e.status);
    TEST_ASSERT_NOT_NULL(strstr(e.msg, "/nonexistent-dir/x.png"));
    TEST_ASSERT_FALSE(arbor_png_encode(px, 0, 1, &png, &len, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_INVALID, e.status);
    /* libpng itself refuses a width beyond its limits: the error comes back through longjmp */
    TEST_ASSERT_FALSE(arbor_png_encode(px, 0x7fffffff, 1, &png, &len, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_IO, e.status);
    TEST_ASSERT_NOT_NULL(strstr(e.msg, "png:"));
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_memory_round_trip);
    RUN_TEST(test_file_round_trip_and_one_pixel);
    RUN_TEST(test_errors_are_reported_not_printed);
    return UNITY_END();
}

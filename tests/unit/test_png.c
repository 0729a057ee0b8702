/*
 * test_png.c - PNG encoding: images read back by libpng (from memory and
 * from a file) have the size and the pixels written; errors come back as
 * arbor_err; a file is replaced whole or not at all (what was there before
 * survives a failed write, nothing but the image is left behind), keeping
 * its permissions and symbolic links, and devices are written in place,
 * never removed. arbor_png_decode gives back exactly the pixels encoded,
 * and refuses what is not a PNG or is larger than asked.
 */
#include <dirent.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
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

/* A scratch folder per test. */
static char scratch[64];

static const char *in_scratch(const char *name)
{
    static char path[128];
    snprintf(path, sizeof path, "%s/%s", scratch, name);
    return path;
}

static void make_scratch(void)
{
    snprintf(scratch, sizeof scratch, "/tmp/arbor_test_png_XXXXXX");
    TEST_ASSERT_NOT_NULL(mkdtemp(scratch));
}

/* Entries in the scratch folder besides . and .. */
static int scratch_entries(void)
{
    DIR *d = opendir(scratch);
    TEST_ASSERT_NOT_NULL(d);
    int n = 0;
    for (struct dirent *ent; (ent = readdir(d)) != NULL;)
        n += strcmp(ent->d_name, ".") != 0 && strcmp(ent->d_name, "..") != 0;
    closedir(d);
    return n;
}

static void remove_scratch(const char *const *names, int n)
{
    for (int i = 0; i < n; i++)
        unlink(in_scratch(names[i]));
    TEST_ASSERT_EQUAL_INT(0, rmdir(scratch));
}

static void write_text_file(const char *path, const char *text)
{
    FILE *f = fopen(path, "w");
    TEST_ASSERT_NOT_NULL(f);
    fputs(text, f);
    TEST_ASSERT_EQUAL_INT(0, fclose(f));
}

static void assert_file_holds(const char *path, const char *text)
{
    char buf[64] = "";
    FILE *f = fopen(path, "r");
    TEST_ASSERT_NOT_NULL(f);
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    buf[n] = '\0';
    fclose(f);
    TEST_ASSERT_EQUAL_STRING(text, buf);
}

static void assert_is_png(const char *path)
{
    png_image img;
    memset(&img, 0, sizeof img);
    img.version = PNG_IMAGE_VERSION;
    TEST_ASSERT_TRUE(png_image_begin_read_from_file(&img, path));
    png_image_free(&img);
}

static void test_a_failed_write_leaves_what_was_there(void)
{
    make_scratch();
    const char *path = in_scratch("old.png");
    write_text_file(path, "keep me");
    uint8_t px[3] = {1, 2, 3};
    arbor_err e;
    /* both failures come after the temporary file exists: ours, and libpng's */
    TEST_ASSERT_FALSE(arbor_png_write_file(path, px, 0, 1, &e));
    TEST_ASSERT_FALSE(arbor_png_write_file(path, px, 0x7fffffff, 1, &e));
    TEST_ASSERT_EQUAL_INT(ARBOR_ERR_IO, e.status);
    assert_file_holds(path, "keep me");
    TEST_ASSERT_EQUAL_INT(1, scratch_entries());
    const char *names[] = {"old.png"};
    remove_scratch(names, 1);
}

static void test_a_device_is_written_in_place_and_never_removed(void)
{
    uint8_t *rgb = test_card(64, 64);
    arbor_err e;
    struct stat st;
    TEST_ASSERT_TRUE_MESSAGE(arbor_png_write_file("/dev/null", rgb, 64, 64, &e), e.msg);
    TEST_ASSERT_EQUAL_INT(0, stat("/dev/null", &st));
    TEST_ASSERT_TRUE(S_ISCHR(st.st_mode));
    if (stat("/dev/full", &st) == 0) {
        TEST_ASSERT_FALSE(arbor_png_write_file("/dev/full", rgb, 64, 64, &e));
        TEST_ASSERT_EQUAL_INT(ARBOR_ERR_IO, e.status);
        TEST_ASSERT_NOT_NULL(strstr(e.msg, "/dev/full: cannot write"));
        TEST_ASSERT_EQUAL_INT(0, stat("/dev/full", &st));
        TEST_ASSERT_TRUE(S_ISCHR(st.st_mode));
    }
    free(rgb);
}

static void test_replacing_keeps_permissions_and_links(void)
{
    make_scratch();
    uint8_t *rgb = test_card(8, 8);
    arbor_err e;
    struct stat st;
    mode_t old_mask = umask(022);
    TEST_ASSERT_TRUE_MESSAGE(arbor_png_write_file(in_scratch("new.png"), rgb, 8, 8, &e), e.msg);
    TEST_ASSERT_EQUAL_INT(0, stat(in_scratch("new.png"), &st));
    TEST_ASSERT_EQUAL_INT(0644, st.st_mode & 07777);
    umask(old_mask);

    write_text_file(in_scratch("old.png"), "old");
    TEST_ASSERT_EQUAL_INT(0, chmod(in_scratch("old.png"), 0640));
    TEST_ASSERT_TRUE_MESSAGE(arbor_png_write_file(in_scratch("old.png"), rgb, 8, 8, &e), e.msg);
    assert_is_png(in_scratch("old.png"));
    TEST_ASSERT_EQUAL_INT(0, stat(in_scratch("old.png"), &st));
    TEST_ASSERT_EQUAL_INT(0640, st.st_mode & 07777);

    char target[128];
    snprintf(target, sizeof target, "%s", in_scratch("target.png"));
    write_text_file(target, "old");
    TEST_ASSERT_EQUAL_INT(0, symlink("target.png", in_scratch("link.png")));
    TEST_ASSERT_TRUE_MESSAGE(arbor_png_write_file(in_scratch("link.png"), rgb, 8, 8, &e), e.msg);
    TEST_ASSERT_EQUAL_INT(0, lstat(in_scratch("link.png"), &st));
    TEST_ASSERT_TRUE(S_ISLNK(st.st_mode));
    assert_is_png(target);
    TEST_ASSERT_EQUAL_INT(4, scratch_entries()); /* no temporary file left */
    free(rgb);
    const char *names[] = {"new.png", "old.png", "target.png", "link.png"};
    remove_scratch(names, 4);
}

static void test_decode_round_trips_and_refuses(void)
{
    const int w = 61, h = 17;
    uint8_t *rgb = test_card(w, h), *png = NULL, *back = NULL;
    size_t len = 0;
    int bw = 0, bh = 0;
    arbor_err e;
    TEST_ASSERT_TRUE(arbor_png_encode(rgb, w, h, &png, &len, &e));
    TEST_ASSERT_TRUE_MESSAGE(arbor_png_decode(png, len, 8192, &back, &bw, &bh, &e), e.msg);
    TEST_ASSERT_EQUAL_INT(w, bw);
    TEST_ASSERT_EQUAL_INT(h, bh);
    TEST_ASSERT_EQUAL_MEMORY(rgb, back, (size_t)w * h * 3);
    free(back);
    back = NULL;
    TEST_ASSERT_FALSE(arbor_png_decode(png, len, 60, &back, &bw, &bh, &e));
    TEST_ASSERT_NOT_NULL(strstr(e.msg, "61x17"));
    TEST_ASSERT_FALSE(arbor_png_decode(png, len / 2, 8192, &back, &bw, &bh, &e));
    TEST_ASSERT_FALSE(arbor_png_decode((const uint8_t *)"not a png at all", 16, 8192, &back, &bw, &bh, &e));
    TEST_ASSERT_NULL(back);
    free(png);
    free(rgb);
}

int main(void)
{
    UNITY_BEGIN();
    RUN_TEST(test_memory_round_trip);
    RUN_TEST(test_decode_round_trips_and_refuses);
    RUN_TEST(test_file_round_trip_and_one_pixel);
    RUN_TEST(test_errors_are_reported_not_printed);
    RUN_TEST(test_a_failed_write_leaves_what_was_there);
    RUN_TEST(test_a_device_is_written_in_place_and_never_removed);
    RUN_TEST(test_replacing_keeps_permissions_and_links);
    return UNITY_END();
}

/*
 * cmd_gen.c - arbord gen: write the procedural models as OBJ (+ MTL).
 *
 *   arbord gen --all [--size small|large] --dir DIR   every model's preset
 *   arbord gen MODEL [--level L] [--n N] -o FILE.obj  one model
 *
 * The small presets are the models committed in models/; the large ones (a
 * few million triangles each) go to DIR/<model>-large.obj and are not
 * committed. Each file written is reported with its triangles and bytes.
 */
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>

#include "arbor/procgen.h"
#include "cli.h"

static void format_params(arbor_gen_params p, char *buf, size_t size)
{
    int len = 0;
    buf[0] = '\0';
    if (p.level != ARBOR_GEN_UNSET)
        len = snprintf(buf, size, "--level %d", p.level);
    if (p.n != ARBOR_GEN_UNSET && len >= 0 && (size_t)len < size)
        snprintf(buf + len, size - (size_t)len, "%s--n %d", len > 0 ? " " : "", p.n);
}

static void usage(FILE *out)
{
    fprintf(out, "usage: arbord gen --all [--size small|large] --dir DIR\n"
                 "       arbord gen MODEL [--level L] [--n N] -o FILE.obj\n"
                 "models (small: the ones in models/; large: DIR/MODEL-large.obj):\n");
    for (int k = 0; k < ARBOR_GEN_COUNT; k++) {
        char small[64], large[64];
        format_params(arbor_gen_preset((arbor_gen_kind)k, false), small, sizeof small);
        format_params(arbor_gen_preset((arbor_gen_kind)k, true), large, sizeof large);
        fprintf(out, "  %-12s %s\n  %-12s small: %s; large: %s\n", arbor_gen_name((arbor_gen_kind)k),
                arbor_gen_summary((arbor_gen_kind)k), "", small, large);
    }
}

static long long file_bytes(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 ? (long long)st.st_size : -1;
}

/* Generates one model, writes it, and reports it. Returns the exit code:
 * 2 when the parameters do not suit the model, 1 when writing fails. */
static int write_model(arbor_gen_kind kind, arbor_gen_params params, const char *path)
{
    arbor_mesh mesh;
    arbor_err err;
    arbor_err_clear(&err);
    if (!arbor_gen(kind, params, &mesh, &err)) {
        fprintf(stderr, "arbord gen: %s\n", err.msg);
        arbor_mesh_free(&mesh);
        return err.status == ARBOR_ERR_INVALID ? 2 : 1;
    }
    /* the comment names the parameters in effect, given or preset */
    arbor_gen_params preset = arbor_gen_preset(kind, false);
    arbor_gen_params used = {params.level != ARBOR_GEN_UNSET ? params.level : preset.level,
                             params.n != ARBOR_GEN_UNSET ? params.n : preset.n};
    char args[64], comment[256];
    format_params(used, args, sizeof args);
    snprintf(comment, sizeof comment, "arbor's own procedural model (MIT): arbord gen %s %s", arbor_gen_name(kind),
             args);
    bool ok = arbor_write_obj(&mesh, path, comment, &err);
    if (!ok) {
        fprintf(stderr, "arbord gen: %s\n", err.msg);
    } else {
        char mtl[4096];
        long long mtl_bytes = arbor_obj_mtl_path(path, mtl, sizeof mtl) ? file_bytes(mtl) : -1;
        printf("wrote %s: %u triangles, %u vertices, %lld bytes", path, mesh.ntris, mesh.nverts, file_bytes(path));
        if (mesh.nmats > 1 && mtl_bytes >= 0)
            printf(" (+ %s, %lld bytes)", mtl, mtl_bytes);
        printf("\n");
    }
    arbor_mesh_free(&mesh);
    return ok ? 0 : 1;
}

static int write_all(const char *dir, bool large)
{
    for (int k = 0; k < ARBOR_GEN_COUNT; k++) {
        arbor_gen_kind kind = (arbor_gen_kind)k;
        char path[4096];
        int len = snprintf(path, sizeof path, "%s/%s%s.obj", dir, arbor_gen_name(kind), large ? "-large" : "");
        if (len < 0 || (size_t)len >= sizeof path) {
            fprintf(stderr, "arbord gen: directory name too long: %s\n", dir);
            return 2;
        }
        int status = write_model(kind, arbor_gen_preset(kind, large), path);
        if (status != 0)
            return status;
    }
    return 0;
}

typedef struct {
    bool all, large;
    const char *dir, *size, *model, *out;
    arbor_gen_params params;
} gen_args;

/* Reads argv into a; prints the problem and returns false on a usage error. */
static bool parse_args(int argc, char **argv, gen_args *a)
{
    cli_seen seen = {.n = 0};
    for (int i = 1; i < argc; i++) {
        const char *s = argv[i];
        const char **target = NULL;
        int *number = NULL;
        if (s[0] == '-' && !cli_first("gen", &seen, s))
            return false;
        if (strcmp(s, "--all") == 0) {
            a->all = true;
            continue;
        } else if (strcmp(s, "--dir") == 0) {
            target = &a->dir;
        } else if (strcmp(s, "--size") == 0) {
            target = &a->size;
        } else if (strcmp(s, "-o") == 0) {
            target = &a->out;
        } else if (strcmp(s, "--level") == 0) {
            number = &a->params.level;
        } else if (strcmp(s, "--n") == 0) {
            number = &a->params.n;
        } else if (s[0] == '-') {
            fprintf(stderr, "arbord gen: unknown option '%s'\n", s);
            return false;
        } else if (a->model != NULL) {
            fprintf(stderr, "arbord gen: one MODEL at a time ('%s' and '%s')\n", a->model, s);
            return false;
        } else {
            a->model = s;
            continue;
        }
        const char *value = cli_value("gen", argc, argv, &i);
        if (value == NULL)
            return false;
        if (target != NULL)
            *target = value;
        else if (!cli_int("gen", s, value, 0, 1000000, number))
            return false;
    }
    return true;
}

static bool check_all_args(gen_args *a)
{
    if (a->model != NULL || a->out != NULL || a->params.level != ARBOR_GEN_UNSET || a->params.n != ARBOR_GEN_UNSET) {
        fprintf(stderr, "arbord gen: --all writes the presets; MODEL, --level, --n and -o are for one model\n");
        return false;
    }
    if (a->dir == NULL) {
        fprintf(stderr, "arbord gen: --all needs --dir DIR\n");
        return false;
    }
    if (a->size != NULL && strcmp(a->size, "small") != 0 && strcmp(a->size, "large") != 0) {
        fprintf(stderr, "arbord gen: --size must be small or large, not '%s'\n", a->size);
        return false;
    }
    a->large = a->size != NULL && strcmp(a->size, "large") == 0;
    return true;
}

static bool check_one_args(const gen_args *a, arbor_gen_kind *kind)
{
    if (a->model == NULL) {
        fprintf(stderr, "arbord gen: name a MODEL, or --all\n");
        return false;
    }
    if (!arbor_gen_parse(a->model, kind)) {
        fprintf(stderr, "arbord gen: unknown model '%s' (", a->model);
        for (int k = 0; k < ARBOR_GEN_COUNT; k++)
            fprintf(stderr, "%s%s", k ? ", " : "", arbor_gen_name((arbor_gen_kind)k));
        fprintf(stderr, ")\n");
        return false;
    }
    if (a->dir != NULL || a->size != NULL) {
        fprintf(stderr, "arbord gen: --dir and --size go with --all; one model takes -o FILE.obj\n");
        return false;
    }
    if (a->out == NULL) {
        fprintf(stderr, "arbord gen: -o FILE.obj is required\n");
        return false;
    }
    /* ".obj" in lower case, as the daemon's folder scan takes it, and as
     * arbor_obj_mtl_path replaces it to name the material library beside */
    size_t n = strlen(a->out);
    if (n < 4 || strcmp(a->out + n - 4, ".obj") != 0) {
        fprintf(stderr, "arbord gen: -o %s: the model is written as OBJ, so its name must end in .obj\n", a->out);
        return false;
    }
    return true;
}

int cmd_gen(int argc, char **argv)
{
    for (int i = 1; i < argc; i++)
        if (strcmp(argv[i], "--help") == 0 || strcmp(argv[i], "-h") == 0) {
            usage(stdout);
            return 0;
        }
    gen_args a = {.params = {ARBOR_GEN_UNSET, ARBOR_GEN_UNSET}};
    if (!parse_args(argc, argv, &a)) {
        usage(stderr);
        return 2;
    }
    if (a.all) {
        if (!check_all_args(&a)) {
            usage(stderr);
            return 2;
        }
        return write_all(a.dir, a.large);
    }
    arbor_gen_kind kind;
    if (!check_one_args(&a, &kind)) {
        usage(stderr);
        return 2;
    }
    return write_model(kind, a.params, a.out);
}

/*
 * main.c - arbord's entry point: dispatches to the subcommands
 * serve | render | stats | bench | gen, and checks that what they printed
 * was written.
 */
#include <errno.h>
#include <stdbool.h>
#include <stdio.h>
#include <string.h>

#include "cli.h"

static const struct {
    const char *name;
    int (*run)(int argc, char **argv);
    const char *summary;
} commands[] = {
    {"serve", cmd_serve, "run the render daemon (HTTP/JSON and the viewer)"},
    {"render", cmd_render, "render one frame of a model to a PNG"},
    {"stats", cmd_stats, "build trees over a model and print their statistics"},
    {"bench", cmd_bench, "the study's tables and PROTOCOL.md's ray sets, optionally beside Embree"},
    {"gen", cmd_gen, "write the procedural models (Cornell box, Menger sponge, ...)"},
};

static void usage(FILE *out)
{
    fprintf(out, "usage: arbord COMMAND [options]   (arbord COMMAND --help for its options)\n\ncommands:\n");
    for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
        fprintf(out, "  %-7s %s\n", commands[i].name, commands[i].summary);
}

static int run(int argc, char **argv)
{
    if (argc < 2) {
        usage(stderr);
        return 2;
    }
    if (strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0 || strcmp(argv[1], "help") == 0) {
        usage(stdout);
        return 0;
    }
    for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
        if (strcmp(argv[1], commands[i].name) == 0)
            return commands[i].run(argc - 1, argv + 1);
    fprintf(stderr, "arbord: unknown command '%s'\n", argv[1]);
    usage(stderr);
    return 2;
}

/* stdout is buffered, so a write that failed (a full disk, /dev/full, a
 * closed terminal) may show only in the stream's error flag or at the final
 * flush and close: checked here once for every command, which then fails
 * even if its work succeeded, since its results were lost. */
static int check_output(const char *cmd, int status)
{
    bool failed = ferror(stdout) != 0;
    int err = 0;
    if (fflush(stdout) != 0) {
        failed = true;
        err = errno;
    }
    if (fclose(stdout) != 0 && !failed) {
        failed = true;
        err = errno;
    }
    if (!failed)
        return status;
    char reason[128] = "write error";
    if (err != 0 && strerror_r(err, reason, sizeof reason) != 0)
        snprintf(reason, sizeof reason, "error %d", err);
    fprintf(stderr, "arbord%s%s: cannot write to standard output: %s\n", cmd ? " " : "", cmd ? cmd : "", reason);
    return status != 0 ? status : 1;
}

int main(int argc, char **argv)
{
    int status = run(argc, argv);
    return check_output(argc >= 2 && argv[1][0] != '-' ? argv[1] : NULL, status);
}

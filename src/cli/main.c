/*
 * main.c - arbord's entry point: dispatches to the subcommands
 * serve | render | stats | bench | gen.
 */
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

int main(int argc, char **argv)
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

/* cmd_render.c - arbord render (not written yet). */
#include <stdio.h>

#include "cli.h"

int cmd_render(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "arbord render: not implemented yet\n");
    return 1;
}

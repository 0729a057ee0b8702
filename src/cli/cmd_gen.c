/* cmd_gen.c - arbord gen (not written yet). */
#include <stdio.h>

#include "cli.h"

int cmd_gen(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "arbord gen: not implemented yet\n");
    return 1;
}

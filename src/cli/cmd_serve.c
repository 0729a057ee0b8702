/* cmd_serve.c - arbord serve (not written yet). */
#include <stdio.h>

#include "cli.h"

int cmd_serve(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    fprintf(stderr, "arbord serve: not implemented yet\n");
    return 1;
}

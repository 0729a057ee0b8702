/* args.c - argument helpers shared by the arbord subcommands (see cli.h). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "arbor/sys.h"
#include "cli.h"

const char *cli_value(const char *cmd, int argc, char **argv, int *i)
{
    if (*i + 1 >= argc) {
        fprintf(stderr, "arbord %s: %s needs a value\n", cmd, argv[*i]);
        return NULL;
    }
    *i += 1;
    return argv[*i];
}

bool cli_first(const char *cmd, cli_seen *seen, const char *opt)
{
    const char *name = strcmp(opt, "-o") == 0 ? "--output" : opt;
    for (int k = 0; k < seen->n; k++)
        if (strcmp(seen->name[k], name) == 0) {
            fprintf(stderr, "arbord %s: %s given twice; it takes one\n", cmd, opt);
            return false;
        }
    if (seen->n < CLI_SEEN_MAX)
        seen->name[seen->n++] = name;
    return true;
}

bool cli_print_json(cJSON *o)
{
    char *text = o != NULL ? cJSON_PrintUnformatted(o) : NULL;
    if (text != NULL) {
        arbor_utf8_repair(text, strlen(text)); /* a model's file name may be any bytes */
        puts(text);
    }
    free(text);
    cJSON_Delete(o);
    return text != NULL;
}

bool cli_int(const char *cmd, const char *opt, const char *s, long lo, long hi, int *out)
{
    char *end;
    errno = 0;
    long v = strtol(s, &end, 10);
    if (errno != 0 || end == s || *end != '\0' || v < lo || v > hi) {
        fprintf(stderr, "arbord %s: %s must be a whole number in %ld..%ld, not '%s'\n", cmd, opt, lo, hi, s);
        return false;
    }
    *out = (int)v;
    return true;
}

bool cli_ends_with(const char *path, const char *ext)
{
    size_t n = strlen(path), k = strlen(ext);
    return n >= k && strcasecmp(path + n - k, ext) == 0;
}

bool cli_u64(const char *cmd, const char *opt, const char *s, uint64_t hi, uint64_t *out)
{
    char *end;
    errno = 0;
    unsigned long long v = strtoull(s, &end, 10);
    if (errno != 0 || end == s || *end != '\0' || s[strspn(s, " \t")] == '-' || v > hi) {
        fprintf(stderr, "arbord %s: %s must be a whole number in 0..%llu, not '%s'\n", cmd, opt,
                (unsigned long long)hi, s);
        return false;
    }
    *out = v;
    return true;
}

bool cli_number(const char *cmd, const char *opt, const char *s, double lo, double hi, double *out)
{
    char *end;
    errno = 0;
    double v = strtod(s, &end);
    if (errno != 0 || end == s || *end != '\0' || !isfinite(v) || v < lo || v > hi) {
        fprintf(stderr, "arbord %s: %s must be a number in %g..%g, not '%s'\n", cmd, opt, lo, hi, s);
        return false;
    }
    *out = v;
    return true;
}

/*
 * cli.h - the arbord subcommands and the small argument helpers they share.
 * Each subcommand lives in its own cmd_*.c and returns the process exit code
 * (0 ok, 1 failure, 2 usage error). Only this layer prints.
 */
#ifndef ARBOR_CLI_H
#define ARBOR_CLI_H

#include <cjson/cJSON.h>
#include <stdbool.h>
#include <stdint.h>

int cmd_serve(int argc, char **argv);
int cmd_render(int argc, char **argv);
int cmd_stats(int argc, char **argv);
int cmd_bench(int argc, char **argv);
int cmd_gen(int argc, char **argv);

/* remote_render.c: the frame `request` describes (a render request's
 * fields, less region), rendered by the daemon or load balancer at url as
 * nregions horizontal strips asked for over nconn keep-alive connections at
 * once, assembled and written to out as PNG. Prints a summary; returns the
 * exit code. */
int remote_render(const char *url, const cJSON *request, int width, int height, int nregions, int nconn,
                  const char *out);

/* argv[*i] is an option that takes a value: returns argv[*i + 1] and advances
 * *i, or prints "arbord CMD: OPT needs a value" and returns NULL. */
const char *cli_value(const char *cmd, int argc, char **argv, int *i);
/* The options of one command line seen so far: each is taken once (but
 * the few a command lets repeat, bench's --model, serve's --models), so
 * that a second value is an error rather than silently the one that wins. */
#define CLI_SEEN_MAX 64
typedef struct {
    const char *name[CLI_SEEN_MAX];
    int n;
} cli_seen;
/* Records option opt (-o as --output); prints "arbord CMD: OPT given twice;
 * it takes one" and returns false when it was seen before. */
bool cli_first(const char *cmd, cli_seen *seen, const char *opt);
/* Prints o (a report.h object, or NULL when making it ran out of memory) on
 * one line of stdout and frees it; false for NULL or out of memory. */
bool cli_print_json(cJSON *o);
/* Parse a whole number / a finite number in [lo, hi]; prints the error. */
bool cli_int(const char *cmd, const char *opt, const char *s, long lo, long hi, int *out);
bool cli_number(const char *cmd, const char *opt, const char *s, double lo, double hi, double *out);
/* Whether path ends in ext (".png"), in any case. */
bool cli_ends_with(const char *path, const char *ext);
/* Parse a whole number in [0, hi], beyond an int's range; prints the error. */
bool cli_u64(const char *cmd, const char *opt, const char *s, uint64_t hi, uint64_t *out);

#endif

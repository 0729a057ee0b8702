/*
 * textio.c - what the model loaders share for reading text: whole files into
 * memory (plain or through zlib), a line cursor, and the number parsers,
 * which are hand-written because per-field sscanf/strtod would make OBJ
 * parsing several times slower (see src/geom/loader.h).
 */
#include <errno.h>
#include <float.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <zlib.h>

#include "arbor/load.h"
#include "loader.h"

/* ---- whole files ---- */

/* Only regular files: a FIFO or a device could block or never end. */
static bool check_regular(const char *path, struct stat *st, arbor_err *e)
{
    if (stat(path, st) != 0)
        return arbor_fail_errno(e, path, "cannot open", errno);
    if (!S_ISREG(st->st_mode))
        return arbor_fail(e, ARBOR_ERR_IO, "%s: not a regular file", path);
    return true;
}

static bool read_plain(const char *path, size_t size, char **data, size_t *len, arbor_err *e)
{
    FILE *f = fopen(path, "rb");
    if (f == NULL)
        return arbor_fail_errno(e, path, "cannot open", errno);
    char *buf = malloc(size ? size : 1);
    if (buf == NULL) {
        fclose(f);
        return arbor_fail(e, ARBOR_ERR_NOMEM, "%s: out of memory reading %zu bytes", path, size);
    }
    size_t got = fread(buf, 1, size, f);
    bool short_read = got != size || ferror(f);
    fclose(f);
    if (short_read) {
        free(buf);
        return arbor_fail(e, ARBOR_ERR_IO, "%s: read %zu of %zu bytes", path, got, size);
    }
    *data = buf;
    *len = size;
    return true;
}

/* Decompresses in growing chunks, at most max_bytes: reading one byte more
 * than that tells a stream that is too long from one that fits exactly.
 * zlib reports a stream cut short only through gzerror / gzclose (gzread
 * just returns what it had), so both are checked: a truncated file must
 * fail, not load partially. */
static bool read_gz(const char *path, size_t max_bytes, char **data, size_t *len, arbor_err *e)
{
    gzFile f = gzopen(path, "rb");
    if (f == NULL)
        return arbor_fail_errno(e, path, "cannot open", errno ? errno : ENOMEM);
    gzbuffer(f, 1u << 17);
    size_t cap = 1u << 20, n = 0;
    char *buf = malloc(cap);
    bool ok = buf != NULL;
    while (ok && n <= max_bytes) {
        if (n == cap) {
            char *bigger = cap <= SIZE_MAX / 2 ? realloc(buf, cap * 2) : NULL;
            if (bigger == NULL) {
                ok = false;
                break;
            }
            buf = bigger;
            cap *= 2;
        }
        size_t want = cap - n < (1u << 30) ? cap - n : (1u << 30);
        if (want - 1 > max_bytes - n) /* want > max_bytes - n + 1, without overflow */
            want = max_bytes - n + 1;
        int got = gzread(f, buf + n, (unsigned)want);
        if (got <= 0)
            break;
        n += (size_t)got;
    }
    int zerr = Z_OK;
    const char *zmsg = gzerror(f, &zerr);
    char reason[160];
    snprintf(reason, sizeof reason, "%s", zmsg ? zmsg : "");
    int close_rc = gzclose(f);
    if (ok && n > max_bytes) {
        free(buf);
        return arbor_fail(e, ARBOR_ERR_IO, "%s: decompresses to more than the limit of %zu bytes", path, max_bytes);
    }
    if (!ok || zerr == Z_MEM_ERROR) {
        free(buf);
        return arbor_fail(e, ARBOR_ERR_NOMEM, "%s: out of memory decompressing (%zu bytes so far)", path, n);
    }
    if (zerr != Z_OK || close_rc != Z_OK) {
        free(buf);
        return arbor_fail(e, ARBOR_ERR_IO, "%s: truncated or corrupt gzip data after %zu bytes (%s)", path, n,
                          zerr != Z_OK ? reason : "unexpected end of file");
    }
    *data = buf;
    *len = n;
    return true;
}

bool loader_read_file(const char *path, bool gz, size_t max_bytes, char **data, size_t *len, arbor_err *e)
{
    struct stat st;
    if (!check_regular(path, &st, e))
        return false;
    if (gz)
        return read_gz(path, max_bytes, data, len, e);
    if ((uint64_t)st.st_size > max_bytes)
        return arbor_fail(e, ARBOR_ERR_IO, "%s: %lld bytes, more than the limit of %zu bytes", path,
                          (long long)st.st_size, max_bytes);
    return read_plain(path, (size_t)st.st_size, data, len, e);
}

bool loader_finish(bool ok, arbor_mesh *m, const char *name, arbor_err *e)
{
    if (ok && m->ntris == 0)
        ok = arbor_fail(e, ARBOR_ERR_PARSE, "%s: no triangles", name);
    if (ok)
        ok = arbor_mesh_finish(m, e);
    if (!ok)
        arbor_mesh_free(m);
    return ok;
}

/* ---- the cursor ---- */

void text_cursor_init(text_cursor *c, const char *text, size_t len, const char *name)
{
    c->p = text;
    c->end = text + len;
    c->name = name;
    c->line = 1;
}

void text_next_line(text_cursor *c)
{
    const char *nl = c->p < c->end && *c->p == '\n' ? c->p : memchr(c->p, '\n', (size_t)(c->end - c->p));
    if (nl == NULL) {
        c->p = c->end;
        return;
    }
    c->p = nl + 1;
    c->line++;
}

size_t text_word(text_cursor *c, const char **w)
{
    text_skip_blanks(c);
    const char *start = c->p;
    while (c->p < c->end && !text_is_blank(*c->p) && *c->p != '\n')
        c->p++;
    *w = start;
    return (size_t)(c->p - start);
}

bool text_word_is(const char *w, size_t n, const char *s)
{
    return strlen(s) == n && memcmp(w, s, n) == 0;
}

bool text_fail(const text_cursor *c, arbor_err *e, const char *fmt, ...)
{
    char msg[400];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    return arbor_fail(e, ARBOR_ERR_PARSE, "%s:%u: %s", c->name, c->line, msg);
}

void text_excerpt(char *buf, size_t size, const char *p, const char *end)
{
    const size_t keep = size - 4; /* room for "..." and the NUL */
    size_t n = 0;
    while (p < end && !text_is_blank(*p) && *p != '\n' && n < keep) {
        unsigned char ch = (unsigned char)*p++;
        buf[n++] = ch >= 0x20 && ch < 0x7f ? (char)ch : '?';
    }
    if (p < end && !text_is_blank(*p) && *p != '\n') {
        memcpy(buf + n, "...", 3);
        n += 3;
    }
    buf[n] = '\0';
}

/* ---- numbers ---- */

static inline bool is_digit(char ch)
{
    return (unsigned)(ch - '0') < 10u;
}

const char *text_parse_int(const char *p, const char *end, int64_t *out)
{
    bool neg = false;
    if (p < end && (*p == '+' || *p == '-'))
        neg = *p++ == '-';
    if (p == end || !is_digit(*p))
        return NULL;
    int64_t v = 0;
    for (; p < end && is_digit(*p); p++)
        if (v <= 100000000000000000LL)
            v = v * 10 + (*p - '0');
    *out = neg ? -v : v;
    return p;
}

/* Every power of ten up to 1e22 is exact in a double (5^22 < 2^53). */
static const double exact_pow10[] = {
    1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
    1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
};

/* Case-insensitive match of the literal s (lower case) at p. */
static const char *match_word(const char *p, const char *end, const char *s)
{
    for (; *s; s++, p++)
        if (p == end || (*p | 0x20) != *s)
            return NULL;
    return p;
}

static const char *parse_special(const char *p, const char *end, bool neg, float *out)
{
    const char *q;
    if ((q = match_word(p, end, "nan")) != NULL) {
        *out = neg ? -NAN : NAN;
        return q;
    }
    if ((q = match_word(p, end, "inf")) == NULL)
        return NULL;
    const char *longer = match_word(q, end, "inity");
    *out = neg ? -INFINITY : INFINITY;
    return longer ? longer : q;
}

/* A double whose bits below float precision are exactly one half: rounding
 * it to float may differ from rounding the decimal input directly. */
static bool is_float_midpoint(double v)
{
    uint64_t bits;
    memcpy(&bits, &v, sizeof bits);
    return (bits & ((1ull << 29) - 1)) == (1ull << 28);
}

/* Float midpoints (and the overflow and underflow thresholds) have at most
 * 113 significant decimal digits, so keeping 200 and marking any nonzero rest
 * with a final '1' keeps the input on the same side of every rounding
 * boundary: strtof on the short form rounds exactly as on the original. */
#define SLOW_DIGITS 200

/* The rare inputs the fast path cannot round exactly: strtof on a bounded
 * copy of the (already validated) number [p, end). */
static float parse_slow(const char *p, const char *end)
{
    char buf[SLOW_DIGITS + 32];
    size_t n = 0;
    if (*p == '-')
        buf[n++] = '-';
    if (*p == '+' || *p == '-')
        p++;
    int64_t exp10 = 0;
    int kept = 0;
    bool frac = false, rest_nonzero = false;
    for (; p < end && *p != 'e' && *p != 'E'; p++) {
        if (*p == '.') {
            frac = true;
        } else if (kept == 0 && *p == '0') {
            exp10 -= frac;
        } else if (kept < SLOW_DIGITS) {
            buf[n++] = *p;
            kept++;
            exp10 -= frac;
        } else {
            exp10 += !frac;
            rest_nonzero |= *p != '0';
        }
    }
    if (rest_nonzero) {
        buf[n++] = '1';
        exp10--;
    }
    if (kept == 0)
        buf[n++] = '0';
    if (p < end) {
        int64_t e;
        text_parse_int(p + 1, end, &e);
        exp10 += e;
    }
    /* past +-100000 every input here is 0 or infinite already */
    exp10 = exp10 > 100000 ? 100000 : exp10 < -100000 ? -100000 : exp10;
    snprintf(buf + n, sizeof buf - n, "e%lld", (long long)exp10);
    return strtof(buf, NULL);
}

/* Appends a decimal digit to the mantissa, unless it has 19 significant
 * digits already (leading zeros do not count). */
static inline bool take_digit(uint64_t *mant, int *ndigits, char digit)
{
    if (*ndigits == 19)
        return false;
    *mant = *mant * 10 + (uint64_t)(digit - '0');
    *ndigits += *mant != 0;
    return true;
}

const char *arbor_parse_float(const char *p, const char *end, float *out)
{
    const char *start = p;
    bool neg = false;
    if (p < end && (*p == '+' || *p == '-'))
        neg = *p++ == '-';
    if (p < end && !is_digit(*p) && *p != '.')
        return parse_special(p, end, neg, out);

    /* The significant digits go into mant with exp10 scaling them. Past 19
     * of them mant would overflow, and past 16 it may exceed 2^53 anyway,
     * so such numbers are left to the slow path. */
    uint64_t mant = 0;
    int ndigits = 0;
    int64_t exp10 = 0;
    bool any = false, too_long = false;
    for (; p < end && is_digit(*p); p++, any = true)
        too_long |= !take_digit(&mant, &ndigits, *p);
    if (p < end && *p == '.') {
        for (p++; p < end && is_digit(*p); p++, any = true) {
            too_long |= !take_digit(&mant, &ndigits, *p);
            exp10--;
        }
    }
    if (!any)
        return NULL;
    if (p < end && (*p == 'e' || *p == 'E')) {
        int64_t e;
        const char *q = text_parse_int(p + 1, end, &e);
        if (q != NULL) { /* else the number ends before the 'e', as in strtof */
            exp10 += e;
            p = q;
        }
    }

    if (mant == 0) {
        *out = neg ? -0.0f : 0.0f;
        return p;
    }
    /* Clinger's fast path: mant and 10^|exp10| are exact doubles, so one
     * multiply or divide rounds correctly to double; the rounding to float
     * then matches strtof unless the double sits on a float midpoint. */
    if (!too_long && mant <= (1ull << 53) && exp10 >= -22 && exp10 <= 22) {
        double v = (double)mant;
        v = exp10 < 0 ? v / exact_pow10[-exp10] : v * exact_pow10[exp10];
        if (v >= FLT_MIN && !is_float_midpoint(v)) {
            *out = (float)(neg ? -v : v);
            return p;
        }
    }
    *out = parse_slow(start, p);
    return p;
}

bool text_read_float(text_cursor *c, const char *what, float *out, arbor_err *e)
{
    if (text_at_eol(c))
        return text_fail(c, e, "missing %s", what);
    const char *q = arbor_parse_float(c->p, c->end, out);
    if (q == NULL || !text_is_delim(c, q)) {
        char word[40];
        text_excerpt(word, sizeof word, c->p, c->end);
        return text_fail(c, e, "malformed number '%s' (%s)", word, what);
    }
    if (isnan(*out))
        return text_fail(c, e, "NaN %s", what);
    if (isinf(*out)) {
        char word[40];
        text_excerpt(word, sizeof word, c->p, c->end);
        return text_fail(c, e, "infinite %s '%s'", what, word);
    }
    c->p = q;
    return true;
}

bool text_read_int(text_cursor *c, const char *what, int64_t lo, int64_t hi, int64_t *out, arbor_err *e)
{
    if (text_at_eol(c))
        return text_fail(c, e, "missing %s", what);
    const char *q = text_parse_int(c->p, c->end, out);
    if (q == NULL || !text_is_delim(c, q) || *out < lo || *out > hi) {
        char word[40];
        text_excerpt(word, sizeof word, c->p, c->end);
        if (q == NULL || !text_is_delim(c, q))
            return text_fail(c, e, "malformed integer '%s' (%s)", word, what);
        return text_fail(c, e, "%s %s out of range (%lld to %lld)", what, word, (long long)lo, (long long)hi);
    }
    c->p = q;
    return true;
}

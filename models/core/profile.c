/* profile.c -- the track profiles' CSV reader of models/plant/track.py (parse_profile_csv), with its
 * messages, and the file reading of harness/textio.py and fmu_src/adapter.py (profile.h).
 *
 * Python's pieces it reproduces, each in one function below:
 *   str.splitlines()     line_break()   every break Python knows, the Unicode ones included;
 *   str.strip()          strip()        Python's whitespace (str.isspace(), Unicode 14.0);
 *   float(str)           py_float()     CPython 3.11's PyFloat_FromString: Unicode digits and
 *                                       spaces to ASCII, '_' between digits, ASCII spaces
 *                                       stripped, then _Py_dg_strtod's grammar or inf/nan;
 *   f"{x}", :g           rc_repr(), put_g()
 *   str(pathlib.Path(p)) path_str()     POSIX.
 * The value of a number is strtod() of its digits with the decimal point moved into the exponent
 * ("12.5e3" is read as "125e2"), so the locale's decimal point plays no part; strtod and
 * Python's _Py_dg_strtod both round correctly, hence the same double.
 */
#include "rc_fp_contract.h"
#include "profile.h"

#include <errno.h>
#include <limits.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

/* stat()'s file kinds. glibc and mingw-w64 define these four even under -std=c99 (S_ISSOCK they
 * do not: a socket is "not a regular file" in both languages); MSVC has only the _S_IF* bits.
 * On Windows stat() reports a folder as S_IFDIR, a device such as NUL or CON as S_IFCHR and a
 * pipe as S_IFIFO, so the one rule (profile.h) holds there too; a file of 2 GiB or more makes a
 * 32-bit st_size stat() fail (EOVERFLOW), which refuses it as "cannot read". */
#if defined(_MSC_VER) && !defined(S_ISREG)
#define S_ISREG(m) (((m) & _S_IFMT) == _S_IFREG)
#define S_ISDIR(m) (((m) & _S_IFMT) == _S_IFDIR)
#define S_ISCHR(m) (((m) & _S_IFMT) == _S_IFCHR)
#define S_ISFIFO(m) (((m) & _S_IFMT) == _S_IFIFO)
#endif

/* ---- a growing message ------------------------------------------------------------------ */

typedef struct {
    char *s;
    size_t len, cap;
    int oom;
} msgbuf;

static void put(msgbuf *b, const char *p, size_t n)
{
    if (b->oom)
        return;
    if (b->len + n + 1 > b->cap) {
        size_t cap = b->cap ? b->cap : 128;
        while (b->len + n + 1 > cap)
            cap *= 2;
        char *s = realloc(b->s, cap);
        if (!s) {
            b->oom = 1;
            return;
        }
        b->s = s;
        b->cap = cap;
    }
    memcpy(b->s + b->len, p, n);
    b->len += n;
    b->s[b->len] = '\0';
}

static void puts_(msgbuf *b, const char *p) { put(b, p, strlen(p)); }

static void put_long(msgbuf *b, long x)
{
    char t[32];
    snprintf(t, sizeof t, "%ld", x);
    puts_(b, t);
}

static void put_size(msgbuf *b, size_t x)
{
    char t[32];
    snprintf(t, sizeof t, "%lu", (unsigned long)x);
    puts_(b, t);
}

static void put_repr(msgbuf *b, double x)          /* f"{x}" */
{
    char t[64];
    rc_repr(x, t, sizeof t);
    puts_(b, t);
}

void rc_profile_g(double x, char *buf, size_t size)      /* f"{x:g}" */
{
    char t[64];
    if (isnan(x)) {
        snprintf(buf, size, "nan");                 /* Python never writes "-nan" */
        return;
    }
    snprintf(t, sizeof t, "%g", x);
    /* C's %g is Python's :g (6 significant digits, e+XX), but with the locale's decimal point:
     * make it '.' */
    size_t i = 0, w = 0;
    int point = 0;
    for (; t[i]; i++) {
        char c = t[i];
        if ((c >= '0' && c <= '9') || c == 'e' || c == '+' || c == '-' || c == 'i' || c == 'n'
                || c == 'f') {
            t[w++] = c;
            point = 0;
        } else if (!point) {
            t[w++] = '.';
            point = 1;
        }
    }
    t[w] = '\0';
    snprintf(buf, size, "%s", t);
}

static void put_g(msgbuf *b, double x)             /* f"{x:g}" */
{
    char t[64];
    rc_profile_g(x, t, sizeof t);
    puts_(b, t);
}

/* The refusal: out->message takes the buffer, out->err a cut copy. */
static int refuse(rc_profile *out, msgbuf *b)
{
    if (b->oom || !b->s) {
        free(b->s);
        out->message = NULL;
        snprintf(out->err.msg, RC_MSG_SIZE, "out of memory");
        return RC_BAD_CONFIG;
    }
    out->message = b->s;
    out->message_len = b->len;
    size_t n = b->len;
    if (n > RC_MSG_SIZE - 1) {
        n = RC_MSG_SIZE - 1;
        while (n > 0 && ((unsigned char)b->s[n] & 0xC0) == 0x80)   /* not inside a character */
            n--;
    }
    memcpy(out->err.msg, b->s, n);
    out->err.msg[n] = '\0';
    return RC_BAD_CONFIG;
}

/* ---- UTF-8 and Python's character classes --------------------------------------------- */

/* The code point at s[i] (i < len) and its length in *n; a malformed byte is -1, length 1
 * (the text is taken to be UTF-8; anything else is read byte by byte and never crashes). */
static long u8_at(const unsigned char *s, size_t len, size_t i, size_t *n)
{
    unsigned c = s[i];
    size_t k;
    long cp;
    *n = 1;
    if (c < 0x80)
        return (long)c;
    if (c >= 0xC2 && c <= 0xDF) {
        k = 1;
        cp = c & 0x1F;
    } else if (c >= 0xE0 && c <= 0xEF) {
        k = 2;
        cp = c & 0x0F;
    } else if (c >= 0xF0 && c <= 0xF4) {
        k = 3;
        cp = c & 0x07;
    } else {
        return -1;
    }
    if (len - i <= k)
        return -1;
    for (size_t j = 1; j <= k; j++) {
        if ((s[i + j] & 0xC0) != 0x80)
            return -1;
        cp = (cp << 6) | (s[i + j] & 0x3F);
    }
    *n = k + 1;
    return cp;
}

/* The code point that ends at s[e] (b < e), its length in *n; malformed: -1, length 1. */
static long u8_before(const unsigned char *s, size_t b, size_t e, size_t *n)
{
    size_t k = e - 1;
    while (k > b && e - k < 4 && (s[k] & 0xC0) == 0x80)
        k--;
    size_t m;
    long cp = u8_at(s, e, k, &m);
    if (cp >= 0 && k + m == e) {
        *n = m;
        return cp;
    }
    *n = 1;
    return -1;
}

/* str.isspace() (Python 3.11, Unicode 14.0) */
static int py_space(long cp)
{
    if (cp < 0x80)
        return (cp >= 0x09 && cp <= 0x0D) || (cp >= 0x1C && cp <= 0x20);
    return cp == 0x85 || cp == 0xA0 || cp == 0x1680 || (cp >= 0x2000 && cp <= 0x200A)
           || cp == 0x2028 || cp == 0x2029 || cp == 0x202F || cp == 0x205F || cp == 0x3000;
}

/* The decimal digit value of a character (unicodedata.decimal, Unicode 14.0), or -1: the
 * decimal digits come in runs of ten from these zeros (tests/model_tests/core/test_core_profile.py checks the
 * table against the running Python's unicodedata). */
static const long DECIMAL_ZEROS[] = {
    0x30, 0x660, 0x6F0, 0x7C0, 0x966, 0x9E6, 0xA66, 0xAE6, 0xB66, 0xBE6, 0xC66, 0xCE6,
    0xD66, 0xDE6, 0xE50, 0xED0, 0xF20, 0x1040, 0x1090, 0x17E0, 0x1810, 0x1946, 0x19D0,
    0x1A80, 0x1A90, 0x1B50, 0x1BB0, 0x1C40, 0x1C50, 0xA620, 0xA8D0, 0xA900, 0xA9D0, 0xA9F0,
    0xAA50, 0xABF0, 0xFF10, 0x104A0, 0x10D30, 0x11066, 0x110F0, 0x11136, 0x111D0, 0x112F0,
    0x11450, 0x114D0, 0x11650, 0x116C0, 0x11730, 0x118E0, 0x11950, 0x11C50, 0x11D50,
    0x11DA0, 0x16A60, 0x16AC0, 0x16B50, 0x1D7CE, 0x1D7D8, 0x1D7E2, 0x1D7EC, 0x1D7F6,
    0x1E140, 0x1E2F0, 0x1E950, 0x1FBF0
};

static int py_decimal(long cp)
{
    for (size_t k = 0; k < sizeof DECIMAL_ZEROS / sizeof DECIMAL_ZEROS[0]; k++)
        if (cp >= DECIMAL_ZEROS[k] && cp < DECIMAL_ZEROS[k] + 10)
            return (int)(cp - DECIMAL_ZEROS[k]);
    return -1;
}

/* The length of the line break at s[i] (0: none), as str.splitlines() breaks: \n, \r\n, \r,
 * \v, \f, \x1c, \x1d, \x1e, and U+0085, U+2028, U+2029 (their UTF-8 bytes C2 85, E2 80 A8,
 * E2 80 A9 are those characters wherever they stand in UTF-8 text). */
static size_t line_break(const unsigned char *s, size_t len, size_t i)
{
    unsigned c = s[i];
    if (c == '\r')
        return i + 1 < len && s[i + 1] == '\n' ? 2 : 1;
    if (c == '\n' || c == 0x0B || c == 0x0C || c == 0x1C || c == 0x1D || c == 0x1E)
        return 1;
    if (c == 0xC2 && i + 1 < len && s[i + 1] == 0x85)
        return 2;
    if (c == 0xE2 && i + 2 < len && s[i + 1] == 0x80 && (s[i + 2] == 0xA8 || s[i + 2] == 0xA9))
        return 3;
    return 0;
}

/* str.strip() of s[*b..*e) */
static void strip(const unsigned char *s, size_t *b, size_t *e)
{
    size_t n;
    while (*b < *e) {
        long cp = u8_at(s, *e, *b, &n);
        if (!py_space(cp))
            break;
        *b += n;
    }
    while (*e > *b) {
        long cp = u8_before(s, *b, *e, &n);
        if (!py_space(cp))
            break;
        *e -= n;
    }
}

/* ---- float(str) ---------------------------------------------------------------------- */

static int digit(char c) { return c >= '0' && c <= '9'; }

static int ascii_space(char c)                      /* CPython's Py_ISSPACE */
{
    return c == ' ' || (c >= 0x09 && c <= 0x0D);
}

static int match_ci(const char *p, const char *q, const char *word)   /* case-insensitive */
{
    for (; *word; word++, p++) {
        if (p >= q)
            return 0;
        char c = *p;
        if (c >= 'A' && c <= 'Z')
            c = (char)(c - 'A' + 'a');
        if (c != *word)
            return 0;
    }
    return 1;
}

/* float(s[0..n)) as CPython 3.11 reads a str: 1 and *x, or 0 where float() raises ValueError.
 * scratch: 2 n + 40 bytes. */
static int py_float(const unsigned char *s, size_t n, char *scratch, double *x)
{
    char *a = scratch;
    size_t m = 0, i = 0, k;
    /* _PyUnicode_TransformDecimalAndSpaceToASCII: ASCII kept, Unicode spaces to ' ', Unicode
     * decimal digits to ASCII; any other character ends the text with '?' (a refusal) */
    while (i < n) {
        long cp = u8_at(s, n, i, &k);
        if (cp >= 0 && cp < 0x80) {
            a[m++] = (char)cp;
        } else if (cp >= 0 && py_space(cp)) {
            a[m++] = ' ';
        } else {
            int d = cp >= 0 ? py_decimal(cp) : -1;
            if (d < 0)
                return 0;
            a[m++] = (char)('0' + d);
        }
        i += k;
    }
    /* _Py_string_to_number_with_underscores: '_' only between two digits, then dropped */
    if (memchr(a, '_', m)) {
        size_t w = 0;
        char prev = '\0';
        for (i = 0; i < m; i++) {
            char c = a[i];
            if (c == '_') {
                if (!digit(prev))
                    return 0;
            } else {
                if (prev == '_' && !digit(c))
                    return 0;
                a[w++] = c;
            }
            prev = c;
        }
        if (prev == '_')
            return 0;
        m = w;
    }
    /* float_from_string_inner: ASCII whitespace stripped, the rest must be one number */
    const char *p = a, *q = a + m;
    while (p < q && ascii_space(*p))
        p++;
    while (q > p + 1 && ascii_space(q[-1]))
        q--;
    if (p == q)
        return 0;
    int negative = 0;
    const char *signed_start = p;
    if (*p == '+' || *p == '-') {
        negative = *p == '-';
        p++;
    }
    /* _Py_dg_strtod: digits [. digits] [e [sign] digits], at least one digit, no hex */
    const char *int_start = p;
    while (p < q && digit(*p))
        p++;
    size_t n_int = (size_t)(p - int_start), n_frac = 0;
    const char *frac_start = p;
    if (p < q && *p == '.') {
        frac_start = ++p;
        while (p < q && digit(*p))
            p++;
        n_frac = (size_t)(p - frac_start);
    }
    if (n_int + n_frac == 0) {
        /* nothing read: _Py_parse_inf_or_nan, from the sign on */
        p = signed_start + (signed_start < q && (*signed_start == '+' || *signed_start == '-'));
        if (match_ci(p, q, "inf")) {
            p += 3;
            if (match_ci(p, q, "inity"))
                p += 5;
            *x = negative ? -HUGE_VAL : HUGE_VAL;
        } else if (match_ci(p, q, "nan")) {
            p += 3;
            *x = negative ? -NAN : NAN;
        } else {
            return 0;
        }
        return p == q;
    }
    long long exponent = 0;
    if (p < q && (*p == 'e' || *p == 'E')) {
        const char *e = p + 1;
        int e_negative = 0;
        if (e < q && (*e == '+' || *e == '-')) {
            e_negative = *e == '-';
            e++;
        }
        if (e < q && digit(*e)) {          /* else _Py_dg_strtod stops before the 'e' */
            while (e < q && digit(*e)) {
                if (exponent < 1000000000LL)   /* beyond, every value is 0 or inf anyway */
                    exponent = exponent * 10 + (*e - '0');
                e++;
            }
            if (e_negative)
                exponent = -exponent;
            p = e;
        }
    }
    if (p != q)
        return 0;
    /* the value: strtod of "[-]DIGITS" "e" EXP, the point moved into EXP (no locale) */
    char *b = scratch + m + 1;
    size_t w = 0;
    if (negative)
        b[w++] = '-';
    size_t first = w;
    for (const char *c = int_start; c < int_start + n_int; c++)
        if (w > first || *c != '0')
            b[w++] = *c;
    for (const char *c = frac_start; c < frac_start + n_frac; c++)
        if (w > first || *c != '0')
            b[w++] = *c;
    if (w == first) {
        *x = negative ? -0.0 : 0.0;
        return 1;
    }
    snprintf(b + w, 32, "e%lld", exponent - (long long)n_frac);
    *x = strtod(b, NULL);
    return 1;
}

/* ---- csv_number_rows ---------------------------------------------------------------------- */

typedef struct {
    size_t b, e;
} span;

static int span_is(const unsigned char *s, span c, const char *word)
{
    size_t n = strlen(word);
    return c.e - c.b == n && memcmp(s + c.b, word, n) == 0;
}

/* "{prefix}{source}: line {lineno}: " */
static void begin(msgbuf *m, const char *prefix, const char *source, long lineno)
{
    if (prefix)
        puts_(m, prefix);
    puts_(m, source);
    if (lineno > 0) {
        puts_(m, ": line ");
        put_long(m, lineno);
    }
    puts_(m, ": ");
}

static void quoted_line(msgbuf *m, const unsigned char *s, span line)
{
    puts_(m, "'");
    put(m, (const char *)s + line.b, line.e - line.b);
    puts_(m, "'");
}

/* ','.join(columns) */
static void put_columns(msgbuf *m, const char *const *columns, int n_columns)
{
    for (int k = 0; k < n_columns; k++) {
        if (k > 0)
            puts_(m, ",");
        puts_(m, columns[k]);
    }
}

int rc_csv_rows_open(rc_csv_rows *r, const char *text, size_t len, const char *source,
                     const char *prefix, const char *const *columns, int n_columns,
                     rc_profile *out)
{
    const unsigned char *s = (const unsigned char *)text;
    memset(r, 0, sizeof *r);
    memset(out, 0, sizeof *out);
    if (n_columns < 1 || n_columns > RC_CSV_MAX_COLUMNS) {
        snprintf(out->err.msg, RC_MSG_SIZE, "a CSV of %d columns: 1 .. %d are read", n_columns,
                 RC_CSV_MAX_COLUMNS);
        return RC_BAD_CONFIG;
    }
    if (!text)
        len = 0;
    size_t start = 0;
    if (len >= 3 && s[0] == 0xEF && s[1] == 0xBB && s[2] == 0xBF)    /* the BOM */
        start = 3;
    /* how many lines (a bound on the rows) and the longest (the numbers' scratch) */
    size_t lines = 0, longest = 0, pos = start;
    while (pos < len) {
        size_t e = pos, br = 0;
        while (e < len && (br = line_break(s, len, e)) == 0)
            e++;
        lines++;
        if (e - pos > longest)
            longest = e - pos;
        pos = e + br;
    }
    if (lines > (size_t)LONG_MAX || lines > (size_t)-1 / (4 * sizeof(double))
            || longest > ((size_t)-1 - 40) / 2) {
        snprintf(out->err.msg, RC_MSG_SIZE, "out of memory");
        return RC_BAD_CONFIG;
    }
    r->scratch = malloc(2 * longest + 40);
    if (!r->scratch) {
        snprintf(out->err.msg, RC_MSG_SIZE, "out of memory");
        return RC_BAD_CONFIG;
    }
    r->s = s;
    r->len = len;
    r->pos = start;
    r->source = source;
    r->prefix = prefix;
    r->columns = columns;
    r->n_columns = n_columns;
    r->lines = lines;
    return RC_OK;
}

int rc_csv_rows_next(rc_csv_rows *r, double *values, long *lineno, rc_profile *out)
{
    const unsigned char *s = r->s;
    msgbuf m = {NULL, 0, 0, 0};
    while (r->pos < r->len) {
        size_t e = r->pos, br = 0;
        while (e < r->len && (br = line_break(s, r->len, e)) == 0)
            e++;
        span line = {r->pos, e};
        r->pos = e + br;
        r->lineno++;
        strip(s, &line.b, &line.e);
        if (line.b == line.e || s[line.b] == '#')
            continue;
        span cells[RC_CSV_MAX_COLUMNS];
        size_t n_cells = 0, cb = line.b;
        for (size_t i = line.b; i <= line.e; i++) {
            if (i < line.e && s[i] != ',')
                continue;
            span c = {cb, i};                           /* c.strip().strip('"') */
            strip(s, &c.b, &c.e);
            while (c.b < c.e && s[c.b] == '"')
                c.b++;
            while (c.e > c.b && s[c.e - 1] == '"')
                c.e--;
            if (n_cells < RC_CSV_MAX_COLUMNS)
                cells[n_cells] = c;
            n_cells++;
            cb = i + 1;
        }
        if (!r->header_seen) {
            int same = n_cells == (size_t)r->n_columns;
            for (int k = 0; same && k < r->n_columns; k++)
                same = span_is(s, cells[k], r->columns[k]);
            if (!same) {
                begin(&m, r->prefix, r->source, r->lineno);
                puts_(&m, "header must be '");
                put_columns(&m, r->columns, r->n_columns);
                puts_(&m, "', got ");
                quoted_line(&m, s, line);
                return refuse(out, &m), -1;
            }
            r->header_seen = 1;
            continue;
        }
        if (n_cells != (size_t)r->n_columns) {
            begin(&m, r->prefix, r->source, r->lineno);
            puts_(&m, "expected ");
            put_long(&m, r->n_columns);
            puts_(&m, " values, got ");
            put_size(&m, n_cells);
            puts_(&m, ": ");
            quoted_line(&m, s, line);
            return refuse(out, &m), -1;
        }
        int finite = 1;
        for (int k = 0; k < r->n_columns; k++) {
            if (!py_float(s + cells[k].b, cells[k].e - cells[k].b, r->scratch, &values[k])) {
                begin(&m, r->prefix, r->source, r->lineno);
                puts_(&m, "not a number: ");
                quoted_line(&m, s, line);
                return refuse(out, &m), -1;
            }
            finite = finite && isfinite(values[k]);
        }
        if (!finite) {
            begin(&m, r->prefix, r->source, r->lineno);
            puts_(&m, "non-finite value: ");
            quoted_line(&m, s, line);
            return refuse(out, &m), -1;
        }
        *lineno = r->lineno;
        return 1;
    }
    if (!r->header_seen) {
        begin(&m, r->prefix, r->source, 1);
        puts_(&m, "empty file, expected header '");
        put_columns(&m, r->columns, r->n_columns);
        puts_(&m, "'");
        return refuse(out, &m), -1;
    }
    return 0;
}

void rc_csv_rows_close(rc_csv_rows *r)
{
    free(r->scratch);
    r->scratch = NULL;
}

/* ---- parse_profile_csv ------------------------------------------------------------------ */

static int parse(const char *text, size_t len, const char *source, const char *col0,
                 const char *col1, int nonnegative_values, double max_abs_value,
                 const char *prefix, rc_profile *out)
{
    const char *const columns[2] = {col0, col1};
    rc_csv_rows r;
    msgbuf m = {NULL, 0, 0, 0};
    if (rc_csv_rows_open(&r, text, len, source, prefix, columns, 2, out) != RC_OK)
        return RC_BAD_CONFIG;
    size_t lines = r.lines;
    double *rows = malloc(sizeof(double) * 2 * (lines ? lines : 1));
    if (!rows) {
        rc_csv_rows_close(&r);
        snprintf(out->err.msg, RC_MSG_SIZE, "out of memory");
        return RC_BAD_CONFIG;
    }
    double *distances = rows, *values = rows + (lines ? lines : 1);
    long n = 0, lineno = 0;
    double row[2];
    int got;
    while ((got = rc_csv_rows_next(&r, row, &lineno, out)) == 1) {
        double d = row[0], v = row[1];
        if (d < 0) {
            begin(&m, prefix, source, lineno);
            puts_(&m, col0);
            puts_(&m, " must be >= 0, got ");
            put_repr(&m, d);
            goto refused;
        }
        if (n > 0 && d <= distances[n - 1]) {
            begin(&m, prefix, source, lineno);
            puts_(&m, col0);
            puts_(&m, " must increase (");
            put_repr(&m, d);
            puts_(&m, " after ");
            put_repr(&m, distances[n - 1]);
            puts_(&m, ")");
            goto refused;
        }
        if (nonnegative_values && v < 0) {
            begin(&m, prefix, source, lineno);
            puts_(&m, col1);
            puts_(&m, " must be >= 0, got ");
            put_repr(&m, v);
            goto refused;
        }
        if (fabs(v) > max_abs_value) {
            begin(&m, prefix, source, lineno);
            puts_(&m, col1);
            puts_(&m, " must be within +-");
            put_g(&m, max_abs_value);
            puts_(&m, ", got ");
            put_repr(&m, v);
            goto refused;
        }
        distances[n] = d;
        values[n] = v;
        n++;
    }
    rc_csv_rows_close(&r);
    if (got < 0) {                                    /* the row reader's refusal is in out */
        free(rows);
        return RC_BAD_CONFIG;
    }
    if (n == 0) {
        begin(&m, prefix, source, 0);
        puts_(&m, "no data rows after the header");
        free(rows);
        return refuse(out, &m);
    }
    if (values != distances + n)                       /* close the gap: one block of 2 n */
        memmove(distances + n, values, sizeof(double) * (size_t)n);
    out->distances = distances;
    out->values = distances + n;
    out->n = n;
    return RC_OK;
refused:
    rc_csv_rows_close(&r);
    free(rows);
    return refuse(out, &m);
}

int rc_profile_parse(const char *text, size_t len, const char *source, const char *col0,
                     const char *col1, int nonnegative_values, double max_abs_value,
                     rc_profile *out)
{
    return parse(text, len, source, col0, col1, nonnegative_values, max_abs_value, NULL, out);
}

static int parse_kind(const char *text, size_t len, const char *source, rc_profile_kind kind,
                      const char *prefix, rc_profile *out)
{
    if (kind == RC_PROFILE_SPEED)
        return parse(text, len, source, "distance_m", "speed_mps", 1, RC_MAX_SPEED, prefix, out);
    return parse(text, len, source, "distance_m", "grade_permille", 0, RC_MAX_GRADE, prefix, out);
}

int rc_profile_parse_kind(const char *text, size_t len, const char *source, rc_profile_kind kind,
                          rc_profile *out)
{
    return parse_kind(text, len, source, kind, NULL, out);
}

/* ---- the file ----------------------------------------------------------------------------- */

/* str(pathlib.PurePosixPath(path)), malloc'd: empty and "." parts dropped, a root of exactly
 * two slashes kept ("//"), of one or three and more "/", nothing at all is "." */
static char *path_str(const char *path)
{
    size_t n = strlen(path), w = 0, i = 0;
    char *r = malloc(n + 2);
    if (!r)
        return NULL;
    while (i < n && path[i] == '/')
        i++;
    if (i == 2)
        r[w++] = '/';
    if (i >= 1)
        r[w++] = '/';
    size_t root = w;
    while (i < n) {
        size_t j = i;
        while (j < n && path[j] != '/')
            j++;
        if (j > i && !(j - i == 1 && path[i] == '.')) {
            if (w > root)
                r[w++] = '/';
            memcpy(r + w, path + i, j - i);
            w += j - i;
        }
        i = j + 1;
    }
    if (w == 0)
        r[w++] = '.';
    r[w] = '\0';
    return r;
}

/* The offset of the first byte that Python's strict UTF-8 decoder refuses (UnicodeDecodeError
 * .start), or -1: overlong forms, surrogates and code points above U+10FFFF are refused. */
static long utf8_error(const unsigned char *s, size_t n)
{
    size_t i = 0;
    while (i < n) {
        unsigned c = s[i];
        if (c < 0x80) {
            i++;
            continue;
        }
        size_t k;
        unsigned lo = 0x80, hi = 0xBF;
        if (c >= 0xC2 && c <= 0xDF) {
            k = 1;
        } else if (c >= 0xE0 && c <= 0xEF) {
            k = 2;
            if (c == 0xE0)
                lo = 0xA0;
            if (c == 0xED)
                hi = 0x9F;
        } else if (c >= 0xF0 && c <= 0xF4) {
            k = 3;
            if (c == 0xF0)
                lo = 0x90;
            if (c == 0xF4)
                hi = 0x8F;
        } else {
            return (long)i;
        }
        for (size_t j = 1; j <= k; j++) {
            if (i + j >= n)
                return (long)i;
            unsigned t = s[i + j];
            if (j == 1 ? (t < lo || t > hi) : (t & 0xC0) != 0x80)
                return (long)i;
        }
        i += k + 1;
    }
    return -1;
}

/* The whole file, or its first max + 1 bytes when it has more (max SIZE_MAX: no limit): 0, or
 * errno */
static int read_all(const char *path, size_t max, char **data, size_t *len)
{
    FILE *f;
    size_t cap = 4096, n = 0;
    char *buf;
    *data = NULL;
    *len = 0;
    errno = 0;
    f = fopen(path, "rb");
    if (!f)
        return errno ? errno : EIO;
    buf = malloc(cap);
    if (!buf) {
        fclose(f);
        return ENOMEM;
    }
    while (max == SIZE_MAX || n <= max) {
        if (n == cap) {
            char *b = realloc(buf, cap * 2);
            if (!b) {
                free(buf);
                fclose(f);
                return ENOMEM;
            }
            buf = b;
            cap *= 2;
        }
        size_t want = cap - n;
        if (max != SIZE_MAX && want > max + 1 - n)
            want = max + 1 - n;
        errno = 0;
        size_t got = fread(buf + n, 1, want, f);
        n += got;
        if (got == 0) {
            int e = ferror(f) ? (errno ? errno : EIO) : 0;
            if (e) {
                fclose(f);
                free(buf);
                return e;
            }
            break;
        }
    }
    fclose(f);
    *data = buf;
    *len = n;
    return 0;
}

/* The FMU's rule for a profile parameter's file (adapter.read_profile_text): a regular file of
 * at most RC_PROFILE_MAX_BYTES, found so by stat() BEFORE it is opened (opening a FIFO waits for
 * a writer for ever; /dev/zero never ends). 0: read it; else the refusal is in m, or the errno
 * of stat() is in *e. */
static int refuse_unfit_file(msgbuf *m, const char *param, const char *shown, const char *where,
                             int *e)
{
    struct stat st;
    const char *kind = NULL;
    errno = 0;
    if (stat(where, &st) != 0) {
        *e = errno ? errno : EIO;
        return 1;
    }
    if (!S_ISREG(st.st_mode)) {
#ifdef S_ISDIR
        if (S_ISDIR(st.st_mode))
            kind = "a folder";
#endif
#ifdef S_ISFIFO
        if (S_ISFIFO(st.st_mode))
            kind = "a FIFO";
#endif
#ifdef S_ISCHR
        if (S_ISCHR(st.st_mode))
            kind = "a device";
#endif
#ifdef S_ISBLK
        if (S_ISBLK(st.st_mode))
            kind = "a device";
#endif
    } else if (st.st_size <= RC_PROFILE_MAX_BYTES) {
        return 0;
    }
    puts_(m, param);
    puts_(m, ": cannot read '");
    puts_(m, shown);
    puts_(m, "' (looked for ");
    puts_(m, where);
    puts_(m, "): it ");
    if (S_ISREG(st.st_mode)) {
        puts_(m, "has ");
        put_long(m, (long)st.st_size);
        puts_(m, " bytes, more than the " RC_PROFILE_MAX_TEXT " a profile may have");
    } else if (kind) {
        puts_(m, "is ");
        puts_(m, kind);
        puts_(m, ", not a regular file");
    } else {
        puts_(m, "is not a regular file");
    }
    return 1;
}

int rc_profile_read_text(const char *path, const char *param, const char *raw, char **text,
                         size_t *len, char **where, rc_profile *out)
{
    msgbuf m = {NULL, 0, 0, 0};
    char *data = NULL;
    size_t n = 0;
    *text = NULL;
    *len = 0;
    *where = NULL;
    memset(out, 0, sizeof *out);
    char *w = path_str(path ? path : "");
    if (!w) {
        snprintf(out->err.msg, RC_MSG_SIZE, "out of memory");
        return RC_BAD_CONFIG;
    }
    const char *shown = raw ? raw : path;
    int e = 0;
    if (refuse_unfit_file(&m, param, shown, w, &e) && !e)
        goto refused;
    if (!e)
        e = read_all(w, (size_t)RC_PROFILE_MAX_BYTES, &data, &n);
    if (e == ENOMEM) {
        free(w);
        snprintf(out->err.msg, RC_MSG_SIZE, "out of memory");
        return RC_BAD_CONFIG;
    }
    if (e) {
        puts_(&m, param);
        puts_(&m, ": cannot read '");
        puts_(&m, shown);
        puts_(&m, "' (looked for ");
        puts_(&m, w);
        puts_(&m, "): ");
        puts_(&m, strerror(e));
        goto refused;
    }
    if (n > RC_PROFILE_MAX_BYTES) {                 /* it grew after stat() */
        puts_(&m, param);
        puts_(&m, ": cannot read '");
        puts_(&m, shown);
        puts_(&m, "' (looked for ");
        puts_(&m, w);
        puts_(&m, "): it grew past the " RC_PROFILE_MAX_TEXT " a profile may have while it "
                  "was read");
        goto refused;
    }
    long bad = utf8_error((const unsigned char *)data, n);
    if (bad >= 0) {
        puts_(&m, param);
        puts_(&m, ": ");
        puts_(&m, w);
        puts_(&m, ": not UTF-8 text (byte offset ");
        put_long(&m, bad);
        puts_(&m, ")");
        goto refused;
    }
    *text = data;
    *len = n;
    *where = w;
    return RC_OK;
refused:
    free(data);
    free(w);
    return refuse(out, &m);
}

int rc_profile_read_file(const char *path, const char *param, const char *raw,
                         rc_profile_kind kind, rc_profile *out)
{
    msgbuf m = {NULL, 0, 0, 0};
    char *data = NULL;
    size_t len = 0;
    int status;
    if (param) {                                     /* fmu_src/adapter.py load_profiles */
        char *where;
        status = rc_profile_read_text(path, param, raw, &data, &len, &where, out);
        if (status != RC_OK)
            return status;
        puts_(&m, param);
        puts_(&m, ": ");
        if (m.oom) {
            free(data);
            free(where);
            snprintf(out->err.msg, RC_MSG_SIZE, "out of memory");
            return RC_BAD_CONFIG;
        }
        status = parse_kind(data, len, where, kind, m.s, out);
        free(m.s);
        free(data);
        free(where);
        return status;
    }
    memset(out, 0, sizeof *out);
    char *where = path_str(path ? path : "");
    if (!where) {
        snprintf(out->err.msg, RC_MSG_SIZE, "out of memory");
        return RC_BAD_CONFIG;
    }
    int e = read_all(where, SIZE_MAX, &data, &len);
    if (e == ENOMEM) {
        free(where);
        snprintf(out->err.msg, RC_MSG_SIZE, "out of memory");
        return RC_BAD_CONFIG;
    }
    {                                                /* harness/textio.py read_text */
        if (e) {
            puts_(&m, where);
#ifdef EISDIR
            if (e == EISDIR) {
                puts_(&m, ": is a folder, not a file");
                goto refused;
            }
#endif
            puts_(&m, ": cannot read: ");
            puts_(&m, strerror(e));
            goto refused;
        }
        const unsigned char *s = (const unsigned char *)data;
        const char *nul_at = memchr(data, '\0', len);
        long nul = nul_at ? (long)(nul_at - data) : -1;
        long bad = utf8_error(s, len);
        if (bad >= 0 || nul >= 0) {
            puts_(&m, where);
            puts_(&m, ": not UTF-8 text (byte offset ");
            if (bad >= 0) {
                put_long(&m, nul >= 0 && nul < bad ? nul : bad);
                puts_(&m, ")");
                if (len >= 2 && ((s[0] == 0xFF && s[1] == 0xFE) || (s[0] == 0xFE && s[1] == 0xFF)))
                    puts_(&m, " (UTF-16? save it as UTF-8)");
                else if (nul >= 0)
                    puts_(&m, " (a binary file?)");
            } else {
                put_long(&m, nul);
                puts_(&m, ") (a NUL byte: a binary file?)");
            }
            goto refused;
        }
        size_t skip = len >= 3 && s[0] == 0xEF && s[1] == 0xBB && s[2] == 0xBF ? 3 : 0;
        status = parse_kind(data + skip, len - skip, where, kind, NULL, out);
    }
    free(data);
    free(where);
    return status;
refused:
    free(data);
    free(where);
    return refuse(out, &m);
}

int rc_profile_refuse(rc_profile *out, const char *fmt, ...)
{
    msgbuf m = {NULL, 0, 0, 0};
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(NULL, 0, fmt, ap);
    va_end(ap);
    memset(out, 0, sizeof *out);
    if (n >= 0 && (m.s = malloc((size_t)n + 1)) != NULL) {
        va_start(ap, fmt);
        vsnprintf(m.s, (size_t)n + 1, fmt, ap);
        va_end(ap);
        m.len = (size_t)n;
        m.cap = (size_t)n + 1;
    }
    return refuse(out, &m);                 /* m.s NULL: "out of memory" */
}

void rc_profile_free(rc_profile *p)
{
    if (!p)
        return;
    free(p->distances);
    free(p->message);
    memset(p, 0, sizeof *p);
}

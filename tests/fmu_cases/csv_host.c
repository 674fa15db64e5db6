/* csv_host: a small FMI 2.0 / FMI 3.0 co-simulation host that replays inputs from a CSV file
 * through an FMU's binary and writes the outputs to a CSV file. No Python, no XML parser: it
 * loads the shared library (dlopen/dlsym; on Windows LoadLibrary/GetProcAddress) and is told the
 * value references on its command line and in its files. The same source builds for Linux, any
 * POSIX system and Windows (mingw-w64 or MSVC).
 *
 *   csv_host [OPTIONS] fmi2|fmi3 BINARY RESOURCE_DIR GUID PARAMS.csv INPUTS.csv OUT.csv OUTPUT...
 *   csv_host -b RUNS.txt
 *
 *   BINARY        the FMU's shared library (binaries/linux64/X.so or binaries/x86_64-linux/X.so,
 *                 binaries/win64/X.dll ...)
 *   RESOURCE_DIR  the extracted FMU's resources/ folder; passed to fmi2Instantiate as a file: URI
 *                 (Windows: file:///C:/...), to fmi3InstantiateCoSimulation as an absolute path
 *                 ending in '/' (Windows: '\')
 *   GUID          the guid (FMI 2) or instantiationToken (FMI 3) of its modelDescription.xml
 *   PARAMS.csv    header "vr,type,value", then one line per parameter: value reference, type
 *                 (real, integer, boolean or string) and value. A string is the rest of the line
 *                 after the second comma, verbatim (a path may hold commas), or one CSV-quoted
 *                 field ("" for a quote). Set in initialisation mode, one call per line, in order.
 *   INPUTS.csv    header "time [s]" (or "time") then one column per input, named by its value
 *                 reference with an optional type letter: "12" or "r12" real, "i12" integer,
 *                 "b12" boolean. Row k: the time t_k at which its step starts (strictly
 *                 increasing, finite) and the input values set before that step (reals as
 *                 strtod reads them: "nan" and "inf" reach the FMU, which judges them).
 *   OUT.csv       created once the FMU has initialised (a run that cannot start leaves none; "-"
 *                 is standard output): header "time [s]", the OUTPUT arguments as given,
 *                 "status"; one row at the start time after initialisation, then one row after
 *                 each step: the communication point t_k + h_k (FMI 3: the step's
 *                 lastSuccessfulTime), the outputs (reals with %.17g, which strtod and Python's
 *                 float() read back as the same double; integers and booleans as integers) and
 *                 the step's status: 0 OK, 1 Warning, 2 discarded and retried (see -d hold).
 *   OUTPUT...     value references of the outputs to record, with the same optional type letter.
 *
 * Options:
 *   -s STEP    every row steps doStep(t_k, STEP): the step size exactly as given (default: h_k is
 *              t_(k+1) - t_k, and the last row's step ends at the stop time, so -e is needed)
 *   -e STOP    the stop time given to the FMU (default with -s: the last row's t + STEP)
 *   -d hold    (default) a step the FMU discards is retried once over the same interval with the
 *              inputs of the last row it accepted (for the first row, the input values read from
 *              the FMU after initialisation); the row gets status 2 and the run goes on with the
 *              next row. A discarded retry is an error.
 *   -d stop    a discarded step is an error
 *   -q         quiet: no warning lines, no summary (discards and errors are still reported)
 *   -v         loggingOn = true, and every message the FMU logs is printed
 *   -k ROW     the FMU state's round trip (the code's section "-k" says more): before row ROW's
 *              step (0: right after initialisation) the state is taken and serialized; pass A
 *              (the normal run, OUT.csv) goes on to the end; pass B deserializes the bytes, sets
 *              that state and replays rows ROW.. with the same inputs; pass C sets the state
 *              taken with get and replays again; both replays must give pass A's rows bit for
 *              bit. Needs -R. The FMU-state functions are loaded only with -k.
 *   -R REPORT.txt   (-k) the round trip's result, one "key value" line each: row, serialized_size,
 *              bytes_written, bytes_read, pass_b / pass_c "identical" or "differs row R column
 *              NAME: A x, replay y", failed (a call that failed, as reported on standard error)
 *   -S STATE.bin    (-k) the serialized state written to this file
 *   -L STATE.bin    (-k) pass B deserializes these bytes (another host's -S: another platform's
 *              state) instead of its own; a refusal is a failed call (exit status 2)
 *   -b RUNS.txt   many runs in one process (a process start is what costs under Wine or qemu):
 *              each line of RUNS.txt is one run's arguments, OPTIONS included, separated by tabs;
 *              the runs go one after the other, each reported as alone, and a run that fails
 *              is named "RUNS.txt:LINE: exit status N" and does not stop the next
 *
 * Reporting: every message goes to standard error, starting "csv_host: " and saying where: the
 * file and line (PARAMS.csv:4, INPUTS.csv:52 (t = 5)) or the call. An FMU call that returns
 * Warning, Discard, Error or Fatal is reported on one line with the messages the FMU logged in
 * that call; messages of Warning level in a call that returned OK are reported too. Warnings,
 * discarded steps and errors are counted in a summary line at the end.
 *
 * Exit status (with -b: the largest of the runs'): 0 every row stepped and no step was
 * discarded; 1 every row stepped, some steps were discarded and retried (their rows have
 * status 2); 2 the run failed (an FMU call returned Error or Fatal, a retry was discarded,
 * -d stop saw a discard, the FMU asked to terminate) and OUT.csv holds the rows up to there;
 * 3 bad arguments or input files (named with the line), a library or symbol that cannot be
 * loaded, a version mismatch, or OUT.csv cannot be written. With -k a replay that differs from
 * pass A, or a refused state, is status 2 (OUT.csv holds pass A whole).
 *
 * After Error the instance is freed without fmi2Terminate/fmi3Terminate; after Fatal it is not
 * touched again. Both follow "Status Returned by Functions" (FMI 2.0 section 2.1.3, FMI 3.0
 * section 2.2.3): after Error only a reset, a stored FMU state or freeing the instance; after
 * Fatal no call at all. The retry of -d hold is what FMI 3.0's section allows after Discard:
 * "advanced importers may try alternative approaches ... by calling the function with
 * different arguments" (here: other inputs, the same interval).
 *
 * Build: cc -std=c99 -O2 -Wall -Wextra -Werror -pedantic -I FMPY/c-code csv_host.c -o csv_host -ldl
 *        x86_64-w64-mingw32-gcc (same flags) -I FMPY/c-code csv_host.c -o csv_host.exe
 * Tested by tests/fmu_tests/test_native_csv_host.py; built for aarch64 (run under qemu) and for
 * Windows (run under Wine) by tests/fmu_tests/test_cross_platform.py. */
#ifndef _WIN32
#define _XOPEN_SOURCE 700   /* dlopen, realpath */
#endif

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

/* The one platform-dependent part: loading the library, resolving a symbol, the absolute path of
   the resources folder. Windows: LoadLibrary/GetProcAddress, GetFullPathName; elsewhere POSIX
   dlopen/dlsym, realpath. */
#ifdef _WIN32
#define WIN32_LEAN_AND_MEAN
#include <windows.h>
#else
#include <dlfcn.h>
#endif

#define PROGRAM "csv_host"
#define EXIT_DISCARDED 1
#define EXIT_RUN_FAILED 2
#define EXIT_BAD_INPUT 3

/* dlsym's object pointer (GetProcAddress's FARPROC) is copied into a function pointer (POSIX
   guarantees they have the same representation; ISO C has no conversion between them): the sizes
   must agree. */
typedef void (*AnyFunction)(void);
typedef char function_pointer_size_check[sizeof(AnyFunction) == sizeof(void *) ? 1 : -1];

/* ======================================================================== reporting */

static void say(const char *fmt, ...) {
    va_list ap;
    fputs(PROGRAM ": ", stderr);
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fputc('\n', stderr);
}

static const char *status_name(int status) {
    static const char *const names[] = {"OK", "Warning", "Discard", "Error", "Fatal", "Pending"};
    return status >= 0 && status <= 5 ? names[status] : "unknown status";
}

/* The messages the FMU logs during one call, kept until the host reports them. */
#define SINK_SIZE 8192
typedef struct {
    char text[SINK_SIZE];   /* messages, each "<status digit><text>\0" */
    size_t used;
    int truncated;
    int verbose;            /* -v: messages of OK level printed too */
    int quiet;              /* -q: warnings counted, not printed */
    char failure[SINK_SIZE + 256];  /* the last call that failed, as reported (-R writes it) */
} LogSink;

static void sink_clear(LogSink *s) {
    s->used = 0;
    s->truncated = 0;
}

static void sink_add(LogSink *s, int status, const char *fmt, va_list ap) {
    size_t room = SINK_SIZE - s->used;
    int n;
    if (room < 3) {
        s->truncated = 1;
        return;
    }
    s->text[s->used] = (char)('0' + (status >= 0 && status <= 5 ? status : 3));
    n = fmt ? vsnprintf(s->text + s->used + 1, room - 1, fmt, ap) : 0;
    if (n < 0) n = 0;
    if ((size_t)n >= room - 1) {
        n = (int)(room - 2);
        s->truncated = 1;
    }
    s->text[s->used + 1 + (size_t)n] = '\0';
    s->used += (size_t)n + 2;
}

/* FMI 2: printf-like (the message is a format; arguments may follow) */
static void log_fmi2(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                     fmi2String category, fmi2String message, ...) {
    va_list ap;
    (void)instance;
    (void)category;
    va_start(ap, message);
    sink_add((LogSink *)env, (int)status, message, ap);
    va_end(ap);
}

static void sink_add_format(LogSink *s, int status, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    sink_add(s, status, fmt, ap);
    va_end(ap);
}

/* FMI 3: the message is plain text */
static void log_fmi3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                     fmi3String message) {
    (void)category;
    sink_add_format((LogSink *)env, (int)status, "%s", message ? message : "");
}

/* Reports the call and the messages it logged; returns the number of warnings: messages of
   Warning level, or 1 for a call that returned Warning without logging one. */
static int report_call(LogSink *s, const char *where, const char *call, int status) {
    size_t at;
    int warnings = 0;
    if (status != 0) {
        char line[SINK_SIZE + 256];
        size_t len = 0;
        int any = 0;
        len += (size_t)snprintf(line, sizeof line, "%s: %s returned %s: ", where, call,
                                status_name(status));
        for (at = 0; at < s->used; at += strlen(s->text + at) + 1) {
            const char *msg = s->text + at + 1;
            if (s->text[at] == '1') warnings++;
            if (len < sizeof line)
                len += (size_t)snprintf(line + len, sizeof line - len, "%s%s", any ? " | " : "",
                                        msg);
            any = 1;
        }
        if (!any && len < sizeof line)
            snprintf(line + len, sizeof line - len, "(the FMU logged no message)");
        if (status == 1 && warnings == 0) warnings = 1;
        if (status > 1 || !s->quiet) say("%s%s", line, s->truncated ? " [more messages cut]" : "");
        if (status > 1) memcpy(s->failure, line, sizeof s->failure);
    } else {
        for (at = 0; at < s->used; at += strlen(s->text + at) + 1) {
            int level = s->text[at] - '0';
            if (level == 1) warnings++;
            if ((level >= 1 && !s->quiet) || s->verbose)
                say("%s: %s: %s: %s", where, call, status_name(level), s->text + at + 1);
        }
    }
    sink_clear(s);
    return warnings;
}

/* ======================================================================== files */

typedef enum { T_REAL, T_INTEGER, T_BOOLEAN, T_STRING } VarType;
static const char *const TYPE_NAMES[] = {"real", "integer", "boolean", "string"};

typedef struct {
    uint32_t vr;
    VarType type;
} Var;

typedef struct {
    const char *path;
    char *text;           /* the whole file, NUL-terminated; lines and fields cut in place */
    char **lines;
    long *numbers;        /* the 1-based line number of each kept line */
    size_t n_lines;
} TextFile;

static void text_free(TextFile *f) {
    free(f->text);
    free(f->lines);
    free(f->numbers);
    memset(f, 0, sizeof *f);
}

/* Reads a file and cuts it into lines ('\n', an optional '\r' before it); skips a UTF-8 BOM and
   lines that are empty. 0, or -1 with the reason reported. */
static int text_read(TextFile *f, const char *path) {
    FILE *in;
    size_t cap = 4096, len = 0, i, start, n_breaks = 1;
    long number = 0;
    char *p;
    memset(f, 0, sizeof *f);
    f->path = path;
    in = fopen(path, "rb");
    if (!in) {
        say("%s: cannot open: %s", path, strerror(errno));
        return -1;
    }
    f->text = malloc(cap);
    while (f->text) {
        size_t got = fread(f->text + len, 1, cap - len - 1, in);
        len += got;
        if (len < cap - 1) break;
        p = realloc(f->text, cap * 2);
        if (!p) {
            free(f->text);
            f->text = NULL;
        } else {
            f->text = p;
            cap *= 2;
        }
    }
    if (!f->text || ferror(in)) {
        say("%s: cannot read: %s", path, f->text ? strerror(errno) : "out of memory");
        fclose(in);
        text_free(f);
        return -1;
    }
    fclose(in);
    f->text[len] = '\0';
    if (strlen(f->text) != len) {
        size_t nul = strlen(f->text);
        for (i = 0; i < nul; i++) number += f->text[i] == '\n';
        say("%s:%ld: a NUL byte (not a text file)", path, number + 1);
        text_free(f);
        return -1;
    }
    for (i = 0; i < len; i++) n_breaks += f->text[i] == '\n';
    f->lines = malloc(n_breaks * sizeof *f->lines);
    f->numbers = malloc(n_breaks * sizeof *f->numbers);
    if (!f->lines || !f->numbers) {
        say("%s: out of memory", path);
        text_free(f);
        return -1;
    }
    start = len >= 3 && memcmp(f->text, "\xEF\xBB\xBF", 3) == 0 ? 3 : 0;
    while (start < len) {
        char *line = f->text + start, *nl = strchr(line, '\n');
        size_t n = nl ? (size_t)(nl - line) : strlen(line);
        number++;
        line[n] = '\0';
        if (n > 0 && line[n - 1] == '\r') line[--n] = '\0';
        if (n > 0) {
            f->lines[f->n_lines] = line;
            f->numbers[f->n_lines++] = number;
        }
        start += (nl ? (size_t)(nl - (f->text + start)) + 1 : n + 1);
    }
    return 0;
}

static char *trim(char *s) {
    char *end;
    while (*s == ' ' || *s == '\t') s++;
    end = s + strlen(s);
    while (end > s && (end[-1] == ' ' || end[-1] == '\t')) *--end = '\0';
    return s;
}

static size_t count_fields(const char *line) {
    size_t n = 1;
    for (; *line; line++) n += *line == ',';
    return n;
}

/* Cuts line at commas into fields (trimmed); returns how many fields the line has (only the
   first `max` are stored). */
static size_t split(char *line, char **fields, size_t max) {
    size_t n = 0;
    for (;;) {
        char *comma = strchr(line, ',');
        if (comma) *comma = '\0';
        if (n < max) fields[n] = trim(line);
        n++;
        if (!comma) return n;
        line = comma + 1;
    }
}

/* A double as strtod reads it: the whole (trimmed) field, not empty, not overflowing. */
static int parse_real(const char *s, double *out) {
    char *end;
    errno = 0;
    if (!*s) return -1;
    *out = strtod(s, &end);
    if (*end != '\0' || end == s) return -1;
    if (errno == ERANGE && (*out == HUGE_VAL || *out == -HUGE_VAL)) return -1;
    return 0;
}

/* A 32-bit signed integer in decimal. */
static int parse_int32(const char *s, double *out) {
    char *end;
    long long v;
    errno = 0;
    if (!*s) return -1;
    v = strtoll(s, &end, 10);
    if (*end != '\0' || errno == ERANGE || v < INT32_MIN || v > INT32_MAX) return -1;
    *out = (double)v;
    return 0;
}

static int parse_bool(const char *s, double *out) {
    if (!strcmp(s, "1") || !strcmp(s, "true")) *out = 1.0;
    else if (!strcmp(s, "0") || !strcmp(s, "false")) *out = 0.0;
    else return -1;
    return 0;
}

static int parse_value(VarType type, const char *s, double *out) {
    switch (type) {
    case T_REAL: return parse_real(s, out);
    case T_INTEGER: return parse_int32(s, out);
    case T_BOOLEAN: return parse_bool(s, out);
    default: return -1;
    }
}

/* A value reference with an optional type letter (r, i, b): "12", "r12", "i3", "b7". */
static int parse_var(const char *s, Var *v) {
    unsigned long long n = 0;
    const char *p = s;
    v->type = T_REAL;
    if (*p == 'r' || *p == 'i' || *p == 'b') {
        v->type = *p == 'r' ? T_REAL : *p == 'i' ? T_INTEGER : T_BOOLEAN;
        p++;
    }
    if (*p < '0' || *p > '9') return -1;
    for (; *p >= '0' && *p <= '9'; p++) {
        n = n * 10 + (unsigned long long)(*p - '0');
        if (n > UINT32_MAX) return -1;
    }
    if (*p) return -1;
    v->vr = (uint32_t)n;
    return 0;
}

/* -------------------------------------------------------------------- PARAMS.csv */

typedef struct {
    Var var;
    double number;
    const char *text;     /* strings: points into the file's text (or an unquoted copy) */
    long line;
} Param;

typedef struct {
    TextFile file;
    Param *items;
    size_t n;
    char **unquoted;      /* strings that were CSV-quoted, unquoted into their own memory */
    size_t n_unquoted;
} Params;

static void params_free(Params *p) {
    size_t i;
    for (i = 0; i < p->n_unquoted; i++) free(p->unquoted[i]);
    free(p->unquoted);
    free(p->items);
    text_free(&p->file);
}

/* A CSV-quoted field "..." ("" for a quote) that must end the line: its text, or NULL. */
static char *unquote(const char *s) {
    size_t n = strlen(s), i, j;
    char *out;
    if (n < 2 || s[0] != '"' || s[n - 1] != '"') return NULL;
    out = malloc(n);
    if (!out) return NULL;
    for (i = 1, j = 0; i < n - 1; i++) {
        if (s[i] == '"') {
            if (i + 1 >= n - 1 || s[i + 1] != '"') {
                free(out);
                return NULL;
            }
            i++;
        }
        out[j++] = s[i];
    }
    out[j] = '\0';
    return out;
}

static int params_read(Params *p, const char *path) {
    size_t k;
    char *f[3];
    memset(p, 0, sizeof *p);
    if (text_read(&p->file, path) != 0) return -1;
    if (p->file.n_lines == 0) {
        say("%s: empty (the header \"vr,type,value\" is needed)", path);
        return -1;
    }
    {
        char *header = p->file.lines[0];
        if (split(header, f, 3) != 3 || strcmp(f[0], "vr") || strcmp(f[1], "type") ||
            strcmp(f[2], "value")) {
            say("%s:%ld: the header must be \"vr,type,value\"", path, p->file.numbers[0]);
            return -1;
        }
    }
    p->items = calloc(p->file.n_lines, sizeof *p->items);
    p->unquoted = calloc(p->file.n_lines, sizeof *p->unquoted);
    if (!p->items || !p->unquoted) {
        say("%s: out of memory", path);
        return -1;
    }
    for (k = 1; k < p->file.n_lines; k++) {
        char *line = p->file.lines[k], *c1, *c2;
        long number = p->file.numbers[k];
        Param *item = &p->items[p->n];
        c1 = strchr(line, ',');
        c2 = c1 ? strchr(c1 + 1, ',') : NULL;
        if (!c2) {
            say("%s:%ld: expected \"vr,type,value\", got \"%s\"", path, number, line);
            return -1;
        }
        *c1 = *c2 = '\0';
        item->line = number;
        {
            char *vr = trim(line), *type = trim(c1 + 1);
            if (parse_var(vr, &item->var) != 0 || vr[0] < '0' || vr[0] > '9') {
                say("%s:%ld: \"%s\" is not a value reference (0 .. 4294967295)", path, number, vr);
                return -1;
            }
            for (item->var.type = T_REAL; item->var.type <= T_STRING; item->var.type++)
                if (!strcmp(type, TYPE_NAMES[item->var.type])) break;
            if (item->var.type > T_STRING) {
                say("%s:%ld: type \"%s\" is not real, integer, boolean or string", path, number,
                    type);
                return -1;
            }
        }
        if (item->var.type == T_STRING) {
            char *value = c2 + 1;
            if (value[0] == '"') {
                char *plain = unquote(value);
                if (!plain) {
                    say("%s:%ld: a quoted string must end the line, quotes doubled inside", path,
                        number);
                    return -1;
                }
                p->unquoted[p->n_unquoted++] = plain;
                item->text = plain;
            } else {
                item->text = value;
            }
        } else {
            char *value = trim(c2 + 1);
            if (parse_value(item->var.type, value, &item->number) != 0) {
                say("%s:%ld: \"%s\" is not a valid %s value", path, number, value,
                    TYPE_NAMES[item->var.type]);
                return -1;
            }
        }
        p->n++;
    }
    return 0;
}

/* -------------------------------------------------------------------- INPUTS.csv */

typedef struct {
    TextFile file;
    size_t n_cols;        /* inputs, the time column not counted */
    Var *cols;
    size_t n_rows;
    double *time;         /* n_rows */
    double *values;       /* n_rows x n_cols; integers and booleans as exact doubles */
    long *line;           /* each row's line in the file */
} Inputs;

static void inputs_free(Inputs *in) {
    free(in->cols);
    free(in->time);
    free(in->values);
    free(in->line);
    text_free(&in->file);
}

static int inputs_read(Inputs *in, const char *path) {
    size_t n_fields, k, j;
    char **f = NULL;
    int rc = -1;
    memset(in, 0, sizeof *in);
    if (text_read(&in->file, path) != 0) return -1;
    if (in->file.n_lines < 2) {
        say("%s: needs a header \"time [s],VR,...\" and at least one row", path);
        return -1;
    }
    n_fields = count_fields(in->file.lines[0]);
    f = malloc(n_fields * sizeof *f);
    in->cols = malloc(n_fields * sizeof *in->cols);
    in->n_rows = in->file.n_lines - 1;
    in->n_cols = n_fields - 1;
    in->time = malloc(in->n_rows * sizeof *in->time);
    in->values = malloc(in->n_rows * (in->n_cols ? in->n_cols : 1) * sizeof *in->values);
    in->line = malloc(in->n_rows * sizeof *in->line);
    if (!f || !in->cols || !in->time || !in->values || !in->line) {
        say("%s: out of memory", path);
        goto done;
    }
    split(in->file.lines[0], f, n_fields);
    if (strcmp(f[0], "time [s]") != 0 && strcmp(f[0], "time") != 0) {
        say("%s:%ld: the first column must be \"time [s]\", not \"%s\"", path,
            in->file.numbers[0], f[0]);
        goto done;
    }
    for (j = 1; j < n_fields; j++) {
        size_t i;
        if (parse_var(f[j], &in->cols[j - 1]) != 0) {
            say("%s:%ld: column %lu: \"%s\" is not an input value reference (12, r12, i12 or b12)",
                path, in->file.numbers[0], (unsigned long)(j + 1), f[j]);
            goto done;
        }
        for (i = 0; i + 1 < j; i++)
            if (in->cols[i].vr == in->cols[j - 1].vr) {
                say("%s:%ld: value reference %lu in columns %lu and %lu", path,
                    in->file.numbers[0], (unsigned long)in->cols[i].vr, (unsigned long)(i + 2),
                    (unsigned long)(j + 1));
                goto done;
            }
    }
    for (k = 0; k < in->n_rows; k++) {
        long number = in->file.numbers[k + 1];
        size_t got = split(in->file.lines[k + 1], f, n_fields);
        in->line[k] = number;
        if (got != n_fields) {
            say("%s:%ld: %lu fields, the header has %lu", path, number, (unsigned long)got,
                (unsigned long)n_fields);
            goto done;
        }
        if (parse_real(f[0], &in->time[k]) != 0 || !isfinite(in->time[k])) {
            say("%s:%ld: time \"%s\" is not a finite number", path, number, f[0]);
            goto done;
        }
        if (k > 0 && !(in->time[k] > in->time[k - 1])) {
            say("%s:%ld: time %.17g does not follow %.17g (line %ld): times must increase", path,
                number, in->time[k], in->time[k - 1], in->line[k - 1]);
            goto done;
        }
        for (j = 1; j < n_fields; j++)
            if (parse_value(in->cols[j - 1].type, f[j], &in->values[k * in->n_cols + j - 1]) != 0) {
                say("%s:%ld: column %lu (vr %lu): \"%s\" is not a valid %s value", path, number,
                    (unsigned long)(j + 1), (unsigned long)in->cols[j - 1].vr, f[j],
                    TYPE_NAMES[in->cols[j - 1].type]);
                goto done;
            }
    }
    rc = 0;
done:
    free(f);
    return rc;
}

/* ======================================================================== the FMU */

/* The variables of one type among a list (inputs or outputs), with their positions in it. */
typedef struct {
    VarType type;
    size_t n;
    size_t *index;
    fmi2ValueReference *vr2;
    fmi3ValueReference *vr3;
} Group;

typedef struct {
    int version;          /* 2 or 3 */
    const char *binary;
    void *library;
    void *instance;
    int dead;             /* after Error: only free; after Fatal: nothing */
    int fatal;
    LogSink sink;
    fmi2CallbackFunctions callbacks2;
    struct {
        fmi2GetVersionTYPE *getVersion;
        fmi2InstantiateTYPE *instantiate;
        fmi2FreeInstanceTYPE *freeInstance;
        fmi2SetupExperimentTYPE *setupExperiment;
        fmi2EnterInitializationModeTYPE *enterInitializationMode;
        fmi2ExitInitializationModeTYPE *exitInitializationMode;
        fmi2TerminateTYPE *terminate;
        fmi2SetRealTYPE *setReal;
        fmi2SetIntegerTYPE *setInteger;
        fmi2SetBooleanTYPE *setBoolean;
        fmi2SetStringTYPE *setString;
        fmi2GetRealTYPE *getReal;
        fmi2GetIntegerTYPE *getInteger;
        fmi2GetBooleanTYPE *getBoolean;
        fmi2DoStepTYPE *doStep;
        /* FMU states: loaded only for -k */
        fmi2GetFMUstateTYPE *getState;
        fmi2SetFMUstateTYPE *setState;
        fmi2FreeFMUstateTYPE *freeState;
        fmi2SerializedFMUstateSizeTYPE *stateSize;
        fmi2SerializeFMUstateTYPE *serializeState;
        fmi2DeSerializeFMUstateTYPE *deserializeState;
    } f2;
    struct {
        fmi3GetVersionTYPE *getVersion;
        fmi3InstantiateCoSimulationTYPE *instantiateCoSimulation;
        fmi3FreeInstanceTYPE *freeInstance;
        fmi3EnterInitializationModeTYPE *enterInitializationMode;
        fmi3ExitInitializationModeTYPE *exitInitializationMode;
        fmi3TerminateTYPE *terminate;
        fmi3SetFloat64TYPE *setFloat64;
        fmi3SetInt32TYPE *setInt32;
        fmi3SetBooleanTYPE *setBoolean;
        fmi3SetStringTYPE *setString;
        fmi3GetFloat64TYPE *getFloat64;
        fmi3GetInt32TYPE *getInt32;
        fmi3GetBooleanTYPE *getBoolean;
        fmi3DoStepTYPE *doStep;
        fmi3GetFMUStateTYPE *getState;
        fmi3SetFMUStateTYPE *setState;
        fmi3FreeFMUStateTYPE *freeState;
        fmi3SerializedFMUStateSizeTYPE *stateSize;
        fmi3SerializeFMUStateTYPE *serializeState;
        fmi3DeserializeFMUStateTYPE *deserializeState;
    } f3;
    int states;           /* -k: the FMU-state functions are needed */
    /* scratch for one set/get call (sized for the largest group) */
    double *reals;
    fmi2Integer *ints2;
    fmi3Int32 *ints3;
    fmi2Boolean *bools2;
    fmi3Boolean *bools3;
} Fmu;

#ifdef _WIN32
/* The system's text for GetLastError(), without its line break. */
static const char *last_error_text(void) {
    static char text[512];
    DWORD code = GetLastError();
    DWORD n = FormatMessageA(FORMAT_MESSAGE_FROM_SYSTEM | FORMAT_MESSAGE_IGNORE_INSERTS, NULL,
                             code, 0, text, (DWORD)sizeof text, NULL);
    while (n > 0 && (text[n - 1] == '\n' || text[n - 1] == '\r' || text[n - 1] == ' '))
        text[--n] = '\0';
    if (n == 0) snprintf(text, sizeof text, "Windows error %lu", (unsigned long)code);
    return text;
}

static void *library_open(const char *path) { return (void *)LoadLibraryA(path); }
static const char *library_error(void) { return last_error_text(); }
static void library_close(void *library) { FreeLibrary((HMODULE)library); }

static int library_symbol(void *library, const char *name, AnyFunction *out) {
    FARPROC symbol = GetProcAddress((HMODULE)library, name);
    if (!symbol) return -1;
    memcpy(out, &symbol, sizeof symbol);
    return 0;
}
#else
static void *library_open(const char *path) { return dlopen(path, RTLD_NOW | RTLD_LOCAL); }
static const char *library_error(void) { return dlerror(); }
static void library_close(void *library) { dlclose(library); }

static int library_symbol(void *library, const char *name, AnyFunction *out) {
    void *symbol;
    dlerror();
    symbol = dlsym(library, name);
    if (!symbol) {
        dlerror();
        return -1;
    }
    memcpy(out, &symbol, sizeof symbol);
    return 0;
}
#endif

static int resolve(Fmu *f, const char *name, AnyFunction *out) {
    if (library_symbol(f->library, name, out) != 0) {
        say("%s: no symbol %s", f->binary, name);
        return 1;
    }
    return 0;
}

#define LOAD(field, TYPE, name)                                                               \
    do {                                                                                     \
        AnyFunction any_;                                                                    \
        if (resolve(f, name, &any_) == 0) (field) = (TYPE *)any_;                            \
        else missing++;                                                                      \
    } while (0)

/* Load the binary and resolve the co-simulation functions; 0, or -1 (every missing symbol
   reported). */
static int fmu_load(Fmu *f) {
    int missing = 0;
    const char *version;
    f->library = library_open(f->binary);
    if (!f->library) {
        say("%s: cannot load: %s", f->binary, library_error());
        return -1;
    }
    if (f->version == 2) {
        LOAD(f->f2.getVersion, fmi2GetVersionTYPE, "fmi2GetVersion");
        LOAD(f->f2.instantiate, fmi2InstantiateTYPE, "fmi2Instantiate");
        LOAD(f->f2.freeInstance, fmi2FreeInstanceTYPE, "fmi2FreeInstance");
        LOAD(f->f2.setupExperiment, fmi2SetupExperimentTYPE, "fmi2SetupExperiment");
        LOAD(f->f2.enterInitializationMode, fmi2EnterInitializationModeTYPE,
             "fmi2EnterInitializationMode");
        LOAD(f->f2.exitInitializationMode, fmi2ExitInitializationModeTYPE,
             "fmi2ExitInitializationMode");
        LOAD(f->f2.terminate, fmi2TerminateTYPE, "fmi2Terminate");
        LOAD(f->f2.setReal, fmi2SetRealTYPE, "fmi2SetReal");
        LOAD(f->f2.setInteger, fmi2SetIntegerTYPE, "fmi2SetInteger");
        LOAD(f->f2.setBoolean, fmi2SetBooleanTYPE, "fmi2SetBoolean");
        LOAD(f->f2.setString, fmi2SetStringTYPE, "fmi2SetString");
        LOAD(f->f2.getReal, fmi2GetRealTYPE, "fmi2GetReal");
        LOAD(f->f2.getInteger, fmi2GetIntegerTYPE, "fmi2GetInteger");
        LOAD(f->f2.getBoolean, fmi2GetBooleanTYPE, "fmi2GetBoolean");
        LOAD(f->f2.doStep, fmi2DoStepTYPE, "fmi2DoStep");
        if (f->states) {
            LOAD(f->f2.getState, fmi2GetFMUstateTYPE, "fmi2GetFMUstate");
            LOAD(f->f2.setState, fmi2SetFMUstateTYPE, "fmi2SetFMUstate");
            LOAD(f->f2.freeState, fmi2FreeFMUstateTYPE, "fmi2FreeFMUstate");
            LOAD(f->f2.stateSize, fmi2SerializedFMUstateSizeTYPE, "fmi2SerializedFMUstateSize");
            LOAD(f->f2.serializeState, fmi2SerializeFMUstateTYPE, "fmi2SerializeFMUstate");
            LOAD(f->f2.deserializeState, fmi2DeSerializeFMUstateTYPE, "fmi2DeSerializeFMUstate");
        }
    } else {
        LOAD(f->f3.getVersion, fmi3GetVersionTYPE, "fmi3GetVersion");
        LOAD(f->f3.instantiateCoSimulation, fmi3InstantiateCoSimulationTYPE,
             "fmi3InstantiateCoSimulation");
        LOAD(f->f3.freeInstance, fmi3FreeInstanceTYPE, "fmi3FreeInstance");
        LOAD(f->f3.enterInitializationMode, fmi3EnterInitializationModeTYPE,
             "fmi3EnterInitializationMode");
        LOAD(f->f3.exitInitializationMode, fmi3ExitInitializationModeTYPE,
             "fmi3ExitInitializationMode");
        LOAD(f->f3.terminate, fmi3TerminateTYPE, "fmi3Terminate");
        LOAD(f->f3.setFloat64, fmi3SetFloat64TYPE, "fmi3SetFloat64");
        LOAD(f->f3.setInt32, fmi3SetInt32TYPE, "fmi3SetInt32");
        LOAD(f->f3.setBoolean, fmi3SetBooleanTYPE, "fmi3SetBoolean");
        LOAD(f->f3.setString, fmi3SetStringTYPE, "fmi3SetString");
        LOAD(f->f3.getFloat64, fmi3GetFloat64TYPE, "fmi3GetFloat64");
        LOAD(f->f3.getInt32, fmi3GetInt32TYPE, "fmi3GetInt32");
        LOAD(f->f3.getBoolean, fmi3GetBooleanTYPE, "fmi3GetBoolean");
        LOAD(f->f3.doStep, fmi3DoStepTYPE, "fmi3DoStep");
        if (f->states) {
            LOAD(f->f3.getState, fmi3GetFMUStateTYPE, "fmi3GetFMUState");
            LOAD(f->f3.setState, fmi3SetFMUStateTYPE, "fmi3SetFMUState");
            LOAD(f->f3.freeState, fmi3FreeFMUStateTYPE, "fmi3FreeFMUState");
            LOAD(f->f3.stateSize, fmi3SerializedFMUStateSizeTYPE, "fmi3SerializedFMUStateSize");
            LOAD(f->f3.serializeState, fmi3SerializeFMUStateTYPE, "fmi3SerializeFMUState");
            LOAD(f->f3.deserializeState, fmi3DeserializeFMUStateTYPE, "fmi3DeserializeFMUState");
        }
    }
    if (missing) {
        say("%s: %d FMI %d.0 co-simulation function(s) missing", f->binary, missing, f->version);
        return -1;
    }
    version = f->version == 2 ? f->f2.getVersion() : f->f3.getVersion();
    if (!version || (f->version == 2 ? strcmp(version, "2.0") != 0
                                     : strncmp(version, "3.", 2) != 0)) {
        say("%s: fmi%dGetVersion() says \"%s\", this host wants %s", f->binary, f->version,
            version ? version : "(null)", f->version == 2 ? "2.0" : "3.x");
        return -1;
    }
    return 0;
}

/* "file://" and the absolute path, percent-encoded (RFC 3986: unreserved characters and '/'
   stay) and ending in '/'. Windows: "C:\dir" becomes "file:///C:/dir/" (RFC 8089's form, the
   drive's ':' as it is). */
static char *file_uri(const char *absolute) {
    static const char hex[] = "0123456789ABCDEF";
    size_t n = strlen(absolute);
    char *out = malloc(8 + 3 * n + 2), *q;
    const unsigned char *p;
    if (!out) return NULL;
    q = out + 7;
    memcpy(out, "file://", 7);
#ifdef _WIN32
    if (absolute[0] && absolute[1] == ':') {
        *q++ = '/';
        *q++ = absolute[0];
        *q++ = ':';
        absolute += 2;
    }
#endif
    for (p = (const unsigned char *)absolute; *p; p++) {
#ifdef _WIN32
        if (*p == '\\') {
            *q++ = '/';
            continue;
        }
#endif
        if ((*p >= 'a' && *p <= 'z') || (*p >= 'A' && *p <= 'Z') || (*p >= '0' && *p <= '9') ||
            *p == '-' || *p == '.' || *p == '_' || *p == '~' || *p == '/') {
            *q++ = (char)*p;
        } else {
            *q++ = '%';
            *q++ = hex[*p >> 4];
            *q++ = hex[*p & 15];
        }
    }
    if (q[-1] != '/') *q++ = '/';
    *q = '\0';
    return out;
}

#ifdef _WIN32
#define PATH_SEPARATOR "\\"
/* The absolute path of an existing folder (malloc'd), or NULL with the reason reported. */
static char *absolute_folder(const char *path) {
    DWORD n = GetFullPathNameA(path, 0, NULL, NULL), attributes;
    char *absolute = n ? malloc(n) : NULL;
    if (!absolute || GetFullPathNameA(path, n, absolute, NULL) == 0) {
        say("%s: not a folder: %s", path, absolute ? last_error_text() : "out of memory");
        free(absolute);
        return NULL;
    }
    attributes = GetFileAttributesA(absolute);
    if (attributes == INVALID_FILE_ATTRIBUTES || !(attributes & FILE_ATTRIBUTE_DIRECTORY)) {
        say("%s: not a folder%s", path, attributes == INVALID_FILE_ATTRIBUTES ? ": not found" : "");
        free(absolute);
        return NULL;
    }
    n = (DWORD)strlen(absolute);
    while (n > 3 && (absolute[n - 1] == '\\' || absolute[n - 1] == '/')) absolute[--n] = '\0';
    return absolute;
}
#else
#define PATH_SEPARATOR "/"
static char *absolute_folder(const char *path) {
    char *absolute = realpath(path, NULL);
    if (!absolute) say("%s: not a folder: %s", path, strerror(errno));
    return absolute;
}
#endif

static int fmu_instantiate(Fmu *f, const char *resources, const char *guid) {
    char *absolute = absolute_folder(resources), *location;
    if (!absolute) return -1;
    if (f->version == 2) {
        location = file_uri(absolute);
    } else {
        location = malloc(strlen(absolute) + 2);
        if (location) sprintf(location, "%s" PATH_SEPARATOR, absolute);
    }
    free(absolute);
    if (!location) {
        say("out of memory");
        return -1;
    }
    if (f->version == 2) {
        f->callbacks2.logger = log_fmi2;
        f->callbacks2.allocateMemory = calloc;
        f->callbacks2.freeMemory = free;
        f->callbacks2.stepFinished = NULL;
        f->callbacks2.componentEnvironment = &f->sink;
        f->instance = f->f2.instantiate(PROGRAM, fmi2CoSimulation, guid, location,
                                        &f->callbacks2, fmi2False,
                                        f->sink.verbose ? fmi2True : fmi2False);
    } else {
        f->instance = f->f3.instantiateCoSimulation(
            PROGRAM, guid, location, fmi3False, f->sink.verbose ? fmi3True : fmi3False,
            fmi3False, fmi3False, NULL, 0, &f->sink, log_fmi3, NULL);
    }
    if (!f->instance) {
        report_call(&f->sink, location, f->version == 2 ? "fmi2Instantiate"
                                                        : "fmi3InstantiateCoSimulation", 3);
        free(location);
        return -1;
    }
    report_call(&f->sink, location,
                f->version == 2 ? "fmi2Instantiate" : "fmi3InstantiateCoSimulation", 0);
    free(location);
    return 0;
}

static const char *call_name(const Fmu *f, const char *fmi2, const char *fmi3) {
    return f->version == 2 ? fmi2 : fmi3;
}

/* Sets the group's variables to row[index[i]] (numbers; integers and booleans exact). */
static int fmu_set(Fmu *f, const Group *g, const double *row) {
    size_t i;
    if (g->n == 0) return 0;
    switch (g->type) {
    case T_REAL:
        for (i = 0; i < g->n; i++) f->reals[i] = row[g->index[i]];
        return f->version == 2 ? (int)f->f2.setReal(f->instance, g->vr2, g->n, f->reals)
                               : (int)f->f3.setFloat64(f->instance, g->vr3, g->n, f->reals, g->n);
    case T_INTEGER:
        if (f->version == 2) {
            for (i = 0; i < g->n; i++) f->ints2[i] = (fmi2Integer)row[g->index[i]];
            return (int)f->f2.setInteger(f->instance, g->vr2, g->n, f->ints2);
        }
        for (i = 0; i < g->n; i++) f->ints3[i] = (fmi3Int32)row[g->index[i]];
        return (int)f->f3.setInt32(f->instance, g->vr3, g->n, f->ints3, g->n);
    case T_BOOLEAN:
        if (f->version == 2) {
            for (i = 0; i < g->n; i++) f->bools2[i] = row[g->index[i]] != 0.0;
            return (int)f->f2.setBoolean(f->instance, g->vr2, g->n, f->bools2);
        }
        for (i = 0; i < g->n; i++) f->bools3[i] = row[g->index[i]] != 0.0;
        return (int)f->f3.setBoolean(f->instance, g->vr3, g->n, f->bools3, g->n);
    default:
        return 3;
    }
}

/* Reads the group's variables into row[index[i]]. */
static int fmu_get(Fmu *f, const Group *g, double *row) {
    size_t i;
    int s;
    if (g->n == 0) return 0;
    switch (g->type) {
    case T_REAL:
        s = f->version == 2 ? (int)f->f2.getReal(f->instance, g->vr2, g->n, f->reals)
                            : (int)f->f3.getFloat64(f->instance, g->vr3, g->n, f->reals, g->n);
        for (i = 0; i < g->n; i++) row[g->index[i]] = f->reals[i];
        return s;
    case T_INTEGER:
        if (f->version == 2) {
            s = (int)f->f2.getInteger(f->instance, g->vr2, g->n, f->ints2);
            for (i = 0; i < g->n; i++) row[g->index[i]] = f->ints2[i];
        } else {
            s = (int)f->f3.getInt32(f->instance, g->vr3, g->n, f->ints3, g->n);
            for (i = 0; i < g->n; i++) row[g->index[i]] = f->ints3[i];
        }
        return s;
    case T_BOOLEAN:
        if (f->version == 2) {
            s = (int)f->f2.getBoolean(f->instance, g->vr2, g->n, f->bools2);
            for (i = 0; i < g->n; i++) row[g->index[i]] = f->bools2[i] ? 1.0 : 0.0;
        } else {
            s = (int)f->f3.getBoolean(f->instance, g->vr3, g->n, f->bools3, g->n);
            for (i = 0; i < g->n; i++) row[g->index[i]] = f->bools3[i] ? 1.0 : 0.0;
        }
        return s;
    default:
        return 3;
    }
}

static const char *group_call(const Fmu *f, VarType type, int set) {
    static const char *const names[2][2][3] = {
        {{"fmi2GetReal", "fmi2GetInteger", "fmi2GetBoolean"},
         {"fmi2SetReal", "fmi2SetInteger", "fmi2SetBoolean"}},
        {{"fmi3GetFloat64", "fmi3GetInt32", "fmi3GetBoolean"},
         {"fmi3SetFloat64", "fmi3SetInt32", "fmi3SetBoolean"}}};
    return names[f->version == 3][set != 0][type <= T_BOOLEAN ? type : 0];
}

static int fmu_set_param(Fmu *f, const Param *p) {
    fmi2ValueReference vr2 = p->var.vr;
    fmi3ValueReference vr3 = p->var.vr;
    double row[1];
    Group g;
    size_t zero = 0;
    if (p->var.type == T_STRING)
        return f->version == 2 ? (int)f->f2.setString(f->instance, &vr2, 1, &p->text)
                               : (int)f->f3.setString(f->instance, &vr3, 1, &p->text, 1);
    row[0] = p->number;
    g.type = p->var.type;
    g.n = 1;
    g.index = &zero;
    g.vr2 = &vr2;
    g.vr3 = &vr3;
    return fmu_set(f, &g, row);
}

/* ======================================================================== the run */

typedef struct {
    int version;
    const char *binary, *resources, *guid, *params_path, *inputs_path, *out_path;
    int n_outputs;
    char **outputs;
    int fixed_step, stop_given, hold, quiet, verbose;
    double step, stop;
    long state_row;       /* -k: the row before whose step the FMU state is taken; -1: none */
    const char *state_out, *state_in, *report_path;     /* -S, -L, -R */
} Args;

static void usage(FILE *to) {
    fputs("usage: " PROGRAM " [-s STEP] [-e STOP] [-d hold|stop] [-q] [-v] "
          "[-k ROW -R REPORT.txt [-S STATE.bin] [-L STATE.bin]] fmi2|fmi3 BINARY "
          "RESOURCE_DIR GUID PARAMS.csv INPUTS.csv OUT.csv OUTPUT...\n"
          "  OUTPUT: a value reference, optionally typed: 12 or r12 (real), i12, b12\n"
          "  (the header of csv_host.c documents the files, the options and the exit status)\n",
          to);
}

static int parse_args(int argc, char **argv, Args *a) {
    int i = 1;
    memset(a, 0, sizeof *a);
    a->hold = 1;
    a->state_row = -1;
    for (; i < argc && argv[i][0] == '-' && argv[i][1] != '\0'; i++) {
        const char *o = argv[i];
        if (!strcmp(o, "--")) {
            i++;
            break;
        }
        if (!strcmp(o, "-h") || !strcmp(o, "--help")) {
            usage(stdout);
            exit(0);
        }
        if (!strcmp(o, "-q")) {
            a->quiet = 1;
        } else if (!strcmp(o, "-v")) {
            a->verbose = 1;
        } else if (!strcmp(o, "-S") || !strcmp(o, "-L") || !strcmp(o, "-R")) {
            const char *v = i + 1 < argc ? argv[++i] : NULL;
            if (!v || !*v) {
                say("option %s needs a file", o);
                return -1;
            }
            if (o[1] == 'S') a->state_out = v;
            else if (o[1] == 'L') a->state_in = v;
            else a->report_path = v;
        } else if (!strcmp(o, "-k")) {
            const char *v = i + 1 < argc ? argv[++i] : NULL;
            double row;
            if (!v || parse_int32(v, &row) != 0 || row < 0.0) {
                say("-k %s: the row is an integer >= 0 (0: right after initialisation)",
                    v ? v : "");
                return -1;
            }
            a->state_row = (long)row;
        } else if (!strcmp(o, "-s") || !strcmp(o, "-e") || !strcmp(o, "-d")) {
            const char *v = i + 1 < argc ? argv[++i] : NULL;
            double x;
            if (!v) {
                say("option %s needs a value", o);
                return -1;
            }
            if (o[1] == 'd') {
                if (!strcmp(v, "hold")) a->hold = 1;
                else if (!strcmp(v, "stop")) a->hold = 0;
                else {
                    say("-d %s: the discard policy is hold or stop", v);
                    return -1;
                }
            } else if (parse_real(v, &x) != 0 || !isfinite(x) || (o[1] == 's' && !(x > 0.0))) {
                say("%s %s: not a finite number%s", o, v, o[1] == 's' ? " > 0" : "");
                return -1;
            } else if (o[1] == 's') {
                a->fixed_step = 1;
                a->step = x;
            } else {
                a->stop_given = 1;
                a->stop = x;
            }
        } else {
            say("unknown option %s", o);
            return -1;
        }
    }
    if (argc - i < 8) {
        say("%d argument(s) after the options, at least 8 needed", argc - i);
        return -1;
    }
    if (!strcmp(argv[i], "fmi2")) a->version = 2;
    else if (!strcmp(argv[i], "fmi3")) a->version = 3;
    else {
        say("\"%s\": the FMI version is fmi2 or fmi3", argv[i]);
        return -1;
    }
    a->binary = argv[i + 1];
    a->resources = argv[i + 2];
    a->guid = argv[i + 3];
    a->params_path = argv[i + 4];
    a->inputs_path = argv[i + 5];
    a->out_path = argv[i + 6];
    a->outputs = argv + i + 7;
    a->n_outputs = argc - i - 7;
    if (!a->fixed_step && !a->stop_given) {
        say("give -s STEP (each row's step size) or -e STOP (the last row's step ends there)");
        return -1;
    }
    if (a->state_row < 0 && (a->state_out || a->state_in || a->report_path)) {
        say("-S, -L and -R go with -k ROW (the FMU state's round trip)");
        return -1;
    }
    if (a->state_row >= 0 && !a->report_path) {
        say("-k %ld needs -R REPORT.txt (where the round trip's result is written)",
            a->state_row);
        return -1;
    }
    return 0;
}

/* Splits vars[0..n) into groups by type (real, integer, boolean). */
static int make_groups(const Var *vars, size_t n, Group groups[3]) {
    int t;
    for (t = 0; t < 3; t++) {
        size_t i, m = 0;
        Group *g = &groups[t];
        g->type = (VarType)t;
        for (i = 0; i < n; i++) m += vars[i].type == (VarType)t;
        g->n = 0;
        g->index = malloc((m ? m : 1) * sizeof *g->index);
        g->vr2 = malloc((m ? m : 1) * sizeof *g->vr2);
        g->vr3 = malloc((m ? m : 1) * sizeof *g->vr3);
        if (!g->index || !g->vr2 || !g->vr3) return -1;
        for (i = 0; i < n; i++)
            if (vars[i].type == (VarType)t) {
                g->index[g->n] = i;
                g->vr2[g->n] = vars[i].vr;
                g->vr3[g->n] = vars[i].vr;
                g->n++;
            }
    }
    return 0;
}

static void free_groups(Group groups[3]) {
    int t;
    for (t = 0; t < 3; t++) {
        free(groups[t].index);
        free(groups[t].vr2);
        free(groups[t].vr3);
    }
}

typedef struct {
    Fmu fmu;
    Args args;
    Params params;
    Inputs inputs;
    Var *out_vars;
    Group in_groups[3], out_groups[3];
    double *held;          /* the inputs of the last accepted row */
    long held_line;        /* its line in INPUTS.csv; 0: the values after initialisation */
    double *out_row;
    FILE *out;
    char where[512];
    long warnings, discards, errors, rows;
    /* -k: the FMU state's round trip */
    FILE *report;          /* -R */
    double *recorded;      /* pass A's rows from the state's row on: time, outputs, status */
    double *held_at_state; /* held and held_line when the state was taken */
    long held_line_at_state;
    void *state;           /* the state taken with get (fmi2FMUstate and fmi3FMUState: void *) */
    void *restored;        /* the state deserialized from the bytes */
    unsigned char *bytes;  /* the state serialized */
    size_t n_bytes;
    unsigned char *foreign;        /* -L: bytes another host serialized, for pass B */
    size_t n_foreign;
    long mismatches;       /* replayed rows that differ from pass A */
} Host;

/* After an FMU call: report it and count; 0 if the run may go on (OK, Warning), the status
   otherwise (Discard left to the caller; Error and Fatal mark the instance). */
static int after_call(Host *h, const char *call, int status) {
    h->warnings += report_call(&h->fmu.sink, h->where, call, status);
    if (status >= 3) {
        h->errors++;
        h->fmu.dead = 1;
        h->fmu.fatal = status >= 4;
    }
    return status <= 1 ? 0 : status;
}

static int set_all(Host *h, const double *row) {
    int t, s;
    for (t = 0; t < 3; t++) {
        s = after_call(h, group_call(&h->fmu, (VarType)t, 1),
                       fmu_set(&h->fmu, &h->in_groups[t], row));
        if (s) {
            if (s == 2) {       /* no set function may discard: an error */
                say("%s: a set call returned Discard", h->where);
                h->errors++;
            }
            return -1;
        }
    }
    return 0;
}

static int get_outputs(Host *h) {
    int t, s;
    for (t = 0; t < 3; t++) {
        s = after_call(h, group_call(&h->fmu, (VarType)t, 0),
                       fmu_get(&h->fmu, &h->out_groups[t], h->out_row));
        if (s) {
            if (s == 2) h->errors++;
            return -1;
        }
    }
    return 0;
}

static int write_row(Host *h, double time, int status) {
    int i;
    fprintf(h->out, "%.17g", time);
    for (i = 0; i < h->args.n_outputs; i++) {
        if (h->out_vars[i].type == T_REAL) fprintf(h->out, ",%.17g", h->out_row[i]);
        else fprintf(h->out, ",%.0f", h->out_row[i]);
    }
    fprintf(h->out, ",%d\n", status);
    h->rows++;
    return ferror(h->out) ? -1 : 0;
}

/* One doStep; the status (0..4), *end = the time the FMU reached. */
static int do_step(Host *h, double t, double step, double *end, int *terminate) {
    Fmu *f = &h->fmu;
    int s;
    *terminate = 0;
    if (f->version == 2) {
        s = (int)f->f2.doStep(f->instance, t, step, fmi2True);
        *end = t + step;
    } else {
        fmi3Boolean event = fmi3False, term = fmi3False, early = fmi3False;
        fmi3Float64 last = t;
        s = (int)f->f3.doStep(f->instance, t, step, fmi3True, &event, &term, &early, &last);
        *end = last;
        *terminate = term;
        if (s <= 1 && (early || event)) {
            say("%s: fmi3DoStep returned early or asked for event handling, which this host "
                "did not allow (earlyReturnAllowed and eventModeUsed are false)", h->where);
            return 3;
        }
    }
    return s;
}

/* Row k's step: its inputs set, doStep, -d hold's retry of a discarded step. 0 with the time
   reached (*end), the row's status (0, 1, 2: discarded and retried) and the FMU's terminate
   request; or the run's exit status. */
static int step_row(Host *h, size_t k, double *end, int *row_status, int *terminate) {
    Args *a = &h->args;
    Fmu *f = &h->fmu;
    Inputs *in = &h->inputs;
    const double *row = in->values + k * in->n_cols;
    double tk = in->time[k], stop = a->stop_given ? a->stop : in->time[in->n_rows - 1] + a->step;
    double step = a->fixed_step ? a->step : (k + 1 < in->n_rows ? in->time[k + 1] : stop) - tk;
    int s;
    snprintf(h->where, sizeof h->where, "%s:%ld (t = %.17g)", a->inputs_path, in->line[k], tk);
    if (set_all(h, row) != 0) return EXIT_RUN_FAILED;
    s = do_step(h, tk, step, end, terminate);
    *row_status = s;
    if (s == 2) {
        h->discards++;
        h->warnings += report_call(&f->sink, h->where,
                                   call_name(f, "fmi2DoStep", "fmi3DoStep"), s);
        if (!a->hold) {
            say("%s: stopped (-d stop)", h->where);
            return EXIT_RUN_FAILED;
        }
        if (h->held_line > 0)
            say("%s: retried from t = %.17g over %.17g s with the inputs of %s:%ld", h->where,
                tk, step, a->inputs_path, h->held_line);
        else
            say("%s: retried from t = %.17g over %.17g s with the inputs the FMU had after "
                "initialisation", h->where, tk, step);
        if (set_all(h, h->held) != 0) return EXIT_RUN_FAILED;
        s = do_step(h, tk, step, end, terminate);
        if (s == 2) {
            h->discards++;
            h->warnings += report_call(&f->sink, h->where,
                                       call_name(f, "fmi2DoStep", "fmi3DoStep"), s);
            say("%s: the retry was discarded too: stopped", h->where);
            return EXIT_RUN_FAILED;
        }
    } else {
        memcpy(h->held, row, in->n_cols * sizeof *row);
        h->held_line = in->line[k];
    }
    if (after_call(h, call_name(f, "fmi2DoStep", "fmi3DoStep"), s)) return EXIT_RUN_FAILED;
    return 0;
}

/* ---------------------------------------------------------------- -k: the FMU state's round trip
 * Before row K's step (-k K) the host takes the FMU state (get), asks its serialized size and
 * serializes it (-S: the bytes written to a file); pass A, the normal run, goes on to the end
 * and its rows from K on are kept. Pass B: the bytes (or -L's, another host's) deserialized into
 * a new state, that state set, rows K.. replayed with the same inputs; pass C: the state taken
 * with get set once more and replayed again. Every replayed row (the outputs right after the
 * set; then after each step: the time reached, the outputs, the status) must equal pass A's bit
 * for bit. Both states are freed. REPORT.txt (-R), one "key value" line each:
 *   row K, serialized_size N, bytes_written FILE (-S), bytes_read FILE N (-L),
 *   pass_b identical | pass_b differs row R column NAME: A VALUE, replay VALUE (the first),
 *   pass_c likewise, failed CALL... (a call that failed: the line on standard error).
 * A replay that differs makes the exit status 2 (after both passes ran). */

static void record_row(Host *h, double *dest, double time, int status) {
    int n = h->args.n_outputs;
    dest[0] = time;
    memcpy(dest + 1, h->out_row, (size_t)n * sizeof *dest);
    dest[n + 1] = (double)status;
}

/* A whole file's bytes (malloc'd, *n long); NULL with the reason reported. */
static unsigned char *read_bytes(const char *path, size_t *n) {
    FILE *in = fopen(path, "rb");
    unsigned char *data = NULL, *grown;
    size_t cap = 0, got;
    *n = 0;
    if (!in) {
        say("%s: cannot open: %s", path, strerror(errno));
        return NULL;
    }
    do {
        if (*n == cap) {
            cap = cap ? 2 * cap : 65536;
            if (!(grown = realloc(data, cap))) {
                say("%s: out of memory", path);
                free(data);
                fclose(in);
                return NULL;
            }
            data = grown;
        }
        got = fread(data + *n, 1, cap - *n, in);
        *n += got;
    } while (got > 0);
    if (ferror(in)) {
        say("%s: cannot read: %s", path, strerror(errno));
        free(data);
        data = NULL;
    }
    fclose(in);
    return data;
}

/* get, size, serialize (the bytes kept; -S: written); the inputs held for -d hold kept too. */
static int take_state(Host *h) {
    Fmu *f = &h->fmu;
    int s;
    snprintf(h->where, sizeof h->where, "-k %ld (t = %.17g)", h->args.state_row,
             h->inputs.time[h->args.state_row]);
    s = f->version == 2 ? (int)f->f2.getState(f->instance, &h->state)
                        : (int)f->f3.getState(f->instance, &h->state);
    if (after_call(h, call_name(f, "fmi2GetFMUstate", "fmi3GetFMUState"), s))
        return EXIT_RUN_FAILED;
    s = f->version == 2 ? (int)f->f2.stateSize(f->instance, h->state, &h->n_bytes)
                        : (int)f->f3.stateSize(f->instance, h->state, &h->n_bytes);
    if (after_call(h, call_name(f, "fmi2SerializedFMUstateSize", "fmi3SerializedFMUStateSize"),
                   s))
        return EXIT_RUN_FAILED;
    if (!(h->bytes = malloc(h->n_bytes ? h->n_bytes : 1))) {
        say("%s: out of memory (%lu bytes for the serialized state)", h->where,
            (unsigned long)h->n_bytes);
        return EXIT_RUN_FAILED;
    }
    s = f->version == 2
            ? (int)f->f2.serializeState(f->instance, h->state, (fmi2Byte *)h->bytes, h->n_bytes)
            : (int)f->f3.serializeState(f->instance, h->state, (fmi3Byte *)h->bytes, h->n_bytes);
    if (after_call(h, call_name(f, "fmi2SerializeFMUstate", "fmi3SerializeFMUState"), s))
        return EXIT_RUN_FAILED;
    fprintf(h->report, "row %ld\nserialized_size %lu\n", h->args.state_row,
            (unsigned long)h->n_bytes);
    if (h->args.state_out) {
        FILE *out = fopen(h->args.state_out, "wb");
        if (!out || fwrite(h->bytes, 1, h->n_bytes, out) != h->n_bytes || fclose(out) != 0) {
            say("%s: cannot write: %s", h->args.state_out, strerror(errno));
            return EXIT_BAD_INPUT;
        }
        fprintf(h->report, "bytes_written %s\n", h->args.state_out);
    }
    memcpy(h->held_at_state, h->held, (h->inputs.n_cols + 1) * sizeof *h->held);
    h->held_line_at_state = h->held_line;
    /* the state's own row of pass A: the outputs it was taken with */
    record_row(h, h->recorded, h->inputs.time[h->args.state_row], 0);
    return 0;
}

/* The first column where a replayed row (time, outputs, status) differs from pass A's, bit for
   bit; -1: none. `from` 1 skips the time (the row right after a set has no step). */
static int first_difference(const double *a, const double *b, int n, int from) {
    int j;
    for (j = from; j < n; j++)
        if (memcmp(a + j, b + j, sizeof *a) != 0) return j;
    return -1;
}

/* Sets `state` and replays rows K.. against pass A; 0 (differences counted and reported), or
   the run's exit status when a call fails. */
static int replay(Host *h, const char *pass, void *state, const char *how) {
    Args *a = &h->args;
    Fmu *f = &h->fmu;
    int width = a->n_outputs + 2, s, terminate, row_status, column;
    size_t k, K = (size_t)a->state_row;
    double *got = malloc((size_t)width * sizeof *got), end;
    if (!got) {
        say("out of memory");
        return EXIT_RUN_FAILED;
    }
    snprintf(h->where, sizeof h->where, "%s (%s, row %ld)", pass, how, a->state_row);
    s = f->version == 2 ? (int)f->f2.setState(f->instance, state)
                        : (int)f->f3.setState(f->instance, state);
    if (after_call(h, call_name(f, "fmi2SetFMUstate", "fmi3SetFMUState"), s)) {
        free(got);
        return EXIT_RUN_FAILED;
    }
    memcpy(h->held, h->held_at_state, (h->inputs.n_cols + 1) * sizeof *h->held);
    h->held_line = h->held_line_at_state;
    if (get_outputs(h) != 0) {
        free(got);
        return EXIT_RUN_FAILED;
    }
    record_row(h, got, h->recorded[0], 0);
    column = first_difference(h->recorded, got, width, 1);
    for (k = K; column < 0 && k < h->inputs.n_rows; k++) {
        if ((s = step_row(h, k, &end, &row_status, &terminate)) != 0 || get_outputs(h) != 0) {
            free(got);
            return s ? s : EXIT_RUN_FAILED;
        }
        record_row(h, got, end, row_status);
        column = first_difference(h->recorded + (k + 1 - K) * (size_t)width, got, width, 0);
        if (terminate && k + 1 < h->inputs.n_rows) {
            say("%s: the FMU asked to terminate the replay at t = %.17g", h->where, end);
            free(got);
            return EXIT_RUN_FAILED;
        }
    }
    if (column < 0) {
        fprintf(h->report, "%s identical\n", pass);
    } else {
        size_t row = k;         /* the row that differs: the loop stopped just past its step */
        const double *ref = h->recorded + (row - K) * (size_t)width;
        const char *name = column == 0 ? "time" : column == width - 1 ? "status"
                                                                     : a->outputs[column - 1];
        h->mismatches++;
        fprintf(h->report, "%s differs row %lu column %s: A %.17g, replay %.17g\n", pass,
                (unsigned long)row, name, ref[column], got[column]);
        say("%s: %s (%s) differs from the run at row %lu of %s, column %s: %.17g, not %.17g",
            h->where, pass, how, (unsigned long)row, a->out_path, name, got[column],
            ref[column]);
    }
    free(got);
    return 0;
}

/* Passes B (the bytes deserialized) and C (the state taken with get), then both states freed. */
static int round_trip(Host *h) {
    Fmu *f = &h->fmu;
    const unsigned char *bytes = h->foreign ? h->foreign : h->bytes;
    size_t n = h->foreign ? h->n_foreign : h->n_bytes;
    int s;
    snprintf(h->where, sizeof h->where, "pass_b (row %ld, %s)", h->args.state_row,
             h->foreign ? h->args.state_in : "the bytes serialized");
    s = f->version == 2
            ? (int)f->f2.deserializeState(f->instance, (const fmi2Byte *)bytes, n, &h->restored)
            : (int)f->f3.deserializeState(f->instance, (const fmi3Byte *)bytes, n, &h->restored);
    if (after_call(h, call_name(f, "fmi2DeSerializeFMUstate", "fmi3DeserializeFMUState"), s))
        return EXIT_RUN_FAILED;
    if ((s = replay(h, "pass_b", h->restored,
                    h->foreign ? h->args.state_in : "the bytes serialized")) != 0)
        return s;
    if ((s = replay(h, "pass_c", h->state, "the state taken with get")) != 0) return s;
    return h->mismatches ? EXIT_RUN_FAILED : 0;
}

/* Frees the states (allowed after Error too; not after Fatal); 0, or the exit status. */
static int free_states(Host *h) {
    Fmu *f = &h->fmu;
    void **states[2];
    int i, rc = 0;
    states[0] = &h->state;
    states[1] = &h->restored;
    snprintf(h->where, sizeof h->where, "the end");
    for (i = 0; i < 2; i++) {
        int s;
        if (!*states[i] || !f->instance || f->fatal) continue;
        s = f->version == 2 ? (int)f->f2.freeState(f->instance, states[i])
                            : (int)f->f3.freeState(f->instance, states[i]);
        if (after_call(h, call_name(f, "fmi2FreeFMUstate", "fmi3FreeFMUState"), s))
            rc = EXIT_RUN_FAILED;
    }
    return rc;
}

static int run(Host *h) {
    Args *a = &h->args;
    Fmu *f = &h->fmu;
    Inputs *in = &h->inputs;
    size_t k, n_max;
    int t, s, exit_code = 0;
    double start, stop;

    /* ---- files and arguments, all checked before the FMU is loaded */
    if (params_read(&h->params, a->params_path) != 0) return EXIT_BAD_INPUT;
    if (inputs_read(in, a->inputs_path) != 0) return EXIT_BAD_INPUT;
    h->out_vars = malloc((size_t)a->n_outputs * sizeof *h->out_vars);
    h->out_row = malloc(((size_t)a->n_outputs + 1) * sizeof *h->out_row);
    h->held = malloc((in->n_cols + 1) * sizeof *h->held);
    if (!h->out_vars || !h->out_row || !h->held) {
        say("out of memory");
        return EXIT_BAD_INPUT;
    }
    for (t = 0; t < a->n_outputs; t++)
        if (parse_var(a->outputs[t], &h->out_vars[t]) != 0) {
            say("output \"%s\" is not a value reference (12, r12, i12 or b12)", a->outputs[t]);
            return EXIT_BAD_INPUT;
        }
    if (make_groups(in->cols, in->n_cols, h->in_groups) != 0 ||
        make_groups(h->out_vars, (size_t)a->n_outputs, h->out_groups) != 0) {
        say("out of memory");
        return EXIT_BAD_INPUT;
    }
    start = in->time[0];
    stop = a->stop_given ? a->stop : in->time[in->n_rows - 1] + a->step;
    if (!a->fixed_step && !(stop > in->time[in->n_rows - 1])) {
        say("-e %.17g: the stop time must come after the last row's time %.17g (%s:%ld)", stop,
            in->time[in->n_rows - 1], a->inputs_path, in->line[in->n_rows - 1]);
        return EXIT_BAD_INPUT;
    }
    if (!(stop > start)) {
        say("the stop time %.17g must come after the start time %.17g", stop, start);
        return EXIT_BAD_INPUT;
    }
    if (a->state_row >= 0) {
        if ((size_t)a->state_row >= in->n_rows) {
            say("-k %ld: %s has %lu row(s); the state is taken before a row's step (0 .. %lu)",
                a->state_row, a->inputs_path, (unsigned long)in->n_rows,
                (unsigned long)in->n_rows - 1);
            return EXIT_BAD_INPUT;
        }
        h->recorded = malloc((in->n_rows - (size_t)a->state_row + 1) *
                             ((size_t)a->n_outputs + 2) * sizeof *h->recorded);
        h->held_at_state = malloc((in->n_cols + 1) * sizeof *h->held_at_state);
        if (!h->recorded || !h->held_at_state) {
            say("out of memory");
            return EXIT_BAD_INPUT;
        }
        if (a->state_in && !(h->foreign = read_bytes(a->state_in, &h->n_foreign)))
            return EXIT_BAD_INPUT;
        if (!(h->report = fopen(a->report_path, "w"))) {
            say("%s: cannot write: %s", a->report_path, strerror(errno));
            return EXIT_BAD_INPUT;
        }
        if (a->state_in)
            fprintf(h->report, "bytes_read %s %lu\n", a->state_in, (unsigned long)h->n_foreign);
        f->states = 1;
    }
    n_max = in->n_cols > (size_t)a->n_outputs ? in->n_cols : (size_t)a->n_outputs;
    f->reals = malloc((n_max + 1) * sizeof *f->reals);
    f->ints2 = malloc((n_max + 1) * sizeof *f->ints2);
    f->ints3 = malloc((n_max + 1) * sizeof *f->ints3);
    f->bools2 = malloc((n_max + 1) * sizeof *f->bools2);
    f->bools3 = malloc((n_max + 1) * sizeof *f->bools3);
    if (!f->reals || !f->ints2 || !f->ints3 || !f->bools2 || !f->bools3) {
        say("out of memory");
        return EXIT_BAD_INPUT;
    }
    /* ---- load, instantiate, initialise */
    if (fmu_load(f) != 0) return EXIT_BAD_INPUT;
    if (fmu_instantiate(f, a->resources, a->guid) != 0) {
        h->errors++;
        return EXIT_RUN_FAILED;
    }
    snprintf(h->where, sizeof h->where, "initialisation (start %.17g s, stop %.17g s)", start,
             stop);
    if (f->version == 2) {
        s = after_call(h, "fmi2SetupExperiment",
                       (int)f->f2.setupExperiment(f->instance, fmi2False, 0.0, start, fmi2True,
                                                  stop));
        if (!s) s = after_call(h, "fmi2EnterInitializationMode",
                               (int)f->f2.enterInitializationMode(f->instance));
    } else {
        s = after_call(h, "fmi3EnterInitializationMode",
                       (int)f->f3.enterInitializationMode(f->instance, fmi3False, 0.0, start,
                                                          fmi3True, stop));
    }
    if (s) return EXIT_RUN_FAILED;
    for (k = 0; k < h->params.n; k++) {
        const Param *p = &h->params.items[k];
        char call[64];
        snprintf(h->where, sizeof h->where, "%s:%ld", a->params_path, p->line);
        snprintf(call, sizeof call, "%s(vr %lu)",
                 p->var.type == T_STRING ? call_name(f, "fmi2SetString", "fmi3SetString")
                                         : group_call(f, p->var.type, 1),
                 (unsigned long)p->var.vr);
        if (after_call(h, call, fmu_set_param(f, p))) return EXIT_RUN_FAILED;
    }
    snprintf(h->where, sizeof h->where, "initialisation (start %.17g s, stop %.17g s)", start,
             stop);
    if (after_call(h, call_name(f, "fmi2ExitInitializationMode", "fmi3ExitInitializationMode"),
                   f->version == 2 ? (int)f->f2.exitInitializationMode(f->instance)
                                   : (int)f->f3.exitInitializationMode(f->instance)))
        return EXIT_RUN_FAILED;
    /* the inputs a first discarded row is retried with, and the row at the start time */
    for (t = 0; t < 3; t++)
        if (after_call(h, group_call(f, (VarType)t, 0), fmu_get(f, &h->in_groups[t], h->held)))
            return EXIT_RUN_FAILED;
    if (get_outputs(h) != 0) return EXIT_RUN_FAILED;
    /* OUT.csv is created once the FMU initialised: a run that cannot start leaves none */
    if (strcmp(a->out_path, "-") == 0) {
        h->out = stdout;
    } else if (!(h->out = fopen(a->out_path, "w"))) {
        say("%s: cannot write: %s", a->out_path, strerror(errno));
        return EXIT_BAD_INPUT;
    }
    fputs("time [s]", h->out);
    for (t = 0; t < a->n_outputs; t++) fprintf(h->out, ",%s", a->outputs[t]);
    fputs(",status\n", h->out);
    if (write_row(h, start, 0) != 0) return EXIT_BAD_INPUT;

    /* ---- the rows */
    for (k = 0; k < in->n_rows; k++) {
        double end;
        int terminate, row_status;
        if (a->state_row >= 0 && k == (size_t)a->state_row) {
            s = take_state(h);
            if (s) return s;
        }
        s = step_row(h, k, &end, &row_status, &terminate);
        if (s) return s;
        if (row_status == 2) exit_code = EXIT_DISCARDED;
        if (get_outputs(h) != 0) return EXIT_RUN_FAILED;
        if (write_row(h, end, row_status) != 0) return EXIT_BAD_INPUT;
        if (h->recorded && k >= (size_t)a->state_row)
            record_row(h, h->recorded + (k + 1 - (size_t)a->state_row) * (a->n_outputs + 2), end,
                       row_status);
        if (terminate) {
            say("%s: the FMU asked to terminate the simulation at t = %.17g", h->where, end);
            if (k + 1 < in->n_rows) return EXIT_RUN_FAILED;
        }
    }
    if (a->state_row >= 0) {
        s = round_trip(h);
        if (s) return s;
    }
    return exit_code;
}

/* One run: the command line's arguments (argv[0] the program); its exit status. */
static int run_command(int argc, char **argv) {
    Host *h = calloc(1, sizeof *h);
    int rc, instantiated;
    if (!h) {
        say("out of memory");
        return EXIT_BAD_INPUT;
    }
    if (parse_args(argc, argv, &h->args) != 0) {
        usage(stderr);
        free(h);
        return EXIT_BAD_INPUT;
    }
    h->fmu.version = h->args.version;
    h->fmu.binary = h->args.binary;
    h->fmu.sink.verbose = h->args.verbose;
    h->fmu.sink.quiet = h->args.quiet;
    rc = run(h);
    instantiated = h->fmu.instance != NULL;
    {
        int freed = free_states(h);
        if (freed > rc) rc = freed;
    }

    /* ---- finish: terminate and free the instance as the FMI state allows */
    if (h->fmu.instance && !h->fmu.fatal) {
        Fmu *f = &h->fmu;
        snprintf(h->where, sizeof h->where, "the end");
        if (!f->dead) {
            if (after_call(h, call_name(f, "fmi2Terminate", "fmi3Terminate"),
                           f->version == 2 ? (int)f->f2.terminate(f->instance)
                                           : (int)f->f3.terminate(f->instance)) &&
                rc < EXIT_RUN_FAILED)
                rc = EXIT_RUN_FAILED;
        }
        if (f->version == 2) f->f2.freeInstance(f->instance);
        else f->f3.freeInstance(f->instance);
        report_call(&f->sink, h->where, call_name(f, "fmi2FreeInstance", "fmi3FreeInstance"), 0);
    }
    if (h->fmu.library && !h->fmu.fatal) library_close(h->fmu.library);
    if (h->report) {
        if (rc >= EXIT_RUN_FAILED && h->fmu.sink.failure[0])
            fprintf(h->report, "failed %s\n", h->fmu.sink.failure);
        if (fclose(h->report) != 0) {
            say("%s: cannot write: %s", h->args.report_path, strerror(errno));
            rc = EXIT_BAD_INPUT;
        }
    }
    if (h->out && h->out != stdout) {
        if (fclose(h->out) != 0) {
            say("%s: cannot write: %s", h->args.out_path, strerror(errno));
            rc = EXIT_BAD_INPUT;
        }
    } else if (h->out && fflush(h->out) != 0) {
        rc = EXIT_BAD_INPUT;
    }
    if (instantiated && !h->args.quiet)
        say("%ld row(s) written to %s%s, %ld warning(s), %ld discarded step(s), %ld error(s); "
            "exit status %d", h->rows, h->args.out_path, h->out ? "" : " (not created)",
            h->warnings, h->discards, h->errors, rc);
    params_free(&h->params);
    inputs_free(&h->inputs);
    free_groups(h->in_groups);
    free_groups(h->out_groups);
    free(h->out_vars);
    free(h->out_row);
    free(h->held);
    free(h->recorded);
    free(h->held_at_state);
    free(h->bytes);
    free(h->foreign);
    free(h->fmu.reals);
    free(h->fmu.ints2);
    free(h->fmu.ints3);
    free(h->fmu.bools2);
    free(h->fmu.bools3);
    free(h);
    return rc;
}

/* -b RUNS.txt: one run per line, its arguments separated by tabs (paths may hold spaces), each
   run as if given on the command line; the exit status is the largest of the runs'. */
static int run_batch(const char *path) {
    TextFile file;
    size_t k;
    int worst = 0;
    if (text_read(&file, path) != 0) return EXIT_BAD_INPUT;
    if (file.n_lines == 0) {
        say("%s: no run (one line per run, its arguments separated by tabs)", path);
        text_free(&file);
        return EXIT_BAD_INPUT;
    }
    for (k = 0; k < file.n_lines; k++) {
        char *line = file.lines[k], **args, *tab;
        int n = 2, rc;
        for (tab = line; *tab; tab++) n += *tab == '\t';
        args = malloc((size_t)(n + 1) * sizeof *args);
        if (!args) {
            say("%s:%ld: out of memory", path, file.numbers[k]);
            text_free(&file);
            return EXIT_BAD_INPUT;
        }
        args[0] = (char *)PROGRAM;
        for (n = 1;; n++) {
            args[n] = line;
            tab = strchr(line, '\t');
            if (!tab) break;
            *tab = '\0';
            line = tab + 1;
        }
        args[++n] = NULL;
        rc = run_command(n, args);
        free(args);
        if (rc != 0) say("%s:%ld: exit status %d", path, file.numbers[k], rc);
        if (rc > worst) worst = rc;
    }
    text_free(&file);
    return worst;
}

int main(int argc, char **argv) {
    if (argc >= 2 && !strcmp(argv[1], "-b")) {
        if (argc != 3) {
            say("-b takes one file (RUNS.txt) and nothing else");
            return EXIT_BAD_INPUT;
        }
        return run_batch(argv[2]);
    }
    return run_command(argc, argv);
}

/* profile.h -- reading the track profiles (CSV) in C, the twin of models/plant/track.py's
 * parse_profile_csv, GradeProfile.from_csv_text and SpeedProfile.from_csv_text: the same rules,
 * the same doubles bit for bit, and Python's ProfileError messages byte for byte (they name the
 * source and the 1-based line). For the native FMUs, which have no Python.
 *
 * Text is UTF-8 (as Python decodes the file). The rules (models/plant/track.py):
 *   - a UTF-8 byte-order mark at the start is skipped;
 *   - lines are split as Python's str.splitlines() splits them: "\n", "\r\n", "\r", "\v", "\f",
 *     "\x1c", "\x1d", "\x1e" and the Unicode ones U+0085, U+2028, U+2029 (all matched);
 *   - each line is stripped of Python's whitespace (str.strip(): ASCII and Unicode); blank lines
 *     and lines starting with '#' are skipped;
 *   - cells are the line split at ',', each stripped of whitespace, then of surrounding '"';
 *   - the first line left must be the header, exactly the two column names;
 *   - every other line: two numbers as Python's float() reads them (underscores between digits,
 *     "inf"/"nan", Unicode digits and spaces; no hex), finite, distance >= 0 and strictly
 *     increasing, value >= 0 if asked, |value| <= max_abs_value.
 *
 * Memory: a successful parse allocates one block holding distances[] and values[] (n each);
 * a refused one allocates the message. rc_profile_free() releases both; the caller owns the
 * rc_profile and must call it once whatever the status (it is safe on a zeroed struct and
 * twice). Nothing else is kept: no globals, reentrant.
 */
#ifndef RAILCAR_PROFILE_H
#define RAILCAR_PROFILE_H

#include <stddef.h>

#include "rc_common.h"

#define RC_MAX_GRADE 200.0   /* [permille] models.plant.track.MAX_GRADE */
#define RC_MAX_SPEED 200.0   /* [m/s] models.plant.track.MAX_SPEED */

typedef enum {
    RC_PROFILE_GRADE = 0,    /* distance_m,grade_permille; |grade| <= RC_MAX_GRADE */
    RC_PROFILE_SPEED = 1     /* distance_m,speed_mps; 0 <= speed <= RC_MAX_SPEED */
} rc_profile_kind;

typedef struct {
    double *distances;       /* [m], n values, strictly increasing, >= 0; NULL when refused */
    double *values;          /* grades [permille] or speeds [m/s], n values (same block) */
    long n;                  /* >= 1 on success, 0 when refused */
    char *message;           /* refused: Python's whole message, malloc'd, NUL-terminated
                                (NULL if even that allocation failed); NULL on success */
    size_t message_len;      /* its length in bytes: a NUL byte of the text quoted in it (a
                                line is quoted whole, as Python quotes it) is kept */
    rc_error err;            /* refused: the message cut to RC_MSG_SIZE - 1 bytes (at a UTF-8
                                character boundary), or "out of memory"; "" on success */
} rc_profile;

/* parse_profile_csv(text, source, (col0, col1), nonnegative_values=..., max_abs_value=...):
 * text[0..len) (may hold NUL bytes), source a NUL-terminated UTF-8 name for the messages.
 * Returns RC_OK, or RC_BAD_CONFIG (out->message says why; also when memory runs out). */
int rc_profile_parse(const char *text, size_t len, const char *source, const char *col0,
                     const char *col1, int nonnegative_values, double max_abs_value,
                     rc_profile *out);

/* GradeProfile.from_csv_text(text, source) / SpeedProfile.from_csv_text(text, source) */
int rc_profile_parse_kind(const char *text, size_t len, const char *source, rc_profile_kind kind,
                          rc_profile *out);

/* Read the file at `path` and parse it as a profile of `kind`; the messages are those of the
 * Python reader that reads such a file (the path in them is str(pathlib.Path(path)): repeated
 * and trailing '/' and "." parts dropped, "" is "."; POSIX paths):
 *
 *   param == NULL: the harness (harness/run/scenario.py: textio.read_text, then from_csv_text with
 *     source str(path)): "PATH: cannot read: <strerror>", "PATH: is a folder, not a file",
 *     "PATH: not UTF-8 text (byte offset N)[ (UTF-16? save it as UTF-8)| (a binary file?)]",
 *     "PATH: not UTF-8 text (byte offset N) (a NUL byte: a binary file?)"; a leading BOM is
 *     dropped before the parser (which drops one more);
 *   param != NULL: the FMU (fmu_src/adapter.py load_profiles; param is "track.grade_profile" or
 *     "track.speed_profile", raw the parameter's value, path the file it resolved it to):
 *     "PARAM: cannot read 'RAW' (looked for PATH): <strerror>", "PARAM: PATH: not UTF-8 text
 *     (byte offset N)", and "PARAM: " before the parser's messages. raw NULL is taken as path.
 *     The file must be a regular file of at most RC_PROFILE_MAX_BYTES, which stat() tells
 *     before it is opened: "PARAM: cannot read 'RAW' (looked for PATH): it is a FIFO, not a
 *     regular file" (or a folder, a device; "it is not a regular file" for any other kind),
 *     "...: it has N bytes, more than the 16777216 bytes (16 MiB) a profile may have" (and
 *     "...: it grew past the ... while it was read" if it grows after the stat()).
 *
 * C99 stdio and stat() (glibc, mingw-w64, MSVC); in the harness's reading a folder is
 * recognised by EISDIR from the read, as on Linux, and no size is refused. */
/* The most bytes a profile parameter's file may have. A 100 km line's grade profile at 1 m
 * resolution ("100000.0,-12.5" and a line break a row) is about 1.6 MB, a tenth of it; what
 * the bound stops is a wrong file (/dev/zero's like, a log, a disc image) filling the memory. */
#define RC_PROFILE_MAX_BYTES 16777216L
#define RC_PROFILE_MAX_TEXT "16777216 bytes (16 MiB)"

int rc_profile_read_file(const char *path, const char *param, const char *raw,
                         rc_profile_kind kind, rc_profile *out);

/* adapter.read_profile_text: the checks and reading of rc_profile_read_file with param (its
 * messages, param required) without the parsing, for a CSV of other columns (the AtoController's
 * line files: ato_line_profile.h). RC_OK: *text (len bytes, strict UTF-8, NOT NUL-terminated)
 * and *where (str(pathlib.Path(path)), NUL-terminated) are malloc'd, the caller frees both; else
 * they are NULL and out holds the refusal (rc_profile_free it). */
int rc_profile_read_text(const char *path, const char *param, const char *raw, char **text,
                         size_t *len, char **where, rc_profile *out);

/* models.plant.track.csv_number_rows: the data rows of a CSV whose header is exactly the
 * `columns`, read one at a time so that a caller checks each row before the next is read, as
 * Python's generator does (the first refusal is then the same line's). The rules are the ones
 * above (BOM, line breaks, stripping, blank and '#' lines, cells, float()); a row must have
 * n_columns cells, each a finite number. Messages: "{prefix}{source}: line N: header must be
 * 'a,b,c', got '...'", "...: expected 3 values, got 2: '...'", "...: not a number: '...'",
 * "...: non-finite value: '...'", "{prefix}{source}: line 1: empty file, expected header
 * 'a,b,c'". prefix may be NULL. text, source and columns must outlive the reader. */
#define RC_CSV_MAX_COLUMNS 8

typedef struct {
    const unsigned char *s;
    size_t len, pos;
    const char *source, *prefix;
    const char *const *columns;
    int n_columns;
    long lineno;             /* the last line read, 1-based */
    int header_seen;
    size_t lines;            /* the text's lines: a bound on its rows */
    char *scratch;           /* float()'s */
} rc_csv_rows;

/* RC_OK, or RC_BAD_CONFIG with out->err "out of memory" (or the column count refused: 1 ..
 * RC_CSV_MAX_COLUMNS); out is zeroed first. rc_csv_rows_close() after either. */
int rc_csv_rows_open(rc_csv_rows *r, const char *text, size_t len, const char *source,
                     const char *prefix, const char *const *columns, int n_columns,
                     rc_profile *out);
/* 1: the next row's numbers in values[n_columns], its line in *lineno; 0: no more rows; -1:
 * refused, the message in out (rc_profile_free it) */
int rc_csv_rows_next(rc_csv_rows *r, double *values, long *lineno, rc_profile *out);
void rc_csv_rows_close(rc_csv_rows *r);

/* out refused with the printf-made message (whole in out->message, cut in out->err; "out of
 * memory" if it cannot be made); returns RC_BAD_CONFIG. out is zeroed first. */
int rc_profile_refuse(rc_profile *out, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;

/* f"{x:g}" into buf (a 32-byte buf holds every double's) */
void rc_profile_g(double x, char *buf, size_t size);

/* Free what a parse or read allocated and zero the struct. */
void rc_profile_free(rc_profile *p);

#endif

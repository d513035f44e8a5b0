/* sea.h — readers of measured seas (buoys and wave forecasts) into the sea
 * document, the JSON object the simulation library accepts (docs/operations.md,
 * "Measured seas"):
 *   sea_ndbc.c   NDBC realtime (.data_spec .swdir .swdir2 .swr1 .swr2) and historical
 *                ({id}{w,d,i,j,k}{year}.txt[.gz]) files: "moments" documents
 *   sea_ww3.c    WAVEWATCH III point-spectrum text: one "spectrum2d" document per time
 *   sea_cdip.c   CDIP's OPeNDAP .ascii text: a "moments" document
 *   sea_doc.c    limits, the JSON (cJSON), the summary (Hs, Tp, direction at the peak)
 *   sea_fetch.c  files (gzip through zlib) and http(s):// URLs (libwebsockets' client)
 * Every reader parses text already in memory (so the fuzz targets call them as
 * they are) and never half-succeeds: 0 and a complete, checked document, or
 * -1 and a coded error naming the file, the line and the band. Directions
 * in a document are where waves come FROM, degrees clockwise from true north. */
#ifndef OCEAND_SEA_H
#define OCEAND_SEA_H

#include <stddef.h>

#include <cjson/cJSON.h>

#define SEA_MAX_FREQ 128
#define SEA_MAX_DIR 72
#define SEA_MAX_M0 100.0 /* m^2: Hs at most 40 m */
#define SEA_MAX_TIMES 512 /* of a forecast */

enum sea_form { SEA_MOMENTS, SEA_SPECTRUM2D };

struct sea_doc {
    enum sea_form form;
    char source[128];
    char time[24];              /* "YYYY-MM-DDThh:mm:ssZ" */
    double depth;               /* metres; NAN = unknown (null) */
    int nf, nd;
    double freq[SEA_MAX_FREQ], bw[SEA_MAX_FREQ];
    double energy[SEA_MAX_FREQ];                       /* moments: C11, m^2/Hz */
    double a1[SEA_MAX_FREQ], b1[SEA_MAX_FREQ], a2[SEA_MAX_FREQ], b2[SEA_MAX_FREQ];
    double dir[SEA_MAX_DIR];                           /* spectrum2d: degrees, from, increasing */
    double e2[SEA_MAX_FREQ][SEA_MAX_DIR];              /* spectrum2d: m^2/(Hz rad) */
    double file_hs;             /* the file's own Hs, NAN if it gives none */
};

/* Error codes (the first word of every message, for scripts):
 *   io              a file or URL could not be read
 *   bad_header      a header line (or the format itself) is not what the reader knows
 *   bad_number      a token that should be a number is not one
 *   missing         a value the sea needs is missing (MM, 999, -999 fill)
 *   truncated       a row or the file ends before its values do
 *   bands_mismatch  the files of one sea disagree on their bands
 *   too_many_bands  more than SEA_MAX_FREQ frequencies or SEA_MAX_DIR directions
 *   out_of_range    a value outside its range (r > 1, energy < 0, bands not increasing, m0 > 100)
 *   no_time         the time asked for (or a time common to the five files) is not there
 *   hs_mismatch     the file's own Hs disagrees with 4 sqrt(m0) of its bands by more than 10 %
 *   flagged         the source flags the record as bad (CDIP waveFlagPrimary != 1) */
struct sea_err {
    char code[24];
    char file[256];
    long line;                  /* 1-based, 0 = the file as a whole */
    int band;                   /* 1-based, 0 = no band */
    char msg[320];
};

/* One input file, in memory (NUL-terminated; len without the NUL). */
struct sea_text {
    const char *name;
    const char *data;
    size_t len;
};

/* Set e (the first failure wins: later ones are its consequences); returns -1. */
int sea_fail(struct sea_err *e, const char *code, const char *file, long line, int band, const char *fmt, ...)
    __attribute__((format(printf, 6, 7)));
/* "ocean-tap: sea: error CODE: FILE:LINE: band K: message" into buf. */
void sea_err_format(const struct sea_err *e, char *buf, size_t n);

/* NDBC realtime: f = .data_spec, .swdir, .swdir2, .swr1, .swr2 (this order).
 * want_time: "YYYY-MM-DDThh:mm:ssZ" or NULL for the newest time in all five. */
int sea_ndbc_realtime(const struct sea_text f[5], const char *station, const char *want_time,
                      struct sea_doc *d, struct sea_err *e);
/* NDBC historical: f = w (swden), d (swdir), i (swdir2), j (swr1), k (swr2). */
int sea_ndbc_historical(const struct sea_text f[5], const char *station, const char *want_time,
                        struct sea_doc *d, struct sea_err *e);
/* WAVEWATCH III point spectra: every time (at most SEA_MAX_TIMES) of point `point`
 * (NULL: the first) into *docs[0..*n-1], in the file's order; free(*docs) whatever it returns. */
int sea_ww3(const struct sea_text *f, const char *point, struct sea_doc **docs, int *n, struct sea_err *e);
/* CDIP OPeNDAP ascii: the newest record, or the one at want_time. */
int sea_cdip(const struct sea_text *f, const char *station, const char *want_time, struct sea_doc *d,
             struct sea_err *e);

/* Band widths from neighbouring centres (half the distance to each side). */
void sea_bandwidth_from_centres(const double *f, int n, double *bw);
/* The document's limits (sea_doc.md): sizes, finite, >= 0, increasing, |a..b| <= 1, m0 <= 100. */
int sea_doc_check(const struct sea_doc *d, const char *file, struct sea_err *e);
cJSON *sea_doc_json(const struct sea_doc *d);
struct sea_stats { double m0, hs, tp, fp, dir_peak; int peak; };
void sea_doc_stats(const struct sea_doc *d, struct sea_stats *st);
/* "NDBC 46026 2026-12-01T20:40:00Z: Hs 2.31 m, Tp 12.50 s, from 271.3 deg at the peak (0.080 Hz)" */
void sea_doc_summary(const struct sea_doc *d, char *buf, size_t n);
/* strtod for the decimal numbers these files hold, [+-](digits[.digits] | .digits)[(e|E)[+-]digits],
 * and nothing else: no hex, inf, nan or leading blanks, which strtod would take (and the Python
 * readers would not). *end = s when s does not start with one. */
double sea_strtod(const char *s, char **end);
/* "YYYY-MM-DDThh:mm[:ss][Z]" -> canonical "YYYY-MM-DDThh:mm:ssZ"; -1 if not a time. */
int sea_time_canon(const char *in, char out[24]);

/* Read a file (gunzipped when it ends in .gz) or GET an http:// or https:// URL
 * (also gunzipped when the name ends in .gz); at most 64 MiB. *out is
 * NUL-terminated, free() it. Returns 0, or -1 with e set (code io). */
int sea_load(const char *source, char **out, size_t *len, struct sea_err *e);

#endif

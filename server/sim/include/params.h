/* params.h — the one table of sea parameters.
 *
 * Every user-visible parameter of the simulation is described once here:
 * name, type, unit, range, default, description, and where it lives in
 * struct ocean_params. The daemon derives its config file, CLI flags, JSON
 * validation and the `hello` schema (and so the web panel) from this table.
 * No networking and no global mutable state. */
#ifndef OCEAND_PARAMS_H
#define OCEAND_PARAMS_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* SPECTRUM_MEASURED: a buoy's or a forecast's spectrum (sea_spectrum.h), attached to the
 * ocean with ocean_create_sea / ocean_prepare_sea; params_validate alone refuses it. */
enum spectrum_kind { SPECTRUM_PHILLIPS, SPECTRUM_PIERSON_MOSKOWITZ, SPECTRUM_JONSWAP, SPECTRUM_TMA,
                     SPECTRUM_MEASURED };
enum transform_kind { TRANSFORM_FFT, TRANSFORM_DFT };

/* All lengths in metres, times in seconds, angles in degrees unless named. */
struct ocean_params {
    int    resolution;          /* N, samples per side, power of two 16..2048 */
    double patch_size;          /* L, side of the periodic patch, m (cascade 0, the largest) */
    int    cascades;            /* 1..OCEAN_MAX_CASCADES patches, each OCEAN_CASCADE_RATIO smaller (ocean.h) */
    double wind_speed;          /* U10, wind speed 10 m above the sea, m/s */
    double wind_direction;      /* degrees, 0 = +x, 90 = +z */
    double amplitude;           /* dimensionless multiplier of the spectrum */
    int    spectrum;            /* enum spectrum_kind */
    double fetch;               /* km of open water upwind (JONSWAP, TMA) */
    double depth;               /* m, water depth (dispersion, TMA) */
    double gamma;               /* JONSWAP peak enhancement */
    double directional_spread;  /* 0 = spreading as spectrum, 1 = fully directional (see params.c) */
    double swell;               /* 0..1, elongation of the spreading toward the wind direction */
    double choppiness;          /* lambda, horizontal displacement scale */
    double small_wave_cutoff;   /* m, waves shorter than this are damped */
    double loop_period;         /* s, 0 = never repeats */
    int    seed;                /* random seed, >= 0 */
    int    transform;           /* enum transform_kind */
    double time_scale;          /* playback speed (used by the daemon) */
    bool   paused;              /* playback pause (used by the daemon) */
};

/* One settings-table shape for everything configurable: the sea parameters
 * below (param_table, offsets into struct ocean_params) and the daemon's own
 * options (server/config/config.c, offsets into its struct daemon_config) are rows
 * of struct param_def, and both are checked by the same setters here. */
enum param_type { PARAM_INT, PARAM_FLOAT, PARAM_ENUM, PARAM_BOOL, PARAM_STRING };

enum param_flags {
    PARAM_POW2      = 1u << 0, /* integer must be a power of two */
    PARAM_REPLAN    = 1u << 1, /* changing it rebuilds FFT plans (N) */
    PARAM_PLAYBACK  = 1u << 2, /* read by the daemon's clock, not the physics */
    PARAM_LIVE      = 1u << 3, /* may change while running (a JSON `set`) */
    PARAM_RESTART   = 1u << 4, /* read at start-up only (daemon options) */
    PARAM_SECRET    = 1u << 5, /* value never printed (help, errors, logs) */
    PARAM_PHASE     = 1u << 6, /* changing it gives the sea other phases (or another grid):
                                  the frames before do not predict the new ones */
};

struct param_def {
    const char *name;
    enum param_type type;
    const char *unit;            /* "" when dimensionless */
    double min, max;             /* inclusive; for ENUM 0..count-1 */
    double def;                  /* default; for ENUM the index */
    const char *const *choices;  /* ENUM only: NULL-terminated names */
    const char *description;
    size_t offset;               /* offsetof(struct ..., field) in the table's struct */
    unsigned flags;              /* enum param_flags */
    size_t size;                 /* STRING only: bytes of the char array, NUL included */
    const char *def_text;        /* STRING only: the default */
};

/* Why a value was refused. The daemon maps these to its wire error codes
 * (server/control/control.c), so every path (config file, flags, JSON `set`, state
 * file) reports the same fault the same way. */
enum param_error {
    PARAM_OK = 0,
    PARAM_ERR_UNKNOWN,      /* no setting of that name */
    PARAM_ERR_TYPE,         /* text is not a number / true-false; wrong JSON type */
    PARAM_ERR_NOT_FINITE,   /* NaN or infinity */
    PARAM_ERR_NOT_INTEGER,  /* fractional value for an int */
    PARAM_ERR_RANGE,        /* outside [min, max] */
    PARAM_ERR_NOT_POW2,     /* int that must be a power of two is not */
    PARAM_ERR_BAD_ENUM,     /* not one of the choices */
    PARAM_ERR_TOO_LONG,     /* string longer than its field */
    PARAM_ERR_INVALID,      /* whole-set rule (params_validate) */
};

/* The number of sea parameters, as a constant: the daemon's `changed` masks
 * are uint64_t, and it checks PARAM_COUNT <= 64 at compile time. */
#define PARAM_COUNT 19
extern const struct param_def param_table[PARAM_COUNT];
extern const size_t param_count;

/* What a person reads about a sea parameter (the `hello` schema's label,
 * group and help, so the web panel hard-codes no names). A second table
 * beside param_table, one row per parameter (tests/test_ocean.c checks
 * that every row of param_table has one). */
enum param_group {
    PARAM_GROUP_SEA,        /* everyday: wind, waves, playback */
    PARAM_GROUP_ADVANCED,   /* the spectrum's shape and the patch */
    PARAM_GROUP_DEVELOPER,  /* resolution, transform: cost and checking, not the look */
};
struct param_ui {
    const char *name;       /* param_table's name */
    const char *label;      /* short human name: "Wind speed" */
    enum param_group group;
    const char *help;       /* one line for a tooltip */
};
/* The row for d, or NULL if it has none. */
const struct param_ui *param_ui(const struct param_def *d);
/* "sea", "advanced", "developer". */
const char *param_group_name(enum param_group g);

/* Fill with the defaults from the table. */
void params_defaults(struct ocean_params *p);
/* Look a parameter up by name; NULL if unknown. */
const struct param_def *param_find(const char *name);
/* Value of a parameter as a double (ENUM: index, BOOL: 0/1). */
double param_get(const struct ocean_params *p, const struct param_def *d);
/* Set from a double after checking type and range (ints must be whole, POW2
 * enforced). Returns 0, or -1 with a message in err; p unchanged on error. */
int param_set(struct ocean_params *p, const struct param_def *d, double v, char *err, size_t errlen);
/* Set from text, as on a command line: numbers, true/false, enum names.
 * Returns 0, or -1 with a message in err; p unchanged on error. */
int param_set_text(struct ocean_params *p, const struct param_def *d, const char *text, char *err, size_t errlen);
/* Name of an ENUM value, or NULL. */
const char *param_enum_name(const struct param_def *d, int index);
/* Index of an ENUM name, or -1. */
int param_enum_index(const struct param_def *d, const char *name);
/* Bit i set for every row i of param_table whose flags include any of flags. */
uint64_t params_mask(unsigned flags);
/* The first row of param_table with flag (PARAM_REPLAN: the resolution), or NULL. */
const struct param_def *param_with_flag(unsigned flag);
/* base with the parameters in mask (bits of param_table rows) taken from values. */
struct ocean_params params_with(const struct ocean_params *base, const struct ocean_params *values, uint64_t mask);
/* The rows whose values differ between a and b, as a mask. */
uint64_t params_diff(const struct ocean_params *a, const struct ocean_params *b);
/* Whether a and b give different seas (anything but playback differs). */
bool params_physics_differ(const struct ocean_params *a, const struct ocean_params *b);
/* Whole-set checks that no single range can express (e.g. DFT only for
 * small N). Returns 0, or -1 with a message in err. spectrum "measured"
 * is refused here (no sea is attached to bare parameters): the ocean's
 * own checks use params_validate_sea. */
int params_validate(const struct ocean_params *p, char *err, size_t errlen);
/* The same, where a measured sea is (have_sea) or is not attached. */
int params_validate_sea(const struct ocean_params *p, bool have_sea, char *err, size_t errlen);

/* The checks and setters behind all of the above, for any table of this
 * shape: base is the struct the table's offsets point into. Each returns
 * PARAM_OK, or the reason with a message in err and *base unchanged. */
enum param_error setting_check(const struct param_def *d, double v, char *err, size_t errlen);
/* INT, FLOAT, ENUM (index), BOOL (0/1) from a number. */
enum param_error setting_set_number(void *base, const struct param_def *d, double v, char *err, size_t errlen);
/* Any type from text: numbers, true/false/yes/no/on/off/1/0, enum names
 * (any case), strings as they are. */
enum param_error setting_set_text(void *base, const struct param_def *d, const char *text, char *err,
                                  size_t errlen);
/* The default of one setting onto base (STRING: def_text). */
void setting_set_default(void *base, const struct param_def *d);
/* The default of a setting as text ("8080", "jonswap", "true", "127.0.0.1"). */
void setting_default_text(const struct param_def *d, char *buf, size_t len);

#endif

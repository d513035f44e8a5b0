/* fuzz_sea.c — libFuzzer target: a measured sea document (sea_spectrum.h)
 * made from the input, through the validator, and for the seas it accepts
 * through the directional reconstruction and the capture on a small grid.
 * Whatever the input: the check never writes its input, a refusal has a
 * code and a message, and an accepted sea gives distributions that are
 * finite, >= 0 and of unit integral, and a finite capture (its share may
 * exceed 1: a band narrower than the grid's rings is sampled, not integrated).
 *
 * Input: 6 header bytes (mode, form, tail, directional, bands, directions),
 * then values read one at a time. Mode bit 0 set: each value is 8 raw bytes
 * (NaN, infinities, denormals); else 2 bytes scaled into a plausible range
 * (most documents are then nearly valid, and the fuzzer finds the edges).
 * A short input fills the rest with a valid pattern. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "sea_spectrum.h"

static void check(int ok)
{
    if (!ok)
        abort();
}

struct reader {
    const uint8_t *p;
    size_t left;
    int raw;
};

/* The next value: raw double, or a 16-bit integer mapped by scale/offset; fallback when empty. */
static double next(struct reader *r, double scale, double offset, double fallback)
{
    if (r->raw && r->left >= 8) {
        double v;
        memcpy(&v, r->p, 8);
        r->p += 8;
        r->left -= 8;
        return v;
    }
    if (!r->raw && r->left >= 2) {
        int16_t v;
        memcpy(&v, r->p, 2);
        r->p += 2;
        r->left -= 2;
        return offset + scale * v;
    }
    return fallback;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static struct sea_spectrum s, copy;
    static double d[360];
    if (size < 6)
        return 0;
    sea_spectrum_init(&s, SEA_FORM_MOMENTS);
    struct reader r = {data + 6, size - 6, data[0] & 1};
    s.form = (enum sea_form)(data[1] % 3);            /* 2: not a form */
    s.tail = (enum sea_tail)(data[2] % (SEA_TAIL_COUNT + 1));
    s.directional = (enum sea_directional)(data[3] % (SEA_DIR_COUNT + 1));
    s.bands = data[4] % (SEA_MAX_BANDS + 2);           /* 0 .. 129 */
    s.directions = data[5] % (SEA_MAX_DIRECTIONS + 2); /* 0 .. 73 */
    memcpy(s.source, "fuzz", 5);
    s.depth = next(&r, 0.5, 0, 0);
    int nb = s.bands < SEA_MAX_BANDS ? s.bands : SEA_MAX_BANDS;
    int nd = s.directions < SEA_MAX_DIRECTIONS ? s.directions : SEA_MAX_DIRECTIONS;
    double f = 0;
    for (int i = 0; i < nb; i++) {
        f += fabs(next(&r, 1e-4, 0, 0.01)) + 1e-4;
        s.frequency[i] = r.raw ? next(&r, 0, 0, f) : f;
        s.bandwidth[i] = next(&r, 1e-5, 0.005, 0.01);
        s.energy[i] = next(&r, 1e-3, 0, 0.1);
        s.a1[i] = next(&r, 1.0 / 30000, 0, 0.3);
        s.b1[i] = next(&r, 1.0 / 30000, 0, -0.2);
        s.a2[i] = next(&r, 1.0 / 30000, 0, 0.1);
        s.b2[i] = next(&r, 1.0 / 30000, 0, 0.05);
    }
    for (int j = 0; j < nd; j++)
        s.direction[j] = next(&r, 0.01, 0, 5.0 * j);
    for (int i = 0; i < nb && s.form == SEA_FORM_SPECTRUM2D; i++)
        for (int j = 0; j < nd; j++)
            s.energy2d[i][j] = next(&r, 1e-3, 0, 0.01 * (j % 7));

    copy = s;
    char err[256];
    enum sea_error e = sea_spectrum_check(&s, err, sizeof err);
    check(memcmp(&copy, &s, sizeof s) == 0);
    if (e != SEA_OK) {
        check(err[0] != 0 && strcmp(sea_error_name(e), "sea_unknown") != 0);
        return 0;
    }
    double m0 = sea_spectrum_m0(&s);
    check(isfinite(m0) && m0 >= 0 && m0 <= SEA_M0_MAX);
    for (int i = 0; i < s.bands; i++) {
        double en, c[4];
        sea_spectrum_band(&s, i, &en, c);
        check(isfinite(en) && en >= 0);
        for (int m = 0; m < SEA_DIR_COUNT; m++) {
            check(sea_directional_distribution(m, c[0], c[1], c[2], c[3], d, 360) == 0);
            double sum = 0;
            for (int j = 0; j < 360; j++) {
                check(isfinite(d[j]) && d[j] >= 0);
                sum += d[j];
            }
            check(fabs(sum * 2 * M_PI / 360 - 1) < 1e-9);
        }
    }
    struct ocean_params p;
    params_defaults(&p);
    p.resolution = 16;
    p.patch_size = 64;
    p.cascades = 1 + data[0] % 2;
    struct sea_capture cap;
    e = sea_capture(&s, &p, &cap, err, sizeof err);
    check(e == SEA_OK);
    check(isfinite(cap.m0_grid) && isfinite(cap.m0_tail) && cap.m0_grid >= 0 && cap.m0_tail >= 0);
    check(isfinite(cap.share) && cap.share >= 0);
    check(memchr(cap.warning, 0, sizeof cap.warning) != NULL);
    return 0;
}

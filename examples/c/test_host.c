/*
 * Unit test of the C interface on the developer's machine: the host build of libnemm_c.a
 * through nemm.h, as a C program sees it. Run by `cargo xtask test` (`cargo xtask c-test
 * --host-only` alone):
 *
 *   cc -std=c11 -Wall -Wextra -Werror -pedantic -I nemm-c/include examples/c/test_host.c \
 *      <target>/release/libnemm_c.a -lpthread -ldl -lm -o test_host
 *   ./test_host nemm-firmware/data/trained-nemm.nemm nemm-firmware/data/example-nemm.nemm
 *
 * The first blob stores level tables (7 levels), the second stores none. Checks the status
 * codes of bad blobs, bad storage, NULL arguments and bad settings, a few hundred steps of
 * the estimator and the observer, and the level tables: read in place from the blob (held
 * 4-byte aligned; a copy off the boundary is refused), a level per sample, and the observer
 * on level tables finding the alpha of a synthetic trace. A first blob of format version 4
 * or 5 stores its tables unaligned: its level tables are refused (NEMM_E_LEVELS_LAYOUT, which
 * is checked) and the rest of the level tables' checks is skipped, with a line that says so.
 * Ends with `N passed, M failed`.
 */
#include "nemm.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

_Static_assert(sizeof(nemm_estimator_t) == NEMM_ESTIMATOR_SIZE, "estimator storage size");
_Static_assert(_Alignof(nemm_estimator_t) == NEMM_ESTIMATOR_ALIGN, "estimator alignment");
_Static_assert(sizeof(nemm_observer_t) == NEMM_OBSERVER_SIZE, "observer storage size");
_Static_assert(_Alignof(nemm_observer_t) == NEMM_OBSERVER_ALIGN, "observer alignment");
_Static_assert(sizeof(nemm_levels_t) == NEMM_LEVELS_SIZE, "level tables storage size");
_Static_assert(_Alignof(nemm_levels_t) == NEMM_LEVELS_ALIGN, "level tables alignment");
_Static_assert(sizeof(nemm_status_t) == 4, "status width");

static int passed, failed;

#define CHECK(cond)                                                                         \
    do {                                                                                    \
        if (cond) {                                                                         \
            passed++;                                                                       \
        } else {                                                                            \
            failed++;                                                                       \
            fprintf(stderr, "test_host.c:%d: check failed: %s\n", __LINE__, #cond);        \
        }                                                                                   \
    } while (0)

#define CHECK_STATUS(call, want)                                                            \
    do {                                                                                    \
        nemm_status_t got_ = (call);                                                        \
        if (got_ == (want)) {                                                               \
            passed++;                                                                       \
        } else {                                                                            \
            failed++;                                                                       \
            fprintf(stderr, "test_host.c:%d: %s returned %d (%s), expected %s\n", __LINE__, \
                    #call, (int)got_, nemm_status_str(got_), #want);                        \
        }                                                                                   \
    } while (0)

/* Large objects: statics, as on an ECU. */
static nemm_estimator_t est;
static nemm_estimator_t est_table;
static nemm_observer_t obs;
static nemm_levels_t levels;
/* Storage for the misalignment check: one byte off an aligned object. */
static struct {
    NEMM_ALIGNAS(NEMM_ESTIMATOR_ALIGN) unsigned char bytes[NEMM_ESTIMATOR_SIZE + 16];
} raw;

/* Reads a blob (at most 1 MiB) into a buffer of uint32_t words: 4-byte aligned, as level
 * tables need it (they read the blob in place). */
static unsigned char *read_file(const char *path, size_t *len) {
    FILE *f = fopen(path, "rb");
    if (!f) {
        return NULL;
    }
    uint32_t *words = malloc((1 << 20) / sizeof(uint32_t));
    unsigned char *buf = (unsigned char *)words;
    *len = buf ? fread(buf, 1, 1 << 20, f) : 0;
    fclose(f);
    return buf;
}

static void statuses(void) {
    CHECK(NEMM_OK == 0);
    static const nemm_status_t all[] = {
        NEMM_OK, NEMM_E_NULL, NEMM_E_STORAGE_SIZE, NEMM_E_BLOB_CRC_MISMATCH,
        NEMM_E_MODEL_UNSTABLE_STEP, NEMM_E_ALPHA_OUT_OF_RANGE, NEMM_E_TABLE_EXCEEDS_BOUND,
        NEMM_E_OBSERVER_SETTING, NEMM_E_LEVELS_TOO_FEW, NEMM_E_LEVELS_MISMATCH,
        NEMM_E_LEVELS_UNALIGNED, NEMM_E_LEVELS_LAYOUT};
    for (size_t i = 0; i < sizeof all / sizeof all[0]; i++) {
        const char *s = nemm_status_str(all[i]);
        CHECK(s != NULL && strncmp(s, "NEMM_", 5) == 0);
    }
    CHECK(strcmp(nemm_status_str(12345), "unknown status") == 0);
    CHECK(strncmp(nemm_status_str(NEMM_E_BLOB_CRC_MISMATCH), "NEMM_E_BLOB_CRC_MISMATCH:", 25) == 0);
    CHECK(NEMM_E_LEVELS_UNALIGNED == 78 && NEMM_E_LEVELS_LAYOUT == 79);
}

static void blobs(const unsigned char *blob, size_t len) {
    nemm_blob_info_t info;
    CHECK_STATUS(nemm_blob_validate(blob, len, &info), NEMM_OK);
    CHECK(info.format_version >= 1 && info.kind == NEMM_KIND_NEMM && info.blob_len == len);
    CHECK(info.max_scaler_params <= NEMM_PARAM_CAPACITY);
    CHECK_STATUS(nemm_blob_validate(blob, len, NULL), NEMM_OK);
    CHECK_STATUS(nemm_blob_validate(NULL, len, &info), NEMM_E_NULL);
    CHECK_STATUS(nemm_blob_validate(blob, len - 1, &info), NEMM_E_BLOB_TRUNCATED);
    CHECK_STATUS(nemm_blob_validate(blob, 2, &info), NEMM_E_BLOB_TRUNCATED);
    unsigned char *copy = malloc(len + 1);
    memcpy(copy, blob, len);
    copy[len] = 0;
    CHECK_STATUS(nemm_blob_validate(copy, len + 1, &info), NEMM_E_BLOB_TRAILING_BYTES);
    copy[len / 2] ^= 0x40;
    CHECK_STATUS(nemm_blob_validate(copy, len, &info), NEMM_E_BLOB_CRC_MISMATCH);
    nemm_estimator_config_t cfg = {.alpha = 0.15f};
    CHECK_STATUS(nemm_estimator_init(&est, sizeof est, copy, len, &cfg), NEMM_E_BLOB_CRC_MISMATCH);
    copy[len / 2] ^= 0x40;
    copy[0] = 'X';
    CHECK_STATUS(nemm_blob_validate(copy, len, &info), NEMM_E_BLOB_BAD_MAGIC);
    CHECK_STATUS(nemm_estimator_init(&est, sizeof est, copy, len, &cfg), NEMM_E_BLOB_BAD_MAGIC);
    free(copy);
}

/* A sample of the velocity `v` with the optional fields `fields` (NEMM_SAMPLE_* bits)
 * taken from `x` (position), `alpha` and `f` (force). */
static nemm_sample_t sample_of(float v, uint8_t fields, float x, float alpha, float f) {
    nemm_sample_t s = {.velocity_m_s = v, .position_m = x, .alpha = alpha, .force_n = f,
                       .fields = fields};
    return s;
}

/* One estimator step of the velocity `v` alone. */
static nemm_status_t step_v(nemm_estimator_t *e, float v, nemm_estimate_t *out) {
    nemm_sample_t s = sample_of(v, 0, 0.0f, 0.0f, 0.0f);
    return nemm_estimator_step(e, &s, out);
}

/* One estimator step of the velocity `v` at the level `alpha`. */
static nemm_status_t step_alpha(nemm_estimator_t *e, float v, float alpha, nemm_estimate_t *out) {
    nemm_sample_t s = sample_of(v, NEMM_SAMPLE_ALPHA, 0.0f, alpha, 0.0f);
    return nemm_estimator_step(e, &s, out);
}

/* One observer step of the velocity `v` and the measured force `f`. */
static nemm_status_t observe(nemm_observer_t *o, float v, float f, nemm_alpha_estimate_t *out) {
    nemm_sample_t s = sample_of(v, NEMM_SAMPLE_FORCE, 0.0f, 0.0f, f);
    return nemm_observer_step(o, &s, out);
}

static void storage_and_settings(const unsigned char *blob, size_t len) {
    nemm_estimator_config_t cfg = {.alpha = 0.15f};
    nemm_estimate_t e;
    /* Never initialised (static storage is zero). */
    CHECK_STATUS(step_v(&est, 0.1f, &e), NEMM_E_NOT_INITIALISED);
    CHECK_STATUS(nemm_estimator_init(NULL, sizeof est, blob, len, &cfg), NEMM_E_NULL);
    CHECK_STATUS(nemm_estimator_init(&est, sizeof est, NULL, len, &cfg), NEMM_E_NULL);
    CHECK_STATUS(nemm_estimator_init(&est, sizeof est, blob, len, NULL), NEMM_E_NULL);
    CHECK_STATUS(nemm_estimator_init(&est, sizeof est - 1, blob, len, &cfg), NEMM_E_STORAGE_SIZE);
    CHECK_STATUS(nemm_estimator_init((nemm_estimator_t *)(void *)(raw.bytes + 1),
                                     NEMM_ESTIMATOR_SIZE, blob, len, &cfg),
                 NEMM_E_STORAGE_ALIGN);
    nemm_estimator_config_t bad = cfg;
    bad.alpha = 1.5f;
    CHECK_STATUS(nemm_estimator_init(&est, sizeof est, blob, len, &bad), NEMM_E_ALPHA_OUT_OF_RANGE);
    bad.alpha = NAN;
    CHECK_STATUS(nemm_estimator_init(&est, sizeof est, blob, len, &bad), NEMM_E_ALPHA_OUT_OF_RANGE);
    bad = cfg;
    bad.mode = 7;
    CHECK_STATUS(nemm_estimator_init(&est, sizeof est, blob, len, &bad), NEMM_E_INVALID_ARGUMENT);
    bad = cfg;
    bad.velocity_limit_m_s = -1.0f;
    CHECK_STATUS(nemm_estimator_init(&est, sizeof est, blob, len, &bad), NEMM_E_BAD_VELOCITY_LIMIT);
    /* After a failed init the storage is no estimator. */
    CHECK_STATUS(step_v(&est, 0.1f, &e), NEMM_E_NOT_INITIALISED);
}

static void estimator(const unsigned char *blob, size_t len) {
    nemm_estimator_config_t cfg = {.alpha = 0.15f};
    CHECK_STATUS(nemm_estimator_init(&est, sizeof est, blob, len, &cfg), NEMM_OK);
    nemm_estimator_info_t info;
    CHECK_STATUS(nemm_estimator_info(&est, &info), NEMM_OK);
    CHECK(info.kind == NEMM_KIND_NEMM && info.mode == NEMM_MODE_EXACT);
    CHECK(info.table_origin == NEMM_TABLES_NONE && info.table_bytes == 0);
    CHECK(info.alpha == 0.15f && info.dt_s > 0.0f && info.velocity_limit_m_s > 0.0f);
    CHECK(info.alpha_min <= info.alpha_max);
    nemm_estimate_t e;
    int ok = 1, finite = 1, clean = 1;
    for (int k = 0; k < 500; k++) {
        float v = 0.5f * sinf(2.0f * 3.14159265f * 5.0f * (float)k * info.dt_s);
        nemm_sample_t s = sample_of(v, NEMM_SAMPLE_POSITION, 0.0f, 0.0f, 0.0f);
        ok &= nemm_estimator_step(&est, &s, &e) == NEMM_OK;
        finite &= isfinite(e.force_n) != 0;
        clean &= (e.flags & ~NEMM_FLAG_ALPHA_EXTRAPOLATED) == 0;
    }
    CHECK(ok && finite && clean);
    /* A NaN velocity is held and flagged; the force stays finite. */
    CHECK_STATUS(step_v(&est, NAN, &e), NEMM_OK);
    CHECK(isfinite(e.force_n) && (e.flags & NEMM_FLAG_INPUT_HELD) && (e.flags & NEMM_FLAG_INPUT_NON_FINITE));
    CHECK_STATUS(step_v(&est, 0.1f, NULL), NEMM_E_NULL);
    CHECK_STATUS(nemm_estimator_step(&est, NULL, &e), NEMM_E_NULL);
    nemm_sample_t odd = sample_of(0.1f, 0x80, 0.0f, 0.0f, 0.0f);
    CHECK_STATUS(nemm_estimator_step(&est, &odd, &e), NEMM_E_INVALID_ARGUMENT);
    CHECK_STATUS(nemm_estimator_set_alpha(&est, 0.2f), NEMM_OK);
    CHECK_STATUS(nemm_estimator_set_alpha(&est, -0.5f), NEMM_E_ALPHA_OUT_OF_RANGE);
    CHECK_STATUS(step_alpha(&est, 0.1f, 0.25f, &e), NEMM_OK);
    nemm_sample_t at = sample_of(0.1f, NEMM_SAMPLE_ALPHA | NEMM_SAMPLE_POSITION, 0.0f, 0.3f, 0.0f);
    CHECK_STATUS(nemm_estimator_step(&est, &at, &e), NEMM_OK);
    CHECK_STATUS(nemm_estimator_info(&est, &info), NEMM_OK);
    CHECK(info.alpha == 0.3f && info.steps == 503 && info.held_samples == 1);
    CHECK_STATUS(nemm_estimator_reset(&est), NEMM_OK);
    /* Table mode: the trained blob stores tables at 0.15. */
    nemm_estimator_config_t tab = {.alpha = 0.15f, .mode = NEMM_MODE_TABLE};
    CHECK_STATUS(nemm_estimator_init(&est_table, sizeof est_table, blob, len, &tab), NEMM_OK);
    CHECK_STATUS(nemm_estimator_info(&est_table, &info), NEMM_OK);
    CHECK(info.mode == NEMM_MODE_TABLE && info.table_origin == NEMM_TABLES_STORED && info.table_bytes > 0);
    CHECK_STATUS(step_alpha(&est_table, 0.1f, 0.2f, &e), NEMM_E_ALPHA_PER_SAMPLE_IN_TABLE_MODE);
    CHECK_STATUS(step_alpha(&est_table, 0.1f, 0.15f, &e), NEMM_OK);
    tab.table_max_rel_error = 1e-12f;
    CHECK_STATUS(nemm_estimator_init(&est_table, sizeof est_table, blob, len, &tab),
                 NEMM_E_TABLE_EXCEEDS_BOUND);
    /* The blob inside the storage. */
    memcpy(raw.bytes + 64, blob, len < 4096 ? len : 4096);
    CHECK_STATUS(nemm_estimator_init((nemm_estimator_t *)(void *)raw.bytes, NEMM_ESTIMATOR_SIZE,
                                     raw.bytes + 64, len, &cfg),
                 NEMM_E_OVERLAP);
}

static void observer(void) {
    nemm_observer_config_t cfg;
    CHECK_STATUS(nemm_observer_config_default(&cfg), NEMM_OK);
    CHECK(cfg.points == 0 && cfg.horizon_s == 3.0f && cfg.grid_lo == 0.0f && cfg.grid_hi == 0.0f);
    CHECK(cfg.crossing_hysteresis == 0.1f && cfg.settle_tolerance == 0.02f && cfg.change_tolerance == 0.03f);
    CHECK_STATUS(nemm_observer_init(&obs, sizeof obs, &est, &cfg), NEMM_OK);
    nemm_alpha_estimate_t a;
    CHECK_STATUS(nemm_observer_estimate(&obs, &a), NEMM_OK);
    CHECK((a.flags & NEMM_OBSERVER_NOT_EXCITED) && (a.flags & NEMM_OBSERVER_NOT_SETTLED));
    nemm_estimator_info_t info;
    CHECK_STATUS(nemm_estimator_info(&est, &info), NEMM_OK);
    CHECK_STATUS(nemm_estimator_set_alpha(&est, 0.15f), NEMM_OK);
    int ok = 1;
    for (int k = 0; k < 300; k++) {
        float v = 0.8f * sinf(2.0f * 3.14159265f * 8.0f * (float)k * info.dt_s);
        nemm_estimate_t e;
        ok &= step_v(&est, v, &e) == NEMM_OK;
        ok &= observe(&obs, v, e.force_n, &a) == NEMM_OK;
        ok &= isfinite(a.alpha) && isfinite(a.band) && a.alpha >= 0.0f && a.alpha <= 1.0f;
    }
    CHECK(ok);
    CHECK_STATUS(observe(&obs, 0.1f, NAN, &a), NEMM_OK);
    CHECK(a.flags & NEMM_OBSERVER_FORCE_FAULT);
    /* A sample without a force: a missing measurement, as a NaN one. */
    nemm_sample_t no_force = sample_of(0.1f, 0, 0.0f, 0.0f, 0.0f);
    CHECK_STATUS(nemm_observer_step(&obs, &no_force, &a), NEMM_OK);
    CHECK((a.flags & NEMM_OBSERVER_FORCE_FAULT) && (a.flags & NEMM_OBSERVER_HELD));
    CHECK_STATUS(nemm_observer_reset(&obs), NEMM_OK);
    nemm_observer_config_t bad = cfg;
    bad.points = 1;
    CHECK_STATUS(nemm_observer_init(&obs, sizeof obs, &est, &bad), NEMM_E_OBSERVER_POINTS);
    CHECK_STATUS(observe(&obs, 0.1f, 1.0f, &a), NEMM_E_NOT_INITIALISED);
    bad = cfg;
    bad.grid_lo = 0.5f;
    bad.grid_hi = 0.1f;
    CHECK_STATUS(nemm_observer_init(&obs, sizeof obs, &est, &bad), NEMM_E_OBSERVER_GRID);
    bad = cfg;
    bad.horizon_s = 0.0f;
    CHECK_STATUS(nemm_observer_init(&obs, sizeof obs, &est, &bad), NEMM_E_OBSERVER_SETTING);
    CHECK_STATUS(nemm_observer_init(&obs, sizeof obs - 1, &est, NULL), NEMM_E_STORAGE_SIZE);
    CHECK_STATUS(nemm_observer_init(&obs, sizeof obs, NULL, NULL), NEMM_E_NULL);
    /* est_table's last init failed: no model to observe. */
    CHECK_STATUS(nemm_observer_init(&obs, sizeof obs, &est_table, NULL), NEMM_E_NOT_INITIALISED);
    CHECK_STATUS(nemm_observer_init(&obs, sizeof obs, &est, NULL), NEMM_OK);
}

/* `blob` (4-byte aligned) stores level tables, `plain` (another model) none. The level tables
 * read `blob` in place: it stays allocated and unchanged until main frees it, after their
 * last use. */
static void level_tables(const unsigned char *blob, size_t len, const unsigned char *plain,
                         size_t plain_len) {
    /* The "measured" force: the exact estimator's at alpha 0.12, between two levels. */
    nemm_estimator_config_t cfg = {.alpha = 0.12f};
    CHECK_STATUS(nemm_estimator_init(&est, sizeof est, blob, len, &cfg), NEMM_OK);
    CHECK_STATUS(nemm_estimator_init(&est_table, sizeof est_table, plain, plain_len, &cfg), NEMM_OK);
    /* Refused: a blob without level tables, a blob that is not the estimator's. */
    CHECK_STATUS(nemm_levels_init(&levels, sizeof levels, &est_table, plain, plain_len),
                 NEMM_E_LEVELS_TOO_FEW);
    CHECK_STATUS(nemm_levels_init(&levels, sizeof levels, &est, plain, plain_len),
                 NEMM_E_LEVELS_OTHER_BLOB);
    CHECK_STATUS(nemm_levels_init(&levels, sizeof levels, &est_table, blob, len),
                 NEMM_E_LEVELS_OTHER_BLOB);
    CHECK_STATUS(nemm_levels_init(&levels, sizeof levels - 1, &est, blob, len), NEMM_E_STORAGE_SIZE);
    nemm_levels_info_t li;
    CHECK_STATUS(nemm_levels_info(&levels, &li), NEMM_E_NOT_INITIALISED);
    nemm_blob_info_t bi;
    CHECK_STATUS(nemm_blob_validate(blob, len, &bi), NEMM_OK);
    if (bi.format_version < 6) {
        /* Tables stored unaligned (format version 4 or 5): not readable in place. */
        CHECK_STATUS(nemm_levels_init(&levels, sizeof levels, &est, blob, len),
                     NEMM_E_LEVELS_LAYOUT);
        CHECK_STATUS(nemm_levels_info(&levels, &li), NEMM_E_NOT_INITIALISED);
        printf("level tables: the blob is of format version %u, refused with "
               "NEMM_E_LEVELS_LAYOUT; the other level tables checks are skipped (export it "
               "again to run them)\n",
               (unsigned)bi.format_version);
        return;
    }
    /* The same bytes one byte off the 4-byte boundary: the estimator's blob (same length
     * and CRC), but its tables cannot be read in place. */
    unsigned char *shifted = malloc(len + 1);
    CHECK(shifted != NULL);
    if (shifted) {
        memcpy(shifted + 1, blob, len);
        CHECK_STATUS(nemm_levels_init(&levels, sizeof levels, &est, shifted + 1, len),
                     NEMM_E_LEVELS_UNALIGNED);
        CHECK_STATUS(nemm_levels_info(&levels, &li), NEMM_E_NOT_INITIALISED);
        free(shifted);
    }
    CHECK_STATUS(nemm_levels_init(&levels, sizeof levels, &est, blob, len), NEMM_OK);
    CHECK_STATUS(nemm_levels_info(&levels, &li), NEMM_OK);
    CHECK(li.levels == 7 && li.alpha[0] == 0.0f && li.alpha[6] == 0.3f && li.alpha[7] == 0.0f);
    /* The tables' bytes in the blob, where they are read (32 + 28 x segments per table). */
    CHECK(li.table_bytes == 14u * (32u + 28u * NEMM_TABLE_SEGMENTS) &&
          li.table_max_rel_error > 0.0f);

    /* A level per sample at table cost, on a second estimator (est keeps its own level). */
    nemm_estimator_config_t tab = {.alpha = 0.15f, .mode = NEMM_MODE_TABLE};
    CHECK_STATUS(nemm_estimator_init(&est_table, sizeof est_table, blob, len, &tab), NEMM_OK);
    CHECK_STATUS(nemm_estimator_attach_levels(&est_table, &levels), NEMM_OK);
    nemm_estimator_info_t info;
    CHECK_STATUS(nemm_estimator_info(&est, &info), NEMM_OK);
    nemm_estimate_t e;
    int ok = 1, finite = 1, clean = 1;
    for (int k = 0; k < 2000; k++) {
        float t = (float)k * info.dt_s;
        float v = 0.5f * sinf(2.0f * 3.14159265f * 5.0f * t);
        float alpha = 0.15f + 0.15f * sinf(2.0f * 3.14159265f * 2.0f * t); /* 0 to 0.3 */
        ok &= step_alpha(&est_table, v, alpha, &e) == NEMM_OK;
        finite &= isfinite(e.force_n) != 0;
        clean &= (e.flags & ~NEMM_FLAG_ALPHA_EXTRAPOLATED) == 0;
    }
    CHECK(ok && finite && clean);
    nemm_sample_t at = sample_of(0.1f, NEMM_SAMPLE_ALPHA | NEMM_SAMPLE_POSITION, 0.0f, 0.12f, 0.0f);
    CHECK_STATUS(nemm_estimator_step(&est_table, &at, &e), NEMM_OK);
    CHECK_STATUS(step_alpha(&est_table, 0.1f, 1.5f, &e), NEMM_E_ALPHA_OUT_OF_RANGE);
    /* The same level tables drive any estimator of their model; NULL detaches them: a
     * changed alpha is then refused in table mode. */
    CHECK_STATUS(nemm_estimator_attach_levels(&est, &levels), NEMM_OK);
    CHECK_STATUS(nemm_estimator_attach_levels(&est, NULL), NEMM_OK);
    CHECK_STATUS(nemm_estimator_attach_levels(NULL, &levels), NEMM_E_NULL);
    CHECK_STATUS(nemm_estimator_attach_levels(&est_table, NULL), NEMM_OK);
    CHECK_STATUS(step_alpha(&est_table, 0.1f, 0.1f, &e), NEMM_E_ALPHA_PER_SAMPLE_IN_TABLE_MODE);

    /* The observer on level tables: 3 s of a 0.5 m/s, 5 Hz sinusoid at alpha 0.12. */
    CHECK_STATUS(nemm_observer_init_on_levels(&obs, sizeof obs, &est, &levels, NULL), NEMM_OK);
    nemm_alpha_estimate_t a = {0};
    ok = 1;
    int n = (int)(3.0f / info.dt_s);
    for (int k = 0; k < n; k++) {
        float v = 0.5f * sinf(2.0f * 3.14159265f * 5.0f * (float)k * info.dt_s);
        ok &= step_v(&est, v, &e) == NEMM_OK;
        ok &= observe(&obs, v, e.force_n, &a) == NEMM_OK;
    }
    CHECK(ok);
    CHECK(fabsf(a.alpha - 0.12f) < 0.02f && !(a.flags & (NEMM_OBSERVER_NOT_EXCITED | NEMM_OBSERVER_NOT_SETTLED)));
    printf("observer on level tables: alpha %.4f +- %.4f (true 0.12), flags 0x%02x\n", a.alpha,
           a.band, a.flags);
    /* The grid is the levels': another one is refused. */
    nemm_observer_config_t oc;
    CHECK_STATUS(nemm_observer_config_default(&oc), NEMM_OK);
    oc.points = 5;
    CHECK_STATUS(nemm_observer_init_on_levels(&obs, sizeof obs, &est, &levels, &oc),
                 NEMM_E_OBSERVER_POINTS);
    CHECK_STATUS(nemm_observer_init(&obs, sizeof obs, &est, NULL), NEMM_OK);
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: %s <blob with level tables.nemm> <blob without.nemm>\n", argv[0]);
        return 2;
    }
    size_t len = 0, plain_len = 0;
    unsigned char *blob = read_file(argv[1], &len);
    unsigned char *plain = read_file(argv[2], &plain_len);
    if (!blob || len == 0 || !plain || plain_len == 0) {
        fprintf(stderr, "cannot read %s or %s\n", argv[1], argv[2]);
        return 2;
    }
    statuses();
    blobs(blob, len);
    storage_and_settings(blob, len);
    estimator(blob, len);
    observer();
    level_tables(blob, len, plain, plain_len);
    /* After the last use of the level tables, which read `blob` in place. */
    free(blob);
    free(plain);
    printf("nemm-c host test: %zu-byte estimator, %zu-byte observer, %zu-byte level tables\n",
           sizeof est, sizeof obs, sizeof levels);
    printf("%d passed, %d failed\n", passed, failed);
    return failed == 0 ? 0 : 1;
}

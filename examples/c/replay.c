/*
 * The NEMM estimator and alpha observer in a C program: what an ECU's 10 kHz task does,
 * replayed over recorded inputs.
 *
 * The weights blob and the inputs are linked into flash (mps2/embed.S). The inputs are the
 * samples a sensor path hands the estimator, little-endian:
 *
 *   offset  field
 *    0      magic "NCIN"
 *    4      mode: uint32, NEMM_MODE_EXACT or NEMM_MODE_TABLE
 *    8      alpha: float, the oil-loss level to estimate at
 *   12      n: uint32, number of samples
 *   16      n x (velocity_m_s, position_m, measured force_n): float each (NaN: none)
 *
 * Per sample the program steps the estimator with the velocity and the position (a model
 * without a static force ignores the position) and prints
 *
 *   s <k> <velocity bits> <force bits> <flags>
 *
 * (k decimal, the rest hex: the float's bits and the NEMM_FLAG_* bits, the first fields of
 * the Rust firmware's `s` lines), and steps two alpha observers with the velocity, the
 * position and the measured force: one on the exact model, one on the blob's level tables
 * (if it stores them), at a tenth of the cost. Around them a `c-example boot` line (what was
 * built), a `c-example summary` line (counters, the exact observer's estimate, instructions
 * per step, stack) and a `c-example levels` line (the level tables, the estimate and
 * instructions per step of the observer on them, and the instructions per step of the
 * estimator on them, run again over the velocities with a level ramping across the stored
 * levels). Exit code 0, or 2 after an error
 * (`c-example error call=<function> status=<code> <text>`).
 *
 * Freestanding C11: no C library, no allocation. Board support: mps2/board.h.
 */
#include "board.h"
#include "nemm.h"

extern const uint8_t nemm_example_blob[], nemm_example_blob_end[];
extern const uint8_t nemm_example_inputs[], nemm_example_inputs_end[];

/* The objects' storage: statics, as on an ECU (together about 107 KiB on Cortex-M; an ECU
 * would keep one of the two observers, usually the one on level tables). */
static nemm_estimator_t estimator;
static nemm_observer_t observer;
static nemm_levels_t levels;
static nemm_observer_t levels_observer;

/* --- output: one line at a time, integers in decimal or hex ------------------------------ */

static char line[256];
static size_t line_len;

static void put(const char *s) {
    while (*s && line_len < sizeof line) {
        line[line_len++] = *s++;
    }
}

static void put_dec(uint32_t v) {
    char digits[10];
    int n = 0;
    do {
        digits[n++] = (char)('0' + v % 10u);
        v /= 10u;
    } while (v != 0u);
    while (n > 0 && line_len < sizeof line) {
        line[line_len++] = digits[--n];
    }
}

static void put_hex(uint32_t v, int digits) {
    for (int i = digits - 1; i >= 0 && line_len < sizeof line; i--) {
        line[line_len++] = "0123456789abcdef"[(v >> (4 * i)) & 0xFu];
    }
}

static void end_line(void) {
    if (line_len == sizeof line) {
        line_len--;
    }
    line[line_len++] = '\n';
    board_write(line, line_len);
    line_len = 0;
}

static uint32_t bits_of(float f) {
    uint32_t b;
    __builtin_memcpy(&b, &f, sizeof b);
    return b;
}

static float float_at(const uint8_t *p) {
    uint32_t b = (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
    float f;
    __builtin_memcpy(&f, &b, sizeof f);
    return f;
}

static uint32_t u32_at(const uint8_t *p) { return bits_of(float_at(p)); }

/* A failed call: its name and status, exit code 2. */
static int fail(const char *call, nemm_status_t status) {
    put("c-example error call=");
    put(call);
    put(" status=");
    put_dec((uint32_t)status);
    put(" ");
    put(nemm_status_str(status));
    end_line();
    return 2;
}

/* SysTick ticks from `start` (it counts down over 24 bits). */
static uint32_t ticks_since(uint32_t start) { return (start - board_ticks()) & 0x00FFFFFFu; }

int main(void) {
    const uint8_t *in = nemm_example_inputs;
    size_t in_len = (size_t)(nemm_example_inputs_end - nemm_example_inputs);
    if (in_len < 16 || in[0] != 'N' || in[1] != 'C' || in[2] != 'I' || in[3] != 'N') {
        put("c-example error inputs");
        end_line();
        return 2;
    }
    uint32_t n = u32_at(in + 12);
    if ((in_len - 16) / 12 < n) {
        put("c-example error inputs");
        end_line();
        return 2;
    }

    /* Build the estimator from the blob in flash; the estimator does not read it afterwards
     * (the level tables below do: it stays in flash, unchanged). */
    const uint8_t *blob = nemm_example_blob;
    size_t blob_len = (size_t)(nemm_example_blob_end - nemm_example_blob);
    nemm_blob_info_t blob_info;
    nemm_status_t s = nemm_blob_validate(blob, blob_len, &blob_info);
    if (s != NEMM_OK) {
        return fail("nemm_blob_validate", s);
    }
    nemm_estimator_config_t config = {.alpha = float_at(in + 8), .mode = u32_at(in + 4)};
    s = nemm_estimator_init(&estimator, sizeof estimator, blob, blob_len, &config);
    if (s != NEMM_OK) {
        return fail("nemm_estimator_init", s);
    }
    /* The observer of the same model, with the default settings. */
    s = nemm_observer_init(&observer, sizeof observer, &estimator, NULL);
    if (s != NEMM_OK) {
        return fail("nemm_observer_init", s);
    }
    /* The blob's level tables (read in place from the blob in flash, which mps2/embed.S
     * places 4-byte aligned), and an observer on them. A blob without usable level tables
     * (none stored, or stored by format version 4 or 5) is no error here: that observer is
     * left out. An unaligned blob is: the embedding is wrong. */
    nemm_levels_info_t levels_info = {0};
    nemm_status_t levels_status = nemm_levels_init(&levels, sizeof levels, &estimator, blob, blob_len);
    int on_levels = levels_status == NEMM_OK;
    if (!on_levels && !((levels_status >= NEMM_E_LEVELS_NO_NEURAL_COEFFICIENT &&
                         levels_status <= NEMM_E_LEVELS_MISMATCH) ||
                        levels_status == NEMM_E_LEVELS_LAYOUT)) {
        return fail("nemm_levels_init", levels_status);
    }
    if (on_levels) {
        s = nemm_levels_info(&levels, &levels_info);
        if (s != NEMM_OK) {
            return fail("nemm_levels_info", s);
        }
        s = nemm_observer_init_on_levels(&levels_observer, sizeof levels_observer, &estimator,
                                         &levels, NULL);
        if (s != NEMM_OK) {
            return fail("nemm_observer_init_on_levels", s);
        }
    }
    nemm_estimator_info_t info;
    s = nemm_estimator_info(&estimator, &info);
    if (s != NEMM_OK) {
        return fail("nemm_estimator_info", s);
    }
    put("c-example boot estimator_bytes=");
    put_dec((uint32_t)sizeof estimator);
    put(" observer_bytes=");
    put_dec((uint32_t)sizeof observer);
    put(" format_version=");
    put_dec(blob_info.format_version);
    put(" kind=");
    put_dec(info.kind);
    put(" mode=");
    put(info.mode == NEMM_MODE_TABLE ? "table" : "exact");
    put(" tables=");
    put(info.table_origin == NEMM_TABLES_STORED  ? "stored"
        : info.table_origin == NEMM_TABLES_BUILT ? "built"
                                                 : "none");
    put(" alpha=0x");
    put_hex(bits_of(info.alpha), 8);
    put(" needs_position=");
    put_dec(info.needs_position);
    put(" samples=");
    put_dec(n);
    end_line();

    /* The sample loop: on an ECU, the body of the 10 kHz task. */
    uint32_t step_ticks = 0, observer_ticks = 0, levels_observer_ticks = 0;
    nemm_alpha_estimate_t alpha = {0}, levels_alpha = {0};
    for (uint32_t k = 0; k < n; k++) {
        const uint8_t *sample = in + 16 + 12 * (size_t)k;
        float velocity = float_at(sample), position = float_at(sample + 4);
        float measured = float_at(sample + 8);
        /* One sample: the velocity, the position and the measured force (the estimator
         * reads no force, the observer no alpha). */
        const nemm_sample_t in_sample = {
            .velocity_m_s = velocity,
            .position_m = position,
            .force_n = measured,
            .fields = NEMM_SAMPLE_POSITION | NEMM_SAMPLE_FORCE,
        };
        nemm_estimate_t e;
        uint32_t t0 = board_ticks();
        s = nemm_estimator_step(&estimator, &in_sample, &e);
        step_ticks += ticks_since(t0);
        if (s != NEMM_OK) {
            return fail("nemm_estimator_step", s);
        }
        t0 = board_ticks();
        s = nemm_observer_step(&observer, &in_sample, &alpha);
        observer_ticks += ticks_since(t0);
        if (s != NEMM_OK) {
            return fail("nemm_observer_step", s);
        }
        if (on_levels) {
            t0 = board_ticks();
            s = nemm_observer_step(&levels_observer, &in_sample, &levels_alpha);
            levels_observer_ticks += ticks_since(t0);
            if (s != NEMM_OK) {
                return fail("nemm_observer_step (on levels)", s);
            }
        }
        put("s ");
        put_dec(k);
        put(" ");
        put_hex(bits_of(velocity), 8);
        put(" ");
        put_hex(bits_of(e.force_n), 8);
        put(" ");
        put_hex(e.flags, 2);
        end_line();
    }

    s = nemm_estimator_info(&estimator, &info);
    if (s != NEMM_OK) {
        return fail("nemm_estimator_info", s);
    }
    put("c-example summary steps=");
    put_dec(info.steps);
    put(" held=");
    put_dec(info.held_samples);
    put(" resets=");
    put_dec(info.resets);
    put(" observer_alpha_e4=");
    put_dec((uint32_t)(alpha.alpha * 10000.0f + 0.5f));
    put(" observer_band_e4=");
    put_dec((uint32_t)(alpha.band * 10000.0f + 0.5f));
    put(" observer_flags=");
    put_hex(alpha.flags, 2);
    put(" step_instructions=");
    put_dec(n ? (uint32_t)((uint64_t)step_ticks * BOARD_INSTRUCTIONS_PER_TICK / n) : 0);
    put(" observer_step_instructions=");
    put_dec(n ? (uint32_t)((uint64_t)observer_ticks * BOARD_INSTRUCTIONS_PER_TICK / n) : 0);
    put(" stack_used=");
    put_dec(board_stack_used());
    end_line();

    /* A level per sample at table cost: the estimator once more over the velocities (after
     * the records above, so from rest), its level ramping across the stored levels. */
    uint32_t levels_step_ticks = 0;
    if (on_levels) {
        s = nemm_estimator_reset(&estimator);
        if (s != NEMM_OK) {
            return fail("nemm_estimator_reset", s);
        }
        s = nemm_estimator_attach_levels(&estimator, &levels);
        if (s != NEMM_OK) {
            return fail("nemm_estimator_attach_levels", s);
        }
        float lo = levels_info.alpha[0], hi = levels_info.alpha[levels_info.levels - 1];
        for (uint32_t k = 0; k < n; k++) {
            const uint8_t *sample = in + 16 + 12 * (size_t)k;
            float level = lo + (hi - lo) * (float)k / (float)n;
            const nemm_sample_t at_level = {
                .velocity_m_s = float_at(sample),
                .position_m = float_at(sample + 4),
                .alpha = level,
                .fields = NEMM_SAMPLE_POSITION | NEMM_SAMPLE_ALPHA,
            };
            nemm_estimate_t e;
            uint32_t t0 = board_ticks();
            s = nemm_estimator_step(&estimator, &at_level, &e);
            levels_step_ticks += ticks_since(t0);
            if (s != NEMM_OK) {
                return fail("nemm_estimator_step (on levels)", s);
            }
        }
    }

    put("c-example levels status=");
    put_dec((uint32_t)levels_status);
    put(" levels=");
    put_dec(levels_info.levels);
    put(" levels_bytes=");
    put_dec((uint32_t)sizeof levels);
    put(" table_bytes=");
    put_dec(levels_info.table_bytes);
    if (on_levels) {
        put(" observer_alpha_e4=");
        put_dec((uint32_t)(levels_alpha.alpha * 10000.0f + 0.5f));
        put(" observer_band_e4=");
        put_dec((uint32_t)(levels_alpha.band * 10000.0f + 0.5f));
        put(" observer_flags=");
        put_hex(levels_alpha.flags, 2);
        put(" observer_step_instructions=");
        put_dec(n ? (uint32_t)((uint64_t)levels_observer_ticks * BOARD_INSTRUCTIONS_PER_TICK / n) : 0);
        put(" step_instructions=");
        put_dec(n ? (uint32_t)((uint64_t)levels_step_ticks * BOARD_INSTRUCTIONS_PER_TICK / n) : 0);
    }
    end_line();
    return 0;
}

/* mimo_tilt.h: controller "mimo_tilt", exported by workbench.export. Re-export rather than edit.
 *
 * Form: cascade of 2 second-order sections, transposed direct form II (TDF-II). Each section,
 * input x, output y, states s1, s2:  y = b0 x + s1;  s1 = b1 x - a1 y + s2;  s2 = b2 x - a2 y.
 * Sample rate 10000 Hz: call one step per sample. The reset puts the controller at rest at
 * an output u0 with zero error (bumpless start at a bias; u0 = 0 zeroes every state).
 * Input:  gauge error (reference minus demodulated gauge reading), firmware volts, +/-57.3864 V.
 * Output: commanded PZT voltage, volts, clamped to [-70, 70] V
 *         and to [v - 0.064, v + 0.064] V, v the model of the stack voltage (v += alpha (u - v), alpha = 0.102146):
 *         the current (u - v) / R stays within the amplifier's limits, the command slews at most +65.37 / -65.37 V/s. The clamped value
 *         drives the last section (anti-windup): the integrator is conditioned on what was applied.
 *
 * mimo_tilt_float_step: double precision, MIMO_TILT_GAIN times the input, then the rows of MIMO_TILT_SOS.
 * mimo_tilt_fixed_step: int32 words, int64 accumulators, F = MIMO_TILT_A_FRAC_BITS = 29:
 *   input word  Q6.25 (volts * 2^25), clamped to +/-MIMO_TILT_INPUT_LIMIT_Q
 *   output word Q7.24 (volts * 2^24), clamped to [MIMO_TILT_OUTPUT_MIN_Q, MIMO_TILT_OUTPUT_MAX_Q]
 *   a1, a2 in Q2.29; per section (y, s1 and s2 share the signal format):
 *   section 0: signals Q5.26, b, b shift 7
 *   section 1: signals Q7.24, b, b shift 3 (integrator, exact at z = 1)
 *   acc = align(b x) + s * 2^F - a y  (64 bit);  word = (acc + 2^(F-1)) >> F, round half up,
 *   saturated to int32;  align(p) = p >> shift, or p * 2^-shift for a negative shift.
 *   Scaling: L1 norms from the input bound every state but the last section's; the output clamp
 *   bounds those. No state can overflow for any input word. Right shifts of negative integers
 *   must be arithmetic (gcc, clang, arm-none-eabi-gcc, IAR and Keil are).
 * Quantized response against the design up to 4000 Hz: 1.8e-08 dB, 1.1e-07 deg;
 * largest pole radius 0.836244027 (integrators excluded: they stay exactly at z = 1).
 */
#ifndef MIMO_TILT_H
#define MIMO_TILT_H

#include <math.h>   /* INFINITY */
#include <stdint.h>

#define MIMO_TILT_N_SECTIONS 2
#define MIMO_TILT_SAMPLE_RATE_HZ 10000.0
#define MIMO_TILT_INPUT_RANGE_V 57.386364802696775
#define MIMO_TILT_OUTPUT_MIN_V (-70.0)
#define MIMO_TILT_OUTPUT_MAX_V (70.0)
#define MIMO_TILT_INPUT_FRAC_BITS 25
#define MIMO_TILT_OUTPUT_FRAC_BITS 24
#define MIMO_TILT_A_FRAC_BITS 29
#define MIMO_TILT_INPUT_LIMIT_Q INT32_C(1925566875)
#define MIMO_TILT_OUTPUT_MIN_Q INT32_C(-1174405120)
#define MIMO_TILT_OUTPUT_MAX_Q INT32_C(1174405120)
/* current-limit window: model v of the stack voltage, v += alpha (u - v); u within [v - h_down, v + h_up] */
#define MIMO_TILT_ALPHA (0.10214635534294046)
#define MIMO_TILT_ALPHA_Q INT64_C(109678814)
#define MIMO_TILT_ALPHA_FRAC_BITS 30
#define MIMO_TILT_HEADROOM_UP_V (0.06399999985850155)
#define MIMO_TILT_HEADROOM_DOWN_V (0.06399999985850155)
#define MIMO_TILT_HEADROOM_UP_Q INT64_C(1073741)
#define MIMO_TILT_HEADROOM_DOWN_Q INT64_C(1073741)

static const double MIMO_TILT_GAIN = 0.010290378144311904;
/* rows b0, b1, b2, a0 = 1, a1, a2 */
static const double MIMO_TILT_SOS[MIMO_TILT_N_SECTIONS][6] = {
    {0.5000000000000019, 1.0, 0.5000000000000088, 1.0, -1.6237219899936903, 0.6993040714071791},
    {1.0, -0.8597607344731598, 0.0, 1.0, -1.0, 0.0}
};
static const int32_t MIMO_TILT_B_Q[MIMO_TILT_N_SECTIONS][3] = {
    {INT32_C(707149401), INT32_C(1414298802), INT32_C(707149401)},
    {INT32_C(1073741824), INT32_C(-923161059), INT32_C(0)}
};
static const int32_t MIMO_TILT_A_Q[MIMO_TILT_N_SECTIONS][2] = {
    {INT32_C(-871729106), INT32_C(375436015)},
    {INT32_C(-536870912), INT32_C(0)}
};
static const int MIMO_TILT_B_SHIFT[MIMO_TILT_N_SECTIONS] = {7, 3};

/* s: section states; v: the model of the stack voltage (the current-limit window's centre) */
typedef struct { double s[MIMO_TILT_N_SECTIONS][2]; double v; } mimo_tilt_float_state;
typedef struct { int32_t s[MIMO_TILT_N_SECTIONS][2]; int32_t v; } mimo_tilt_fixed_state;

/* At rest at output u0_v (V) with zero error: the last (integrator) section holds it. */
static inline void mimo_tilt_float_reset(mimo_tilt_float_state *st, double u0_v)
{
    for (int k = 0; k < MIMO_TILT_N_SECTIONS; k++) st->s[k][0] = st->s[k][1] = 0.0;
    st->s[MIMO_TILT_N_SECTIONS - 1][0] = u0_v;
    st->s[MIMO_TILT_N_SECTIONS - 1][1] = -MIMO_TILT_SOS[MIMO_TILT_N_SECTIONS - 1][5] * u0_v;
    st->v = u0_v;
}

/* One sample: gauge error e_v (V) in, PZT command (V) out. */
static inline double mimo_tilt_float_step(mimo_tilt_float_state *st, double e_v)
{
    double v = MIMO_TILT_GAIN * e_v;
    for (int k = 0; k < MIMO_TILT_N_SECTIONS; k++) {
        const double *c = MIMO_TILT_SOS[k];
        double y = c[0] * v + st->s[k][0];
        if (k == MIMO_TILT_N_SECTIONS - 1) {
            double lo = st->v - MIMO_TILT_HEADROOM_DOWN_V, hi = st->v + MIMO_TILT_HEADROOM_UP_V;
            if (lo < MIMO_TILT_OUTPUT_MIN_V) lo = MIMO_TILT_OUTPUT_MIN_V;
            if (hi > MIMO_TILT_OUTPUT_MAX_V) hi = MIMO_TILT_OUTPUT_MAX_V;
            y = y < lo ? lo : y > hi ? hi : y;
        }
        st->s[k][0] = c[1] * v - c[4] * y + st->s[k][1];
        st->s[k][1] = c[2] * v - c[5] * y;
        v = y;
    }
    st->v += MIMO_TILT_ALPHA * (v - st->v);
    return v;
}

static inline int64_t mimo_tilt_align_(int64_t p, int shift)
{
    return shift >= 0 ? p >> shift : p * ((int64_t)1 << -shift);
}

static inline int32_t mimo_tilt_sat32_(int64_t v)
{
    return v > INT32_MAX ? INT32_MAX : v < INT32_MIN ? INT32_MIN : (int32_t)v;
}

/* At rest at output word u0_q with zero error: y = s1 = u0, s2 = round(-a2 u0) in the last section. */
static inline void mimo_tilt_fixed_reset(mimo_tilt_fixed_state *st, int32_t u0_q)
{
    const int64_t half = (int64_t)1 << (MIMO_TILT_A_FRAC_BITS - 1);
    int64_t u0 = u0_q > MIMO_TILT_OUTPUT_MAX_Q ? MIMO_TILT_OUTPUT_MAX_Q : u0_q < MIMO_TILT_OUTPUT_MIN_Q ? MIMO_TILT_OUTPUT_MIN_Q : u0_q;
    for (int k = 0; k < MIMO_TILT_N_SECTIONS; k++) st->s[k][0] = st->s[k][1] = 0;
    st->s[MIMO_TILT_N_SECTIONS - 1][0] = (int32_t)u0;
    st->s[MIMO_TILT_N_SECTIONS - 1][1] = (int32_t)((-(int64_t)MIMO_TILT_A_Q[MIMO_TILT_N_SECTIONS - 1][1] * u0 + half) >> MIMO_TILT_A_FRAC_BITS);
    st->v = (int32_t)u0;
}

/* One sample: input word e_q (Q6.25) in, output word (Q7.24) out. */
static inline int32_t mimo_tilt_fixed_step(mimo_tilt_fixed_state *st, int32_t e_q)
{
    const int64_t one = (int64_t)1 << MIMO_TILT_A_FRAC_BITS, half = one >> 1;
    int64_t v = e_q > MIMO_TILT_INPUT_LIMIT_Q ? MIMO_TILT_INPUT_LIMIT_Q : e_q < -MIMO_TILT_INPUT_LIMIT_Q ? -MIMO_TILT_INPUT_LIMIT_Q : e_q;
    for (int k = 0; k < MIMO_TILT_N_SECTIONS; k++) {
        const int32_t *b = MIMO_TILT_B_Q[k], *a = MIMO_TILT_A_Q[k];
        const int shift = MIMO_TILT_B_SHIFT[k];
        const int last = k == MIMO_TILT_N_SECTIONS - 1;
        int64_t lo = INT32_MIN, hi = INT32_MAX;
        if (last) {
            lo = (int64_t)st->v - MIMO_TILT_HEADROOM_DOWN_Q;
            hi = (int64_t)st->v + MIMO_TILT_HEADROOM_UP_Q;
            if (lo < MIMO_TILT_OUTPUT_MIN_Q) lo = MIMO_TILT_OUTPUT_MIN_Q;
            if (hi > MIMO_TILT_OUTPUT_MAX_Q) hi = MIMO_TILT_OUTPUT_MAX_Q;
        }
        int64_t y = (mimo_tilt_align_(b[0] * v, shift) + st->s[k][0] * one + half) >> MIMO_TILT_A_FRAC_BITS;
        y = y > hi ? hi : y < lo ? lo : y;
        const int64_t s1 = (mimo_tilt_align_(b[1] * v, shift) - a[0] * y + st->s[k][1] * one + half) >> MIMO_TILT_A_FRAC_BITS;
        const int64_t s2 = (mimo_tilt_align_(b[2] * v, shift) - a[1] * y + half) >> MIMO_TILT_A_FRAC_BITS;
        st->s[k][0] = mimo_tilt_sat32_(s1);
        st->s[k][1] = mimo_tilt_sat32_(s2);
        v = y;
    }
    st->v = (int32_t)((int64_t)st->v + (((v - (int64_t)st->v) * MIMO_TILT_ALPHA_Q
                                         + ((int64_t)1 << (MIMO_TILT_ALPHA_FRAC_BITS - 1))) >> MIMO_TILT_ALPHA_FRAC_BITS));
    return (int32_t)v;
}

#endif /* MIMO_TILT_H */

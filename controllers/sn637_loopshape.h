/* sn637_loopshape.h: controller "sn637_loopshape", exported by workbench.export. Re-export rather than edit.
 *
 * Form: cascade of 2 second-order sections, transposed direct form II (TDF-II). Each section,
 * input x, output y, states s1, s2:  y = b0 x + s1;  s1 = b1 x - a1 y + s2;  s2 = b2 x - a2 y.
 * Sample rate 10000 Hz: call one step per sample, states zeroed by the reset.
 * Input:  gauge error (reference minus demodulated gauge reading), firmware volts, +/-2.6 V.
 * Output: commanded PZT voltage, volts, clamped to [-20, 120] V. The clamped value drives the
 *         last section (anti-windup): the integrator state cannot wind past the limits.
 *
 * sn637_loopshape_float_step: double precision, SN637_LOOPSHAPE_GAIN times the input, then the rows of SN637_LOOPSHAPE_SOS.
 * sn637_loopshape_fixed_step: int32 words, int64 accumulators, F = SN637_LOOPSHAPE_A_FRAC_BITS = 29:
 *   input word  Q2.29 (volts * 2^29), clamped to +/-SN637_LOOPSHAPE_INPUT_LIMIT_Q
 *   output word Q9.22 (volts * 2^22), clamped to [SN637_LOOPSHAPE_OUTPUT_MIN_Q, SN637_LOOPSHAPE_OUTPUT_MAX_Q]
 *   a1, a2 in Q2.29; per section (y, s1 and s2 share the signal format):
 *   section 0: signals Q8.23, b Q0.31, b shift 2
 *   section 1: signals Q9.22, b Q0.31, b shift 2 (integrator, exact at z = 1)
 *   acc = align(b x) + s * 2^F - a y  (64 bit);  word = (acc + 2^(F-1)) >> F, round half up,
 *   saturated to int32;  align(p) = p >> shift, or p * 2^-shift for a negative shift.
 *   Scaling: L1 norms from the input bound every state but the last section's; the output clamp
 *   bounds those. No state can overflow for any input word. Right shifts of negative integers
 *   must be arithmetic (gcc, clang, arm-none-eabi-gcc, IAR and Keil are).
 * Quantized response against the design up to 3963.58 Hz: 2e-08 dB, 9.8e-08 deg;
 * largest pole radius 0.500000417 (integrators excluded: they stay exactly at z = 1).
 */
#ifndef SN637_LOOPSHAPE_H
#define SN637_LOOPSHAPE_H

#include <stdint.h>

#define SN637_LOOPSHAPE_N_SECTIONS 2
#define SN637_LOOPSHAPE_SAMPLE_RATE_HZ 10000.0
#define SN637_LOOPSHAPE_INPUT_RANGE_V 2.6
#define SN637_LOOPSHAPE_OUTPUT_MIN_V (-20.0)
#define SN637_LOOPSHAPE_OUTPUT_MAX_V (120.0)
#define SN637_LOOPSHAPE_INPUT_FRAC_BITS 29
#define SN637_LOOPSHAPE_OUTPUT_FRAC_BITS 22
#define SN637_LOOPSHAPE_A_FRAC_BITS 29
#define SN637_LOOPSHAPE_INPUT_LIMIT_Q INT32_C(1395864371)
#define SN637_LOOPSHAPE_OUTPUT_MIN_Q INT32_C(-83886080)
#define SN637_LOOPSHAPE_OUTPUT_MAX_Q INT32_C(503316480)

static const double SN637_LOOPSHAPE_GAIN = 32.05524668494441;
/* rows b0, b1, b2, a0 = 1, a1, a2 */
static const double SN637_LOOPSHAPE_SOS[SN637_LOOPSHAPE_N_SECTIONS][6] = {
    {0.5000000000000001, 1.0, 0.5000000000000002, 1.0, 0.0016690788352692887, 0.2500004178736697},
    {1.0, -0.9691902900923616, 0.0, 1.0, -1.0, 0.0}
};
static const int32_t SN637_LOOPSHAPE_B_Q[SN637_LOOPSHAPE_N_SECTIONS][3] = {
    {INT32_C(537797798), INT32_C(1075595596), INT32_C(537797798)},
    {INT32_C(1073741824), INT32_C(-1040660150), INT32_C(0)}
};
static const int32_t SN637_LOOPSHAPE_A_Q[SN637_LOOPSHAPE_N_SECTIONS][2] = {
    {INT32_C(896080), INT32_C(134217952)},
    {INT32_C(-536870912), INT32_C(0)}
};
static const int SN637_LOOPSHAPE_B_SHIFT[SN637_LOOPSHAPE_N_SECTIONS] = {2, 2};

typedef struct { double s[SN637_LOOPSHAPE_N_SECTIONS][2]; } sn637_loopshape_float_state;
typedef struct { int32_t s[SN637_LOOPSHAPE_N_SECTIONS][2]; } sn637_loopshape_fixed_state;

static inline void sn637_loopshape_float_reset(sn637_loopshape_float_state *st)
{
    for (int k = 0; k < SN637_LOOPSHAPE_N_SECTIONS; k++) st->s[k][0] = st->s[k][1] = 0.0;
}

static inline void sn637_loopshape_fixed_reset(sn637_loopshape_fixed_state *st)
{
    for (int k = 0; k < SN637_LOOPSHAPE_N_SECTIONS; k++) st->s[k][0] = st->s[k][1] = 0;
}

/* One sample: gauge error e_v (V) in, PZT command (V) out. */
static inline double sn637_loopshape_float_step(sn637_loopshape_float_state *st, double e_v)
{
    double v = SN637_LOOPSHAPE_GAIN * e_v;
    for (int k = 0; k < SN637_LOOPSHAPE_N_SECTIONS; k++) {
        const double *c = SN637_LOOPSHAPE_SOS[k];
        double y = c[0] * v + st->s[k][0];
        if (k == SN637_LOOPSHAPE_N_SECTIONS - 1) {
            if (y < SN637_LOOPSHAPE_OUTPUT_MIN_V) y = SN637_LOOPSHAPE_OUTPUT_MIN_V;
            else if (y > SN637_LOOPSHAPE_OUTPUT_MAX_V) y = SN637_LOOPSHAPE_OUTPUT_MAX_V;
        }
        st->s[k][0] = c[1] * v - c[4] * y + st->s[k][1];
        st->s[k][1] = c[2] * v - c[5] * y;
        v = y;
    }
    return v;
}

static inline int64_t sn637_loopshape_align_(int64_t p, int shift)
{
    return shift >= 0 ? p >> shift : p * ((int64_t)1 << -shift);
}

static inline int32_t sn637_loopshape_sat32_(int64_t v)
{
    return v > INT32_MAX ? INT32_MAX : v < INT32_MIN ? INT32_MIN : (int32_t)v;
}

/* One sample: input word e_q (Q2.29) in, output word (Q9.22) out. */
static inline int32_t sn637_loopshape_fixed_step(sn637_loopshape_fixed_state *st, int32_t e_q)
{
    const int64_t one = (int64_t)1 << SN637_LOOPSHAPE_A_FRAC_BITS, half = one >> 1;
    int64_t v = e_q > SN637_LOOPSHAPE_INPUT_LIMIT_Q ? SN637_LOOPSHAPE_INPUT_LIMIT_Q : e_q < -SN637_LOOPSHAPE_INPUT_LIMIT_Q ? -SN637_LOOPSHAPE_INPUT_LIMIT_Q : e_q;
    for (int k = 0; k < SN637_LOOPSHAPE_N_SECTIONS; k++) {
        const int32_t *b = SN637_LOOPSHAPE_B_Q[k], *a = SN637_LOOPSHAPE_A_Q[k];
        const int shift = SN637_LOOPSHAPE_B_SHIFT[k];
        const int last = k == SN637_LOOPSHAPE_N_SECTIONS - 1;
        const int64_t lo = last ? SN637_LOOPSHAPE_OUTPUT_MIN_Q : INT32_MIN, hi = last ? SN637_LOOPSHAPE_OUTPUT_MAX_Q : INT32_MAX;
        int64_t y = (sn637_loopshape_align_(b[0] * v, shift) + st->s[k][0] * one + half) >> SN637_LOOPSHAPE_A_FRAC_BITS;
        y = y > hi ? hi : y < lo ? lo : y;
        const int64_t s1 = (sn637_loopshape_align_(b[1] * v, shift) - a[0] * y + st->s[k][1] * one + half) >> SN637_LOOPSHAPE_A_FRAC_BITS;
        const int64_t s2 = (sn637_loopshape_align_(b[2] * v, shift) - a[1] * y + half) >> SN637_LOOPSHAPE_A_FRAC_BITS;
        st->s[k][0] = sn637_loopshape_sat32_(s1);
        st->s[k][1] = sn637_loopshape_sat32_(s2);
        v = y;
    }
    return (int32_t)v;
}

#endif /* SN637_LOOPSHAPE_H */

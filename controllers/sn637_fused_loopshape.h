/* sn637_fused_loopshape.h: controller "sn637_fused_loopshape", exported by workbench.export. Re-export rather than edit.
 *
 * Form: cascade of 2 second-order sections, transposed direct form II (TDF-II). Each section,
 * input x, output y, states s1, s2:  y = b0 x + s1;  s1 = b1 x - a1 y + s2;  s2 = b2 x - a2 y.
 * Sample rate 10000 Hz: call one step per sample. The reset puts the controller at rest at
 * an output u0 with zero error (bumpless start at a bias; u0 = 0 zeroes every state).
 * Input:  gauge error (reference minus demodulated gauge reading), firmware volts, +/-2.6 V.
 * Output: commanded PZT voltage, volts, clamped to [-20, 120] V
 *         and to [v - 1.12, v + 0.16] V, v the model of the stack voltage (v += alpha (u - v), alpha = 0.0996443):
 *         the current (u - v) / R stays within the amplifier's limits, the command slews at most +159.4 / -1116 V/s. The clamped value
 *         drives the last section (anti-windup): the integrator is conditioned on what was applied.
 *
 * sn637_fused_loopshape_float_step: double precision, SN637_FUSED_LOOPSHAPE_GAIN times the input, then the rows of SN637_FUSED_LOOPSHAPE_SOS.
 * sn637_fused_loopshape_fixed_step: int32 words, int64 accumulators, F = SN637_FUSED_LOOPSHAPE_A_FRAC_BITS = 29:
 *   input word  Q2.29 (volts * 2^29), clamped to +/-SN637_FUSED_LOOPSHAPE_INPUT_LIMIT_Q
 *   output word Q10.21 (volts * 2^21), clamped to [SN637_FUSED_LOOPSHAPE_OUTPUT_MIN_Q, SN637_FUSED_LOOPSHAPE_OUTPUT_MAX_Q]
 *   a1, a2 in Q2.29; per section (y, s1 and s2 share the signal format):
 *   section 0: signals Q9.22, b, b shift 3
 *   section 1: signals Q10.21, b Q0.31, b shift 2 (integrator, exact at z = 1)
 *   acc = align(b x) + s * 2^F - a y  (64 bit);  word = (acc + 2^(F-1)) >> F, round half up,
 *   saturated to int32;  align(p) = p >> shift, or p * 2^-shift for a negative shift.
 *   Scaling: L1 norms from the input bound every state but the last section's; the output clamp
 *   bounds those. No state can overflow for any input word. Right shifts of negative integers
 *   must be arithmetic (gcc, clang, arm-none-eabi-gcc, IAR and Keil are).
 * Quantized response against the design up to 3963.58 Hz: 1.1e-08 dB, 5.1e-08 deg;
 * largest pole radius 0.643661384 (integrators excluded: they stay exactly at z = 1).
 */
#ifndef SN637_FUSED_LOOPSHAPE_H
#define SN637_FUSED_LOOPSHAPE_H

#include <math.h>   /* INFINITY */
#include <stdint.h>

#define SN637_FUSED_LOOPSHAPE_N_SECTIONS 2
#define SN637_FUSED_LOOPSHAPE_SAMPLE_RATE_HZ 10000.0
#define SN637_FUSED_LOOPSHAPE_INPUT_RANGE_V 2.6
#define SN637_FUSED_LOOPSHAPE_OUTPUT_MIN_V (-20.0)
#define SN637_FUSED_LOOPSHAPE_OUTPUT_MAX_V (120.0)
#define SN637_FUSED_LOOPSHAPE_INPUT_FRAC_BITS 29
#define SN637_FUSED_LOOPSHAPE_OUTPUT_FRAC_BITS 21
#define SN637_FUSED_LOOPSHAPE_A_FRAC_BITS 29
#define SN637_FUSED_LOOPSHAPE_INPUT_LIMIT_Q INT32_C(1395864371)
#define SN637_FUSED_LOOPSHAPE_OUTPUT_MIN_Q INT32_C(-41943040)
#define SN637_FUSED_LOOPSHAPE_OUTPUT_MAX_Q INT32_C(251658240)
/* current-limit window: model v of the stack voltage, v += alpha (u - v); u within [v - h_down, v + h_up] */
#define SN637_FUSED_LOOPSHAPE_ALPHA (0.0996443105766158)
#define SN637_FUSED_LOOPSHAPE_ALPHA_Q INT64_C(106992264)
#define SN637_FUSED_LOOPSHAPE_ALPHA_FRAC_BITS 30
#define SN637_FUSED_LOOPSHAPE_HEADROOM_UP_V (0.16)
#define SN637_FUSED_LOOPSHAPE_HEADROOM_DOWN_V (1.12)
#define SN637_FUSED_LOOPSHAPE_HEADROOM_UP_Q INT64_C(335544)
#define SN637_FUSED_LOOPSHAPE_HEADROOM_DOWN_Q INT64_C(2348810)

static const double SN637_FUSED_LOOPSHAPE_GAIN = -61.16195135044136;
/* rows b0, b1, b2, a0 = 1, a1, a2 */
static const double SN637_FUSED_LOOPSHAPE_SOS[SN637_FUSED_LOOPSHAPE_N_SECTIONS][6] = {
    {0.5, 1.0, 0.4999999999999993, 1.0, 0.0016690788352693026, 0.2500004178736699},
    {-0.6087449593320364, 1.0, -0.4095106087941091, 1.0, -1.6436613833115916, 0.6436613833115915}
};
static const int32_t SN637_FUSED_LOOPSHAPE_B_Q[SN637_FUSED_LOOPSHAPE_N_SECTIONS][3] = {
    {INT32_C(-1026127269), INT32_C(-2052254538), INT32_C(-1026127269)},
    {INT32_C(-653634923), INT32_C(1073741824), INT32_C(-439708668)}
};
static const int32_t SN637_FUSED_LOOPSHAPE_A_Q[SN637_FUSED_LOOPSHAPE_N_SECTIONS][2] = {
    {INT32_C(896080), INT32_C(134217952)},
    {INT32_C(-882433986), INT32_C(345563074)}
};
static const int SN637_FUSED_LOOPSHAPE_B_SHIFT[SN637_FUSED_LOOPSHAPE_N_SECTIONS] = {3, 2};

/* s: section states; v: the model of the stack voltage (the current-limit window's centre) */
typedef struct { double s[SN637_FUSED_LOOPSHAPE_N_SECTIONS][2]; double v; } sn637_fused_loopshape_float_state;
typedef struct { int32_t s[SN637_FUSED_LOOPSHAPE_N_SECTIONS][2]; int32_t v; } sn637_fused_loopshape_fixed_state;

/* At rest at output u0_v (V) with zero error: the last (integrator) section holds it. */
static inline void sn637_fused_loopshape_float_reset(sn637_fused_loopshape_float_state *st, double u0_v)
{
    for (int k = 0; k < SN637_FUSED_LOOPSHAPE_N_SECTIONS; k++) st->s[k][0] = st->s[k][1] = 0.0;
    st->s[SN637_FUSED_LOOPSHAPE_N_SECTIONS - 1][0] = u0_v;
    st->s[SN637_FUSED_LOOPSHAPE_N_SECTIONS - 1][1] = -SN637_FUSED_LOOPSHAPE_SOS[SN637_FUSED_LOOPSHAPE_N_SECTIONS - 1][5] * u0_v;
    st->v = u0_v;
}

/* One sample: gauge error e_v (V) in, PZT command (V) out. */
static inline double sn637_fused_loopshape_float_step(sn637_fused_loopshape_float_state *st, double e_v)
{
    double v = SN637_FUSED_LOOPSHAPE_GAIN * e_v;
    for (int k = 0; k < SN637_FUSED_LOOPSHAPE_N_SECTIONS; k++) {
        const double *c = SN637_FUSED_LOOPSHAPE_SOS[k];
        double y = c[0] * v + st->s[k][0];
        if (k == SN637_FUSED_LOOPSHAPE_N_SECTIONS - 1) {
            double lo = st->v - SN637_FUSED_LOOPSHAPE_HEADROOM_DOWN_V, hi = st->v + SN637_FUSED_LOOPSHAPE_HEADROOM_UP_V;
            if (lo < SN637_FUSED_LOOPSHAPE_OUTPUT_MIN_V) lo = SN637_FUSED_LOOPSHAPE_OUTPUT_MIN_V;
            if (hi > SN637_FUSED_LOOPSHAPE_OUTPUT_MAX_V) hi = SN637_FUSED_LOOPSHAPE_OUTPUT_MAX_V;
            y = y < lo ? lo : y > hi ? hi : y;
        }
        st->s[k][0] = c[1] * v - c[4] * y + st->s[k][1];
        st->s[k][1] = c[2] * v - c[5] * y;
        v = y;
    }
    st->v += SN637_FUSED_LOOPSHAPE_ALPHA * (v - st->v);
    return v;
}

static inline int64_t sn637_fused_loopshape_align_(int64_t p, int shift)
{
    return shift >= 0 ? p >> shift : p * ((int64_t)1 << -shift);
}

static inline int32_t sn637_fused_loopshape_sat32_(int64_t v)
{
    return v > INT32_MAX ? INT32_MAX : v < INT32_MIN ? INT32_MIN : (int32_t)v;
}

/* At rest at output word u0_q with zero error: y = s1 = u0, s2 = round(-a2 u0) in the last section. */
static inline void sn637_fused_loopshape_fixed_reset(sn637_fused_loopshape_fixed_state *st, int32_t u0_q)
{
    const int64_t half = (int64_t)1 << (SN637_FUSED_LOOPSHAPE_A_FRAC_BITS - 1);
    int64_t u0 = u0_q > SN637_FUSED_LOOPSHAPE_OUTPUT_MAX_Q ? SN637_FUSED_LOOPSHAPE_OUTPUT_MAX_Q : u0_q < SN637_FUSED_LOOPSHAPE_OUTPUT_MIN_Q ? SN637_FUSED_LOOPSHAPE_OUTPUT_MIN_Q : u0_q;
    for (int k = 0; k < SN637_FUSED_LOOPSHAPE_N_SECTIONS; k++) st->s[k][0] = st->s[k][1] = 0;
    st->s[SN637_FUSED_LOOPSHAPE_N_SECTIONS - 1][0] = (int32_t)u0;
    st->s[SN637_FUSED_LOOPSHAPE_N_SECTIONS - 1][1] = (int32_t)((-(int64_t)SN637_FUSED_LOOPSHAPE_A_Q[SN637_FUSED_LOOPSHAPE_N_SECTIONS - 1][1] * u0 + half) >> SN637_FUSED_LOOPSHAPE_A_FRAC_BITS);
    st->v = (int32_t)u0;
}

/* One sample: input word e_q (Q2.29) in, output word (Q10.21) out. */
static inline int32_t sn637_fused_loopshape_fixed_step(sn637_fused_loopshape_fixed_state *st, int32_t e_q)
{
    const int64_t one = (int64_t)1 << SN637_FUSED_LOOPSHAPE_A_FRAC_BITS, half = one >> 1;
    int64_t v = e_q > SN637_FUSED_LOOPSHAPE_INPUT_LIMIT_Q ? SN637_FUSED_LOOPSHAPE_INPUT_LIMIT_Q : e_q < -SN637_FUSED_LOOPSHAPE_INPUT_LIMIT_Q ? -SN637_FUSED_LOOPSHAPE_INPUT_LIMIT_Q : e_q;
    for (int k = 0; k < SN637_FUSED_LOOPSHAPE_N_SECTIONS; k++) {
        const int32_t *b = SN637_FUSED_LOOPSHAPE_B_Q[k], *a = SN637_FUSED_LOOPSHAPE_A_Q[k];
        const int shift = SN637_FUSED_LOOPSHAPE_B_SHIFT[k];
        const int last = k == SN637_FUSED_LOOPSHAPE_N_SECTIONS - 1;
        int64_t lo = INT32_MIN, hi = INT32_MAX;
        if (last) {
            lo = (int64_t)st->v - SN637_FUSED_LOOPSHAPE_HEADROOM_DOWN_Q;
            hi = (int64_t)st->v + SN637_FUSED_LOOPSHAPE_HEADROOM_UP_Q;
            if (lo < SN637_FUSED_LOOPSHAPE_OUTPUT_MIN_Q) lo = SN637_FUSED_LOOPSHAPE_OUTPUT_MIN_Q;
            if (hi > SN637_FUSED_LOOPSHAPE_OUTPUT_MAX_Q) hi = SN637_FUSED_LOOPSHAPE_OUTPUT_MAX_Q;
        }
        int64_t y = (sn637_fused_loopshape_align_(b[0] * v, shift) + st->s[k][0] * one + half) >> SN637_FUSED_LOOPSHAPE_A_FRAC_BITS;
        y = y > hi ? hi : y < lo ? lo : y;
        const int64_t s1 = (sn637_fused_loopshape_align_(b[1] * v, shift) - a[0] * y + st->s[k][1] * one + half) >> SN637_FUSED_LOOPSHAPE_A_FRAC_BITS;
        const int64_t s2 = (sn637_fused_loopshape_align_(b[2] * v, shift) - a[1] * y + half) >> SN637_FUSED_LOOPSHAPE_A_FRAC_BITS;
        st->s[k][0] = sn637_fused_loopshape_sat32_(s1);
        st->s[k][1] = sn637_fused_loopshape_sat32_(s2);
        v = y;
    }
    st->v = (int32_t)((int64_t)st->v + (((v - (int64_t)st->v) * SN637_FUSED_LOOPSHAPE_ALPHA_Q
                                         + ((int64_t)1 << (SN637_FUSED_LOOPSHAPE_ALPHA_FRAC_BITS - 1))) >> SN637_FUSED_LOOPSHAPE_ALPHA_FRAC_BITS));
    return (int32_t)v;
}

/* Sensor block: the loop closes on the complementary blend c + lowpass(g - c), crossover 0.893889 Hz (a = exp(-w_c T) = 0.999438510874).
 * Inputs: int32 counts of 1e-12 m (reference r, gauge reading g, charge estimate c).
 * e = r - reading (counts); cascade input word = (e * SN637_FUSED_LOOPSHAPE_ERROR_SCALE_Q + 2^(B-1)) >> B, B = 23,
 * clamped to +/-SN637_FUSED_LOOPSHAPE_INPUT_LIMIT_Q (324991.776 firmware V per m); then sn637_fused_loopshape_fixed_step. */
#define SN637_FUSED_LOOPSHAPE_SENSOR_KIND "fused"
#define SN637_FUSED_LOOPSHAPE_ERROR_SCALE_Q INT64_C(1463632843)
#define SN637_FUSED_LOOPSHAPE_ERROR_SCALE_BITS 23
#define SN637_FUSED_LOOPSHAPE_BLEND_K INT64_C(9420)
#define SN637_FUSED_LOOPSHAPE_BLEND_K_BITS 24
#define SN637_FUSED_LOOPSHAPE_BLEND_FRAC_BITS 12
#define SN637_FUSED_LOOPSHAPE_BLEND_MAX_DIFF INT64_C(67108863)
/* open loop this long after the charge integrator's reset before sn637_fused_loopshape_sensor_reset, s */
#define SN637_FUSED_LOOPSHAPE_STARTUP_WAIT_S 4.7076
/* reference lead 1/K_v, s: velocity feedforward on the trajectory generator's planned slope v (ramps):
   feed r + v * SN637_FUSED_LOOPSHAPE_REF_LEAD_S (a type-1 loop's ramp error v/K_v); not on steps or tones */
#define SN637_FUSED_LOOPSHAPE_REF_LEAD_S 0.00040732160787023325
/* gauge metres: x = x_lin - beta (x_lin - x_c)^2, beta in 1/m, x_c in m (eq. 27's curvature) */
#define SN637_FUSED_LOOPSHAPE_GAUGE_CURVATURE_PER_M -25.303838931807693
#define SN637_FUSED_LOOPSHAPE_GAUGE_CENTER_M 7.5e-06
static inline double sn637_fused_loopshape_gauge_metres(double x_lin_m)
{
    double u = x_lin_m - SN637_FUSED_LOOPSHAPE_GAUGE_CENTER_M;
    return x_lin_m - SN637_FUSED_LOOPSHAPE_GAUGE_CURVATURE_PER_M * u * u;
}

typedef struct { sn637_fused_loopshape_fixed_state c; int64_t y; } sn637_fused_loopshape_sensor_state;

/* At rest at output word u0_q; the blend state starts at the first gauge - charge difference (g0 - c0). */
static inline void sn637_fused_loopshape_sensor_reset(sn637_fused_loopshape_sensor_state *st, int32_t u0_q, int32_t g0, int32_t c0)
{
    sn637_fused_loopshape_fixed_reset(&st->c, u0_q);
    st->y = ((int64_t)g0 - (int64_t)c0) * (INT64_C(1) << 12);
}

/* One sample: counts r, g, c in; output word (Q10.21) out. *fused_out (if not NULL): the reading. */
static inline int32_t sn637_fused_loopshape_sensor_step(sn637_fused_loopshape_sensor_state *st, int32_t r, int32_t g, int32_t c, int64_t *fused_out)
{
    int64_t sn637_fused_loopshape_blend_d = (int64_t)g - (int64_t)c;
    sn637_fused_loopshape_blend_d = sn637_fused_loopshape_blend_d > SN637_FUSED_LOOPSHAPE_BLEND_MAX_DIFF ? SN637_FUSED_LOOPSHAPE_BLEND_MAX_DIFF : sn637_fused_loopshape_blend_d < -SN637_FUSED_LOOPSHAPE_BLEND_MAX_DIFF ? -SN637_FUSED_LOOPSHAPE_BLEND_MAX_DIFF : sn637_fused_loopshape_blend_d;
    st->y += (SN637_FUSED_LOOPSHAPE_BLEND_K * (sn637_fused_loopshape_blend_d * (INT64_C(1) << SN637_FUSED_LOOPSHAPE_BLEND_FRAC_BITS) - st->y)) >> SN637_FUSED_LOOPSHAPE_BLEND_K_BITS;
    int64_t sn637_fused_loopshape_blend_fused = (int64_t)c + ((st->y + (INT64_C(1) << (SN637_FUSED_LOOPSHAPE_BLEND_FRAC_BITS - 1))) >> SN637_FUSED_LOOPSHAPE_BLEND_FRAC_BITS);
    int64_t f = sn637_fused_loopshape_blend_fused;
    if (fused_out) *fused_out = f;
    int64_t e = (((int64_t)r - f) * SN637_FUSED_LOOPSHAPE_ERROR_SCALE_Q + (INT64_C(1) << (SN637_FUSED_LOOPSHAPE_ERROR_SCALE_BITS - 1))) >> SN637_FUSED_LOOPSHAPE_ERROR_SCALE_BITS;
    e = e > SN637_FUSED_LOOPSHAPE_INPUT_LIMIT_Q ? SN637_FUSED_LOOPSHAPE_INPUT_LIMIT_Q : e < -SN637_FUSED_LOOPSHAPE_INPUT_LIMIT_Q ? -SN637_FUSED_LOOPSHAPE_INPUT_LIMIT_Q : e;
    return sn637_fused_loopshape_fixed_step(&st->c, (int32_t)e);
}

#endif /* SN637_FUSED_LOOPSHAPE_H */

/* mimo.h: the mirror's MIMO controller "mimo", exported by workbench.export.mimo. Re-export rather than edit.
 *
 * Per sample: gauge words g[3] (firmware V x 2^MIMO_GAUGE_FRAC_BITS) and reference words r[3] (each
 * axis cascade's input format, axis volts; axis volt = 3.30998e-05 rad tip, 3.82203e-05 rad tilt,
 * 6.61996e-07 m piston) in; stack command words v[3] (V x 2^MIMO_STACK_FRAC_BITS) out:
 *   q[a] = (sum_j OUT_Q[a][j] g[j] + 2^(OUT_SHIFT[a]-1)) >> OUT_SHIFT[a]   (gauges -> axes)
 *   u[a] = AXIS_fixed_step(r[a] - q[a])                                    (the axis cascades)
 *   v[j] = clamp((sum_a (IN_Q[j][a] u[a]) >> IN_SHIFT[a] + 2^(V_SHIFT-1)) >> V_SHIFT)   (axes -> stacks)
 * int64 accumulators, arithmetic right shifts. Each axis cascade clamps its output to its axis range and to
 * its current-limit window (a model of its output; the box maps inside every stack's current headroom), and
 * the clamped value drives its integrator (anti-windup).
 */
#ifndef MIMO_H
#define MIMO_H

#include <stdint.h>
#include "mimo_tip.h"
#include "mimo_tilt.h"
#include "mimo_piston.h"

#define MIMO_GAUGE_FRAC_BITS 29
#define MIMO_STACK_FRAC_BITS 24
#define MIMO_V_SHIFT 29

static const int64_t MIMO_OUT_Q[3][3] = {
    {INT64_C(945231916), INT64_C(-488896774), INT64_C(-498573408)},
    {INT64_C(0), INT64_C(733345169), INT64_C(-747860120)},
    {INT64_C(945231926), INT64_C(977793558), INT64_C(997146827)}
};
static const int MIMO_OUT_SHIFT[3] = {31, 30, 31};
static const int64_t MIMO_IN_Q[3][3] = {
    {INT64_C(536870912), INT64_C(0), INT64_C(1073741812)},
    {INT64_C(-268435455), INT64_C(536870904), INT64_C(1073741808)},
    {INT64_C(-268435459), INT64_C(-536870912), INT64_C(1073741824)}
};
static const int MIMO_IN_SHIFT[3] = {0, 0, 0};
static const int64_t MIMO_STACK_LIMITS_Q[3][2] = {
    {INT64_C(-335544320), INT64_C(2013265920)},
    {INT64_C(-335544320), INT64_C(2013265920)},
    {INT64_C(-335544320), INT64_C(2013265920)}
};

typedef struct { mimo_tip_fixed_state a0; mimo_tilt_fixed_state a1; mimo_piston_fixed_state a2; } mimo_fixed_state;

/* At rest with the axis cascades' outputs at u0_q (each in its output format) and zero error. */
static inline void mimo_fixed_reset(mimo_fixed_state *st, const int32_t u0_q[3])
{
    mimo_tip_fixed_reset(&st->a0, u0_q[0]);
    mimo_tilt_fixed_reset(&st->a1, u0_q[1]);
    mimo_piston_fixed_reset(&st->a2, u0_q[2]);
}

static inline int32_t mimo_sat32_(int64_t v)
{
    return v > INT32_MAX ? INT32_MAX : v < INT32_MIN ? INT32_MIN : (int32_t)v;
}

static inline void mimo_fixed_step(mimo_fixed_state *st, const int32_t g_q[3], const int32_t r_q[3],
                                     int32_t v_q[3])
{
    int64_t u[3];
    int32_t e[3];
    for (int a = 0; a < 3; a++) {
        int64_t acc = 0;
        for (int j = 0; j < 3; j++) acc += MIMO_OUT_Q[a][j] * (int64_t)g_q[j];
        const int64_t q = (acc + ((int64_t)1 << (MIMO_OUT_SHIFT[a] - 1))) >> MIMO_OUT_SHIFT[a];
        e[a] = mimo_sat32_((int64_t)r_q[a] - q);
    }
    u[0] = mimo_tip_fixed_step(&st->a0, e[0]);
    u[1] = mimo_tilt_fixed_step(&st->a1, e[1]);
    u[2] = mimo_piston_fixed_step(&st->a2, e[2]);
    for (int j = 0; j < 3; j++) {
        int64_t acc = 0;
        for (int a = 0; a < 3; a++) acc += (MIMO_IN_Q[j][a] * u[a]) >> MIMO_IN_SHIFT[a];
        int64_t v = ((acc + ((int64_t)1 << (MIMO_V_SHIFT - 1))) >> MIMO_V_SHIFT);
        v = v < MIMO_STACK_LIMITS_Q[j][0] ? MIMO_STACK_LIMITS_Q[j][0] : v > MIMO_STACK_LIMITS_Q[j][1] ? MIMO_STACK_LIMITS_Q[j][1] : v;
        v_q[j] = (int32_t)v;
    }
}

#endif /* MIMO_H */

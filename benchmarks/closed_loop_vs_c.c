/* closed_loop_vs_c.c: the closed loop of workbench.verify.closed_loop in plain C, for the speed reference.
 *
 * The same computation per servo period as the compiled loop (_loop, fixed-point form):
 *   1. the PZT: n_sub steps of workbench.plant.kernels.pzt_step (voltage range, R and the current limits,
 *      the PI operators G and Q, the creep branches, the modes; with R out the quasi-static step, still
 *      current-limited), command held;
 *   2. the gauge chain, equivalent discrete model: the bridge (eq. 26, imbalance included) a quarter and
 *      three quarters into the period, x amp, clipped to the ADC range, 0.5 demod (vp - vn) + noise (one
 *      standard normal a period from the run's numpy bit generator, times sigma), trim, DAC quantization;
 *   3. the controller: the exported header's CTRL_fixed_step (int32 words, int64 accumulators, the output
 *      range and the current-limit window around the stack-voltage model), input word round-half-even;
 *   4. its output applied the next period.
 * Streaming statistics and the decimated trace as _loop keeps them.
 *
 * The model and the plant state are the packed vectors of workbench.plant.kernels (m, st): their layout is
 * read from the head of m, so this file follows pack_model. Built by benchmarks/closed_loop_vs_c.py with
 *   gcc -O2 -march=native -ffp-contract=off -shared -fPIC -I<numpy include> -include CTRL.h -DCTRL=name
 *       closed_loop_vs_c.c <numpy>/random/lib/libnpyrandom.a -lm
 * (-ffp-contract=off: no fused multiply-add, so the doubles round as numba's do and the words agree).
 */
#include <math.h>
#include <stdint.h>
#include <string.h>
#include <numpy/random/bitgen.h>

/* numpy's own Gaussian draw (ziggurat on the bit generator), from numpy/random/lib/libnpyrandom.a: the draw
 * Generator.standard_normal makes and numba's Generator support reproduces, so the loops draw the same noise */
double random_standard_normal(bitgen_t *bitgen_state);

#ifndef CTRL
#error "define CTRL (the controller name) and -include its exported header"
#endif
#define PASTE2(a, b) a##b
#define PASTE(a, b) PASTE2(a, b)
#define STATE PASTE(CTRL, _fixed_state)
#define STEP PASTE(CTRL, _fixed_step)
#define N_SEC ((int)(sizeof(((STATE *)0)->s) / sizeof(((STATE *)0)->s[0])))

/* m head: workbench.plant.kernels */
enum { R, I_SRC, I_SNK, V_MIN, V_MAX, T_EM, K_P, C_PP, DT, QUASI_STATIC,
       INV_R, INV_I_SRC, INV_I_SNK, INV_K_P, INV_C_PP, INV_DT,
       N_G, O_RG, O_WG, N_Q, O_RQ, O_WQ, N_C, O_CC, O_CDEC, N_M, O_AD, O_BD, O_CD, O_DD,
       OS_ZG, OS_ZQ, OS_QC, OS_XM, O_CB };
enum { S_QH, S_U, S_QC, S_GUP, S_GDN, S_KUP, S_KDN, S_FUP, S_FDN, S_PL, S_PU, S_Y1, S_FDT, S_FR };

static inline double clampd(double v, double lo, double hi) { return v < lo ? lo : v > hi ? hi : v; }

/* the fixed products of plant_params (workbench.plant.kernels), formed once per call */
typedef struct { double r_isrc, r_isnk, k_f, k_x, b_tot, d_eff, kx_c, kx_f, qs_k, k_h_min, c_q_max; } plant_consts;

static plant_consts plant_params(const double *m)
{
    plant_consts p;
    const double r = m[R], t_em = m[T_EM], inv_kp = m[INV_K_P], inv_cpp = m[INV_C_PP];
    const int n_c = (int)m[N_C], o_cb = (int)m[O_CB], n = (int)m[N_M], o_b = (int)m[O_BD], o_cd = (int)m[O_CD];
    p.b_tot = 0.0;
    for (int j = 0; j < n_c; j++) p.b_tot += m[o_cb + j];
    p.qs_k = inv_cpp / (1.0 + p.b_tot * inv_cpp);
    {   /* G's smallest slope (least prefix sum of its weights) less 1 / C_pp: 1 / C_h's largest capacitance */
        const int n_g = (int)m[N_G], o_wg = (int)m[O_WG];
        double g_acc = 0.0, g_min = INFINITY;
        for (int i = 0; i < n_g; i++) { g_acc += m[o_wg + i]; g_min = fmin(g_min, g_acc); }
        p.k_h_min = g_min - inv_cpp;
        p.c_q_max = 1.0 / g_min;                 /* Q's largest slope: the quasi-static step's bound */
    }
    p.d_eff = n > 0 ? m[(int)m[O_DD]] : 1.0;
    for (int a = 0; a < n; a++) p.d_eff += m[o_cd + a] * m[o_b + n + a];
    p.r_isrc = r * m[I_SRC];
    p.r_isnk = r * m[I_SNK];
    p.k_f = t_em * inv_kp;
    p.k_x = t_em * inv_cpp * inv_kp;
    p.kx_c = p.d_eff * p.k_x;
    p.kx_f = p.d_eff * inv_kp;
    return p;
}

/* rc_factor and rc_charge of workbench.plant.kernels */
static inline double rc_factor(double cap, double dt, double r) { return cap * (1.0 - exp(-dt / (r * cap))); }

static inline double rc_charge(double du, double cap, double f_full, double dt, double r, double i_lim,
                               double inv_i, double r_ilim)
{
    double gap = fabs(du);
    if (gap <= r_ilim) return du * f_full;
    double d = du > 0 ? 1.0 : -1.0;
    double t_sat = (gap - r_ilim) * inv_i * cap;
    if (t_sat >= dt) return d * i_lim * dt;
    return d * i_lim * t_sat + d * r_ilim * cap * (1.0 - exp(-(dt - t_sat) / (r * cap)));
}

/* _pi_update / _pi_output_at of workbench.plant.kernels: a packed PI operator to input v (or its output there) */
static double pi_update(const double *m, double *st, int o_r, int o_w, int o_z, int n, double v, int write)
{
    double y = 0.0;
    for (int i = 0; i < n; i++) {
        double z = clampd(st[o_z + i], v - m[o_r + i], v + m[o_r + i]);
        if (write) st[o_z + i] = z;
        y += m[o_w + i] * z;
    }
    return y;
}

/* _q_states_from_g of workbench.plant.kernels: Q's play states from G's (a state from the dynamic form) */
static void q_states_from_g(const double *m, double *st, double u)
{
    const int n = (int)m[N_G], o_wg = (int)m[O_WG], o_zg = (int)m[OS_ZG], o_zq = (int)m[OS_ZQ];
    double s = 0.0, w_acc = 0.0;
    for (int i = 0; i < n; i++) {
        double zi = st[o_zg + i], wi = m[o_wg + i];
        st[o_zq + i] = (u - s) + w_acc * zi;
        s += wi * zi;
        w_acc += wi;
    }
}

/* _pi_update_segment of workbench.plant.kernels for the quasi-static step: G's plays to qh_new (the first every
 * step, the others when qh_new leaves their band), the segment entries current. The dynamic step below keeps its
 * own copy written out in place, so the code timed for a plant with R in is as it was. */
static double g_update_segment(const double *m, double *st, double qh_new, double dt, double r)
{
    const int n = (int)m[N_G], o_r = (int)m[O_RG], o_w = (int)m[O_WG], o_z = (int)m[OS_ZG];
    const double r0 = m[o_r], w0 = m[o_w], lo0 = qh_new - r0, hi0 = qh_new + r0;
    double z0 = st[o_z];
    z0 = z0 > lo0 ? z0 : lo0;
    z0 = z0 < hi0 ? z0 : hi0;
    st[o_z] = z0;
    double up = z0 <= lo0 ? w0 : 0.0, dn = z0 >= hi0 ? w0 : 0.0, y;
    if (st[S_PL] < qh_new && qh_new < st[S_PU]) {
        y = w0 * z0 + st[S_Y1];
    } else {
        double pl = -INFINITY, pu = INFINITY, r_max = r0, y1 = 0.0;
        y = w0 * z0;
        for (int i = 1; i < n; i++) {
            double ri = m[o_r + i], wi = m[o_w + i], lo = qh_new - ri, hi = qh_new + ri;
            double z = st[o_z + i];
            z = z > lo ? z : lo;
            z = z < hi ? z : hi;
            up += z <= lo ? wi : 0.0;
            dn += z >= hi ? wi : 0.0;
            st[o_z + i] = z;
            y += wi * z;
            y1 += wi * z;
            pl = z - ri > pl ? z - ri : pl;
            pu = z + ri < pu ? z + ri : pu;
            r_max = ri > r_max ? ri : r_max;
        }
        double margin = 1e-12 * (fabs(qh_new) + r_max);
        st[S_PL] = pl + margin;
        st[S_PU] = pu - margin;
        st[S_Y1] = y1;
    }
    if (up != st[S_KUP]) { st[S_KUP] = up; double cap = 1.0 / up; st[S_GUP] = cap; st[S_FUP] = rc_factor(cap, dt, r); }
    if (dn != st[S_KDN]) { st[S_KDN] = dn; double cap = 1.0 / dn; st[S_GDN] = cap; st[S_FDN] = rc_factor(cap, dt, r); }
    return y;
}

/* One plant sub-step: pzt_advance of workbench.plant.kernels; returns x, writes the current to *i_a. */
static inline double pzt_step(const double *m, double *st, const plant_consts *p, double v_cmd, double f_e,
                              double *i_a)
{
    const double dt = m[DT], r = m[R], inv_cpp = m[INV_C_PP];
    double v = clampd(v_cmd, m[V_MIN], m[V_MAX]);
    double qh = st[S_QH], u = st[S_U], qh_new, u_new;
    double qc_old = st[S_QC];
    double q_old = qh + qc_old;
    double f_term = f_e * p->k_f;
    /* the creep branches first at a held terminal charge, semi-implicit on C_h's local slope: as pzt_advance */
    double v_h_old = u - qh * inv_cpp;
    const int nc = (int)m[N_C], o_cb = (int)m[O_CB], o_dec = (int)m[O_CDEC], o_qc = (int)m[OS_QC];
    double th_c = 0.0, qc_new = 0.0;
    if (nc > 0) {
        double s_dec = 0.0, v_h_s;
        for (int j = 0; j < nc; j++) s_dec += m[o_dec + j] * st[o_qc + j];
        double e_c = (s_dec + p->b_tot * v_h_old) - qc_old;
        if (m[QUASI_STATIC] > 0.5) {
            v_h_s = v_h_old - e_c * p->qs_k;
        } else {
            double h_dn = 1.0 - st[S_GDN] * inv_cpp, h_up = 1.0 - st[S_GUP] * inv_cpp;
            double a_dn = 1.0 / (st[S_GDN] + p->b_tot * h_dn), a_up = 1.0 / (st[S_GUP] + p->b_tot * h_up);
            int falling = e_c > 0;
            double t_c = e_c * (falling ? a_dn : a_up);
            v_h_s = v_h_old - t_c * (falling ? h_dn : h_up);
            th_c = t_c * (falling ? st[S_GDN] : st[S_GUP]) * p->k_h_min;   /* V_t's drop, never overstated */
        }
        for (int j = 0; j < nc; j++) st[o_qc + j] = m[o_dec + j] * st[o_qc + j] + m[o_cb + j] * v_h_s;
        qc_new = s_dec + p->b_tot * v_h_s;
    }
    if (m[QUASI_STATIC] > 0.5) {
        /* R = 0: to V_t = v within the current limit over the step, else the limit's charge (pzt_advance) */
        const int n_q = (int)m[N_Q], o_rq = (int)m[O_RQ], o_wq = (int)m[O_WQ], o_zq = (int)m[OS_ZQ];
        if (st[S_FR] != r || st[S_FDT] != dt) {              /* _check_segment, then Q's plays from G's */
            st[S_FUP] = rc_factor(st[S_GUP], dt, r);
            st[S_FDN] = rc_factor(st[S_GDN], dt, r);
            st[S_FDT] = dt;
            st[S_FR] = r;
            st[S_PL] = st[S_PU] = NAN;
            q_states_from_g(m, st, u);
        }
        double u_t = v - (qc_new - f_term) * inv_cpp;
        double dqc = qc_new - qc_old, q_src = m[I_SRC] * dt, q_snk = m[I_SNK] * dt;
        double span = fabs(u_t - u) * p->c_q_max, dq = 0.0;
        int limited = 0;
        if (dqc + span > q_src || dqc - span < -q_snk) {
            dq = (pi_update(m, st, o_rq, o_wq, o_zq, n_q, u_t, 0) - qh) + dqc;
            limited = dq > q_src || dq < -q_snk;
        }
        if (limited) {
            qh_new = qh + ((dq > 0 ? q_src : -q_snk) - dqc);
            u_new = g_update_segment(m, st, qh_new, dt, r);
            pi_update(m, st, o_rq, o_wq, o_zq, n_q, u_new, 1);
        } else {
            qh_new = pi_update(m, st, o_rq, o_wq, o_zq, n_q, u_t, 1);
            if (qh_new != qh) g_update_segment(m, st, qh_new, dt, r);
            u_new = u_t;
        }
    } else {
        double du = (v - (qc_old - f_term) * inv_cpp - u) + th_c;   /* the gap after the branches' step */
        double dq = 0.0;
        if (du != 0.0) {
            if (st[S_FDT] != dt || st[S_FR] != r) {          /* _check_segment */
                st[S_FUP] = rc_factor(st[S_GUP], dt, r);
                st[S_FDN] = rc_factor(st[S_GDN], dt, r);
                st[S_FDT] = dt;
                st[S_FR] = r;
                st[S_PL] = st[S_PU] = NAN;
            }
            int rising = du > 0;
            dq = rc_charge(du, rising ? st[S_GUP] : st[S_GDN], rising ? st[S_FUP] : st[S_FDN], dt, r,
                           rising ? m[I_SRC] : m[I_SNK], rising ? m[INV_I_SRC] : m[INV_I_SNK],
                           rising ? p->r_isrc : p->r_isnk);
        }
        qh_new = qh + (dq - (qc_new - qc_old));
        if (qh_new != qh) {
            /* _pi_update_segment: the first play every step, the others when qh_new leaves their band */
            const int n = (int)m[N_G], o_r = (int)m[O_RG], o_w = (int)m[O_WG], o_z = (int)m[OS_ZG];
            const double r0 = m[o_r], w0 = m[o_w], lo0 = qh_new - r0, hi0 = qh_new + r0;
            double z0 = st[o_z];
            z0 = z0 > lo0 ? z0 : lo0;
            z0 = z0 < hi0 ? z0 : hi0;
            st[o_z] = z0;
            double up = z0 <= lo0 ? w0 : 0.0, dn = z0 >= hi0 ? w0 : 0.0, y;
            if (st[S_PL] < qh_new && qh_new < st[S_PU]) {
                y = w0 * z0 + st[S_Y1];
            } else {
                double pl = -INFINITY, pu = INFINITY, r_max = r0, y1 = 0.0;
                y = w0 * z0;
                for (int i = 1; i < n; i++) {
                    double ri = m[o_r + i], wi = m[o_w + i], lo = qh_new - ri, hi = qh_new + ri;
                    double z = st[o_z + i];
                    z = z > lo ? z : lo;          /* min(max(z, lo), hi) */
                    z = z < hi ? z : hi;
                    up += z <= lo ? wi : 0.0;
                    dn += z >= hi ? wi : 0.0;
                    st[o_z + i] = z;
                    y += wi * z;
                    y1 += wi * z;
                    pl = z - ri > pl ? z - ri : pl;
                    pu = z + ri < pu ? z + ri : pu;
                    r_max = ri > r_max ? ri : r_max;
                }
                double margin = 1e-12 * (fabs(qh_new) + r_max);
                st[S_PL] = pl + margin;
                st[S_PU] = pu - margin;
                st[S_Y1] = y1;
            }
            if (up != st[S_KUP]) {
                st[S_KUP] = up;
                double cap = 1.0 / up;
                st[S_GUP] = cap;
                st[S_FUP] = rc_factor(cap, dt, r);
            }
            if (dn != st[S_KDN]) {
                st[S_KDN] = dn;
                double cap = 1.0 / dn;
                st[S_GDN] = cap;
                st[S_FDN] = rc_factor(cap, dt, r);
            }
            u_new = y;
        } else {
            u_new = u;
        }
    }
    double q = qh_new + qc_new;
    st[S_QH] = qh_new;
    st[S_U] = u_new;
    st[S_QC] = qc_new;
    double qf = q - f_term;
    double x_qs = qf * p->k_x + f_e * m[INV_K_P];
    const int nm = (int)m[N_M];
    double x;
    if (nm > 0) {
        const int o_x = (int)m[OS_XM], o_a = (int)m[O_AD], o_b = (int)m[O_BD], o_cd = (int)m[O_CD];
        double x_before = st[o_x + 2 * nm], x_part = 0.0;
        for (int a = 0; a < nm; a++) {
            double acc = m[o_b + a] * x_before;
            for (int b = 0; b < nm; b++) acc += m[o_a + a * nm + b] * st[o_x + b];
            st[o_x + nm + a] = acc;
            x_part += m[o_cd + a] * acc;
        }
        for (int a = 0; a < nm; a++) st[o_x + a] = st[o_x + nm + a] + m[o_b + nm + a] * x_qs;
        /* pzt_advance: x_qs's chain expanded, a sum over qh_new and the held terms */
        x = (p->kx_c * qh_new + (p->kx_c * (qc_new - f_term) + p->kx_f * f_e)) + x_part;
        st[o_x + 2 * nm] = x_qs;
    } else {
        x = x_qs;
    }
    *i_a = (q - q_old) * m[INV_DT];
    return x;
}

/* n periods. rng, sigma: the gauge noise's bit generator and its standard deviation (V; 0: no draw);
 * gp: the gauge parameters as ClosedLoop._gp; r0: the four arm rest resistances;
 * cs (n_sections x 2) and vm: the cascade's words (int64, in and out); lim: [lo, hi] output words;
 * in_scale, out_scale, in_lim: the input/output word scales and the input clamp; io: [pending output V,
 * last x, decimation counter, trace row]; rec (rows x 6) and stats (5) as _loop. */
void cl_run(const double *m, double *st, long n_sub, long n, const double *ref, const double *force,
            bitgen_t *rng, double sigma, const double *gp, const double *r0, int64_t *cs, int64_t *vm,
            const int64_t *lim, double in_scale, double out_scale, int64_t in_lim, double *io, long decimate,
            double *rec, long rec_rows, double *stats)
{
    const double L = gp[0], W = gp[1], kgf = gp[2], vmod = gp[3], amp = gp[4], adc_fs = gp[5];
    const double demod = gp[6], trim_s = gp[7], trim_b = gp[8], dac_fs = gp[9];
    const double dac_lsb = 2.0 * dac_fs / ldexp(1.0, (int)gp[10]), inv_lsb = 1.0 / dac_lsb;
    const double dac_top = dac_fs - dac_lsb;
    /* the bridge's halves as (n0 + n1 x) / (d0 + d1 x), as _loop forms them */
    const double kw = kgf * (W / L), r0a = r0[0], r0b = r0[1], r0c = r0[2], r0d = r0[3];
    const double n10 = r0d - r0a, n11 = (r0d * kgf + r0a * kw) / L;
    const double d10 = r0d + r0a, d11 = (r0d * kgf - r0a * kw) / L;
    const double n20 = r0b - r0c, n21 = -(r0b * kw + r0c * kgf) / L;
    const double d20 = r0b + r0c, d21 = (r0c * kgf - r0b * kw) / L;
    const double k_br = amp * vmod, k_dem = trim_s * (0.5 * demod);
    const plant_consts pc = plant_params(m);
    const double i_src = m[I_SRC], i_snk = m[I_SNK];
    const int64_t lo_w = lim[0], hi_w = lim[1], h_up = lim[3], h_dn = lim[4];
    STATE c;
    for (int k = 0; k < N_SEC; k++) {
        c.s[k][0] = (int32_t)cs[2 * k];
        c.s[k][1] = (int32_t)cs[2 * k + 1];
    }
    c.v = (int32_t)vm[0];
    /* the sub-steps holding a quarter and three quarters of the period, and their interpolation weights */
    long jq = -1, jt = -1;
    double fqn = 0.0, ftn = 0.0;
    for (long j = 0; j < n_sub; j++) {
        double t_end = (double)(j + 1) / n_sub, t_beg = (double)j / n_sub;
        if (t_beg < 0.25 && 0.25 <= t_end) { jq = j; fqn = (0.25 - t_beg) * n_sub; }
        if (t_beg < 0.75 && 0.75 <= t_end) { jt = j; ftn = (0.75 - t_beg) * n_sub; }
    }
    /* in_scale is a power of two: ref*s - code*(lsb*s) rounds as (ref - code*lsb)*s, bit for bit */
    const double lsb_in = dac_lsb * in_scale;
    double pending = io[0], x_prev = io[1];
    long count = (long)io[2], row = (long)io[3];
    for (long k = 0; k < n; k++) {
        double u = pending, fk = force[k], x_start = x_prev, xq = 0.0, xt = 0.0, xsum = 0.0, i_peak = 0.0;
        double xprev_sub = x_prev;
        for (long j = 0; j < n_sub; j++) {
            double ij, xj = pzt_step(m, st, &pc, u, fk, &ij);
            if (j == jq) {
                double xb = j == 0 ? x_start : xprev_sub;
                xq = xb + (xj - xb) * fqn;
            }
            if (j == jt) {
                double xb = j == 0 ? x_start : xprev_sub;
                xt = xb + (xj - xb) * ftn;
            }
            xprev_sub = xj;
            xsum += xj;
            if (fabs(ij) > fabs(i_peak)) i_peak = ij;
            if (ij > stats[0]) stats[0] = ij;
            if (ij < stats[1]) stats[1] = ij;
            if (ij >= i_src * (1 - 1e-9) || -ij >= i_snk * (1 - 1e-9)) stats[2] += 1;
        }
        x_prev = xprev_sub;
        double vp = clampd(((n10 + n11 * xq) / (d10 + d11 * xq) - (n20 + n21 * xq) / (d20 + d21 * xq)) * k_br,
                           -adc_fs, adc_fs);
        double vn = clampd(((n10 + n11 * xt) / (d10 + d11 * xt) - (n20 + n21 * xt) / (d20 + d21 * xt)) * -k_br,
                           -adc_fs, adc_fs);
        double w = sigma > 0.0 ? random_standard_normal(rng) * sigma : 0.0;
        double reading = clampd(k_dem * (vp - vn) + (trim_s * w + trim_b), -dac_fs, dac_top);
        double code = floor(reading * inv_lsb + 0.5);
        reading = code * dac_lsb;
        double e = ref[k] - reading;
        double ew = rint(ref[k] * in_scale - code * lsb_in);  /* round half even, as np.rint */
        int64_t v = ew > (double)in_lim ? in_lim : ew < -(double)in_lim ? -in_lim : (int64_t)ew;
        int64_t wlo = (int64_t)c.v - h_dn, whi = (int64_t)c.v + h_up;
        int64_t u_w = STEP(&c, (int32_t)v);
        if ((u_w == wlo && wlo > lo_w) || (u_w == whi && whi < hi_w)) stats[3] += 1;
        if (u_w == lo_w || u_w == hi_w) stats[4] += 1;
        pending = (double)u_w * out_scale;
        if (++count == decimate) {
            count = 0;
            if (row < rec_rows) {
                double *r = rec + 6 * row++;
                r[0] = xsum / n_sub; r[1] = reading; r[2] = u; r[3] = e; r[4] = fk; r[5] = i_peak;
            }
        }
    }
    for (int k = 0; k < N_SEC; k++) {
        cs[2 * k] = c.s[k][0];
        cs[2 * k + 1] = c.s[k][1];
    }
    vm[0] = c.v;
    io[0] = pending; io[1] = x_prev; io[2] = (double)count; io[3] = (double)row;
}

/* The pieces of cl_run alone, for benchmarks/closed_loop_breakdown.py (not used by the loop above): the gauge chain
 * (n_sub 1: the points 1/4 and 3/4 between x[k-1] and x[k]; no noise) writing each period's DAC code, and the
 * controller (error word, STEP) writing each output in V. CHAINED: each input waits on the last output through
 * + y * zero (zero 0.0 at run time); the plain form reads the record only. */
#define GAUGE_PIECE(NAME, CHAIN)                                                                                    \
    double NAME(const double *x, long n, const double *gp, const double *r0, double *out, double zero)          \
    {                                                                                                               \
        const double L = gp[0], W = gp[1], kgf = gp[2], vmod = gp[3], amp = gp[4], adc_fs = gp[5];               \
        const double demod = gp[6], trim_s = gp[7], trim_b = gp[8], dac_fs = gp[9];                              \
        const double dac_lsb = 2.0 * dac_fs / ldexp(1.0, (int)gp[10]), inv_lsb = 1.0 / dac_lsb;                  \
        const double dac_top = dac_fs - dac_lsb;                                                                  \
        const double kw = kgf * (W / L), r0a = r0[0], r0b = r0[1], r0c = r0[2], r0d = r0[3];                     \
        const double n10 = r0d - r0a, n11 = (r0d * kgf + r0a * kw) / L;                                           \
        const double d10 = r0d + r0a, d11 = (r0d * kgf - r0a * kw) / L;                                           \
        const double n20 = r0b - r0c, n21 = -(r0b * kw + r0c * kgf) / L;                                          \
        const double d20 = r0b + r0c, d21 = (r0c * kgf - r0b * kw) / L;                                           \
        const double k_br = amp * vmod, k_dem = trim_s * (0.5 * demod);                                          \
        double xb = x[0], code = 0.0, acc = 0.0;                                                                  \
        for (long k = 1; k < n; k++) {                                                                            \
            double xj = CHAIN ? x[k] + code * zero : x[k];                                                        \
            double xq = xb + (xj - xb) * 0.25, xt = xb + (xj - xb) * 0.75;                                        \
            xb = xj;                                                                                              \
            double vp = clampd(((n10 + n11 * xq) / (d10 + d11 * xq) - (n20 + n21 * xq) / (d20 + d21 * xq)) * k_br, \
                               -adc_fs, adc_fs);                                                                  \
            double vn = clampd(((n10 + n11 * xt) / (d10 + d11 * xt) - (n20 + n21 * xt) / (d20 + d21 * xt)) * -k_br,\
                               -adc_fs, adc_fs);                                                                  \
            double reading = clampd(k_dem * (vp - vn) + trim_b, -dac_fs, dac_top);                                \
            code = floor(reading * inv_lsb + 0.5);                                                                \
            out[k] = code;                                                                                        \
            acc += code;                                                                                          \
        }                                                                                                         \
        return acc;                                                                                               \
    }
GAUGE_PIECE(gauge_free, 0)
GAUGE_PIECE(gauge_chained, 1)

#define CTRL_PIECE(NAME, CHAIN)                                                                                     \
    double NAME(const double *code, long n, double ref, double lsb_in, double in_scale, int64_t in_lim,         \
                int64_t *cs, int64_t *vm, double out_scale, double *out, double zero)                             \
    {                                                                                                               \
        STATE c;                                                                                                  \
        for (int k = 0; k < N_SEC; k++) {                                                                         \
            c.s[k][0] = (int32_t)cs[2 * k];                                                                       \
            c.s[k][1] = (int32_t)cs[2 * k + 1];                                                                   \
        }                                                                                                         \
        c.v = (int32_t)vm[0];                                                                                     \
        double u = 0.0, acc = 0.0;                                                                                \
        for (long k = 0; k < n; k++) {                                                                            \
            double ck = CHAIN ? code[k] + u * zero : code[k];                                                     \
            double ew = rint(ref * in_scale - ck * lsb_in);                                                       \
            int64_t v = ew > (double)in_lim ? in_lim : ew < -(double)in_lim ? -in_lim : (int64_t)ew;              \
            u = (double)STEP(&c, (int32_t)v) * out_scale;                                                         \
            out[k] = u;                                                                                           \
            acc += u;                                                                                             \
        }                                                                                                         \
        for (int k = 0; k < N_SEC; k++) {                                                                         \
            cs[2 * k] = c.s[k][0];                                                                                \
            cs[2 * k + 1] = c.s[k][1];                                                                            \
        }                                                                                                         \
        vm[0] = c.v;                                                                                              \
        return acc;                                                                                               \
    }
CTRL_PIECE(ctrl_free, 0)
CTRL_PIECE(ctrl_chained, 1)

/* The plant step alone over the commands u (V, no force): x of the last step plus the summed currents. */
#define PLANT_PIECE(NAME, CHAIN)                                                                                    \
    double NAME(const double *m, double *st, const double *u, long n, double zero)                               \
    {                                                                                                               \
        const plant_consts pc = plant_params(m);                                                                  \
        double x = 0.0, acc = 0.0, i_a;                                                                           \
        for (long k = 0; k < n; k++) {                                                                            \
            x = pzt_step(m, st, &pc, CHAIN ? u[k] + x * zero : u[k], 0.0, &i_a);                                  \
            acc += i_a;                                                                                           \
        }                                                                                                         \
        return x + acc;                                                                                           \
    }
PLANT_PIECE(plant_free, 0)
PLANT_PIECE(plant_chained, 1)

/* Per-body adaptive reference for benchmarks/bench_adaptive.py: Dormand–Prince 5(4) and
 * Tsitouras 5(4), written by hand in C, float64, OpenMP over bodies, each body its own steps.
 *
 * The step rule is Diffrax's PIDController with its default coefficients (pcoeff = dcoeff = 0,
 * icoeff = 1, safety 0.9, factormin 0.2, factormax 10, error order 5 for both tableaux), and
 * the intervals as rigidjax's `solve_saved` runs them:
 *
 *   error     E = sqrt(mean_j (err_j / (atol + rtol max(|y0_j|, |y1_j|)))²)   (RMS over the 7
 *             components; y1 after the quaternion's renormalisation, as rigidjax's StepEndMap)
 *   accept    E < 1
 *   next step h' = h clip(0.9 E^(-1/5), 1, 10) accepted, h clip(.., 0.2, 0.9) rejected
 *   end       every output time ends a step: a proposed step end past the 100th float below
 *             the interval's end t1 becomes t1 (accepted) or the midpoint to t1 (rejected),
 *             as Diffrax's _clip_to_end
 *   first h   Hairer's heuristic as Diffrax's _select_initial_step (d0, d1, the explicit Euler
 *             probe, d2, (0.01 / max(d1, d2))^(1/5), at most 100 h0), at ts[0]; each later
 *             interval starts at the previous one's mean accepted step (width / accepted)
 *   state     y = (Ω, q), the quaternion renormalised after every step
 *
 * All stages are evaluated as the tableaux define them (7 for both, the 7th at the new state,
 * needed by the error estimate). `fsal` = 1 reuses the 7th stage as the next step's first (a
 * hand-written solver's first-same-as-last: 6 evaluations per step; the 7th is taken at the
 * state before its renormalisation, so the numbers differ from rigidjax's at rounding-to-
 * tolerance level); `fsal` = 0 evaluates the first stage at the renormalised state (7 per
 * accepted step, 6 per rejected one): the same steps and numbers as rigidjax's ExplicitRK with
 * its StepEndMap (Diffrax evaluates it again after a rejection too; the value is the same).
 *
 * Models (p: the body's parameters, P per body):
 *   0 free body        p = c (3)                    Ω̇ = c-terms (models_rhs.h's rhs_free_body)
 *   1 attitude torque  p = (c, J, I0, s) (10)       K = s c × (I0 c), c = Pᵀ e_Z with
 *                      P = E + 2(q0 [λ]× + [λ]×²)/|q|² (rigidjax.quat.to_matrix of any q: the
 *                      gravity-gradient torque of reference/models.c, also off the unit sphere
 *                      as rigidjax's field sees the stage states)
 * with c = ((I2 − I3)/I1, (I3 − I1)/I2, (I1 − I2)/I3), J = 1/I.
 *
 * long adaptive_solve(int model, int method, int fsal, long B, long T, const double *ts,
 *                     const double *y0, const double *par, double rtol, double atol,
 *                     long max_steps, double *ys, long *counts)
 *   method 0 Dopri5, 1 Tsit5; y0 (B, 7), par (B, P), ys (B, T, 7) (row-major), counts (B, 2):
 *   accepted and rejected steps over all intervals. max_steps bounds the steps (accepted and
 *   rejected) of each interval; a body that reaches it gets NaN from there on. Returns the
 *   number of such bodies. */
#include <float.h>
#include <math.h>

#include "models_rhs.h"

#define NS 7 /* stages */
#define NY 7 /* state components */

typedef struct {
    double c[NS], a[NS][NS], b[NS], e[NS];
} Tableau;

/* Diffrax's tableaux (diffrax.Dopri5.tableau, diffrax.Tsit5.tableau: c, a_lower, b_sol,
 * b_error), to the last digit of their float64 values. */
static const Tableau DOPRI5 = {
    .c = {0.0, 0.2, 0.3, 0.8, 0.8888888888888888, 1.0, 1.0},
    .a = {{0},
          {0.2},
          {0.075, 0.225},
          {0.9777777777777777, -3.7333333333333334, 3.5555555555555554},
          {2.9525986892242035, -11.595793324188385, 9.822892851699436, -0.2908093278463649},
          {2.8462752525252526, -10.757575757575758, 8.906422717743473, 0.2784090909090909,
           -0.2735313036020583},
          {0.09114583333333333, 0.0, 0.44923629829290207, 0.6510416666666666,
           -0.322376179245283, 0.13095238095238096}},
    .b = {0.09114583333333333, 0.0, 0.44923629829290207, 0.6510416666666666,
          -0.322376179245283, 0.13095238095238096, 0.0},
    .e = {0.0008217592592592582, 0.0, -0.002835180193670739, 0.024652777777777746,
          -0.03390919811320753, 0.02793650793650794, -0.016666666666666666},
};

static const Tableau TSIT5 = {
    .c = {0.0, 0.161, 0.327, 0.9, 0.9800255409045097, 1.0, 1.0},
    .a = {{0},
          {0.161},
          {-0.008480655492356989, 0.335480655492357},
          {2.8971530571054935, -6.359448489975075, 4.3622954328695815},
          {5.325864828439257, -11.748883564062828, 7.4955393428898365, -0.09249506636175525},
          {5.86145544294642, -12.92096931784711, 8.159367898576159, -0.071584973281401,
           -0.028269050394068383},
          {0.09646076681806523, 0.01, 0.4798896504144996, 1.379008574103742,
           -3.290069515436081, 2.324710524099774}},
    .b = {0.09646076681806523, 0.01, 0.4798896504144996, 1.379008574103742, -3.290069515436081,
          2.324710524099774, 0.0},
    .e = {0.0017800110522257773, 0.0008164344596567463, -0.007880878010261994,
          0.1447110071732629, -0.5823571654525552, 0.45808210592918686, -0.015151515151515152},
};

/* The gravity-gradient torque of models.c with P(q) of any q (rigidjax.quat.to_matrix). */
static inline void rhs_attitude(double t, const double *y, const double *p, double *k)
{
    const double *q = y + 3;
    double K[3];
    gravity_torque(q, 2 / (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]), p, K);
    euler(y, p, K, k);
    quat_rates(y, q, k + 3);
}

typedef void (*Rhs)(double, const double *, const double *, double *);

static inline __attribute__((always_inline)) double rms_scaled(const double *err,
                                                                const double *y0,
                                                                const double *y1, double rtol,
                                                                double atol)
{
    double s = 0;
    for (int j = 0; j < NY; j++) {
        const double a0 = fabs(y0[j]), a1 = fabs(y1[j]);
        const double v = err[j] / (atol + rtol * (a0 > a1 ? a0 : a1));
        s += v * v;
    }
    return sqrt(s / NY);
}

/* Diffrax's _select_initial_step (error order 5, RMS norm) at (t0, y0) with f0 = f(t0, y0). */
static inline __attribute__((always_inline)) double initial_step(Rhs f, double t0,
                                                                  const double *y0,
                                                                  const double *f0,
                                                                  const double *p, double rtol,
                                                                  double atol)
{
    double sc[NY], d0 = 0, d1 = 0, d2 = 0, y1[NY], f1[NY];
    for (int j = 0; j < NY; j++) {
        sc[j] = atol + fabs(y0[j]) * rtol;
        d0 += (y0[j] / sc[j]) * (y0[j] / sc[j]);
        d1 += (f0[j] / sc[j]) * (f0[j] / sc[j]);
    }
    d0 = sqrt(d0 / NY), d1 = sqrt(d1 / NY);
    const int small = d0 < 1e-5 || d1 < 1e-5;
    const double h0 = small ? 1e-6 : 0.01 * (d0 / d1);
    for (int j = 0; j < NY; j++) y1[j] = y0[j] + h0 * f0[j];
    f(t0 + h0, y1, p, f1);
    for (int j = 0; j < NY; j++) d2 += ((f1[j] - f0[j]) / sc[j]) * ((f1[j] - f0[j]) / sc[j]);
    d2 = sqrt(d2 / NY) / h0;
    const double max_d = d1 > d2 ? d1 : d2;
    const double h1 = max_d <= 1e-15 ? (h0 * 1e-3 > 1e-6 ? h0 * 1e-3 : 1e-6)
                                     : pow(0.01 / max_d, 1.0 / 5);
    return 100 * h0 < h1 ? 100 * h0 : h1;
}

/* The 100th float below t (Diffrax's t1_clip_floor; eqxi.prevbefore(0) = −DBL_MIN): a
 * proposed step end past it is clipped to the interval's end t. */
static void clip_floor(double t, double *out)
{
    for (int u = 0; u < 100; u++) t = t == 0 ? -DBL_MIN : nextafter(t, -INFINITY);
    *out = t;
}

/* One body through every output interval (floors: clip_floor of each output time); returns 1
 * if an interval reached max_steps. */
static inline __attribute__((always_inline)) int solve_body(Rhs f, const Tableau *tb, int fsal,
                                                            long T, const double *ts,
                                                            const double *floors,
                                                            const double *y0, const double *p,
                                                            double rtol, double atol,
                                                            long max_steps, double *ys,
                                                            long *counts)
{
    double y[NY], k[NS][NY], z[NY], y1[NY], err[NY];
    long accepted = 0, rejected = 0;
    for (int j = 0; j < NY; j++) y[j] = ys[j] = y0[j];
    f(ts[0], y, p, k[0]);
    double h = initial_step(f, ts[0], y, k[0], p, rtol, atol);
    for (long n = 0; n + 1 < T; n++) {
        const double t0 = ts[n], t1 = ts[n + 1], floor1 = floors[n + 1];
        double t = t0, tnext = t0 + h < t1 ? t0 + h : t1;
        long acc = 0, steps = 0;
        while (t < t1) {
            if (steps == max_steps) {
                for (long m = n + 1; m < T; m++)
                    for (int j = 0; j < NY; j++) ys[m * NY + j] = NAN;
                counts[0] = accepted, counts[1] = rejected;
                return 1;
            }
            const double dt = tnext - t;
#pragma GCC unroll 8
            for (int s = 1; s < NS; s++) {
#pragma GCC unroll 8
                for (int j = 0; j < NY; j++) {
                    double inc = 0;
#pragma GCC unroll 8
                    for (int l = 0; l < s; l++) inc += tb->a[s][l] * k[l][j];
                    z[j] = y[j] + dt * inc;
                }
                f(t + tb->c[s] * dt, z, p, k[s]);
            }
#pragma GCC unroll 8
            for (int j = 0; j < NY; j++) {
                double inc = 0, e = 0;
#pragma GCC unroll 8
                for (int l = 0; l < NS; l++) inc += tb->b[l] * k[l][j], e += tb->e[l] * k[l][j];
                y1[j] = y[j] + dt * inc;
                err[j] = dt * e;
            }
            const double r =
                1 / sqrt(y1[3] * y1[3] + y1[4] * y1[4] + y1[5] * y1[5] + y1[6] * y1[6]);
            for (int j = 3; j < NY; j++) y1[j] *= r;
            const double E = rms_scaled(err, y, y1, rtol, atol);
            const int keep = E < 1;
            double factor = 0.9 * pow(1 / E, 1.0 / 5); /* E = 0: +inf, clipped to 10 */
            const double lo = keep ? 1.0 : 0.2, hi = keep ? 10.0 : 0.9;
            factor = factor < lo ? lo : (factor > hi ? hi : factor);
            steps++;
            if (keep) {
                t = tnext;
                for (int j = 0; j < NY; j++) y[j] = y1[j];
                if (fsal)
                    for (int j = 0; j < NY; j++) k[0][j] = k[NS - 1][j];
                else
                    f(t, y, p, k[0]);
                acc++;
            } else {
                rejected++;
            }
            tnext = t + dt * factor;
            if (tnext > floor1) tnext = keep ? t1 : t + 0.5 * (t1 - t);
        }
        accepted += acc;
        h = (t1 - t0) / (acc > 1 ? acc : 1);
        for (int j = 0; j < NY; j++) ys[(n + 1) * NY + j] = y[j];
    }
    counts[0] = accepted, counts[1] = rejected;
    return 0;
}

#define SOLVE(NAME, RHS, TAB)                                                                   \
    static long NAME(int fsal, long B, long T, const double *ts, const double *y0,              \
                     const double *par, long P, double rtol, double atol, long max_steps,       \
                     double *ys, long *counts)                                                  \
    {                                                                                           \
        long failed = 0;                                                                        \
        double floors[T];                                                                       \
        for (long n = 0; n < T; n++) clip_floor(ts[n], &floors[n]);                              \
        _Pragma("omp parallel for schedule(dynamic, 16) reduction(+ : failed)")                 \
        for (long b = 0; b < B; b++)                                                            \
            failed += solve_body(RHS, &TAB, fsal, T, ts, floors, y0 + b * NY, par + b * P,      \
                                 rtol, atol, max_steps, ys + b * T * NY, counts + 2 * b);       \
        return failed;                                                                          \
    }

SOLVE(free_dopri5, rhs_free_body, DOPRI5)
SOLVE(free_tsit5, rhs_free_body, TSIT5)
SOLVE(attitude_dopri5, rhs_attitude, DOPRI5)
SOLVE(attitude_tsit5, rhs_attitude, TSIT5)

long adaptive_solve(int model, int method, int fsal, long B, long T, const double *ts,
                    const double *y0, const double *par, double rtol, double atol,
                    long max_steps, double *ys, long *counts)
{
    if (model == 0)
        return (method ? free_tsit5 : free_dopri5)(fsal, B, T, ts, y0, par, 3, rtol, atol,
                                                   max_steps, ys, counts);
    return (method ? attitude_tsit5 : attitude_dopri5)(fsal, B, T, ts, y0, par, 10, rtol, atol,
                                                       max_steps, ys, counts);
}

/* Reference kernels for benchmarks/bench_models.py: the models with torques that rigidjax's
 * model kernel runs, written by hand in C, classical RK4 at a fixed step, float64, for the CPU.
 *
 * Each model is its right-hand side `rhs_<model>(t, y, p, k)` on one body's scalars; one RK4
 * driver (RK4_MODEL) takes bodies in blocks of BLOCK that stay in L1 over all steps, with the
 * loop over a block's bodies the vectorised one (check with -fopt-info-vec-optimized; GCC
 * scalarises the small per-body arrays, which `omp simd` would privatise into memory) and
 * OpenMP over blocks, as reference/free_body.c. The quaternion (at offset QO) is renormalised
 * after every step. The state and the parameters are structure of arrays: N (P) arrays of B
 * doubles. Every right-hand side uses P(q) of the unit quaternion q = (w, x, y, z):
 *
 *   Pᵀ v = ((1 − 2(y² + z²)) v1 + 2(xy + wz) v2 + 2(xz − wy) v3,  ...)   (rows of Pᵀ)
 *
 *   free body          y = (Ω, q)        p = (c, J)           K = 0
 *   damping            y = (Ω, q)        p = (c, J, k)        Ω̇ = c Ω×Ω-terms + J (−k Ω)
 *   gravity gradient   y = (Ω, q)        p = (c, J, I, s)     K = s c × (I c), c = Pᵀ e_Z
 *   heavy top          y = (Ω, γ, q)     p = (c, J, μ)        K = γ × μ,  γ̇ = γ × Ω
 *   6-DOF body         y = (R, V, q, Ω)  p = (c, J, 1/m, F, a)  Ṙ = V, V̇ = F/m, K = a × PᵀF
 *                                      (P of q/|q|: simulate_6dof's load sees a unit q)
 *   satellite          y = (R, V, q, Ω)  p = (c, J, I, μ)     V̇ = −μR/r³, K = 3μ/r³ n × (I n),
 *                                                             n = PᵀR/r
 *   gyrostat           y = (Ω, q)        p = (c, J, h)        K = −Ω × h (constant rotor momentum)
 *   Darboux quaternion y = q             p = a                q̇ = ½ q ∘ (0, Ω(t))
 *   Darboux rotvec     y = θ             p = a                θ̇ = Zᵀ(θ) Ω(t), then its shadow
 * with c = ((I2 − I3)/I1, (I3 − I1)/I2, (I1 − I2)/I3), J = 1/I (principal axes).
 */
#include <math.h>
#include <stddef.h>

#define BLOCK 64

#include "models_rhs.h"

/* `steps` RK4 steps of size h from t = 0 for the B bodies of `state` (N × B, in place),
 * parameters `par` (P × B), each step followed by END(y) (NO_END or the shadow):
 * void <name>_rk4(double *state, const double *par, long B, long steps, double h). */
#define RK4_MODEL(NAME, N, P, QO, END)                                                         \
    static void NAME##_block(long m, double (*x)[BLOCK], const double (*C)[BLOCK], long steps, \
                             double h)                                                         \
    {                                                                                          \
        for (long s = 0; s < steps; s++) {                                                     \
            _Pragma("GCC ivdep") for (long i = 0; i < m; i++)                                   \
            {                                                                                  \
                double y[N], p[P];                                                             \
                for (int j = 0; j < N; j++) y[j] = x[j][i];                                    \
                for (int j = 0; j < P; j++) p[j] = C[j][i];                                    \
                RK4_STEP(NAME, N, QO, y, p, (double)s * h, h);                                 \
                END(y);                                                                        \
                for (int j = 0; j < N; j++) x[j][i] = y[j];                                    \
            }                                                                                  \
        }                                                                                      \
    }                                                                                          \
    void NAME##_rk4(double *state, const double *par, long B, long steps, double h)            \
    {                                                                                          \
        _Pragma("omp parallel for schedule(static)") for (long b0 = 0; b0 < B; b0 += BLOCK)    \
        {                                                                                      \
            double x[N][BLOCK], C[P][BLOCK];                                                   \
            const long m = B - b0 < BLOCK ? B - b0 : BLOCK;                                    \
            for (int j = 0; j < N; j++)                                                        \
                for (long i = 0; i < m; i++) x[j][i] = state[j * B + b0 + i];                  \
            for (int j = 0; j < P; j++)                                                        \
                for (long i = 0; i < m; i++) C[j][i] = par[j * B + b0 + i];                    \
            NAME##_block(m, x, (const double (*)[BLOCK])C, steps, h);                          \
            for (int j = 0; j < N; j++)                                                        \
                for (long i = 0; i < m; i++) state[j * B + b0 + i] = x[j][i];                  \
        }                                                                                      \
    }

RJ_MODELS(RK4_MODEL)

/* The closed loop (rhs_closed_loop, control_pd): `steps` RK4 steps of size h, the motor
 * torques u sampled every `every` steps and held; par (32 × B: the model's parameters, u
 * slots last) and the law's constants ctl (19, shared).
 * void closed_loop_rk4(double *state, const double *par, const double *ctl, long B,
 *                      long steps, double h, long every) */
static void closed_loop_block(long m, double (*x)[BLOCK], double (*C)[BLOCK], const double *ctl,
                              long steps, double h, long every)
{
    for (long s = 0; s < steps; s++) {
        if (s % every == 0) {
            for (long i = 0; i < m; i++) {
                double y[11], u[4];
                for (int j = 0; j < 11; j++) y[j] = x[j][i];
                control_pd(y, ctl, u);
                for (int j = 0; j < 4; j++) C[28 + j][i] = u[j];
            }
        }
        _Pragma("GCC ivdep") for (long i = 0; i < m; i++)
        {
            double y[11], p[32];
            /* unrolled completely, so that p and y stay scalars and the bodies vectorise
             * (GCC unrolls at most 16 iterations by itself) */
            _Pragma("GCC unroll 32") for (int j = 0; j < 11; j++) y[j] = x[j][i];
            _Pragma("GCC unroll 32") for (int j = 0; j < 32; j++) p[j] = C[j][i];
            RK4_STEP(closed_loop, 11, 3, y, p, (double)s * h, h);
            for (int j = 0; j < 11; j++) x[j][i] = y[j];
        }
    }
}

void closed_loop_rk4(double *state, const double *par, const double *ctl, long B, long steps,
                     double h, long every)
{
    _Pragma("omp parallel for schedule(static)") for (long b0 = 0; b0 < B; b0 += BLOCK)
    {
        double x[11][BLOCK], C[32][BLOCK];
        const long m = B - b0 < BLOCK ? B - b0 : BLOCK;
        for (int j = 0; j < 11; j++)
            for (long i = 0; i < m; i++) x[j][i] = state[j * B + b0 + i];
        for (int j = 0; j < 32; j++)
            for (long i = 0; i < m; i++) C[j][i] = par[j * B + b0 + i];
        closed_loop_block(m, x, C, ctl, steps, h, every);
        for (int j = 0; j < 11; j++)
            for (long i = 0; i < m; i++) state[j * B + b0 + i] = x[j][i];
    }
}

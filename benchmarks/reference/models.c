/* Reference kernels for benchmarks/bench_models.py: the models with torques that rigidjax's
 * model kernel runs, written by hand in C, classical RK4 at a fixed step, float64, for the CPU.
 *
 * Each model is its right-hand side `rhs_<model>(y, p, k)` on one body's scalars; one RK4
 * driver (RK4_MODEL) takes bodies in blocks of BLOCK that stay in L1 over all steps, with the
 * loop over a block's bodies the vectorised one (check with -fopt-info-vec-optimized; GCC
 * scalarises the small per-body arrays, which `omp simd` would privatise into memory) and
 * OpenMP over blocks, as reference/free_body.c. The quaternion (at offset QO) is renormalised
 * after every step. The state and the parameters are structure of arrays: N (P) arrays of B
 * doubles. Every right-hand side uses P(q) of the unit quaternion q = (w, x, y, z):
 *
 *   Pᵀ v = ((1 − 2(y² + z²)) v1 + 2(xy + wz) v2 + 2(xz − wy) v3,  ...)   (rows of Pᵀ)
 *
 *   damping            y = (Ω, q)        p = (c, J, k)        Ω̇ = c Ω×Ω-terms + J (−k Ω)
 *   gravity gradient   y = (Ω, q)        p = (c, J, I, s)     K = s c × (I c), c = Pᵀ e_Z
 *   heavy top          y = (Ω, γ, q)     p = (c, J, μ)        K = γ × μ,  γ̇ = γ × Ω
 *   6-DOF body         y = (R, V, q, Ω)  p = (c, J, 1/m, F, a)  Ṙ = V, V̇ = F/m, K = a × PᵀF
 *   satellite          y = (R, V, q, Ω)  p = (c, J, I, μ)     V̇ = −μR/r³, K = 3μ/r³ n × (I n),
 *                                                             n = PᵀR/r
 *   gyrostat           y = (Ω, q)        p = (c, J, h)        K = −Ω × h (constant rotor momentum)
 * with c = ((I2 − I3)/I1, (I3 − I1)/I2, (I1 − I2)/I3), J = 1/I (principal axes).
 */
#include <math.h>
#include <stddef.h>

#define BLOCK 64

static inline void quat_rates(const double *w, const double *q, double *dq)
{
    dq[0] = 0.5 * (-q[1] * w[0] - q[2] * w[1] - q[3] * w[2]);
    dq[1] = 0.5 * (q[0] * w[0] + q[2] * w[2] - q[3] * w[1]);
    dq[2] = 0.5 * (q[0] * w[1] + q[3] * w[0] - q[1] * w[2]);
    dq[3] = 0.5 * (q[0] * w[2] + q[1] * w[1] - q[2] * w[0]);
}

/* Pᵀ v: v in space axes to body axes. */
static inline void to_body(const double *q, const double *v, double *out)
{
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    out[0] = (1 - 2 * (y * y + z * z)) * v[0] + 2 * (x * y + w * z) * v[1] + 2 * (x * z - w * y) * v[2];
    out[1] = 2 * (x * y - w * z) * v[0] + (1 - 2 * (x * x + z * z)) * v[1] + 2 * (y * z + w * x) * v[2];
    out[2] = 2 * (x * z + w * y) * v[0] + 2 * (y * z - w * x) * v[1] + (1 - 2 * (x * x + y * y)) * v[2];
}

/* Euler's equations in principal axes: Ω̇ = c-terms + J K. */
static inline void euler(const double *w, const double *p, const double *K, double *dw)
{
    dw[0] = p[0] * w[1] * w[2] + p[3] * K[0];
    dw[1] = p[1] * w[2] * w[0] + p[4] * K[1];
    dw[2] = p[2] * w[0] * w[1] + p[5] * K[2];
}

static inline void cross(const double *a, const double *b, double *out)
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

static inline void rhs_damping(const double *y, const double *p, double *k)
{
    const double K[3] = {-p[6] * y[0], -p[7] * y[1], -p[8] * y[2]};
    euler(y, p, K, k);
    quat_rates(y, y + 3, k + 3);
}

static inline void rhs_gravity_gradient(const double *y, const double *p, double *k)
{
    const double *q = y + 3;
    const double c[3] = {2 * (q[1] * q[3] - q[0] * q[2]), 2 * (q[2] * q[3] + q[0] * q[1]),
                         1 - 2 * (q[1] * q[1] + q[2] * q[2])};
    const double Ic[3] = {p[6] * c[0], p[7] * c[1], p[8] * c[2]};
    double K[3];
    cross(c, Ic, K);
    for (int i = 0; i < 3; i++) K[i] *= p[9];
    euler(y, p, K, k);
    quat_rates(y, q, k + 3);
}

static inline void rhs_heavy_top(const double *y, const double *p, double *k)
{
    double K[3];
    cross(y + 3, p + 6, K);
    euler(y, p, K, k);
    cross(y + 3, y, k + 3);
    quat_rates(y, y + 6, k + 6);
}

static inline void rhs_sixdof(const double *y, const double *p, double *k)
{
    const double *F = p + 7, *a = p + 10, *q = y + 6, *w = y + 10;
    double Fb[3], K[3];
    to_body(q, F, Fb);
    cross(a, Fb, K);
    for (int i = 0; i < 3; i++) k[i] = y[3 + i], k[3 + i] = p[6] * F[i];
    quat_rates(w, q, k + 6);
    euler(w, p, K, k + 10);
}

static inline void rhs_satellite(const double *y, const double *p, double *k)
{
    const double *R = y, *q = y + 6, *w = y + 10, mu = p[9];
    const double r2 = R[0] * R[0] + R[1] * R[1] + R[2] * R[2], r = sqrt(r2);
    const double g = mu / (r2 * r);
    double n[3], In[3], K[3];
    to_body(q, R, n);
    for (int i = 0; i < 3; i++) n[i] /= r, In[i] = p[6 + i] * n[i];
    cross(n, In, K);
    for (int i = 0; i < 3; i++) K[i] *= 3 * g, k[i] = y[3 + i], k[3 + i] = -g * R[i];
    quat_rates(w, q, k + 6);
    euler(w, p, K, k + 10);
}

static inline void rhs_gyrostat(const double *y, const double *p, double *k)
{
    double K[3];
    cross(y, p + 6, K);
    for (int i = 0; i < 3; i++) K[i] = -K[i];
    euler(y, p, K, k);
    quat_rates(y, y + 3, k + 3);
}

/* `steps` RK4 steps of size h for the B bodies of `state` (N × B, in place), parameters
 * `par` (P × B): void <name>_rk4(double *state, const double *par, long B, long steps, double h). */
#define RK4_MODEL(NAME, N, P, QO)                                                              \
    static void NAME##_block(long m, double (*x)[BLOCK], const double (*C)[BLOCK], long steps, \
                             double h)                                                         \
    {                                                                                          \
        for (long s = 0; s < steps; s++) {                                                     \
            _Pragma("GCC ivdep") for (long i = 0; i < m; i++)                                   \
            {                                                                                  \
                double y[N], p[P], z[N], k1[N], k2[N], k3[N], k4[N];                           \
                for (int j = 0; j < N; j++) y[j] = x[j][i];                                    \
                for (int j = 0; j < P; j++) p[j] = C[j][i];                                    \
                rhs_##NAME(y, p, k1);                                                          \
                for (int j = 0; j < N; j++) z[j] = y[j] + 0.5 * h * k1[j];                     \
                rhs_##NAME(z, p, k2);                                                          \
                for (int j = 0; j < N; j++) z[j] = y[j] + 0.5 * h * k2[j];                     \
                rhs_##NAME(z, p, k3);                                                          \
                for (int j = 0; j < N; j++) z[j] = y[j] + h * k3[j];                           \
                rhs_##NAME(z, p, k4);                                                          \
                for (int j = 0; j < N; j++)                                                    \
                    y[j] += h * (k1[j] / 6 + k2[j] / 3 + k3[j] / 3 + k4[j] / 6);               \
                const double r = 1.0 / sqrt(y[QO] * y[QO] + y[QO + 1] * y[QO + 1] +            \
                                            y[QO + 2] * y[QO + 2] + y[QO + 3] * y[QO + 3]);    \
                for (int j = QO; j < QO + 4; j++) y[j] *= r;                                   \
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

RK4_MODEL(damping, 7, 9, 3)
RK4_MODEL(gravity_gradient, 7, 10, 3)
RK4_MODEL(heavy_top, 10, 9, 6)
RK4_MODEL(sixdof, 13, 13, 6)
RK4_MODEL(satellite, 13, 10, 6)
RK4_MODEL(gyrostat, 7, 9, 3)

/* Reference kernel for benchmarks/bench_dynamics.py: the free rigid body with its attitude
 * quaternion, classical RK4 at a fixed step, float64, written by hand for the CPU.
 *
 *   Euler's equations in principal axes   dΩ1/dt = c1 Ω2 Ω3,  c1 = (I2 − I3)/I1  (cyclic)
 *   body-frame quaternion kinematics      dq/dt  = ½ q ∘ (0, Ω)
 *   after every step                      q ← q / |q|
 *
 * The same work as rigidjax's fixed-step fast path. The state is structure of arrays
 * (seven arrays of B doubles, Ω first); c1, c2, c3 are per body. Bodies are taken in blocks of
 * BLOCK that stay in L1 over all N steps; the loop over a block's bodies is the vectorised one
 * (check with -fopt-info-vec-optimized); OpenMP spreads the blocks over the cores.
 *
 * Flops per body-step (adds, multiplies, one sqrt, one divide counted as one each): 238.
 */
#include <math.h>
#include <stddef.h>

#define BLOCK 64

/* k = f(y) for one body, on scalars so that the loop over bodies vectorises. */
#define RHS(k, w1, w2, w3, a, b, cq, d)                                                       \
    double k##0 = c1 * (w2) * (w3), k##1 = c2 * (w3) * (w1), k##2 = c3 * (w1) * (w2);           \
    double k##3 = 0.5 * (-(b) * (w1) - (cq) * (w2) - (d) * (w3));                              \
    double k##4 = 0.5 * ((a) * (w1) + (cq) * (w3) - (d) * (w2));                               \
    double k##5 = 0.5 * ((a) * (w2) + (d) * (w1) - (b) * (w3));                                \
    double k##6 = 0.5 * ((a) * (w3) + (b) * (w2) - (cq) * (w1))

#define STAGE(k, kp, f)                                                                        \
    RHS(k, y0 + (f) * kp##0, y1 + (f) * kp##1, y2 + (f) * kp##2, y3 + (f) * kp##3,             \
        y4 + (f) * kp##4, y5 + (f) * kp##5, y6 + (f) * kp##6)

/* y + h Σ b_l k_l with the weights b = (1/6, 1/3, 1/3, 1/6), summed in order as Diffrax and
 * rigidjax's kernel do, so that the two agree to the last bit. */
#define UPDATE(j) (y##j + h * (B1 * k1##j + B2 * k2##j + B2 * k3##j + B1 * k4##j))
#define B1 (1.0 / 6.0)
#define B2 (1.0 / 3.0)

static void block_steps(long n, double *restrict s[7], const double *restrict coef[3],
                        long steps, double h)
{
    double x0[BLOCK], x1[BLOCK], x2[BLOCK], x3[BLOCK], x4[BLOCK], x5[BLOCK], x6[BLOCK];
    double C1[BLOCK], C2[BLOCK], C3[BLOCK];
    double *x[7] = {x0, x1, x2, x3, x4, x5, x6};
    for (int j = 0; j < 7; j++)
        for (long i = 0; i < n; i++) x[j][i] = s[j][i];
    for (long i = 0; i < n; i++) {
        C1[i] = coef[0][i];
        C2[i] = coef[1][i];
        C3[i] = coef[2][i];
    }
    const double h2 = 0.5 * h;
    for (long step = 0; step < steps; step++) {
#pragma omp simd
        for (long i = 0; i < n; i++) {
            const double c1 = C1[i], c2 = C2[i], c3 = C3[i];
            const double y0 = x0[i], y1 = x1[i], y2 = x2[i], y3 = x3[i], y4 = x4[i], y5 = x5[i],
                         y6 = x6[i];
            RHS(k1, y0, y1, y2, y3, y4, y5, y6);
            STAGE(k2, k1, h2);
            STAGE(k3, k2, h2);
            STAGE(k4, k3, h);
            const double a = UPDATE(3), b = UPDATE(4), cq = UPDATE(5), d = UPDATE(6);
            const double r = 1.0 / sqrt(a * a + b * b + cq * cq + d * d);
            x0[i] = UPDATE(0);
            x1[i] = UPDATE(1);
            x2[i] = UPDATE(2);
            x3[i] = a * r;
            x4[i] = b * r;
            x5[i] = cq * r;
            x6[i] = d * r;
        }
    }
    for (int j = 0; j < 7; j++)
        for (long i = 0; i < n; i++) s[j][i] = x[j][i];
}

/* Advance B bodies by `steps` RK4 steps of size h, in place. state: 7 × B doubles (Ω1, Ω2, Ω3,
 * q0, q1, q2, q3, each contiguous); coef: 3 × B doubles (c1, c2, c3). */
void free_body_rk4(double *state, const double *coef, long B, long steps, double h)
{
    long nblocks = (B + BLOCK - 1) / BLOCK;
#pragma omp parallel for schedule(static)
    for (long blk = 0; blk < nblocks; blk++) {
        size_t start = (size_t)blk * BLOCK;
        long n = B - (long)start < BLOCK ? B - (long)start : BLOCK;
        double *s[7];
        const double *cf[3];
        for (int j = 0; j < 7; j++) s[j] = state + (size_t)j * (size_t)B + start;
        for (int j = 0; j < 3; j++) cf[j] = coef + (size_t)j * (size_t)B + start;
        block_steps(n, s, cf, steps, h);
    }
}

/* GPU reference kernels for benchmarks/bench_gpu.py: the models of models.c, written by hand in
 * CUDA C, classical RK4 at a fixed step, float64, one body per thread, its state in registers
 * over all steps (the same right-hand sides, models_rhs.h). Built at run time by NVRTC (CuPy's
 * RawModule). The state and parameters are structure of arrays: N (P) arrays of B doubles.
 *
 *   <name>_rk4(double *state, const double *par, long B, long steps, double h)
 */
#define RJ_DEVICE __device__
#include "models_rhs.h"

#define RK4_MODEL(NAME, N, P, QO)                                                              \
    extern "C" __global__ void NAME##_rk4(double *state, const double *par, long B, long steps,\
                                          double h)                                            \
    {                                                                                          \
        const long i = blockIdx.x * (long)blockDim.x + threadIdx.x;                            \
        if (i >= B) return;                                                                    \
        double y[N], p[P], z[N], k1[N], k2[N], k3[N], k4[N];                                   \
        for (int j = 0; j < N; j++) y[j] = state[j * B + i];                                   \
        for (int j = 0; j < P; j++) p[j] = par[j * B + i];                                     \
        for (long s = 0; s < steps; s++) {                                                     \
            rhs_##NAME(y, p, k1);                                                              \
            for (int j = 0; j < N; j++) z[j] = y[j] + 0.5 * h * k1[j];                         \
            rhs_##NAME(z, p, k2);                                                              \
            for (int j = 0; j < N; j++) z[j] = y[j] + 0.5 * h * k2[j];                         \
            rhs_##NAME(z, p, k3);                                                              \
            for (int j = 0; j < N; j++) z[j] = y[j] + h * k3[j];                               \
            rhs_##NAME(z, p, k4);                                                              \
            for (int j = 0; j < N; j++)                                                        \
                y[j] += h * (k1[j] / 6 + k2[j] / 3 + k3[j] / 3 + k4[j] / 6);                   \
            const double r = 1.0 / sqrt(y[QO] * y[QO] + y[QO + 1] * y[QO + 1] +                \
                                        y[QO + 2] * y[QO + 2] + y[QO + 3] * y[QO + 3]);        \
            for (int j = QO; j < QO + 4; j++) y[j] *= r;                                       \
        }                                                                                      \
        for (int j = 0; j < N; j++) state[j * B + i] = y[j];                                   \
    }

RK4_MODEL(free_body, 7, 6, 3)
RK4_MODEL(damping, 7, 9, 3)
RK4_MODEL(gravity_gradient, 7, 10, 3)
RK4_MODEL(heavy_top, 10, 9, 6)
RK4_MODEL(sixdof, 13, 13, 6)
RK4_MODEL(satellite, 13, 10, 6)
RK4_MODEL(gyrostat, 7, 9, 3)

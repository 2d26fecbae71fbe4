/* GPU reference kernels for benchmarks/bench_gpu.py: the models of models.c, written by hand in
 * CUDA C, classical RK4 at a fixed step, float64, one body per thread, its state in registers
 * over all steps (the same right-hand sides, models_rhs.h). Built at run time by NVRTC (CuPy's
 * RawModule). The state and parameters are structure of arrays: N (P) arrays of B doubles.
 *
 *   <name>_rk4(double *state, const double *par, long B, long steps, double h)
 *
 * each step followed by END(y) (NO_END, or the rotation vector's shadow).
 */
#define RJ_DEVICE __device__
#include "models_rhs.h"

#define RK4_MODEL(NAME, N, P, QO, END)                                                         \
    extern "C" __global__ void NAME##_rk4(double *state, const double *par, long B, long steps,\
                                          double h)                                            \
    {                                                                                          \
        const long i = blockIdx.x * (long)blockDim.x + threadIdx.x;                            \
        if (i >= B) return;                                                                    \
        double y[N], p[P];                                                                     \
        for (int j = 0; j < N; j++) y[j] = state[j * B + i];                                   \
        for (int j = 0; j < P; j++) p[j] = par[j * B + i];                                     \
        for (long s = 0; s < steps; s++) {                                                     \
            RK4_STEP(NAME, N, QO, y, p, (double)s * h, h);                                     \
            END(y);                                                                            \
        }                                                                                      \
        for (int j = 0; j < N; j++) state[j * B + i] = y[j];                                   \
    }

RJ_MODELS(RK4_MODEL)

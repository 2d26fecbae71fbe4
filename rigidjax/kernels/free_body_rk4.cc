// The free rigid body with its attitude quaternion, classical RK4 at fixed steps, as an XLA FFI
// kernel for the CPU (rigidjax/kernels/free_body.py builds and registers it).
//
//   Euler's equations in principal axes  dΩ1/dt = c1 Ω2 Ω3, c1 = (I2 − I3)/I1 (cyclic;
//                                        Zegrya–Parshin 004)
//   body-frame quaternion kinematics     dq/dt = ½ q ∘ (0, Ω)  (Borisov–Mamaev 001)
//   after every step                     q ← q / |q|
//
// The same arithmetic, in the same order, as rigidjax's component path (`simulate` with
// solver=RK4(), diffrax.ConstantStepSize()). XLA compiles that path into one loop per state
// component, each recomputing the stage chain it needs (about 3× the flops); here each body's
// step stays in registers. Bodies go in blocks of kBlock that stay in L1 over all steps; the
// loop over a block's bodies is the vectorised one; OpenMP spreads blocks over the cores.
//
// Shapes (L: leading batch dimensions added by jax.vmap, flattened):
//   y0 (L, 7, B)  Ω1 Ω2 Ω3 q0 q1 q2 q3, bodies last
//   coef (L, 3, B)  c1 c2 c3
//   n (L, K) int32  steps in output interval k;  h (L, K)  their size
//   ys (L, K + 1, 7, B)  the state at every output time, ys[:, 0] = y0
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

constexpr int64_t kBlock = 64;

#define RJ_RHS(k, w1, w2, w3, a, b, cq, d)                                    \
  const T k##0 = c1 * (w2) * (w3), k##1 = c2 * (w3) * (w1),                   \
          k##2 = c3 * (w1) * (w2);                                            \
  const T k##3 = T(0.5) * (-(b) * (w1) - (cq) * (w2) - (d) * (w3));           \
  const T k##4 = T(0.5) * ((a) * (w1) + (cq) * (w3) - (d) * (w2));            \
  const T k##5 = T(0.5) * ((a) * (w2) + (d) * (w1) - (b) * (w3));             \
  const T k##6 = T(0.5) * ((a) * (w3) + (b) * (w2) - (cq) * (w1))

#define RJ_STAGE(k, kp, f)                                                    \
  RJ_RHS(k, y0 + (f) * kp##0, y1 + (f) * kp##1, y2 + (f) * kp##2,             \
         y3 + (f) * kp##3, y4 + (f) * kp##4, y5 + (f) * kp##5,                \
         y6 + (f) * kp##6)

#define RJ_UPDATE(j) (y##j + h6 * (k1##j + T(2) * k2##j + T(2) * k3##j + k4##j))

// `steps` RK4 steps of size h on the n ≤ kBlock bodies of x (7 rows of kBlock), coefficients C.
template <typename T>
void Steps(int64_t n, T (*__restrict x)[kBlock], const T (*__restrict C)[kBlock],
           int64_t steps, T h) {
  const T h2 = T(0.5) * h, h6 = h / T(6);
  T *__restrict x0 = x[0], *__restrict x1 = x[1], *__restrict x2 = x[2], *__restrict x3 = x[3],
                *__restrict x4 = x[4], *__restrict x5 = x[5], *__restrict x6 = x[6];
  for (int64_t s = 0; s < steps; ++s) {
#pragma omp simd
    for (int64_t i = 0; i < n; ++i) {
      const T c1 = C[0][i], c2 = C[1][i], c3 = C[2][i];
      const T y0 = x0[i], y1 = x1[i], y2 = x2[i], y3 = x3[i], y4 = x4[i], y5 = x5[i],
              y6 = x6[i];
      RJ_RHS(k1, y0, y1, y2, y3, y4, y5, y6);
      RJ_STAGE(k2, k1, h2);
      RJ_STAGE(k3, k2, h2);
      RJ_STAGE(k4, k3, h);
      const T a = RJ_UPDATE(3), b = RJ_UPDATE(4), cq = RJ_UPDATE(5), d = RJ_UPDATE(6);
      const T r = T(1) / std::sqrt(a * a + b * b + cq * cq + d * d);
      x0[i] = RJ_UPDATE(0);
      x1[i] = RJ_UPDATE(1);
      x2[i] = RJ_UPDATE(2);
      x3[i] = a * r;
      x4[i] = b * r;
      x5[i] = cq * r;
      x6[i] = d * r;
    }
  }
}

// One group of bodies that share their steps (n, h): `count` bodies, body g at batch row
// first + g / B, column g % B.
template <typename T>
void Group(const T* y0, const T* coef, const int32_t* n, const T* h, T* ys, int64_t first,
           int64_t count, int64_t B, int64_t K) {
  const int64_t blocks = (count + kBlock - 1) / kBlock;
#pragma omp parallel for schedule(static)
  for (int64_t blk = 0; blk < blocks; ++blk) {
    alignas(64) T x[7][kBlock];
    alignas(64) T C[3][kBlock];
    const int64_t start = blk * kBlock, m = std::min(kBlock, count - start);
    for (int64_t i = 0; i < m; ++i) {
      const int64_t l = first + (start + i) / B, b = (start + i) % B;
      for (int j = 0; j < 7; ++j) x[j][i] = y0[(l * 7 + j) * B + b];
      for (int j = 0; j < 3; ++j) C[j][i] = coef[(l * 3 + j) * B + b];
    }
    for (int64_t k = 0; k <= K; ++k) {
      if (k > 0) Steps<T>(m, x, C, n[k - 1], h[k - 1]);
      for (int64_t i = 0; i < m; ++i) {
        const int64_t l = first + (start + i) / B, b = (start + i) % B;
        for (int j = 0; j < 7; ++j) ys[((l * (K + 1) + k) * 7 + j) * B + b] = x[j][i];
      }
    }
  }
}

template <ffi::DataType DT>
ffi::Error FreeBodyRK4(ffi::Buffer<DT> y0, ffi::Buffer<DT> coef, ffi::Buffer<ffi::S32> n,
                       ffi::Buffer<DT> h, ffi::ResultBuffer<DT> ys) {
  using T = ffi::NativeType<DT>;
  const auto dims = y0.dimensions();
  if (dims.size() < 2 || dims[dims.size() - 2] != 7) {
    return ffi::Error::InvalidArgument("free_body_rk4: y0 must have shape (..., 7, B)");
  }
  const int64_t B = dims[dims.size() - 1];
  const int64_t L = static_cast<int64_t>(y0.element_count()) / (7 * B);
  const auto ndims = n.dimensions();
  const int64_t K = ndims.size() == 0 ? 0 : ndims[ndims.size() - 1];
  if (coef.element_count() != static_cast<size_t>(L * 3 * B) ||
      n.element_count() != static_cast<size_t>(L * K) ||
      h.element_count() != static_cast<size_t>(L * K) ||
      ys->element_count() != static_cast<size_t>(L * (K + 1) * 7 * B)) {
    return ffi::Error::InvalidArgument("free_body_rk4: inconsistent shapes");
  }
  const int32_t* nn = n.typed_data();
  const T* hh = h.typed_data();
  // Batch rows with the same steps are one group, so that a vmapped single body still fills
  // the vector lanes; rows with their own steps (vmapped output times) go one by one.
  bool shared = true;
  for (int64_t l = 1; l < L && shared; ++l) {
    shared = std::memcmp(nn, nn + l * K, K * sizeof(int32_t)) == 0 &&
             std::memcmp(hh, hh + l * K, K * sizeof(T)) == 0;
  }
  if (shared) {
    Group<T>(y0.typed_data(), coef.typed_data(), nn, hh, ys->typed_data(), 0, L * B, B, K);
  } else {
    for (int64_t l = 0; l < L; ++l) {
      Group<T>(y0.typed_data(), coef.typed_data(), nn + l * K, hh + l * K, ys->typed_data(), l,
               B, B, K);
    }
  }
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(RigidjaxFreeBodyRK4F64, FreeBodyRK4<ffi::F64>,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Ret<ffi::Buffer<ffi::F64>>());

XLA_FFI_DEFINE_HANDLER_SYMBOL(RigidjaxFreeBodyRK4F32, FreeBodyRK4<ffi::F32>,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>());

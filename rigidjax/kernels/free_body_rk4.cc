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
#include <vector>

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

// Batch row and column of a block's bodies start … start + m − 1 in a group: body g is at row
// first + g / B, column g % B (counted up, not divided per body).
inline void Place(int64_t first, int64_t start, int64_t m, int64_t B, int64_t* row, int64_t* col) {
  int64_t l = first + start / B, b = start % B;
  for (int64_t i = 0; i < m; ++i) {
    row[i] = l;
    col[i] = b;
    if (++b == B) b = 0, ++l;
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
    int64_t row[kBlock], col[kBlock];
    Place(first, start, m, B, row, col);
    for (int64_t i = 0; i < m; ++i) {
      const int64_t l = row[i], b = col[i];
      for (int j = 0; j < 7; ++j) x[j][i] = y0[(l * 7 + j) * B + b];
      for (int j = 0; j < 3; ++j) C[j][i] = coef[(l * 3 + j) * B + b];
    }
    for (int64_t k = 0; k <= K; ++k) {
      if (k > 0) Steps<T>(m, x, C, n[k - 1], h[k - 1]);
      for (int64_t i = 0; i < m; ++i) {
        const int64_t l = row[i], b = col[i];
        for (int j = 0; j < 7; ++j) ys[((l * (K + 1) + k) * 7 + j) * B + b] = x[j][i];
      }
    }
  }
}

// ---------------------------------------------------------------- reverse mode (adjoint)

// f(z) of one body (Euler + quaternion kinematics) into k.
template <typename T>
inline void F(const T* z, T c1, T c2, T c3, T* k) {
  k[0] = c1 * z[1] * z[2];
  k[1] = c2 * z[2] * z[0];
  k[2] = c3 * z[0] * z[1];
  k[3] = T(0.5) * (-z[4] * z[0] - z[5] * z[1] - z[6] * z[2]);
  k[4] = T(0.5) * (z[3] * z[0] + z[5] * z[2] - z[6] * z[1]);
  k[5] = T(0.5) * (z[3] * z[1] + z[6] * z[0] - z[4] * z[2]);
  k[6] = T(0.5) * (z[3] * z[2] + z[4] * z[1] - z[5] * z[0]);
}

// zb += J_f(z)^T v;  cb += (∂f/∂c)^T v.
template <typename T>
inline void FT(const T* z, T c1, T c2, T c3, const T* v, T* zb, T* cb) {
  const T w1 = z[0], w2 = z[1], w3 = z[2], a = z[3], b = z[4], cq = z[5], d = z[6];
  zb[0] += v[1] * c2 * w3 + v[2] * c3 * w2 + T(0.5) * (-b * v[3] + a * v[4] + d * v[5] - cq * v[6]);
  zb[1] += v[0] * c1 * w3 + v[2] * c3 * w1 + T(0.5) * (-cq * v[3] - d * v[4] + a * v[5] + b * v[6]);
  zb[2] += v[0] * c1 * w2 + v[1] * c2 * w1 + T(0.5) * (-d * v[3] + cq * v[4] - b * v[5] + a * v[6]);
  zb[3] += T(0.5) * (w1 * v[4] + w2 * v[5] + w3 * v[6]);
  zb[4] += T(0.5) * (-w1 * v[3] - w3 * v[5] + w2 * v[6]);
  zb[5] += T(0.5) * (-w2 * v[3] + w3 * v[4] - w1 * v[6]);
  zb[6] += T(0.5) * (-w3 * v[3] - w2 * v[4] + w1 * v[5]);
  cb[0] += v[0] * w2 * w3;
  cb[1] += v[1] * w3 * w1;
  cb[2] += v[2] * w1 * w2;
}

// Reverse one step from the states x (7 rows of kBlock) it started from: lam (7 rows), the
// cotangent of the step's end state, becomes that of its start; cb (3 rows) and hb (1 row)
// collect the cotangents of the coefficients and of the step size.
template <typename T>
void StepBack(int64_t n, const T (*__restrict x)[kBlock], const T (*__restrict C)[kBlock], T h,
              T (*__restrict lam)[kBlock], T (*__restrict cb)[kBlock], T* __restrict hb) {
  const T h2 = T(0.5) * h, h6 = h / T(6);
#pragma GCC ivdep
  for (int64_t i = 0; i < n; ++i) {
    const T c1 = C[0][i], c2 = C[1][i], c3 = C[2][i];
    T y[7], k1[7], k2[7], k3[7], k4[7], z2[7], z3[7], z4[7], u[7];
    for (int j = 0; j < 7; ++j) y[j] = x[j][i];
    F(y, c1, c2, c3, k1);
    for (int j = 0; j < 7; ++j) z2[j] = y[j] + h2 * k1[j];
    F(z2, c1, c2, c3, k2);
    for (int j = 0; j < 7; ++j) z3[j] = y[j] + h2 * k2[j];
    F(z3, c1, c2, c3, k3);
    for (int j = 0; j < 7; ++j) z4[j] = y[j] + h * k3[j];
    F(z4, c1, c2, c3, k4);
    for (int j = 0; j < 7; ++j) u[j] = y[j] + h6 * (k1[j] + T(2) * k2[j] + T(2) * k3[j] + k4[j]);
    // end state (u_Ω, u_q / |u_q|): ū_q = (λ_q − n (n·λ_q)) / |u_q|, n = u_q / |u_q|
    const T r = T(1) / std::sqrt(u[3] * u[3] + u[4] * u[4] + u[5] * u[5] + u[6] * u[6]);
    T ub[7];
    T dot = T(0);
    for (int j = 3; j < 7; ++j) dot += u[j] * r * lam[j][i];
    for (int j = 0; j < 3; ++j) ub[j] = lam[j][i];
    for (int j = 3; j < 7; ++j) ub[j] = r * (lam[j][i] - u[j] * r * dot);
    T yb[7], kb1[7], kb2[7], kb3[7], cbar[3] = {T(0), T(0), T(0)};
    T hbar = T(0);
    for (int j = 0; j < 7; ++j) {
      yb[j] = ub[j];
      kb1[j] = h6 * ub[j];
      kb2[j] = T(2) * h6 * ub[j];
      kb3[j] = T(2) * h6 * ub[j];
      hbar += ub[j] * (k1[j] + T(2) * k2[j] + T(2) * k3[j] + k4[j]) / T(6);
    }
    // stage 4: z4 = y + h k3
    T zb[7] = {T(0), T(0), T(0), T(0), T(0), T(0), T(0)};
    T v4[7];
    for (int j = 0; j < 7; ++j) v4[j] = h6 * ub[j];
    FT(z4, c1, c2, c3, v4, zb, cbar);
    for (int j = 0; j < 7; ++j) {
      yb[j] += zb[j];
      kb3[j] += h * zb[j];
      hbar += zb[j] * k3[j];
      zb[j] = T(0);
    }
    // stage 3: z3 = y + h/2 k2
    FT(z3, c1, c2, c3, kb3, zb, cbar);
    for (int j = 0; j < 7; ++j) {
      yb[j] += zb[j];
      kb2[j] += h2 * zb[j];
      hbar += T(0.5) * zb[j] * k2[j];
      zb[j] = T(0);
    }
    // stage 2: z2 = y + h/2 k1
    FT(z2, c1, c2, c3, kb2, zb, cbar);
    for (int j = 0; j < 7; ++j) {
      yb[j] += zb[j];
      kb1[j] += h2 * zb[j];
      hbar += T(0.5) * zb[j] * k1[j];
    }
    // stage 1: z1 = y
    FT(y, c1, c2, c3, kb1, yb, cbar);
    for (int j = 0; j < 7; ++j) lam[j][i] = yb[j];
    for (int j = 0; j < 3; ++j) cb[j][i] += cbar[j];
    hb[i] += hbar;
  }
}

// Cotangents of y0, coef and h from those of ys, for one group of bodies (see Group). Each
// output interval is reversed from its saved start state: its steps are recomputed in segments
// of S (all of them when n ≤ 512, else S ≈ √n with checkpoints between segments).
template <typename T>
void GroupBack(const T* ys, const T* coef, const int32_t* n, const T* h, const T* g, T* y0b,
               T* coefb, T* hb, int64_t first, int64_t count, int64_t B, int64_t K) {
  const int64_t blocks = (count + kBlock - 1) / kBlock;
#pragma omp parallel for schedule(static)
  for (int64_t blk = 0; blk < blocks; ++blk) {
    alignas(64) T x[7][kBlock];
    alignas(64) T C[3][kBlock];
    alignas(64) T lam[7][kBlock];
    alignas(64) T cb[3][kBlock];
    alignas(64) T hsum[kBlock];
    std::vector<T> saved;
    const int64_t start = blk * kBlock, m = std::min(kBlock, count - start);
    int64_t row[kBlock], col[kBlock];
    Place(first, start, m, B, row, col);
    auto at = [&](int64_t i, int64_t k, int j) {
      const int64_t l = row[i], b = col[i];
      return ((l * (K + 1) + k) * 7 + j) * B + b;
    };
    for (int64_t i = 0; i < m; ++i) {
      const int64_t l = row[i], b = col[i];
      for (int j = 0; j < 3; ++j) C[j][i] = coef[(l * 3 + j) * B + b], cb[j][i] = T(0);
      for (int j = 0; j < 7; ++j) lam[j][i] = g[at(i, K, j)];
    }
    for (int64_t k = K - 1; k >= 0; --k) {
      const int64_t steps = n[k];
      const int64_t S = steps <= 512 ? steps : static_cast<int64_t>(std::ceil(std::sqrt(double(steps))));
      const int64_t segments = (steps + S - 1) / S;
      saved.resize(static_cast<size_t>((segments + S) * 7 * kBlock));
      T (*ckpt)[7][kBlock] = reinterpret_cast<T (*)[7][kBlock]>(saved.data());
      T (*states)[7][kBlock] = ckpt + segments;
      for (int64_t i = 0; i < m; ++i)
        for (int j = 0; j < 7; ++j) x[j][i] = ys[at(i, k, j)];
      for (int64_t s = 0; s < segments; ++s) {
        std::memcpy(ckpt[s], x, sizeof(x));
        if (s + 1 < segments) Steps<T>(m, x, C, S, h[k]);
      }
      for (int64_t i = 0; i < m; ++i) hsum[i] = T(0);
      for (int64_t s = segments - 1; s >= 0; --s) {
        const int64_t len = std::min(S, steps - s * S);
        std::memcpy(x, ckpt[s], sizeof(x));
        for (int64_t j = 0; j < len; ++j) {
          std::memcpy(states[j], x, sizeof(x));
          if (j + 1 < len) Steps<T>(m, x, C, 1, h[k]);
        }
        for (int64_t j = len - 1; j >= 0; --j) StepBack<T>(m, states[j], C, h[k], lam, cb, hsum);
      }
      for (int64_t i = 0; i < m; ++i) {
        const int64_t l = row[i], b = col[i];
        hb[(l * K + k) * B + b] = hsum[i];
        for (int j = 0; j < 7; ++j) lam[j][i] += g[at(i, k, j)];
      }
    }
    for (int64_t i = 0; i < m; ++i) {
      const int64_t l = row[i], b = col[i];
      for (int j = 0; j < 7; ++j) y0b[(l * 7 + j) * B + b] = lam[j][i];
      for (int j = 0; j < 3; ++j) coefb[(l * 3 + j) * B + b] = cb[j][i];
    }
  }
}

// Whether the L batch rows share their steps (n, h): then they are one group of L·B bodies.
template <typename T>
bool Shared(const int32_t* n, const T* h, int64_t L, int64_t K) {
  for (int64_t l = 1; l < L; ++l) {
    if (std::memcmp(n, n + l * K, K * sizeof(int32_t)) != 0 ||
        std::memcmp(h, h + l * K, K * sizeof(T)) != 0)
      return false;
  }
  return true;
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
  const bool shared = Shared<T>(nn, hh, L, K);
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


template <ffi::DataType DT>
ffi::Error FreeBodyRK4Back(ffi::Buffer<DT> ys, ffi::Buffer<DT> coef, ffi::Buffer<ffi::S32> n,
                           ffi::Buffer<DT> h, ffi::Buffer<DT> g, ffi::ResultBuffer<DT> y0b,
                           ffi::ResultBuffer<DT> coefb, ffi::ResultBuffer<DT> hb) {
  using T = ffi::NativeType<DT>;
  const auto dims = coef.dimensions();
  if (dims.size() < 2 || dims[dims.size() - 2] != 3) {
    return ffi::Error::InvalidArgument("free_body_rk4_back: coef must have shape (..., 3, B)");
  }
  const int64_t B = dims[dims.size() - 1];
  const int64_t L = static_cast<int64_t>(coef.element_count()) / (3 * B);
  const auto ndims = n.dimensions();
  const int64_t K = ndims.size() == 0 ? 0 : ndims[ndims.size() - 1];
  if (ys.element_count() != static_cast<size_t>(L * (K + 1) * 7 * B) ||
      g.element_count() != ys.element_count() ||
      n.element_count() != static_cast<size_t>(L * K) ||
      h.element_count() != static_cast<size_t>(L * K) ||
      y0b->element_count() != static_cast<size_t>(L * 7 * B) ||
      coefb->element_count() != coef.element_count() ||
      hb->element_count() != static_cast<size_t>(L * K * B)) {
    return ffi::Error::InvalidArgument("free_body_rk4_back: inconsistent shapes");
  }
  const int32_t* nn = n.typed_data();
  const T* hh = h.typed_data();
  if (Shared<T>(nn, hh, L, K)) {
    GroupBack<T>(ys.typed_data(), coef.typed_data(), nn, hh, g.typed_data(), y0b->typed_data(),
                 coefb->typed_data(), hb->typed_data(), 0, L * B, B, K);
  } else {
    for (int64_t l = 0; l < L; ++l) {
      GroupBack<T>(ys.typed_data(), coef.typed_data(), nn + l * K, hh + l * K, g.typed_data(),
                   y0b->typed_data(), coefb->typed_data(), hb->typed_data(), l, B, B, K);
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

XLA_FFI_DEFINE_HANDLER_SYMBOL(RigidjaxFreeBodyRK4BackF64, FreeBodyRK4Back<ffi::F64>,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Arg<ffi::Buffer<ffi::F64>>()
                                  .Ret<ffi::Buffer<ffi::F64>>()
                                  .Ret<ffi::Buffer<ffi::F64>>()
                                  .Ret<ffi::Buffer<ffi::F64>>());

XLA_FFI_DEFINE_HANDLER_SYMBOL(RigidjaxFreeBodyRK4BackF32, FreeBodyRK4Back<ffi::F32>,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::S32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>());

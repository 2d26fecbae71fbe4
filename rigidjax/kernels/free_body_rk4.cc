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
// Shapes (L: leading batch dimensions added by jax.vmap, flattened), in the layout of
// `simulate`'s arguments and trajectory, so that no layout change costs a pass over memory:
//   w0 (L, B, 3), q0 (L, B, 4)  initial Ω and q
//   coef (L, 3, Bc)  c1 c2 c3, per body (Bc = B) or for the whole row (Bc = 1)
//   n (L, K) int32  steps in output interval k;  h (L, K)  their size
//   w (L, B, K + 1, 3), q (L, B, K + 1, 4)  the state at every output time, [:, :, 0] = initial
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

constexpr int64_t kBlock = 64;

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

// One RK4 step of one body from y: the stages k1 … k4, their arguments z2 = y + h/2 k1,
// z3 = y + h/2 k2, z4 = y + h k3, and the end state u before renormalisation.
template <typename T>
inline void Stages(const T* y, T c1, T c2, T c3, T h, T* k1, T* k2, T* k3, T* k4, T* z2, T* z3,
                   T* z4, T* u) {
  const T h2 = T(0.5) * h, h6 = h / T(6);
  F(y, c1, c2, c3, k1);
  for (int j = 0; j < 7; ++j) z2[j] = y[j] + h2 * k1[j];
  F(z2, c1, c2, c3, k2);
  for (int j = 0; j < 7; ++j) z3[j] = y[j] + h2 * k2[j];
  F(z3, c1, c2, c3, k3);
  for (int j = 0; j < 7; ++j) z4[j] = y[j] + h * k3[j];
  F(z4, c1, c2, c3, k4);
  for (int j = 0; j < 7; ++j) u[j] = y[j] + h6 * (k1[j] + T(2) * k2[j] + T(2) * k3[j] + k4[j]);
}

// `steps` RK4 steps of size h on the n ≤ kBlock bodies of x (7 rows of kBlock), coefficients C,
// the quaternion renormalised after each. The loop over bodies is the vectorised one (GCC
// scalarises the small arrays; `omp simd` would privatise them into memory instead).
template <typename T>
void Steps(int64_t n, T (*__restrict x)[kBlock], const T (*__restrict C)[kBlock],
           int64_t steps, T h) {
  for (int64_t s = 0; s < steps; ++s) {
#pragma GCC ivdep
    for (int64_t i = 0; i < n; ++i) {
      T y[7], k1[7], k2[7], k3[7], k4[7], z2[7], z3[7], z4[7], u[7];
      for (int j = 0; j < 7; ++j) y[j] = x[j][i];
      Stages(y, C[0][i], C[1][i], C[2][i], h, k1, k2, k3, k4, z2, z3, z4, u);
      const T r = T(1) / std::sqrt(u[3] * u[3] + u[4] * u[4] + u[5] * u[5] + u[6] * u[6]);
      for (int j = 0; j < 3; ++j) x[j][i] = u[j];
      for (int j = 3; j < 7; ++j) x[j][i] = u[j] * r;
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

// Where a body's data lie: row l, body b (see the shapes above).
struct Layout {
  int64_t B, K, Bc;
  int64_t w0(int64_t l, int64_t b, int j) const { return (l * B + b) * 3 + j; }
  int64_t q0(int64_t l, int64_t b, int j) const { return (l * B + b) * 4 + j; }
  int64_t w(int64_t l, int64_t b, int64_t k, int j) const {
    return ((l * B + b) * (K + 1) + k) * 3 + j;
  }
  int64_t q(int64_t l, int64_t b, int64_t k, int j) const {
    return ((l * B + b) * (K + 1) + k) * 4 + j;
  }
  int64_t c(int64_t l, int64_t b, int j) const { return (l * 3 + j) * Bc + (Bc == 1 ? 0 : b); }
};

// One group of bodies that share their steps (n, h): `count` bodies, body g at batch row
// first + g / B, column g % B.
template <typename T>
void Group(const T* w0, const T* q0, const T* coef, const int32_t* n, const T* h, T* w, T* q,
           int64_t first, int64_t count, const Layout& at) {
  const int64_t blocks = (count + kBlock - 1) / kBlock;
#pragma omp parallel for schedule(static)
  for (int64_t blk = 0; blk < blocks; ++blk) {
    alignas(64) T x[7][kBlock];
    alignas(64) T C[3][kBlock];
    const int64_t start = blk * kBlock, m = std::min(kBlock, count - start);
    int64_t row[kBlock], col[kBlock];
    Place(first, start, m, at.B, row, col);
    for (int64_t i = 0; i < m; ++i) {
      const int64_t l = row[i], b = col[i];
      for (int j = 0; j < 3; ++j) x[j][i] = w0[at.w0(l, b, j)];
      for (int j = 0; j < 4; ++j) x[3 + j][i] = q0[at.q0(l, b, j)];
      for (int j = 0; j < 3; ++j) C[j][i] = coef[at.c(l, b, j)];
    }
    for (int64_t k = 0; k <= at.K; ++k) {
      if (k > 0) Steps<T>(m, x, C, n[k - 1], h[k - 1]);
      for (int64_t i = 0; i < m; ++i) {
        const int64_t l = row[i], b = col[i];
        for (int j = 0; j < 3; ++j) w[at.w(l, b, k, j)] = x[j][i];
        for (int j = 0; j < 4; ++j) q[at.q(l, b, k, j)] = x[3 + j][i];
      }
    }
  }
}

// ---------------------------------------------------------------- reverse mode (adjoint)

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
    Stages(y, c1, c2, c3, h, k1, k2, k3, k4, z2, z3, z4, u);
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

// Cotangents of w0, q0, coef (per body) and h (per body) from those of w, q (gw, gq), for one
// group of bodies (see Group). Each output interval is reversed from its saved start state: its
// steps are recomputed in segments of S (all of them when n ≤ 512, else S ≈ √n with checkpoints
// between segments).
template <typename T>
void GroupBack(const T* w, const T* q, const T* coef, const int32_t* n, const T* h, const T* gw,
               const T* gq, T* w0b, T* q0b, T* coefb, T* hb, int64_t first, int64_t count,
               const Layout& at) {
  const int64_t blocks = (count + kBlock - 1) / kBlock;
  const int64_t K = at.K;
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
    Place(first, start, m, at.B, row, col);
    auto add_cotangent = [&](int64_t k) {
      for (int64_t i = 0; i < m; ++i) {
        const int64_t l = row[i], b = col[i];
        for (int j = 0; j < 3; ++j) lam[j][i] += gw[at.w(l, b, k, j)];
        for (int j = 0; j < 4; ++j) lam[3 + j][i] += gq[at.q(l, b, k, j)];
      }
    };
    for (int64_t i = 0; i < m; ++i) {
      const int64_t l = row[i], b = col[i];
      for (int j = 0; j < 3; ++j) C[j][i] = coef[at.c(l, b, j)], cb[j][i] = T(0);
      for (int j = 0; j < 7; ++j) lam[j][i] = T(0);
    }
    add_cotangent(K);
    for (int64_t k = K - 1; k >= 0; --k) {
      const int64_t steps = n[k];
      const int64_t S =
          steps <= 512 ? steps : static_cast<int64_t>(std::ceil(std::sqrt(double(steps))));
      const int64_t segments = (steps + S - 1) / S;
      saved.resize(static_cast<size_t>((segments + S) * 7 * kBlock));
      T(*ckpt)[7][kBlock] = reinterpret_cast<T(*)[7][kBlock]>(saved.data());
      T(*states)[7][kBlock] = ckpt + segments;
      for (int64_t i = 0; i < m; ++i) {
        const int64_t l = row[i], b = col[i];
        for (int j = 0; j < 3; ++j) x[j][i] = w[at.w(l, b, k, j)];
        for (int j = 0; j < 4; ++j) x[3 + j][i] = q[at.q(l, b, k, j)];
      }
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
      for (int64_t i = 0; i < m; ++i) hb[(row[i] * K + k) * at.B + col[i]] = hsum[i];
      add_cotangent(k);
    }
    for (int64_t i = 0; i < m; ++i) {
      const int64_t l = row[i], b = col[i];
      for (int j = 0; j < 3; ++j) w0b[at.w0(l, b, j)] = lam[j][i];
      for (int j = 0; j < 4; ++j) q0b[at.q0(l, b, j)] = lam[3 + j][i];
      for (int j = 0; j < 3; ++j) coefb[(l * 3 + j) * at.B + b] = cb[j][i];
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

// The batch size L, bodies B, intervals K and coefficient columns Bc of the arguments, or an
// error naming the inconsistency.
template <typename T>
ffi::Error Shapes(size_t w0, size_t q0, const ffi::Span<const int64_t>& cdims, size_t n,
                  size_t h, Layout* at, int64_t* L) {
  if (cdims.size() < 2 || cdims[cdims.size() - 2] != 3) {
    return ffi::Error::InvalidArgument("free_body_rk4: coef must have shape (..., 3, B or 1)");
  }
  const int64_t Bc = cdims[cdims.size() - 1];
  int64_t rows = 1;
  for (size_t i = 0; i + 2 < cdims.size(); ++i) rows *= cdims[i];
  if (rows == 0 || w0 % (3 * rows) != 0 || q0 * 3 != w0 * 4 || n != h || n % rows != 0) {
    return ffi::Error::InvalidArgument("free_body_rk4: inconsistent shapes");
  }
  const int64_t B = static_cast<int64_t>(w0) / (3 * rows);
  if (Bc != 1 && Bc != B) {
    return ffi::Error::InvalidArgument("free_body_rk4: coef must have B or 1 columns");
  }
  *at = Layout{B, static_cast<int64_t>(n) / rows, Bc};
  *L = rows;
  return ffi::Error::Success();
}

template <ffi::DataType DT>
ffi::Error FreeBodyRK4(ffi::Buffer<DT> w0, ffi::Buffer<DT> q0, ffi::Buffer<DT> coef,
                       ffi::Buffer<ffi::S32> n, ffi::Buffer<DT> h, ffi::ResultBuffer<DT> w,
                       ffi::ResultBuffer<DT> q) {
  using T = ffi::NativeType<DT>;
  Layout at;
  int64_t L;
  ffi::Error e = Shapes<T>(w0.element_count(), q0.element_count(), coef.dimensions(),
                           n.element_count(), h.element_count(), &at, &L);
  if (e.failure()) return e;
  if (w->element_count() != static_cast<size_t>(L * at.B * (at.K + 1) * 3) ||
      q->element_count() != static_cast<size_t>(L * at.B * (at.K + 1) * 4)) {
    return ffi::Error::InvalidArgument("free_body_rk4: inconsistent output shapes");
  }
  const int32_t* nn = n.typed_data();
  const T* hh = h.typed_data();
  // Batch rows with the same steps are one group, so that a vmapped single body still fills
  // the vector lanes; rows with their own steps (vmapped output times) go one by one.
  const bool shared = Shared<T>(nn, hh, L, at.K);
  for (int64_t l = 0; l < (shared ? 1 : L); ++l) {
    Group<T>(w0.typed_data(), q0.typed_data(), coef.typed_data(), nn + l * at.K, hh + l * at.K,
             w->typed_data(), q->typed_data(), shared ? 0 : l, shared ? L * at.B : at.B, at);
  }
  return ffi::Error::Success();
}

template <ffi::DataType DT>
ffi::Error FreeBodyRK4Back(ffi::Buffer<DT> w, ffi::Buffer<DT> q, ffi::Buffer<DT> coef,
                           ffi::Buffer<ffi::S32> n, ffi::Buffer<DT> h, ffi::Buffer<DT> gw,
                           ffi::Buffer<DT> gq, ffi::ResultBuffer<DT> w0b,
                           ffi::ResultBuffer<DT> q0b, ffi::ResultBuffer<DT> coefb,
                           ffi::ResultBuffer<DT> hb) {
  using T = ffi::NativeType<DT>;
  Layout at;
  int64_t L;
  ffi::Error e = Shapes<T>(w0b->element_count(), q0b->element_count(), coef.dimensions(),
                           n.element_count(), h.element_count(), &at, &L);
  if (e.failure()) return e;
  const size_t ws = static_cast<size_t>(L * at.B * (at.K + 1) * 3);
  if (w.element_count() != ws || gw.element_count() != ws || q.element_count() * 3 != ws * 4 ||
      gq.element_count() * 3 != ws * 4 ||
      coefb->element_count() != static_cast<size_t>(L * 3 * at.B) ||
      hb->element_count() != static_cast<size_t>(L * at.K * at.B)) {
    return ffi::Error::InvalidArgument("free_body_rk4_back: inconsistent shapes");
  }
  const int32_t* nn = n.typed_data();
  const T* hh = h.typed_data();
  const bool shared = Shared<T>(nn, hh, L, at.K);
  for (int64_t l = 0; l < (shared ? 1 : L); ++l) {
    GroupBack<T>(w.typed_data(), q.typed_data(), coef.typed_data(), nn + l * at.K,
                 hh + l * at.K, gw.typed_data(), gq.typed_data(), w0b->typed_data(),
                 q0b->typed_data(), coefb->typed_data(), hb->typed_data(), shared ? 0 : l,
                 shared ? L * at.B : at.B, at);
  }
  return ffi::Error::Success();
}

}  // namespace

// The forward and reverse handlers for one element type.
#define RJ_HANDLERS(DT)                                                                    \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(RigidjaxFreeBodyRK4##DT, FreeBodyRK4<ffi::DT>,             \
                                ffi::Ffi::Bind()                                           \
                                    .Arg<ffi::Buffer<ffi::DT>>()                           \
                                    .Arg<ffi::Buffer<ffi::DT>>()                           \
                                    .Arg<ffi::Buffer<ffi::DT>>()                           \
                                    .Arg<ffi::Buffer<ffi::S32>>()                          \
                                    .Arg<ffi::Buffer<ffi::DT>>()                           \
                                    .Ret<ffi::Buffer<ffi::DT>>()                           \
                                    .Ret<ffi::Buffer<ffi::DT>>());                         \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(RigidjaxFreeBodyRK4Back##DT, FreeBodyRK4Back<ffi::DT>,     \
                                ffi::Ffi::Bind()                                           \
                                    .Arg<ffi::Buffer<ffi::DT>>()                           \
                                    .Arg<ffi::Buffer<ffi::DT>>()                           \
                                    .Arg<ffi::Buffer<ffi::DT>>()                           \
                                    .Arg<ffi::Buffer<ffi::S32>>()                          \
                                    .Arg<ffi::Buffer<ffi::DT>>()                           \
                                    .Arg<ffi::Buffer<ffi::DT>>()                           \
                                    .Arg<ffi::Buffer<ffi::DT>>()                           \
                                    .Ret<ffi::Buffer<ffi::DT>>()                           \
                                    .Ret<ffi::Buffer<ffi::DT>>()                           \
                                    .Ret<ffi::Buffer<ffi::DT>>()                           \
                                    .Ret<ffi::Buffer<ffi::DT>>())

RJ_HANDLERS(F64);
RJ_HANDLERS(F32);

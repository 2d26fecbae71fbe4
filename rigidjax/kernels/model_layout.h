// The batch layout of rigidjax/kernels/model.cc's kernels, shared by a model's build (its
// steps: model.cc, model_adaptive.h) and the XLA FFI handler that decodes and checks the
// operands (model_ffi.cc, compiled once per kernel and dtype and linked into every model's
// library, so that a model's build parses no XLA header): the rows that jax.vmap adds to every
// operand, the parameter blocks, a block of bodies' setup, the model's sizes (Info) and the
// entry points by which the handler runs its steps.
#pragma once

#include <cstdint>

struct XLA_FFI_Error;
struct XLA_FFI_CallFrame;

#define RJ_HIDDEN __attribute__((visibility("hidden")))

namespace rj {

constexpr int64_t kBlock = 64;  // bodies stepped together (the vectorised loop)
constexpr int kControls = 14;   // the adaptive controller's and event's constants (Ctl)

inline void Place(int64_t first, int64_t start, int64_t m, int64_t B, int64_t* row, int64_t* col) {
  int64_t l = first + start / B, b = start % B;
  for (int64_t i = 0; i < m; ++i) {
    row[i] = l;
    col[i] = b;
    if (++b == B) b = 0, ++l;
  }
}

// jax.vmap adds leading dimensions to every operand ("expand_dims": of size 1 where the
// operand is not mapped, so that shared parameters and steps are never copied per row); the
// output's leading dimensions, flattened, number the rows l.
constexpr int kMaxLead = 8;

struct Rows {
  int nd = 0;
  int64_t dims[kMaxLead] = {};
  int64_t count() const {
    int64_t L = 1;
    for (int d = 0; d < nd; ++d) L *= dims[d];
    return L;
  }
};

// An operand's element strides over the leading dimensions (0 where it has size 1).
struct Lead {
  int64_t s[kMaxLead] = {};
  int64_t at(const Rows& r, int64_t l) const {
    if (r.nd == 1) return l * s[0];  // (one jax.vmap: l is the row)
    int64_t off = 0;
    for (int d = r.nd - 1; d >= 0; --d) {
      off += (l % r.dims[d]) * s[d];
      l /= r.dims[d];
    }
    return off;
  }
  bool shared(const Rows& r) const {
    for (int d = 0; d < r.nd; ++d)
      if (s[d] != 0) return false;
    return true;
  }
};

// A block of parameters (shape (leading…, Bc, Pj)): its data, row strides, stride over the
// bodies (0 for a block shared by a row's bodies), and its components [first, first + width).
// A list of blocks ends with one of width 0.
template <typename T>
struct Param {
  const T* data;
  Lead lead;
  int64_t body;
  int first, width;
};

// The sizes of a model: state N, parameters P (the lifted constants counted), and the
// components [R0, R0 + NR) that its jump map records.
struct Info {
  int N, P, NR;
};

struct Layout {
  int64_t B, K, S, R;  // bodies per row, intervals, saved states, recorded jumps
  int64_t N, NR;       // the model's state and recorded components (Info)
  Rows rows;
  Lead y0, y, gy, steps, jump, save;  // steps: n, h, t0; y, gy: reverse mode's states, cotangents
  int64_t x0(int64_t l, int64_t b, int j) const { return y0.at(rows, l) + b * N + j; }
  int64_t saved(int64_t l, int64_t b, int64_t k, int j) const {
    return y.at(rows, l) + (b * (K + 1) + k) * N + j;
  }
  int64_t cot(int64_t l, int64_t b, int64_t k, int j) const {
    return gy.at(rows, l) + (b * (K + 1) + k) * N + j;
  }
  int64_t out(int64_t l, int64_t b, int64_t k, int j) const {
    return ((l * B + b) * S + k) * N + j;
  }
  int64_t rec(int64_t l, int64_t b, int64_t r, int j) const {
    return ((l * B + b) * R + r) * NR + j;
  }
};

// The parameters of the m bodies at (row, col) into C (P rows of kBlock).
template <typename T>
void Fill(int64_t m, const int64_t* row, const int64_t* col, const Param<T>* prm,
          const Rows& rows, T (*__restrict C)[kBlock]) {
  for (int b = 0; prm[b].width > 0; ++b) {
    const Param<T>& q = prm[b];
    for (int64_t i = 0; i < m; ++i) {
      const T* x = q.data + q.lead.at(rows, row[i]) + col[i] * q.body;
      for (int c = 0; c < q.width; ++c) C[q.first + c][i] = x[c];
    }
  }
}

// The model's build defines ModelInfo and the entry point of its one kernel, for one dtype;
// model_ffi.cc, compiled for the same kernel and dtype, calls it.
RJ_HIDDEN Info ModelInfo();

// Their parameters and arguments, by kernel.
#define RJ_STEPS_ARGS(T)                                                                        \
  (const T* y0, const Param<T>* prm, const int32_t* n, const T* h, const T* t0,                 \
   const int32_t* jump, const int32_t* save, T* y, T* rec, int64_t first, int64_t count,        \
   const Layout& at)
#define RJ_STEPS_CALL (y0, prm, n, h, t0, jump, save, y, rec, first, count, at)
#define RJ_STEPS_BACK_ARGS(T)                                                                   \
  (const T* y, const Param<T>* prm, const int32_t* n, const T* h, const T* t0,                  \
   const int32_t* jump, const T* gy, T* y0b, T* pb, T* hb, T* tb, int64_t first, int64_t count, \
   const Layout& at)
#define RJ_STEPS_BACK_CALL (y, prm, n, h, t0, jump, gy, y0b, pb, hb, tb, first, count, at)
#define RJ_ADAPTIVE_ARGS(T)                                                                     \
  (const Layout& at, const Param<T>* prm, const Lead& tl, const Lead& cl, const T* y0,          \
   const T* ts, const int32_t* jump, const int32_t* save, const T* ctl, T* y, T* rec, T* hk,    \
   int32_t* st, T* ev)
#define RJ_ADAPTIVE_CALL (at, prm, tl, cl, y0, ts, jump, save, ctl, y, rec, hk, st, ev)
#define RJ_ADAPTIVE_BACK_ARGS(T)                                                                \
  (const Layout& at, const Param<T>* prm, const Lead& tl, const Lead& cl, const Lead& hl,       \
   const T* y, const T* ts, const int32_t* jump, const T* ctl, const T* hk, const T* gy,        \
   T* y0b, T* pb)
#define RJ_ADAPTIVE_BACK_CALL (at, prm, tl, cl, hl, y, ts, jump, ctl, hk, gy, y0b, pb)

// RunSteps: fixed steps (model.cc's Group) of the bodies [first, first + count) that share
// their steps; RunStepsBack: their reverse mode (GroupBack); RunAdaptive: adaptive steps of
// every body (model_adaptive.h; tl, cl: the strides of ts and ctl); RunAdaptiveBack: their
// reverse mode (hl: the strides of hk).
#define RJ_ENTRY_POINTS(T)                        \
  RJ_HIDDEN void RunSteps RJ_STEPS_ARGS(T);        \
  RJ_HIDDEN void RunStepsBack RJ_STEPS_BACK_ARGS(T); \
  RJ_HIDDEN void RunAdaptive RJ_ADAPTIVE_ARGS(T);  \
  RJ_HIDDEN void RunAdaptiveBack RJ_ADAPTIVE_BACK_ARGS(T);
RJ_ENTRY_POINTS(float)
RJ_ENTRY_POINTS(double)

}  // namespace rj

// model_ffi.cc's handler (XLA's FFI calling convention), per kernel and dtype; a model's
// library exports it under the kernel's own name (model.cc's RJ_KERNEL).
#define RJ_HANDLERS(DT)                                                     \
  extern "C" RJ_HIDDEN XLA_FFI_Error* RjSteps##DT(XLA_FFI_CallFrame*);      \
  extern "C" RJ_HIDDEN XLA_FFI_Error* RjStepsBack##DT(XLA_FFI_CallFrame*);  \
  extern "C" RJ_HIDDEN XLA_FFI_Error* RjAdaptive##DT(XLA_FFI_CallFrame*);   \
  extern "C" RJ_HIDDEN XLA_FFI_Error* RjAdaptiveBack##DT(XLA_FFI_CallFrame*);
RJ_HANDLERS(F32)
RJ_HANDLERS(F64)

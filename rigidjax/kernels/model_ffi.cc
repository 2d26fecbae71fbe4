// The XLA FFI handlers of rigidjax/kernels/model.cc's kernels: each decodes its operands, checks
// their shapes against the model's sizes (rj::ModelInfo) and runs the model's steps through
// the entry points of model_layout.h. Nothing here depends on a model, so this file is compiled
// once (rigidjax/kernels/_build.py) and linked into every model's library; a model's own build
// then parses no XLA header (measured: about half of a model's build time).
//
// Handlers, each for float32 and float64 (RjSteps##DT, …; model.cc exports its kernel's under
// the kernel's name):
//   RjSteps         fixed steps: y0, n, h, t0, jump, save, blocks… -> y, rec
//   RjStepsBack     their reverse mode: y, n, h, t0, jump, save, gy, blocks… -> y0b, pb, hb, tb
//   RjAdaptive      adaptive steps: y0, ts, jump, save, ctl, blocks… -> y, rec, hk, st, ev
//   RjAdaptiveBack  their reverse mode: y, ts, jump, save, ctl, hk, gy, blocks… -> y0b, pb
// (the shapes: model.cc and model_adaptive.h).
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "model_layout.h"
#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace rj {
namespace {

// The strides of an operand of shape (leading…, base…) with `base` trailing dimensions; false
// where its leading dimensions are neither the output's nor 1.
bool Strides(const Rows& r, ffi::Span<const int64_t> dims, size_t base, Lead* lead) {
  if (dims.size() != static_cast<size_t>(r.nd) + base) return false;
  int64_t inner = 1;
  for (size_t i = r.nd; i < dims.size(); ++i) inner *= dims[i];
  for (int d = r.nd - 1; d >= 0; --d) {
    if (dims[d] != r.dims[d] && dims[d] != 1) return false;
    lead->s[d] = dims[d] == 1 ? 0 : inner;
    inner *= dims[d];
  }
  return true;
}

// Whether the rows share their steps (n, h, t0, jump, save): then they are one group of L·B
// bodies (a vmapped single body still fills the vector lanes).
template <typename T>
bool Shared(const int32_t* n, const T* h, const T* t0, const int32_t* jump, const int32_t* save,
            const Layout& at) {
  const Rows& r = at.rows;
  if (at.steps.shared(r) && at.jump.shared(r) && at.save.shared(r)) return true;
  const int64_t K = at.K, s0 = at.steps.at(r, 0), j0 = at.jump.at(r, 0), v0 = at.save.at(r, 0);
  for (int64_t l = 1; l < r.count(); ++l) {
    const int64_t s = at.steps.at(r, l), j = at.jump.at(r, l), v = at.save.at(r, l);
    if (std::memcmp(n + s0, n + s, K * sizeof(int32_t)) != 0 ||
        std::memcmp(jump + j0, jump + j, K * sizeof(int32_t)) != 0 ||
        std::memcmp(save + v0, save + v, (K + 1) * sizeof(int32_t)) != 0 ||
        std::memcmp(h + s0, h + s, K * sizeof(T)) != 0 ||
        std::memcmp(t0 + s0, t0 + s, K * sizeof(T)) != 0)
      return false;
  }
  return true;
}

// run(steps, jump, save, first, count) for each group of bodies that share their steps: all
// L·B bodies when the rows share them, else row by row; steps, jump and save are the group's
// offsets in (n, h, t0), jump and save.
template <typename T, class Run>
void ForEachGroup(const int32_t* n, const T* h, const T* t0, const int32_t* jump,
                  const int32_t* save, const Layout& at, Run run) {
  const Rows& r = at.rows;
  const int64_t L = r.count();
  if (Shared<T>(n, h, t0, jump, save, at)) {
    run(at.steps.at(r, 0), at.jump.at(r, 0), at.save.at(r, 0), 0, L * at.B);
    return;
  }
  for (int64_t l = 0; l < L; ++l) run(at.steps.at(r, l), at.jump.at(r, l), at.save.at(r, l), l, at.B);
}

// The layout from the operands' shapes (`lead`: an output with `base` trailing dimensions
// (B, …), whose leading ones are the rows), and the parameter components from the blocks
// (prm: P + 1 entries, the list ended by one of width 0).
template <ffi::DataType DT>
ffi::Error Shapes(const Info& info, ffi::Span<const int64_t> lead, size_t base,
                  ffi::Span<const int64_t> x0, size_t x0_base, ffi::Span<const int64_t> n,
                  ffi::Span<const int64_t> h, ffi::Span<const int64_t> t0,
                  ffi::Span<const int64_t> jump, ffi::Span<const int64_t> save,
                  const ffi::RemainingArgs& blocks, Layout* at,
                  std::vector<Param<ffi::NativeType<DT>>>* prm) {
  const auto bad = [](const char* what) {
    return ffi::Error::InvalidArgument(std::string("model kernel: ") + what);
  };
  if (lead.size() < base || lead.size() - base > static_cast<size_t>(kMaxLead)) {
    return bad("too many mapped dimensions");
  }
  Rows& r = at->rows;
  r.nd = static_cast<int>(lead.size() - base);
  for (int d = 0; d < r.nd; ++d) r.dims[d] = lead[d];
  at->B = lead[r.nd];
  at->K = n.size() == 0 ? 0 : n.back();
  at->N = info.N;
  at->NR = info.NR;
  if (x0.size() != r.nd + x0_base || x0[r.nd] != at->B || x0.back() != info.N ||
      !Strides(r, x0, x0_base, x0_base == 2 ? &at->y0 : &at->y) ||
      !Strides(r, n, 1, &at->steps) || !(n == h) || !(n == t0) ||
      !Strides(r, jump, 1, &at->jump) || jump.back() != at->K ||
      !Strides(r, save, 1, &at->save) || save.back() != at->K + 1) {
    return bad("inconsistent shapes of y0, n, h, t0, jump and save");
  }
  prm->assign(info.P + 1, {});
  int j = 0, used = 0;
  for (size_t i = 0; i < blocks.size(); ++i) {
    auto block = blocks.get<ffi::Buffer<DT>>(i);
    if (block.has_error()) return block.error();
    const auto dims = block->dimensions();
    Lead rows;
    if (!Strides(r, dims, 2, &rows) || (dims[r.nd] != 1 && dims[r.nd] != at->B) ||
        j + dims[r.nd + 1] > info.P) {
      return bad("parameter blocks must have shape (B or 1, Pj), Σ Pj = P");
    }
    const int width = static_cast<int>(dims[r.nd + 1]);
    if (width == 0) continue;
    (*prm)[used++] = {block->typed_data(), rows, dims[r.nd] == 1 ? 0 : width, j, width};
    j += width;
  }
  if (j != info.P) return bad("parameter blocks must have shape (B or 1, Pj), Σ Pj = P");
  return ffi::Error::Success();
}

ffi::Error Unbuilt() {
  return ffi::Error::Internal("model kernel: this library holds another kernel");
}

// What both fixed-step handlers do: the layout and parameter blocks from the operands' shapes,
// the handler's own checks (check(at): an error, or success), then group(prm, n, h, t0, jump,
// save, first, count, at) for each group of rows that share their steps.
template <ffi::DataType DT, typename Check, typename G>
ffi::Error Handle(ffi::Span<const int64_t> lead, size_t base, ffi::Span<const int64_t> x0,
                  size_t xbase, ffi::Buffer<ffi::S32> n, ffi::Buffer<DT> h, ffi::Buffer<DT> t0,
                  ffi::Buffer<ffi::S32> jump, ffi::Buffer<ffi::S32> save,
                  ffi::RemainingArgs blocks, Check check, G group) {
  using T = ffi::NativeType<DT>;
  Layout at;
  std::vector<Param<T>> prm;
  ffi::Error e = Shapes<DT>(ModelInfo(), lead, base, x0, xbase, n.dimensions(), h.dimensions(),
                            t0.dimensions(), jump.dimensions(), save.dimensions(), blocks, &at,
                            &prm);
  if (e.failure()) return e;
  e = check(at);
  if (e.failure()) return e;
  const int32_t *nn = n.typed_data(), *jj = jump.typed_data(), *ss = save.typed_data();
  const T *hh = h.typed_data(), *tt = t0.typed_data();
  ForEachGroup(nn, hh, tt, jj, ss, at,
               [&](int64_t s, int64_t sj, int64_t sv, int64_t first, int64_t count) {
                 group(prm.data(), nn + s, hh + s, tt + s, jj + sj, ss + sv, first, count, at);
               });
  return ffi::Error::Success();
}

// The entry points of the model's build for a dtype (null where it built another kernel).
template <ffi::DataType DT>
struct Entry;
template <>
struct Entry<ffi::F32> {
  static auto steps() { return &StepsF32; }
  static auto back() { return &StepsBackF32; }
  static auto adaptive() { return &AdaptiveF32; }
  static auto adaptive_back() { return &AdaptiveBackF32; }
};
template <>
struct Entry<ffi::F64> {
  static auto steps() { return &StepsF64; }
  static auto back() { return &StepsBackF64; }
  static auto adaptive() { return &AdaptiveF64; }
  static auto adaptive_back() { return &AdaptiveBackF64; }
};

template <ffi::DataType DT>
ffi::Error ModelSteps(ffi::Buffer<DT> y0, ffi::Buffer<ffi::S32> n, ffi::Buffer<DT> h,
                      ffi::Buffer<DT> t0, ffi::Buffer<ffi::S32> jump, ffi::Buffer<ffi::S32> save,
                      ffi::RemainingArgs blocks, ffi::ResultBuffer<DT> y,
                      ffi::ResultBuffer<DT> rec) {
  using T = ffi::NativeType<DT>;
  const auto run = Entry<DT>::steps();
  if (run == nullptr) return Unbuilt();
  auto check = [&](Layout& at) {
    const auto yd = y->dimensions(), rd = rec->dimensions();
    const int nd = at.rows.nd;
    at.S = yd[nd + 1];
    at.R = rd.size() == yd.size() ? rd[nd + 1] : -1;
    if (yd[nd + 2] != at.N || at.R < 0 || rd[nd] != at.B || rd[nd + 2] != at.NR) {
      return ffi::Error::InvalidArgument("model kernel: inconsistent output shapes");
    }
    return ffi::Error::Success();
  };
  auto group = [&](const Param<T>* prm, const int32_t* nn, const T* hh, const T* tt,
                   const int32_t* jj, const int32_t* ss, int64_t first, int64_t count,
                   const Layout& at) {
    run(y0.typed_data(), prm, nn, hh, tt, jj, ss, y->typed_data(), rec->typed_data(), first,
        count, at);
  };
  return Handle<DT>(y->dimensions(), 3, y0.dimensions(), 2, n, h, t0, jump, save, blocks, check,
                    group);
}

template <ffi::DataType DT>
ffi::Error ModelStepsBack(ffi::Buffer<DT> y, ffi::Buffer<ffi::S32> n, ffi::Buffer<DT> h,
                          ffi::Buffer<DT> t0, ffi::Buffer<ffi::S32> jump,
                          ffi::Buffer<ffi::S32> save, ffi::Buffer<DT> gy,
                          ffi::RemainingArgs blocks, ffi::ResultBuffer<DT> y0b,
                          ffi::ResultBuffer<DT> pb, ffi::ResultBuffer<DT> hb,
                          ffi::ResultBuffer<DT> tb) {
  using T = ffi::NativeType<DT>;
  const auto run = Entry<DT>::back();
  if (run == nullptr) return Unbuilt();
  const int P = ModelInfo().P;
  auto check = [&](Layout& at) {
    at.S = at.K + 1;
    at.R = 0;
    const size_t rows = static_cast<size_t>(at.rows.count() * at.B);
    if (y.dimensions()[at.rows.nd + 1] != at.K + 1 ||
        !Strides(at.rows, gy.dimensions(), 3, &at.gy) ||
        !std::equal(y.dimensions().begin() + at.rows.nd, y.dimensions().end(),
                    gy.dimensions().begin() + at.rows.nd, gy.dimensions().end()) ||
        pb->element_count() != rows * P || hb->element_count() != rows * at.K ||
        tb->element_count() != rows * at.K) {
      return ffi::Error::InvalidArgument("model kernel (reverse): inconsistent shapes");
    }
    return ffi::Error::Success();
  };
  auto group = [&](const Param<T>* prm, const int32_t* nn, const T* hh, const T* tt,
                   const int32_t* jj, const int32_t*, int64_t first, int64_t count,
                   const Layout& at) {
    run(y.typed_data(), prm, nn, hh, tt, jj, gy.typed_data(), y0b->typed_data(),
        pb->typed_data(), hb->typed_data(), tb->typed_data(), first, count, at);
  };
  return Handle<DT>(y0b->dimensions(), 2, y.dimensions(), 3, n, h, t0, jump, save, blocks, check,
                    group);
}

// The checks and strides both adaptive handlers share: Shapes with jump standing for the
// fixed steps' n, h and t0, and the strides of ts and ctl.
template <ffi::DataType DT>
ffi::Error AdaptiveShapes(ffi::Span<const int64_t> lead, size_t base, ffi::Span<const int64_t> x0,
                          size_t xbase, ffi::Buffer<DT>& ts, ffi::Buffer<ffi::S32>& jump,
                          ffi::Buffer<ffi::S32>& save, ffi::Buffer<DT>& ctl,
                          const ffi::RemainingArgs& blocks, Layout* at, Lead* tl, Lead* cl,
                          std::vector<Param<ffi::NativeType<DT>>>* prm) {
  const auto jd = jump.dimensions();
  ffi::Error e = Shapes<DT>(ModelInfo(), lead, base, x0, xbase, jd, jd, jd, jd, save.dimensions(),
                            blocks, at, prm);
  if (e.failure()) return e;
  if (!Strides(at->rows, ts.dimensions(), 1, tl) || ts.dimensions().back() != at->K + 1 ||
      !Strides(at->rows, ctl.dimensions(), 1, cl) || ctl.dimensions().back() != kControls) {
    return ffi::Error::InvalidArgument("adaptive model kernel: inconsistent shapes of ts, ctl");
  }
  return ffi::Error::Success();
}

template <ffi::DataType DT>
ffi::Error AdaptiveSteps(ffi::Buffer<DT> y0, ffi::Buffer<DT> ts, ffi::Buffer<ffi::S32> jump,
                         ffi::Buffer<ffi::S32> save, ffi::Buffer<DT> ctl,
                         ffi::RemainingArgs blocks, ffi::ResultBuffer<DT> y,
                         ffi::ResultBuffer<DT> rec, ffi::ResultBuffer<DT> hk,
                         ffi::ResultBuffer<ffi::S32> st, ffi::ResultBuffer<DT> ev) {
  using T = ffi::NativeType<DT>;
  const auto run = Entry<DT>::adaptive();
  if (run == nullptr) return Unbuilt();
  Layout at;
  Lead tl, cl;
  std::vector<Param<T>> prm;
  ffi::Error e = AdaptiveShapes<DT>(y->dimensions(), 3, y0.dimensions(), 2, ts, jump, save, ctl,
                                    blocks, &at, &tl, &cl, &prm);
  if (e.failure()) return e;
  const auto yd = y->dimensions(), rd = rec->dimensions();
  const int nd = at.rows.nd;
  at.S = yd[nd + 1];
  at.R = rd.size() == yd.size() ? rd[nd + 1] : -1;
  const size_t bodies = static_cast<size_t>(at.rows.count() * at.B);
  if (yd[nd + 2] != at.N || at.R < 0 || rd[nd] != at.B || rd[nd + 2] != at.NR ||
      hk->element_count() != bodies * at.K || st->element_count() != bodies * 5 ||
      ev->element_count() != bodies) {
    return ffi::Error::InvalidArgument("adaptive model kernel: inconsistent output shapes");
  }
  run(at, prm.data(), tl, cl, y0.typed_data(), ts.typed_data(), jump.typed_data(),
      save.typed_data(), ctl.typed_data(), y->typed_data(), rec->typed_data(), hk->typed_data(),
      st->typed_data(), ev->typed_data());
  return ffi::Error::Success();
}

template <ffi::DataType DT>
ffi::Error AdaptiveStepsBack(ffi::Buffer<DT> y, ffi::Buffer<DT> ts, ffi::Buffer<ffi::S32> jump,
                             ffi::Buffer<ffi::S32> save, ffi::Buffer<DT> ctl,
                             ffi::Buffer<DT> hk, ffi::Buffer<DT> gy, ffi::RemainingArgs blocks,
                             ffi::ResultBuffer<DT> y0b, ffi::ResultBuffer<DT> pb) {
  using T = ffi::NativeType<DT>;
  const auto run = Entry<DT>::adaptive_back();
  if (run == nullptr) return Unbuilt();
  Layout at;
  Lead tl, cl, hl;
  std::vector<Param<T>> prm;
  ffi::Error e = AdaptiveShapes<DT>(y0b->dimensions(), 2, y.dimensions(), 3, ts, jump, save, ctl,
                                    blocks, &at, &tl, &cl, &prm);
  if (e.failure()) return e;
  at.S = at.K + 1;
  at.R = 0;
  const size_t rows = static_cast<size_t>(at.rows.count() * at.B);
  if (y.dimensions()[at.rows.nd + 1] != at.K + 1 || !Strides(at.rows, gy.dimensions(), 3, &at.gy) ||
      !std::equal(y.dimensions().begin() + at.rows.nd, y.dimensions().end(),
                  gy.dimensions().begin() + at.rows.nd, gy.dimensions().end()) ||
      !Strides(at.rows, hk.dimensions(), 2, &hl) ||
      pb->element_count() != rows * ModelInfo().P) {
    return ffi::Error::InvalidArgument("adaptive model kernel (reverse): inconsistent shapes");
  }
  run(at, prm.data(), tl, cl, hl, y.typed_data(), ts.typed_data(), jump.typed_data(),
      ctl.typed_data(), hk.typed_data(), gy.typed_data(), y0b->typed_data(), pb->typed_data());
  return ffi::Error::Success();
}

// The fixed-step handlers' leading operands: y0 (forward) or y (reverse mode), n, h, t0, jump,
// save; the adaptive ones': y0 or y, ts, jump, save, ctl.
template <ffi::DataType DT>
auto BindSteps() {
  return ffi::Ffi::Bind()
      .template Arg<ffi::Buffer<DT>>()
      .template Arg<ffi::Buffer<ffi::S32>>()
      .template Arg<ffi::Buffer<DT>>()
      .template Arg<ffi::Buffer<DT>>()
      .template Arg<ffi::Buffer<ffi::S32>>()
      .template Arg<ffi::Buffer<ffi::S32>>();
}

template <ffi::DataType DT>
auto BindAdaptive() {
  return ffi::Ffi::Bind()
      .template Arg<ffi::Buffer<DT>>()
      .template Arg<ffi::Buffer<DT>>()
      .template Arg<ffi::Buffer<ffi::S32>>()
      .template Arg<ffi::Buffer<ffi::S32>>()
      .template Arg<ffi::Buffer<DT>>();
}

}  // namespace
}  // namespace rj

#define RJ_DEFINE_HANDLERS(DT)                                                               \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(RjSteps##DT, (rj::ModelSteps<ffi::DT>),                     \
                                rj::BindSteps<ffi::DT>()                                    \
                                    .RemainingArgs()                                        \
                                    .Ret<ffi::Buffer<ffi::DT>>()                            \
                                    .Ret<ffi::Buffer<ffi::DT>>());                          \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(RjStepsBack##DT, (rj::ModelStepsBack<ffi::DT>),             \
                                rj::BindSteps<ffi::DT>()                                    \
                                    .Arg<ffi::Buffer<ffi::DT>>()                            \
                                    .RemainingArgs()                                        \
                                    .Ret<ffi::Buffer<ffi::DT>>()                            \
                                    .Ret<ffi::Buffer<ffi::DT>>()                            \
                                    .Ret<ffi::Buffer<ffi::DT>>()                            \
                                    .Ret<ffi::Buffer<ffi::DT>>());                          \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(RjAdaptive##DT, (rj::AdaptiveSteps<ffi::DT>),               \
                                rj::BindAdaptive<ffi::DT>()                                 \
                                    .RemainingArgs()                                        \
                                    .Ret<ffi::Buffer<ffi::DT>>()                            \
                                    .Ret<ffi::Buffer<ffi::DT>>()                            \
                                    .Ret<ffi::Buffer<ffi::DT>>()                            \
                                    .Ret<ffi::Buffer<ffi::S32>>()                           \
                                    .Ret<ffi::Buffer<ffi::DT>>());                          \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(RjAdaptiveBack##DT, (rj::AdaptiveStepsBack<ffi::DT>),       \
                                rj::BindAdaptive<ffi::DT>()                                 \
                                    .Arg<ffi::Buffer<ffi::DT>>()                            \
                                    .Arg<ffi::Buffer<ffi::DT>>()                            \
                                    .RemainingArgs()                                        \
                                    .Ret<ffi::Buffer<ffi::DT>>()                            \
                                    .Ret<ffi::Buffer<ffi::DT>>());

RJ_DEFINE_HANDLERS(F32)
RJ_DEFINE_HANDLERS(F64)

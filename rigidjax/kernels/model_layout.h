// The batch layout of rigidjax/kernels/model.cc (included there after kBlock, N, P and the
// generated model.h): the rows that jax.vmap adds to every operand, the parameter blocks, the
// per-call setup of a block of bodies, the groups of bodies that share their steps, and the
// operands' shapes checked into a Layout; and the two handlers' bindings (RJ_FORWARD,
// RJ_BACKWARD). Included inside model.cc's anonymous namespace.
#pragma once

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

// A block of parameters (shape (leading…, Bc, Pj)): its data, row strides, stride over the
// bodies (0 for a block shared by a row's bodies), and its components [first, first + width).
template <typename T>
struct Param {
  const T* data;
  Lead lead;
  int64_t body;
  int first, width;
};

// At most one block per parameter component (an empty block has none).
constexpr int kBlocks = P;

struct Layout {
  int64_t B, K, S, R;  // bodies per row, intervals, saved states, recorded jumps
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
    return ((l * B + b) * R + r) * Model::NR + j;
  }
};

// The parameters of the m bodies at (row, col) into C (P rows of kBlock).
template <typename T>
void Fill(int64_t m, const int64_t* row, const int64_t* col, const Param<T>* prm,
          const Rows& rows, T (*__restrict C)[kBlock]) {
  for (int b = 0; b < kBlocks && prm[b].width > 0; ++b) {
    const Param<T>& q = prm[b];
    for (int64_t i = 0; i < m; ++i) {
      const T* x = q.data + q.lead.at(rows, row[i]) + col[i] * q.body;
      for (int c = 0; c < q.width; ++c) C[q.first + c][i] = x[c];
    }
  }
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
// (B, …), whose leading ones are the rows), and the parameter components from the blocks.
template <ffi::DataType DT>
ffi::Error Shapes(ffi::Span<const int64_t> lead, size_t base, ffi::Span<const int64_t> x0,
                  size_t x0_base, ffi::Span<const int64_t> n, ffi::Span<const int64_t> h,
                  ffi::Span<const int64_t> t0, ffi::Span<const int64_t> jump,
                  ffi::Span<const int64_t> save, const ffi::RemainingArgs& blocks, Layout* at,
                  Param<ffi::NativeType<DT>>* prm) {
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
  if (x0.size() != r.nd + x0_base || x0[r.nd] != at->B || x0.back() != N ||
      !Strides(r, x0, x0_base, x0_base == 2 ? &at->y0 : &at->y) ||
      !Strides(r, n, 1, &at->steps) || !(n == h) || !(n == t0) ||
      !Strides(r, jump, 1, &at->jump) || jump.back() != at->K ||
      !Strides(r, save, 1, &at->save) || save.back() != at->K + 1) {
    return bad("inconsistent shapes of y0, n, h, t0, jump and save");
  }
  int j = 0, used = 0;
  for (size_t i = 0; i < blocks.size(); ++i) {
    auto block = blocks.get<ffi::Buffer<DT>>(i);
    if (block.has_error()) return block.error();
    const auto dims = block->dimensions();
    Lead rows;
    if (!Strides(r, dims, 2, &rows) || (dims[r.nd] != 1 && dims[r.nd] != at->B) ||
        j + dims[r.nd + 1] > Model::P) {
      return bad("parameter blocks must have shape (B or 1, Pj), Σ Pj = P");
    }
    const int width = static_cast<int>(dims[r.nd + 1]);
    if (width == 0) continue;
    prm[used++] = {block->typed_data(), rows, dims[r.nd] == 1 ? 0 : width, j, width};
    j += width;
  }
  if (used < kBlocks) prm[used].width = 0;  // the end of the list
  if (j != Model::P) return bad("parameter blocks must have shape (B or 1, Pj), Σ Pj = P");
  return ffi::Error::Success();
}

// The one handler of this build, named by model.h: the forward steps (RJ_FORWARD), or their
// reverse mode (RJ_BACKWARD), built separately on the first gradient, so that a first forward
// call compiles only the forward templates.
// Both handlers' leading operands: y0 (forward) or y (reverse mode), n, h, t0, jump, save.
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

#define RJ_FORWARD(NAME, DT)                                                                    \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(                                                                \
      NAME, (ModelSteps<ffi::DT>),                                                              \
      BindSteps<ffi::DT>().RemainingArgs().Ret<ffi::Buffer<ffi::DT>>().Ret<ffi::Buffer<ffi::DT>>());
#define RJ_BACKWARD(NAME, DT)                                               \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(NAME, (ModelStepsBack<ffi::DT>),            \
                                BindSteps<ffi::DT>()                        \
                                    .Arg<ffi::Buffer<ffi::DT>>()            \
                                    .RemainingArgs()                        \
                                    .Ret<ffi::Buffer<ffi::DT>>()            \
                                    .Ret<ffi::Buffer<ffi::DT>>()            \
                                    .Ret<ffi::Buffer<ffi::DT>>()            \
                                    .Ret<ffi::Buffer<ffi::DT>>());

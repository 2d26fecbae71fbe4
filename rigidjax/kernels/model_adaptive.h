// Adaptive steps of an embedded explicit Runge–Kutta pair on rigidjax/kernels/model.cc's model,
// each body its own step size: Diffrax's PIDController, step for step (included at the end of
// model.cc's anonymous namespace in the builds whose model.h defines RJ_ADAPTIVE).
//
//   Tab (model.h)  all S stages (none dropped: the last one feeds the error estimate), row S
//                  the weights b_l, row S + 1 the error weights e_l
//   one attempt    u = y + h Σ b_l k_l, its unit groups normalised, then E;  err = h Σ e_l k_l
//   scaled error   ε = RMS_j err_j / (atol + rtol max(|y_j|, |u_j|))  (u ← y where u has NaN,
//                  err_j NaN ← ∞)
//   accept         ε < 1;  next size h' = h · clip(safety ε^−β1 ε_prev^−β2 ε_prev2^−β3,
//                  accepted: [1, factormax], rejected: [factormin, safety]), min(h', dtmax)
//                  (the PID step-size control of Söderlind, "Digital filters in adaptive
//                  time-stepping", ACM TOMS 29, 2003, in Diffrax's form (4), pid.py)
//   the end        a proposal within 100 ulp of the interval's end t1 becomes t1 (accepted)
//                  or halves the rest (rejected), as `diffrax.diffeqsolve`
//   intervals      one solve per output interval [ts[k], ts[k+1]] from the previous one's mean
//                  accepted step (the first from dt0 or Hairer's initial-step heuristic; a model
//                  with a jump map from dt0 or the heuristic at every interval); at most
//                  max_steps attempts each; a non-finite state is not integrated further
//
//   an event      (Model::G, with Model::kEvent) after each accepted step where the condition's
//                 sign changes in its direction, as Diffrax decides it: its time located on the
//                 step (Locate: the Illinois method, Dowell & Jarratt, BIT 11, 1971); a
//                 terminating event stops the body, its later states held (no later jump)
//   fixed steps   with Tab::kFixed (the tableau of model.cc's fixed steps, no error weights):
//                 each body its own fixed steps (Fixed: those of model.cc's Steps), for an
//                 event, which model.cc's bodies in lockstep cannot stop at
//
// Shapes (leading…: as model.cc): y0 (…, B, N);  ts (…, T);  jump (…, T − 1) int32 as model.cc's;
// save (…, T) int32 0 or 1 + the slot of y;  ctl (…, kControls) the controller and event (Ctl);
// blocks as model.cc. Forward: y (L…, B, S, N), rec (L…, B, R, NR), hk (L…, B, T − 1) each
// interval's first step, st (L…, B, 5) int32 (attempts, accepted, rejected, valid output times,
// result: 0 successful, 1 max_steps reached, 2 non-finite), ev (L…, B) the first event's time
// (∞: none). Reverse: from y (…, B, T, N) (every state), ts, jump,
// save, ctl, hk (…, B, T − 1), gy (…, B, T, N) and the blocks, y0b (L…, B, N), pb (L…, B, P):
// the discrete adjoint of the accepted steps (the step sizes are constants, as Diffrax's
// `stop_gradient` of the controller makes them), recomputed interval by interval.
#pragma once

template <typename T>
struct Ctl {
  T rtol, atol, safety, fmin, fmax, dtmax, dt0, c1, c2, c3, inv_order;
  int64_t max_steps;
  int direction;   // of the event (Model::G): 0 either, 1 rising, −1 falling
  bool terminate;  // the event stops the body
  explicit Ctl(const T* c)
      : rtol(c[0]), atol(c[1]), safety(c[2]), fmin(c[3]), fmax(c[4]), dtmax(c[5]), dt0(c[6]),
        c1(c[7]), c2(c[8]), c3(c[9]), inv_order(c[10]), max_steps(static_cast<int64_t>(c[11])),
        direction(static_cast<int>(c[12])), terminate(c[13] != T(0)) {}
};

// The event of one body: the condition's value at the current state, and the first event's
// time (∞ until it happens); `stopped` once a terminating event happened.
template <typename T>
struct Watch {
  T g = T(0), time = std::numeric_limits<T>::infinity();
  bool stopped = false;
};

template <typename T>
RJ_INLINE T Condition(T t, const T* y, const T* p) {
  T g[1];
  Model::G(t, y, p, g);
  return g[0];
}

template <typename T>
RJ_INLINE int Sign(T x) {
  return (x > T(0)) - (x < T(0));
}

// Whether the condition's change from g0 to g1 is an event, as Diffrax decides it.
template <typename T>
RJ_INLINE bool Crossed(int direction, T g0, T g1) {
  if (direction == 0) return Sign(g0) != Sign(g1);
  if (direction > 0) return Sign(g0) <= 0 && Sign(g1) > 0;
  return Sign(g0) > 0 && Sign(g1) <= 0;
}

template <typename T>
RJ_INLINE T Rms(T s) {
  return std::sqrt(s / T(N));
}

template <typename T>
RJ_INLINE bool Finite(const T* y) {
  bool ok = true;
  RJ_UNROLL
  for (int j = 0; j < N; ++j) ok &= std::isfinite(y[j]);
  return ok;
}

// Diffrax's `_select_initial_step` (Hairer, Nørsett & Wanner, Solving Ordinary Differential
// Equations I, 2nd ed., II.4 "Starting step size") from y at t: the first step's size.
template <typename T>
T InitialStep(const Ctl<T>& c, const T* y, const T* p, T t) {
  T scale[N], f0[N], f1[N], y1[N];
  T a = T(0), b = T(0);
  Model::F(t, y, p, f0);
  RJ_UNROLL
  for (int j = 0; j < N; ++j) {
    scale[j] = c.atol + std::abs(y[j]) * c.rtol;
    const T u = y[j] / scale[j], v = f0[j] / scale[j];
    a += u * u;
    b += v * v;
  }
  const T d0 = Rms(a), d1 = Rms(b);
  const bool small = d0 < T(1e-5) || d1 < T(1e-5);
  const T h0 = small ? T(1e-6) : T(0.01) * (d0 / d1);
  RJ_UNROLL
  for (int j = 0; j < N; ++j) y1[j] = y[j] + h0 * f0[j];
  Model::F(t + h0, y1, p, f1);
  T s = T(0);
  RJ_UNROLL
  for (int j = 0; j < N; ++j) {
    const T u = (f1[j] - f0[j]) / scale[j];
    s += u * u;
  }
  const T d2 = Rms(s) / h0, most = std::max(d1, d2);
  const T h1 = most <= T(1e-15) ? std::max(T(1e-6), h0 * T(1e-3))
                                 : T(std::pow(T(0.01) / most, c.inv_order));
  return std::min(T(100) * h0, h1);
}

// A step of size h from y at t without its error: its end u (normalised, mapped; r the inverse
// norms of its unit groups before). The fixed steps, and the truncated steps of Locate.
template <typename T>
RJ_INLINE void Advance(const T* y, const T* p, T t, T h, T* u, T* r) {
  constexpr int S = Tab::S;
  T k[S][N], z[S][N];
  Stages<S>(y, p, t, h, k, z);
  Combine<S>(y, h, k, u);
  EndStep(t + h, p, u, r);
}

// One attempt of size h from y at t: its end u (as Advance) and scaled error.
template <typename T>
RJ_INLINE T Attempt(const Ctl<T>& c, const T* y, const T* p, T t, T h, T* u, T* r) {
  constexpr int S = Tab::S;
  T k[S][N], z[S][N], err[N];
  Stages<S>(y, p, t, h, k, z);
  Combine<S>(y, h, k, u);
  RJ_UNROLL
  for (int j = 0; j < N; ++j) err[j] = Model::still[j] ? T(0) : h * Row<S + 1, 0, true>(k, j, T(0));
  EndStep(t + h, p, u, r);
  bool nan = false;
  RJ_UNROLL
  for (int j = 0; j < N; ++j) nan |= std::isnan(u[j]);
  T s = T(0);
  RJ_UNROLL
  for (int j = 0; j < N; ++j) {
    const T e = std::isnan(err[j]) ? std::numeric_limits<T>::infinity() : err[j];
    const T m = std::max(std::abs(y[j]), std::abs(nan ? y[j] : u[j]));
    const T q = e / (c.atol + m * c.rtol);
    s += q * q;
  }
  return Rms(s);
}

// 100 floats below b (Diffrax's `t1_clip_floor`): for a positive b the float whose bit
// pattern is 100 less (floats of one sign are ordered as their bits), otherwise step by step.
template <typename T>
RJ_INLINE T Below(T b) {
  using U = std::conditional_t<sizeof(T) == 8, uint64_t, uint32_t>;
  U bits;
  std::memcpy(&bits, &b, sizeof(T));
  if (b > T(0) && std::isfinite(b) && bits > U(100)) {
    bits -= U(100);
    std::memcpy(&b, &bits, sizeof(T));
    return b;
  }
  for (int i = 0; i < 100; ++i) b = std::nextafter(b, -std::numeric_limits<T>::infinity());
  return b;
}

// `x^e`, or 1 for a coefficient 0 (as Diffrax skips it).
template <typename T>
RJ_INLINE T Power(T x, T e) {
  return e == T(0) ? T(1) : T(std::pow(x, e));
}

// The accepted steps of one body in one interval, for the reverse sweep: each step's start
// state, time, size and inverse norms of its end's unit groups.
template <typename T>
struct Taken {
  std::vector<T> y, t, h, inv;
  void clear() { y.clear(), t.clear(), h.clear(), inv.clear(); }
};

struct Count {
  int64_t attempts = 0, accepted = 0;
  bool done = true;  // the interval's end reached (false: max_steps reached)
};

// The event between t and t + h (an accepted step from y, the condition g0 there and g1 at
// its end): its time, located by the Illinois method on τ ↦ G(t + τ, the step of size τ from
// y) (each value one step of the pair: its error that of a step), and the state there into u.
template <typename T>
T Locate(const T* y, const T* p, T t, T h, T g0, T g1, T* u) {
  T a = T(0), b = h, fa = g0, fb = g1, r[NU];
  int side = 0;
  T m = g0 == T(0) ? T(0) : b;
  const T tiny = T(4) * std::numeric_limits<T>::epsilon() * std::max(std::abs(t) + h, T(1));
  for (int i = 0; i < 200 && g0 != T(0) && b - a > tiny; ++i) {
    m = (a * fb - b * fa) / (fb - fa);
    if (!(m > a && m < b)) m = T(0.5) * (a + b);
    Advance(y, p, t, m, u, r);
    const T fm = Condition(t + m, u, p);
    if (fm == T(0)) break;
    if (Sign(fm) == Sign(fb)) {
      b = m, fb = fm;
      if (side == -1) fa *= T(0.5);
      side = -1;
    } else {
      a = m, fa = fm;
      if (side == 1) fb *= T(0.5);
      side = 1;
    }
    m = b;
  }
  if (m == T(0)) {
    RJ_UNROLL
    for (int j = 0; j < N; ++j) u[j] = y[j];
  } else {
    Advance(y, p, t, m, u, r);
  }
  return t + m;
}

// After a step from y at t of size h to u: whether the event happened (Crossed) on it; its
// time into ev, and with a terminating event the state there into y (the body stops).
template <typename T>
RJ_INLINE bool Watched(const Ctl<T>& c, T* y, const T* p, T t, T h, const T* u, Watch<T>* ev) {
  if (!(ev && Model::kEvent)) return false;
  const T g1 = Condition(t + h, u, p);
  if (std::isinf(ev->time) && Crossed(c.direction, ev->g, g1)) {
    T v[N];
    ev->time = Locate(y, p, t, h, ev->g, g1, v);
    if (c.terminate) {
      RJ_UNROLL
      for (int j = 0; j < N; ++j) y[j] = v[j];
      ev->stopped = true;
      return true;
    }
  }
  ev->g = g1;
  return false;
}

template <typename T>
RJ_INLINE void Keep(Taken<T>* keep, const T* y, T t, T h, const T* r) {
  if (!keep) return;
  keep->y.insert(keep->y.end(), y, y + N);
  keep->t.push_back(t);
  keep->h.push_back(h);
  RJ_UNROLL
  for (int g = 0; g < Model::NU; ++g) keep->inv.push_back(r[g]);
}

// Fixed steps (Tab::kFixed) over [a, b] from y (in place): the fewest equal steps of at most
// dt0 (`_integrate.fixed_step_count`), step s at a + s h as model.cc's Steps, at most
// max_steps of them (more: max_steps reached); the event watched as on adaptive steps.
template <typename T>
Count Fixed(const Ctl<T>& c, T* y, const T* p, T a, T b, Taken<T>* keep, Watch<T>* ev) {
  Count n;
  if (!(a < b)) return n;
  const T w = b - a;
  const T steps = std::max(std::ceil(w / c.dt0 * T(1 - 1e-6)), T(1));
  const T h = w / steps;
  const int64_t taken = std::min<int64_t>(static_cast<int64_t>(steps), c.max_steps);
  for (int64_t s = 0; s < taken; ++s) {
    T u[N], r[NU];
    const T t = a + T(s) * h;
    Advance(y, p, t, h, u, r);
    ++n.attempts, ++n.accepted;
    if (Watched(c, y, p, t, h, u, ev)) return n;
    Keep(keep, y, t, h, r);
    RJ_UNROLL
    for (int j = 0; j < N; ++j) y[j] = u[j];
  }
  n.done = static_cast<int64_t>(steps) <= c.max_steps;
  return n;
}

// `diffrax.diffeqsolve` of one body over [a, b] from y (in place) with first step h0 under the
// PID controller (Fixed where Tab::kFixed); returns the attempts and accepted steps. With
// `keep`, the accepted steps into *keep; with `ev`, the event watched.
template <typename T>
Count Interval(const Ctl<T>& c, T* y, const T* p, T a, T b, T h0, Taken<T>* keep = nullptr,
               Watch<T>* ev = nullptr) {
  if constexpr (Tab::kFixed) {
    return Fixed(c, y, p, a, b, keep, ev);
  } else {
    const T floor = Below(b);
    T tprev = a, tnext = std::min(a + std::min(h0, c.dtmax), b);
    T inv1 = T(1), inv2 = T(1);
    Count n;
    while (tprev < b && n.attempts < c.max_steps) {
      T u[N], r[NU];
      const T h = tnext - tprev;
      const T eps = Attempt(c, y, p, tprev, h, u, r);
      ++n.attempts;
      const bool ok = eps < T(1);
      T inv = T(1) / eps;
      const T f = c.safety * Power(inv, c.c1) * Power(inv1, c.c2) * Power(inv2, c.c3);
      const T factor = std::min(std::max(f, ok ? T(1) : c.fmin), ok ? c.fmax : c.safety);
      const T dt = std::min(h * factor, c.dtmax);
      if (inv == T(0) || std::isinf(inv)) inv = T(1);
      const T t0 = ok ? tnext : tprev, t1 = t0 + dt;
      if (ok) {
        if (Watched(c, y, p, tprev, h, u, ev)) {
          ++n.accepted;
          return n;
        }
        Keep(keep, y, tprev, h, r);
        RJ_UNROLL
        for (int j = 0; j < N; ++j) y[j] = u[j];
        inv2 = inv1, inv1 = inv;
        ++n.accepted;
      }
      tprev = std::min(t0, b);
      tnext = t1 > floor ? (ok ? b : tprev + T(0.5) * (b - tprev)) : t1;
    }
    n.done = !(tprev < b);
    return n;
  }
}

// One body over all intervals: the states at the saved times, each interval's first step, and
// the counts. `y` holds the body's state (N) on entry.
template <typename T>
void Body(const Ctl<T>& c, T* y, const T* p, const T* ts, const int32_t* jump, const int32_t* save,
          int64_t K, T* out, T* rec, T* hk, int32_t* st, T* event) {
  Watch<T> ev;
  int64_t attempts = 0, accepted = 0, valid = 1;
  int32_t result = 0;
  T h = T(0);
  const bool guess = std::isnan(c.dt0);
  if (save[0]) std::memcpy(out + (save[0] - 1) * N, y, N * sizeof(T));
  for (int64_t k = 0; k < K; ++k) {
    const T a = ts[k];
    if constexpr (Model::kJump) {
      if (jump[k]) {  // (stopped by an event: held, the held state recorded)
        T u[N];
        if (!ev.stopped) {
          Model::J(a, y, p, u);
          std::memcpy(y, u, sizeof(u));
        }
        RJ_UNROLL
        for (int j = 0; j < Model::NR; ++j) rec[(jump[k] - 1) * Model::NR + j] = y[Model::R0 + j];
      }
    }
    const bool alive = Finite(y);
    const T b = alive && !ev.stopped ? ts[k + 1] : a;  // (stopped by an event: held)
    if constexpr (!Tab::kFixed) {
      if (k == 0 || Model::kJump) h = guess ? (a + std::min(InitialStep(c, y, p, a), c.dtmax)) - a : c.dt0;
    }
    hk[k] = h;
    if (Model::kEvent && !ev.stopped) ev.g = Condition(a, y, p);
    const Count n = Interval(c, y, p, a, b, h, static_cast<Taken<T>*>(nullptr), &ev);
    attempts += n.attempts;
    accepted += n.accepted;
    int32_t r = n.done ? (Finite(y) ? 0 : 2) : 1;
    if (alive) h = (b - a) / T(std::max<int64_t>(n.accepted, 1));
    if (result == 0) result = r;
    if (result == 0) ++valid;
    if (save[k + 1]) std::memcpy(out + (save[k + 1] - 1) * N, y, N * sizeof(T));
  }
  st[0] = static_cast<int32_t>(attempts);
  st[1] = static_cast<int32_t>(accepted);
  st[2] = static_cast<int32_t>(attempts - accepted);
  st[3] = static_cast<int32_t>(valid);
  st[4] = result;
  *event = ev.time;
}

// A body's operands in a call: its row l and column b.
struct Where {
  int64_t l, b;
};

// f(i, where) for every body of the call, in blocks whose parameters are filled into C; the
// blocks are handed out dynamically (bodies take different numbers of steps).
template <typename T, class F>
void EachBody(const Layout& at, const Param<T>* prm, F f) {
  const int64_t count = at.rows.count() * at.B, blocks = (count + kBlock - 1) / kBlock;
#pragma omp parallel for schedule(dynamic, 1)
  for (int64_t blk = 0; blk < blocks; ++blk) {
    alignas(64) T C[P][kBlock];
    const int64_t start = blk * kBlock, m = std::min(kBlock, count - start);
    int64_t row[kBlock], col[kBlock];
    Place(0, start, m, at.B, row, col);
    Fill<T>(m, row, col, prm, at.rows, C);
    for (int64_t i = 0; i < m; ++i) {
      T p[P];
      RJ_UNROLL
      for (int j = 0; j < P; ++j) p[j] = C[j][i];
      f(p, Where{row[i], col[i]});
    }
  }
}

// Every body's adaptive steps (model_layout.h's Adaptive: the operands checked by
// model_ffi.cc).
template <typename T>
void AdaptiveRun RJ_ADAPTIVE_ARGS(T) {
  EachBody<T>(at, prm, [&](const T* p, Where w) {
    T x[N];
    RJ_UNROLL
    for (int j = 0; j < N; ++j) x[j] = y0[at.x0(w.l, w.b, j)];
    const Ctl<T> c(ctl + cl.at(at.rows, w.l));
    const int64_t body = w.l * at.B + w.b;
    Body<T>(c, x, p, ts + tl.at(at.rows, w.l), jump + at.jump.at(at.rows, w.l),
            save + at.save.at(at.rows, w.l), at.K, y + at.out(w.l, w.b, 0, 0),
            rec + (at.R > 0 ? at.rec(w.l, w.b, 0, 0) : 0), hk + body * at.K, st + body * 5,
            ev + body);
  });
}

// The reverse sweep of one body (lam: the cotangent of its last state on entry, of its first
// on return; pbar: the parameters' cotangents, added to).
template <typename T>
void BodyBack(const Ctl<T>& c, const Layout& at, Where w, const T* p, const T* y, const T* ts,
              const int32_t* jump, const T* hk, const T* gy, T* lam, T* pbar, Taken<T>& tk) {
  alignas(64) T x[N][kBlock], nx[N][kBlock], inv[NU][kBlock], C[P][kBlock];
  alignas(64) T lb[N][kBlock], pb[P][kBlock], hb[kBlock], tb[kBlock];
  RJ_UNROLL
  for (int j = 0; j < P; ++j) C[j][0] = p[j], pb[j][0] = T(0);
  RJ_UNROLL
  for (int j = 0; j < N; ++j) lb[j][0] = lam[j];
  for (int64_t k = at.K - 1; k >= 0; --k) {
    const T a = ts[k];
    T s0[N], s[N];
    RJ_UNROLL
    for (int j = 0; j < N; ++j) s0[j] = s[j] = y[at.saved(w.l, w.b, k, j)];
    const bool jumped = Model::kJump && jump[k];
    if (jumped) Model::J(a, s0, p, s);
    const T b = Finite(s) ? ts[k + 1] : a;
    tk.clear();
    Interval(c, s, p, a, b, hk[k], &tk);  // s: the interval's end
    for (int64_t i = static_cast<int64_t>(tk.t.size()) - 1; i >= 0; --i) {
      const T* start = tk.y.data() + i * N;
      const T* end = i + 1 < static_cast<int64_t>(tk.t.size()) ? start + N : s;
      RJ_UNROLL
      for (int j = 0; j < N; ++j) x[j][0] = start[j], nx[j][0] = end[j];
      RJ_UNROLL
      for (int g = 0; g < Model::NU; ++g) inv[g][0] = tk.inv[i * NU + g];
      hb[0] = tb[0] = T(0);
      StepBack<T>(1, x, nx, inv, C, 0, tk.t[i], tk.h[i], lb, pb, hb, tb);
    }
    if (jumped) {
      alignas(64) T xj[N][kBlock];
      RJ_UNROLL
      for (int j = 0; j < N; ++j) xj[j][0] = s0[j];
      JumpBack<T>(1, xj, C, a, lb, pb, tb);
    }
    RJ_UNROLL
    for (int j = 0; j < N; ++j) lb[j][0] += gy[at.cot(w.l, w.b, k, j)];
  }
  RJ_UNROLL
  for (int j = 0; j < N; ++j) lam[j] = lb[j][0];
  RJ_UNROLL
  for (int j = 0; j < Model::P; ++j) pbar[j] += pb[j][0];
}

// Their reverse mode (model_layout.h's AdaptiveBack).
template <typename T>
void AdaptiveRunBack RJ_ADAPTIVE_BACK_ARGS(T) {
#pragma omp parallel
  {
    Taken<T> tk;
    const int64_t count = at.rows.count() * at.B;
#pragma omp for schedule(dynamic, 16)
    for (int64_t i = 0; i < count; ++i) {
      const Where w{i / at.B, i % at.B};
      T p[P], pbar[P], lam[N];
      // (the parameters of one body: Fill with one column)
      alignas(64) T C[P][kBlock];
      int64_t row[1] = {w.l}, col[1] = {w.b};
      Fill<T>(1, row, col, prm, at.rows, C);
      RJ_UNROLL
      for (int j = 0; j < P; ++j) p[j] = C[j][0], pbar[j] = T(0);
      RJ_UNROLL
      for (int j = 0; j < N; ++j) lam[j] = gy[at.cot(w.l, w.b, at.K, j)];
      const Ctl<T> c(ctl + cl.at(at.rows, w.l));
      BodyBack<T>(c, at, w, p, y, ts + tl.at(at.rows, w.l), jump + at.jump.at(at.rows, w.l),
                  hk + hl.at(at.rows, w.l) + w.b * at.K, gy, lam, pbar, tk);
      RJ_UNROLL
      for (int j = 0; j < N; ++j) y0b[i * N + j] = lam[j];
      RJ_UNROLL
      for (int j = 0; j < Model::P; ++j) pb[i * Model::P + j] = pbar[j];
    }
  }
}

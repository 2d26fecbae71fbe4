/* The right-hand sides of the reference models (see models.c), shared by the CPU reference
 * (models.c) and the GPU one (models.cu): RJ_DEVICE is `__device__` under CUDA, empty in C.
 * Needs sqrt (math.h in C; a CUDA built-in). */
#ifndef RJ_DEVICE
#define RJ_DEVICE
#endif

/* One classical RK4 step of size h at time t of the model NAME (N states, the unit quaternion
 * at QO, none where QO < 0) on the state y (in place) with parameters p, the quaternion
 * renormalised after it: the step of every reference (models.c, models.cu). */
#define RK4_STEP(NAME, N, QO, y, p, t, h)                                                       \
    do {                                                                                        \
        double z_[N], k1_[N], k2_[N], k3_[N], k4_[N];                                           \
        rhs_##NAME(t, y, p, k1_);                                                               \
        for (int j_ = 0; j_ < N; j_++) z_[j_] = y[j_] + 0.5 * (h) * k1_[j_];                    \
        rhs_##NAME((t) + 0.5 * (h), z_, p, k2_);                                                \
        for (int j_ = 0; j_ < N; j_++) z_[j_] = y[j_] + 0.5 * (h) * k2_[j_];                    \
        rhs_##NAME((t) + 0.5 * (h), z_, p, k3_);                                                \
        for (int j_ = 0; j_ < N; j_++) z_[j_] = y[j_] + (h) * k3_[j_];                          \
        rhs_##NAME((t) + (h), z_, p, k4_);                                                      \
        for (int j_ = 0; j_ < N; j_++)                                                          \
            y[j_] += (h) * (k1_[j_] / 6 + k2_[j_] / 3 + k3_[j_] / 3 + k4_[j_] / 6);             \
        if ((QO) >= 0) {                                                                        \
            const int o_ = (QO) >= 0 ? (QO) : 0;                                                \
            const double r_ = 1.0 / sqrt(y[o_] * y[o_] + y[o_ + 1] * y[o_ + 1] +                \
                                         y[o_ + 2] * y[o_ + 2] + y[o_ + 3] * y[o_ + 3]);        \
            for (int j_ = o_; j_ < o_ + 4; j_++) y[j_] *= r_;                                   \
        }                                                                                       \
    } while (0)

RJ_DEVICE static inline void quat_rates(const double *w, const double *q, double *dq)
{
    dq[0] = 0.5 * (-q[1] * w[0] - q[2] * w[1] - q[3] * w[2]);
    dq[1] = 0.5 * (q[0] * w[0] + q[2] * w[2] - q[3] * w[1]);
    dq[2] = 0.5 * (q[0] * w[1] + q[3] * w[0] - q[1] * w[2]);
    dq[3] = 0.5 * (q[0] * w[2] + q[1] * w[1] - q[2] * w[0]);
}

/* Pᵀ v: v in space axes to body axes. */
RJ_DEVICE static inline void to_body(const double *q, const double *v, double *out)
{
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    out[0] = (1 - 2 * (y * y + z * z)) * v[0] + 2 * (x * y + w * z) * v[1] + 2 * (x * z - w * y) * v[2];
    out[1] = 2 * (x * y - w * z) * v[0] + (1 - 2 * (x * x + z * z)) * v[1] + 2 * (y * z + w * x) * v[2];
    out[2] = 2 * (x * z + w * y) * v[0] + 2 * (y * z - w * x) * v[1] + (1 - 2 * (x * x + y * y)) * v[2];
}

/* Euler's equations in principal axes: Ω̇ = c-terms + J K. */
RJ_DEVICE static inline void euler(const double *w, const double *p, const double *K, double *dw)
{
    dw[0] = p[0] * w[1] * w[2] + p[3] * K[0];
    dw[1] = p[1] * w[2] * w[0] + p[4] * K[1];
    dw[2] = p[2] * w[0] * w[1] + p[5] * K[2];
}

RJ_DEVICE static inline void cross(const double *a, const double *b, double *out)
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

RJ_DEVICE static inline void rhs_free_body(double t, const double *y, const double *p, double *k)
{
    k[0] = p[0] * y[1] * y[2];
    k[1] = p[1] * y[2] * y[0];
    k[2] = p[2] * y[0] * y[1];
    quat_rates(y, y + 3, k + 3);
}

RJ_DEVICE static inline void rhs_damping(double t, const double *y, const double *p, double *k)
{
    const double K[3] = {-p[6] * y[0], -p[7] * y[1], -p[8] * y[2]};
    euler(y, p, K, k);
    quat_rates(y, y + 3, k + 3);
}

/* The gravity-gradient torque K = s c × (I0 c), c = P(q)ᵀ e_Z (the third row of P(q)) with
   r = 2 / |q|² (r = 2 for a unit q: the same arithmetic as the literal 2). */
RJ_DEVICE static inline void gravity_torque(const double *q, double r, const double *p, double *K)
{
    const double c[3] = {r * (q[1] * q[3] - q[0] * q[2]), r * (q[2] * q[3] + q[0] * q[1]),
                         1 - r * (q[1] * q[1] + q[2] * q[2])};
    const double Ic[3] = {p[6] * c[0], p[7] * c[1], p[8] * c[2]};
    cross(c, Ic, K);
    for (int i = 0; i < 3; i++) K[i] *= p[9];
}

RJ_DEVICE static inline void rhs_gravity_gradient(double t, const double *y, const double *p, double *k)
{
    double K[3];
    gravity_torque(y + 3, 2.0, p, K);
    euler(y, p, K, k);
    quat_rates(y, y + 3, k + 3);
}

RJ_DEVICE static inline void rhs_heavy_top(double t, const double *y, const double *p, double *k)
{
    double K[3];
    cross(y + 3, p + 6, K);
    euler(y, p, K, k);
    cross(y + 3, y, k + 3);
    quat_rates(y, y + 6, k + 6);
}

RJ_DEVICE static inline void rhs_sixdof(double t, const double *y, const double *p, double *k)
{
    const double *F = p + 7, *a = p + 10, *w = y + 10;
    /* the load sees the unit quaternion, as simulate_6dof's does */
    const double r = 1.0 / sqrt(y[6] * y[6] + y[7] * y[7] + y[8] * y[8] + y[9] * y[9]);
    const double q[4] = {y[6] * r, y[7] * r, y[8] * r, y[9] * r};
    double Fb[3], K[3];
    to_body(q, F, Fb);
    cross(a, Fb, K);
    for (int i = 0; i < 3; i++) k[i] = y[3 + i], k[3 + i] = p[6] * F[i];
    quat_rates(w, y + 6, k + 6);
    euler(w, p, K, k + 10);
}

RJ_DEVICE static inline void rhs_satellite(double t, const double *y, const double *p, double *k)
{
    const double *R = y, *q = y + 6, *w = y + 10, mu = p[9];
    const double r2 = R[0] * R[0] + R[1] * R[1] + R[2] * R[2], r = sqrt(r2);
    const double g = mu / (r2 * r);
    double n[3], In[3], K[3];
    to_body(q, R, n);
    for (int i = 0; i < 3; i++) n[i] /= r, In[i] = p[6 + i] * n[i];
    cross(n, In, K);
    for (int i = 0; i < 3; i++) K[i] *= 3 * g, k[i] = y[3 + i], k[3 + i] = -g * R[i];
    quat_rates(w, q, k + 6);
    euler(w, p, K, k + 10);
}

RJ_DEVICE static inline void rhs_gyrostat(double t, const double *y, const double *p, double *k)
{
    double K[3];
    cross(y, p + 6, K);
    for (int i = 0; i < 3; i++) K[i] = -K[i];
    euler(y, p, K, k);
    quat_rates(y, y + 3, k + 3);
}

/* Closed loop: a gyrostat with four reaction wheels, y = (Ω, q, ω_w), principal moments I
 * (p[0..2]), M⁻¹ = (I − A J Aᵀ)⁻¹ (p[3..11], row-major), spin axes A (p[12..23], 3 × 4
 * row-major), wheel inertias J (p[24..27]), and the held motor torques u (p[28..31]):
 *   Ω̇ = M⁻¹ (−A u − Ω × (I Ω + A J ω_w)),  q̇ = ½ q ∘ (0, Ω),  ω̇_w = u / J − Aᵀ Ω̇. */
RJ_DEVICE static inline void rhs_closed_loop(double t, const double *y, const double *p, double *k)
{
    const double *w = y, *ws = y + 7, *M = p + 3, *A = p + 12, *J = p + 24, *u = p + 28;
    double L[3], r[3], c[3];
    for (int i = 0; i < 3; i++) {
        double h = 0, Au = 0;
        for (int j = 0; j < 4; j++) h += A[4 * i + j] * J[j] * ws[j], Au += A[4 * i + j] * u[j];
        L[i] = p[i] * w[i] + h;
        r[i] = -Au;
    }
    cross(w, L, c);
    for (int i = 0; i < 3; i++) r[i] -= c[i];
    for (int i = 0; i < 3; i++) k[i] = M[3 * i] * r[0] + M[3 * i + 1] * r[1] + M[3 * i + 2] * r[2];
    quat_rates(w, y + 3, k + 3);
    for (int j = 0; j < 4; j++)
        k[7 + j] = u[j] / J[j] - (A[j] * k[0] + A[4 + j] * k[1] + A[8 + j] * k[2]);
}

/* The sampled quaternion PD law: q_e = q_t⁻¹ ∘ q, τ = −kp sgn(q_e0) q_e,1:3 − kd Ω, motor torques
 * u = G τ (G = −A⁺, 4 × 3 row-major) clipped to ±umax; c = (kp, kd, q_t (4), G (12), umax). */
RJ_DEVICE static inline void control_pd(const double *y, const double *c, double *u)
{
    const double *q = y + 3, *t = c + 2;
    const double e[4] = {t[0] * q[0] + t[1] * q[1] + t[2] * q[2] + t[3] * q[3],
                         t[0] * q[1] - t[1] * q[0] - t[2] * q[3] + t[3] * q[2],
                         t[0] * q[2] + t[1] * q[3] - t[2] * q[0] - t[3] * q[1],
                         t[0] * q[3] - t[1] * q[2] + t[2] * q[1] - t[3] * q[0]};
    const double sign = e[0] < 0 ? -1.0 : 1.0, umax = c[18];
    double tau[3];
    for (int i = 0; i < 3; i++) tau[i] = -c[0] * sign * e[1 + i] - c[1] * y[i];
    for (int j = 0; j < 4; j++) {
        const double v = c[6 + 3 * j] * tau[0] + c[7 + 3 * j] * tau[1] + c[8 + 3 * j] * tau[2];
        u[j] = v > umax ? umax : (v < -umax ? -umax : v);
    }
}

/* Darboux kinematics in the body frame: the attitude from a given body angular velocity
 * Ω(t) = (a sin t, 4 cos 2t, 3 + a t / 2), a = p[0]. The quaternion: q̇ = ½ q ∘ (0, Ω). The
 * rotation vector: θ̇ = Zᵀ(θ) Ω = Ω + ½ θ × Ω + d θ × (θ × Ω), d = (1 − (θ/2) cot(θ/2)) / θ²
 * (Zhilin 3.14.22; Taylor series below θ² = 0.01), replaced by its shadow θ (1 − 2πk/|θ|),
 * k = round(|θ|/2π), after a step that leaves |θ| > π (shadow). */
RJ_DEVICE static inline void darboux_omega(double t, const double *p, double *w)
{
    w[0] = p[0] * sin(t);
    w[1] = 4 * cos(2 * t);
    w[2] = 3 + 0.5 * p[0] * t;
}

RJ_DEVICE static inline void rhs_darboux_quat(double t, const double *y, const double *p, double *k)
{
    double w[3];
    darboux_omega(t, p, w);
    quat_rates(w, y, k);
}

RJ_DEVICE static inline void rhs_darboux_rotvec(double t, const double *y, const double *p,
                                                double *k)
{
    const double x2 = y[0] * y[0] + y[1] * y[1] + y[2] * y[2], hx = 0.5 * sqrt(x2);
    const double d = x2 < 1e-2 ? 1.0 / 12 + x2 * (1.0 / 720 + x2 * (1.0 / 30240 + x2 / 1209600))
                               : (1 - hx * cos(hx) / sin(hx)) / x2;
    double w[3], a[3], b[3];
    darboux_omega(t, p, w);
    cross(y, w, a);
    cross(y, a, b);
    for (int i = 0; i < 3; i++) k[i] = w[i] + 0.5 * a[i] + d * b[i];
}

RJ_DEVICE static inline void shadow(double *y)
{
    const double two_pi = 6.283185307179586, x2 = y[0] * y[0] + y[1] * y[1] + y[2] * y[2];
    const double n = sqrt(x2 > two_pi * two_pi / 4 ? x2 : 1.0);
    const double s = x2 > two_pi * two_pi / 4 ? 1 - two_pi * round(n / two_pi) / n : 1.0;
    for (int i = 0; i < 3; i++) y[i] *= s;
}

/* The models with a reference of their own loop (not the closed loop), as an X-macro:
 * X(NAME, N states, P parameters, quaternion offset QO (−1: none), step-end map END). */
#define NO_END(y) ((void)(y))
#define RJ_MODELS(X)                    \
    X(free_body, 7, 6, 3, NO_END)       \
    X(damping, 7, 9, 3, NO_END)         \
    X(gravity_gradient, 7, 10, 3, NO_END) \
    X(heavy_top, 10, 9, 6, NO_END)      \
    X(sixdof, 13, 13, 6, NO_END)        \
    X(satellite, 13, 10, 6, NO_END)     \
    X(gyrostat, 7, 9, 3, NO_END)        \
    X(darboux_quat, 4, 1, 0, NO_END)    \
    X(darboux_rotvec, 3, 1, -1, shadow)

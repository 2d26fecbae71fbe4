"""The TOML config of `rigidjax sweep`: read, checked key by key, turned into a design (the
one-point model it describes: `_sweep_model`). Every error names the file, the key and the fix
(a `UsageError`)."""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ._common import UsageError, check_tolerance

OBSERVABLES = (
    "max_nutation",
    "first_flip_time",
    "energy_drift",
    "momentum_drift",
    "omega_end",
    "quat_end",
)
CLOSED_LOOP = ("settling_time", "peak_wheel_speed", "saturation_count", "pointing_error_end")
"""The observables of a sweep with `[wheels]` and `[control]` (a closed loop)."""
ESTIMATED = ("knowledge_error_end", "knowledge_error_rms", "control_error_end")
"""The observables a closed loop with `[sensors]` adds (the estimator in the loop)."""
SECTIONS: dict[str, dict[str, str]] = {
    "body": {"inertia": "principal moments [I1, I2, I3] or a 3×3 tensor (body axes)"},
    "initial": {
        "omega0": "initial body angular velocity [Ω1, Ω2, Ω3] in rad/s",
        "q0": "initial attitude quaternion [w, x, y, z] (default: identity)",
    },
    "times": {"t_end": "time span [s]", "num": "number of output times (≥ 2)"},
    "solver": {
        "method": "tsit5 (default), dopri5, dopri8 or rk4 (fixed steps: give dt)",
        "kinematics": "quat (default), rotvec, matrix, euler, cayley_klein or geometric",
        "rtol": "relative tolerance",
        "atol": "absolute tolerance",
        "dt": "step size [s] (rk4: required; adaptive methods: the first step)",
        "max_steps": "the most steps per output interval",
    },
    "design": {
        "kind": "grid or sample",
        "factors": "grid: one table per factor, values = [...] or start, stop, num, scale",
        "n": "sample: the number of points",
        "method": "sample: sobol (default), latin or uniform",
        "seed": "sample: the random seed (default 0)",
        "ranges": "sample: NAME = [low, high] or [low, high, 'log']",
    },
    "wheels": {
        "axes": "spin axes of the n reaction wheels, one row [x, y, z] each (body axes)",
        "inertia": "axial inertia of each wheel [kg m²]",
        "torque_max": "motor torque bound of each wheel [N m] (default: unbounded)",
        "tilt": "misalignment of each wheel [rad], n numbers or factor names: its axis turned "
        "by that angle about a fixed perpendicular (default: none)",
    },
    "control": {
        "law": "quaternion_pd (u = −kp sgn(q_e0) q_e,1:3 − kd Ω, allocated to the nominal axes)",
        "kp": "proportional gain [N m]",
        "kd": "derivative gain [N m s]",
        "period": "control period [s]: sampled and held (zero-order hold)",
        "target": "target attitude as a rotation vector [x, y, z] in degrees (body → space)",
        "tolerance": "settling tolerance on the pointing error [deg] (default 0.5)",
    },
    "sensors": {
        "gyro_arw": "the gyro's angle random walk [rad/√s] (needs [control]: the estimator "
        "in the loop)",
        "gyro_rrw": "the gyro's rate random walk [rad/s^1.5]",
        "gyro_bias": "1σ of the gyro's initial bias per axis [rad/s] (the filter's prior too: > 0)",
        "star_tracker": "the star tracker's 1σ noise per body axis [rad]: a number or [x, y, z]",
        "knowledge0": "1σ of the initial knowledge error per axis [rad] (default 1e-3)",
        "seed": "the noise seed: each point's key is folded from it and the point's factor "
        "values (default 0)",
    },
    "observables": {
        "names": f"which observables to compute (default: {', '.join(OBSERVABLES[:4])}; "
        f"with [control]: {', '.join(CLOSED_LOOP)}, with [sensors] also {', '.join(ESTIMATED)}; "
        f"a free body also offers {', '.join(OBSERVABLES[4:])})"
    },
    "run": {
        "chunk_size": "points per compiled chunk (default: from the memory per point)",
        "precision": "float64 (default) or float32",
    },
}
REQUIRED = {"body": ("inertia",), "initial": ("omega0",), "times": ("t_end", "num")}
METHODS = ("tsit5", "dopri5", "dopri8", "rk4")
KINEMATICS = ("quat", "rotvec", "matrix", "euler", "cayley_klein", "geometric")
Template = Any  # nested lists of floats and factor names


@dataclass(frozen=True)
class Config:
    """A checked sweep config."""

    path: Path
    text: str
    inertia: Template
    omega0: Template
    q0: Template
    t_end: float
    num: int
    method: str
    kinematics: str
    rtol: float | None
    atol: float | None
    dt: float | None
    max_steps: int
    design: dict[str, Any]
    log_factors: tuple[str, ...]  # plotted on log axes
    observables: tuple[str, ...]
    chunk_size: int | None
    float32: bool
    wheels: dict[str, Any] | None = None  # axes (n, 3), perpendiculars (n, 3), inertia, ...
    control: dict[str, Any] | None = None  # kp, kd, period, target (4,), tolerance [rad]
    sensors: dict[str, Any] | None = None  # arw, rrw, bias, star_tracker (3,), knowledge0, seed


def _fail(path: Path, where: str, problem: str) -> UsageError:
    return UsageError(f"{path}: {where}: {problem}")


def _number(path: Path, where: str, v: Any, *, positive: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise _fail(path, where, f"must be a finite number, got {v!r}")
    if positive and v <= 0:
        raise _fail(path, where, f"must be positive, got {v!r}")
    return float(v)


def _integer(path: Path, where: str, v: Any, low: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < low:
        raise _fail(path, where, f"must be an integer ≥ {low}, got {v!r}")
    return v


def _template(path: Path, where: str, v: Any, shapes: tuple[tuple[int, ...], ...]) -> Template:
    """A vector or matrix of numbers and factor names, of one of `shapes`."""

    def walk(x: Any) -> Any:
        if isinstance(x, list):
            return [walk(e) for e in x]
        if isinstance(x, str):
            if not x.isidentifier():
                raise _fail(path, where, f"{x!r} is not a factor name (letters, digits, _)")
            return x
        return _number(path, where, x)

    t = walk(v)
    shape = np.shape(np.array(t, dtype=object))
    if shape not in shapes:
        want = " or ".join(str(list(s)) for s in shapes)
        raise _fail(path, where, f"must have shape {want} (numbers or factor names), got {v!r}")
    return t


def _names(t: Template) -> set[str]:
    if isinstance(t, list):
        return set().union(*(_names(e) for e in t)) if t else set()
    return {t} if isinstance(t, str) else set()


def fill(t: Template, values: dict[str, Any], xp: Any) -> Any:
    """The array of template `t` with the factors' `values` (scalars or arrays of one shape:
    the result then has that shape in front)."""
    if isinstance(t, list):
        return xp.stack([fill(e, values, xp) for e in t], axis=-1)
    if isinstance(t, str):
        return values[t]
    first = next(iter(values.values()), None)
    return xp.full(xp.shape(first) if first is not None else (), t)


def _grid_factor(path: Path, name: str, spec: Any) -> tuple[np.ndarray, bool]:
    where = f"[design.factors.{name}]"
    if isinstance(spec, list):
        spec = {"values": spec}
    if not isinstance(spec, dict):
        raise _fail(path, where, "give values = [...] or start, stop, num (and scale = 'log')")
    allowed = {"values", "start", "stop", "num", "scale"}
    _unknown(path, where, spec, allowed)
    if "values" in spec:
        if set(spec) - {"values"}:
            raise _fail(path, where, "give either values or start/stop/num, not both")
        v = spec["values"]
        if not isinstance(v, list) or not v:
            raise _fail(path, f"{where} values", "must be a non-empty list of numbers")
        return np.array([_number(path, f"{where} values", x) for x in v]), False
    missing = [k for k in ("start", "stop", "num") if k not in spec]
    if missing:
        raise _fail(path, where, f"missing {', '.join(missing)}; or give values = [...]")
    start = _number(path, f"{where} start", spec["start"])
    stop = _number(path, f"{where} stop", spec["stop"])
    num = _integer(path, f"{where} num", spec["num"], 1)
    scale = spec.get("scale", "linear")
    if scale not in ("linear", "log"):
        raise _fail(path, f"{where} scale", f"must be 'linear' or 'log', got {scale!r}")
    if scale == "log":
        if start <= 0 or stop <= 0:
            raise _fail(path, where, "a log scale needs positive start and stop")
        return np.geomspace(start, stop, num), True
    return np.linspace(start, stop, num), False


def _design(path: Path, d: dict[str, Any]) -> tuple[dict[str, Any], tuple[str, ...]]:
    """The design spec (`kind` and its arguments, checked) and the factors on log scales."""
    kind = d.get("kind", "grid")
    if kind == "grid":
        _unknown(path, "[design] (grid)", d, {"kind", "factors"})
        factors = d.get("factors")
        if not isinstance(factors, dict) or not factors:
            raise _fail(path, "[design.factors]", "a grid needs at least one factor table")
        values, logs = {}, []
        for name, spec in factors.items():
            values[name], log = _grid_factor(path, name, spec)
            if log:
                logs.append(name)
        return {"kind": "grid", "factors": values}, tuple(logs)
    if kind == "sample":
        _unknown(path, "[design] (sample)", d, {"kind", "n", "method", "seed", "ranges"})
        if "n" not in d:
            raise _fail(path, "[design] n", "a sample needs n, the number of points")
        n = _integer(path, "[design] n", d["n"], 1)
        method = d.get("method", "sobol")
        if method not in ("sobol", "latin", "uniform"):
            raise _fail(path, "[design] method", f"must be sobol, latin or uniform, not {method!r}")
        seed = _integer(path, "[design] seed", d.get("seed", 0), 0)
        ranges = d.get("ranges")
        if not isinstance(ranges, dict) or not ranges:
            raise _fail(path, "[design.ranges]", "a sample needs NAME = [low, high] ranges")
        out, logs = {}, []
        for name, r in ranges.items():
            where = f"[design.ranges] {name}"
            log = isinstance(r, list) and len(r) == 3 and r[2] == "log"
            if not isinstance(r, list) or len(r) not in (2, 3) or (len(r) == 3 and not log):
                raise _fail(path, where, f"must be [low, high] or [low, high, 'log'], got {r!r}")
            lo, hi = (_number(path, where, x) for x in r[:2])
            out[name] = (lo, hi, "log") if log else (lo, hi)
            if log:
                logs.append(name)
        spec = {"kind": "sample", "n": n, "method": method, "seed": seed, "ranges": out}
        return spec, tuple(logs)
    raise _fail(path, "[design] kind", f"must be 'grid' or 'sample', got {kind!r}")


def _closed_loop(path: Path, raw: dict) -> tuple[dict | None, dict | None]:
    """`[wheels]` and `[control]`, checked (both or neither): the nominal axes and the
    perpendiculars about which `tilt` turns them (each axis `a`: `a × e`, `e` the coordinate
    axis least along `a`), and the law's gains, period, target quaternion and tolerance."""
    wheels, control = raw.get("wheels"), raw.get("control")
    if wheels is None and control is None:
        return None, None
    if wheels is None or control is None:
        raise _fail(path, "[wheels]/[control]", "a closed loop needs both tables: give both")
    axes = wheels.get("axes")
    if not isinstance(axes, list) or not axes:
        raise _fail(path, "[wheels] axes", "missing: one row [x, y, z] per wheel")
    A = np.array([[_number(path, "[wheels] axes", x) for x in row] for row in axes])
    if A.ndim != 2 or A.shape[1] != 3 or np.any(np.linalg.norm(A, axis=1) == 0):
        raise _fail(path, "[wheels] axes", f"must be non-zero rows [x, y, z], got {axes!r}")
    if np.linalg.matrix_rank(A) < 3:
        raise _fail(path, "[wheels] axes", "must span 3-D space (three independent axes)")
    A = A / np.linalg.norm(A, axis=1, keepdims=True)
    e = np.eye(3)[np.argmin(np.abs(A), axis=1)]
    perp = np.cross(A, e)
    n = A.shape[0]
    if "inertia" not in wheels:
        raise _fail(path, "[wheels] inertia", "missing: the axial inertia of a wheel [kg m²]")
    tilt = _template(path, "[wheels] tilt", wheels.get("tilt", [0.0] * n), ((n,),))
    u_max = wheels.get("torque_max")
    out_w = dict(
        axes=A,
        perp=perp / np.linalg.norm(perp, axis=1, keepdims=True),
        inertia=_number(path, "[wheels] inertia", wheels["inertia"], positive=True),
        torque_max=None
        if u_max is None
        else _number(path, "[wheels] torque_max", u_max, positive=True),
        tilt=tilt,
    )
    law = control.get("law", "quaternion_pd")
    if law != "quaternion_pd":
        raise _fail(path, "[control] law", f"must be quaternion_pd, got {law!r}")
    for key in ("kp", "kd", "period", "target"):
        if key not in control:
            raise _fail(path, f"[control] {key}", f"missing: {SECTIONS['control'][key]}")
    target = control["target"]
    if not isinstance(target, list) or len(target) != 3:
        raise _fail(path, "[control] target", f"must be [x, y, z] in degrees, got {target!r}")
    rv = np.radians([_number(path, "[control] target", x) for x in target])
    angle = np.linalg.norm(rv)
    axis = rv / angle if angle > 0 else np.zeros(3)
    out_c = dict(
        kp=_number(path, "[control] kp", control["kp"], positive=True),
        kd=_number(path, "[control] kd", control["kd"], positive=True),
        period=_number(path, "[control] period", control["period"], positive=True),
        target=np.r_[np.cos(angle / 2), np.sin(angle / 2) * axis],
        tolerance=np.radians(
            _number(path, "[control] tolerance", control.get("tolerance", 0.5), positive=True)
        ),
    )
    return out_w, out_c


def _sensors(path: Path, raw: dict, control: dict | None) -> dict | None:
    """`[sensors]`, checked: the gyro's and star tracker's noise, the initial errors' spread
    and the noise seed of the estimator in the loop (a closed loop only)."""
    table = raw.get("sensors")
    if table is None:
        return None
    if control is None:
        raise _fail(path, "[sensors]", "the estimator in the loop needs [wheels] and [control]")
    for key in ("gyro_arw", "gyro_rrw", "gyro_bias", "star_tracker"):
        if key not in table:
            raise _fail(path, f"[sensors] {key}", f"missing: {SECTIONS['sensors'][key]}")
    st = table["star_tracker"]
    if isinstance(st, list):
        if len(st) != 3:
            raise _fail(
                path, "[sensors] star_tracker", f"must be a number or [x, y, z], got {st!r}"
            )
        sigma = [_number(path, "[sensors] star_tracker", x, positive=True) for x in st]
    else:
        sigma = [_number(path, "[sensors] star_tracker", st, positive=True)] * 3

    def level(key: str, default: float | None = None) -> float:
        v = _number(path, f"[sensors] {key}", table.get(key, default))
        if v < 0:
            raise _fail(path, f"[sensors] {key}", f"must be ≥ 0, got {v!r}")
        return v

    return dict(
        arw=level("gyro_arw"),
        rrw=level("gyro_rrw"),
        bias=_number(path, "[sensors] gyro_bias", table["gyro_bias"], positive=True),
        star_tracker=np.array(sigma),
        knowledge0=_number(
            path, "[sensors] knowledge0", table.get("knowledge0", 1e-3), positive=True
        ),
        seed=_integer(path, "[sensors] seed", table.get("seed", 0), 0),
    )


def _unknown(path: Path, where: str, table: dict, allowed: set[str] | dict) -> None:
    extra = sorted(set(table) - set(allowed))
    if extra:
        raise _fail(
            path, where, f"unknown key {extra[0]!r}; the keys are {', '.join(sorted(allowed))}"
        )


def load(path: Path) -> Config:
    """Read and check the config at `path` (a UsageError names the file, key and fix)."""
    try:
        text = path.read_text(encoding="utf-8-sig")  # a BOM (as some editors write) is dropped
    except OSError as e:
        raise UsageError(f"{path}: cannot read the config ({e.strerror or e})") from e
    except UnicodeDecodeError as e:
        raise UsageError(
            f"{path}: not UTF-8 text (byte {e.start}: {e.reason}); save the config as UTF-8"
        ) from e
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise UsageError(f"{path}: not valid TOML: {e}; fix the syntax there") from e
    _unknown(path, "top level", raw, SECTIONS)
    for section, keys in SECTIONS.items():
        table = raw.get(section, {})
        if not isinstance(table, dict):
            raise _fail(path, f"[{section}]", "must be a table")
        _unknown(path, f"[{section}]", table, keys)
        for key in REQUIRED.get(section, ()):
            if key not in table:
                raise _fail(path, f"[{section}] {key}", f"missing: {keys[key]}")
    body, initial, times = raw["body"], raw["initial"], raw["times"]
    solver, run = raw.get("solver", {}), raw.get("run", {})
    inertia = _template(path, "[body] inertia", body["inertia"], ((3,), (3, 3)))
    omega0 = _template(path, "[initial] omega0", initial["omega0"], ((3,),))
    q0 = _template(path, "[initial] q0", initial.get("q0", [1.0, 0.0, 0.0, 0.0]), ((4,),))
    design, logs = _design(path, raw.get("design", {}))
    factors = design["factors"] if design["kind"] == "grid" else design["ranges"]
    wheels, control = _closed_loop(path, raw)
    sensors = _sensors(path, raw, control)
    used = _names(inertia) | _names(omega0) | _names(q0)
    used |= _names(wheels["tilt"]) if wheels else set()
    for name in sorted(used - set(factors)):
        raise _fail(path, "[body]/[initial]", f"factor {name!r} is not defined in [design]")
    for name in sorted(set(factors) - used):
        raise _fail(
            path,
            "[design]",
            f"factor {name!r} is not used in [body], [initial] or [wheels]; remove it",
        )
    method = solver.get("method", "tsit5")
    if method not in METHODS:
        raise _fail(path, "[solver] method", f"must be one of {', '.join(METHODS)}")
    kinematics = solver.get("kinematics", "quat")
    if kinematics not in KINEMATICS:
        raise _fail(path, "[solver] kinematics", f"must be one of {', '.join(KINEMATICS)}")
    tol = {
        k: _number(path, f"[solver] {k}", solver[k], positive=True)
        for k in ("rtol", "atol")
        if k in solver
    }
    dt = _number(path, "[solver] dt", solver["dt"], positive=True) if "dt" in solver else None
    if method == "rk4" and dt is None:
        raise _fail(path, "[solver] dt", "rk4 takes fixed steps: give dt, the step size [s]")
    known = (CLOSED_LOOP + (ESTIMATED if sensors else ())) if control else OBSERVABLES
    default = list(known[:4]) + (list(ESTIMATED) if sensors else [])
    names = raw.get("observables", {}).get("names", default)
    if not isinstance(names, list) or not names:
        raise _fail(path, "[observables] names", "must be a non-empty list")
    for n in names:
        if n not in known:
            kind = "a closed loop" if control else f"a free body ([control] adds {CLOSED_LOOP})"
            raise _fail(
                path, "[observables] names", f"unknown {n!r} for {kind}; choose from {known}"
            )
    precision = run.get("precision", "float64")
    if precision not in ("float64", "float32"):
        raise _fail(path, "[run] precision", f"must be float64 or float32, got {precision!r}")
    if sensors and precision != "float64":
        raise _fail(
            path, "[run] precision", "the estimator in the loop ([sensors]) runs in float64"
        )
    for k, v in tol.items():
        check_tolerance(f"{path}: [solver] {k}", v, float32=precision == "float32")
    chunk = run.get("chunk_size")
    return Config(
        path=path,
        text=text,
        inertia=inertia,
        omega0=omega0,
        q0=q0,
        t_end=_number(path, "[times] t_end", times["t_end"], positive=True),
        num=_integer(path, "[times] num", times["num"], 2),
        method=method,
        kinematics=kinematics,
        rtol=tol.get("rtol"),
        atol=tol.get("atol"),
        dt=dt,
        max_steps=_integer(path, "[solver] max_steps", solver.get("max_steps", 100_000), 1),
        design=design,
        log_factors=logs,
        observables=tuple(names),
        chunk_size=None if chunk is None else _integer(path, "[run] chunk_size", chunk, 1),
        float32=precision == "float32",
        wheels=wheels,
        control=control,
        sensors=sensors,
    )


def make_design(c: Config):
    """The `rigidjax.sweep` design of the config."""
    import jax

    from .. import sweep

    d = c.design
    if d["kind"] == "grid":
        return sweep.grid(**d["factors"])
    key = jax.random.PRNGKey(d["seed"])
    return sweep.sample(d["n"], key=key, method=d["method"], **d["ranges"])

"""The C++ of a model kernel: `struct Model` written from a hoisted field's jaxprs (its field,
cotangent map, jump and step-end maps and event condition, unrolled into scalar statements by
`_scalar.unroll` and written by `_emit.CEmitter`) and the generated `model.h` with the tableau
(`header`), for `model.cc` (fixed steps) and `model_adaptive.h` (adaptive steps)."""

from __future__ import annotations

import functools
import hashlib
import re
from collections.abc import Sequence
from importlib import resources
from typing import TYPE_CHECKING

import diffrax
import jax.numpy as jnp
import numpy as np

from . import tableau
from ._emit import CEmitter
from ._objects import _is_const, scalars
from ._scalar import _const_array, unroll

if TYPE_CHECKING:
    from .model import Hoisted


def _inputs(n: int, p: int, pc: int, *extra: str) -> list[np.ndarray]:
    """The scalar names of `(t, y, p, c, *extra)` in the kernel: the parameters and the lifted
    constants are one vector `p` of P + Pc per body."""
    out = [scalars(["t"], ()), scalars([f"y[{i}]" for i in range(n)], (n,))]
    out.append(scalars([f"p[{i}]" for i in range(p)], (p,)))
    out.append(scalars([f"p[{p + i}]" for i in range(pc)], (pc,)))
    out += [scalars([f"{name}[{i}]" for i in range(n)], (n,)) for name in extra]
    return out


def consts(closed) -> list[np.ndarray]:
    return [np.asarray(_const_array(x), dtype=object) for x in closed.consts]


def program(jaxpr, out: str, prefix: str, n: int, p: int, pc: int) -> tuple[list[str], list]:
    """C++ statements of a map `(t, y, p, c) -> (N,)` writing `out[i]`, and its outputs."""
    em = CEmitter(prefix)
    (k,) = unroll(jaxpr, em, consts(jaxpr), _inputs(n, p, pc))
    return em.lines + [f"{out}[{i}] = {em.operand(x)};" for i, x in enumerate(k)], list(k)


def _cotangent_program(jaxpr, prefix: str, n: int, p: int, pc: int) -> list[str]:
    """C++ statements of a cotangent map `(t, y, p, c, v) -> (t̄, ȳ, p̄, c̄)` adding into `tb`,
    `yb[i]` and `pb[i]` (the parameters, then the lifted constants)."""
    eb = CEmitter(prefix)
    tb, yb, pb, cb = unroll(jaxpr, eb, consts(jaxpr), _inputs(n, p, pc, "v"))
    body = list(eb.lines)
    for target, values in (("tb", [tb.item()]), ("yb", yb), ("pb", [*pb, *cb])):
        for i, x in enumerate(values):
            lhs = "tb" if target == "tb" else f"{target}[{i}]"
            if not (_is_const(x) and x == 0):
                body.append(f"{lhs} += {eb.operand(x)};")
    return body


def model_source(
    hoisted: Hoisted, unit: Sequence[tuple[int, int]], record: tuple[int, int] = (0, 0)
) -> str:
    """`struct Model` of `model.cc`: sizes, unit groups, the components `[R0, R0 + NR)` that
    each jump records (`record`), `F` and `FT` (and the jump map `J` and `JT`, the step-end
    map `E` and `ET`, empty without one) as C++."""
    n, p, pc = hoisted.n, hoisted.p, hoisted.c.shape[0]
    body_f, rates = hoisted.forward_program
    # components whose rate is the constant 0 (a held command): the stages copy them
    still = ", ".join("true" if _is_const(x) and x == 0 else "false" for x in rates)
    body_b = _cotangent_program(hoisted.backward, "b", n, p, pc)
    jumps = hoisted.jumps
    jump = hoisted.jump_fn
    body_j = program(hoisted.jaxpr(jump), "u", "j", n, p, pc)[0] if jumps else []
    body_jb = _cotangent_program(hoisted.jaxpr(jump, True), "jb", n, p, pc) if jumps else []
    ends, end = hoisted.ends, hoisted.end_fn
    body_e = program(hoisted.jaxpr(end), "u", "e", n, p, pc)[0] if ends else []
    body_eb = _cotangent_program(hoisted.jaxpr(end, True), "eb", n, p, pc) if ends else []
    events = hoisted.events
    body_g = program(hoisted.jaxpr(hoisted.event_fn), "g", "g", n, p, pc)[0] if events else []
    units = ", ".join(f"{{{a}, {m}}}" for a, m in unit) or "{0, 0}"
    indent = "\n    "
    forward_args = "(T t, const T* y, const T* p, T* {}) {{\n    "
    backward_args = "(T t, const T* y, const T* p, const T* v, T* yb, T* pb, T& tb) {\n    "
    return (
        "struct Model {\n"
        f"  static constexpr int N = {n}, P = {p + pc}, NU = {len(unit)};\n"
        f"  static constexpr bool kJump = {'true' if jumps else 'false'};\n"
        f"  static constexpr bool kEnd = {'true' if ends else 'false'};\n"
        f"  static constexpr bool kEvent = {'true' if events else 'false'};\n"
        f"  static constexpr int R0 = {record[0]}, NR = {record[1]};\n"
        f"  static constexpr int unit[{max(len(unit), 1)}][2] = {{{units}}};\n"
        f"  static constexpr bool still[{n}] = {{{still}}};\n"
        + "".join(
            "  template <typename T>\n"
            f"  static RJ_INLINE void {name}{args}" + indent.join(body) + "\n  }\n"
            for name, args, body in (
                ("F", forward_args.format("k"), body_f),
                ("FT", backward_args, body_b),
                ("J", forward_args.format("u"), body_j),
                ("JT", backward_args, body_jb),
                ("E", forward_args.format("u"), body_e),
                ("ET", backward_args, body_eb),
                ("G", forward_args.format("g"), body_g),
            )
        )
        + "};\n"
    )


def header(
    method: type[diffrax.AbstractERK],
    dtype,
    model: str,
    part: str,
    times: bool = True,
    adaptive: bool = False,
    fixed: bool = False,
) -> tuple[str, str]:
    """`model.h` of the `part` (`"forward"` or `"backward"`; the latter with the cotangents of
    the steps' sizes and start times where `times`), of fixed steps or, with `adaptive`, of the
    per-body kernel (`model_adaptive.h`): the embedded pair's adaptive steps (the whole tableau
    and its error weights) or, also `fixed`, each body's fixed steps (`Tab::kFixed`, the
    tableau of fixed steps); and its handler's name (unique to all of these)."""
    if adaptive and not fixed:
        a, ct = tableau.embedded(method), tableau.all_stage_times(method)
    else:
        a, ct = tableau.coefficients(method), tableau.stage_times(method)
    rows = ",\n    ".join("{" + ", ".join(float(x).hex() for x in row) + "}" for row in a)
    dt = tableau.DTYPES[jnp.dtype(dtype).name]
    variant = ("adaptive" if adaptive else "") + ("fixed" if adaptive and fixed else "")
    key = f"{method.__name__}{dt}{model}{times}{variant}"
    digest = hashlib.sha256(key.encode()).hexdigest()[:16]
    kind = ("Adaptive" if adaptive else "") + ("Back" if part == "backward" else "")
    name = f"RigidjaxModel{kind}{digest}"
    macro = f"RJ_{'ADAPTIVE_' if adaptive else ''}{part.upper()}"
    text = (
        f"// Generated by rigidjax/kernels/model.py ({method.__name__}, {part}).\n#pragma once\n\n"
        + ("#define RJ_ADAPTIVE 1\n\n" if adaptive else "")
        + f"struct Tab {{\n  static constexpr int S = {a.shape[1]};\n"
        f"  static constexpr double c[{a.shape[0]}][{a.shape[1]}] = {{\n    {rows}}};\n"
        f"  static constexpr double ct[{a.shape[1]}] = "
        f"{{{', '.join(float(x).hex() for x in ct)}}};\n"
        "  static constexpr double a(int i, int l) { return c[i][l]; }\n"
        + (
            f"  static constexpr bool kFixed = {'true' if fixed else 'false'};\n"
            if adaptive
            else ""
        )
        + "};\n\n"
        f"constexpr bool kTimes = {'true' if times and not adaptive else 'false'};\n\n"
        f"{model}\n#define RJ_KERNEL {macro}({name}, {dt})\n"
    )
    return text, name


def headers(model_h: str, adaptive: bool = False) -> tuple[tuple[str, str], ...]:
    """The headers of a `model.cc` build: the generated `model.h`, the batch layout and, for
    adaptive steps, `model_adaptive.h`."""
    extra = (("model_adaptive.h", _text("model_adaptive.h")),) if adaptive else ()
    return (("model.h", model_h), ("model_layout.h", _text("model_layout.h")), *extra)


def linked(model_h: str) -> tuple[tuple[str, tuple[tuple[str, str], ...]], ...]:
    """The translation unit that the `model.cc` build of `model_h` links (`_build.build`'s
    `link`): `model_ffi.cc`, the XLA FFI handler of its kernel and dtype (`model_ffi.h`: its
    `RJ_KERNEL` without the name), with the batch layout; compiled once for all models."""
    match = re.search(r"^#define RJ_KERNEL (\w+)\(\w+, (\w+)\)$", model_h, re.MULTILINE)
    if match is None:
        raise ValueError("a generated model.h names its kernel in its last line (RJ_KERNEL)")
    handler = f"#define RJ_HANDLER {match[1]}({match[2]})\n"
    return (("model_ffi", (("model_ffi.h", handler), ("model_layout.h", _text("model_layout.h")))),)


@functools.cache
def _text(name: str) -> str:
    """A header of `rigidjax/kernels`, read once."""
    return resources.files("rigidjax.kernels").joinpath(name).read_text()

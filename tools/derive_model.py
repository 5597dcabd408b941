"""Derive the filter's balloon model and its Jacobians symbolically (sympy) and write them as plain-float
Python to ``firmware_py/estimator/generated.py`` (PX4's SymForce derivation, in miniature).

    .venv/bin/python tools/derive_model.py            # regenerate
    .venv/bin/python tools/derive_model.py --check    # exit 1 if the checked-in file differs

The model (paper Sec. 2.3 with the Morison form of the translational equation, docs/estimator.md):

    m_eff a_free = (1 + Ca) rho V dw/dt + D + (rho V - m) g up + W_rope down + R_rope
    D = k (1/2 rho Cd pi r^2) |u| u,  u = w - v (horizontal wind, no vertical wind)
    taut: a = a_free - (e . a_free + |v_t|^2 / |p_a|) e,  tension = m_eff (e . a_free + |v_t|^2 / |p_a|)
    with p_a = p + r z_body the attachment point (r z_body a parameter, from the attitude), e = p_a / |p_a|
    rope force on the balloon (what it aligns with): F = -tension e + W_rope down + R_rope

Inputs are plain floats; outputs are tuples of floats (no allocation beyond the tuple; a C port maps
each line to one line). The state columns of every Jacobian are, in order, COLUMNS below.
"""

from __future__ import annotations

import sys
from pathlib import Path

import sympy as sp
from sympy.printing.c import C99CodePrinter
from sympy.printing.pycode import PythonCodePrinter

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "firmware_py" / "estimator" / "generated.py"
OUT_C = ROOT / "firmware_c" / "src" / "generated.c"
OUT_H = ROOT / "firmware_c" / "src" / "generated.h"
OUT_PARAMS = ROOT / "firmware_c" / "src" / "params.h"
COLUMNS = ("pos_n", "pos_e", "pos_d", "vel_n", "vel_e", "vel_d", "wind_n", "wind_e", "wrate_n", "wrate_e", "drag_scale")
EPS2 = sp.Rational(1, 10**12)  # keeps |u| differentiable at u = 0


def symbols():
    pn, pe, pd, vn, ve, vd, wn, we, rn, re, k = sp.symbols("pn pe pd vn ve vd wn we rn re k", real=True)
    x = sp.Matrix([pn, pe, pd, vn, ve, vd, wn, we, rn, re, k])
    # parameters: m_eff, (1+Ca) rho V, c = rho Cd pi r^2 / 2, net lift of the balloon (N, up), rope weight
    # carried (N, down), its slope with pos_d (free ascent), rope cross-flow coefficient rho (Cn d L / 4),
    # the tether's attachment point relative to the centre, NED (r times the body down axis; taut only)
    par = sp.symbols("m_eff push c lift rope_w rope_slope kr att_n att_e att_d", real=True)
    return x, par


def free_forces(x, par):
    pn, pe, pd, vn, ve, vd, wn, we, rn, re, k = x
    m_eff, push, c, lift, rope_w, rope_slope, kr, *_ = par
    u = sp.Matrix([wn - vn, we - ve, -vd])
    speed = sp.sqrt(u.dot(u) + EPS2)
    weight = rope_w + rope_slope * pd  # rope_slope = -lambda g in free ascent (more rope airborne higher up)
    f = push * sp.Matrix([rn, re, 0]) + k * c * speed * u + sp.Matrix([0, 0, weight - lift])
    return f / m_eff, u


def taut_parts(x, par):
    pn, pe, pd, vn, ve, vd, *_ = x
    m_eff, push, c, lift, rope_w, rope_slope, kr, att_n, att_e, att_d = par
    a_free, u = free_forces(x, par)
    # the rope pulls at the attachment point (bottom of the sphere, paper Eq. 7), along the line from
    # it to the anchor: not along the centre's direction when the balloon leans differently from the
    # rope (the rope's weight tilts the rope force, and the balloon with it, towards the vertical)
    p = sp.Matrix([pn + att_n, pe + att_e, pd + att_d])
    v = sp.Matrix([vn, ve, vd])
    dist = sp.sqrt(p.dot(p))
    e = p / dist
    # cross-flow drag on the straight rope, the balloon carrying half of it: R = kr |u_n| u_n
    un = u - u.dot(e) * e
    rope = kr * sp.sqrt(un.dot(un) + EPS2) * un
    a_free = a_free + rope / m_eff
    vr = v.dot(e)
    pull = a_free.dot(e) + (v.dot(v) - vr * vr) / dist  # tension / m_eff that keeps |p| constant
    a = a_free - pull * e
    force = -pull * m_eff * e + sp.Matrix([0, 0, rope_w]) + rope
    return a, pull, force


def emit(name: str, doc: str, outputs: list[sp.Expr], args: list[sp.Symbol]) -> str:
    # no "basic" optimisations: they cost 10 minutes on the taut model and the code is as fast without
    reps, reduced = sp.cse(outputs, symbols=sp.numbered_symbols("t"))
    lines = [f"def {name}(", "    " + ", ".join(str(a) for a in args) + ",", ") -> tuple[float, ...]:"]
    lines.append(f'    """{doc}"""')
    printer = PythonCodePrinter({"standard": "python3"})
    for sym, expr in reps:
        lines.append(f"    {sym} = {printer.doprint(expr)}")
    body = ", ".join(printer.doprint(e) for e in reduced)
    lines.append(f"    return ({body},)")
    return "\n".join(lines).replace("math.sqrt", "sqrt")


class RealPrinter(C99CodePrinter):
    """C99 in the core's own real type (``bw_real``: float on the microcontroller, double for the
    reference build): constants cast to it, integer powers as products, half powers through BW_SQRT
    (sqrtf or sqrt), so that a float build never computes in double."""

    def _print_Rational(self, expr):
        return f"BW_R({float(expr)!r})"

    def _print_Float(self, expr):
        return f"BW_R({float(expr)!r})"

    def _print_Pow(self, expr):
        base, e = self.parenthesize(expr.base, 100), expr.exp
        if e.is_Integer:
            n = int(e)
            prod = "*".join([base] * abs(n))
            return f"({prod})" if n > 0 else f"(BW_R(1.0)/({prod}))"
        if e.is_Rational and e.q == 2:
            root = f"BW_SQRT({self._print(expr.base)})"
            k = abs(int(e.p)) // 2  # x^(p/2) = x^k sqrt(x)
            prod = "*".join([base] * k + [root])
            return f"({prod})" if e > 0 else f"(BW_R(1.0)/({prod}))"
        raise ValueError(f"no C form for the power {expr}")


# the generated C functions: name, outputs, what they return (the Python functions' tuples, in order)
def c_function(name: str, doc: str, outputs: list[sp.Expr], x, par) -> tuple[str, str, int]:
    reps, reduced = sp.cse(outputs, symbols=sp.numbered_symbols("t"))
    printer = RealPrinter()
    sig = f"void bw_{name}(const bw_real x[{len(x)}], const bw_real par[{len(par)}], bw_real out[{len(reduced)}])"
    lines = [f"/* {doc} */", sig, "{"]
    for i, s_ in enumerate(x):
        lines.append(f"    const bw_real {s_} = x[{i}];")
    for i, s_ in enumerate(par):
        lines.append(f"    const bw_real {s_} = par[{i}];")
    used = set().union(*(e.free_symbols for e in [*[r for _, r in reps], *reduced]))
    lines = [
        ln for ln in lines if not ln.startswith("    const bw_real ") or sp.Symbol(ln.split()[2], real=True) in used
    ]
    for sym, expr in reps:
        lines.append(f"    const bw_real {sym} = {printer.doprint(expr)};")
    for i, e in enumerate(reduced):
        lines.append(f"    out[{i}] = {printer.doprint(e)};")
    lines.append("}")
    return "\n".join(lines), sig + ";", len(reduced)


def generate_c() -> tuple[str, str]:
    x, par = symbols()
    a_free, _ = free_forces(x, par)
    a_taut, pull, force = taut_parts(x, par)
    n = force / sp.sqrt(force.dot(force))
    kr = par[6]
    a_plain, pull_plain, n_plain = a_taut.subs(kr, 0), pull.subs(kr, 0), n.subs(kr, 0)
    specs = [
        (
            "free_model",
            "Free ascent: acceleration (3) then d a / d x (3 x 11, row-major).",
            [*a_free, *a_free.jacobian(x)],
        ),
        (
            "taut_model",
            "Taut tether: acceleration (3), tension / m_eff, d a / d x (3 x 11), d(tension / m_eff) / d x (11).",
            [*a_taut, pull, *a_taut.jacobian(x), *sp.Matrix([pull]).jacobian(x)],
        ),
        (
            "taut_model_plain",
            "taut_model without rope drag (kr = 0).",
            [*a_plain, pull_plain, *a_plain.jacobian(x), *sp.Matrix([pull_plain]).jacobian(x)],
        ),
        (
            "rope_direction_plain",
            "rope_direction without rope drag (kr = 0).",
            [n_plain[0], n_plain[1], *n_plain[:2, :].jacobian(x)],
        ),
        (
            "rope_direction",
            "Unit rope force on the balloon, N and E (2), and their d / d x (2 x 11).",
            [n[0], n[1], *n[:2, :].jacobian(x)],
        ),
    ]
    head = [
        "/* GENERATED by tools/derive_model.py from the symbolic model: do not edit by hand.",
        " * x: " + ", ".join(COLUMNS) + "; par: " + ", ".join(str(p) for p in par) + ". */",
        "#ifndef BW_GENERATED_H",
        "#define BW_GENERATED_H",
        "",
        '#include "bw_real.h"',
        "",
        f"#define BW_N_COLUMNS {len(COLUMNS)}",
        f"#define BW_N_PARAMS {len(par)}",
    ]
    body = [
        "/* GENERATED by tools/derive_model.py from the symbolic model: do not edit by hand. */",
        '#include "generated.h"',
        "",
    ]
    for name, doc, outs in specs:
        code, proto, size = c_function(name, doc, outs, list(x), list(par))
        head += [f"#define BW_{name.upper()}_SIZE {size}", proto]
        body += [code, ""]
    head += ["", "#endif", ""]
    return "\n".join(head), "\n".join(body)


def generate_params() -> str:
    """The estimator's constants as C macros, from the Python modules that name them once."""
    from firmware_py.estimator import catenary, consistency, ekf, model, outputs, params, state, tuning

    lines = [
        "/* GENERATED by tools/derive_model.py from firmware_py/estimator (params, state, consistency,",
        " * tuning, model, catenary, outputs): the constants are named once, in Python. Do not edit. */",
        "#ifndef BW_PARAMS_H",
        "#define BW_PARAMS_H",
        "",
    ]

    def put(prefix: str, module, names=None) -> None:
        for key, value in vars(module).items():
            if names is not None and key not in names:
                continue
            if key.isupper() and isinstance(value, (int, float)) and not isinstance(value, bool):
                lines.append(f"#define {prefix}{key} {value!r}")
            elif key.isupper() and isinstance(value, tuple) and all(isinstance(v, float) for v in value):
                for i, v in enumerate(value):
                    lines.append(f"#define {prefix}{key}_{i} {v!r}")
        lines.append("")

    put("BW_", params)
    put(
        "BW_",
        state,
        {k for k in vars(state) if k.isupper() and k not in ("MODEL_COLUMNS", "STATE_NAMES", "MODE_NAMES")},
    )
    put(
        "BW_",
        consistency,
        {"ACCEL", "ALIGN", "RADIUS", "BARO", "MAG", "FORCE", "CONSISTENCY_S", "NIS_CLIP", "FORCE_NIS_CLIP", "FLAG_NIS",
         "FLAG_NIS_CLEAR", "SLOW_INNOV_S", "HEADING_MISFIT_RATIO"},
    )
    lines[-1:-1] = [f"#define BW_N_SOURCES {len(consistency.SOURCES)}"]
    put("BW_", ekf, {"RESET_INITIALISE", "RESET_TAUT", "RESET_HEIGHT", "RESET_DRAG"})
    lines[-1:-1] = [f"#define BW_N_RESET_KINDS {len(ekf.RESET_NAMES)}"]
    put("BW_", tuning)
    put("BW_", model, {"ADDED_MASS_COEFFICIENT", "SITE_AIR_K"})
    put("BW_", catenary, {"SHAPE_STEPS", "ANCHORED_NEWTON_STEPS"})
    put("BW_WINDCOV_", outputs, {"WINDOW_S"})
    lines += ["#endif", ""]
    return "\n".join(lines)


def outputs_all() -> dict[Path, str]:
    h, c = generate_c()
    return {OUT: generate(), OUT_H: h, OUT_C: c, OUT_PARAMS: generate_params()}


def generate() -> str:
    x, par = symbols()
    args = [*x, *par]
    a_free, _ = free_forces(x, par)
    a_taut, pull, force = taut_parts(x, par)
    n = force / sp.sqrt(force.dot(force))
    ja_free = a_free.jacobian(x)
    ja_taut = a_taut.jacobian(x)
    jpull = sp.Matrix([pull]).jacobian(x)
    jn = n[:2, :].jacobian(x)
    # the paper's model has no rope drag: the same expressions with kr = 0, much shorter
    kr = par[6]
    a_plain = a_taut.subs(kr, 0)
    pull_plain = pull.subs(kr, 0)
    n_plain = n.subs(kr, 0)
    parts = [
        '"""GENERATED by tools/derive_model.py from the symbolic model: do not edit by hand.',
        "",
        "Jacobian columns: " + ", ".join(COLUMNS) + ".",
        '"""',
        "",
        "# ruff: noqa: E501",
        "from math import sqrt",
        "",
        "COLUMNS = " + repr(COLUMNS),
        "",
        "",
        emit(
            "free_model",
            "Free ascent: acceleration (3) then d a / d x (3 x 11, row-major).",
            [*a_free, *ja_free],
            args,
        ),
        "",
        "",
        emit(
            "taut_model",
            "Taut tether: acceleration (3), tension / m_eff, d a / d x (3 x 11), d(tension / m_eff) / d x (11).",
            [*a_taut, pull, *ja_taut, *jpull],
            args,
        ),
        "",
        "",
        emit(
            "taut_model_plain",
            "taut_model without rope drag (kr = 0): the paper's model, evaluated every step.",
            [*a_plain, pull_plain, *a_plain.jacobian(x), *sp.Matrix([pull_plain]).jacobian(x)],
            args,
        ),
        "",
        "",
        emit(
            "rope_direction_plain",
            "rope_direction without rope drag (kr = 0).",
            [n_plain[0], n_plain[1], *n_plain[:2, :].jacobian(x)],
            args,
        ),
        "",
        "",
        emit(
            "rope_direction",
            "Unit rope force on the balloon, N and E components (2), and their d / d x (2 x 11).",
            [n[0], n[1], *jn],
            args,
        ),
        "",
    ]
    return "\n".join(parts)


def main() -> int:
    files = outputs_all()
    if "--check" in sys.argv:
        stale = [p.relative_to(ROOT) for p, code in files.items() if not p.exists() or p.read_text() != code]
        for p in stale:
            print(f"{p} differs from tools/derive_model.py")
        if not stale:
            print("generated Python and C are up to date")
        return 1 if stale else 0
    for p, code in files.items():
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(code)
        print(f"wrote {p.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

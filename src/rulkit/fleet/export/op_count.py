"""Operations per update, counted in the generated C (docs/rul-on-the-device.md section 5).

The count is dynamic and at the source level: the export and its PC driver are compiled with
``--coverage -O0``, the driver runs a steady-state record twice (``n`` and ``2 n``
acquisitions), and ``gcov`` gives how often each source line ran; the difference of the two
runs divided by ``n`` is each line's executions per update in steady state. Each line's
arithmetic is read by a small C tokenizer (:func:`line_operations`): multiplications,
divisions, additions and subtractions (compound assignments included), negations,
comparisons and math-library calls. In the floating-point builds only lines that touch a
floating-point value (a name declared with the real type, a field of the state or output, a
floating literal) count, so loop counters and the acquisition count are left out; in the
fixed-point build every integer operation counts (it is the arithmetic). A line counts all of
its operations each time it runs (both arms of a conditional expression).
"""

from __future__ import annotations

import re
import subprocess
from collections import Counter
from pathlib import Path

import numpy as np

from rulkit.fleet.export.device_spec import DeviceSpec, ExportError

MATH_CALLS = ("log", "log1p", "exp", "expm1", "sqrt", "pow", "erfc", "fabs", "copysign",
              "ldexp")
CATEGORIES = ("mul", "div", "add", "neg", "cmp", "log", "other_math")
_TOKEN = re.compile(
    r"0[xX][0-9A-Fa-f]+[uUlL]*|(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?[fFuUlL]*|[A-Za-z_]\w*"
    r"|->|\+\+|--|<<=|>>=|<<|>>|<=|>=|==|!=|&&|\|\||[-+*/]=|[-+*/<>=!&|^~?:;,(){}\[\].%]")
_TYPES = {"double", "float", "int", "char", "void", "unsigned", "signed", "long", "short",
          "const", "static", "uint8_t", "uint32_t", "uint64_t", "int32_t", "int64_t"}
_KEYWORDS = {"return", "if", "else", "for", "while", "case", "sizeof"}


def _strip(line: str) -> str:
    line = re.sub(r"/\*.*?\*/", " ", line)
    line = re.sub(r"//.*", "", line)
    return re.sub(r'"(?:\\.|[^"\\])*"', '""', line)


def _is_float_literal(tok: str) -> bool:
    return bool(re.fullmatch(r"(?:\d+\.\d*|\.\d+|\d+[eE][-+]?\d+|\d+\.?\d*[eE][-+]?\d+)[fF]?"
                             r"|\d+\.\d*[fF]", tok)) or tok in ("INFINITY", "NAN")


def line_operations(line: str, types: set[str]) -> Counter[str]:
    """Arithmetic operations on one line of C (comments stripped). ``types`` are extra type
    names (the export's ``<prefix>_state`` ...), after which ``*`` declares a pointer."""
    toks = _TOKEN.findall(_strip(line))
    ops: Counter[str] = Counter()
    type_names = _TYPES | types
    for i, tok in enumerate(toks):
        prev = toks[i - 1] if i else ""
        operand_before = (prev in (")", "]") or re.fullmatch(r"[\w.]+", prev) is not None) and (
            prev not in type_names and prev not in _KEYWORDS)
        if tok in ("*", "*="):
            if tok == "*=" or operand_before:
                ops["mul"] += 1
        elif tok in ("/", "/="):
            ops["div"] += 1
        elif tok in ("+", "+=", "-=") or (tok == "-" and operand_before):
            ops["add"] += 1
        elif tok == "-":
            ops["neg"] += 1
        elif tok in ("<", ">", "<=", ">=", "==", "!="):
            ops["cmp"] += 1
        elif i + 1 < len(toks) and toks[i + 1] == "(":
            base = tok[:-1] if tok.endswith("f") and tok[:-1] in MATH_CALLS else tok
            if base == "log":
                ops["log"] += 1
            elif base in MATH_CALLS:
                ops["other_math"] += 1
    return ops


def real_names(source: str, header: str, real: str, prefix: str) -> set[str]:
    """Names declared with the build's floating type in the sources (variables, parameters,
    constants, struct fields, functions returning it)."""
    reals = {real, f"{prefix}_real", f"{prefix}_time", "double"}
    names: set[str] = set()
    decl = re.compile(rf"\b(?:{'|'.join(map(re.escape, reals))})\s+([^;{{)]*)")
    for text in (source, header):
        for m in decl.finditer(_strip(text)):
            for part in m.group(1).split(","):
                name = re.match(r"\s*\**\s*([A-Za-z_]\w*)", part)
                if name:
                    names.add(name.group(1))
    return names


def _gcov_counts(workdir: Path, source: str) -> dict[int, int]:
    out = subprocess.run(["gcov", "-t", "-o", str(workdir), source], cwd=workdir,
                         capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise ExportError(f"gcov failed: {out.stderr}")
    counts = {}
    for line in out.stdout.splitlines():
        parts = line.split(":", 2)
        if len(parts) == 3 and parts[0].strip().rstrip("*").isdigit():
            counts[int(parts[1])] = int(parts[0].strip().rstrip("*"))
    return counts


_FUNCTION = re.compile(r"^(?:static\s+)?[A-Za-z_][\w ]*?\**\s*\b([A-Za-z_]\w*)\(")


def steady_state_operations(device: DeviceSpec, workdir: str | Path, number: str = "double",
                            prefix: str = "rk", n: int = 2000) -> dict[str, dict[str, float]]:
    """Operations per update (:data:`CATEGORIES`) of the export in steady state, per C
    function and in ``"total"``: a regular record of HI growing from 0.2 to 0.6 (module
    docstring). A helper's operations (``clip``, ``time_to_one``...) are its own, whoever
    calls it."""
    from rulkit.fleet.export.verify import compiler, write_sources

    d = Path(workdir)
    files = write_sources(device, d, number, prefix)
    cc = compiler()
    assert cc is not None
    objs = []
    for name in (prefix, f"{prefix}_harness", f"{prefix}_driver"):
        flags = ["--coverage", "-O0"] if name == prefix else ["-O0"]
        subprocess.run([cc, "-std=c99", *flags, "-c", f"{name}.c", "-o", f"{name}.o"],
                       cwd=d, check=True)
        objs.append(f"{name}.o")
    subprocess.run([cc, "--coverage", "-o", "count", *objs, "-lm"], cwd=d, check=True)
    n_in = device.hi_model.n if device.hi_model is not None else 1
    totals = []
    for m in (n, 2 * n):
        for f in d.glob("*.gcda"):
            f.unlink()
        t = device.config.dt * np.arange(1.0, m + 1)
        hi = np.linspace(0.2, 0.6, m)
        x = np.repeat(hi[:, None], n_in, axis=1) / np.sqrt(n_in)
        blob = (np.array([1, m], dtype=np.uint32).tobytes()
                + np.array([0, m], dtype=np.uint32).tobytes() + t.tobytes() + x.tobytes())
        (d / "in.bin").write_bytes(blob)
        subprocess.run(["./count", "in.bin", "out.bin", "0"], cwd=d, check=True)
        totals.append(_gcov_counts(d, f"{prefix}.c"))
    source = files[f"{prefix}.c"].splitlines()
    reals = real_names(files[f"{prefix}.c"], files[f"{prefix}.h"],
                       {"double": "double", "float": "float", "fixed": "int32_t"}[number],
                       prefix)
    floats = number != "fixed"
    types = {f"{prefix}_state", f"{prefix}_output", f"{prefix}_real", f"{prefix}_time"}
    per_update: dict[str, dict[str, float]] = {"total": {}}
    function = ""
    for lineno, text in enumerate(source, start=1):
        head = _FUNCTION.match(text)
        if head and not text.rstrip().endswith(";"):
            function = head.group(1)
        runs = (totals[1].get(lineno, 0) - totals[0].get(lineno, 0)) / n
        if runs <= 0:
            continue
        toks = set(_TOKEN.findall(_strip(text)))
        if floats and not (toks & reals or any(_is_float_literal(t) for t in toks)):
            continue
        for k, v in line_operations(text, types).items():
            for key in ("total", function):
                counts = per_update.setdefault(key, {})
                counts[k] = counts.get(k, 0.0) + runs * v
    return {f: {k: round(float(c.get(k, 0.0)), 3) for k in CATEGORIES}
            for f, c in per_update.items()}


__all__ = ["CATEGORIES", "MATH_CALLS", "line_operations", "real_names",
           "steady_state_operations"]

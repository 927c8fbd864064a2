"""C99 sources of one component type's prognosis chain, rendered from templates
(docs/rul-on-the-device.md section 1).

:func:`generate_c` fills the templates in ``templates/`` (plain C with Jinja2 placeholders for
the constants and the parts a component type has or not) from a
:class:`~rulkit.fleet.export.device_spec.DeviceSpec` and returns ``{file name: text}``: a header
with the documented API and one source file. The C is computed from the same constants as the
Python reference, in the same order of operations, so that the double build agrees with
:mod:`rulkit.fleet.tracking.tracker_chain` and :mod:`rulkit.fleet.learned.degradation` to
rounding (tests/fleet/export).

Number formats: ``double``; ``float`` (the same template with float arithmetic and float math
functions); ``fixed`` (the tracker chain in int32 fixed point, Q formats chosen from the
settings by :func:`rulkit.fleet.export.fixed_point.q_formats`).
"""

from __future__ import annotations

import json
import math
import re
import zlib
from pathlib import Path
from typing import Any

from rulkit.fleet.export.device_spec import DeviceSpec, ExportError
from rulkit.fleet.export.learned_device import learned_device
from rulkit.fleet.tracking.tracker_chain import MIN_UPDATES_VALID

NUMBER_FORMATS = ("double", "float", "fixed")
FORMAT_VERSION = 1
_NUMBER_CODE = {"double": 1, "float": 2, "fixed": 3}
_HEADER_BYTES = 20
_NAME = re.compile(r"[a-z][a-z0-9_]{0,30}")


def c_literal(x: float, number: str) -> str:
    """``x`` as a C constant of the build's real type: the shortest decimal that reads back as
    the same double (``repr``), with an ``f`` suffix in the float build; infinities as
    ``INFINITY``."""
    x = float(x)
    if math.isnan(x):
        raise ExportError("a constant is NaN")
    if math.isinf(x):
        return "INFINITY" if x > 0 else "-INFINITY"
    text = repr(x)
    if "e" not in text and "." not in text:
        text += ".0"
    return text + ("f" if number == "float" else "")


def template_environment() -> Any:
    import jinja2

    return jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(Path(__file__).parent / "templates")),
        undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True,
        keep_trailing_newline=True, autoescape=False)


def _tracker_constants(device: DeviceSpec, lit: Any) -> dict[str, Any]:
    cfg = device.config
    g = cfg.gains()
    q = cfg.paris_exponent if cfg.load_exponent is None else cfg.load_exponent
    p = 0.5 * cfg.paris_exponent
    return {
        "dt": lit(cfg.dt), "alpha1": lit(g.alpha1), "beta1": lit(g.beta1),
        "alpha2": lit(g.alpha2), "beta2": lit(g.beta2), "gamma2": lit(g.gamma2),
        "lambda_hi_text": f"{cfg.lambda_hi:g}", "lambda_rul_text": f"{cfg.lambda_rul:g}",
        "dhi_min": lit(1.0 / cfg.design_life), "hi_floor": lit(cfg.hi_floor),
        "hi_max": lit(cfg.hi_max), "paris_two": cfg.paris_exponent == 2.0,
        "paris_p": lit(p), "one_minus_p": lit(1.0 - p), "paris_m": f"{cfg.paris_exponent:g}",
        "hi_sigma": lit(cfg.hi_sigma), "load_factor": f"{cfg.load_factor:g}",
        "load_exponent": f"{q:g}",
        "load_up": lit((1.0 + cfg.load_factor) ** q),
        "load_down": lit((1.0 - cfg.load_factor) ** q),
        "valid_lo": lit(cfg.valid_drul[0]), "valid_hi": lit(cfg.valid_drul[1]),
        "valid_d2rul": lit(cfg.valid_d2rul), "warn_hi": lit(cfg.warn_hi),
        "warn_rul": lit(cfg.warn_rul), "alarm_hi": lit(cfg.alarm_hi),
        "initiation": cfg.initiation,
        "two_point": cfg.initiation in ("two-point", "measured"),
        "n_init": 3 if cfg.initiation == "two-point" else (
            2 if cfg.initiation == "measured" else 1),
        "min_updates": MIN_UPDATES_VALID, "rul_clip": cfg.rul_clip,
    }


def _math_literals(number: str) -> dict[str, str]:
    def lit(x: float) -> str:
        return c_literal(x, number)

    return {
        "zero": lit(0.0), "one": lit(1.0), "half": lit(0.5), "two": lit(2.0), "four": lit(4.0),
        "sqrt1_2": lit(math.sqrt(0.5)), "sqrt_2pi": lit(math.sqrt(2.0 * math.pi)),
        "half_log_2pi": lit(0.5 * math.log(2.0 * math.pi)), "ln2": lit(math.log(2.0)),
        # Abramowitz & Stegun 26.2.23: the start of the normal quantile's Halley steps
        "as_c0": lit(2.515517), "as_c1": lit(0.802853), "as_c2": lit(0.010328),
        "as_d1": lit(1.432788), "as_d2": lit(0.189269), "as_d3": lit(0.001308),
        "halley_steps": "3" if number == "double" else "2",
        # below it erfc underflows (double: erfc(26.5) ~ 1e-307; float: erfcf(9) ~ 4e-37)
        "erfc_limit": lit(37.0 if number == "double" else 12.0),
        # eq. (6)'s tolerances scale with the precision: squaring the quadratic's rounding
        # error gives roots off by ~sqrt(eps) (double 1e-8, float 2.4e-4)
        "lin_tol": lit(1e-14 if number == "double" else 1e-6),
        "sign_tol": lit(1e-7 if number == "double" else 3e-3),
        "tiny": lit(1e-300 if number == "double" else 1e-30),
        # eq. (5b)'s search stops where two successive trials this close (relative, in u)
        # straddle the root, or the bracket is this wide: Python's in double, a few float eps
        "fp_utol": lit(1e-12 if number == "double" else 1e-6),
        "fp_width": lit(1e-15 if number == "double" else 1e-7),
    }


def _state_layout(number: str, learned_fields: list[str]) -> tuple[list[dict[str, Any]], int]:
    """Byte offsets of the saved state (persistence.c.j2) and the offset of the CRC."""
    width = 8 if number == "double" else 4
    names = ["t", "hi", "fhi", "dhi", "rul", "frul", "drul", "d2rul", *learned_fields]
    fields = []
    off = _HEADER_BYTES
    for name in names:
        w = 4 if (name == "t" and number == "fixed") else width
        ctype = {8: "f64", 4: "f32" if number == "float" else "i32"}[w]
        if name == "t" and number == "fixed":
            ctype = "u32"
        fields.append({"name": name, "offset": off, "ctype": ctype + " " * (7 - len(ctype))})
        off += w
    return fields, off


def check_prefix(prefix: str) -> str:
    """A C identifier prefix: lower case letters, digits and ``_``, starting with a letter."""
    if not _NAME.fullmatch(prefix):
        raise ExportError(f"prefix {prefix!r}: expected 1-31 characters a-z, 0-9 or _, "
                          "starting with a letter")
    return prefix


def template_context(device: DeviceSpec, number: str, prefix: str) -> dict[str, Any]:
    from rulkit import __version__

    def lit(x: float) -> str:
        return c_literal(x, number)

    learned = None
    learned_fields: list[str] = []
    if device.learned is not None:
        dev = learned_device(device.learned, device.one_measurement)
        consts = {k: (v if isinstance(v, (bool, int, str)) else
                      [lit(x) for x in v] if isinstance(v, list) else lit(v))
                  for k, v in dev.constants.items()}
        learned = {**consts, "kind": dev.kind, "template": dev.template,
                   "tau_time": c_literal(device.learned.time_scale, "double"),
                   "state_fields": dev.state_fields,
                   "levels_text": "0.5, 0.05, 0.95"}
        learned_fields = [f for f, _ in dev.state_fields]
    fields, crc_offset = _state_layout(number, learned_fields)
    hm = device.hi_model
    unit = device.learned.time_unit if device.learned is not None else ""
    ctx: dict[str, Any] = {
        "p": prefix, "P": prefix.upper(), "name": device.name, "source": device.source,
        "version": __version__, "number": number,
        "real": {"double": "double", "float": "float", "fixed": "int32_t"}[number],
        "fn": (lambda f: f + "f") if number == "float" else (lambda f: f),
        "c": _tracker_constants(device, lit), "learned": learned,
        "n_ci": hm.n if hm is not None else 0,
        "ci_names": list(hm.names) if hm is not None else [],
        "ci_offset": [lit(v) for v in hm.offset] if hm is not None else [],
        "hi_scale": [[lit(v) for v in row] for row in hm.scale] if hm is not None else [],
        "pfa": f"{hm.pfa:g}" if hm is not None else "",
        "time_unit_text": unit or "the database's time unit",
        "hi_max_text": f"{device.config.hi_max:g}",
        # an interval whose float64 arithmetic would overflow (the store refuses it too)
        "dt_max": c_literal(1e300, "double"),
        "hi_sigma_text": f"{device.config.hi_sigma:g}",
        "load_text": f"{100 * device.config.load_factor:g} %",
        "format_version": FORMAT_VERSION, "number_code": _NUMBER_CODE[number],
        "flags": (1 if learned else 0) | (2 if hm is not None else 0),
        "fields": fields, "crc_offset": crc_offset, "state_bytes": crc_offset + 4,
        "state_doc": f"{len(fields) + 2} numbers" + (" and the learned posterior"
                                                      if learned else ""),
        **_math_literals(number),
    }
    return ctx


def _model_id(ctx: dict[str, Any]) -> str:
    """CRC-32 of every constant of the export: a saved state names the model it belongs to."""
    keys = ("number", "c", "learned", "ci_offset", "hi_scale", "fx")
    text = json.dumps({k: ctx.get(k) for k in keys}, sort_keys=True, default=str)
    return f"0x{zlib.crc32(text.encode()):08X}"


def generate_c(device: DeviceSpec, number: str = "double", prefix: str = "rk") -> dict[str, str]:
    """The C99 header and source of ``device`` as ``{"<prefix>.h": ..., "<prefix>.c": ...}``.

    ``number``: ``double``, ``float`` or ``fixed`` (the tracker chain only: a learned model or
    a CI -> HI map raises :class:`ExportError`, see
    :func:`rulkit.fleet.export.fixed_point.fixed_context`). ``prefix`` names every public
    symbol (``<prefix>_update``, ``<prefix>_state``...).
    """
    if number not in NUMBER_FORMATS:
        raise ExportError(f"number format {number!r}: expected one of {NUMBER_FORMATS}")
    check_prefix(prefix)
    ctx = template_context(device, number, prefix)
    template = "device.c.j2"
    if number == "fixed":
        from rulkit.fleet.export.fixed_point import fixed_context

        ctx.update(fixed_context(device))
        template = "device_fixed.c.j2"
    ctx["model_id"] = _model_id(ctx)
    env = template_environment()
    return {f"{prefix}.h": env.get_template("device.h.j2").render(**ctx),
            f"{prefix}.c": env.get_template(template).render(**ctx)}


def write_c(device: DeviceSpec, out: str | Path, number: str = "double",
            prefix: str = "rk") -> list[Path]:
    """:func:`generate_c` written into the directory ``out`` (created); returns the paths."""
    files = generate_c(device, number, prefix)
    d = Path(out)
    d.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, text in files.items():
        path = d / name
        path.write_text(text)
        paths.append(path)
    return paths


__all__ = ["FORMAT_VERSION", "NUMBER_FORMATS", "c_literal", "check_prefix", "generate_c",
           "write_c"]

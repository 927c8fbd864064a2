"""RUL on the device: the figures of the C export (docs/rul-on-the-device.md section 5).

    python benchmarks/bench_export.py            # everything; installs gcc-arm-none-eabi as root
    python benchmarks/bench_export.py --no-arm   # without the Cortex-M4 cross-compilation

For the Lu & Meeker crack data (the tracker settings fitted by `fit_tracker_config`, the learned
Paris model fitted by `fit_model`), in each number format: operations per update counted in the
generated code (beside the seed's 11 multiplications, 9 additions, 1 logarithm), bytes of state
per component, code and constant sizes on this machine, ns per update (C through the harness
vs the Python reference, medians of repeats in one run, ratio=), the error of float and fixed
point against Python over long records (with the bound the tests enforce), and the same
sources cross-compiled for a Cortex-M4 (arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb
-mfloat-abi=hard -mfpu=fpv4-sp-d16 -Os): text/data/bss of the object and of a linked program.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from rulkit.fleet.export.device_spec import DeviceSpec
from rulkit.fleet.export.generator import template_context, template_environment
from rulkit.fleet.export.op_count import steady_state_operations
from rulkit.fleet.export.verify import (
    ERROR_BOUNDS,
    STRICT_FLAGS,
    build,
    long_record_case,
    long_records,
    python_reference,
    scaled_error,
)
from rulkit.fleet.learned.datasets import fatigue_histories
from rulkit.fleet.learned.degradation import fit_model
from rulkit.fleet.tracking.tracker_chain import TrackerState, tracker_update
from rulkit.fleet.tracking.tracker_run import tracker_run
from rulkit.fleet.tracking.tracker_settings import fit_tracker_config
from timing import median_time

ARM_FLAGS = ("-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16", "-Os",
             "-ffunction-sections", "-fdata-sections")
SEED_CHAIN = ("track_hi", "paris_rul", "track_rul")


def specs() -> dict[str, DeviceSpec]:
    hist = fatigue_histories()
    cfg = fit_tracker_config(hist)
    model = fit_model(hist, "paris", time_unit="kcycles")
    return {"chain": DeviceSpec("crack", "Lu & Meeker", cfg),
            "chain+learned": DeviceSpec("crack", "Lu & Meeker", cfg, None, model)}


def variants(sp: dict[str, DeviceSpec]) -> list[tuple[str, str, DeviceSpec]]:
    return [("chain", n, sp["chain"]) for n in ("double", "float", "fixed")] + [
        ("chain+learned", n, sp["chain+learned"]) for n in ("double", "float")]


def fmt_ops(c: dict[str, float]) -> str:
    return (f"{c['mul']:g} mul, {c['div']:g} div, {c['add']:g} add/sub, {c['log']:g} log, "
            f"{c['other_math']:g} other math, {c['cmp']:g} compare")


def operations(work: Path, sp: dict[str, DeviceSpec]) -> None:
    print("\n# operations per update, steady state (counted in the generated C; seed 004: "
          "11 multiplications, 9 additions, 1 logarithm)")
    for part, number, spec in variants(sp):
        ops = steady_state_operations(spec, work / f"ops_{part}_{number}", number)
        print(f"{part:14s} {number:6s} whole update: {fmt_ops(ops['total'])}")
        if number == "fixed":  # the work is in the arithmetic helpers
            for f in ("ln_hi", "mul_q", "div_round", "sat"):
                print(f"{'':21s} in {f}: {fmt_ops(ops[f])}")
        else:
            chain = {k: sum(ops.get(f, {}).get(k, 0.0) for f in SEED_CHAIN)
                     for k in ops["total"]}
            print(f"{'':21s} the seed's chain (track_hi, paris_rul, track_rul): "
                  f"{fmt_ops(chain)}")


def section_sizes(obj: Path, size_tool: str) -> dict[str, int]:
    out = subprocess.run([size_tool, "-A", str(obj)], capture_output=True, text=True,
                         check=True).stdout
    sizes: dict[str, int] = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].startswith(".") and parts[1].isdigit():
            key = parts[0].split(".")[1]
            sizes[key] = sizes.get(key, 0) + int(parts[1])
    return sizes


def sizes_and_speed(work: Path, sp: dict[str, DeviceSpec], repeats: int) -> None:
    print("\n# state, code and speed on this machine (x86-64, cc -O2)")
    start, t, hi = long_records(np.random.default_rng(0), 4, 20_000, irregular=False)
    n = t.size
    for part, number, spec in variants(sp):
        lib = build(spec, work / f"lib_{part}_{number}", number)
        cc = shutil.which(os.environ.get("CC", "cc")) or "cc"
        obj = work / f"lib_{part}_{number}" / "rk.o"
        subprocess.run([cc, *STRICT_FLAGS, "-c", str(obj.with_suffix(".c")), "-o", str(obj)],
                       check=True)
        s = section_sizes(obj, "size")
        saved = lib.state_bytes(t[:3], hi[:3], 4096)[1]
        n_saved = int(template_context(spec, number, "rk")["state_bytes"])
        assert len(saved) >= n_saved
        sec = median_time(lambda lib=lib: lib.run(start, t, hi), repeats)
        print(f"{part:14s} {number:6s} state {lib.state_struct_bytes} B in RAM "
              f"(sizeof), {n_saved} B saved; code .text {s.get('text', 0)} B, constants "
              f".rodata {s.get('rodata', 0)} B, .data {s.get('data', 0)} B, .bss "
              f"{s.get('bss', 0)} B; {1e9 * sec / n:.1f} ns per update (median of {repeats}, "
              f"{n} updates through the harness)")
    cfg = sp["chain"].config
    py_seq = median_time(lambda: tracker_run(TrackerState.empty(4), start, t, hi, cfg,
                                             strategy="python"), max(1, repeats // 2))
    c_chain = median_time(lambda: build_cache["lib"].run(start, t, hi), repeats)
    b = 100_000
    st = TrackerState.empty(b)
    for k in range(5):
        st, _ = tracker_update(st, np.full(b, cfg.dt * (k + 1)), np.full(b, 0.3 + 0.01 * k), cfg)
    tt, hh = np.full(b, cfg.dt * 6), np.full(b, 0.36)
    py_vec = median_time(lambda: tracker_update(st, tt, hh, cfg), repeats)
    print(f"chain double: C {1e9 * c_chain / n:.1f} ns/update vs Python per-acquisition loop "
          f"(tracker_run, strategy python) {1e9 * py_seq / n:.0f} ns/update: "
          f"ratio={py_seq / c_chain:.0f}")
    print(f"chain double: C {1e9 * c_chain / n:.1f} ns/update (one component after another) vs "
          f"Python vectorised over {b} components (tracker_update) {1e9 * py_vec / b:.1f} "
          f"ns/update: ratio={py_vec / b / (c_chain / n):.2f}")


build_cache: dict[str, object] = {}


def errors(work: Path) -> None:
    print("\n# number formats against the Python reference over long records "
          "(max |C - Python| / max |Python| per output; bound = what the tests enforce)")
    case, start, t, hi = long_record_case(4, 20_000)
    cfg, model = case.config, case.learned
    print(f"4 records x 20000 acquisitions, HI 0.05-0.3 -> 1 (noise sd 0.01); tracker "
          f"{cfg.to_dict()}; learned {model}")
    for number in ("double", "float", "fixed"):
        spec = DeviceSpec("long", "synthetic", cfg, None, model if number != "fixed" else None)
        ref = python_reference(spec, start, t, hi)
        got = build(spec, work / f"err_{number}", number).run(start, t, hi)
        cols = [c for c in ref if c not in ("valid", "level", "new_alert")]
        bound = ERROR_BOUNDS.get(number, {})
        text = ", ".join(f"{c} {scaled_error(got[c], ref[c]):.2g}"
                         + (f" (<= {bound[c]:g})" if c in bound else "") for c in cols)
        flags = ", ".join(f"{f} differs in {int(np.sum(got[f] != ref[f]))}"
                          for f in ("valid", "level"))
        print(f"{number:6s} {text}; {flags} of {t.size} rows")


def ensure_arm() -> str | None:
    gcc = shutil.which("arm-none-eabi-gcc")
    if gcc:
        return gcc
    if os.geteuid() != 0:
        print("arm-none-eabi-gcc missing (install gcc-arm-none-eabi and libnewlib-arm-none-eabi"
              ", as root this script does it)")
        return None
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    subprocess.run(["apt-get", "update", "-qq"], check=True, env=env)
    subprocess.run(["apt-get", "install", "-y", "-qq", "gcc-arm-none-eabi",
                    "libnewlib-arm-none-eabi"], check=True, env=env, stdout=subprocess.DEVNULL)
    return shutil.which("arm-none-eabi-gcc")


def arm(work: Path, sp: dict[str, DeviceSpec]) -> None:
    print("\n# Cortex-M4 (arm-none-eabi-gcc " + " ".join(ARM_FLAGS) + ")")
    gcc = ensure_arm()
    if gcc is None:
        return
    version = subprocess.run([gcc, "--version"], capture_output=True, text=True).stdout
    print(version.splitlines()[0])
    env = template_environment()
    for part, number, spec in variants(sp):
        d = work / f"arm_{part}_{number}"
        lib_dir = work / f"lib_{part}_{number}"
        d.mkdir(parents=True, exist_ok=True)
        for name in ("rk.h", "rk.c"):
            shutil.copy(lib_dir / name, d / name)
        ctx = template_context(spec, number, "rk")
        if number == "fixed":
            from rulkit.fleet.export.fixed_point import fixed_context

            ctx.update(fixed_context(spec))
        (d / "main.c").write_text(env.get_template("target_main.c.j2").render(**ctx))
        subprocess.run([gcc, *STRICT_FLAGS[:-1], *ARM_FLAGS, "-c", "rk.c", "-o", "rk.o"],
                       cwd=d, check=True)
        subprocess.run([gcc, *STRICT_FLAGS[:-1], *ARM_FLAGS, "--specs=nano.specs",
                        "--specs=nosys.specs", "-Wl,--gc-sections", "main.c", "rk.c", "-o",
                        "main.elf", "-lm"], cwd=d, check=True, capture_output=True)
        obj = subprocess.run(["arm-none-eabi-size", "rk.o"], cwd=d, capture_output=True,
                             text=True, check=True).stdout.splitlines()[1].split()
        img = subprocess.run(["arm-none-eabi-size", "main.elf"], cwd=d, capture_output=True,
                             text=True, check=True).stdout.splitlines()[1].split()
        print(f"{part:14s} {number:6s} rk.o text {obj[0]} data {obj[1]} bss {obj[2]}; linked "
              f"program with newlib-nano, libm, startup: text {img[0]} data {img[1]} bss "
              f"{img[2]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-arm", action="store_true", help="skip the Cortex-M4 sizes")
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} "
          f"{os.getloadavg()[2]:.2f} on {os.cpu_count()} cores; python {sys.version.split()[0]}")
    sp = specs()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        build_cache["lib"] = build(sp["chain"], work / "speed", "double")
        operations(work, sp)
        sizes_and_speed(work, sp, args.repeats)
        errors(work)
        if not args.no_arm:
            arm(work, sp)


if __name__ == "__main__":
    main()

"""RUL on the device: the figures of the C export (docs/rul-on-the-device.md section 5).

    python benchmarks/bench_export.py            # everything; installs gcc-arm-none-eabi as root
    python benchmarks/bench_export.py --no-arm   # without the Cortex-M4 cross-compilation
    python benchmarks/bench_export.py --only-hi-noise   # the learned HI-noise models alone
    python benchmarks/bench_export.py --only-table      # the error of a coarser eq. (5b) table

For the Lu & Meeker crack data (the tracker settings fitted by `fit_tracker_config`, the learned
Paris model fitted by `fit_model`), in each number format: operations per update counted in the
generated code (beside the seed's 11 multiplications, 9 additions, 1 logarithm), bytes of state
per component, code and constant sizes on this machine, ns per update (C through the harness
vs the Python reference, medians of repeats in one run, ratio=), the error of float and fixed
point against Python over long records (with the bound the tests enforce), and the same
sources cross-compiled for a Cortex-M4 (arm-none-eabi-gcc -mcpu=cortex-m4 -mthumb
-mfloat-abi=hard -mfpu=fpv4-sp-d16 -Os): text/data/bss of the object and of a linked program.
Then the learned HI-noise models (paris-additive, -multiplicative, -mixed) fitted on synthetic
fleets of their noise kinds: the iterated update's operations and its cost per acquisition in C
against the Python model (``--only-hi-noise`` runs this part alone).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from rulkit.fleet.export.device_spec import DeviceSpec
from rulkit.fleet.export.generator import template_context, template_environment
from rulkit.fleet.export.op_count import steady_state_operations
from rulkit.fleet.export.verify import (
    ERROR_BOUNDS,
    LEARNED_COLUMNS,
    STRICT_FLAGS,
    DeviceLibrary,
    build,
    long_record_case,
    long_records,
    python_reference,
    relative_error,
    scaled_error,
    segments,
)
from rulkit.fleet.learned.datasets import GOAL_FLEETS, fatigue_histories, goal_fleet
from rulkit.fleet.learned.degradation import UnitState, fit_model
from rulkit.fleet.learned.hi_noise import NOISES, HiNoiseModel, fit_hi_noise
from rulkit.fleet.learned.histories import histories_from_frame
from rulkit.fleet.store.learned_state import LEVELS
from rulkit.fleet.tracking.tracker_chain import TrackerState, tracker_update
from rulkit.fleet.tracking.tracker_run import tracker_run
from rulkit.fleet.tracking.tracker_settings import fit_tracker_config
from timing import median_time

ARM_FLAGS = ("-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16", "-Os",
             "-ffunction-sections", "-fdata-sections")
SEED_CHAIN = ("track_hi", "paris_rul", "track_rul")
QUANTILE_FUNCTIONS = ("learned_quantiles", "learned_monotone", "quantile_root",
                      "rk_normal_quantile", "rk_log_normal_cdf", "learned_root",
                      "learned_log_surv", "learned_ystar")
"""The C functions of the learned RUL quantiles: eq. (5b)'s search, or eq. (6)'s roots with
one measurement."""


def specs() -> dict[str, DeviceSpec]:
    hist = fatigue_histories()
    cfg = fit_tracker_config(hist)
    model = fit_model(hist, "paris", time_unit="kcycles")
    learned = DeviceSpec("crack", "Lu & Meeker", cfg, None, model)
    return {"chain": DeviceSpec("crack", "Lu & Meeker", cfg), "chain+learned": learned,
            "chain+learned-1m": replace(learned, one_measurement=True)}


def variants(sp: dict[str, DeviceSpec]) -> list[tuple[str, str, DeviceSpec]]:
    """The chain in every number format; the learned model with the RUL of eq. (5b) (the
    default) and of one measurement (``-1m``, eq. (5)) in double and float."""
    return [("chain", n, sp["chain"]) for n in ("double", "float", "fixed")] + [
        (part, n, sp[part]) for part in ("chain+learned", "chain+learned-1m")
        for n in ("double", "float")]


def fmt_ops(c: dict[str, float]) -> str:
    return (f"{c['mul']:g} mul, {c['div']:g} div, {c['add']:g} add/sub, {c['log']:g} log, "
            f"{c['other_math']:g} other math, {c['cmp']:g} compare")


def operations(work: Path, sp: dict[str, DeviceSpec]) -> None:
    print("\n# operations per update, steady state (counted in the generated C; seed 004: "
          "11 multiplications, 9 additions, 1 logarithm)")
    for part, number, spec in variants(sp):
        ops = steady_state_operations(spec, work / f"ops_{part}_{number}", number)
        print(f"{part:16s} {number:6s} whole update: {fmt_ops(ops['total'])}")
        if number == "fixed":  # the work is in the arithmetic helpers
            for f in ("ln_hi", "mul_q", "div_round", "sat"):
                print(f"{'':21s} in {f}: {fmt_ops(ops[f])}")
        else:
            chain = {k: sum(ops.get(f, {}).get(k, 0.0) for f in SEED_CHAIN)
                     for k in ops["total"]}
            print(f"{'':21s} the seed's chain (track_hi, paris_rul, track_rul): "
                  f"{fmt_ops(chain)}")
            if "learned" in part:
                print(f"{'':21s} the learned RUL quantiles: {fmt_ops(_quantile_ops(ops))}")


def _quantile_ops(ops: dict[str, dict[str, float]]) -> dict[str, float]:
    """The operations of :data:`QUANTILE_FUNCTIONS` together."""
    return {k: sum(ops.get(f, {}).get(k, 0.0) for f in QUANTILE_FUNCTIONS) for k in ops["total"]}


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
        print(f"{part:16s} {number:6s} state {lib.state_struct_bytes} B in RAM "
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


def hi_noise_specs() -> dict[str, tuple[DeviceSpec, pd.DataFrame]]:
    """paris-additive / -multiplicative / -mixed, each fitted on a 10-unit fleet of its own
    noise kind (datasets.GOAL_FLEETS, the shape at the generator's m), with the tracker
    settings fitted on the same fleet."""
    out = {}
    for noise in NOISES:
        frame, _ = goal_fleet(noise, np.random.default_rng(11), 10)
        hist = histories_from_frame(frame, "bench")
        model = fit_hi_noise(hist, noise, shape=1.0 - float(GOAL_FLEETS[noise]["m"]) / 2.0)
        out[model.name] = (DeviceSpec("g", noise, fit_tracker_config(hist), None, model), frame)
    return out


def _c_seconds(lib: DeviceLibrary, start: np.ndarray, t: np.ndarray, hi: np.ndarray,
               repeats: int) -> float:
    """Median seconds per update of the C through the harness."""
    return median_time(lambda: lib.run(start, t, hi), repeats) / t.size


def hi_noise(work: Path, repeats: int) -> None:
    """The HI-noise variants: operations of the iterated update, state and code, and ns per
    update of the C (chain + learned, and the learned part as the difference with the chain
    alone on the same rows) against the Python model's update + RUL quantiles, one
    acquisition of one unit per call and vectorised over 100,000 units."""
    print("\n# learned HI-noise models (eq. (8), iterated extended Kalman update), double; "
          "each fleet's rows run 50 times as 50 components")
    for name, (spec, frame) in hi_noise_specs().items():
        model = spec.learned
        assert isinstance(model, HiNoiseModel)
        ops = steady_state_operations(spec, work / f"ops_{name}", "double")
        upd = {k: sum(ops.get(f, {}).get(k, 0.0) for f in ("learned_update", "growth_inverse",
                                                          "clip_z")) for k in ops["total"]}
        iters = ops["growth_inverse"]["other_math"] - 1.0
        print(f"{name:21s} whole update: {fmt_ops(ops['total'])}")
        one_m = replace(spec, one_measurement=True)
        ops_1m = steady_state_operations(one_m, work / f"ops1m_{name}", "double")
        print(f"{'':21s} of which eq. (8) ({iters:g} Gauss-Newton iterations per update): "
              f"{fmt_ops(upd)}")
        print(f"{'':21s} of which the RUL quantiles (eq. (5b), three bracketing searches): "
              f"{fmt_ops(_quantile_ops(ops))}")
        print(f"{'':21s} (with one measurement, eq. (6), three normal quantiles: "
              f"{fmt_ops(_quantile_ops(ops_1m))})")
        start1, df = segments(frame)
        reps = 50
        lens = np.tile(np.diff(start1), reps)
        start = np.concatenate([[0], np.cumsum(lens)])
        t, hi = np.tile(df["time"].to_numpy(), reps), np.tile(df["hi"].to_numpy(), reps)
        lib = build(spec, work / f"lib_{name}", "double")
        chain = build(DeviceSpec("g", "chain", spec.config), work / f"chain_{name}", "double")
        kalman = build(DeviceSpec("g", "kalman", spec.config, None, fit_model(
            histories_from_frame(frame, "bench"), "paris", shape=model.shape)),
            work / f"kalman_{name}", "double")
        lib_1m = build(one_m, work / f"lib1m_{name}", "double")
        c_all, c_chain, c_kalman, c_1m = (_c_seconds(x, start, t, hi, repeats)
                                          for x in (lib, chain, kalman, lib_1m))
        c_learned = c_all - c_chain
        n_saved = int(template_context(spec, "double", "rk")["state_bytes"])
        print(f"{'':21s} state {lib.state_struct_bytes} B in RAM, {n_saved} B saved; C "
              f"{1e9 * c_all:.0f} ns per update with the chain, learned part "
              f"{1e9 * c_learned:.0f} ns (minus the chain alone, {1e9 * c_chain:.0f} ns); the "
              f"Kalman paris model (eq. (2)) of the same shape on the same rows: learned part "
              f"{1e9 * (c_kalman - c_chain):.0f} ns, ratio={c_learned / (c_kalman - c_chain):.2f}"
              f" (medians of {repeats}, {t.size} updates); with the RUL of one measurement"
              f" (eq. (5)): learned part {1e9 * (c_1m - c_chain):.0f} ns, eq. (5b) / eq. (5) "
              f"ratio={c_learned / (c_1m - c_chain):.2f}")
        ref = python_reference(spec, start1, df["time"].to_numpy(), df["hi"].to_numpy())
        got = lib.run(start1, df["time"], df["hi"])
        flt = build(spec, work / f"float_{name}", "float").run(start1, df["time"], df["hi"])
        print(f"{'':21s} against the Python model on the fleet's {len(df)} acquisitions: "
              "double, largest relative error " + ", ".join(
                  f"{c} {relative_error(got[c], ref[c]).max():.2g}" for c in LEARNED_COLUMNS)
              + "; float, max |C - Python| / max |Python| " + ", ".join(
                  f"{c} {scaled_error(flt[c], ref[c]):.2g}" for c in LEARNED_COLUMNS))
        one = model.update(model.empty_state(1), df["time"].to_numpy()[:1],
                           df["hi"].to_numpy()[:1])
        tt, hh = df["time"].to_numpy()[1:2], df["hi"].to_numpy()[1:2]

        def py_one(one=one, tt=tt, hh=hh, model=model):
            model.rul_quantiles(model.update(one, tt, hh), LEVELS)

        b = 100_000
        many = UnitState(m=np.repeat(one.m, b, 0), p=np.repeat(one.p, b, 0),
                         t=np.repeat(one.t, b), hi=np.repeat(one.hi, b), n=np.repeat(one.n, b))
        tb, hb = np.full(b, tt[0]), np.full(b, hh[0])

        def py_many(many=many, tb=tb, hb=hb, model=model):
            model.rul_quantiles(model.update(many, tb, hb), LEVELS)

        py1 = median_time(py_one, repeats)
        pyb = median_time(py_many, max(1, repeats // 2)) / b
        print(f"{'':21s} Python update + quantiles, one unit per call {1e9 * py1:.0f} ns: "
              f"ratio={py1 / c_learned:.0f} (vs the C's learned part); vectorised over "
              f"{b} units {1e9 * pyb:.0f} ns per unit: ratio={pyb / c_learned:.2f}")


def _fp_quantiles(model: HiNoiseModel, st: UnitState, table: tuple) -> np.ndarray:
    """eq. (5b)'s quantiles (scaled time) of every state with the table ``table`` (the layout
    of ``first_passage.kernel_table``)."""
    from rulkit.fleet.learned.degradation import growth_scale_of
    from rulkit.fleet.learned.filter_kernels import first_passage_quantiles

    with np.errstate(invalid="ignore", divide="ignore"):
        d = st.t / np.maximum(st.n, 1) / model.time_scale
    delta = np.where((st.n >= 2) & (d > 0), d, np.inf)
    out = np.empty((len(LEVELS), len(st)))
    first_passage_quantiles(np.ascontiguousarray(st.m), np.ascontiguousarray(st.p), st.hi,
                            growth_scale_of(model), delta,
                            model.walk_sd**2, model.threshold, np.sqrt(model.measured_var),
                            np.asarray(LEVELS, dtype=np.float64), *table, 200, out)
    return out


def table_grid() -> None:
    """What a coarser table of mu*, sigma* (eq. (5b)) would cost: the learned RUL quantiles of
    the HI-noise fleets' every acquisition with the server's table and with coarser grids over
    the same ranges (filled from the server's table by its trilinear lookup,
    ``ystar_moments``): the largest relative error and max |error| / max |quantile|."""
    from rulkit.fleet.learned.first_passage import kernel_table, ystar_moments

    table = kernel_table()
    mu, lc0, dlc, dlj = table[0], table[2], table[3], table[4]
    print(f"\n# the table of eq. (5b): {' x '.join(map(str, mu.shape))} nodes, 2 tables: "
          f"{2 * mu.size * 8} B in double, {2 * mu.size * 4} B in float; coarser grids")
    fits = [(spec.learned, histories_from_frame(frame, "bench"))
            for spec, frame in hi_noise_specs().values()]
    refs = [(model, st, _fp_quantiles(model, st, table))
            for model, st in ((m, m.replay(h)) for m, h in fits)]
    for n_c, n_j, n_t in ((48, 60, 5), (32, 40, 9), (32, 40, 5), (24, 30, 5)):
        lc = np.linspace(lc0, lc0 + dlc * (mu.shape[0] - 1), n_c)
        lj = np.linspace(0.0, dlj * (mu.shape[1] - 1), n_j)
        th = np.linspace(0.0, 1.0, n_t)
        c_grid, j_grid, t_grid = np.meshgrid(np.exp(lc), np.exp(lj), th, indexing="ij")
        c_mu, c_sd = ystar_moments(c_grid, j_grid, t_grid)
        coarse = (c_mu, c_sd, float(lc[0]), float(lc[1] - lc[0]), float(lj[1] - lj[0]),
                  float(th[1] - th[0]))
        worst = []
        for model, st, ref in refs:
            got = _fp_quantiles(model, st, coarse)
            ok = np.isfinite(ref) & (ref > 0) & (st.hi < 1.0)
            err = np.abs(got[ok] - ref[ok])
            worst.append(f"{model.name} {np.max(err / ref[ok]):.2g} relative, "
                         f"{np.max(err) / np.max(ref[ok]):.2g} scaled")
        size = 2 * n_c * n_j * n_t
        print(f"{n_c} x {n_j} x {n_t} ({size * 8} B double, {size * 4} B float): "
              + "; ".join(worst))


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
        print(f"{part:16s} {number:6s} rk.o text {obj[0]} data {obj[1]} bss {obj[2]}; linked "
              f"program with newlib-nano, libm, startup: text {img[0]} data {img[1]} bss "
              f"{img[2]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-arm", action="store_true", help="skip the Cortex-M4 sizes")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--only-hi-noise", action="store_true",
                    help="only the learned HI-noise models' section")
    ap.add_argument("--only-table", action="store_true",
                    help="only the error a coarser table of eq. (5b) would add")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} "
          f"{os.getloadavg()[2]:.2f} on {os.cpu_count()} cores; python {sys.version.split()[0]}")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if args.only_hi_noise:
            hi_noise(work, args.repeats)
            return
        if args.only_table:
            table_grid()
            return
        sp = specs()
        build_cache["lib"] = build(sp["chain"], work / "speed", "double")
        operations(work, sp)
        sizes_and_speed(work, sp, args.repeats)
        errors(work)
        hi_noise(work, args.repeats)
        table_grid()
        if not args.no_arm:
            arm(work, sp)


if __name__ == "__main__":
    main()

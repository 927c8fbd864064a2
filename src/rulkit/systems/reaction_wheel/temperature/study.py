"""The Table 5 study of the temperature estimators (seed 001 Table 5;
docs/systems/reaction-wheel.md section 3) and its figures (like seed 001 Figs 9-11).

:func:`run_table5` runs every (variant, design, noise, N, run) cell of the grid with
:func:`rulkit.systems.reaction_wheel.temperature.particle.filter_temperature` (the
Rao-Blackwellised PF
and the EKF reference beside them) and prints our RMSPE beside the paper's
(:func:`format_table5`); :func:`plot_temperature_estimates` draws one run per estimator.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.temperature import kernels as kern
from rulkit.systems.reaction_wheel.temperature.ekf import run_ekf
from rulkit.systems.reaction_wheel.temperature.particle import (
    Design,
    FloatArray,
    TemperatureConfig,
    filter_temperature,
)
from rulkit.systems.reaction_wheel.wheel import simulate_table3

#: Seed 001 Table 5 (RMSPE of T, %), keyed by (method, noise) -> values for N = 50..350.
PAPER_TABLE5: dict[tuple[str, str], tuple[float, ...]] = {
    ("adaptive", "low"): (2.359, 2.216, 2.012, 1.983, 2.015, 1.935, 1.919),
    ("apf_eq28", "low"): (2.554, 2.471, 2.292, 2.340, 2.378, 2.436, 2.305),
    ("adaptive", "high"): (3.596, 3.118, 2.745, 2.742, 2.735, 2.707, 2.748),
    ("apf_eq28", "high"): (3.048, 2.691, 2.697, 2.605, 2.589, 2.496, 2.480),
}


TABLE5_N: tuple[int, ...] = (50, 100, 150, 200, 250, 300, 350)


_NOISES = ("low", "high")


def _data_rng(seed: int, noise: str, run: int) -> np.random.Generator:
    """Generator of the measurement noise of run ``run`` at ``noise``: shared by every method
    and particle count (common random numbers), independent of the filter's own generator."""
    return np.random.default_rng(np.random.SeedSequence([seed, _NOISES.index(noise), run]))


def _cell_seed(seed: int, variant: str, design: str, noise: str, n: int, run: int) -> list[int]:
    """Entropy of a Table 5 filter run, from its identity: a cell's numbers do not change when
    rows are added to or removed from the grid."""
    return [seed, 1, list(kern.VARIANTS).index(variant), list(kern.DESIGNS).index(design),
            _NOISES.index(noise), n, run]


def _table5_pf_task(task: tuple[Any, ...], rng: np.random.Generator) -> dict[str, Any]:
    """One filter run of the Table 5 grid (module level: picklable for the runner). The filter
    generator comes from :func:`_cell_seed` (the runner's ``rng`` is not used). With
    ``coverage`` the 90 % interval (weighted 5 % / 95 % quantiles) is computed too; the
    quantiles draw no random numbers, so the estimates are the same either way."""
    variant, design, noise, n, run, seed, t_burn, overrides, initial, *rest = task
    coverage = bool(rest[0]) if rest else False
    data = simulate_table3(_data_rng(seed, noise, run), noise, initial=initial)
    cfg = replace(TemperatureConfig(design=design, variant=variant, n_particles=n),
                  **dict(overrides))
    if coverage:
        cfg = replace(cfg, quantiles=COVERAGE_QUANTILES)
    frng = np.random.default_rng(np.random.SeedSequence(_cell_seed(seed, variant, design, noise,
                                                                   n, run)))
    res = filter_temperature(data.y, data.V, frng, cfg, sigma=(data.sigma_w, data.sigma_I),
                    dt=data.dt, quantiles=coverage)
    band = (res.T_lo, res.T_hi) if coverage else None
    return _scores(res.T_mean, data.T, data.t, t_burn, band) | {
        "n_spread": int(np.sum(res.action == 2)), "n_resampled": int(np.sum(res.action == 1)),
        "n_reset": int(np.sum(res.action == 3)), "clipped_frac": float(res.n_clipped.sum())
        / (n * (res.t.size - 1)),
    }


def _table5_rbpf_task(task: tuple[Any, ...], rng: np.random.Generator) -> dict[str, Any]:
    """One Rao-Blackwellised PF run (design ``RBPF_DESIGNS[design]``, beyond the seeds) of the
    Table 5 grid; its generator is ``SeedSequence([seed, 2, design index, noise, N, run])``."""
    from rulkit.systems.reaction_wheel.temperature.rbpf import RBPF_DESIGNS, run_rbpf

    _, design, noise, n, run, seed, t_burn, _overrides, initial, *rest = task
    coverage = bool(rest[0]) if rest else False
    data = simulate_table3(_data_rng(seed, noise, run), noise, initial=initial)
    cfg = replace(RBPF_DESIGNS[design], n_particles=n, quantiles=COVERAGE_QUANTILES)
    frng = np.random.default_rng(np.random.SeedSequence(
        [seed, 2, list(RBPF_DESIGNS).index(design), _NOISES.index(noise), n, run]))
    res = run_rbpf(data.y, data.V, frng, cfg, sigma=(data.sigma_w, data.sigma_I), dt=data.dt,
                   quantiles=coverage)
    band = (res.T_lo, res.T_hi) if coverage else None
    return _scores(res.T_mean, data.T, data.t, t_burn, band) | {
        "n_spread": 0, "n_resampled": int(np.sum(res.action == 1)), "n_reset": 0,
        "clipped_frac": 0.0,
    }


def _table5_ekf_task(task: tuple[Any, ...], rng: np.random.Generator) -> list[dict[str, Any]]:
    """EKF reference for every run at both noise levels in one batched filter (B = 2 runs);
    deterministic given the data. Its 90 % interval (``coverage``) is mean +- 1.645 sd."""
    runs, seed, t_burn, initial, *rest = task
    coverage = bool(rest[0]) if rest else False
    datas = [simulate_table3(_data_rng(seed, nz, r), nz, initial=initial)
             for nz in _NOISES for r in range(runs)]
    d0 = datas[0]
    ys = np.stack([d.y for d in datas], axis=1)
    sig = np.array([(d.sigma_w, d.sigma_I) for d in datas])
    res = run_ekf(ys, d0.V, sigma=sig, dt=d0.dt)
    from scipy.stats import norm

    z = float(norm.ppf(COVERAGE_QUANTILES[1]))
    out = []
    for b in range(len(datas)):
        m, s = res.T_mean[:, b], res.T_std[:, b]
        out.append(_scores(m, d0.T, d0.t, t_burn, (m - z * s, m + z * s) if coverage else None))
    return out


#: Interval whose coverage of the true T Table 5 reports with ``coverage=True`` (90 %).
COVERAGE_QUANTILES: tuple[float, float] = (0.05, 0.95)


def _scores(
    T_hat: FloatArray, T: FloatArray, t: FloatArray, t_burn: float,
    band: tuple[FloatArray, FloatArray] | None = None,
) -> dict[str, float]:
    """RMSPE of T over all estimates of a run (samples 1..K-1; row 0 is the prior) and over
    t >= t_burn (docs/systems/reaction-wheel.md section 6); with ``band = (lo, hi)`` also the
    fraction of those samples whose true T lies in [lo, hi] (interval coverage; ~0.90 for a
    calibrated 90 % interval)."""
    from rulkit.metrics import rmspe

    late = t >= t_burn
    out = {"rmspe": float(rmspe(T_hat[1:], T[1:])),
           "rmspe_late": float(rmspe(T_hat[late], T[late]))}
    if band is not None:
        inside = (band[0] <= T) & (T <= band[1])
        out |= {"cover": float(inside[1:].mean()), "cover_late": float(inside[late].mean())}
    return out


def run_table5(
    runs: int = 20,
    seed: int = 0,
    quick: bool = False,
    workers: int = 1,
    scheduler: str | None = None,
    progress: Any = None,
    *,
    methods: Sequence[tuple[str, str]] | None = None,
    designs: Sequence[str] = ("F1",),
    n_particles: Sequence[int] | None = None,
    extra: bool = False,
    ekf: bool = True,
    t_burn: float = 100.0,
    overrides: dict[str, Any] | None = None,
    initial: str = "rest",
    coverage: bool = False,
) -> Any:
    """Seed 001 Table 5: RMSPE of T (%) over the Table 3 path (500 s at dt = 0.05 s) for
    N = 50..350, low and high noise, ``runs`` seeded runs each
    (docs/systems/reaction-wheel.md sections 2, 3, 6).

    ``methods``: (variant, design) pairs; default the paper's two methods, PF + adaptive
    resampling and APF (eq. 28), in each of ``designs`` (default the seed-faithful F1: 560
    filter runs of 10,000 steps). ``extra`` adds plain PF and tempered APF in the same designs.
    ``ekf`` adds the EKF reference (independent of N; reported with N = 0). ``quick``: 3 runs,
    N in (50, 200, 350).

    Run r at a noise level sees the same measurements for every method and N (data seed
    ``SeedSequence([seed, noise, r])``); each filter run's generator is seeded from its identity
    ``SeedSequence([seed, 1, variant, design, noise, N, r])``, so a cell does not change when
    rows are added, and results are identical serially, with ``workers`` or on a Dask
    ``scheduler`` (the runner only distributes). ``initial``: "rest" ([R]) or
    "equilibrium" start of the truth; ``overrides``: TemperatureConfig fields for every seed-PF run.
    Beyond the seeds: a design named in
    :data:`rulkit.systems.reaction_wheel.temperature.rbpf.RBPF_DESIGNS` ("RB", "RB05", "RBJ",
    "RBJ0") adds the
    Rao-Blackwellised PF (method "rbpf") in that design (e.g. ``designs=("F1", "RBJ")``);
    its generator is ``SeedSequence([seed, 2, design index, noise, N, r])``. ``coverage``:
    also compute each run's 90 % interval and report the fraction of samples in which it
    covers the true T (cover_mean over 0-500 s, cover_late_mean for t >= t_burn); costs a
    sort per step for the particle filters and leaves every estimate unchanged.
    Returns a long ``pandas.DataFrame``: method, design, noise, N, runs, seed, rmspe_mean /
    rmspe_sd / rmspe_min / rmspe_max over runs, rmspe_late_mean (t >= t_burn), mean counts of
    adaptive spreads and resamplings, APF clipped fraction, paper (Table 5 value or NaN).
    """
    from rulkit.runner import run_independent

    if quick:
        runs = min(runs, 3)
        n_list = tuple(n_particles) if n_particles else (50, 200, 350)
    else:
        n_list = tuple(n_particles) if n_particles else TABLE5_N
    methods = _table5_methods(methods, designs, extra)
    ov = tuple(sorted((overrides or {}).items()))
    # largest N first so the slowest tasks start early on the workers
    tasks: list[tuple[Any, ...]] = [
        (v, d, noise, n, r, seed, t_burn, ov, initial, coverage)
        for n in sorted(n_list, reverse=True) for (v, d) in methods for noise in _NOISES
        for r in range(runs)
    ]
    ekf_tasks = [("ekf", runs, seed, t_burn, initial, coverage)] if ekf else []
    all_tasks = ekf_tasks + tasks
    outs = run_independent(_table5_dispatch, all_tasks, seed=seed, workers=workers,
                           scheduler=scheduler, progress=progress, description="Table 5 runs")
    return _table5_summary(all_tasks, outs, runs, seed, coverage, bool(tasks))


def _table5_methods(methods: Sequence[tuple[str, str]] | None, designs: Sequence[str],
                    extra: bool) -> list[tuple[str, str]]:
    """The (variant, design) pairs of :func:`run_table5` (its default from ``designs`` and
    ``extra``), each checked to be a known pair."""
    from rulkit.systems.reaction_wheel.temperature.rbpf import RBPF_DESIGNS

    if methods is None:
        variants = ["adaptive", "apf_eq28"] + (["pf", "apf_tempered"] if extra else [])
        methods = [(v, d) for d in designs
                   for v in (["rbpf"] if d in RBPF_DESIGNS else variants)]
    for v, d in methods:
        ok = d in RBPF_DESIGNS if v == "rbpf" else (v in kern.VARIANTS and d in kern.DESIGNS)
        if not ok:
            raise ValueError(f"methods: ({v!r}, {d!r}) is not a known (variant, design) pair; "
                             f"designs {sorted(kern.DESIGNS)} take {sorted(kern.VARIANTS)}, "
                             f"{sorted(RBPF_DESIGNS)} take 'rbpf'")
    return list(methods)


def _table5_summary(all_tasks: list[tuple[Any, ...]], outs: Sequence[Any], runs: int,
                    seed: int, coverage: bool, has_tasks: bool) -> Any:
    """:func:`run_table5`'s table: the runs' scores aggregated per (method, design, noise,
    N) beside the paper's values, in the paper's order."""
    import pandas as pd

    rows: list[dict[str, Any]] = []
    for task, out in zip(all_tasks, outs, strict=True):
        if task[0] == "ekf":
            for b, sc in enumerate(out):
                rows.append({"method": "ekf", "design": "-", "noise": _NOISES[b // runs],
                             "N": 0, "run": b % runs, **sc})
        else:
            v, d, noise, n, r = task[:5]
            rows.append({"method": v, "design": d, "noise": noise, "N": n, "run": r, **out})
    df = pd.DataFrame(rows)
    agg = df.groupby(["method", "design", "noise", "N"], sort=False).agg(
        runs=("rmspe", "size"), rmspe_mean=("rmspe", "mean"), rmspe_sd=("rmspe", "std"),
        rmspe_min=("rmspe", "min"), rmspe_max=("rmspe", "max"),
        rmspe_late_mean=("rmspe_late", "mean"),
        **({"cover_mean": ("cover", "mean"), "cover_late_mean": ("cover_late", "mean")}
           if coverage else {}),
        **({"spreads_mean": ("n_spread", "mean"), "resamplings_mean": ("n_resampled", "mean"),
            "clipped_frac_mean": ("clipped_frac", "mean")} if has_tasks else {}),
    ).reset_index()
    agg["seed"] = seed

    def paper(row: Any) -> float:
        vals = PAPER_TABLE5.get((row["method"], row["noise"]))
        if vals is None or row["N"] not in TABLE5_N:
            return float("nan")
        return vals[TABLE5_N.index(row["N"])]

    agg["paper"] = agg.apply(paper, axis=1)
    order = {m: i for i, m in enumerate(["adaptive", "apf_eq28", "pf", "apf_tempered",
                                                    "rbpf", "ekf"])}
    agg = agg.sort_values(["noise", "method", "design", "N"],
                          key=lambda s: s.map(order) if s.name == "method" else s)
    return agg.reset_index(drop=True)


def _table5_dispatch(task: tuple[Any, ...], rng: np.random.Generator) -> Any:
    if task[0] == "ekf":
        return _table5_ekf_task(task[1:], rng)
    if task[0] == "rbpf":
        return _table5_rbpf_task(task, rng)

    return _table5_pf_task(task, rng)


def format_table5(df: Any, column: str = "rmspe_mean") -> str:
    """Wide text table: one row per (noise, method, design), columns N, each cell
    ``ours (paper)`` in % (``column``: "rmspe_mean" over 0-500 s, or "rmspe_late_mean" over
    t >= t_burn, which the paper does not report); EKF reference in its own row."""
    lines = []
    ns = sorted(int(n) for n in df["N"].unique() if n > 0)
    head = f"{'noise':5} {'method':13} {'design':6} " + " ".join(f"{'N=' + str(n):>15}" for n in ns)
    lines.append(head)
    for (noise, method, design), g in df.groupby(["noise", "method", "design"], sort=False):
        cells = []
        for n in ns:
            r = g[g["N"] == n]
            if r.empty:
                r = g[g["N"] == 0]
            if r.empty:
                cells.append(f"{'':>15}")
                continue
            ours = r[column].iloc[0]
            pap = r["paper"].iloc[0] if column == "rmspe_mean" else float("nan")
            if column.startswith("cover"):
                ours = 100.0 * ours
            cells.append(
                f"{ours:7.3f} ({pap:5.3f})" if np.isfinite(pap) else f"{ours:7.3f}        "
            )
        lines.append(f"{noise:5} {method:13} {design:6} " + " ".join(f"{c:>15}" for c in cells))
    runs = ", ".join(str(int(r)) for r in sorted(df["runs"].unique()))
    span = "t >= 100 s (t_burn)" if column.endswith("late_mean") else "0-500 s"
    what = ("coverage of the true T by the 90 % interval, in % of samples," if
            column.startswith("cover") else "RMSPE of T in %")
    lines.append(f"{what} over {span}, mean of {runs} runs per cell, seed "
                 f"{int(df['seed'].iloc[0])}" + ("; (paper) = seed 001 Table 5."
                                                 if column == "rmspe_mean" else "."))
    return "\n".join(lines)


_TITLES = {"pf": "PF", "adaptive": "PF + adaptive resampling", "apf_eq28": "APF (eq. 28)",
           "apf_tempered": "APF (tempering)",
           "rbpf": "Rao-Blackwellised PF (beyond the seeds)"}


def plot_temperature_estimates(
    out_dir: str | Path,
    *,
    seed: int = 0,
    n_particles: int = 350,
    design: Design = "F1",
    variants: Sequence[str] = ("pf", "adaptive", "apf_eq28"),
    with_ekf: bool = True,
    fmt: str = "png",
    t_end: float = 500.0,
    rbpf_design: str = "RBJ",
) -> list[Path]:
    """One figure per estimator (like seed 001 Figs 9, 10, 11): (a) low and (b) high noise,
    estimate, 95 % interval (weighted particle quantiles), truth on the Table 3 path, and the
    EKF reference (dashed). Returns the written paths. Run r = 0 of :func:`run_table5`'s data
    seed; the filter generator is ``default_rng(SeedSequence([seed, 99, i]))``. A variant
    ``"rbpf"`` draws the Rao-Blackwellised PF in design ``rbpf_design`` (beyond the seeds)."""
    import matplotlib

    from rulkit.systems.reaction_wheel.temperature.rbpf import RBPF_DESIGNS, run_rbpf

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    datas = {nz: simulate_table3(_data_rng(seed, nz, 0), nz, t_end=t_end) for nz in _NOISES}
    ekfs = {}
    if with_ekf:
        for nz, d in datas.items():
            ekfs[nz] = run_ekf(d.y, d.V, sigma=(d.sigma_w, d.sigma_I), dt=d.dt).T_mean[:, 0]
    paths = []
    for i, v in enumerate(variants):
        fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
        for ax, nz, lab in zip(axes, _NOISES, ("(a) low noise", "(b) high noise"), strict=True):
            d = datas[nz]
            rng = np.random.default_rng(np.random.SeedSequence([seed, 99, i]))
            r: Any
            if v == "rbpf":
                rcfg = replace(RBPF_DESIGNS[rbpf_design], n_particles=n_particles,
                               quantiles=(0.025, 0.975))
                r = run_rbpf(d.y, d.V, rng, rcfg, sigma=(d.sigma_w, d.sigma_I), dt=d.dt)
            else:
                cfg = TemperatureConfig(design=design, variant=v, n_particles=n_particles)  # type: ignore[arg-type]
                r = filter_temperature(d.y, d.V, rng, cfg, sigma=(d.sigma_w, d.sigma_I), dt=d.dt)
            ax.fill_between(r.t, r.T_lo, r.T_hi, color="C0", alpha=0.25, lw=0,
                            label="95 % interval")
            ax.plot(r.t, r.T_mean, color="C0", lw=1, label="estimate")
            ax.plot(d.t, d.T, color="k", lw=1.5, label="true $T_{lub}$")
            if with_ekf:
                ax.plot(d.t, ekfs[nz], color="C3", lw=1, ls="--", label="EKF reference")
            from rulkit.metrics import rmspe

            ax.set_title(f"{lab}: RMSPE {rmspe(r.T_mean[1:], d.T[1:]):.2f} %")
            ax.set_xlabel("time (s)")
            ax.set_ylim(10, 45)
            ax.grid(alpha=0.3)
        axes[0].set_ylabel("lubricant temperature (C)")
        axes[0].legend(loc="lower right", fontsize=8)
        dname = rbpf_design if v == "rbpf" else design
        fig.suptitle(f"{_TITLES.get(v, v)}, design {dname}, N = {n_particles}, seed {seed}")
        fig.tight_layout()
        path = out / f"rw_step1_{v}_{dname}.{fmt}"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


# --------------------------------------------------------------------------------------------
# the seeds' filters complete: every weighting in both designs, and why eq. 28 fails

#: The five weightings of docs/systems/reaction-wheel.md §3.2 (Fig. 9 is the plain PF).
SEED_VARIANTS = ("pf", "adaptive", "apf", "apf_eq28", "apf_tempered")


def run_seed_filters(runs: int, seed: int, n_particles: Sequence[int], *, workers: int = 1,
                     scheduler: str | None = None, progress: Any = None) -> Any:
    """Table 5 for all five weightings (:data:`SEED_VARIANTS`) in both designs F1 and F2, with
    the coverage of the 90 % interval (:func:`run_table5`'s cells: the paper's two methods in
    F1 have the numbers of Table 5 itself)."""
    t = run_table5(runs=runs, seed=seed, n_particles=tuple(n_particles), ekf=False,
                   methods=[(v, d) for d in ("F1", "F2") for v in SEED_VARIANTS],
                   workers=workers, scheduler=scheduler, progress=progress, coverage=True)
    t.loc[t["design"] != "F1", "paper"] = np.nan  # the paper's rows are design F1
    return t


def eq28_weight_analysis(seed: int, n_particles: int = 200, t_end: float = 500.0) -> Any:
    """What eq. 28 does to the weights (docs/systems/reaction-wheel.md §3.2), measured on the
    Table 3 path (run 0 of :func:`run_table5`'s data, both noise levels): a plain F2 particle
    filter runs, and at every step the same prior weights ``w_prev`` and likelihoods ``p`` are
    weighted both ways, by Bayes (``w_prev p``) and by eq. 28 (:func:`rulkit.systems.
    reaction_wheel.temperature.particle.apf_eq28_weights`). Returns one row per noise level:
    the mean effective sample size (ESS / N) after each, the median log10 ratio of the largest
    to the smallest non-zero weight, and the mean fraction of weights eq. 28 clips to zero."""
    import pandas as pd

    from rulkit.estimation.batched import ess_rows, normalise_rows, systematic_rows
    from rulkit.systems.reaction_wheel.temperature.particle import apf_eq28_weights
    from rulkit.systems.reaction_wheel.wheel import IthacoParams, rk4_wheel_step

    p = IthacoParams()
    rows = []
    for noise in _NOISES:
        d = simulate_table3(_data_rng(seed, noise, 0), noise, t_end=t_end)
        rng = np.random.default_rng(np.random.SeedSequence([seed, 28, _NOISES.index(noise)]))
        N, (sw, sI) = n_particles, (d.sigma_w, d.sigma_I)
        T = rng.uniform(15.0, 45.0, N)
        X = np.column_stack([d.y[0, 1] + sI * rng.standard_normal(N),
                             d.y[0, 0] + sw * rng.standard_normal(N)])
        logw = np.full(N, -np.log(N))
        log_norm = np.log(2 * np.pi * sw * sI)
        stats: dict[str, list[float]] = {k: [] for k in ("ess_bayes", "ess_eq28", "r_bayes",
                                                         "r_eq28", "clipped")}
        for k in range(1, d.t.size):
            T = T + 0.02 * rng.standard_normal(N)
            X = rk4_wheel_step(X, d.V[k - 1], T, d.t[k - 1], d.dt, p)
            ll = -0.5 * (((d.y[k, 0] - X[:, 1]) / sw) ** 2 + ((d.y[k, 1] - X[:, 0]) / sI) ** 2)
            ll -= log_norm
            w_prev = np.exp(logw)
            logw, w, _ = normalise_rows(logw + ll)
            w28, n_clip = apf_eq28_weights(w_prev, np.exp(ll), float(d.V[k - 1]))
            w28 = w28 / w28.sum() if w28.sum() > 0 else w
            stats["ess_bayes"].append(float(ess_rows(w)) / N)
            stats["ess_eq28"].append(float(ess_rows(w28)) / N)
            for key, ww in (("r_bayes", w), ("r_eq28", w28)):
                nz = ww[ww > 0]
                stats[key].append(float(np.log10(nz.max() / nz.min())))
            stats["clipped"].append(n_clip / N)
            if stats["ess_bayes"][-1] < 0.5:
                idx = systematic_rows(w, rng.random())
                T, X, logw = T[idx], X[idx], np.full(N, -np.log(N))
        rows.append({"noise": noise, "N": N, "steps": d.t.size - 1,
                     "ess_over_N_bayes": float(np.mean(stats["ess_bayes"])),
                     "ess_over_N_eq28": float(np.mean(stats["ess_eq28"])),
                     "log10_weight_ratio_bayes": float(np.median(stats["r_bayes"])),
                     "log10_weight_ratio_eq28": float(np.median(stats["r_eq28"])),
                     "clipped_fraction_eq28": float(np.mean(stats["clipped"])), "seed": seed})
    return pd.DataFrame(rows)

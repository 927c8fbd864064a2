"""The report of steps 1-3 on a user's record (``rulkit rw pipeline``;
docs/systems/reaction-wheel.md §7.4): tables (CSV), figures (PNG), ``report.md`` and
``summary.json`` of a
:class:`rulkit.systems.reaction_wheel.pipeline.PipelineResult`.

Files: ``temperature_hourly.csv`` (the step-1 estimate per hour: mean, lowest lower and highest
upper bound of its interval), ``tracks.csv`` (b and beta0 per loss window with intervals, per
tracker), ``posterior.csv``, ``step2.json``, ``step2.npz`` (what ``rulkit rw rul`` needs:
:func:`rulkit.systems.reaction_wheel.degradation.track.save_step2`),
``rul_<tracker>.json`` (the RUL distribution, days; :class:`rulkit.prognosis.rul.
RULDistribution`), ``temperature.png``, ``tracks.png``, ``rul.png``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

DAY_S = 86400.0


def write_record_report(res: Any, out: Path) -> Path:
    """Write every file of the module docstring for ``res`` into ``out``; sets ``res.files``
    and returns the path of ``report.md``."""
    out = Path(out)
    files = [out / "temperature_hourly.csv"]
    res.hourly.to_csv(files[0], index=False)
    files.append(_plot_temperature(res, out / "temperature.png"))
    if res.tracks is not None:
        from rulkit.systems.reaction_wheel.degradation.track import save_step2

        res.tracks.table.to_csv(out / "tracks.csv", index=False)
        files += [out / "tracks.csv", *save_step2(out, res.tracks, *res.windows),
                  _plot_tracks(res, out / "tracks.png")]
    for name, dist in res.ruls.items():
        files.append(dist.to_json(out / f"rul_{name}.json"))
    if res.ruls:
        files.append(_plot_rul(res, out / "rul.png"))
    res.files = [*files, out / "report.md", out / "summary.json"]
    (out / "report.md").write_text(render_record_report(res))
    (out / "summary.json").write_text(json.dumps(_summary(res), indent=1, default=float))
    return out / "report.md"


def _summary(res: Any) -> dict[str, Any]:
    return summary_row(res) | {"notes": res.notes, "files": [p.name for p in res.files]}


def render_record_report(res: Any) -> str:
    """``report.md``: the inputs, what step 1 saw, the step-2 tracks and the step-3 RUL, the
    settings where the user's record needs a choice [R], timings."""
    L = [f"# Reaction-wheel lubrication: {res.record.name}\n"]
    t0, t1 = res.span_s
    tel = res.record.telemetry
    what = (f"telemetry rows ({len(tel)} file(s), {tel[0].name} .. {tel[-1].name})" if tel
            else f"rows of the step-1 estimate {res.record.temperature}")
    L.append(f"{res.rows:,} {what} over {(t1 - t0) / DAY_S:.3g} days"
             + (f"; resumed after file {res.resumed_after}" if res.resumed_after else "")
             + ".\n")
    L.append(f"Wheel: {res.wheel.source}; step-1 method: {res.options.method or res.wheel.method}"
             f" (docs/systems/reaction-wheel.md §3.4).\n")
    L += ["## Step 1: lubricant temperature\n"]
    h = res.hourly
    if len(h):
        L.append(f"Estimate (hourly means) from {h['T_mean'].min():.2f} to "
                 f"{h['T_mean'].max():.2f} C; last hour {h['T_mean'].iloc[-1]:.2f} C "
                 f"(95 % interval within {h['T_lo'].iloc[-1]:.2f} .. {h['T_hi'].iloc[-1]:.2f} C)."
                 " Per hour: `temperature_hourly.csv`, `temperature.png`.\n")
    L += [f"- {n}" for n in res.notes] + [""]
    L += _step2_lines(res) + _step3_lines(res)
    L.append("## Timings\n")
    L += [f"- {k}: {v:.1f} s" for k, v in res.timings.items()] + [""]
    L.append("## Files\n")
    L += [f"- {p.name}" for p in res.files]
    return "\n".join(L) + "\n"


def _step2_lines(res: Any) -> list[str]:
    tr = res.tracks
    if tr is None:
        return ["## Step 2: lubricant-loss parameters\n",
                "Not run: no loss measurements or injection log was given.\n"]
    tab = tr.table
    L = ["## Step 2: lubricant-loss parameters (docs/systems/reaction-wheel.md §4)\n",
         f"{len(tab)} loss windows used ({tr.n_missing} without a temperature estimate left "
         f"out); measurement noise {tr.sigma_y:.4g} mL ({tr.noise_source}); the constant law "
         f"fitted to the first {tr.fit.n} windows: b = {tr.fit.b:.3g} C, beta0 = "
         f"{tr.fit.beta0:.4g} mL/s (the scale of the beta0 prior). Last window "
         f"({tr.level:.0%} intervals, mean +- z sd of the particles):\n",
         "| tracker | b (C) | b interval | beta0 (mL/s) | beta0 interval |",
         "| --- | --- | --- | --- | --- |"]
    for name in tr.posteriors:
        r = tab.iloc[-1]
        L.append(f"| {name} | {r[f'b_{name}']:.3g} | {r[f'b_lo_{name}']:.3g} .. "
                 f"{r[f'b_hi_{name}']:.3g} | {r[f'beta0_{name}']:.4g} | "
                 f"{r[f'beta0_lo_{name}']:.4g} .. {r[f'beta0_hi_{name}']:.4g} |")
    L.append(f"\nCumulative measured loss at the end: {tr.X_end:.6g} mL. Per window: "
             "`tracks.csv`, `tracks.png`.\n")
    return L


def _step3_lines(res: Any) -> list[str]:
    if not res.ruls:
        return []
    lvl = res.options.level
    L = ["## Step 3: remaining useful life (docs/systems/reaction-wheel.md §5)\n",
         f"To a cumulative loss of {res.options.threshold_mL:.6g} mL along {res.future}; "
         f"censored beyond {res.wheel.rul['horizon_days']:g} days.\n",
         f"| tracker | median (days) | {lvl:.0%} interval (days) | mean (days) | censored |",
         "| --- | --- | --- | --- | --- |"]
    for name, d in res.ruls.items():
        lo, hi = d.interval(lvl)
        cens = float(np.sum(d.weights[d.censored])) if d.censored is not None else 0.0
        L.append(f"| {name} | {d.median:.4g} | {lo:.4g} .. {hi:.4g} | {d.mean:.4g} | "
                 f"{100 * cens:.1f} % |")
    return [*L, ""]


def _figure(size: tuple[float, float], rows: int = 1, sharex: bool = False) -> tuple[Any, Any]:
    """A new pyplot-free figure of ``size`` inches with ``rows`` axes stacked (one Axes when
    ``rows`` is 1, else an array of them)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    return fig, fig.subplots(rows, 1, sharex=sharex)


def _save(fig: Any, path: Path) -> Path:
    """Lay out ``fig`` and write it to ``path`` (PNG, 110 dpi)."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def _plot_temperature(res: Any, path: Path) -> Path:
    h = res.hourly
    fig, ax = _figure((9, 3.5))
    days = (h["time_s"] - res.span_s[0]) / DAY_S
    ax.fill_between(days, h["T_lo"], h["T_hi"], alpha=0.3, lw=0, label="95 % interval (range)")
    ax.plot(days, h["T_mean"], lw=0.8, label="hourly mean")
    ax.set_xlabel("days since the record's start")
    ax.set_ylabel("lubricant temperature (C)")
    ax.set_title(f"{res.record.name}: step-1 estimate")
    ax.legend(fontsize=8)
    return _save(fig, path)


def _plot_tracks(res: Any, path: Path) -> Path:
    tab = res.tracks.table
    days = (tab["end_s"] - res.span_s[0]) / DAY_S
    fig, axes = _figure((9, 6), rows=2, sharex=True)
    for i, name in enumerate(res.tracks.posteriors):
        for ax, v in zip(axes, ("b", "beta0"), strict=True):
            ax.fill_between(days, tab[f"{v}_lo_{name}"], tab[f"{v}_hi_{name}"], alpha=0.15,
                            lw=0, color=f"C{i}")
            ax.plot(days, tab[f"{v}_{name}"], lw=0.8, color=f"C{i}", label=name)
    axes[0].set_ylabel("b (C)")
    axes[1].set_ylabel("beta0 (mL/s)")
    axes[1].set_xlabel("days since the record's start")
    axes[0].legend(fontsize=8)
    axes[0].set_title(f"{res.record.name}: step-2 tracks ({res.tracks.level:.0%} intervals)")
    return _save(fig, path)


def _plot_rul(res: Any, path: Path) -> Path:
    fig, ax = _figure((7, 3.5))
    for i, (name, d) in enumerate(res.ruls.items()):
        s = d.samples[~d.censored] if d.censored is not None else d.samples
        if s.size > 1 and np.ptp(s) > 0:
            grid = np.linspace(s.min() * 0.9, s.max() * 1.1, 300)
            ax.plot(grid, d.pdf(grid), color=f"C{i}", label=f"{name} (median {d.median:.3g} d)")
        ax.axvline(d.median, color=f"C{i}", lw=0.8, ls="--")
    ax.set_xlabel("RUL (days)")
    ax.set_ylabel("density")
    ax.set_title(f"{res.record.name}: RUL to {res.options.threshold_mL:.4g} mL")
    ax.legend(fontsize=8)
    return _save(fig, path)


def summary_row(res: Any) -> dict[str, Any]:
    """The fleet table's row of a record: rows, last temperature, last b and beta0 and the
    median RUL of the two-step tracker (NaN where not run)."""
    row: dict[str, Any] = {"wheel": res.record.name, "rows": res.rows}
    h = res.hourly
    row["T_last_C"] = float(h["T_mean"].iloc[-1]) if len(h) else float("nan")
    tab = res.tracks.table if res.tracks is not None else None
    for v in ("b", "beta0"):
        row[f"{v}_last"] = float(tab[f"{v}_two_step"].iloc[-1]) if tab is not None else np.nan
    r = res.ruls.get("two_step")
    row["rul_median_days"] = float(r.median) if r is not None else float("nan")
    lo, hi = r.interval(res.options.level) if r is not None else (np.nan, np.nan)
    row["rul_lo_days"], row["rul_hi_days"] = float(lo), float(hi)
    return row

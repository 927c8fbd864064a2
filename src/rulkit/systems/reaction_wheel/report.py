"""The report of the reaction-wheel reproduction: tables (CSV), figures (PNG), ``report.md``
(our numbers beside the paper's, every [R] choice, timings) and ``settings.json`` of a
:class:`rulkit.systems.reaction_wheel.reproduce.Reproduction` (docs/systems/reaction-wheel.md
§6).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from rulkit.systems.reaction_wheel.degradation.study import (
    STEP1_VARIANTS,
    truth_parameters,
)
from rulkit.systems.reaction_wheel.lubrication import DAY_S, PATHS, SCENARIOS, WINDOW_S
from rulkit.systems.reaction_wheel.reproduce import Reproduction, ReproductionConfig
from rulkit.systems.reaction_wheel.rul.study import plot_forecasts, plot_rul_densities


def write_report(result: Reproduction, out: Path) -> Path:
    """Write the tables (CSV), figures (PNG), ``report.md`` and ``settings.json`` of ``result``
    into ``out``; sets ``result.files`` and returns the path of ``report.md``.

    The step-1 figures rerun one filter per estimator (their own seeds); a failing figure is
    noted in the report instead of sinking the run."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rep, cfg = result, result.config
    t = time.perf_counter()
    files: list[Path] = []
    if rep.table5 is not None:
        rep.table5.to_csv(out / "table5.csv", index=False)
        files.append(out / "table5.csv")
        try:
            from rulkit.systems.reaction_wheel.temperature.study import plot_temperature_estimates

            files += plot_temperature_estimates(out, seed=cfg.seed,
                                                n_particles=200 if cfg.quick else 350,
                                                variants=(("adaptive", "apf_eq28") if cfg.quick
                                                          else ("pf", "adaptive", "apf",
                                                                "apf_eq28")),
                                                with_ekf=not cfg.quick)
        except Exception as err:  # a figure must not sink the run; say so in the report
            rep.notes.append(f"step-1 figures failed: {type(err).__name__}: {err}")
    rep.table6.table.to_csv(out / "table6.csv", index=False)
    files.append(out / "table6.csv")
    files += _plot_tracking(rep.table6, out)
    if rep.table6_alt is not None:
        name = f"table6_errors_{cfg.alt_error_on}.csv"
        rep.table6_alt.table.to_csv(out / name, index=False)
        files.append(out / name)
    rep.step3.table.to_csv(out / "table7.csv", index=False)
    rep.step3.metrics.to_csv(out / "prognostic_metrics.csv", index=False)
    files += [out / "table7.csv", out / "prognostic_metrics.csv"]
    plot_rul_densities(rep.step3, out / "rul_density.png")
    files.append(out / "rul_density.png")
    for s in (1, 2):
        p = out / f"forecast_scenario{s}.png"
        plot_forecasts(rep.step3, rep.table6, s, p)
        files.append(p)
    files.append(_plot_paths(out / "temperature_paths.png"))
    if rep.sensitivity is not None:
        rep.sensitivity.to_csv(out / "sensitivity.csv", index=False)
        files.append(out / "sensitivity.csv")
    for name, df in (("table5_seed_filters.csv", rep.seed_filters), ("eq28_weights.csv", rep.eq28),
                     ("table6_one_vs_two_step.csv", rep.one_vs_two),
                     ("table6_real_step1.csv", rep.real_step1)):
        if df is not None:
            df.to_csv(out / name, index=False)
            files.append(out / name)
    rep.files = [*files, out / "report.md", out / "settings.json"]
    rep.timings["tables, figures and report files"] = time.perf_counter() - t
    (out / "report.md").write_text(render_report(rep))
    (out / "settings.json").write_text(json.dumps(_jsonable(cfg), indent=2))
    return out / "report.md"


def _jsonable(cfg: ReproductionConfig) -> dict[str, Any]:
    d = asdict(cfg)
    d["step2"]["n_windows"] = cfg.step2.n_windows
    return d


def _plot_tracking(t6: Any, out: Path) -> list[Path]:
    """b and beta0 estimates of run 0 against the truth (like seed 001 Figs 13, 16, 17)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from rulkit.systems.reaction_wheel.degradation.study import row_label

    paths = []
    for sid in sorted({c.scenario_id for c in t6.cases}):
        fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
        W = t6.settings.n_windows
        days = (np.arange(W) + 1) * WINDOW_S / DAY_S
        b_true, beta_true = truth_parameters(sid, W)
        for c in (c for c in t6.cases if c.scenario_id == sid):
            for meth, (bm, _bs, em, _es) in c.traces.items():
                lab = row_label(c.source, meth)
                axes[0].plot(days, bm, lw=0.7, label=lab)
                axes[1].plot(days, em, lw=0.7, label=lab)
        axes[0].plot(days, b_true, "k--", lw=1.2, label="truth")
        axes[1].plot(days, beta_true, "k--", lw=1.2, label="truth")
        axes[0].set_ylabel("b (C)")
        axes[1].set_ylabel("beta0 (mL/s)")
        axes[1].set_xlabel("time (days)")
        axes[0].set_xscale("symlog", linthresh=1.0)
        axes[0].legend(fontsize=7, ncol=2)
        axes[0].set_title(f"Scenario {sid}: step-2 parameter tracking, run 0")
        fig.tight_layout()
        p = out / f"step2_tracking_scenario{sid}.png"
        fig.savefig(p, dpi=120)
        plt.close(fig)
        paths.append(p)
    return paths


def _plot_paths(path: Path) -> Path:
    """The assumed temperature paths of the two scenarios (like seed 001 Figs 18, 20)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.linspace(0, 120 * DAY_S, 20000)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.5))
    for ax, s in zip(axes, (1, 2), strict=True):
        ax.plot(t / DAY_S, PATHS[s](t), lw=0.3)
        ax.set_title(f"Scenario {s} lubricant temperature [R]")
        ax.set_xlabel("time (days)")
        ax.set_ylabel("T (C)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _md(df: Any) -> str:
    """A table of the report: :func:`rulkit.reporting.markdown_table`, 3 decimals."""
    from rulkit.reporting import markdown_table

    return markdown_table(df, ".3f")


def render_report(rep: Reproduction) -> str:
    """report.md: our numbers beside the paper's, every [R] choice, timings and caveats."""
    cfg = rep.config
    st2, st3 = cfg.step2, cfg.step3
    L: list[str] = []
    L.append("# Reaction-wheel lubrication prognostics: reproduction of seed 001 (Tables 5-7)\n")
    L.append(f"Command size: {'--quick' if cfg.quick else 'full'}; runs = {cfg.n_runs}; "
             f"seed = {cfg.seed}; step-2 horizon = {st2.horizon_days:g} days "
             f"({st2.n_windows} windows of 4 min).\n")
    if cfg.quick:
        L.append("**This is the reduced `--quick` run**: fewer runs, a 10-day step-2 horizon "
                 "instead of three months, fewer particles, no shortcut validation; its numbers "
                 "are indicative only. The full run is `rulkit reproduce rw-lubrication`.\n")
    L += _table5_lines(rep)
    L += _seed_filter_lines(rep)
    L.append("## Step 1 -> 2: the T^ shortcut\n")
    L.append("A 0.05 s particle filter over three months (155 million steps) per run is out of "
             "reach for 20 runs, so step 2 uses T^ = T + e with e a bias plus a stationary AR(1) "
             f"process held over {st2.hold_samples} samples ({st2.hold_samples * 0.05:g} s), "
             "whose statistics are measured on real step-1 runs "
             "(docs/systems/reaction-wheel.md §4):\n")
    L.append("| source | step-1 variant | bias (C) | std (C) | tau (s) | within-block jitter (C) "
             "| measured on |")
    L.append("| --- | --- | --- | --- | --- | --- | --- |")
    for src, e in list(rep.errors.items()) + list(rep.errors_alt.items()):
        L.append(f"| {src} | {STEP1_VARIANTS[src]} | {e.bias_c:.3f} | {e.std_c:.3f} | "
                 f"{e.tau_s:.1f} | {e.white_std_c:.4f} | {e.source} |")
    L.append("")
    L.append(f"Table 6 below uses the statistics measured on the {cfg.error_on} runs (first "
             "rows)" + (", and is repeated with the others." if rep.errors_alt else ".") + "\n")
    if rep.validation:
        L.append("**Validation of the shortcut** against the real step-1 estimator on the "
                 "scenario-1 path (wheel at constant 2 V [R], low noise; other noise seeds than "
                 "the fit), synthetic T^ from the statistics used for Table 6:\n")
        L.append("| source | hours | runs | window-mean T^ error std, real (C) | same, synthetic "
                 "(C) | b RMSPE two-step real / synth (%) | b RMSPE RB-PF real / synth (%) | "
                 "error process fitted on this path |")
        L.append("| --- | --- | --- | --- | --- | --- | --- | --- |")
        for src, v in rep.validation.items():
            f = v.fitted_on_path
            L.append(f"| {src} | {v.hours:g} | {v.n_runs} | {v.window_error_std_real:.3f} | "
                     f"{v.window_error_std_synth:.3f} | "
                     f"{v.rmspe_b_real['two_step'].mean():.1f} / "
                     f"{v.rmspe_b_synth['two_step'].mean():.1f} | "
                     f"{v.rmspe_b_real['rbpf'].mean():.1f} / {v.rmspe_b_synth['rbpf'].mean():.1f}"
                     f" | bias {f.bias_c:.2f} C, std {f.std_c:.2f} C, tau {f.tau_s:.0f} s |")
        L.append("")
    else:
        L.append("The shortcut was **not validated** in this (quick) run; the full run compares "
                 "it with the real step-1 estimator over a few hours.\n")
    L.append("## Step 2: degradation-model parameters (Table 6)\n")
    L.append(f"RMSPE in %, mean (and sd) over {rep.table6.n_runs} runs (seed {rep.table6.seed}) "
             "of each run's RMSPE over all windows against the piecewise-constant truth at the "
             "window ends. Paper values from seed 001 Table 6. Rows marked (ours) are not in the "
             "paper: the RB-PF step-2 tracker, and the RBPF step-1 source (the Rao-Blackwellised "
             "PF, design RBJ, of Table 5) whose T^ error statistics are measured like the "
             "others'.\n")
    L.append(_md(rep.table6.table) + "\n")
    L.append(f"Step-2 wall time: {rep.table6.seconds:.1f} s.\n")
    if rep.table6_alt is not None:
        alt = "table3" if cfg.error_on == "path" else "path"
        L.append(f"**Table 6 with the T^ error statistics of the {alt} runs** (same runs, "
                 "seeds and settings otherwise):\n")
        L.append(_md(rep.table6_alt.table) + "\n")
    if rep.sensitivity is not None:
        L.append("### Sensitivity to the unstated settings (scenario 1, APF T^)\n")
        L.append(f"{cfg.sensitivity_runs} runs, {cfg.sensitivity_days:g}-day horizon, one setting "
                 "varied at a time from the defaults below.\n")
        L.append(_md(rep.sensitivity[["setting", "value", "method", "rmspe_b", "rmspe_beta0"]])
                 + "\n")
    L += _one_vs_two_lines(rep) + _real_step1_lines(rep)
    L += _findings(rep)
    L.append("## Step 3: RUL (Table 7)\n")
    thr = rep.step3.thresholds
    L.append(f"Thresholds [R] set so the expected truth fails on day {st3.failure_day:g}: "
             f"X_total = {thr[1]:.6g} mL (scenario 1), X_bearing = {thr[2]:.6g} mL (scenario 2)."
             f" Table 7 at the prediction time nearest day {st3.table7_day:g}: min / max / mean "
             f"over runs of 100 |mean RUL^ - RUL| / RUL.\n")
    L.append(_md(rep.table7) + "\n")
    L.append("### Prognostics metrics over prediction times\n")
    L.append(f"alpha-lambda (alpha = {st3.alpha_lambda_alpha}, lambda = "
             f"{st3.alpha_lambda_lambda}, mass >= 0.5) pass rate over runs; prognostic horizon "
             f"(alpha = {st3.ph_alpha} of t_EoL, absolute bounds) median over runs; coverage of "
             f"the stated {st3.interval_level:.0%} intervals over all (time, run) pairs.\n")
    L.append(_md(rep.step3.metrics) + "\n")
    L += _report_choices_and_files(rep)
    return "\n".join(L) + "\n"


def _table5_lines(rep: Reproduction) -> list[str]:
    """The step-1 section: Table 5 beside the paper's, and what the RBPF rows are."""
    cfg = rep.config
    L: list[str] = []
    L.append("## Step 1: lubricant temperature (Table 5)\n")
    if rep.table5 is not None:
        t5 = rep.table5
        keep = [c for c in ("method", "design", "noise", "N", "runs", "rmspe_mean", "rmspe_sd",
                            "paper", "rmspe_late_mean", "cover_mean", "cover_late_mean")
                if c in t5.columns]
        L.append("Produced by `rulkit.systems.reaction_wheel.temperature.study.run_table5` "
                 "(see its own documentation for its settings). RMSPE of T in % over 0-500 s, "
                 "ours beside the paper's; `rmspe_late_mean` is the RMSPE after 100 s and "
                 "`cover_*` the fraction of samples whose 90 % interval holds the true T "
                 "(over 0-500 s, after 100 s).\n")
        L.append(_md(t5[keep]) + "\n")
        if cfg.table5_extra_designs:
            L.append(
                "Beyond the seeds: method `rbpf` (designs "
                + ", ".join(cfg.table5_extra_designs)
                + ") is a Rao-Blackwellised particle filter: each particle samples the "
                "temperature path and carries an exact Kalman filter of [I, w] given it "
                "(`rulkit.systems.reaction_wheel.temperature.rbpf`). RBJ models the temperature as "
                "a random "
                "walk (q_T = 0.01 C per sample) with rare 5 C jumps, proposed more often than "
                "their prior rate and reweighted. Its three settings were chosen on runs 0-2 of "
                "seed 0 (so they are not independent of this table); a held-out seed-1 grid "
                "gave the same picture. The seed-faithful rows are unchanged by it. Why the "
                "seed designs lag: under a q_T random walk the 8 C step at 50 s has almost no "
                "prior probability, so a particle cloud follows it by diffusion and selection "
                "and then oscillates, while the EKF's linear update jumps.\n")
    else:
        L.append("Not run in this reproduction.\n")
    return L


def _seed_filter_lines(rep: Reproduction) -> list[str]:
    """The five weightings in both designs, and eq. 28 against Bayes
    (docs/systems/reaction-wheel.md §3.2)."""
    L: list[str] = []
    if rep.seed_filters is not None:
        t5 = rep.seed_filters
        keep = [c for c in ("method", "design", "noise", "N", "runs", "rmspe_mean", "paper",
                            "rmspe_late_mean", "cover_mean", "cover_late_mean") if c in t5]
        L.append("### All five weightings in both designs\n")
        L.append("The plain PF (seed Fig. 9), PF + adaptive resampling, the auxiliary PF of Pitt "
                 "and Shephard (`apf`: first-stage weights from each particle's point "
                 "prediction), eq. 28 as printed (`apf_eq28`) and its tempered form, each in "
                 "design F1 (as in the papers) and F2 (particles carry [I, w]); same data and "
                 "seeds as Table 5, 90 % interval coverage beside the RMSPE.\n")
        L.append(_md(t5[keep]) + "\n")
    if rep.eq28 is not None:
        e = rep.eq28
        L.append("### Why eq. 28 fails\n")
        L.append("A plain F2 PF runs over the Table 3 path, and at every step the same prior "
                 "weights and likelihoods are weighted by Bayes (w_prev p) and by eq. 28: "
                 "ESS / N after each, the median log10 ratio of the largest to the smallest "
                 "non-zero weight, and the fraction of weights eq. 28 clips to zero.\n")
        L.append(_md(e) + "\n")
        for _, r in e.iterrows():
            L.append(f"- {r['noise']} noise: Bayes spreads the weights over "
                     f"{r['log10_weight_ratio_bayes']:.2f} decades, eq. 28 over "
                     f"{r['log10_weight_ratio_eq28']:.2f} "
                     + ("(it compresses them instead of sharpening them)"
                        if r["log10_weight_ratio_eq28"] < r["log10_weight_ratio_bayes"]
                        else "(not a compression here)")
                     + f", and clips {100 * r['clipped_fraction_eq28']:.1f} % of them to zero.")
        L.append("")
    return L


def _one_vs_two_lines(rep: Reproduction) -> list[str]:
    t = rep.one_vs_two
    if t is None or t.empty:
        return []
    return ["### One-step against two-step on every T^\n",
            "The seeds claim the two-step PF beats the one-step PF; Table 6 tests it only on the "
            "biased APF estimate. Here both run on every T^ source, the good ones (RBPF, and "
            "IMM, the default estimator on a user's record) included; RMSPE in %, mean over the "
            "runs (same measured losses and seeds as Table 6).\n", _md(t) + "\n"]


def _real_step1_lines(rep: Reproduction) -> list[str]:
    t = rep.real_step1
    if t is None:
        return ["The real step-1 estimator was not run over the whole horizon in this run "
                "(`real_step1_runs = 0`).\n"]
    per_run = float(t["step-1 s per run"].mean())
    days = float(t["days"].iloc[0])
    full = per_run * 2 * rep.config.n_runs
    return ["### The real step 1 over the whole horizon\n",
            f"The compiled IMM EKF over all {days:g} days of 20 Hz telemetry per run (both "
            "scenarios, the wheel at 2 V; docs/systems/reaction-wheel.md §7.4), against the "
            "shortcut built from its measured error statistics, on the same measured losses "
            "with the same tracker streams: RMSPE in %.\n", _md(t) + "\n",
            f"One run's real step 1 took {per_run:.0f} s here; all {rep.config.n_runs} runs of "
            f"both scenarios would take about {full / 60:.0f} min of one core, so Table 6 keeps "
            "the shortcut (for the seeds' particle filters, which cost about N times more per "
            "sample, the real path is out of reach); `--real-step1-runs N` runs more.\n"]


def _report_choices_and_files(rep: Reproduction) -> list[str]:
    """The end of report.md: every setting where the seeds are silent, timings, notes, files."""
    st2, st3 = rep.config.step2, rep.config.step3
    L: list[str] = []
    L.append("## Choices where the seeds are silent [R]\n")
    L.append("Step 2 (`rulkit.systems.reaction_wheel.degradation.trackers.DegradationConfig`):\n")
    for k, v in asdict(st2).items():
        L.append(f"- `{k}` = {v}")
    L.append("- measurement noise: the Wiener term gives y_k noise sigma_y = noise_rel x healthy "
             "window loss at the mean path temperature")
    L.append("- b and T in deg C; loss rate beta0 exp(-b/T) (docs/systems/reaction-wheel.md §4)")
    L.append("- two-step PF1 likelihood on ln z with delta-method variance; PF2 uses PF1's "
             "posterior mean of b")
    L.append("- RB-PF beta0 prior: Gaussian with the mean and sd of the uniform prior")
    L.append("- truth per window taken at the window end (the fault at 159 min falls in window "
             "index 39)")
    L.append("- window sums by Gauss quadrature on the distribution of 1/T^ within each window "
             f"({st2.n_nodes} nodes; tests bound the error against the direct sum)")
    L.append("\nStep-2/3 temperature paths (`rulkit.systems.reaction_wheel.lubrication.PATHS`):\n")
    for s, p in PATHS.items():
        L.append(f"- scenario {s}: {p}")
    L.append("\nStep 3 (`rulkit.systems.reaction_wheel.rul.forecast.RULConfig`):\n")
    for k, v in asdict(st3).items():
        L.append(f"- `{k}` = {v}")
    L.append("- forecast along the true (known) future path; true RUL from the true "
             "post-fault parameters and the same measured X_k")
    L.append(f"- fault scenarios: {SCENARIOS[1]}; {SCENARIOS[2]}")
    L.append("\n## Timings\n")
    for k, v in rep.timings.items():
        L.append(f"- {k}: {v:.1f} s")
    if rep.notes:
        L.append("\n## Notes\n")
        L += [f"- {n}" for n in rep.notes]
    L.append("\n## Files\n")
    L += [f"- {p.name}" for p in rep.files]
    return L


def _findings(rep: Reproduction) -> list[str]:
    """Computed statements comparing our Table 6 with the paper's claims (no fixed prose)."""
    L = ["### Reading Table 6\n"]
    t6 = rep.table6.table.set_index("method")

    def get(row: str, col: str) -> float:
        try:
            return float(t6.loc[row, col])
        except KeyError:
            return float("nan")

    for s in (1, 2):
        two = get("APF + two-step PF", f"S{s} b ours")
        one = get("APF + one-step PF", f"S{s} b ours")
        rb = get("APF + RB-PF (ours)", f"S{s} b ours")
        p2, p1 = get("APF + two-step PF", f"S{s} b paper"), get("APF + one-step PF",
                                                              f"S{s} b paper")
        L.append(f"- Scenario {s}, RMSPE of b with the APF T^: two-step {two:.1f} %, one-step "
                 f"{one:.1f} %, RB-PF {rb:.1f} % (paper: two-step {p2:.1f} %, one-step "
                 f"{p1:.1f} %).")
    L += _rbpf_source_finding(rep, get)
    for src, e in rep.errors.items():
        head = (f"- The measured {src} T^ error (bias {e.bias_c:+.2f} C, std {e.std_c:.2f} C, "
                f"correlation time {e.tau_s:.0f} s)")
        if max(abs(e.bias_c), e.std_c) > 0.1:
            L.append(head + " is an error in the regressor 1/T of step 2: b is identified only "
                     "through the change of 1/T between windows "
                     "(docs/systems/reaction-wheel.md §4), so a slow T^ "
                     "error biases b (errors-in-variables attenuation) and a T^ bias rescales it "
                     "by about (T^/T)^2.")
        else:
            L.append(head + " is small: step 2 is then limited by the measurement noise, the "
                     "random-walk settings and the re-convergence after the fault.")
    if rep.sensitivity is not None:
        sv = rep.sensitivity
        sel = sv[sv["setting"].str.startswith("T^ error std")]
        for meth in sel["method"].unique():
            r = sel[sel["method"] == meth].sort_values("value")
            pairs = ", ".join(f"x{v:g}: {b:.1f} %" for v, b in zip(r["value"], r["rmspe_b"],
                                                                    strict=True))
            L.append(f"- Sensitivity, {meth}: RMSPE of b against the T^ error std scale "
                     f"({pairs}).")
    L.append("- docs/systems/reaction-wheel.md §6 notes that an unoptimised attempt gave "
             "10-25 % RMSPE of b for both "
             "methods while the seeds claim about 4 % (two-step) vs 137 % (one-step); the "
             "numbers above are what this implementation measures under the settings listed "
             "below, not tuned towards either.\n")
    return L


def _rbpf_source_finding(rep: Reproduction, get: Callable[[str, str], float]) -> list[str]:
    """One computed sentence: what the RBPF step-1 source (ours) changes in Table 6."""
    e_rb, e_apf = rep.errors.get("RBPF"), rep.errors.get("APF")
    if e_rb is None or e_apf is None:
        return []

    def pair(row: str) -> str:
        return " / ".join(f"{get(row, f'S{s} b ours'):.1f}" for s in (1, 2))

    two_rb = [get("RBPF + two-step PF (ours)", f"S{s} b ours") for s in (1, 2)]
    two_apf = [get("APF + two-step PF", f"S{s} b ours") for s in (1, 2)]
    paper = [get("APF + two-step PF", f"S{s} b paper") for s in (1, 2)]
    better = all(r < a for r, a in zip(two_rb, two_apf, strict=True))
    level = all(r <= 1.5 * p for r, p in zip(two_rb, paper, strict=True))
    verdict = ("lower than with the APF T^ in both scenarios" if better
               else "not lower than with the APF T^ in both scenarios")
    close = ("at or below 1.5x" if level else "above 1.5x")
    return [f"- RBPF step-1 source (ours): its T^ error (bias {e_rb.bias_c:+.2f} C, std "
            f"{e_rb.std_c:.2f} C; APF: {e_apf.bias_c:+.2f} C, {e_apf.std_c:.2f} C) gives b "
            f"RMSPE (S1 / S2, %) {pair('RBPF + two-step PF (ours)')} with the two-step PF and "
            f"{pair('RBPF + RB-PF (ours)')} with the RB-PF, against "
            f"{pair('APF + two-step PF')} for APF + two-step PF and "
            f"{pair('PF + two-step PF')} for PF + two-step PF: {verdict}, and {close} the "
            f"paper's APF + two-step values ({' / '.join(f'{p:.1f}' for p in paper)}). "
            + ("Step 2 is the same in all rows (same measured losses, trackers and settings), "
               "so the gap between our APF rows and the paper's follows the quality of the "
               "step-1 T^, not step 2." if better else
               "So the quality of the step-1 T^ alone does not explain the APF rows.")]

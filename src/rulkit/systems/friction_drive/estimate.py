"""``rulkit drive`` as a library call: the augmented EKF over a user's record, its consistency
checks and the Monte Carlo RUL (docs/systems/friction-drive.md §9).

:func:`estimate` runs the compiled filter (:mod:`.deterioration`) over a checked record
(:mod:`.record`) with the drive of a machine file (:mod:`.machine`), checks the innovations
(time-averaged NIS against its chi-square interval, Ljung-Box whiteness) and predicts the RUL
from the last estimate (:func:`rulkit.systems.friction_drive.rul.predict_rul`: trajectories
from N(x_hat, P) at the future current, optimistic and pessimistic trajectories from alpha +- c
sd, m -+ c sd, a few re-run with LSODA). Two results refuse to be reported: more samples outside
the gate than the machine file allows (:class:`DriveModelMismatchError`: the record is not
described by this machine, usually a unit) and a contact quality or wear rate clearly below
zero (:class:`ImpossibleDriveEstimateError`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rulkit.estimation.consistency import InnovationCheck, check_innovations
from rulkit.machine_file import machine_file_template
from rulkit.systems.friction_drive.deterioration import (
    GATED,
    STATUS,
    UPDATED,
    DriveTrack,
    EKFSettings,
    track,
)
from rulkit.systems.friction_drive.machine import DRIVE_SCHEMA, DriveMachine
from rulkit.systems.friction_drive.record import DriveRecord, DriveRecordError
from rulkit.systems.friction_drive.rul import RULResult, predict_rul

__all__ = ["IMPOSSIBLE_SDS", "MAX_LAG", "WHITENESS_ALPHA", "DriveEstimate",
           "DriveModelMismatchError", "ImpossibleDriveEstimateError", "estimate", "summary",
           "summary_lines", "write_outputs"]

#: Ljung-Box lags and level of the whiteness test (docs/systems/friction-drive.md §5).
MAX_LAG = 20
WHITENESS_ALPHA = 0.01
#: An estimate more than this many standard deviations below zero is physically impossible.
IMPOSSIBLE_SDS = 5.0


class DriveModelMismatchError(DriveRecordError):
    """Too many samples outside the filter's gate: the machine file does not describe the
    record (a unit, a constant or the noise levels)."""


class ImpossibleDriveEstimateError(DriveRecordError):
    """A contact quality alpha or a wear rate m clearly below zero: no physical drive gives
    it, the record and the machine file disagree."""


@dataclass(frozen=True)
class DriveEstimate:
    """What :func:`estimate` found: the ``record``, the ``machine``, the filter's ``track``,
    the innovation checks over the fully updated samples (``None`` when there are too few) and
    the ``rul`` prognosis from the last sample."""

    record: DriveRecord
    machine: DriveMachine
    track: DriveTrack
    innovations: InnovationCheck | None
    rul: RULResult


def settings(machine: DriveMachine, dt: float) -> EKFSettings:
    """The kernel settings of ``machine`` for a sampling step ``dt``: RK4 sub-steps no longer
    than ``max_substep``."""
    f = machine.values["filter"]
    return EKFSettings(dt=dt, n_sub=max(1, math.ceil(dt / f["max_substep"] - 1e-9)),
                       f44=f["f44"], gate=f["gate"], midpoint=f["jacobian_at"] == "midpoint")


def estimate(record: DriveRecord, machine: DriveMachine,
             rng: np.random.Generator) -> DriveEstimate:
    """The augmented EKF over ``record``, its innovation checks and the RUL (module docstring).
    Raises :class:`DriveModelMismatchError` or :class:`ImpossibleDriveEstimateError` instead of
    reporting a result no physical drive gives."""
    x0, P0 = machine.prior(*_first_speeds(record))
    tr = track(record.speeds, record.current, x0, P0, settings(machine, record.dt),
               machine.params, machine.q_rates, machine.R)
    _check_gated(tr, record, machine)
    _check_physical(tr, record)
    full = tr.status == UPDATED
    inn = None
    if np.count_nonzero(full) > MAX_LAG + 1:
        inn = check_innovations(tr.nu[full], tr.S[full], max_lag=MAX_LAG,
                                whiteness_alpha=WHITENESS_ALPHA)
    r = machine.values["rul"]
    pred = predict_rul(tr.x[-1], tr.P, rng, t_pred=float(record.t[-1]),
                       n_samples=r["samples"], current=r["current"], c=r["bound_sds"],
                       horizon_h=r["horizon_h"], transient=r["transient"],
                       n_validate=r["lsoda_checks"], params=machine.params)
    return DriveEstimate(record, machine, tr, inn, pred)


def _first_speeds(record: DriveRecord) -> tuple[float, float]:
    """The first measured value of each speed (the prior's speeds)."""
    out = []
    for j, name in enumerate(("w1_rad_s", "w2_rad_s")):
        ok = np.flatnonzero(np.isfinite(record.speeds[:, j]))
        if ok.size == 0:
            raise DriveRecordError(f"{record.source}: column {name!r} has no value at all")
        out.append(float(record.speeds[ok[0], j]))
    return out[0], out[1]


def _check_gated(tr: DriveTrack, record: DriveRecord, machine: DriveMachine) -> None:
    measured = np.count_nonzero(np.isfinite(tr.nis))
    gated = tr.count(GATED)
    limit = machine.values["limits"]["max_gated_fraction"]
    if measured and gated > limit * measured:
        first = int(np.flatnonzero(tr.status == GATED)[0])
        raise DriveModelMismatchError(
            f"{record.source}: {gated} of {measured} samples ({gated / measured:.1%}) are "
            f"outside the filter's gate (NIS > {machine.values['filter']['gate']:g}; the first "
            f"at data row {int(record.row[first]) + 1}): the machine file does not describe "
            "this record. Check the units (rad/s, A, s), [drive] and the speed noise "
            "[sensors]; the machine file's max_gated_fraction is "
            f"{limit:g}")


def _check_physical(tr: DriveTrack, record: DriveRecord) -> None:
    for j, name, unit in ((2, "contact quality alpha", "N s/m"), (3, "wear rate m", "s/m^2")):
        x, sd = float(tr.x[-1, j]), float(tr.sd[-1, j])
        if x + IMPOSSIBLE_SDS * sd < 0:
            raise ImpossibleDriveEstimateError(
                f"{record.source}: the estimated {name} = {x:.4g} {unit} (sd {sd:.2g}) at the "
                "last sample is negative, which is physically impossible; check the units "
                "(speeds in rad/s, current in A, time in s) and the constants [drive] of the "
                "machine file")


def summary(est: DriveEstimate) -> dict[str, Any]:
    """The estimate as plain data (what ``summary.json`` holds)."""
    tr, rec, pr = est.track, est.record, est.rul
    x, sd = tr.x[-1], tr.sd[-1]
    p = est.machine.params
    c = est.machine.values["rul"]["bound_sds"]
    rul = pr.rul
    out: dict[str, Any] = {
        "source": rec.source, "machine": est.machine.source, "rows": rec.n_rows,
        "dt_s": rec.dt, "duration_s": float(rec.t[-1]), "gap_steps": rec.n_gap_steps,
        "missing_speeds": rec.n_missing,
        "status_counts": {STATUS[k]: tr.count(k) for k in STATUS},
        "final": {n: {"mean": float(v), "sd": float(s), "low": float(v - c * s),
                      "high": float(v + c * s)}
                  for n, v, s in zip(("w1", "w2", "alpha", "m"), x, sd, strict=True)},
        "D": float(1.0 - x[2] / p.alpha0), "failure_level": p.failure_level,
        "bound_sds": c,
        "rul_h": {"median": rul.median, "interval_90": list(rul.interval(0.9)),
                  "normal_fit": list(pr.normal_fit), "optimistic": pr.optimistic_h,
                  "pessimistic": pr.pessimistic_h, "nominal": pr.nominal_h,
                  "fraction_never": pr.fraction_never,
                  "fraction_censored": rul.fraction_censored, "samples": rul.n,
                  "lsoda_check_max_abs_h": pr.validation_max_abs_h,
                  "lsoda_checks": pr.validation_n},
        "innovations": None if est.innovations is None else est.innovations.to_dict(),
    }
    return out


def summary_lines(est: DriveEstimate) -> list[str]:
    """The command's printed summary, plain text."""
    s = summary(est)
    f, rec = s["final"], est.record
    st = s["status_counts"]
    r = s["rul_h"]
    cur = est.machine.values["rul"]["current"]
    lines = [
        f"{rec.n_rows} rows, sampling step {_g(rec.dt * 1e3)} ms, {_g(s['duration_s'])} s; "
        f"{rec.n_gap_steps} gap steps bridged, {rec.n_missing} missing speed values",
        f"machine: {s['machine']}",
        f"estimate at t = {_g(s['duration_s'])} s (+- {s['bound_sds']:g} sd):",
        f"  alpha = {_g(f['alpha']['mean'])} +- {_g(s['bound_sds'] * f['alpha']['sd'], 2)} "
        f"N s/m   D = {_g(s['D'])} (failure at D = {s['failure_level']:g})",
        f"  m     = {_g(f['m']['mean'])} +- {_g(s['bound_sds'] * f['m']['sd'], 2)} s/m^2",
        f"samples: {st['updated']} updated, {st['one channel']} on one channel, "
        f"{st['missing']} without speeds, {st['gated']} outside the gate (not trusted)",
    ]
    lines += _innovation_lines(est.innovations)
    lines += [
        f"RUL at {cur:g} A held, m constant ({r['samples']} trajectories): median "
        f"{_h(r['median'])}, 90 % [{_h(r['interval_90'][0])}, {_h(r['interval_90'][1])}]"
        + (f", normal fit {_g(r['normal_fit'][0])} +- {_g(r['normal_fit'][1], 3)} h"
           if r["fraction_never"] == 0 and math.isfinite(r["normal_fit"][0]) else ""),
        f"  optimistic {_h(r['optimistic'])}, pessimistic {_h(r['pessimistic'])} "
        f"(alpha +- {s['bound_sds']:g} sd, m -+ {s['bound_sds']:g} sd); m <= 0 (never fails) "
        f"in {r['fraction_never']:.0%} of the trajectories",
    ]
    if r["lsoda_checks"]:
        lines.append(f"  LSODA over the whole horizon: max |difference| "
                     f"{_g(r['lsoda_check_max_abs_h'], 2)} h on {r['lsoda_checks']} "
                     "trajectories")
    return lines


def _innovation_lines(inn: InnovationCheck | None) -> list[str]:
    if inn is None:
        return [f"innovations: too few fully updated samples for the checks (need "
                f"{MAX_LAG + 2})"]
    lo, hi = inn.nis_interval
    p = ", ".join(f"{v:.2g}" for v in inn.ljung_box_p)
    return [
        f"innovations ({inn.n_steps} samples): mean NIS {inn.mean_nis:.4f}, 95 % interval "
        f"[{lo:.4f}, {hi:.4f}]: {'inside' if inn.nis_ok else 'OUTSIDE'}; whiteness "
        f"(Ljung-Box, {inn.max_lag} lags, p = {p} for w1, w2): "
        f"{'white' if inn.white else 'NOT white'}",
        f"  consistent: {'yes' if inn.consistent else 'no'}"
        + ("" if inn.consistent else " (the filter's uncertainty does not match the data: "
           "read the bounds with care; see docs/commands/drive.md)"),
    ]


def _g(v: float, digits: int = 4) -> str:
    return format(v, f".{digits}g")


def _h(v: float) -> str:
    return "beyond the horizon" if math.isinf(v) else f"{v:.4g} h"


def write_outputs(est: DriveEstimate, out: Path) -> list[Path]:
    """``estimates.csv`` (one row per grid step), ``rul.json``, ``summary.json`` (NaN and
    infinite values as ``null``) and ``machine.toml`` (the machine in effect) into ``out``."""
    import pandas as pd

    out.mkdir(parents=True, exist_ok=True)
    tr, rec = est.track, est.record
    p = est.machine.params
    frame = pd.DataFrame({
        "row": np.where(rec.row >= 0, rec.row + 1, 0), "t_s": rec.t, "current_A": rec.current,
        "w1_rad_s": tr.x[:, 0], "w2_rad_s": tr.x[:, 1], "alpha": tr.x[:, 2], "m": tr.x[:, 3],
        "D": 1.0 - tr.x[:, 2] / p.alpha0, "sd_w1": tr.sd[:, 0], "sd_w2": tr.sd[:, 1],
        "sd_alpha": tr.sd[:, 2], "sd_m": tr.sd[:, 3], "nis": tr.nis,
        "status": pd.Categorical.from_codes(tr.status, [STATUS[k] for k in sorted(STATUS)]),
    })
    paths = [out / "estimates.csv", out / "rul.json", out / "summary.json",
             out / "machine.toml"]
    frame.to_csv(paths[0], index=False)
    est.rul.rul.to_json(paths[1])
    paths[2].write_text(json.dumps(_finite(summary(est)), indent=2, allow_nan=False) + "\n")
    paths[3].write_text(machine_file_template(DRIVE_SCHEMA, f"drive machine in effect "
                                              f"({est.machine.source})",
                                              values=est.machine.values))
    return paths


def _finite(v: Any) -> Any:
    """``v`` with numpy scalars as Python numbers and NaN / inf as ``None`` (valid JSON)."""
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_finite(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v

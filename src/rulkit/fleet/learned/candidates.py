"""The candidate models ``rulkit fit`` chooses among, by name, and how a fitted one is stored.

docs/fleet-models.md section 6. Every candidate offers the same interface
(:class:`FleetModel`): a per-unit state (``empty_state``, ``update`` one acquisition per unit,
``replay`` a history, ``state_from_columns`` / ``state.columns()`` for storage,
``state.take``), the RUL ``rul_quantiles(state, levels)`` (vectorised over units; >= 0, +inf
for censored mass, 0 once the measured hi >= 1, NaN before a first acquisition) and
``rul_cdf(state, r)``, its ``warnings``, ``time_unit`` and ``time_axis``. So one ``status`` row
shows the median and interval of one distribution whatever the candidate.

========================  =======================================================
name                      model
========================  =======================================================
``paris``                 Box-Cox growth, noise on the growth (log-like) scale: eq. (1)
``paris-additive``        Box-Cox growth, additive HI noise: eq. (7)
``paris-multiplicative``  Box-Cox growth, multiplicative HI noise (log scale): eq. (7)
``paris-mixed``           Box-Cox growth, additive and multiplicative noise: eq. (7)
``paris-additive-iid``    ``paris-additive`` without the random walk (independent errors)
``onset``                 flat until a per-unit onset, then ``paris-additive``: eq. (9)
``similarity``            nearest failed trajectories: eq. (12)
``regression``            each unit's own recent trend: eq. (11)
``linear``                linear growth, noise on the HI scale: eq. (1)
``exponential``           ln(hi - phi) growth: eq. (1)
========================  =======================================================

:data:`AUTO_CANDIDATES` are the ones ``rulkit fit`` compares by default.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from rulkit.fleet.learned.histories import Histories

AUTO_CANDIDATES = ("paris", "paris-additive", "paris-multiplicative", "paris-mixed", "onset",
                   "similarity", "regression")
"""Compared by ``rulkit fit`` unless ``--model`` names others."""
ALL_CANDIDATES = (*AUTO_CANDIDATES, "paris-additive-iid", "linear", "exponential")
"""Every name ``--model`` accepts (besides ``auto``, ``all`` and ``tracker``)."""


class UnitStates(Protocol):
    """A batch of per-unit states (struct of arrays, the unit on the leading axis): ``t`` the
    age of each unit's last acquisition, ``hi`` its HI, ``n`` the acquisitions assimilated."""

    t: np.ndarray
    hi: np.ndarray
    n: np.ndarray

    def __len__(self) -> int:
        """Number of units."""

    def take(self, idx: np.ndarray) -> Any:
        """The states of the units ``idx`` (index array or mask)."""

    def columns(self) -> dict[str, np.ndarray]:
        """Named columns as stored (``model.state_columns``)."""


class FleetModel(Protocol):
    """What every fitted candidate offers (module docstring)."""

    @property
    def name(self) -> str:
        """The candidate's name (module docstring's table)."""

    @property
    def time_unit(self) -> str:
        """The label of the time unit of every age and RUL."""

    @property
    def warnings(self) -> tuple[str, ...]:
        """What the checks found when it was fitted (stored with it)."""

    @property
    def time_axis(self) -> dict[str, Any] | None:
        """The :class:`~rulkit.fleet.time_axis.TimeAxis` it was fitted on, as a dict."""

    @property
    def log_likelihood(self) -> float:
        """Log-likelihood of the HI on the fitting units (NaN for the baselines)."""

    @property
    def state_columns(self) -> tuple[str, ...]:
        """Names of the per-unit state columns, as stored."""

    def empty_state(self, size: int) -> Any:
        """``size`` units before their first acquisition."""

    def state_from_columns(self, c: dict[str, Any]) -> Any:
        """A state from stored columns."""

    def update(self, state: Any, t: np.ndarray, hi: np.ndarray) -> Any:
        """One acquisition per unit (``t`` ages; NaN = none for that unit)."""

    def replay(self, hist: Histories) -> Any:
        """The state after each row of ``hist``."""

    def rul_quantiles(self, state: Any, levels: tuple[float, ...] = (0.5, 0.05, 0.95)
                      ) -> tuple[np.ndarray, ...]:
        """RUL quantiles per unit, in the time unit (module docstring)."""

    def rul_cdf(self, state: Any, r: np.ndarray) -> np.ndarray:
        """P(RUL <= r), ``r (B, K)``."""

    def to_dict(self) -> dict[str, Any]:
        """The fitted numbers, JSON-ready."""

    def describe(self) -> str:
        """One paragraph with every learned number."""


def _types() -> dict[str, Any]:
    from rulkit.fleet.learned.degradation import DegradationModel
    from rulkit.fleet.learned.hi_noise import HiNoiseModel
    from rulkit.fleet.learned.onset import OnsetModel
    from rulkit.fleet.learned.regression import RegressionModel
    from rulkit.fleet.learned.similarity import SimilarityModel

    return {"degradation": DegradationModel, "hi-noise": HiNoiseModel, "onset": OnsetModel,
            "regression": RegressionModel, "similarity": SimilarityModel}


def model_to_dict(model: FleetModel) -> dict[str, Any]:
    """The model's dict with its ``type`` tag (what ``rulkit fit`` stores)."""
    tag = next(k for k, cls in _types().items() if isinstance(model, cls))
    return {"type": tag, **model.to_dict()}


def model_from_dict(d: dict[str, Any]) -> FleetModel:
    """A stored model back (a dict without ``type`` is a transformed-noise model, as stored
    before the other candidates existed)."""
    types = _types()
    tag = d.get("type", "degradation")
    if tag not in types:
        raise ValueError(f"stored model type {tag!r}: expected one of {sorted(types)}")
    model: FleetModel = types[tag].from_dict(d)
    return model


def check_name(name: str) -> None:
    """``ValueError`` naming the accepted candidates unless ``name`` is one."""
    if name not in ALL_CANDIDATES:
        raise ValueError(f"model {name!r}: expected one of {', '.join(ALL_CANDIDATES)}")


def fit_candidate(name: str, hist: Histories, *, start: FleetModel | None = None,
                  fixed_shape: bool = False, fitted: dict[str, FleetModel] | None = None
                  ) -> FleetModel:
    """Fit the candidate ``name`` on ``hist`` (all units). ``start``: a fit of the same
    candidate to warm-start from (its shape searched locally, or kept when ``fixed_shape``);
    ``fitted``: candidates already fitted on the same units (the onset model starts from
    ``paris-additive``). The result carries the histories' time axis and unit."""
    check_name(name)
    model = _fit(name, hist, start, fixed_shape, fitted or {})
    axis = hist.axis
    return replace(model, time_unit=axis.unit, time_axis=axis.to_dict())  # type: ignore


def _fit(name: str, hist: Histories, start: Any, fixed: bool,
         fitted: dict[str, FleetModel]) -> Any:
    from rulkit.fleet.learned.degradation import fit_model
    from rulkit.fleet.learned.hi_noise import fit_hi_noise
    from rulkit.fleet.learned.onset import fit_onset
    from rulkit.fleet.learned.regression import fit_regression
    from rulkit.fleet.learned.similarity import fit_similarity

    shape = getattr(start, "shape", None) if fixed else None
    if name in ("linear", "exponential", "paris"):
        return fit_model(hist, name, start=start, shape=shape)
    if name.startswith("paris-"):
        noise = name.split("-")[1]
        return fit_hi_noise(hist, noise, walk=not name.endswith("-iid"), start=start,
                            shape=shape)
    if name == "onset":
        base = fitted.get("paris-additive")
        return fit_onset(hist, "additive", start=start, base=base,  # type: ignore[arg-type]
                         fixed_shape=fixed)
    if name == "regression":
        if fixed and start is not None:
            return fit_regression(hist, shape=start.shape, window=start.window)
        return fit_regression(hist)
    if fixed and start is not None:
        return fit_similarity(hist, window=start.window, temperature=start.temperature,
                              bandwidth=start.bandwidth)
    return fit_similarity(hist)


__all__ = ["ALL_CANDIDATES", "AUTO_CANDIDATES", "FleetModel", "UnitStates", "check_name",
           "fit_candidate", "model_from_dict", "model_to_dict"]

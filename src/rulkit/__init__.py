"""rulkit: model-based prognostics.

Telemetry of a degrading machine -> Bayesian state and parameter estimation -> a Remaining
Useful Life (RUL) distribution, with metrics and alerts. Physics lives in :mod:`rulkit.models`;
the algorithms in :mod:`rulkit.estimation` and :mod:`rulkit.prognosis` know no physics.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("rulkit")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]

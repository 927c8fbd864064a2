"""rulkit.plot: each figure is rendered to PNG (Agg, no pyplot) and what it drew is checked:
the artists present, their line data, the cone polygon's vertices, the chi-square bounds
against scipy, the labels. No pixel comparison."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import PolyCollection
from matplotlib.patches import Polygon
from scipy import stats

from rulkit import plot
from rulkit.estimation.base import Posterior
from rulkit.prognosis.rul import RULDistribution


def _render(fig, path: Path) -> None:
    fig.savefig(path, dpi=40)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _by_gid(ax, gid: str):
    found = [a for a in ax.get_children() if a.get_gid() == gid]
    assert found, f"no artist with gid {gid!r}"
    return found[0]


def _dists(times: np.ndarray, t_eol: float, rng: np.random.Generator) -> list[RULDistribution]:
    return [RULDistribution(np.abs(rng.normal(t_eol - t, 3.0, size=500))) for t in times]


def test_cone_vertices_true_rul_and_intervals(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    times = np.array([10.0, 20.0, 30.0, 40.0])
    dists = _dists(times, 60.0, rng)
    ax = plot.alpha_lambda_cone(times, dists, 60.0, alpha=0.25, lam=0.5)
    _render(ax.figure, tmp_path / "cone.png")
    cone = _by_gid(ax, "alpha-lambda-cone")
    assert isinstance(cone, Polygon)
    verts = cone.get_xy()[:3]  # closed polygons repeat the first vertex
    assert np.allclose(verts, [[10.0, 1.25 * 50.0], [60.0, 0.0], [10.0, 0.75 * 50.0]])
    truth = _by_gid(ax, "true-rul")
    assert np.allclose(truth.get_xdata(), [10.0, 60.0]) and np.allclose(truth.get_ydata(),
                                                                          [50.0, 0.0])
    t_lam = _by_gid(ax, "t-lambda")
    assert np.allclose(t_lam.get_xdata(), 35.0)  # t_P + 0.5 (t_EoL - t_P)
    # the medians and the 90 % interval ends are the distributions' own
    line = next(c for c in ax.containers if c.get_label().startswith("median"))
    assert np.allclose(line.lines[0].get_ydata(), [d.median for d in dists])
    caps = np.sort(np.concatenate([c.get_ydata() for c in line.lines[1]]))
    expect = np.sort(np.concatenate([d.interval(0.9) for d in dists]))
    assert np.allclose(caps, expect)
    assert ax.get_xlabel() == "time" and ax.get_ylabel() == "RUL"
    labels = ax.get_legend_handles_labels()[1]
    assert "alpha = 0.25 cone" in labels and "true RUL" in labels


def test_cone_marks_intervals_open_into_censored_mass() -> None:
    times = np.array([0.0, 10.0])
    cens = np.r_[np.zeros(50, bool), np.ones(50, bool)]
    d_open = RULDistribution(np.r_[np.linspace(80, 95, 50), np.full(50, 100.0)],
                             censored=cens, horizon=100.0)
    d_closed = RULDistribution(np.linspace(80, 95, 100))
    assert d_open.interval(0.9)[1] == np.inf
    ax = plot.alpha_lambda_cone(times, [d_open, d_closed], 100.0, lam=None)
    marks = _by_gid(ax, "censored-upper")
    assert np.allclose(marks.get_xdata(), [0.0])
    assert np.isclose(marks.get_ydata()[0], ax.get_ylim()[1] / 1.04)  # just below the top
    assert not [a for a in ax.get_children() if a.get_gid() == "t-lambda"]
    # mostly censored: the median itself is infinite and is drawn at the top, marked open
    d_most = RULDistribution(np.r_[np.linspace(80, 95, 20), np.full(80, 100.0)],
                             censored=np.r_[np.zeros(20, bool), np.ones(80, bool)], horizon=100.0)
    assert d_most.median == np.inf
    ax = plot.alpha_lambda_cone(times, [d_most, d_closed], 100.0)
    top = ax.get_ylim()[1] / 1.04
    bars = next(c for c in ax.containers if c.get_label().startswith("median"))
    assert np.allclose(bars.lines[0].get_ydata(), [top, d_closed.median])
    assert np.isfinite(ax.get_ylim()).all()


def test_cone_with_point_predictions_and_bad_input() -> None:
    ax = plot.alpha_lambda_cone([0.0, 5.0], [9.0, 4.0], 10.0)
    pts = _by_gid(ax, "predictions")
    assert np.allclose(pts.get_ydata(), [9.0, 4.0])
    with pytest.raises(ValueError, match=r"rul: expected 2 RULDistribution objects or a point"):
        plot.alpha_lambda_cone([0.0, 5.0], [9.0, 4.0, 1.0], 10.0)
    with pytest.raises(ValueError, match=r"t_eol: expected a finite time after t_p = 0.0"):
        plot.alpha_lambda_cone([0.0, 5.0], [9.0, 4.0], 0.0)
    with pytest.raises(ValueError, match=r"times: non-finite value nan at index 1"):
        plot.alpha_lambda_cone([0.0, np.nan], [9.0, 4.0], 10.0)


def test_rul_distributions_one_density_per_time(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    times = np.array([0.0, 10.0, 20.0])
    dists = _dists(times, 50.0, rng)
    ax = plot.rul_distributions(times, dists, t_eol=50.0, width=8.0)
    _render(ax.figure, tmp_path / "dists.png")
    polys = [a for a in ax.get_children() if isinstance(a, PolyCollection)
             and str(a.get_gid()).startswith("rul-density-")]
    assert len(polys) == 3
    for k, (poly, t, d) in enumerate(zip(polys, times, dists, strict=True)):
        xy = poly.get_paths()[0].vertices
        assert xy[:, 0].min() == pytest.approx(t)            # stands on its time
        assert xy[:, 0].max() <= t + 8.0 + 1e-9               # no wider than width
        # the widest point of the violin is near the density's mode (~ the median here)
        top = xy[np.argmax(xy[:, 0]), 1]
        assert abs(top - d.median) < 3.0, k
        med = _by_gid(ax, f"rul-median-{k}")
        assert med.get_ydata()[0] == pytest.approx(d.median)
    # each density is scaled to its own peak: every violin is exactly `width` wide
    for p, t in zip(polys, times, strict=True):
        assert p.get_paths()[0].vertices[:, 0].max() - t == pytest.approx(8.0)


def test_rul_distributions_degenerate_and_censored() -> None:
    single = RULDistribution(np.array([5.0, 5.0]))
    cens = RULDistribution(np.r_[np.linspace(1, 9, 10), np.full(10, 10.0)],
                           censored=np.r_[np.zeros(10, bool), np.ones(10, bool)], horizon=10.0)
    ax = plot.rul_distributions([0.0, 1.0], [single, cens])
    assert not [a for a in ax.get_children() if a.get_gid() == "rul-density-0"]
    assert _by_gid(ax, "rul-density-1") is not None
    assert any("50 % cens." in t.get_text() for t in ax.texts)


def test_state_estimates_band_truth_measurements(tmp_path: Path) -> None:
    T = 30
    t = np.arange(T, dtype=float)
    mean = np.column_stack([np.sin(t / 5), 0.1 * t])
    std = np.column_stack([np.full(T, 0.1), np.full(T, 0.2)])
    truth = mean + 0.05
    ys = mean[:, :1] + 0.01
    fig = plot.state_estimates(t, mean, std=std, n_sigma=2.0, truth=truth, measurements=ys,
                               measured=[0], names=["a", "b"])
    _render(fig, tmp_path / "states.png")
    assert len(fig.axes) == 2
    for i, ax in enumerate(fig.axes):
        est = _by_gid(ax, "estimate")
        assert np.allclose(est.get_ydata(), mean[:, i])
        assert np.allclose(_by_gid(ax, "truth").get_ydata(), truth[:, i])
        band = next(c for c in ax.collections if c.get_label() == "+-2 sigma")
        v = band.get_paths()[0].vertices
        assert v[:, 1].min() == pytest.approx((mean[:, i] - 2 * std[:, i]).min())
        assert v[:, 1].max() == pytest.approx((mean[:, i] + 2 * std[:, i]).max())
    assert fig.axes[0].get_ylabel() == "a" and fig.axes[1].get_ylabel() == "b"
    assert np.allclose(_by_gid(fig.axes[0], "measurements").get_ydata(), ys[:, 0])
    assert not [a for a in fig.axes[1].get_children() if a.get_gid() == "measurements"]


def test_state_estimates_quantile_band_and_errors() -> None:
    t = np.arange(5.0)
    fig = plot.state_estimates(t, t, lower=t - 1, upper=t + 2)
    band = next(c for c in fig.axes[0].collections if c.get_label() == "interval")
    v = band.get_paths()[0].vertices
    assert v[:, 1].min() == pytest.approx(-1.0) and v[:, 1].max() == pytest.approx(6.0)
    with pytest.raises(ValueError, match=r"truth: expected shape \(5,\) or \(5, n\)"):
        plot.state_estimates(t, t, truth=np.zeros(4))
    with pytest.raises(ValueError, match="either std or lower/upper"):
        plot.state_estimates(t, t, std=t, lower=t, upper=t)
    with pytest.raises(ValueError, match="names: expected 1 names"):
        plot.state_estimates(t, t, names=["a", "b"])


def test_state_estimates_from_filter_results() -> None:
    from rulkit.estimation.kalman import KalmanFilter

    rng = np.random.default_rng(4)
    ys = np.cumsum(rng.standard_normal(20))[:, None, None] * 0.1
    kr = KalmanFilter([[1.0]], [[1.0]], [[0.01]], [[0.25]]).filter(ys, [[0.0]], [[1.0]])
    t = np.arange(1.0, 21.0)
    fig = plot.state_estimates(t, kr, n_sigma=1.0)
    assert np.allclose(_by_gid(fig.axes[0], "estimate").get_ydata(), kr.x[:, 0, 0])
    band = next(c for c in fig.axes[0].collections if c.get_label() == "+-1 sigma")
    v = band.get_paths()[0].vertices
    assert v[:, 1].max() == pytest.approx((kr.x[:, 0, 0] + np.sqrt(kr.P[:, 0, 0, 0])).max())

    posts = [Posterior(np.array([ti, 2 * ti]), np.diag([4.0, 9.0])) for ti in t]
    fig = plot.state_estimates(t, posts, n_sigma=2.0)  # a sequence of posteriors
    band = next(c for c in fig.axes[1].collections if c.get_label() == "+-2 sigma")
    assert band.get_paths()[0].vertices[:, 1].min() == pytest.approx(2.0 - 6.0)
    with pytest.raises(ValueError, match="bring their own band"):
        plot.state_estimates(t, posts, std=np.ones(20))


class Fade:
    """state [loss, rate]; the instrument reads state of health 1 - loss (not a state)."""

    output_names = ("soh",)

    def output(self, x, u=None):
        return 1.0 - x[:, :1]


class Direct(Fade):
    output_names = ("loss_measured",)

    def output(self, x, u=None):
        return x[:, :1].copy()


def test_state_estimates_draws_measurements_where_they_belong() -> None:
    """Measurements of a state go on its panel; a measured quantity that is no state (state
    of health 1 - loss) gets a panel of its own beside h(estimate), never the first state's
    axis; without a measurement function, measurements get their own panel."""
    t = np.arange(1.0, 21.0)
    est = np.column_stack([0.01 * t, np.full(20, 0.01)])
    soh = 1.0 - est[:, :1] + 0.001
    fig = plot.state_estimates(t, est, measurements=soh, output=Fade())
    assert len(fig.axes) == 3  # loss, rate, soh
    assert not [a for a in fig.axes[0].get_children() if a.get_gid() == "measurements"]
    np.testing.assert_allclose(_by_gid(fig.axes[2], "measurements").get_ydata(), soh[:, 0])
    np.testing.assert_allclose(_by_gid(fig.axes[2], "predicted-measurement").get_ydata(),
                               1.0 - est[:, 0])
    assert fig.axes[2].get_ylabel() == "soh"
    loss = est[:, :1] + 0.001
    fig = plot.state_estimates(t, est, measurements=loss, output=Direct())
    assert len(fig.axes) == 2
    np.testing.assert_allclose(_by_gid(fig.axes[0], "measurements").get_ydata(), loss[:, 0])
    fig = plot.state_estimates(t, est, measurements=soh)  # nothing known: a panel of its own
    assert len(fig.axes) == 3 and fig.axes[2].get_ylabel() == "y[0]"
    with pytest.raises(ValueError, match=r"measured: expected 1 state indices in \[0, 1\]"):
        plot.state_estimates(t, est, measurements=soh, measured=[5])


def test_consistency_bounds_are_chi_square(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    T, B, dof = 200, 4, 2
    nis = rng.chisquare(dof, size=(T, B))
    nis[7, :] = np.nan  # a skipped update
    ax = plot.consistency(np.arange(T), nis, dof, kind="NIS", level=0.95)
    _render(ax.figure, tmp_path / "nis.png")
    lo = _by_gid(ax, "step-lo").get_ydata()[0]
    hi = _by_gid(ax, "step-hi").get_ydata()[0]
    # oracle: the mean of B chi2_dof variables is chi2_{B dof} / B
    assert lo == pytest.approx(stats.chi2.ppf(0.025, B * dof) / B)
    assert hi == pytest.approx(stats.chi2.ppf(0.975, B * dof) / B)
    stat = _by_gid(ax, "statistic")
    assert len(stat.get_xdata()) == T - 1 and 7 not in stat.get_xdata()
    assert np.allclose(stat.get_ydata(), np.nanmean(np.delete(nis, 7, axis=0), axis=1))
    avg = _by_gid(ax, "time-average").get_ydata()[0]
    assert avg == pytest.approx(np.nanmean(nis))
    patch = _by_gid(ax, "average-bounds")  # a Rectangle (matplotlib >= 3.9) or a Polygon
    xy = patch.get_xy()
    span = (np.array([xy[1], xy[1] + patch.get_height()]) if isinstance(xy, tuple)
            else np.asarray(xy)[:, 1])
    n = (T - 1) * B
    assert span.min() == pytest.approx(stats.chi2.ppf(0.025, n * dof) / n)
    assert span.max() == pytest.approx(stats.chi2.ppf(0.975, n * dof) / n)
    assert ax.get_ylabel() == "NIS" and "mean over 4 units" in ax.get_legend_handles_labels()[1][0]


def test_consistency_bad_input() -> None:
    with pytest.raises(ValueError, match=r"values: expected shape \(3,\) or \(3, B\)"):
        plot.consistency(np.arange(3.0), np.ones(4), 1)
    with pytest.raises(ValueError, match="no finite entry"):
        plot.consistency(np.arange(3.0), np.full(3, np.nan), 1)
    with pytest.raises(ValueError, match="dof: expected a positive integer"):
        plot.consistency(np.arange(3.0), np.ones(3), 0)


def test_draws_on_given_axes_and_never_imports_pyplot() -> None:
    from matplotlib.figure import Figure

    fig = Figure()
    ax = fig.add_subplot()
    assert plot.alpha_lambda_cone([0.0, 1.0], [9.0, 8.0], 10.0, ax=ax) is ax
    tree = ast.parse(Path(plot.__file__).read_text())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {f"{n.module}.{a.name}" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
                 for a in n.names}
    assert not any("pyplot" in name for name in imported), imported


def test_plot_profile_two_panels() -> None:
    class Profile:  # the attributes of rulkit.prognosis.profile.PrognosisProfile it reads
        times = np.array([0.0, 10.0, 20.0])
        distributions = tuple(_dists(times, 40.0, np.random.default_rng(3)))
        t_eol = 40.0
        failed = True
        alpha = 0.3
        level = 0.8

    fig = plot.plot_profile(Profile())
    assert len(fig.axes) == 2
    cone = _by_gid(fig.axes[0], "alpha-lambda-cone")
    assert np.allclose(cone.get_xy()[0], [0.0, 1.3 * 40.0])  # the profile's alpha
    assert "80 % interval" in " ".join(fig.axes[0].get_legend_handles_labels()[1])
    assert _by_gid(fig.axes[1], "rul-density-2") is not None
    # a censored record (failed=False): t_eol is only a lower bound, so no cone
    Profile.failed = False
    fig = plot.plot_profile(Profile())
    assert len(fig.axes) == 1 and _by_gid(fig.axes[0], "rul-density-0") is not None
    with pytest.raises(TypeError, match="'times' and 'distributions'"):
        plot.plot_profile(object())

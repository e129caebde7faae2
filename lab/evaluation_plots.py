"""Figures of evaluation results: error CDFs, estimated tracks on the floor plan and the
reliability of the reported uncertainty; ``write_ilc_plots`` draws them all for ILC runs,
with the magnetic maps on the floor plan (``floor_plots``).

matplotlib is needed to draw them (``plot_canvas``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lab.floor_plots import draw_plan, floor_axes, plot_magnetic_grid
from lab.plot_canvas import figure, save
from lab.scoring import PathResult, errors_m
from server.positioning.mapping.magnetic_gridding import known_share
from server.positioning.model.error_metrics import error_cdf

if TYPE_CHECKING:
    from lab.ilc_evaluation import IlcEvaluation

FloatArray = NDArray[np.float64]


def plot_error_cdf(curves: Mapping[str, Sequence[float]], out: Path, title: str) -> Path:
    """One figure with the empirical error CDF of each engine or method.

    Parameters
    ----------
    curves : mapping of str to sequence of float
        Per name (the legend label) the horizontal errors in metres; non-finite values
        (missing estimates) are dropped.
    out : Path
        PNG file to write; its directory is created when missing.
    title : str

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    RuntimeError
        When matplotlib is not installed.
    """
    fig = figure(7.0, 4.5)
    ax = fig.add_subplot()
    for name, errors in curves.items():
        e, share = error_cdf(errors)
        if e.size == 0:
            ax.plot([], [], label=f"{name} (no estimates)")
            continue
        # the same percentile rule (numpy's linear) as metrics.error_report
        p50, p90 = np.percentile(e, [50.0, 90.0]).tolist()
        (line,) = ax.step(
            np.concatenate([[0.0], e]),
            np.concatenate([[0.0], share]),
            where="post",
            label=f"{name}: median {p50:.2f} m, P90 {p90:.2f} m (n={e.size})",
        )
        ax.plot([p50, p90], [0.5, 0.9], "o", color=line.get_color(), markersize=4)
    ax.set_xlim(left=0.0)
    ax.set_ylim(0.0, 1.0)
    ax.set_xlabel("horizontal error (m)")
    ax.set_ylabel("share of estimates")
    ax.set_title(title)
    ax.grid(visible=True, alpha=0.3)
    ax.legend(loc="lower right", fontsize="small")
    return save(fig, out)


def _points(name: str, value: ArrayLike | None) -> FloatArray:
    array = np.asarray([] if value is None else value, dtype=np.float64)
    if array.size == 0:
        return array.reshape(0, 2)
    if array.ndim != 2 or array.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2), got {array.shape}")
    return array


def _per_point(
    name: str, value: ArrayLike | None, n: int, dtype: type[np.generic]
) -> NDArray[Any] | None:
    if value is None:
        return None
    array = np.asarray(value, dtype=dtype)
    if array.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {array.shape}")
    return array


def plot_track(
    out: Path,
    *,
    title: str,
    plan: Mapping[str, Any] | None,
    truth_xy_m: ArrayLike,
    est_xy_m: ArrayLike,
    est_floor_ok: ArrayLike | None = None,
    waypoint_xy_m: ArrayLike | None = None,
    sigma_m: ArrayLike | None = None,
) -> Path:
    """The floor plan with the true path and the estimated track of one walk.

    Parameters
    ----------
    out : Path
        PNG file to write; its directory is created when missing.
    title : str
    plan : mapping, optional
        GeoJSON FeatureCollection in the building's metric frame. Polygon and
        MultiPolygon outlines and LineStrings are drawn; features with
        ``properties.kind == "outline"`` dark, ``"unit"`` filled light grey.
    truth_xy_m : array_like, shape (n, 2)
        The true path in metres, drawn as a line.
    est_xy_m : array_like, shape (m, 2)
        Estimated positions in metres, in time order.
    est_floor_ok : array_like, shape (m,), bool, optional
        False where the estimate's floor was wrong (drawn red).
    waypoint_xy_m : array_like, shape (k, 2), optional
        Ground-truth waypoints, drawn as rings.
    sigma_m : array_like, shape (m,), optional
        1-σ radius of each estimate, drawn as a faint circle (non-finite ones skipped).

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    RuntimeError
        When matplotlib is not installed.
    ValueError
        When array shapes do not match.
    """
    truth = _points("truth_xy_m", truth_xy_m)
    est = _points("est_xy_m", est_xy_m)
    waypoints = _points("waypoint_xy_m", waypoint_xy_m)
    floor_ok = _per_point("est_floor_ok", est_floor_ok, est.shape[0], np.bool_)
    sigma = _per_point("sigma_m", sigma_m, est.shape[0], np.float64)

    fig = figure(8.0, 6.0)
    from matplotlib.collections import EllipseCollection

    ax = fig.add_subplot()
    if plan is not None:
        draw_plan(ax, plan)
    if sigma is not None:
        keep = np.isfinite(sigma) & np.isfinite(est).all(axis=1)
        if keep.any():
            diameters = 2.0 * sigma[keep]
            circles = EllipseCollection(
                diameters,
                diameters,
                np.zeros(diameters.size),
                units="xy",
                offsets=est[keep],
                offset_transform=ax.transData,
                facecolors="tab:blue",
                edgecolors="none",
                alpha=0.08,
                zorder=3,
            )
            ax.add_collection(circles)
            ax.fill([], [], color="tab:blue", alpha=0.15, label="1-σ circles")
    if truth.shape[0]:
        ax.plot(truth[:, 0], truth[:, 1], "-", color="black", lw=1.5, zorder=4, label="truth")
    if waypoints.shape[0]:
        ax.plot(
            waypoints[:, 0],
            waypoints[:, 1],
            "o",
            mfc="none",
            mec="black",
            ms=6,
            zorder=5,
            label="waypoints",
        )
    if est.shape[0]:
        ok = np.ones(est.shape[0], dtype=bool) if floor_ok is None else floor_ok
        ax.plot(est[:, 0], est[:, 1], "-", color="tab:blue", lw=0.6, alpha=0.5, zorder=6)
        ax.plot(est[ok, 0], est[ok, 1], ".", color="tab:blue", ms=5, zorder=7, label="estimate")
        if not ok.all():
            ax.plot(
                est[~ok, 0],
                est[~ok, 1],
                ".",
                color="red",
                ms=6,
                zorder=8,
                label="estimate, wrong floor",
            )
    floor_axes(ax, title)
    return save(fig, out)


NOMINAL = np.linspace(0.05, 0.95, 19)


def plot_reliability(
    runs: Mapping[str, tuple[Sequence[float], Sequence[float]]], out: Path, title: str
) -> Path:
    """Predicted against observed coverage per engine: for each nominal share ``p`` the
    share of errors within the radius ``sqrt(-2 ln(1 - p)) σ`` of the fix's reported
    (calibrated) covariance, a 2-D Gaussian's ``p`` radius; a calibrated engine lies on the
    diagonal at 68 %, and above it where its errors have a heavier tail.

    Parameters
    ----------
    runs : mapping of name to (errors_m, sigma_m)
        Per engine the error at each scored point and the reported 1-σ of its fix.
    """
    fig = figure(5.5, 5.0)
    ax = fig.add_subplot()
    ax.plot([0, 1], [0, 1], color="0.6", linestyle="--", linewidth=1, label="calibrated")
    for name, (errors, sigma) in runs.items():
        e = np.asarray(errors, dtype=np.float64)
        s = np.asarray(sigma, dtype=np.float64)
        keep = np.isfinite(e) & np.isfinite(s)
        if not keep.any():
            continue
        radius = np.sqrt(-2.0 * np.log(1.0 - NOMINAL))
        observed = [(e[keep] <= r * s[keep]).mean() for r in radius]
        ax.plot(NOMINAL, observed, marker="o", markersize=3, label=name)
    for level in (0.68, 0.95):
        ax.axvline(level, color="0.85", linewidth=1)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_xlabel("predicted share within the radius")
    ax.set_ylabel("observed share within the radius")
    ax.set_title(title)
    ax.legend(loc="lower right", fontsize="small")
    ax.set_aspect("equal")
    return save(fig, out)


def _errors_and_sigma(paths: Sequence[PathResult]) -> tuple[list[float], list[float]]:
    errors: list[float] = []
    sigma: list[float] = []
    for p in paths:
        e = p.estimates
        known = np.isfinite(e.est_xy_m).all(axis=1)
        errors += np.hypot(*(e.est_xy_m[known] - e.true_xy_m[known]).T).tolist()
        sigma += e.sigma_m[known].tolist()
    return errors, sigma


def write_ilc_plots(evaluations: Sequence[IlcEvaluation], out_dir: Path) -> list[Path]:
    """The error CDF of every engine on one figure, per engine and test path the floor
    plan with the truth and the estimated track, and, when an engine read a magnetic map,
    per floor the map on the floor plan (``magnetic_<floor>.png``; the maps come from the
    same training traces for every engine, so once), and the reliability of the reported
    uncertainty (``reliability.png``, ``plot_reliability``)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    site = evaluations[0].site.name
    written = [
        plot_error_cdf(
            {e.summary["engine"]: errors_m(e.paths) for e in evaluations},
            out_dir / "error_cdf.png",
            title=f"ILC {site}: horizontal error at waypoints",
        ),
        plot_reliability(
            {e.summary["engine"]: _errors_and_sigma(e.paths) for e in evaluations},
            out_dir / "reliability.png",
            title=f"ILC {site}: reported uncertainty against the errors",
        ),
    ]
    for evaluation in evaluations:
        engine = evaluation.summary["engine"]
        for path in evaluation.paths:
            floor = evaluation.site.floors[path.floor_index]
            fixes = path.fixes
            est = np.array([(f.x_m, f.y_m) for f in fixes], dtype=np.float64).reshape(-1, 2)
            floor_ok = np.array([f.floor == path.floor_index for f in fixes], dtype=bool)
            written.append(
                plot_track(
                    out_dir / engine / f"{floor.name}_{path.path_id}.png",
                    title=f"{engine} · {floor.name} · {path.path_id}",
                    plan=floor.plan,
                    truth_xy_m=path.estimates.true_xy_m,
                    est_xy_m=est,
                    est_floor_ok=floor_ok,
                    waypoint_xy_m=path.estimates.true_xy_m,
                    sigma_m=np.array([f.uncertainty_m for f in fixes]),
                )
            )
    magnetic = next((e for e in evaluations if e.maps.magnetic is not None), None)
    if magnetic is not None and magnetic.maps.magnetic is not None:
        plans = magnetic.maps.plans
        for index, (floor, grid) in enumerate(
            zip(magnetic.site.floors, magnetic.maps.magnetic.grids, strict=False)
        ):
            if grid is None:
                continue
            plan = plans[index] if index < len(plans) else None
            coverage = known_share(grid, plan)
            known = "no walkable cell" if coverage is None else f"{coverage:.0%} of walkable cells"
            written.append(
                plot_magnetic_grid(
                    out_dir / f"magnetic_{floor.name}.png",
                    title=f"{magnetic.site.name} · {floor.name}: magnetic map, {known} known",
                    plan=floor.plan,
                    grid=grid,
                )
            )
    return written

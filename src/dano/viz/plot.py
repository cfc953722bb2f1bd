"""Static plots with matplotlib :class:`~matplotlib.figure.Figure` objects: no pyplot, no
global backend switch (a notebook's own plots are untouched), no display needed."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._files import atomic_write
from ..errors import DanoError


def check_image_path(path: str | Path, option: str = "") -> Path:
    """``path`` as a Path if matplotlib can write an image in the format of its suffix (none:
    png). Raises DanoError naming the file, ``option`` (e.g. ``--plot``) and the formats
    that work otherwise: checked before the work, not after it."""
    from matplotlib.figure import Figure

    path = Path(path)
    fmt = path.suffix.lstrip(".").lower() or "png"
    formats = Figure().canvas.get_supported_filetypes()
    if fmt not in formats:
        raise DanoError(f"{path}: {option + ': ' if option else ''}cannot write an image as .{fmt}; "
                        f"use one of {', '.join('.' + f for f in sorted(formats))}")
    return path


def plot_samples(asset, path: str | Path, max_arrows: int = 600, seed: int = 0) -> Path:
    """Draw an asset's boundary samples, their outward normals and the centre of mass
    (the paper's Fig. 2) to an image file (format from the suffix, e.g. ``.png``).

    Samples are shown in the object frame [m]; arrows (a random subset of at most
    ``max_arrows``) have length 5 % of the object's size. Written atomically.
    """
    from matplotlib.figure import Figure

    pts = asset.points + asset.center_of_mass
    size = float(np.ptp(pts, axis=0).max())
    fig = Figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    ax.scatter(*pts.T, s=2, c=asset.densities, cmap="viridis", alpha=0.6)
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(pts), min(max_arrows, len(pts)), replace=False)
    ok = asset.normals_valid[idx]
    idx = idx[ok]
    n = asset.normals[idx] * 0.05 * size
    ax.quiver(*pts[idx].T, *n.T, color="tab:red", linewidth=0.6)
    ax.scatter(*asset.center_of_mass, s=80, c="k", marker="*", label="centre of mass")
    lo, hi = pts.min(0), pts.max(0)
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo).max()
    ax.set(xlim=(mid[0] - half, mid[0] + half), ylim=(mid[1] - half, mid[1] + half),
           zlim=(mid[2] - half, mid[2] + half), xlabel="x [m]", ylabel="y [m]", zlabel="z [m]")
    ax.set_title(f"{asset.name}: {asset.num_samples} boundary samples, normals ({len(idx)} shown)")
    ax.legend(loc="upper left")
    path = Path(path)
    fmt = path.suffix.lstrip(".") or "png"
    atomic_write(path, lambda f: fig.savefig(f, format=fmt, dpi=120))
    return path


def plot_sysid(series, cost_history, path, profiles=None, title: str = "") -> Path:
    """An identification's fit: observed vs fitted paths (top view) and x, y positions over
    time, the cost per iteration and, where given, the cost profile along each parameter,
    to an image file (format from the suffix). Written atomically.

    series: list of dicts, one per tracked object and trajectory: ``label`` (str), ``time``
    (T,) [s], ``observed`` (T, 2) world x, y [m], ``fitted`` (F, 2) [m] or None and, where
    its times are not ``time``'s, ``fitted_time`` (F,) [s] (NaN rows break the line: one per
    window of a multiple shooting); optional ``observed_angle`` (T,) and ``fitted_angle`` (F,)
    [deg], the rotation from the first observed pose, shown in a panel of their own where
    some series has them.
    cost_history: (K,) cost ½‖r‖² per iteration. profiles: {label: {"values": (P,),
    "cost": (P,) with None where not evaluated, "estimate": float}}. title: the figure's title.
    """
    import matplotlib
    from matplotlib.figure import Figure

    profiles = profiles or {}
    angles = any(s.get("observed_angle") is not None for s in series)
    fig = Figure(figsize=(15 + 5 * bool(profiles) + 5 * angles, 4.5))
    axes = list(fig.subplots(1, 3 + bool(profiles) + angles))
    rotation = axes.pop(2) if angles else None
    colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, s in enumerate(series):
        c, t, p, fitted = colors[i % len(colors)], np.asarray(s["time"]), np.asarray(s["observed"]), s["fitted"]
        ft = t if s.get("fitted_time") is None else np.asarray(s["fitted_time"])
        axes[0].plot(p[:, 0], p[:, 1], "o", ms=3, color=c, alpha=0.6, label=f"{s['label']} observed")
        axes[1].plot(t, p[:, 0], "o", ms=3, color=c, alpha=0.6)
        axes[1].plot(t, p[:, 1], "s", ms=3, color=c, alpha=0.6)
        if fitted is not None:
            fitted = np.asarray(fitted)
            axes[0].plot(fitted[:, 0], fitted[:, 1], "-", color=c, label="fitted")
            axes[1].plot(ft, fitted[:, 0], "-", color=c)
            axes[1].plot(ft, fitted[:, 1], "--", color=c)
        if rotation is not None and s.get("observed_angle") is not None:
            rotation.plot(t, np.asarray(s["observed_angle"]), "o", ms=3, color=c, alpha=0.6)
            if s.get("fitted_angle") is not None:
                rotation.plot(ft, np.asarray(s["fitted_angle"]), "-", color=c)
    if rotation is not None:
        rotation.set(xlabel="time [s]", ylabel="rotation [deg]", title="rotation from the first frame (o: observed)")
    # equal scales by widening the narrower range (not by squeezing the panel: a straight slide
    # then ran its tick labels together), at most 5 ticks per axis
    axes[0].set(xlabel="x [m]", ylabel="y [m]", title="paths (top view)", aspect="equal", adjustable="datalim")
    axes[0].locator_params(nbins=5)
    axes[0].legend(fontsize=7)
    axes[1].set(xlabel="time [s]", ylabel="position [m]", title="x (o, solid) and y (s, dashed)")
    axes[2].plot(np.maximum(np.asarray(cost_history, dtype=float), 1e-300), "o-")
    _log_scale_where_wide(axes[2], cost_history)
    axes[2].set(xlabel="iteration", ylabel="cost ½‖r‖²", title="cost")
    if profiles:  # the global scan: lowest cost along each parameter, and the estimate
        for (label, prof), c in zip(profiles.items(), colors):
            x = [v for v, y in zip(prof["values"], prof["cost"]) if y is not None]
            y = [y for y in prof["cost"] if y is not None]
            axes[3].plot(x, y, "o-", color=c, label=label)
            axes[3].axvline(prof["estimate"], color=c, ls=":")
        _log_scale_where_wide(axes[3], [y for prof in profiles.values() for y in prof["cost"] if y is not None])
        axes[3].set(xlabel="parameter value", ylabel="lowest cost on the scan", title="global scan (dotted: estimate)")
        axes[3].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path, dpi=110)


def _log_scale_where_wide(ax, values) -> None:
    """A logarithmic y axis where ``values`` (positive costs) span more than a factor of 10;
    a linear one (its tick labels then differ, with an offset) where they span less: a
    review's cost per iteration, 7.3664e-4 to 7.3666e-4, had every tick of a log axis labelled
    7.36639e-4 (2026-12-02)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v) & (v > 0)]
    if len(v) and v.max() > 10 * v.min():
        ax.set_yscale("log")


def plot_trajopt(log: dict, status: str, iterations: int, runs, path, goals=()) -> Path:
    """A trajectory optimisation's convergence (cost, constraint violation and penalty per
    iteration) and top-down paths, to an image file. Written atomically.

    log: per-iteration arrays ``iteration``, ``cost``, ``merit``, ``max_violation``,
    ``penalty``, ``step`` (:data:`dano.trajopt.LOG_KEYS`); status, iterations: the solver's.
    runs: list of (label, object_xy (T, 2) [m], pusher_xy (T, 2) [m] or None, line style),
    e.g. the initial guess, the optimised plan, an open-loop and a receding-horizon run.
    goals: list of (label, xy (2,) [m], marker).
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(14, 4.5))
    ax_cost, ax_viol, ax_path = fig.subplots(1, 3)
    it = log["iteration"]
    ax_cost.plot(it, log["cost"], label="cost J")
    ax_cost.plot(it, log["merit"], "--", label="augmented Lagrangian")
    ax_cost.set(xlabel="iteration", ylabel="cost", yscale="symlog", title=f"{status}, {iterations} iterations")
    ax_cost.legend()
    ax_viol.semilogy(it, np.maximum(log["max_violation"], 1e-12), label="max constraint violation")
    ax_viol.semilogy(it, log["penalty"], ":", label="penalty μ")
    ax_viol.semilogy(it, np.maximum(log["step"], 1e-6), ".", ms=3, label="line-search step")
    ax_viol.set(xlabel="iteration", title="constraints")
    ax_viol.legend(fontsize=8)
    for label, obj, pusher, style in runs:
        line, = ax_path.plot(obj[:, 0], obj[:, 1], style, label=label)
        if pusher is not None:
            ax_path.plot(pusher[:, 0], pusher[:, 1], style, color=line.get_color(), alpha=0.4)
    for label, xy, marker in goals:
        ax_path.plot(*np.asarray(xy)[:2], marker, ms=11, label=label)
    ax_path.set(xlabel="x [m]", ylabel="y [m]", title="top view (faint: pusher)", aspect="equal")
    ax_path.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return _save(fig, path, dpi=110)


def _save(fig, path, dpi: int) -> Path:
    """Write ``fig`` atomically, the format from the suffix (png by default)."""
    path = Path(path)
    atomic_write(path, lambda f: fig.savefig(f, format=path.suffix.lstrip(".") or "png", dpi=dpi))
    return path


def plot_heldout(renders, references, titles, path, max_views: int = 4) -> Path:
    """Held-out views: renders (top row) over the reference images (bottom row), to an image
    file. renders, references: lists of (H, W, 3) in [0, 1]; titles: one string per view
    (e.g. its name and PSNR). Written atomically."""
    from matplotlib.figure import Figure

    n = min(max_views, len(renders))
    fig = Figure(figsize=(2.6 * n, 5.4))
    axes = fig.subplots(2, n, squeeze=False)
    for k in range(n):
        axes[0, k].imshow(np.clip(renders[k], 0.0, 1.0))
        axes[0, k].set_title(f"render: {titles[k]}", fontsize=8)
        axes[1, k].imshow(references[k])
        axes[1, k].set_title("held-out image", fontsize=8)
        for ax in axes[:, k]:
            ax.set_axis_off()
    fig.tight_layout()
    return _save(fig, path, dpi=100)

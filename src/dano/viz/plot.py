"""Static plots with matplotlib :class:`~matplotlib.figure.Figure` objects: no pyplot, no
global backend switch (a notebook's own plots are untouched), no display needed."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._files import atomic_write


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


def plot_sysid(problem, result, path, max_trajectories: int = 4) -> Path:
    """Observed vs fitted trajectories (top-down x–y paths of the tracked DANOs and their
    positions over time), the cost per iteration and, after a global scan, the cost profile
    along each parameter, to an image file. Written atomically."""
    import matplotlib
    from matplotlib.figure import Figure

    from ..sysid.problem import SEGMENT_NUISANCE_PREFIXES

    segs = problem.segments[:max_trajectories]
    profiles = (result.scan or {}).get("profile", {})
    fig = Figure(figsize=(15 + 5 * bool(profiles), 4.5))
    axes = fig.subplots(1, 3 + bool(profiles))
    colors = matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, seg in enumerate(segs):
        obs = problem.observations[seg.obs]
        fitted = result.fitted[i] if i < len(result.fitted) else None
        t = np.asarray(obs.time)[seg.start : seg.start + seg.frames]
        for name, poses in obs.poses.items():
            k = problem.scene.dano_index(name)
            a = problem.scene.qpos_adr[k]
            p = np.asarray(poses)[seg.start : seg.start + seg.frames]
            c = colors[i % len(colors)]
            axes[0].plot(p[:, 0], p[:, 1], "o", ms=3, color=c, alpha=0.6, label=f"{obs.name or i} observed")
            axes[1].plot(t, p[:, 0], "o", ms=3, color=c, alpha=0.6)
            axes[1].plot(t, p[:, 1], "s", ms=3, color=c, alpha=0.6)
            if fitted is not None:
                axes[0].plot(fitted[:, a], fitted[:, a + 1], "-", color=c, label="fitted")
                axes[1].plot(t, fitted[:, a], "-", color=c)
                axes[1].plot(t, fitted[:, a + 1], "--", color=c)
    axes[0].set(xlabel="x [m]", ylabel="y [m]", title="paths (top view)", aspect="equal")
    axes[0].legend(fontsize=7)
    axes[1].set(xlabel="time [s]", ylabel="position [m]", title="x (o, solid) and y (s, dashed)")
    axes[2].semilogy(np.maximum(result.cost_history, 1e-300), "o-")
    axes[2].set(xlabel="iteration", ylabel="cost ½‖r‖²", title="cost")
    if profiles:  # the global scan: lowest cost along each parameter, and the estimate
        for (label, prof), c in zip(profiles.items(), colors):
            x = [v for v, y in zip(prof["values"], prof["cost"]) if y is not None]
            y = [y for y in prof["cost"] if y is not None]
            axes[3].semilogy(x, y, "o-", color=c, label=label)
            axes[3].axvline(result.estimates[result.labels.index(label)], color=c, ls=":")
        axes[3].set(xlabel="parameter value", ylabel="lowest cost on the scan", title="global scan (dotted: estimate)")
        axes[3].legend(fontsize=7)
    interval = result.interval or {"lower": {}, "upper": {}, "level": 0.95}

    def shown(k, v, s):  # the interval where there is one (it is the uncertainty), else the standard error
        if k in interval["lower"]:
            return f"{k} = {v:.4g} [{interval['lower'][k]:.4g}, {interval['upper'][k]:.4g}] ({interval['level']:.0%})"
        return f"{k} = {v:.4g} ± {s:.2g}"

    est = ", ".join(shown(k, v, s) for k, v, s in zip(result.labels, result.estimates, result.standard_errors)
                    if not k.startswith(SEGMENT_NUISANCE_PREFIXES))
    fig.suptitle(est, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    atomic_write(path, lambda f: fig.savefig(f, format=path.suffix.lstrip(".") or "png", dpi=110))
    return path


def plot_trajopt(task, solution, model_error, path) -> Path:
    """A trajectory optimisation's convergence (cost, constraint violation and penalty per
    iteration) and its top-down paths (plain push, optimised plan, goals and, with a model
    error, the open-loop and receding-horizon runs in the other world), to an image file.
    Written atomically."""
    from matplotlib.figure import Figure

    log = solution.log
    fig = Figure(figsize=(14, 4.5))
    ax_cost, ax_viol, ax_path = fig.subplots(1, 3)
    it = log["iteration"]
    ax_cost.plot(it, log["cost"], label="cost J")
    ax_cost.plot(it, log["merit"], "--", label="augmented Lagrangian")
    ax_cost.set(xlabel="iteration", ylabel="cost", yscale="symlog", title=f"{solution.status}, "
                f"{solution.iterations} iterations")
    ax_cost.legend()
    ax_viol.semilogy(it, np.maximum(log["max_violation"], 1e-12), label="max constraint violation")
    ax_viol.semilogy(it, log["penalty"], ":", label="penalty μ")
    ax_viol.semilogy(it, np.maximum(log["step"], 1e-6), ".", ms=3, label="line-search step")
    ax_viol.set(xlabel="iteration", title="constraints")
    ax_viol.legend(fontsize=8)
    runs = [("initial guess", task.X_plain, ":"), ("optimised", np.asarray(solution.states), "-")]
    if model_error is not None:
        runs += [(f"open loop, μ={model_error.friction:.3g}", model_error.open_loop_states, "--"),
                 ("receding horizon", model_error.receding.states, "-.")]
    from ..trajopt.tasks import pusher_positions

    for label, X, style in runs:
        b, p = X[:, task.bunny_qpos], pusher_positions(task, X)
        line, = ax_path.plot(b[:, 0], b[:, 1], style, label=f"bunny, {label}")
        ax_path.plot(p[:, 0], p[:, 1], style, color=line.get_color(), alpha=0.4)
    ax_path.plot(*task.bunny_goal[:2], "k*", ms=12, label="bunny goal")
    if task.pusher_goal is not None:
        ax_path.plot(*task.pusher_goal[:2], "kx", ms=10, label="pusher goal")
    ax_path.set(xlabel="x [m]", ylabel="y [m]", title="top view (faint: pusher)", aspect="equal")
    ax_path.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    path = Path(path)
    atomic_write(path, lambda f: fig.savefig(f, format=path.suffix.lstrip(".") or "png", dpi=110))
    return path


def plot_heldout(renders, data, path, max_views: int = 4) -> Path:
    """Held-out views: the field's renders (top row) over the images (bottom row), with each
    view's PSNR, to an image file. ``renders``: list of (H, W, 3) in [0, 1]; ``data``: the
    held-out :class:`~dano.nerf.Dataset`. Written atomically."""
    from matplotlib.figure import Figure

    from ..render import psnr

    n = min(max_views, len(renders))
    fig = Figure(figsize=(2.6 * n, 5.4))
    axes = fig.subplots(2, n, squeeze=False)
    for k in range(n):
        ref = data.images[k]
        if data.alpha is not None:
            ref = ref * data.alpha[k][..., None] + (1.0 - data.alpha[k][..., None])
        image = np.clip(renders[k], 0.0, 1.0)
        axes[0, k].imshow(image)
        axes[0, k].set_title(f"{data.names[k]}\n{psnr(image, ref):.2f} dB", fontsize=8)
        axes[1, k].imshow(ref)
        for ax in axes[:, k]:
            ax.set_axis_off()
    axes[1, 0].set_title("images", fontsize=8)
    fig.tight_layout()
    path = Path(path)
    atomic_write(path, lambda f: fig.savefig(f, format=path.suffix.lstrip(".") or "png", dpi=100))
    return path

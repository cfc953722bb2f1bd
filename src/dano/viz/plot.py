"""Static plots with matplotlib (Agg backend: works without a display)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_samples(asset, path: str | Path, max_arrows: int = 600, seed: int = 0) -> Path:
    """Draw an asset's boundary samples, their outward normals and the centre of mass
    (the paper's Fig. 2) to an image file (format from the suffix, e.g. ``.png``).

    Samples are shown in the object frame [m]; arrows (a random subset of at most
    ``max_arrows``) have length 5 % of the object's size. Written atomically.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..asset import _atomic_write

    pts = asset.points + asset.center_of_mass
    size = float(np.ptp(pts, axis=0).max())
    fig = plt.figure(figsize=(7, 6))
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
    _atomic_write(path, lambda f: fig.savefig(f, format=fmt, dpi=120))
    plt.close(fig)
    return path

"""DANO assets: a density field turned into a rigid body (paper §IV).

:func:`build` integrates the scaled density αφ for the mass properties and draws
boundary samples with outward normals; :class:`DanoAsset` holds the result and
:func:`save` / :func:`load` write and read the versioned ``.dano`` file.

Frames. The *object frame* is the frame of the density field. The *body frame*
has the object frame's axes and its origin at the centre of mass μ: sample
points and the visual mesh are stored in the body frame (x_body = x_object − μ),
``center_of_mass`` records μ in the object frame. This is the frame a MuJoCo free
body with ``ipos = 0`` uses, so a simulator needs no further offset.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from ._version import __version__
from ._compiled import HOST_ONLY
from ._files import atomic_write, source_kind
from ._jax_setup import in_float64
from .errors import DanoError, FileFormatError
from .fields import DensityField, TransformedField, from_arrays, to_arrays
from .fields.base import check_bounds, evaluate, field_name

#: ``progress(done, total, description)``, called from long loops; may be None.
Progress = Callable[[int, int, str], None]

FORMAT_NAME = "dano"
FORMAT_VERSION = 1
DEFAULT_NUM_SAMPLES = 5000


# --------------------------------------------------------------------------- mass


class _PrincipalInertia:
    """Principal moments and axes of an ``inertia`` (3, 3) attribute."""

    inertia: np.ndarray

    @property
    def principal_moments(self) -> np.ndarray:
        """(3,) principal moments of inertia [kg m²], ascending."""
        return np.linalg.eigvalsh(self.inertia)

    @property
    def principal_axes(self) -> np.ndarray:
        """(3, 3) columns: principal axes (object frame, right-handed), matching
        :attr:`principal_moments`."""
        _, axes = np.linalg.eigh(self.inertia)
        if np.linalg.det(axes) < 0:
            axes[:, 2] *= -1
        return axes


@dataclass(frozen=True)
class MassProperties(_PrincipalInertia):
    """Mass properties of αφ with one-sigma error estimates.

    mass [kg]; center_of_mass (3,) object frame [m]; inertia (3, 3) [kg m²] about
    the centre of mass, object axes: J = ∫αφ(|r|²I − r rᵀ) dV, r = x − μ.
    ``*_std``: estimated standard errors of the numerical integration (same shapes).
    """

    mass: float
    center_of_mass: np.ndarray
    inertia: np.ndarray
    alpha: float
    mass_std: float
    center_of_mass_std: np.ndarray
    inertia_std: np.ndarray
    method: str
    num_points: int


@jax.jit
def _moments(field, points, origin):
    """Σφ, Σφr, Σφ r rᵀ over points (r = x − origin); also min φ and a NaN count."""
    phi = field.density(points)
    r = points - origin
    return (
        jnp.sum(phi),
        phi @ r,
        jnp.einsum("n,ni,nj->ij", phi, r, r),
        jnp.min(phi),
        jnp.sum(~jnp.isfinite(phi)),
    )


def _check_density_values(min_phi: float, num_nonfinite: int, what: str) -> None:
    if num_nonfinite:
        raise DanoError(f"{what}: the field returned {num_nonfinite} NaN or infinite densities")
    if min_phi < 0:
        raise DanoError(f"{what}: the field returned negative densities (min {min_phi:.4g}); densities must be >= 0")


def _derive(m0: np.ndarray, m1: np.ndarray, m2: np.ndarray, origin: np.ndarray):
    """Mass, com and inertia from the integrals ∫φ, ∫φr, ∫φrrᵀ (with α applied by caller)."""
    mass = m0
    c = m1 / m0
    S = m2 - m0 * np.outer(c, c)  # second moment about the centre of mass
    J = np.trace(S) * np.eye(3) - S
    return mass, c + origin, 0.5 * (J + J.T)


@in_float64
def mass_properties(
    field: DensityField,
    *,
    alpha: float | None = None,
    mass: float | None = None,
    method: str = "sobol",
    num_points: int = 1 << 20,
    seed: int = 0,
    bounds: Any = None,
    progress: Progress | None = None,
) -> MassProperties:
    """Mass, centre of mass and inertia of the scaled density αφ.

    method ``"sobol"``: randomised quasi-Monte Carlo, 8 independently scrambled Sobol
    sequences of ``num_points/8`` points each over ``bounds`` (default the field's);
    the standard error is the spread of the 8 estimates / √8.
    method ``"grid"``: midpoint rule on a cell grid of ~``num_points`` cells; the
    error estimate is the Richardson difference (I_h − I_2h)/3 with a half-resolution grid.

    alpha: the mass scale α (mass = α∫φ); or mass [kg]: sets α = mass/∫φ.
    Giving neither means α = 1. Raises DanoError if both are given, if a value is
    not positive and finite, if the field returns NaN or negative densities, or if
    the field is zero everywhere in ``bounds``.
    """
    if alpha is not None and mass is not None:
        raise DanoError("give either alpha or mass, not both")
    for name, v in (("alpha", alpha), ("mass", mass)):
        if v is not None and (not np.isfinite(v) or v <= 0):
            raise DanoError(f"{name} must be a finite positive number, got {v}")
    b = check_bounds(field.bounds() if bounds is None else bounds)
    volume = float(np.prod(b[1] - b[0]))
    origin = 0.5 * (b[0] + b[1])
    jorigin = jnp.asarray(origin)

    if method == "sobol":
        reps = 8
        n = max(1 << int(np.ceil(np.log2(max(num_points // reps, 2)))), 256)
        chunk = min(n, 1 << 17)
        estimates = []
        rng = np.random.default_rng(seed)
        from scipy.stats import qmc  # (scipy.stats: 0.5 s to import, only when building)

        for rep in range(reps):
            sampler = qmc.Sobol(d=3, scramble=True, seed=rng)
            acc = [0.0, np.zeros(3), np.zeros((3, 3))]
            for _ in range(n // chunk):
                pts = jnp.asarray(qmc.scale(sampler.random(chunk), b[0], b[1]))
                s0, s1, s2, mn, bad = _moments(field, pts, jorigin)
                _check_density_values(float(mn), int(bad), "mass properties")
                acc[0] += float(s0)
                acc[1] = acc[1] + np.asarray(s1)
                acc[2] = acc[2] + np.asarray(s2)
            estimates.append([a * volume / n for a in acc])
            if progress is not None:
                progress(rep + 1, reps, "mass properties")
        total_points = n * reps
    elif method == "grid":
        res_fine = max(int(round(num_points ** (1 / 3))), 8)
        estimates = []
        for res in (res_fine // 2, res_fine):
            shape = np.maximum(np.round(res * (b[1] - b[0]) / (b[1] - b[0]).max()).astype(int), 2)
            axes = [b[0, k] + (np.arange(shape[k]) + 0.5) * (b[1, k] - b[0, k]) / shape[k] for k in range(3)]
            acc = [0.0, np.zeros(3), np.zeros((3, 3))]
            # iterate over x-slabs to bound memory
            yz = np.stack(np.meshgrid(axes[1], axes[2], indexing="ij"), -1).reshape(-1, 2)
            slab = max(1, (1 << 18) // len(yz))
            for i0 in range(0, shape[0], slab):
                xs = axes[0][i0 : i0 + slab]
                pts = np.concatenate([np.column_stack([np.full(len(yz), x), yz]) for x in xs])
                s0, s1, s2, mn, bad = _moments(field, jnp.asarray(pts), jorigin)
                _check_density_values(float(mn), int(bad), "mass properties")
                acc[0] += float(s0)
                acc[1] = acc[1] + np.asarray(s1)
                acc[2] = acc[2] + np.asarray(s2)
            cellvol = volume / np.prod(shape)
            estimates.append([a * cellvol for a in acc])
            if progress is not None:
                progress(len(estimates), 2, "mass properties")
        total_points = int(res_fine**3)
    else:
        raise DanoError(f"unknown integration method {method!r}; use 'sobol' or 'grid'")

    integral = float(np.mean([e[0] for e in estimates])) if method == "sobol" else estimates[-1][0]
    if not integral > 0:
        raise DanoError("the density field integrates to zero over its bounds: nothing to build")
    a = float(alpha) if alpha is not None else (float(mass) / integral if mass is not None else 1.0)

    derived = [_derive(a * e[0], a * e[1], a * e[2], origin) for e in estimates]
    if method == "sobol":
        pooled = [np.mean([e[k] for e in estimates], axis=0) for k in range(3)]
        m, c, J = _derive(a * pooled[0], a * pooled[1], a * pooled[2], origin)
        std = [np.std([d[k] for d in derived], axis=0, ddof=1) / np.sqrt(len(derived)) for k in range(3)]
    else:
        m, c, J = derived[-1]
        std = [np.abs(derived[1][k] - derived[0][k]) / 3.0 for k in range(3)]
    if mass is not None:
        m = float(mass)  # exact by construction of α; its error moves into α
    return MassProperties(
        mass=float(m),
        center_of_mass=np.asarray(c),
        inertia=np.asarray(J),
        alpha=a,
        mass_std=float(std[0]),
        center_of_mass_std=np.asarray(std[1]),
        inertia_std=np.asarray(std[2]),
        method=method,
        num_points=int(total_points),
    )


# ------------------------------------------------------------------ boundary samples


def _density_gradients(field, points: np.ndarray, stencil: float) -> np.ndarray:
    grad = _GRAD(field, jnp.asarray(points))
    if stencil > 0:
        offsets = stencil * np.concatenate([np.eye(3), -np.eye(3)])
        for off in offsets:
            grad = grad + _GRAD(field, jnp.asarray(points + off))
        grad = grad / 7.0
    return np.asarray(grad)


_GRAD = jax.jit(jax.vmap(lambda f, x: jax.grad(lambda y: f.density(y[None])[0])(x), in_axes=(None, 0)))


def auto_band(densities: np.ndarray) -> tuple[float, float]:
    """The default density band for boundary samples.

    ρ_ref = 99th percentile of the positive densities (ignoring values below
    1e-6·max) found when sampling the field's bounds; band = [0.05, 0.95]·ρ_ref.
    For a logistic edge of width w this is the shell |d| < 2.94w about the surface
    φ = ρ_ref/2. (The paper hand-tuned its bands: bunny 1-105, soap 60-90.)
    """
    d = np.asarray(densities)
    pos = d[d > 1e-6 * d.max()] if d.size and d.max() > 0 else d[:0]
    if pos.size == 0:
        raise DanoError("the density field is zero everywhere in its bounds: no boundary to sample")
    ref = float(np.percentile(pos, 99))
    return 0.05 * ref, 0.95 * ref


@dataclass(frozen=True)
class BoundarySamples:
    """points (N, 3) object frame [m]; densities (N,) φ; normals (N, 3) outward unit;
    band (lo, hi); num_candidates: points drawn to find them."""

    points: np.ndarray
    densities: np.ndarray
    normals: np.ndarray
    band: tuple[float, float]
    num_candidates: int


def boundary_samples(
    field: DensityField,
    num_samples: int = DEFAULT_NUM_SAMPLES,
    *,
    band: tuple[float, float] | None = None,
    seed: int = 0,
    stencil: float = 0.0,
    bounds: Any = None,
    max_candidates: int = 1 << 23,
    progress: Progress | None = None,
) -> BoundarySamples:
    """Draw ``num_samples`` points whose density lies in ``band`` (paper §IV-B).

    Candidates come from a scrambled Sobol sequence (seeded: deterministic) over the
    bounds; until 4·N candidates in the band with a valid gradient are found (or
    ``max_candidates`` are drawn); N of them are chosen uniformly at random (seeded).
    Normals are n = −∇φ/|∇φ| by autodiff, optionally averaged with the gradients at
    the six points ±``stencil`` [m] along the axes.
    band: (lo, hi) densities; None picks :func:`auto_band`.
    Raises DanoError if no (or too few) candidates fall in the band, naming the
    density range that was found, or if the band is empty or not finite.
    """
    if num_samples < 1:
        raise DanoError(f"num_samples must be positive, got {num_samples}")
    b = check_bounds(field.bounds() if bounds is None else bounds)
    from scipy.stats import qmc  # (scipy.stats: 0.5 s to import, only when building)

    sampler = qmc.Sobol(d=3, scramble=True, seed=np.random.default_rng(seed))
    batch = 1 << 16
    want = 4 * num_samples
    pts_all, phi_all, grad_all = [], [], []
    drawn, found = 0, 0
    lo = hi = None
    seen_min, seen_max = np.inf, -np.inf
    while drawn < max_candidates and found < want:
        pts = qmc.scale(sampler.random(batch), b[0], b[1])
        phi = evaluate(field, pts)
        drawn += batch
        if not np.all(np.isfinite(phi)):
            raise DanoError(f"the field returned {int(np.sum(~np.isfinite(phi)))} NaN or infinite densities")
        if phi.min() < 0:
            raise DanoError(f"the field returned negative densities (min {phi.min():.4g}); densities must be >= 0")
        seen_min, seen_max = min(seen_min, phi.min()), max(seen_max, phi.max())
        if lo is None:
            lo, hi = auto_band(phi) if band is None else _check_band(band)
        mask = (phi >= lo) & (phi <= hi)
        if mask.any():
            grad = _density_gradients(field, pts[mask], stencil)
            norm = np.linalg.norm(grad, axis=1)
            ok = np.isfinite(norm) & (norm > 1e-12 * max(hi, 1e-300))
            pts_all.append(pts[mask][ok])
            phi_all.append(phi[mask][ok])
            grad_all.append(grad[ok] / norm[ok, None])
            found += int(ok.sum())
        if progress is not None:
            progress(min(found, want), want, "boundary samples")
    if found == 0:
        raise DanoError(
            f"no samples in the density band [{lo:.4g}, {hi:.4g}]: the field's densities range over "
            f"[{seen_min:.4g}, {seen_max:.4g}] in its bounds; choose a band inside that range"
        )
    if found < num_samples:
        raise DanoError(
            f"only {found} of {num_samples} requested samples found in the density band "
            f"[{lo:.4g}, {hi:.4g}] after {drawn} candidates; widen the band or ask for fewer samples"
        )
    pts = np.concatenate(pts_all)
    phi = np.concatenate(phi_all)
    grad = np.concatenate(grad_all)
    pick = np.sort(np.random.default_rng(seed).choice(len(pts), num_samples, replace=False))
    return BoundarySamples(pts[pick], phi[pick], -grad[pick], (float(lo), float(hi)), drawn)


def _check_band(band) -> tuple[float, float]:
    lo, hi = (float(v) for v in band)
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo < 0 or hi <= lo:
        raise DanoError(f"band must be two finite densities 0 <= lo < hi, got {list(band)}")
    return lo, hi


# ------------------------------------------------------------------------- mesh


def visual_mesh(field: DensityField, level: float, resolution: int = 64, bounds: Any = None,
                signed_distance: bool = False):
    """Marching-cubes surface (scikit-image) of φ = ``level`` on a grid of ``resolution``
    nodes along the box's longest side, for rendering only; with ``signed_distance``, of the
    field's signed distance d = ``level`` [m] instead (d = 0: the field's exact surface, for
    fields that have one).

    Returns ``(vertices (V, 3) object frame [m], faces (F, 3) int)``, faces wound so
    that normals point outward (towards lower density). Raises DanoError if the
    level is outside the sampled range.
    """
    from skimage.measure import marching_cubes

    b = check_bounds(field.bounds() if bounds is None else bounds)
    ext = b[1] - b[0]
    shape = np.maximum(np.round(resolution * ext / ext.max()).astype(int), 2)
    axes = [np.linspace(b[0, k], b[1, k], shape[k]) for k in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    vol = evaluate(field, pts, signed_distance=signed_distance).reshape(shape)
    if signed_distance:
        vol = -vol  # inside high, as for a density
        level = -level
    if not vol.min() < level < vol.max():
        raise DanoError(f"mesh level {level:.4g} is outside the sampled range [{vol.min():.4g}, {vol.max():.4g}]")
    spacing = tuple(ext / (shape - 1))
    verts, faces, _, _ = marching_cubes(vol, level=level, spacing=spacing, gradient_direction="ascent")
    verts = verts + b[0]
    faces = faces.astype(np.int64)
    if _signed_volume(verts, faces) < 0:
        faces = faces[:, ::-1].copy()
    return verts, faces


def _signed_volume(verts: np.ndarray, faces: np.ndarray) -> float:
    a, b_, c = (verts[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b_, c)).sum() / 6.0)


# ------------------------------------------------------------------------ asset


def _frozen(a, dtype=np.float64) -> np.ndarray:
    arr = np.array(a, dtype=dtype)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class DanoAsset(_PrincipalInertia):
    """A dynamics-augmented neural object: mass properties + boundary samples.

    mass: total mass m = α∫φ [kg]; alpha: mass scale α;
    center_of_mass: (3,) μ, object frame [m];
    inertia: (3, 3) J about μ, object axes [kg m²];
    points: (N, 3) boundary samples, body frame (object axes, origin μ) [m];
    normals: (N, 3) outward unit normals −∇φ/|∇φ|, body/object axes;
    densities: (N,) φ_i (unscaled);
    weights: (N,) w_i = φ_i/Σφ·m [kg] (paper's contact weighting: overlaps in mass units);
    band: (2,) density band the samples were drawn from;
    mesh_vertices: (V, 3) body frame [m] and mesh_faces: (F, 3) int, visual only (may be empty);
    field: the density field (object frame), when it can be stored; needed for DANO-DANO contact;
    metadata: provenance (source, seed, integration errors, license) as a JSON-able dict.

    Arrays are read-only; use :func:`dataclasses.replace` (or :meth:`with_mass`) to derive
    new assets.
    """

    name: str
    mass: float
    alpha: float
    center_of_mass: np.ndarray
    inertia: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    densities: np.ndarray
    weights: np.ndarray
    band: np.ndarray
    mesh_vertices: np.ndarray = dc_field(default_factory=lambda: _frozen(np.zeros((0, 3))))
    mesh_faces: np.ndarray = dc_field(default_factory=lambda: _frozen(np.zeros((0, 3)), np.int64))
    field: Any = None
    metadata: dict = dc_field(default_factory=dict, metadata=HOST_ONLY)  # (provenance: not in program keys)

    def __post_init__(self):
        faces = np.asarray(self.mesh_faces)
        if faces.size and not np.issubdtype(faces.dtype, np.integer):
            if not (np.all(np.isfinite(faces)) and np.all(faces == np.round(faces)) and np.all(np.abs(faces) < 2**62)):
                raise DanoError("mesh_faces must be integer vertex indices")
        for name in ("center_of_mass", "inertia", "points", "normals", "densities", "weights", "band", "mesh_vertices"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        object.__setattr__(self, "mesh_faces", _frozen(self.mesh_faces, np.int64))
        object.__setattr__(self, "mass", float(self.mass))
        object.__setattr__(self, "alpha", float(self.alpha))
        validate(self)

    @property
    def num_samples(self) -> int:
        return int(self.points.shape[0])

    @property
    def normals_valid(self) -> np.ndarray:
        """(N,) bool: normal is finite and of unit length (to 1e-6)."""
        n = np.linalg.norm(self.normals, axis=1)
        return np.isfinite(n) & (np.abs(n - 1.0) < 1e-6)

    @property
    def normals_valid_fraction(self) -> float:
        return float(np.mean(self.normals_valid)) if self.num_samples else 0.0

    def with_mass(self, mass: float) -> "DanoAsset":
        """The same object with total mass ``mass`` [kg]: α, inertia and weights scale together."""
        if not np.isfinite(mass) or mass <= 0:
            raise DanoError(f"mass must be a finite positive number, got {mass}")
        k = float(mass) / self.mass
        return dataclasses.replace(self, mass=mass, alpha=self.alpha * k, inertia=self.inertia * k,
                                   weights=self.weights * k)

    def scaled(self, factor: float) -> "DanoAsset":
        """The same object uniformly scaled by ``factor`` about its centre of mass, same
        density: lengths ×s, mass and weights ×s³, inertia ×s⁵; the field is wrapped in a
        :class:`~dano.fields.TransformedField` (the object frame scales about its origin,
        so the centre of mass moves to s·μ)."""
        s = float(factor)
        if not np.isfinite(s) or s <= 0:
            raise DanoError(f"scale factor must be a finite positive number, got {factor}")
        fld = TransformedField.create(self.field, s) if self.field is not None else None
        return dataclasses.replace(
            self, mass=self.mass * s**3, inertia=self.inertia * s**5, weights=self.weights * s**3,
            center_of_mass=self.center_of_mass * s, points=self.points * s, mesh_vertices=self.mesh_vertices * s,
            field=fld, metadata={**self.metadata, "scaled_by": s * self.metadata.get("scaled_by", 1.0)},
        )

    def size(self) -> dict:
        """The object's size: ``bounding_box`` {"min", "max"} (3,) body frame [m] and
        ``extents`` (3,) [m] of the visual mesh (of the boundary samples without one);
        ``volume`` [m³] of the visual mesh when it is closed (trimesh), else of the samples'
        convex hull (``volume_source`` says which); ``mean_density`` = mass / volume [kg/m³]."""
        import trimesh

        has_mesh = len(self.mesh_faces) > 0
        pts = np.asarray(self.mesh_vertices if has_mesh else self.points, dtype=np.float64)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        volume, source = None, None
        if has_mesh:
            mesh = trimesh.Trimesh(self.mesh_vertices, self.mesh_faces, process=True)
            if mesh.is_watertight:
                volume, source = abs(float(mesh.volume)), "visual mesh"
        if volume is None:
            try:
                volume, source = float(trimesh.convex.convex_hull(np.asarray(self.points)).volume), \
                    "convex hull of the boundary samples"
            except Exception:  # degenerate samples (flat, too few): no volume
                volume, source = None, None
        return {"bounding_box": {"min": lo.tolist(), "max": hi.tolist()}, "extents": (hi - lo).tolist(),
                "volume": volume, "volume_source": source,
                "mean_density": self.mass / volume if volume else None}

    def summary(self) -> dict:
        """JSON-able summary (what ``dano inspect --json`` prints), with :meth:`size`."""
        return {
            **self.size(),
            "name": self.name,
            "mass": self.mass,
            "alpha": self.alpha,
            "center_of_mass": self.center_of_mass.tolist(),
            "inertia": self.inertia.tolist(),
            "principal_moments": self.principal_moments.tolist(),
            "principal_axes": self.principal_axes.tolist(),
            "num_samples": self.num_samples,
            "band": self.band.tolist(),
            "normals_valid_fraction": self.normals_valid_fraction,
            "has_field": self.field is not None,
            "mesh_faces": int(self.mesh_faces.shape[0]),
            "metadata": self.metadata,
        }


def _check_inertia(J: np.ndarray) -> None:
    scale = max(float(np.abs(J).max()), 1e-300)
    if not np.allclose(J, J.T, rtol=1e-9, atol=1e-12 * scale):
        raise DanoError("inertia is not symmetric")
    moments = np.linalg.eigvalsh(0.5 * (J + J.T))
    if moments[0] <= 1e-12 * scale:
        raise DanoError(f"inertia is not positive definite (principal moments {moments.tolist()})")
    if moments[0] + moments[1] < moments[2] * (1.0 - 1e-6):
        raise DanoError(f"inertia breaks the triangle inequality I1 + I2 >= I3 of a rigid body (principal moments "
                        f"{moments.tolist()})")


def validate(asset: DanoAsset) -> None:
    """Check shapes and physical validity; raises DanoError naming the first problem.

    Checked: array shapes; finite values; mass > 0 and α > 0 finite; band 0 <= lo < hi;
    densities >= 0; weights >= 0, not all zero, summing to the mass (relative 1e-6);
    normals of unit length (1e-6); inertia symmetric positive definite with the triangle
    inequalities; mesh faces integer indices into the vertices.
    """
    with np.errstate(all="ignore"):  # absurd values are reported by the checks, not by numpy warnings
        _validate(asset)


def _validate(asset: DanoAsset) -> None:
    if not isinstance(asset.name, str):
        raise DanoError(f"name must be a string, got {asset.name!r}")
    if not isinstance(asset.metadata, dict):
        raise DanoError(f"metadata must be a dict, got {type(asset.metadata).__name__}")
    n = asset.points.shape[0] if asset.points.ndim == 2 else -1
    shapes = {
        "center_of_mass": (asset.center_of_mass, (3,)),
        "inertia": (asset.inertia, (3, 3)),
        "points": (asset.points, (n, 3)),
        "normals": (asset.normals, (n, 3)),
        "densities": (asset.densities, (n,)),
        "weights": (asset.weights, (n,)),
        "band": (asset.band, (2,)),
    }
    for name, (arr, shape) in shapes.items():
        if arr.shape != shape or n < 1:
            raise DanoError(f"{name} has shape {arr.shape}, expected {shape if n >= 1 else '(N, 3) with N >= 1'}")
    if asset.mesh_vertices.ndim != 2 or asset.mesh_vertices.shape[1] != 3:
        raise DanoError(f"mesh_vertices has shape {asset.mesh_vertices.shape}, expected (V, 3)")
    if asset.mesh_faces.ndim != 2 or asset.mesh_faces.shape[1] != 3:
        raise DanoError(f"mesh_faces has shape {asset.mesh_faces.shape}, expected (F, 3)")
    for name in ("center_of_mass", "inertia", "points", "normals", "densities", "weights", "band", "mesh_vertices"):
        if not np.all(np.isfinite(getattr(asset, name))):
            raise DanoError(f"{name} contains NaN or infinite values")
    if not (np.isfinite(asset.mass) and asset.mass > 0):
        raise DanoError(f"mass must be finite and positive, got {asset.mass}")
    if not (np.isfinite(asset.alpha) and asset.alpha > 0):
        raise DanoError(f"mass scale alpha must be finite and positive, got {asset.alpha}")
    if not 0 <= asset.band[0] < asset.band[1]:
        raise DanoError(f"band must be two densities 0 <= lo < hi, got {asset.band.tolist()}")
    if np.any(asset.densities < 0) or np.any(asset.weights < 0):
        raise DanoError("sample densities and weights must be non-negative")
    total = float(asset.weights.sum())
    if not abs(total - asset.mass) <= 1e-6 * asset.mass:
        raise DanoError(f"sample weights sum to {total:.9g}, not to the mass {asset.mass:.9g} (the paper's "
                        "weighting w_i = φ_i/Σφ·m)")
    bad = ~asset.normals_valid
    if bad.any():
        raise DanoError(f"{int(bad.sum())} of {n} normals are not unit vectors (first: sample {int(np.argmax(bad))}, "
                        f"{asset.normals[int(np.argmax(bad))].tolist()})")
    _check_inertia(asset.inertia)
    if asset.mesh_faces.size:
        if asset.mesh_faces.min() < 0 or asset.mesh_faces.max() >= len(asset.mesh_vertices):
            raise DanoError(f"mesh_faces index vertices outside 0..{len(asset.mesh_vertices) - 1} "
                            f"(range {int(asset.mesh_faces.min())}..{int(asset.mesh_faces.max())})")


@in_float64
def build(
    field: DensityField,
    *,
    alpha: float | None = None,
    mass: float | None = None,
    num_samples: int = DEFAULT_NUM_SAMPLES,
    band: tuple[float, float] | None = None,
    seed: int = 0,
    stencil: float = 0.0,
    integration: str = "sobol",
    integration_points: int = 1 << 20,
    mesh_level: float | None = None,
    mesh_resolution: int = 64,
    name: str | None = None,
    source: str = "",
    progress: Progress | None = None,
) -> DanoAsset:
    """Turn a density field into a :class:`DanoAsset` (paper §IV).

    field: any :class:`~dano.fields.DensityField` (object frame [m]).
    alpha / mass: the mass scale α, or the total mass [kg] that sets it (default α = 1).
    num_samples, band, seed, stencil: see :func:`boundary_samples`.
    integration, integration_points: see :func:`mass_properties`.
    mesh_level: density of the visual mesh's level set (default: the field's surface, its
    signed distance's zero for a field that has one, e.g. a mesh's; else the middle of the band);
    mesh_resolution: marching-cubes nodes along the longest axis (0: no mesh).
    name: the asset's name, which scenes, tables and exports call it (None or "": the field's,
    :func:`~dano.fields.field_name`: the file's stem for :func:`~dano.fields.mesh_field` and
    :meth:`~dano.fields.VoxelField.load`, "sphere", "box", ...); source: provenance text kept in
    the metadata.
    Raises DanoError on bad input (see the functions above).
    """
    name = name or field_name(field)
    mp = mass_properties(field, alpha=alpha, mass=mass, method=integration, num_points=integration_points,
                         seed=seed, progress=progress)
    bs = boundary_samples(field, num_samples, band=band, seed=seed, stencil=stencil, progress=progress)
    mu = mp.center_of_mass
    verts, faces = np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    if mesh_resolution and mesh_level is None and callable(getattr(field, "signed_distance", None)):
        # a signed distance is linear across a flat face, a sharp density step is not: the level
        # set of the band's middle, interpolated between nodes 2.3 mm apart, sat 0.25 mm inside
        # a 15 mm plate (volume -5.9 %; at d = 0: 15.003 mm, -2.3 %, from the corners)
        verts, faces = visual_mesh(field, 0.0, mesh_resolution, signed_distance=True)
        verts = verts - mu
    elif mesh_resolution:
        level = 0.5 * (bs.band[0] + bs.band[1]) if mesh_level is None else float(mesh_level)
        verts, faces = visual_mesh(field, level, mesh_resolution)
        verts = verts - mu
    weights = bs.densities / bs.densities.sum() * mp.mass
    stored_field = field if to_arrays(field) is not None else None
    return DanoAsset(
        name=name,
        mass=mp.mass,
        alpha=mp.alpha,
        center_of_mass=mu,
        inertia=mp.inertia,
        points=bs.points - mu,
        normals=bs.normals,
        densities=bs.densities,
        weights=weights,
        band=np.asarray(bs.band),
        mesh_vertices=verts,
        mesh_faces=faces,
        field=stored_field,
        metadata={
            "source": source,
            "seed": seed,
            "stencil": stencil,
            "integration": {
                "method": mp.method,
                "num_points": mp.num_points,
                "mass_std": mp.mass_std,
                "center_of_mass_std": mp.center_of_mass_std.tolist(),
                "inertia_std": mp.inertia_std.tolist(),
            },
            "band_rule": "user" if band is not None else "auto: [0.05, 0.95] x 99th percentile of density",
            "num_candidates": bs.num_candidates,
        },
    )


# ---------------------------------------------------------------------- file I/O

_ARRAYS = ("center_of_mass", "inertia", "points", "normals", "densities", "weights", "band", "mesh_vertices", "mesh_faces")


def save(asset: DanoAsset, path: str | Path) -> Path:
    """Write ``asset`` to a ``.dano`` file (format version 1) and return the path.

    The file is a NumPy ``.npz`` archive (open it with ``numpy.load``): the arrays of
    :class:`DanoAsset` under the same names (SI units, frames as documented there),
    the density field under ``field/...`` when it can be stored, and ``metadata``: a
    JSON string with ``format`` ("dano"), ``version``, ``units``, ``frames``, mass,
    α, band, N, seed, source and the dano version. Written atomically: on any error
    no (partial) file is left.
    """
    path = Path(path)
    meta = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "dano_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "name": asset.name,
        "mass": asset.mass,
        "alpha": asset.alpha,
        "num_samples": asset.num_samples,
        "band": asset.band.tolist(),
        "units": {"length": "m", "mass": "kg", "inertia": "kg m^2", "weights": "kg", "densities": "field units"},
        "frames": {
            "center_of_mass": "object frame (frame of the density field)",
            "points": "body frame: object axes, origin at the centre of mass",
            "mesh_vertices": "body frame",
            "inertia": "about the centre of mass, object axes",
            "field": "object frame",
        },
        **{k: v for k, v in asset.metadata.items() if k not in ("format", "version")},
    }
    arrays = {k: np.asarray(getattr(asset, k)) for k in _ARRAYS}
    if asset.field is not None:
        arrays.update(to_arrays(asset.field) or {})
    arrays["metadata"] = np.asarray(json.dumps(meta))
    atomic_write(path, lambda f: np.savez_compressed(f, **arrays))
    return path


def _build_hint(path: Path) -> str:
    """For a file ``dano build`` reads (a mesh, a voxel grid, a paper collider, a trained
    field's folder): how to make a DANO of it; else nothing."""
    try:
        kind = source_kind(path)
    except FileFormatError:
        return ""
    what = {"mesh": "a mesh", "voxel": "a voxel grid", "jld2": "a paper collider",
            "field": "a trained field's folder"}[kind]
    return f"; if it is {what}, make a DANO of it with `dano build {path} -o NAME.dano`"


def load(path: str | Path) -> DanoAsset:
    """Read a ``.dano`` file written by :func:`save`.

    Raises FileFormatError naming the file if it is missing, not a ``.dano`` archive,
    of another format version, or holds arrays of the wrong shapes.
    """
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{path}: {'a folder, not a .dano file' + _build_hint(path) if path.is_dir() else 'no such file'}")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except Exception as exc:  # (NumPy's own message, about pickles, would mislead here)
        raise FileFormatError(f"{path}: not a .dano file (not an npz archive){_build_hint(path)}") from exc
    if "metadata" not in arrays:
        raise FileFormatError(f"{path}: not a .dano file (no metadata){_build_hint(path)}")
    try:
        meta = json.loads(str(arrays["metadata"]))
    except json.JSONDecodeError as exc:
        raise FileFormatError(f"{path}: corrupt metadata ({exc})") from exc
    if not isinstance(meta, dict):
        raise FileFormatError(f"{path}: corrupt metadata (a JSON {type(meta).__name__}, expected an object)")
    if meta.get("format") != FORMAT_NAME:
        raise FileFormatError(f"{path}: not a .dano file (format {meta.get('format')!r})")
    if meta.get("version") != FORMAT_VERSION:
        raise FileFormatError(
            f"{path}: .dano format version {meta.get('version')!r}; this dano {__version__} reads version "
            f"{FORMAT_VERSION}"
        )
    missing = [k for k in _ARRAYS if k not in arrays]
    if missing:
        raise FileFormatError(f"{path}: missing arrays {missing}")
    try:
        fld = from_arrays(arrays)
        extra = {k: v for k, v in meta.items() if k not in ("mass", "alpha", "name", "num_samples", "band")}
        return DanoAsset(
            name=meta.get("name") or path.stem,
            mass=meta["mass"],
            alpha=meta["alpha"],
            field=fld,
            metadata=extra,
            **{k: arrays[k] for k in _ARRAYS},
        )
    except (DanoError, KeyError, ValueError, TypeError) as exc:
        raise FileFormatError(f"{path}: {exc}") from exc


#: mean densities [kg/m³] outside this range are not plausible for a solid object in metres and kilograms
PLAUSIBLE_DENSITY = (10.0, 25_000.0)


def density_warning(summary: dict) -> str | None:
    """A one-line warning when the mean density of an asset's :meth:`DanoAsset.summary` lies
    outside :data:`PLAUSIBLE_DENSITY` (a mesh in millimetres, or a mass in grams), else None."""
    rho = summary["mean_density"]
    if rho is None or PLAUSIBLE_DENSITY[0] <= rho <= PLAUSIBLE_DENSITY[1]:
        return None
    return (f"mean density {rho:.3g} kg/m³ (mass {summary['mass']:.3g} kg, extents "
            + " x ".join(f"{e:.3g}" for e in summary["extents"]) + " m) is outside "
            f"{PLAUSIBLE_DENSITY[0]:g}-{PLAUSIBLE_DENSITY[1]:g} kg/m³: is the object in metres and its mass in kg?")

"""Rotations and rigid poses: the one place dano does rotation maths (on jaxlie).

Conventions (MuJoCo's): a quaternion is (..., 4) ``w x y z`` (scalar first), unit length,
the rotation world ← body; composition q₁ ⊗ q₂ applies q₂ first (in q₁'s frame); a rotation
vector r (..., 3) [rad] is the axis times the angle; ``exp``/``log`` map between them. A
pose (..., 7) is ``x y z`` [m, world] followed by the quaternion. A free body's velocity
(..., 6) is MuJoCo's qvel: linear velocity [m/s, world frame], then angular velocity
[rad/s, body frame].

Every function takes any leading batch axes (``...``; binary ones broadcast), traces under
``jit``/``vmap``/``grad`` (numerically safe branches with ``jnp.where``, so values and
gradients are finite at zero rotation and at a half turn), and takes NumPy input too: when no
argument is a JAX array the computation runs in NumPy and SciPy's ``Rotation`` (float64
whatever JAX's 64-bit setting, nothing to compile: host code that reads a recording's poses
costs no compilation) and returns NumPy arrays; both paths give the same values to rounding
(``tests/test_pose.py``).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from .errors import DanoError

__all__ = ["normalize_quat", "quat_error", "quat_inverse", "quat_mean", "quat_multiply", "quat_to_matrix",
           "quat_to_rotvec", "random_quats", "rotate", "rotvec_to_quat", "slope_weights", "velocity_from_poses"]

#: below this squared norm of the quaternion's vector part, the logarithm's factor comes from
#: its Taylor series (jaxlie's thresholds: the series' error is below the type's rounding)
_TAYLOR = {jnp.dtype("float32"): 1e-5, jnp.dtype("float64"): 1e-10}


def _host_or_jax(host):
    """The decorated function for JAX arrays and tracers (plain JAX: jit, vmap, grad), and
    ``host`` (NumPy/SciPy, float64) for NumPy or list input, which returns NumPy arrays:
    host code neither compiles nor depends on JAX's 64-bit setting, also inside a trace."""

    def decorate(fn):
        @functools.wraps(fn)
        def wrapped(*args, **kwargs):
            if any(isinstance(a, jax.Array) for a in (*args, *kwargs.values())):
                return fn(*args, **kwargs)
            return host(*(_host_float(a) for a in args), **kwargs)

        return wrapped

    return decorate


def _host_float(x) -> np.ndarray:
    return np.array(x, dtype=np.float64)  # (a copy: results never alias the caller's array)


def _rotation(q: np.ndarray):
    """SciPy's Rotation of the quaternions q (..., 4) w x y z (normalised by SciPy). Raises
    DanoError for a quaternion of zero (or non-finite) norm."""
    from scipy.spatial.transform import Rotation

    _norms(q)
    return Rotation.from_quat(q, scalar_first=True)


def _norms(q: np.ndarray) -> np.ndarray:
    """‖q‖ (..., 1) of quaternions q (..., 4). Raises DanoError for a wrong shape or a
    quaternion of zero (or non-finite) norm (the host path's inputs: never a silent NaN)."""
    _check(q, 4, "quaternion")
    norms = np.linalg.norm(q, axis=-1, keepdims=True)
    bad = ~(np.isfinite(norms) & (norms > 0))
    if np.any(bad):
        raise DanoError(f"quaternions must be finite and non-zero, got {np.count_nonzero(bad)} that are not")
    return norms


def _host_broadcast(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Broadcast the leading (batch) axes of a (..., m) and b (..., n)."""
    lead = np.broadcast_shapes(a.shape[:-1], b.shape[:-1])
    return np.array(np.broadcast_to(a, lead + a.shape[-1:])), np.array(np.broadcast_to(b, lead + b.shape[-1:]))


def _host_normalize(q):
    return q / _norms(q)


def _host_multiply(q1, q2):
    # the Hamilton product of q1 and q2 as given (SciPy composes the normalised ones)
    from scipy.spatial.transform import Rotation

    _check(q1, 4, "quaternion")
    _check(q2, 4, "quaternion")
    q1, q2 = _host_broadcast(q1, q2)
    n1, n2 = _norms(q1), _norms(q2)  # (each checked once: _rotation would check them again)
    r1, r2 = Rotation.from_quat(q1, scalar_first=True), Rotation.from_quat(q2, scalar_first=True)
    return (r1 * r2).as_quat(canonical=False, scalar_first=True) * n1 * n2


def _host_inverse(q):
    _check(q, 4, "quaternion")
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _host_matrix(q):
    return _rotation(q).as_matrix()


def _host_rotate(q, v):
    _check(v, 3, "vector")
    _check(q, 4, "quaternion")  # (before broadcasting: its message names the quaternion)
    q, v = _host_broadcast(q, v)
    return _rotation(q).apply(v)


def _host_exp(r):
    from scipy.spatial.transform import Rotation

    _check(r, 3, "rotation vector")
    return Rotation.from_rotvec(r).as_quat(canonical=False, scalar_first=True)


def _host_log(q):
    _check(q, 4, "quaternion")
    return _rotation(q).as_rotvec()  # (angle in [0, π] from the two-argument arctangent, as below)


def _host_error(q_ref, q):
    return _host_log(_host_multiply(_host_inverse(q_ref), q))


def _host_mean(q):
    q = _host_normalize(q)
    _, vectors = np.linalg.eigh(np.einsum("...ki,...kj->...ij", q, q))
    m = vectors[..., :, -1]
    return np.where(m[..., :1] < 0, -m, m)


def _float(x) -> jax.Array:
    a = jnp.asarray(x)
    return a if jnp.issubdtype(a.dtype, jnp.inexact) else a.astype(jnp.result_type(float))


def _check(x: jax.Array, size: int, name: str) -> None:
    if x.ndim == 0 or x.shape[-1] != size:
        raise DanoError(f"{name} must have shape (..., {size}), got {tuple(x.shape)}")


def _so3(q) -> jaxlie.SO3:
    q = _float(q)
    _check(q, 4, "quaternion")
    return jaxlie.SO3(q)


def _broadcast(a: jax.Array, b: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Broadcast the leading (batch) axes of a (..., m) and b (..., n)."""
    lead = jnp.broadcast_shapes(a.shape[:-1], b.shape[:-1])
    return jnp.broadcast_to(a, lead + a.shape[-1:]), jnp.broadcast_to(b, lead + b.shape[-1:])


@_host_or_jax(_host_normalize)
def normalize_quat(q) -> jax.Array:
    """q / ‖q‖, (..., 4) → (..., 4)."""
    q = _float(q)
    _check(q, 4, "quaternion")
    return q / jnp.linalg.norm(q, axis=-1, keepdims=True)


@_host_or_jax(_host_multiply)
def quat_multiply(q1, q2) -> jax.Array:
    """Hamilton product q₁ ⊗ q₂ (..., 4): the rotation q₂, then q₁ (frames: a ← b ⊗ b ← c = a ← c)."""
    a, b = _broadcast(_so3(q1).wxyz, _so3(q2).wxyz)
    return (jaxlie.SO3(a) @ jaxlie.SO3(b)).wxyz


@_host_or_jax(_host_inverse)
def quat_inverse(q) -> jax.Array:
    """The inverse of a unit quaternion (its conjugate), (..., 4): body ← world for world ← body."""
    return _so3(q).inverse().wxyz


@_host_or_jax(_host_matrix)
def quat_to_matrix(q) -> jax.Array:
    """Rotation matrix (..., 3, 3) of the quaternion (..., 4) (normalised first: any non-zero
    quaternion); R·x maps body-frame x to the world frame."""
    return _so3(q).as_matrix()


@_host_or_jax(_host_rotate)
def rotate(q, v) -> jax.Array:
    """q ⊗ v ⊗ q⁻¹: the vectors v (..., 3) rotated by the unit quaternions q (..., 4)
    (body-frame vectors to the world frame); broadcasts q against v's leading axes."""
    v = _float(v)
    _check(v, 3, "vector")
    q, v = _broadcast(_so3(q).wxyz, v)
    return jaxlie.SO3(q) @ v


@_host_or_jax(_host_exp)
def rotvec_to_quat(r) -> jax.Array:
    """Exponential map: the unit quaternion (..., 4) of the rotation vector r (..., 3) [rad]
    (angle ‖r‖ about r/‖r‖); Taylor series near zero (exact value and gradients at r = 0)."""
    r = _float(r)
    _check(r, 3, "rotation vector")
    return jaxlie.SO3.exp(r).wxyz


@_host_or_jax(_host_log)
def quat_to_rotvec(q) -> jax.Array:
    """Logarithm: the rotation vector (..., 3) [rad] of the quaternion (..., 4), angle in
    [0, π]; the same for q and −q and for any positive multiple of q (no normalisation
    needed). Finite value and gradients at the identity (Taylor series) and at a half turn.
    (jaxlie's ``SO3.log`` snaps the angle to ±π within 1e-10 of a half turn, which would
    change results there and zero the gradient; this is the two-argument arctangent throughout.)"""
    q = _float(q)
    _check(q, 4, "quaternion")
    w, v = q[..., :1], q[..., 1:]
    v = jnp.where(w < 0, -v, v)
    w = jnp.abs(w)
    sq = jnp.sum(v * v, axis=-1, keepdims=True)
    taylor = sq < _TAYLOR.get(sq.dtype, 1e-10)
    n = jnp.sqrt(jnp.where(taylor, 1.0, sq))
    w_safe = jnp.where(taylor, jnp.maximum(w, 1e-12), 1.0)
    scale = jnp.where(taylor, 2.0 / w_safe - (2.0 / 3.0) * sq / w_safe**3, 2.0 * jnp.arctan2(n, w) / n)
    return scale * v


@_host_or_jax(_host_error)
def quat_error(q_ref, q) -> jax.Array:
    """log(q_ref⁻¹ ⊗ q) (..., 3) [rad]: the rotation from q_ref to q as a rotation vector in
    q_ref's body frame; sign-invariant in both, NaN-free (also its gradients) when q = q_ref."""
    return quat_to_rotvec(quat_multiply(quat_inverse(q_ref), q))


@_host_or_jax(_host_mean)
def quat_mean(q) -> jax.Array:
    """Chordal L2 mean of unit quaternions (..., K, 4) → (..., 4): the principal eigenvector
    of Σ q qᵀ over the normalised quaternions (Markley et al. 2007; SciPy's ``Rotation.mean``),
    sign chosen with w ≥ 0."""
    q = normalize_quat(q)
    _, vectors = jnp.linalg.eigh(jnp.einsum("...ki,...kj->...ij", q, q))
    m = vectors[..., :, -1]
    return jnp.where(m[..., :1] < 0, -m, m)


def random_quats(rng: np.random.Generator, shape: int | tuple = ()) -> np.ndarray:
    """Uniformly distributed unit quaternions (*shape, 4) (normalised standard normals in
    R⁴) drawn from a NumPy generator; the same numbers as SciPy's ``Rotation.random(n, rng)``
    (which draws x y z w), as w x y z."""
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    xyzw = rng.normal(size=(*shape, 4))
    xyzw /= np.linalg.norm(xyzw, axis=-1, keepdims=True)
    return xyzw[..., [3, 0, 1, 2]]


def _derivative_weights(t: np.ndarray, degree: int, intercept: bool, at: float = 0.0) -> np.ndarray:
    """(..., n) weights c with Σ_k c_k·x_k the derivative at t = ``at`` of the least-squares
    polynomial of ``degree`` through (t_k, x_k) (without a constant term: through zero)."""
    scale = np.max(np.abs(t), axis=-1, keepdims=True)
    powers = np.arange(0 if intercept else 1, degree + 1)
    vander = (t / scale)[..., None] ** powers  # (..., n, p), columns of order 1
    slope = np.where(powers > 0, powers * (at / scale) ** np.maximum(powers - 1, 0), 0.0)  # d/dt of each column
    return np.einsum("...p,...pn->...n", slope, np.linalg.pinv(vander)) / scale


def _fit_times(times, degree: int, at: float, what: str, count: str) -> np.ndarray:
    """times (..., n) [s] relative to the first, checked for a polynomial fit of ``degree``
    (DanoError naming ``what``: too few ``count``, times not increasing, ``at`` not finite)."""
    t = np.asarray(times, dtype=np.float64)
    if t.ndim == 0:
        raise DanoError(f"{what} needs times (..., n), got a scalar")
    if degree < 1 or t.shape[-1] < degree + 1:
        raise DanoError(f"a degree-{degree} fit needs at least {degree + 1} {count}, got {t.shape[-1]}")
    t = t - t[..., :1]
    if np.any(np.diff(t, axis=-1) <= 0):
        raise DanoError(f"{what} needs increasing times")
    if not np.isfinite(at):
        raise DanoError(f"{what} needs a finite time offset at, got {at!r}")
    return t


def slope_weights(times, degree: int = 1, at: float = 0.0) -> np.ndarray:
    """(..., n) weights c: Σ_k c_k·x_k is the slope, ``at`` [s] after the first of ``times``
    (..., n) [s] (negative: before it), of the least-squares polynomial of ``degree``
    through (t_k, x_k), for samples x of any unit (the slope in that unit per second).
    degree 2 through 3 samples at spacing Δ: (−3, 4, −1)/(2Δ) at the first; ``at`` = −ρΔ/2:
    (−(3 + ρ), 4 + 2ρ, −(1 + ρ))/(2Δ). Raises DanoError with fewer than degree + 1 times,
    times not increasing or a non-finite ``at``."""
    return _derivative_weights(_fit_times(times, degree, at, "slope_weights", "samples"), degree, True, at)


def velocity_from_poses(times, poses, degree: int = 1, at: float = 0.0) -> np.ndarray:
    """A free body's velocity (..., 6) at the first of the poses (or ``at`` [s] after it:
    negative is before it), from a polynomial fit.

    times (..., n) [s] (increasing), poses (..., n, 7) (x y z [m, world], quaternion w x y z).
    Linear velocity [m/s, world frame]: the slope at the first time of the least-squares
    polynomial of ``degree`` through the positions. Angular velocity [rad/s, body frame of the
    first pose]: the same of the polynomial *through zero* through the rotation vectors
    log(q₀⁻¹ ⊗ q_k). Exact for a constant velocity (linear velocity and body-frame spin, angle
    per interval below π). degree 1 with n = 2 is a difference quotient, with n = 3 a
    least-squares slope (steadier against tracking noise); degree 2 with n = 3 is the
    second-order one-sided difference (−3x₀ + 4x₁ − x₂)/(2h). Host code: NumPy in, NumPy
    (float64) out. Raises DanoError with fewer than degree + 1 poses, bad shapes or a
    non-finite ``at``."""
    t = np.asarray(times, dtype=np.float64)
    p = np.asarray(poses, dtype=np.float64)
    if p.shape[-1:] != (7,) or p.shape[:-1] != t.shape or t.ndim == 0:
        raise DanoError(f"velocity_from_poses needs times (..., n) and poses (..., n, 7), got {t.shape} and {p.shape}")
    t = _fit_times(t, degree, at, "velocity_from_poses", "poses")
    linear = np.einsum("...k,...ki->...i", _derivative_weights(t[..., :], degree, True, at), p[..., :3])
    r = quat_error(p[..., :1, 3:], p[..., 1:, 3:])  # (..., n - 1, 3), body frame of the first pose
    angular = np.einsum("...k,...ki->...i", _derivative_weights(t[..., 1:], degree, False, at), r)
    return np.concatenate([linear, angular], axis=-1)

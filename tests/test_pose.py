"""dano.pose, in jaxlie's style: properties over batch shapes (exp/log and matrix round trips,
associativity, inverses), SciPy's Rotation as the reference, gradients finite at the identity
and at a half turn and equal to finite differences (float64), float32 and NumPy input, and one
velocity-from-poses that recovers a constant linear and body-frame angular velocity."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from dano import pose
from dano.errors import DanoError

BATCH = st.sampled_from([(), (1,), (3,), (2, 3)])
SEED = st.integers(0, 2**32 - 1)
cases = settings(max_examples=12, deadline=None)


def quats(rng, shape):
    return jnp.asarray(pose.random_quats(rng, shape))


def rotvecs(rng, shape, max_angle=3.0):
    axis = rng.normal(size=(*shape, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    return jnp.asarray(axis * rng.uniform(0.0, max_angle, (*shape, 1)))


def same_rotation(q1, q2, atol=1e-12):
    """q and −q are the same rotation."""
    d = np.abs(np.sum(np.asarray(q1) * np.asarray(q2), axis=-1))
    np.testing.assert_allclose(d, 1.0, atol=atol)


@cases
@given(BATCH, SEED)
def test_exp_log_round_trip(shape, seed):
    rng = np.random.default_rng(seed)
    r = rotvecs(rng, shape)
    q = pose.rotvec_to_quat(r)
    assert q.shape == (*shape, 4)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-14)
    np.testing.assert_allclose(pose.quat_to_rotvec(q), r, atol=1e-12)
    q = quats(rng, shape)
    same_rotation(pose.rotvec_to_quat(pose.quat_to_rotvec(q)), q)
    np.testing.assert_allclose(pose.quat_to_rotvec(-q), pose.quat_to_rotvec(q), atol=1e-12)


@cases
@given(BATCH, SEED)
def test_matrix_and_rotate_agree(shape, seed):
    rng = np.random.default_rng(seed)
    q, v = quats(rng, shape), jnp.asarray(rng.normal(size=(*shape, 3)))
    R = pose.quat_to_matrix(q)
    assert R.shape == (*shape, 3, 3)
    np.testing.assert_allclose(jnp.swapaxes(R, -1, -2) @ R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(pose.rotate(q, v), jnp.einsum("...ij,...j->...i", R, v), atol=1e-12)
    np.testing.assert_allclose(pose.rotate(pose.quat_inverse(q), pose.rotate(q, v)), v, atol=1e-12)
    # a single rotation broadcasts over a batch of vectors
    many = jnp.asarray(rng.normal(size=(5, 3)))
    np.testing.assert_allclose(pose.rotate(q.reshape(-1, 4)[0], many), many @ R.reshape(-1, 3, 3)[0].T, atol=1e-12)


@cases
@given(BATCH, SEED)
def test_composition_is_associative_with_inverses(shape, seed):
    rng = np.random.default_rng(seed)
    a, b, c = quats(rng, shape), quats(rng, shape), quats(rng, shape)
    m = pose.quat_multiply
    np.testing.assert_allclose(m(m(a, b), c), m(a, m(b, c)), atol=1e-12)
    same_rotation(m(a, pose.quat_inverse(a)), np.broadcast_to([1.0, 0.0, 0.0, 0.0], (*shape, 4)))
    np.testing.assert_allclose(pose.quat_to_matrix(m(a, b)), pose.quat_to_matrix(a) @ pose.quat_to_matrix(b),
                               atol=1e-12)
    # quat_error is the body-frame rotation vector from a to b: a ⊗ exp(e) = b, and sign-invariant
    e = pose.quat_error(a, b)
    same_rotation(m(a, pose.rotvec_to_quat(e)), b)
    np.testing.assert_allclose(pose.quat_error(-a, b), e, atol=1e-12)
    np.testing.assert_allclose(pose.quat_error(a, a), 0.0, atol=1e-12)


@cases
@given(BATCH, SEED)
def test_agrees_with_scipy(shape, seed):
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(2, *shape, 4))  # not normalised: SciPy normalises, dano's log and matrix need not
    Ra, Rb = Rotation.from_quat(a.reshape(-1, 4), scalar_first=True), Rotation.from_quat(b.reshape(-1, 4),
                                                                                         scalar_first=True)
    flat = lambda x: np.asarray(x).reshape(-1, *np.shape(x)[len(shape):])  # noqa: E731
    np.testing.assert_allclose(flat(pose.quat_to_matrix(a)), Ra.as_matrix(), atol=1e-14)
    np.testing.assert_allclose(flat(pose.quat_to_rotvec(a)), Ra.as_rotvec(), atol=1e-13)
    np.testing.assert_allclose(flat(pose.quat_error(a, b)), (Ra.inv() * Rb).as_rotvec(), atol=1e-13)
    ua, ub = pose.normalize_quat(a), pose.normalize_quat(b)
    same_rotation(flat(pose.quat_multiply(ua, ub)), (Ra * Rb).as_quat(scalar_first=True), atol=1e-14)
    v = rng.normal(size=(*shape, 3))
    np.testing.assert_allclose(flat(pose.rotate(ua, v)), Ra.apply(v.reshape(-1, 3)), atol=1e-13)
    r = rng.normal(size=(*shape, 3)) * 1e-3 ** rng.integers(0, 4)  # Taylor series and closed form
    np.testing.assert_allclose(flat(pose.rotvec_to_quat(r)), Rotation.from_rotvec(r.reshape(-1, 3))
                               .as_quat(scalar_first=True), atol=1e-15)
    k = 2 + int(rng.integers(0, 5))
    same_rotation(pose.quat_mean(a.reshape(-1, 4)[:k] if a.ndim > 1 else a[None]),
                  Rotation.from_quat(a.reshape(-1, 4)[:k], scalar_first=True).mean().as_quat(scalar_first=True),
                  atol=1e-13)


def test_random_quats_are_scipys_draws():
    """The same numbers as Rotation.random with the same generator (x y z w there, w x y z here)."""
    q = pose.random_quats(np.random.default_rng(7), 50)
    ref = Rotation.random(50, random_state=np.random.default_rng(7)).as_quat(scalar_first=True)
    np.testing.assert_array_equal(q, ref)
    assert pose.random_quats(np.random.default_rng(0), (2, 3)).shape == (2, 3, 4)


def test_gradients_are_finite_at_the_identity_and_a_half_turn():
    ident = jnp.asarray([1.0, 0.0, 0.0, 0.0])
    J = jax.jacfwd(pose.quat_to_rotvec)(ident)
    np.testing.assert_allclose(J, np.c_[np.zeros(3), 2 * np.eye(3)], atol=1e-12)
    np.testing.assert_allclose(jax.jacrev(pose.quat_to_rotvec)(ident), J, atol=1e-12)
    np.testing.assert_allclose(jax.jacfwd(pose.rotvec_to_quat)(jnp.zeros(3)), np.r_[np.zeros((1, 3)), 0.5 * np.eye(3)],
                               atol=1e-12)
    g = jax.grad(lambda r: jnp.sum(pose.quat_error(ident, pose.rotvec_to_quat(r)) ** 2))(jnp.zeros(3))
    assert np.all(np.isfinite(g)) and np.allclose(g, 0.0)
    h = jax.hessian(lambda r: jnp.sum(pose.quat_to_rotvec(pose.rotvec_to_quat(r)) ** 2))(jnp.zeros(3))
    np.testing.assert_allclose(h, 2 * np.eye(3), atol=1e-10)
    half = jnp.asarray([0.0, 0.6, 0.0, 0.8])  # a half turn: w = 0
    for fn in (jax.jacfwd, jax.jacrev):
        assert np.all(np.isfinite(fn(pose.quat_to_rotvec)(half)))
    np.testing.assert_allclose(np.linalg.norm(pose.quat_to_rotvec(half)), np.pi, atol=1e-15)


def _composite(x):
    """x = (quaternion (4), rotation vector (3)) -> error, rotated vector and matrix entries."""
    q = pose.quat_multiply(x[:4], pose.rotvec_to_quat(x[4:]))
    return jnp.concatenate([pose.quat_error(x[:4], q), pose.rotate(q, jnp.asarray([0.3, -0.2, 0.5])),
                            pose.quat_to_matrix(x[:4]).ravel()])


_COMPOSITE = {"f": jax.jit(_composite), "fwd": jax.jit(jax.jacfwd(_composite)), "rev": jax.jit(jax.jacrev(_composite))}


@settings(max_examples=8, deadline=None)
@given(SEED)
def test_gradients_match_finite_differences(seed):
    rng = np.random.default_rng(seed)
    x = jnp.asarray(np.r_[np.asarray(quats(rng, ())), np.asarray(rotvecs(rng, (), 2.5))])
    f, h = _COMPOSITE["f"], 1e-6
    fd = np.stack([(np.asarray(f(x.at[i].add(h))) - np.asarray(f(x.at[i].add(-h)))) / (2 * h) for i in range(7)], 1)
    np.testing.assert_allclose(_COMPOSITE["fwd"](x), fd, atol=1e-7)
    np.testing.assert_allclose(_COMPOSITE["rev"](x), fd, atol=1e-7)


def test_float32_and_numpy_input():
    rng = np.random.default_rng(3)
    q64, r64 = np.asarray(quats(rng, (4,))), np.asarray(rotvecs(rng, (4,)))
    q32, r32 = jnp.asarray(q64, jnp.float32), jnp.asarray(r64, jnp.float32)
    for fn, args64, args32, tol in ((pose.quat_to_rotvec, (q64,), (q32,), 1e-5),
                                    (pose.rotvec_to_quat, (r64,), (r32,), 1e-6),
                                    (pose.quat_error, (q64, q64[::-1]), (q32, q32[::-1]), 1e-5),
                                    (pose.quat_to_matrix, (q64,), (q32,), 1e-6)):
        out = fn(*args32)
        assert out.dtype == jnp.float32 and np.all(np.isfinite(out)), fn.__name__
        np.testing.assert_allclose(out, fn(*args64), atol=tol, err_msg=fn.__name__)
    assert np.all(np.isfinite(jax.jacfwd(pose.quat_to_rotvec)(jnp.asarray([1.0, 0, 0, 0], jnp.float32))))
    # NumPy (and list) input: NumPy float64 output, writable, also inside a trace
    out = pose.quat_to_rotvec([1, 0, 0, 0])
    assert isinstance(out, np.ndarray) and out.dtype == np.float64 and out.flags.writeable
    seen = []
    jax.jit(lambda x: (seen.append(type(pose.quat_to_matrix(q64))), x)[1])(1.0)
    assert seen == [np.ndarray]
    with jax.enable_x64(False):
        assert pose.quat_to_rotvec(q64).dtype == np.float64  # host code keeps float64


@cases
@given(BATCH, SEED)
def test_numpy_input_gives_the_jax_values(shape, seed):
    """The host path (NumPy and SciPy) against the JAX one, at random rotations, the identity,
    a half turn and rotation vectors past π; binary functions broadcast a single argument."""
    rng = np.random.default_rng(seed)
    q1, q2 = np.asarray(quats(rng, shape)), np.asarray(quats(rng, shape))
    q1 = q1 * rng.uniform(0.5, 2.0, (*shape, 1))  # not normalised: the product is Hamilton's as given
    special = np.array([[1.0, 0, 0, 0], [0.0, 1, 0, 0], [0.0, 0.6, 0.8, 0], [-0.5, 0.5, 0.5, 0.5]])
    r = np.concatenate([np.asarray(rotvecs(rng, (5,), max_angle=6.0)), np.zeros((1, 3))])
    v = rng.normal(size=(*shape, 3))
    cases = [(pose.normalize_quat, (q1,)), (pose.quat_multiply, (q1, q2)), (pose.quat_multiply, (special[1], q2)),
             (pose.quat_inverse, (q1,)), (pose.quat_to_matrix, (q1,)), (pose.quat_to_matrix, (special,)),
             (pose.rotate, (q2, v)), (pose.rotate, (special[2], v)), (pose.rotvec_to_quat, (r,)),
             (pose.quat_to_rotvec, (q1,)), (pose.quat_to_rotvec, (special,)), (pose.quat_error, (q1, q2)),
             (pose.quat_error, (special, special[::-1])), (pose.quat_mean, (special,))]
    with jax.enable_x64(True):
        for fn, args in cases:
            host = fn(*args)
            assert isinstance(host, np.ndarray) and host.dtype == np.float64, fn.__name__
            np.testing.assert_allclose(host, fn(*map(jnp.asarray, args)), atol=1e-12, err_msg=fn.__name__)


def test_bad_shapes_are_refused():
    with pytest.raises(DanoError, match=r"quaternion must have shape \(\.\.\., 4\), got \(3,\)"):
        pose.quat_to_matrix(np.zeros(3))
    with pytest.raises(DanoError, match=r"rotation vector must have shape \(\.\.\., 3\)"):
        pose.rotvec_to_quat(np.zeros(4))
    with pytest.raises(DanoError, match=r"vector must have shape \(\.\.\., 3\)"):
        pose.rotate(np.array([1.0, 0, 0, 0]), np.zeros(4))
    with pytest.raises(DanoError, match="quaternions must be finite and non-zero, got 1 that are not"):
        pose.quat_to_matrix(np.array([[1.0, 0, 0, 0], [0.0, 0, 0, 0]]))
    with pytest.raises(DanoError, match="quaternions must be finite and non-zero"):
        pose.normalize_quat(np.array([np.nan, 0, 0, 1.0]))
    with pytest.raises(DanoError, match="at least 3 poses"):
        pose.velocity_from_poses(np.arange(2.0), np.tile([0, 0, 0, 1.0, 0, 0, 0], (2, 1)), degree=2)
    with pytest.raises(DanoError, match="increasing times"):
        pose.velocity_from_poses(np.zeros(3), np.tile([0, 0, 0, 1.0, 0, 0, 0], (3, 1)))


def _constant_motion(times, v, w, p0, q0):
    """Poses of a body moving at constant linear velocity v (world) and angular velocity w (body)."""
    t = times - times[0]
    p = p0 + t[:, None] * v
    q = pose.quat_multiply(q0, pose.rotvec_to_quat(t[:, None] * w))
    return np.c_[p, q]


@pytest.mark.parametrize("degree, n", [(1, 2), (1, 3), (1, 6), (2, 3), (2, 5)])
def test_velocity_from_poses_recovers_a_constant_velocity(degree, n):
    """Constant v (world) and ω (body frame, MuJoCo's qvel): recovered to rounding from any
    window, uniform or not, from a tilted start orientation."""
    rng = np.random.default_rng(degree * 10 + n)
    v, w = np.array([3.0, 0.6, -1.0]), np.array([2.0, -1.0, 6.0])
    q0 = pose.random_quats(rng)
    for times in (1.5 + np.arange(n) / 50.0, 1.5 + np.cumsum(rng.uniform(0.01, 0.03, n))):
        poses = _constant_motion(times, v, w, rng.normal(size=3), q0)
        np.testing.assert_allclose(pose.velocity_from_poses(times, poses, degree), np.r_[v, w], atol=1e-9)
    # batched windows
    times = np.stack([np.arange(n) / 50.0, 0.3 + np.arange(n) / 25.0])
    poses = np.stack([_constant_motion(t, v, w, np.zeros(3), q0) for t in times])
    np.testing.assert_allclose(pose.velocity_from_poses(times, poses, degree), np.tile(np.r_[v, w], (2, 1)), atol=1e-9)


def test_velocity_from_poses_at_an_offset_is_the_parabolas_slope_there():
    """A constant acceleration (linear, world frame; angular about a fixed body axis):
    the degree-2 slope ``at`` τ after the first pose is v + a·τ, before it (τ < 0) too."""
    t = 0.7 + np.arange(3) / 40.0
    v, a = np.array([1.2, -0.4, 2.0]), np.array([-3.4, 1.0, -9.81])
    w, alpha, axis = 0.8, -5.0, np.array([0.0, 0.6, 0.8])
    s = t - t[0]
    angle = w * s + 0.5 * alpha * s**2
    q = pose.quat_multiply(pose.random_quats(np.random.default_rng(2)), pose.rotvec_to_quat(angle[:, None] * axis))
    poses = np.c_[v * s[:, None] + 0.5 * a * s[:, None] ** 2, q]
    for tau in (0.0, -0.0125, -0.003, 0.01):
        np.testing.assert_allclose(pose.velocity_from_poses(t, poses, 2, at=tau),
                                   np.r_[v + a * tau, (w + alpha * tau) * axis], atol=1e-9)
    with pytest.raises(DanoError, match="finite time offset"):
        pose.velocity_from_poses(t, poses, 2, at=float("nan"))


def test_velocity_from_poses_is_what_sysid_and_tracking_use():
    """finite_difference_velocity (sysid) and initial_velocity (tracking) are the one function:
    the one-sided difference −(3x₀ − 4x₁ + x₂)/(2h) and the least-squares slope."""
    from dano.sysid import finite_difference_velocity
    from dano.sysid.problem import finite_difference_gain
    from dano.tracking import initial_velocity

    rng = np.random.default_rng(5)
    t = np.arange(6) / 30.0
    q = pose.quat_multiply(pose.random_quats(rng), pose.rotvec_to_quat(np.cumsum(rng.normal(size=(6, 3)) * 0.1, 0)))
    poses = np.c_[np.cumsum(rng.normal(size=(6, 3)) * 0.05, 0), q]
    h = t[1] - t[0]
    fd = finite_difference_velocity(t, poses)
    np.testing.assert_allclose(fd[:3], (-3 * poses[0, :3] + 4 * poses[1, :3] - poses[2, :3]) / (2 * h), atol=1e-12)
    r1, r2 = (Rotation.from_quat(poses[0, 3:], scalar_first=True).inv()
              * Rotation.from_quat(poses[1:3, 3:], scalar_first=True)).as_rotvec()
    np.testing.assert_allclose(fd[3:], (4 * r1 - r2) / (2 * h), atol=1e-12)
    for rho in (1.0, 0.25):  # half a simulation step of ρ·h earlier, and the stencil's noise gain
        stencil = np.array([-(3 + rho), 4 + 2 * rho, -(1 + rho)]) / (2 * h)
        np.testing.assert_allclose(finite_difference_velocity(t, poses, rho * h)[:3], stencil @ poses[:3, :3], atol=1e-12)
        np.testing.assert_allclose(finite_difference_gain(rho), np.linalg.norm(stencil) * h, rtol=1e-14)
    assert finite_difference_gain(0.0) == pytest.approx(np.sqrt(26) / 2, rel=1e-14)
    iv = initial_velocity(t, poses, frames=4)
    np.testing.assert_allclose(iv[:3], np.polyfit(t[:4], poses[:4, :3], 1)[0], atol=1e-12)
    np.testing.assert_allclose(iv, pose.velocity_from_poses(t[:4], poses[:4]), atol=0)

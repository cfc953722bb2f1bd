"""Scenes: MuJoCo models (composed with ``mujoco.MjSpec``) with DANO bodies and their
contact pairs, as JAX pytrees.

A DANO becomes a free body whose frame is the asset's body frame (object axes, origin at
the centre of mass): ``ipos = 0``, its mass and full inertia from the asset, its visual
mesh as a non-colliding geom (group 1). MuJoCo keeps handling contacts among its own
geoms; dano adds a contact pair between every DANO and every collidable plane, sphere,
capsule or box geom on another body (robot links included), and between every two DANOs
that both carry a queryable field. Pairs are grouped by (pair kind, contact model), and
each group is evaluated vmapped over its pairs.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from scipy.spatial import cKDTree

from .._compiled import HOST_ONLY
from .._mjx import mjx
from ..asset import DanoAsset
from ..contact import PAIR_KINDS, ContactParams, Samples, contact_model
from ..contact.samples import face_sample_count
from ..contact.surface import surface_points
from ..errors import DanoError
from ..fields.base import interior_density
from ..io.exporters import add_to_spec

PRIMITIVES = {
    mujoco.mjtGeom.mjGEOM_PLANE: "plane",
    mujoco.mjtGeom.mjGEOM_SPHERE: "sphere",
    mujoco.mjtGeom.mjGEOM_CAPSULE: "capsule",
    mujoco.mjtGeom.mjGEOM_BOX: "box",
}


@dataclass(frozen=True)
class DanoObject:
    """A DANO to place in a scene.

    name: body name; asset: the :class:`~dano.asset.DanoAsset`;
    pos: (3,) initial centre-of-mass position, world [m]; quat: (4,) initial
    orientation wxyz (object axes in the world); sample_radius: depth [m] over which a
    sample's occupancy rises from 0 (at the other body's surface) to 1 (default: the median
    distance between neighbouring samples); rgba: colour of the visual mesh.
    """

    name: str
    asset: DanoAsset
    pos: Sequence[float] = (0.0, 0.0, 0.0)
    quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0)
    sample_radius: float | None = None
    rgba: Sequence[float] = (0.85, 0.65, 0.45, 1.0)


@dataclass(frozen=True)
class Pair:
    """A DANO contact pair (static): kind (a registered pair kind: plane, sphere, capsule,
    box, dano); a: DANO index; geom: MuJoCo geom id (primitives) or -1; b: other DANO index
    or -1; body_a, body_b: MuJoCo body ids; name: "A/B"; model: its contact model."""

    kind: str
    a: int
    geom: int
    b: int
    body_a: int
    body_b: int
    name: str = dataclasses.field(metadata=HOST_ONLY)  # (a label: traces use the indices)
    model: Any


@dataclass(frozen=True)
class PairGroup:
    """Pairs of one kind and one contact model, evaluated together under ``jax.vmap``
    (static). index: the pairs' positions in the scene's pair list (and in the (P,)
    parameter arrays); a, geom, b, body_a, body_b: per pair, as in :class:`Pair`."""

    kind: str
    model: Any
    index: tuple[int, ...]
    a: tuple[int, ...]
    geom: tuple[int, ...]
    b: tuple[int, ...]
    body_a: tuple[int, ...]
    body_b: tuple[int, ...]


@dataclass(frozen=True, eq=False)
class SceneInfo:
    """Static facts of a scene (pytree metadata, compared by identity).

    What traced programs read, part of their key (:mod:`dano._compiled`): qpos_adr and
    dof_adr (D,) of each DANO's free joint, dano_bodies (D,) their MuJoCo body ids, pairs
    (their kinds, indices and contact models), the sizes nq, nv, nu and quaternion_slots
    ((qpos address of the quaternion, dof address of ω) of every free and ball joint). Host-side only (``HOST_ONLY``: left out of the key and
    hidden from traces, so that programs are shared by every object of the same structure,
    whatever its values and names): the MuJoCo C model (rendering, comparison, name lookups),
    the assets, the DANO and body names, the pairs' names and the scene's name."""

    mj_model: mujoco.MjModel = dataclasses.field(metadata=HOST_ONLY)
    assets: tuple[DanoAsset, ...] = dataclasses.field(metadata=HOST_ONLY)
    dano_names: tuple[str, ...] = dataclasses.field(metadata=HOST_ONLY)
    body_names: tuple[str, ...] = dataclasses.field(metadata=HOST_ONLY)
    qpos_adr: tuple[int, ...]
    dof_adr: tuple[int, ...]
    dano_bodies: tuple[int, ...]
    pairs: tuple[Pair, ...]
    nq: int
    nv: int
    nu: int
    quaternion_slots: tuple[tuple[int, int], ...]
    name: str = dataclasses.field(metadata=HOST_ONLY)  # (a label: programs of any name are shared)


#: per-DANO parameters of its own dynamics besides α (fields of :class:`SimParams`, one per axis)
INERTIAL_PARAMETERS = tuple(f"{f}_{a}" for f in ("com_offset", "second_moment_scale", "principal_axes")
                            for a in "xyz")


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SimParams:
    """Differentiable simulation parameters.

    contact: :class:`~dano.contact.ContactParams` with (P,) fields, one value per contact
    pair (in ``scene.pair_names`` order); alpha: (D,) mass scale α of each DANO (mass,
    inertia and sample weights scale together; the assets' own α by default).

    The object's own dynamics beyond α (paper §V-A: θ may include mass and inertia; the
    field's estimates are guesses to refine from motion), each None for the asset's own:
    com_offset: (D, 3) centre of mass relative to the asset's estimate, in the DANO's body
    frame [m]; the body frame, its samples and its pose (qpos) stay with the geometry, so the
    samples move with the centre of mass consistently. second_moment_scale: (D, 3) factors
    on the principal second moments of mass Σᵢ = ∫xᵢ² dm (the moments are
    I_x = α(Σ_y + Σ_z), ... with Σ per unit α; any factors ≥ 0 give a physically valid inertia, triangle
    inequalities included; 1: the asset's). principal_axes: (D, 3) rotation vector [rad]
    of the principal axes relative to the asset's (body frame).
    """

    contact: ContactParams
    alpha: jax.Array
    com_offset: jax.Array | None = None
    second_moment_scale: jax.Array | None = None
    principal_axes: jax.Array | None = None

    def replace(self, **changes) -> "SimParams":
        """A copy with the given fields replaced (trace-safe; no validation)."""
        return dataclasses.replace(self, **changes)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Scene:
    """A composed scene, a JAX pytree: arrays are leaves (differentiable, vmappable), the
    structure is static metadata.

    model: the MJX model (mjx.Model); samples: contact samples of the D DANOs
    (:class:`~dano.contact.Samples`); fields: (D,) each DANO's object-frame density field
    or None; base_mass: (D,) mass per unit α [kg/α]; base_inertia: (D, 3) principal
    inertia per unit α [kg m²/α]. Static: groups (pair groups), dt (time step [s]),
    has_constraints (whether MuJoCo's own constraint solver has anything to do), info
    (:class:`SceneInfo`). ``replace(model=...)`` swaps arrays, e.g. to vary a geom's pose.
    """

    model: Any
    samples: Samples
    fields: tuple
    base_mass: jax.Array
    base_inertia: jax.Array
    groups: tuple[PairGroup, ...] = dataclasses.field(metadata=dict(static=True))
    dt: float = dataclasses.field(metadata=dict(static=True))
    has_constraints: bool = dataclasses.field(metadata=dict(static=True))
    info: SceneInfo = dataclasses.field(metadata=dict(static=True))

    def replace(self, **changes) -> "Scene":
        """A copy with the given fields replaced."""
        return dataclasses.replace(self, **changes)

    # -- host-side facts
    @property
    def mj_model(self) -> mujoco.MjModel:
        return self.info.mj_model

    @property
    def assets(self) -> tuple[DanoAsset, ...]:
        return self.info.assets

    @property
    def dano_names(self) -> tuple[str, ...]:
        return self.info.dano_names

    @property
    def body_names(self) -> tuple[str, ...]:
        return self.info.body_names

    @property
    def qpos_adr(self) -> tuple[int, ...]:
        """(D,) index of each DANO's free joint in qpos."""
        return self.info.qpos_adr

    @property
    def dof_adr(self) -> tuple[int, ...]:
        """(D,) index of each DANO's free joint in qvel."""
        return self.info.dof_adr

    @property
    def name(self) -> str:
        return self.info.name

    @property
    def pairs(self) -> tuple[Pair, ...]:
        return self.info.pairs

    @property
    def pair_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.info.pairs)

    @property
    def qpos0(self) -> np.ndarray:
        """(nq,) the model's reference configuration (a copy of ``mj_model.qpos0``)."""
        return np.array(self.mj_model.qpos0)

    @property
    def nq(self) -> int:
        return self.info.nq

    @property
    def nv(self) -> int:
        return self.info.nv

    @property
    def nu(self) -> int:
        return self.info.nu

    @property
    def dtype(self):
        """The floating-point type of the scene's arrays."""
        return self.base_mass.dtype

    def astype(self, dtype) -> "Scene":
        """The scene with every floating-point array converted to ``dtype`` (float32 for
        batched/GPU work, float64 for gradient checks and identification). Raises
        DanoError for float64 while JAX's 64-bit mode is off."""
        dtype = jnp.dtype(dtype)
        _check_dtype(dtype)
        return cast_floats(self, dtype)

    def default_params(self, **contact_overrides) -> SimParams:
        """The paper's contact parameters for every pair (overrides by name, scalar or
        (P,)) and each asset's own α, in the scene's dtype. Raises DanoError for unknown
        or invalid values."""
        unknown = set(contact_overrides) - set(ContactParams.names())
        if unknown:
            raise DanoError(f"unknown contact parameter(s) {sorted(unknown)}; known: {', '.join(ContactParams.names())}")
        cp = ContactParams(**contact_overrides).validate()
        return SimParams(cp.broadcast(len(self.pairs), self.dtype),
                         jax.device_put(np.asarray([a.alpha for a in self.assets], dtype=np.dtype(self.dtype)
                                                   ).reshape(len(self.assets))))

    def set_param(self, params: SimParams, name: str, value, target: str | int | None = None) -> SimParams:
        """A copy of ``params`` with contact parameter ``name`` (or ``"alpha"``, or one of
        :data:`INERTIAL_PARAMETERS`, e.g. ``"com_offset_x"``) set to ``value`` for every pair
        (every DANO for alpha and the inertial ones), or only for pair/DANO ``target`` (a
        name, or its index: :meth:`target_index`).
        A convenience over ``params.replace``: differentiable in ``value`` (usable under
        ``jax.jacfwd``); concrete values are validated. Raises DanoError for unknown names
        or targets and invalid values."""
        concrete = not isinstance(value, jax.core.Tracer)
        if concrete and not np.all(np.isfinite(np.asarray(value, dtype=np.float64))):
            raise DanoError(f"parameter {name} must be finite, got {value}")
        if name not in ("alpha",) + INERTIAL_PARAMETERS + ContactParams.names():
            raise DanoError(f"unknown parameter {name!r}; known: alpha, {', '.join(INERTIAL_PARAMETERS)}, "
                            f"{', '.join(ContactParams.names())}")
        index = self.target_index(name, target)
        idx = slice(None) if index is None else index
        if name == "alpha":
            new = params.replace(alpha=jnp.asarray(params.alpha).at[idx].set(value))
        elif name in INERTIAL_PARAMETERS:
            field_name, axis = name[:-2], "xyz".index(name[-1])
            current = getattr(params, field_name)
            if current is None:  # the asset's own: zero offsets and rotations, unit scales
                fill = 1.0 if field_name == "second_moment_scale" else 0.0
                current = jnp.full((len(self.qpos_adr), 3), fill, dtype=jnp.asarray(params.alpha).dtype)
            new = params.replace(**{field_name: jnp.asarray(current).at[idx, axis].set(value)})
        else:
            arr = jnp.asarray(getattr(params.contact, name)).at[idx].set(value)
            new = params.replace(contact=params.contact.replace(**{name: arr}))
        if concrete:
            new.contact.validate()
            if np.any(np.asarray(new.alpha) <= 0):
                raise DanoError(f"alpha must be positive, got {value}")
            if new.second_moment_scale is not None and np.any(np.asarray(new.second_moment_scale) < 0):
                raise DanoError(f"second moment scales must be >= 0 (a physical inertia), got {value}")
        return new

    def target_index(self, name: str, target: str | int | None) -> int | None:
        """Where parameter ``name`` of ``target`` sits in its (D,) array (``alpha`` and the
        inertial parameters: the DANO's index) or (P,) array (contact parameters: the pair's):
        None for every DANO or pair; an int is taken as that index (traced programs pass
        indices, so that they read no names). Raises DanoError for an unknown name or an
        index out of range."""
        if target is None:
            return None
        contact = name in ContactParams.names()
        if isinstance(target, (int, np.integer)) and not isinstance(target, bool):
            count = len(self.pairs) if contact else len(self.qpos_adr)
            if not 0 <= int(target) < count:
                raise DanoError(f"{'contact pair' if contact else 'DANO'} index {int(target)} out of range: "
                                f"the scene has {count}")
            return int(target)
        if contact:
            if target not in self.pair_names:
                raise DanoError(f"no contact pair {target!r}; pairs: {list(self.pair_names)}")
            return self.pair_names.index(target)
        return self.dano_index(target)

    def dano_index(self, name: str) -> int:
        """Index of DANO ``name`` in ``dano_names`` (and in ``params.alpha``). Raises
        DanoError for an unknown name."""
        try:
            return self.dano_names.index(name)
        except ValueError:
            raise DanoError(f"no DANO named {name!r}; the scene has {list(self.dano_names)}") from None


def _is_float(x) -> bool:
    return hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.floating)


def cast_floats(tree, dtype):
    """``tree`` (any pytree: a Scene, SimParams, MJX Model or Data) with every floating-point
    array converted to ``dtype``; other leaves as they are."""
    return jax.tree_util.tree_map(lambda x: x.astype(dtype) if _is_float(x) else x, tree)


def _check_dtype(dtype) -> None:
    if dtype not in (jnp.dtype(jnp.float32), jnp.dtype(jnp.float64)):
        raise DanoError(f"dtype must be float32 or float64, got {dtype}")
    if dtype == jnp.float64 and not jax.config.jax_enable_x64:
        raise DanoError("float64 needs JAX's 64-bit mode: call dano.enable_float64() (or run inside "
                        "`with jax.enable_x64(True):`) before composing the scene")


def default_sample_radius(asset: DanoAsset) -> float:
    """The median distance from a boundary sample to its nearest distinct neighbour [m]."""
    pts = np.unique(asset.points, axis=0)
    if len(pts) < 2:
        return 1e-3
    d, _ = cKDTree(pts).query(pts, k=2)
    return float(np.median(d[:, 1]))


def add_ground(spec: mujoco.MjSpec, name: str = "ground") -> None:
    """Add a ground plane z = 0 (checkered, collidable) and, if the model has none, a light."""
    spec.add_texture(name=f"{name}_checker", type=mujoco.mjtTexture.mjTEXTURE_2D,
                     builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, rgb1=[0.82, 0.84, 0.87], rgb2=[0.7, 0.72, 0.76],
                     width=256, height=256)
    mat = spec.add_material(name=f"{name}_material", texrepeat=[8, 8], texuniform=True)
    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = f"{name}_checker"
    spec.worldbody.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], material=f"{name}_material")
    if not any(True for _ in spec.lights):
        spec.worldbody.add_light(name="sun", pos=[0, 0, 6], dir=[0, 0, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)


#: time step [s] of a scene whose MJCF states none (dano's stiff contact is designed for it)
DEFAULT_DT = 0.01
#: MuJoCo's own time step where a model states none [s]
MUJOCO_DEFAULT_TIMESTEP = 0.002


def stated_timestep(base) -> float | None:
    """The time step [s] an MJCF states in its ``<option timestep="..."/>``: ``base`` a path
    or an MJCF string (the last such option in the file itself; included files are not
    read), or an MjSpec (its ``option.timestep`` where it is not MuJoCo's default 0.002,
    which a spec cannot tell from one never set: give ``dt``). None where none is stated, for
    a URDF without one, or a file that does not parse (:func:`compose` reports that)."""
    import xml.etree.ElementTree as ET

    if isinstance(base, mujoco.MjSpec):
        dt = float(base.option.timestep)
        return None if dt == MUJOCO_DEFAULT_TIMESTEP else dt
    if base is None:
        return None
    try:
        text = str(base).lstrip()
        root = ET.fromstring(text) if isinstance(base, str) and text.startswith("<") else ET.parse(base).getroot()
        options = [o for o in root.iter("option") if "timestep" in o.attrib]
        return float(options[-1].attrib["timestep"]) if options else None
    except (ET.ParseError, OSError, ValueError):
        return None


def _load_spec(base) -> mujoco.MjSpec:
    if base is None:
        return mujoco.MjSpec()
    if isinstance(base, mujoco.MjSpec):
        return base.copy()  # the caller's spec is not modified
    try:
        if isinstance(base, Path) or (isinstance(base, str) and not base.lstrip().startswith("<")):
            path = Path(base)
            if not path.is_file():
                raise DanoError(f"{path}: no such MJCF file")
            return mujoco.MjSpec.from_file(str(path))
        return mujoco.MjSpec.from_string(base)
    except DanoError:
        raise
    except Exception as exc:
        raise DanoError(f"{base if not str(base).lstrip().startswith('<') else 'MJCF string'}: cannot load MJCF ({exc})") from exc


def _add_dano(spec: mujoco.MjSpec, obj: DanoObject) -> None:
    add_to_spec(spec, obj.asset, obj.name, pos=obj.pos, quat=obj.quat, rgba=obj.rgba)


def merge_duplicate_samples(points: np.ndarray, normals: np.ndarray, weights: np.ndarray):
    """Merge samples at identical positions, adding their weights (the paper bunny's 5000
    particles hold 2926 distinct ones). Every contact sum Σ w_i f(x_i) is unchanged, and the
    per-step work shrinks. Duplicates keep the normal of their first occurrence."""
    unique, first, inverse = np.unique(points, axis=0, return_index=True, return_inverse=True)
    merged = np.bincount(inverse.ravel(), weights=weights, minlength=len(unique))
    return unique, normals[first], merged


def contact_samples(obj: DanoObject) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """Contact points (N, 3) body frame [m] (on the surface when the DANO has a field; see
    :mod:`dano.contact.surface`), normals (N, 3), weights per unit α (N,) [kg/α], the sample
    radius [m] and the interior density of the field (1 without one)."""
    a = obj.asset
    r = obj.sample_radius if obj.sample_radius is not None else default_sample_radius(a)
    if not np.isfinite(r) or r <= 0:
        raise DanoError(f"{obj.name}: sample_radius must be positive, got {r}")
    normals = np.nan_to_num(a.normals)
    points = a.points
    rho = 1.0
    if a.field is not None:
        rho = interior_density(a.field)
        obj_pts, _ = surface_points(a.field, points + a.center_of_mass, normals, 0.5 * rho,
                                    max_shift=max(4.0 * r, 0.02 * float(np.ptp(points, axis=0).max())))
        points = obj_pts - a.center_of_mass
    points, normals, w = merge_duplicate_samples(points, normals, a.weights / a.alpha)
    return points, normals, w, float(r), rho


#: radius [m] of the sphere that stands for each DANO's visual geom in the model MJX simulates
PHYSICS_VISUAL_RADIUS = 0.01


def _physics_model(spec: mujoco.MjSpec, names: Sequence[str], mj_model: mujoco.MjModel) -> mujoco.MjModel:
    """The MuJoCo model that MJX simulates: ``spec``'s, with each DANO's visual geom (a mesh or
    an ellipsoid that collides with nothing and has no mass: the inertial is explicit) a
    sphere of :data:`PHYSICS_VISUAL_RADIUS` at the body's origin, its mesh left out, and the
    DANO's body, joint and geom named by its index (``dano:0``, ``dano:0:free``, ...). MJX
    keeps mesh data, geom bounds and names as static (trace-time) facts of its model, so a
    visual mesh or a name made every object's programs its own; without them, every object
    of the same structure shares them (:mod:`dano._compiled`). Bodies, joints, geoms (their
    ids included) and masses are ``mj_model``'s, which keeps the meshes and names for
    rendering and lookups."""
    phys = spec.copy()
    for k, name in enumerate(names):
        phys.body(name).name = f"dano:{k}"
        phys.joint(f"{name}_free").name = f"dano:{k}:free"
        geom = phys.geom(f"{name}_visual")
        if geom is None:  # pragma: no cover - add_to_spec always adds it
            continue
        geom.name = f"dano:{k}:visual"
        mesh = phys.mesh(geom.meshname) if geom.meshname else None
        geom.type, geom.meshname = mujoco.mjtGeom.mjGEOM_SPHERE, ""
        geom.size, geom.pos, geom.quat = [PHYSICS_VISUAL_RADIUS, 0, 0], [0, 0, 0], [1, 0, 0, 0]
        if mesh is not None:
            phys.delete(mesh)
    try:
        model = phys.compile()
    except Exception as exc:  # (a base model naming its own parts dano:0 ...)
        raise DanoError(f"the scene's model without its DANOs' visual meshes does not compile: {exc}") from exc
    same = (model.nbody, model.njnt, model.ngeom, model.nq, model.nv, model.nu) == (
        mj_model.nbody, mj_model.njnt, mj_model.ngeom, mj_model.nq, mj_model.nv, mj_model.nu)
    if not same or not np.array_equal(model.body_mass, mj_model.body_mass):  # pragma: no cover - a guard
        raise DanoError("internal: the physics model of the scene differs from its MuJoCo model")
    return model


def _put_model(m: mujoco.MjModel):
    """``mjx.put_model(m)`` on this process's first device (MJX's default, jax.devices()[0],
    belongs to process 0 in a multi-process run). In a model without height fields, MJX's
    static copy of every geom's bounding radius (``_impl.geom_rbound_hfield``, read only to
    size height-field collisions) is zeroed: it made every geom size (a pusher sized to its
    object) a trace-time fact, so each object compiled its own programs; the bounds MJX
    uses otherwise (``geom_rbound``) are arrays."""
    mx = mjx.put_model(m, device=jax.local_devices()[0])
    impl = getattr(mx, "_impl", None)
    if m.nhfield == 0 and impl is not None and hasattr(impl, "geom_rbound_hfield"):
        mx = mx.replace(_impl=impl.replace(geom_rbound_hfield=np.zeros_like(np.asarray(impl.geom_rbound_hfield))))
    return mx


def quaternion_slots(m: mujoco.MjModel) -> tuple[tuple[int, int], ...]:
    """(qpos address of the quaternion, dof address of ω) of every free and ball joint of ``m``."""
    slots = []
    for j in range(m.njnt):
        kind = int(m.jnt_type[j])
        if kind == int(mujoco.mjtJoint.mjJNT_FREE):
            slots.append((int(m.jnt_qposadr[j]) + 3, int(m.jnt_dofadr[j]) + 3))
        elif kind == int(mujoco.mjtJoint.mjJNT_BALL):
            slots.append((int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])))
    return tuple(slots)


def _could_have_constraints(m: mujoco.MjModel) -> bool:
    """Whether MuJoCo's constraint solver can have rows: equalities, friction loss, joint or
    tendon limits, or geom pairs that may collide (contype/conaffinity or explicit pairs;
    MuJoCo never collides two geoms welded to one body, e.g. the floor and a jointless wall
    body: a user's scene with such a wall ran MJX's solver, a ``while_loop`` that reverse mode
    cannot differentiate, for no rows)."""
    if m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONSTRAINT:
        return False
    if m.neq or m.npair or np.any(m.dof_frictionloss > 0) or np.any(m.jnt_limited) or (m.ntendon and (
            np.any(m.tendon_limited) or np.any(m.tendon_frictionloss > 0))):
        return True
    if m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT:
        return False
    ct, ca, body = m.geom_contype, m.geom_conaffinity, m.body_weldid[m.geom_bodyid]
    for i in range(m.ngeom):
        for j in range(i + 1, m.ngeom):
            if body[i] != body[j] and ((ct[i] & ca[j]) or (ct[j] & ca[i])):
                return True
    return False


#: pair kinds whose other body can be flat (a plane, a box's face, another DANO's face), so that a
#: face of the object can rest on it whole (a box only where its face is as large: :func:`_sized_models`)
FLAT_PAIR_KINDS = ("plane", "box", "dano")


def _sized_models(pairs: Sequence[Pair], data: Sequence, geom_size: np.ndarray) -> list[Pair]:
    """``pairs`` with each contact model that has ``sized_for`` (the per-sample model's room
    for samples) replaced by ``model.sized_for(count)``: count the most samples that can rest
    on the other body at once (:func:`~dano.contact.samples.face_sample_count` of A's
    contact samples, plus B's for a DANO–DANO pair) for :data:`FLAT_PAIR_KINDS`, None for
    the others (spheres, capsules) and for a box whose second-longest side is shorter than
    the object's (a finger pad: it holds a patch of the face, not all of it). ``data``: per
    DANO its :func:`contact_samples`; geom_size: (ngeom, 3) MuJoCo's geom sizes (a box's half
    sides) [m]."""
    faces: dict[int, int] = {}

    def face(i: int) -> int:
        if i not in faces:
            faces[i] = face_sample_count(data[i][0], data[i][3])
        return faces[i]

    def holds_a_face(p: Pair) -> bool:
        if p.kind != "box":
            return p.kind in FLAT_PAIR_KINDS
        sides = np.sort(2 * np.asarray(geom_size[p.geom], dtype=np.float64))[::-1]
        extent = np.sort(np.ptp(np.asarray(data[p.a][0]), axis=0))[::-1]
        return bool(sides[1] >= extent[1])

    out = []
    for p in pairs:
        fit = getattr(p.model, "sized_for", None)
        if fit is not None:
            count = (face(p.a) + (face(p.b) if p.kind == "dano" else 0)) if holds_a_face(p) else None
            p = dataclasses.replace(p, model=fit(count))
        out.append(p)
    return out


def _pair_groups(pairs: Sequence[Pair], fields: Sequence) -> tuple[PairGroup, ...]:
    """Group pairs by (kind, model); DANO-DANO pairs also by the structure of both fields
    (they are stacked for vmap)."""
    keys: dict = {}
    for i, p in enumerate(pairs):
        key = (p.kind, p.model)
        if p.kind == "dano":
            sig = lambda f: (jax.tree_util.tree_structure(f),  # noqa: E731
                             tuple(np.shape(x) for x in jax.tree_util.tree_leaves(f)))
            key += (sig(fields[p.a]), sig(fields[p.b]))
        keys.setdefault(key, []).append(i)
    groups = []
    for key, idx in keys.items():
        ps = [pairs[i] for i in idx]
        groups.append(PairGroup(key[0], key[1], tuple(idx), tuple(p.a for p in ps), tuple(p.geom for p in ps),
                                tuple(p.b for p in ps), tuple(p.body_a for p in ps), tuple(p.body_b for p in ps)))
    return tuple(groups)


def compose(
    objects: Sequence[DanoObject],
    base: mujoco.MjSpec | str | Path | None = None,
    *,
    dt: float | None = None,
    ground: bool | None = None,
    contacts: Sequence[tuple[str, str]] | None = None,
    gravity: Sequence[float] = (0.0, 0.0, -9.81),
    contact_model: Any = "centroid",
    pair_contact_models: Mapping[str, Any] | None = None,
    dtype=None,
    name: str = "scene",
) -> Scene:
    """Build a scene from DANOs and a MuJoCo model.

    objects: the DANOs; base: an MJCF or URDF path, MJCF string or MjSpec (robots,
    primitives; a given MjSpec is copied, not modified), or None for an empty world;
    dt: time step [s]; default: the one ``base`` states in its ``<option timestep>``
    (:func:`stated_timestep`), else :data:`DEFAULT_DT` (0.01 s); ground: add a ground plane
    at z = 0 named "ground" (default: when ``base`` is None); contacts: restrict the DANO
    pairs to these (name, name) pairs of DANO and geom/DANO names (default: all); gravity:
    (3,) [m/s²];
    contact_model: "centroid" (the paper's, default), "per_sample", or a contact model
    instance (e.g. ``Centroid(drag="overlap")``), for every pair; pair_contact_models:
    {pair name "A/B": model} overrides for single pairs; dtype: float32 or float64 (default:
    JAX's default float type, float64 only in 64-bit mode).
    Raises DanoError if the MJCF does not load or compile, for duplicate or unknown
    names, a non-positive dt, unknown contact models or pairs, a requested DANO-DANO pair
    without a queryable field, or float64 without JAX's 64-bit mode.
    """
    if dt is None:
        dt = stated_timestep(base)
        if dt is None:
            dt = DEFAULT_DT
        elif not np.isfinite(dt) or dt <= 0:
            where = str(base) if isinstance(base, (str, Path)) and not str(base).lstrip().startswith("<") else "the MJCF"
            raise DanoError(f"{where}: <option timestep> must be positive, got {dt}; or give dt")
    if not np.isfinite(dt) or dt <= 0:
        raise DanoError(f"time step dt must be positive, got {dt}")
    if dtype is not None:
        _check_dtype(jnp.dtype(dtype))
    names = [o.name for o in objects]
    if len(set(names)) != len(names):
        raise DanoError(f"DANO names must be unique, got {names}")
    default_model = contact_model_or_error(contact_model)
    spec = _load_spec(base)
    if ground if ground is not None else base is None:
        add_ground(spec)
    for o in objects:
        _add_dano(spec, o)
    spec.option.timestep = dt
    spec.option.gravity = list(map(float, gravity))
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_EULERDAMP  # the step integrates damping itself
    try:
        mj_model = spec.compile()
    except Exception as exc:
        where = f"{base}: " if isinstance(base, (str, Path)) and not str(base).lstrip().startswith("<") else ""
        raise DanoError(f"{where}the scene's MuJoCo model does not compile: {exc}") from exc

    physics_model = _physics_model(spec, names, mj_model)
    body_ids = [mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_BODY, n) for n in names]
    pairs = []
    for i, o in enumerate(objects):
        for g in range(mj_model.ngeom):
            kind = PRIMITIVES.get(int(mj_model.geom_type[g]))
            if kind is None or int(mj_model.geom_bodyid[g]) == body_ids[i]:
                continue
            if mj_model.geom_contype[g] == 0 and mj_model.geom_conaffinity[g] == 0:
                continue
            gname = mujoco.mj_id2name(mj_model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}"
            pairs.append(Pair(kind, i, g, -1, body_ids[i], int(mj_model.geom_bodyid[g]), f"{o.name}/{gname}",
                              default_model))
        for j in range(i + 1, len(objects)):
            if o.asset.field is not None and objects[j].asset.field is not None:
                pairs.append(Pair("dano", i, -1, j, body_ids[i], body_ids[j], f"{o.name}/{objects[j].name}",
                                  default_model))
    if contacts is not None:
        wanted = {frozenset(c) for c in contacts}
        chosen = [p for p in pairs if frozenset(p.name.split("/")) in wanted]
        found = {frozenset(p.name.split("/")) for p in chosen}
        missing = wanted - found
        if missing:
            raise DanoError(
                f"contact pair(s) {[sorted(m) for m in missing]} not possible: each needs a DANO and a collidable "
                "plane/sphere/capsule/box geom, or two DANOs with queryable fields"
            )
        pairs = chosen
    overrides = dict(pair_contact_models or {})
    unknown = set(overrides) - {p.name for p in pairs}
    if unknown:
        raise DanoError(f"pair_contact_models names unknown pair(s) {sorted(unknown)}; pairs: {[p.name for p in pairs]}")
    pairs = [dataclasses.replace(p, model=contact_model_or_error(overrides[p.name])) if p.name in overrides else p
             for p in pairs]
    missing_kinds = {p.kind for p in pairs} - set(PAIR_KINDS)
    if missing_kinds:  # pragma: no cover - all built-in kinds are registered on import
        raise DanoError(f"no contact pair kind registered for {sorted(missing_kinds)}")

    data = [contact_samples(o) for o in objects]
    pairs = _sized_models(pairs, data, mj_model.geom_size)
    # the fields that DANO-DANO pairs query (the others stay out of the scene's arrays, so that
    # objects of the same structure share compiled programs whatever their fields' grids)
    queried = {i for p in pairs if p.kind == "dano" for i in (p.a, p.b)}
    boxes = [o.asset.field.bounds() if i in queried else None for i, o in enumerate(objects)]
    samples = Samples.stack([d[0] for d in data], [d[1] for d in data], [d[2] for d in data],
                            [d[3] for d in data], [o.asset.center_of_mass for o in objects], [d[4] for d in data],
                            boxes)
    fields = tuple(o.asset.field if i in queried else None for i, o in enumerate(objects))
    base_mass = np.array([mj_model.body_mass[b] / o.asset.alpha for b, o in zip(body_ids, objects)])
    base_inertia = np.array([mj_model.body_inertia[b] / o.asset.alpha for b, o in zip(body_ids, objects)])
    jnt = [mj_model.body_jntadr[b] for b in body_ids]
    info = SceneInfo(
        mj_model=mj_model,
        assets=tuple(o.asset for o in objects),
        dano_names=tuple(names),
        body_names=tuple(mujoco.mj_id2name(mj_model, mujoco.mjtObj.mjOBJ_BODY, b) or "" for b in range(mj_model.nbody)),
        qpos_adr=tuple(int(mj_model.jnt_qposadr[j]) for j in jnt),
        dof_adr=tuple(int(mj_model.jnt_dofadr[j]) for j in jnt),
        dano_bodies=tuple(int(b) for b in body_ids),
        pairs=tuple(pairs),
        nq=int(mj_model.nq),
        nv=int(mj_model.nv),
        nu=int(mj_model.nu),
        quaternion_slots=quaternion_slots(mj_model),
        name=name,
    )
    scene = Scene(model=_put_model(physics_model), samples=samples, fields=fields,
                  base_mass=jax.device_put(np.asarray(base_mass).reshape(len(objects))),
                  base_inertia=jax.device_put(np.asarray(base_inertia).reshape(len(objects), 3)),
                  groups=_pair_groups(pairs, fields), dt=float(dt),
                  has_constraints=_could_have_constraints(mj_model), info=info)
    return scene.astype(dtype) if dtype is not None else scene


def contact_model_or_error(spec, friction_steepness: float | None = None):
    """:func:`dano.contact.contact_model`, re-raised with the option's name."""
    try:
        return contact_model(spec, friction_steepness)
    except DanoError as exc:
        raise DanoError(f"contact_model: {exc}") from None

"""Scenes: MuJoCo models (composed with ``mujoco.MjSpec``) with DANO bodies and the
list of DANO contact pairs.

A DANO becomes a free body whose frame is the asset's body frame (object axes,
origin at the centre of mass): ``ipos = 0``, its mass and full inertia from the
asset, its visual mesh as a non-colliding geom (group 1). MuJoCo keeps handling
contacts among its own geoms; dano adds a contact pair between every DANO and every
collidable plane, sphere, capsule or box geom on another body (robot links
included), and between every two DANOs that both carry a queryable field.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from .._mjx import mjx
from scipy.spatial import cKDTree

from ..asset import DanoAsset
from ..contact.params import ContactParams
from ..errors import DanoError
from ..fields import BoxField, SdfGridField, SphereField, TransformedField, VoxelField

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
    orientation wxyz (object axes in the world); sample_radius: radius [m] of the
    blob each boundary sample stands for in contact (default: half the median
    distance between neighbouring samples); rgba: colour of the visual mesh.
    """

    name: str
    asset: DanoAsset
    pos: Sequence[float] = (0.0, 0.0, 0.0)
    quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0)
    sample_radius: float | None = None
    rgba: Sequence[float] = (0.85, 0.65, 0.45, 1.0)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class DanoBody:
    """Device-side contact data of one DANO (body frame = object axes, origin at CoM).

    points, normals: (3, N); weights: (N,) per unit mass scale α [kg/α];
    wp: (4, N) = [weights·points; weights]; sample_radius [m]; com: (3,) object-frame
    centre of mass [m]; rho_ref: density of full occupancy; field: object-frame
    density field or None.
    """

    points: jax.Array
    normals: jax.Array
    weights: jax.Array
    wp: jax.Array
    sample_radius: jax.Array
    com: jax.Array
    rho_ref: jax.Array
    field: Any = None


@dataclass(frozen=True)
class Pair:
    """A DANO contact pair (static): kind in plane/sphere/capsule/box/dano; a: DANO
    index; geom: MuJoCo geom id (primitives) or -1; b: other DANO index or -1;
    body_a, body_b: MuJoCo body ids; name: "A/B"."""

    kind: str
    a: int
    geom: int
    b: int
    body_a: int
    body_b: int
    name: str


@dataclass(frozen=True)
class SceneStatic:
    """Hashable description used as a static argument of the jitted functions."""

    pairs: tuple[Pair, ...]
    dano_bodies: tuple[int, ...]
    dt: float


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SceneArrays:
    """Device arrays of a scene: the MJX model and the DANO bodies; base_mass (D,) and
    base_inertia (D, 3) are the DANOs' mass and principal inertia per unit α."""

    model: Any
    danos: tuple
    base_mass: jax.Array
    base_inertia: jax.Array


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SimParams:
    """Differentiable simulation parameters.

    contact: :class:`ContactParams` with (P,) fields, one value per contact pair;
    alpha: (D,) mass scale α of each DANO (mass, inertia and sample weights scale
    together; the assets' own α by default).
    """

    contact: ContactParams
    alpha: jax.Array


@dataclass(frozen=True)
class Scene:
    """A composed scene: the MuJoCo C model (for rendering and comparison), its MJX
    counterpart, DANO contact data and names.

    dano_names (D,), pair_names (P,), body_names (nbody,); qpos_adr/dof_adr: (D,)
    index of each DANO's free joint in qpos / qvel; dt: time step [s].
    """

    mj_model: mujoco.MjModel
    static: SceneStatic
    arrays: SceneArrays
    dano_names: tuple[str, ...]
    assets: tuple[DanoAsset, ...]
    body_names: tuple[str, ...]
    qpos_adr: tuple[int, ...]
    dof_adr: tuple[int, ...]
    name: str = "scene"

    @property
    def qpos0(self) -> np.ndarray:
        """(nq,) the model's reference configuration (a copy of ``mj_model.qpos0``)."""
        return np.array(self.mj_model.qpos0)

    @property
    def pair_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.static.pairs)

    @property
    def dt(self) -> float:
        return self.static.dt

    @property
    def nq(self) -> int:
        return int(self.mj_model.nq)

    @property
    def nv(self) -> int:
        return int(self.mj_model.nv)

    @property
    def nu(self) -> int:
        return int(self.mj_model.nu)

    def default_params(self, **contact_overrides) -> SimParams:
        """The paper's contact parameters for every pair (overrides by name, scalar or
        (P,)) and each asset's own α. Raises DanoError for unknown or invalid values."""
        unknown = set(contact_overrides) - set(ContactParams.names())
        if unknown:
            raise DanoError(f"unknown contact parameter(s) {sorted(unknown)}; known: {', '.join(ContactParams.names())}")
        cp = dataclasses.replace(ContactParams(), **contact_overrides).validate()
        return SimParams(cp.broadcast(len(self.static.pairs)),
                         jnp.asarray([a.alpha for a in self.assets], dtype=jnp.float64))

    def set_param(self, params: SimParams, name: str, value, target: str | None = None) -> SimParams:
        """A copy of ``params`` with contact parameter ``name`` (or ``"alpha"``) set to
        ``value`` for every pair (every DANO for alpha), or only for pair/DANO ``target``.
        Differentiable in ``value`` (usable under ``jax.jacfwd``); concrete values are
        validated. Raises DanoError for unknown names or targets and invalid values."""
        concrete = not isinstance(value, jax.core.Tracer)
        if concrete and not np.isfinite(value):
            raise DanoError(f"parameter {name} must be finite, got {value}")
        if name == "alpha":
            idx = slice(None) if target is None else self.dano_index(target)
            new = SimParams(params.contact, jnp.asarray(params.alpha).at[idx].set(value))
        elif name in ContactParams.names():
            if target is None:
                idx = slice(None)
            elif target in self.pair_names:
                idx = self.pair_names.index(target)
            else:
                raise DanoError(f"no contact pair {target!r}; pairs: {list(self.pair_names)}")
            arr = jnp.asarray(getattr(params.contact, name)).at[idx].set(value)
            new = SimParams(dataclasses.replace(params.contact, **{name: arr}), params.alpha)
        else:
            raise DanoError(f"unknown parameter {name!r}; known: alpha, {', '.join(ContactParams.names())}")
        if concrete:
            new.contact.validate()
            if np.any(np.asarray(new.alpha) <= 0):
                raise DanoError(f"alpha must be positive, got {value}")
        return new

    def dano_index(self, name: str) -> int:
        try:
            return self.dano_names.index(name)
        except ValueError:
            raise DanoError(f"no DANO named {name!r}; the scene has {list(self.dano_names)}") from None


def reference_density(fld) -> float:
    """Density of full occupancy of a field (its interior value)."""
    if isinstance(fld, (SphereField, BoxField, SdfGridField)):
        return float(fld.density_scale)
    if isinstance(fld, VoxelField):
        return float(np.max(np.asarray(fld.values)))
    if isinstance(fld, TransformedField):
        return reference_density(fld.base)
    raise DanoError(f"cannot tell the interior density of a {type(fld).__name__}")


def default_sample_radius(asset: DanoAsset) -> float:
    """Half the median distance from a boundary sample to its nearest distinct neighbour [m]."""
    pts = np.unique(asset.points, axis=0)
    if len(pts) < 2:
        return 1e-3
    d, _ = cKDTree(pts).query(pts, k=2)
    return 0.5 * float(np.median(d[:, 1]))


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
    a = obj.asset
    q = np.asarray(obj.quat, dtype=np.float64)
    if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-12:
        raise DanoError(f"{obj.name}: quat must be a non-zero wxyz quaternion, got {list(obj.quat)}")
    body = spec.worldbody.add_body(name=obj.name, pos=list(map(float, obj.pos)), quat=list(q / np.linalg.norm(q)))
    body.add_freejoint(name=f"{obj.name}_free")
    J = a.inertia
    body.mass = a.mass
    body.ipos = [0.0, 0.0, 0.0]
    body.fullinertia = [J[0, 0], J[1, 1], J[2, 2], J[0, 1], J[0, 2], J[1, 2]]
    body.explicitinertial = True
    if len(a.mesh_faces):
        mesh_name = f"{obj.name}_visual"
        spec.add_mesh(name=mesh_name, uservert=a.mesh_vertices.ravel().tolist(),
                      userface=a.mesh_faces.ravel().tolist())
        body.add_geom(name=mesh_name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh_name, contype=0,
                      conaffinity=0, group=1, density=0, rgba=list(obj.rgba))
    else:  # no mesh: draw the samples' extent as a translucent ellipsoid
        half = 0.5 * np.ptp(a.points, axis=0)
        body.add_geom(name=f"{obj.name}_visual", type=mujoco.mjtGeom.mjGEOM_ELLIPSOID, size=list(half),
                      pos=list(0.5 * (a.points.min(0) + a.points.max(0))), contype=0, conaffinity=0, group=1,
                      density=0, rgba=list(obj.rgba))


def merge_duplicate_samples(points: np.ndarray, normals: np.ndarray, weights: np.ndarray):
    """Merge samples at identical positions, adding their weights (the paper bunny's 5000
    particles hold 2926 distinct ones). Every contact sum Σ w_i f(x_i) is unchanged, and the
    per-step work shrinks. Duplicates keep the normal of their first occurrence."""
    unique, first, inverse = np.unique(points, axis=0, return_index=True, return_inverse=True)
    merged = np.bincount(inverse.ravel(), weights=weights, minlength=len(unique))
    return unique, normals[first], merged


def _dano_body(obj: DanoObject) -> DanoBody:
    a = obj.asset
    r = obj.sample_radius if obj.sample_radius is not None else default_sample_radius(a)
    if not np.isfinite(r) or r <= 0:
        raise DanoError(f"{obj.name}: sample_radius must be positive, got {r}")
    rho = reference_density(a.field) if a.field is not None else 1.0
    points, normals, w = merge_duplicate_samples(a.points, np.nan_to_num(a.normals), a.weights / a.alpha)
    return DanoBody(
        points=jnp.asarray(points.T),
        normals=jnp.asarray(normals.T),
        weights=jnp.asarray(w),
        wp=jnp.asarray(np.vstack([w * points.T, w])),
        sample_radius=jnp.asarray(float(r)),
        com=jnp.asarray(a.center_of_mass),
        rho_ref=jnp.asarray(rho),
        field=a.field,
    )


def compose(
    objects: Sequence[DanoObject],
    base: mujoco.MjSpec | str | Path | None = None,
    *,
    dt: float = 0.01,
    ground: bool | None = None,
    contacts: Sequence[tuple[str, str]] | None = None,
    gravity: Sequence[float] = (0.0, 0.0, -9.81),
    name: str = "scene",
) -> Scene:
    """Build a scene from DANOs and a MuJoCo model.

    objects: the DANOs; base: an MJCF or URDF path, MJCF string or MjSpec (robots,
    primitives; a given MjSpec is copied, not modified), or None for an empty world; dt: time step [s]; ground: add a ground plane at z = 0
    named "ground" (default: when ``base`` is None); contacts: restrict the DANO pairs
    to these (name, name) pairs of DANO and geom/DANO names (default: all);
    gravity: (3,) [m/s²].
    Raises DanoError if the MJCF does not load or compile, for duplicate or unknown
    names, a non-positive dt, or a requested DANO-DANO pair without a queryable field.
    """
    if not np.isfinite(dt) or dt <= 0:
        raise DanoError(f"time step dt must be positive, got {dt}")
    names = [o.name for o in objects]
    if len(set(names)) != len(names):
        raise DanoError(f"DANO names must be unique, got {names}")
    spec = _load_spec(base)
    if ground if ground is not None else base is None:
        add_ground(spec)
    for o in objects:
        _add_dano(spec, o)
    spec.option.timestep = dt
    spec.option.gravity = list(map(float, gravity))
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_EULERDAMP
    try:
        mj_model = spec.compile()
    except Exception as exc:
        where = f"{base}: " if isinstance(base, (str, Path)) and not str(base).lstrip().startswith("<") else ""
        raise DanoError(f"{where}the scene's MuJoCo model does not compile: {exc}") from exc

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
            pairs.append(Pair(kind, i, g, -1, body_ids[i], int(mj_model.geom_bodyid[g]), f"{o.name}/{gname}"))
        for j in range(i + 1, len(objects)):
            if o.asset.field is not None and objects[j].asset.field is not None:
                pairs.append(Pair("dano", i, -1, j, body_ids[i], body_ids[j], f"{o.name}/{objects[j].name}"))
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

    danos = tuple(_dano_body(o) for o in objects)
    base_mass = np.array([mj_model.body_mass[b] / o.asset.alpha for b, o in zip(body_ids, objects)])
    base_inertia = np.array([mj_model.body_inertia[b] / o.asset.alpha for b, o in zip(body_ids, objects)])
    jnt = [mj_model.body_jntadr[b] for b in body_ids]
    return Scene(
        mj_model=mj_model,
        static=SceneStatic(tuple(pairs), tuple(body_ids), float(dt)),
        arrays=SceneArrays(mjx.put_model(mj_model), danos, jnp.asarray(base_mass), jnp.asarray(base_inertia)),
        dano_names=tuple(names),
        assets=tuple(o.asset for o in objects),
        body_names=tuple(mujoco.mj_id2name(mj_model, mujoco.mjtObj.mjOBJ_BODY, b) or "" for b in range(mj_model.nbody)),
        qpos_adr=tuple(int(mj_model.jnt_qposadr[j]) for j in jnt),
        dof_adr=tuple(int(mj_model.jnt_dofadr[j]) for j in jnt),
        name=name,
    )

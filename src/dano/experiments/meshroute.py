"""The mesh route, measured (paper §VII, Fig. 8): level-set meshes of a density field as
MuJoCo colliders against the DANO itself.

For each level-set mesh (extracted with marching cubes from a queryable field, or given,
e.g. the paper's soap level sets) and each collision mode (convex hull, CoACD
decomposition), :func:`compare_mesh` builds the body a mesh-route user would simulate
in MuJoCo C: the collision pieces with uniform density, mass properties computed by
MuJoCo from them; then simulates it at rest on the plane z = 0 and sliding, and the DANO
in dano on the same scenes. All lengths are in the asset's units [m], body frame (object
axes, origin at the DANO's centre of mass).

Metrics per level and mode (keys of the JSON report):

* mesh: ``vertices``, ``faces``, ``components`` (connected pieces: floaters), ``watertight``,
  ``volume`` (of the level mesh, |signed volume|); ``pieces`` (convex collision pieces);
* mass properties, with the collision solid given the DANO's mass: ``com_error`` (distance
  of its centre of mass from the DANO's [m]), ``inertia_error`` (‖J_mesh − J‖_F / ‖J‖_F);
  ``mass_error`` ((ρ·V − m)/m with ρ = α × the field's interior density; ``None`` when the
  asset has no field, as for the paper colliders);
* rest: the DANO first settles from ``ScenarioConfig.quat``; from that stable orientation
  (``start_quat``), a little above the ground, the DANO and each mesh body are dropped and
  settle for ``rest_time`` s: ``rest_height`` (body-frame origin z [m]),
  ``rest_height_error`` (minus the DANO's), ``rest_tilt_deg`` (how differently the mesh body
  and the DANO lean at rest: the angle between the up direction seen in their body frames,
  heading ignored), ``rest_rotation_deg`` (the whole rotation between them, heading included);
* slide (from each one's rest pose with velocity (``slide_speed``, 0, 0), ``slide_time`` s):
  ``slide_distance`` (displacement [m]) and ``slide_divergence`` (‖d_mesh − d_DANO‖ [m]).

Physics in both engines: Coulomb sliding friction ``friction`` (MuJoCo: default soft
constraints, condim 3, the same friction on both geoms, timestep ``mujoco_dt``, implicitfast
integrator; dano: the paper's spring, damper and torsional friction, no drags, no rolling
friction).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Callable, Literal, Sequence

import mujoco
import numpy as np
import trimesh
import tyro

from .._files import atomic_path
from ..asset import visual_mesh
from ..contact import CONTACT_MODELS
from ..data import load_asset
from ..errors import DanoError
from ..fields.base import check_resolution, interior_density
from ..fields.mesh import load_mesh
from ..io.exporters import BodyMeshes, Decomposition, add_collision_geoms, add_to_spec, body_meshes
from ..pose import normalize_quat, quat_error, quat_inverse, quat_to_matrix, rotate
from ..sim import DanoObject, compose, rollout
from ..sim.scene import add_ground
from ..sim.scenes import initial_state, resting_height

COLLISIONS = ("hull", "decomposition")


@dataclass(frozen=True)
class Level:
    """A level-set mesh to compare: label (e.g. "φ = 0.70"), the mesh (object frame [m]),
    level: its density (None if unknown), file: where it came from (or "")."""

    label: str
    mesh: trimesh.Trimesh
    level: float | None = None
    file: str = ""


@dataclass(frozen=True)
class ScenarioConfig:
    """The two scenes of :func:`compare_mesh`: a drop that settles, then a slide. Raises
    DanoError naming the setting for a value out of range."""

    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    """Orientation of the drop, a wxyz quaternion (object axes in the world), (4,), non-zero."""
    friction: float = 0.2
    """Sliding friction μ [-] (both engines), finite, >= 0."""
    rest_time: float = 3.0
    """Settling time after the drop [s], finite, > 0."""
    slide_time: float = 2.0
    """Duration of the slide [s], finite, > 0."""
    slide_speed: float = 1.0
    """Initial speed of the slide along +x [m/s], finite, >= 0."""
    clearance: float = 0.02
    """Drop height above the lowest point's contact [m], finite, >= 0."""
    dt: float = 0.01
    """dano's time step [s], finite, > 0."""
    mujoco_dt: float = 0.002
    """MuJoCo's time step [s], finite, > 0."""

    def __post_init__(self):
        for opt, v, least in (("friction", self.friction, "non-negative"),
                              ("slide-speed", self.slide_speed, "non-negative"),
                              ("rest-time", self.rest_time, "positive"), ("slide-time", self.slide_time, "positive"),
                              ("clearance", self.clearance, "non-negative"), ("dt", self.dt, "positive"),
                              ("mujoco-dt", self.mujoco_dt, "positive")):
            if not (0 <= v < float("inf")) or (least == "positive" and v == 0):
                raise DanoError(f"--{opt} must be a finite {least} number, got {v}")


Scenario = ScenarioConfig  # old name, kept


def extract_levels(asset, levels: Sequence[float], resolution: int = 96) -> list[Level]:
    """Marching-cubes meshes (object frame) of the asset's field at ``levels`` (densities).
    Raises DanoError if the asset has no field or a level is outside its range."""
    if asset.field is None:
        raise DanoError(f"{asset.name}: no density field stored, so no level set can be extracted; give level-set "
                        "meshes instead (--mesh)")
    out = []
    for lv in levels:
        v, f = visual_mesh(asset.field, float(lv), resolution)
        out.append(Level(f"φ = {lv:g}", trimesh.Trimesh(v, f, process=False), float(lv)))
    return out


def default_levels(asset, resolution: int = 96) -> list[Level]:
    """The levels compared when none are given: 0.1, 0.5 and 0.9 of the field's interior
    density if the asset stores its field, else its visual mesh. Raises DanoError if it has
    neither."""
    if asset.field is not None:
        rho = interior_density(asset.field)
        return extract_levels(asset, [f * rho for f in (0.1, 0.5, 0.9)], resolution)
    if len(asset.mesh_faces):
        visual = trimesh.Trimesh(asset.mesh_vertices + asset.center_of_mass, asset.mesh_faces, process=False)
        return [Level("visual mesh", visual, file="(stored in the .dano)")]
    raise DanoError(f"{asset.name}: no field, no visual mesh and no level-set mesh given: nothing to compare")


def _quat_angle_deg(q1: np.ndarray, q2: np.ndarray) -> float:
    """Angle of the rotation between two orientations [deg]."""
    return float(np.degrees(np.linalg.norm(quat_error(q1, q2))))


def _tilt_deg(q1: np.ndarray, q2: np.ndarray) -> float:
    """Angle between the world's up direction seen in two orientations' body frames [deg]:
    how differently the body leans, whatever its heading (yaw)."""
    up = [rotate(quat_inverse(normalize_quat(q)), np.array([0.0, 0.0, 1.0])) for q in (q1, q2)]
    return float(np.degrees(np.arccos(np.clip(np.dot(up[0], up[1]), -1.0, 1.0))))


def _full_inertia(m: mujoco.MjModel, b: int) -> np.ndarray:
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, m.body_iquat[b])
    R = R.reshape(3, 3)
    return R @ np.diag(m.body_inertia[b]) @ R.T


def mesh_body_model(pieces: Sequence[trimesh.Trimesh], mass: float, friction: float, dt: float,
                    pos=(0.0, 0.0, 0.0)) -> mujoco.MjModel:
    """A MuJoCo model: the ground plane z = 0 and a free body ``mesh`` at ``pos`` (3,) [m],
    made of the convex ``pieces`` (body frame [m]) with the uniform density that gives it
    ``mass`` [kg] (MuJoCo computes centre of mass and inertia from the pieces; overlapping
    pieces count twice, as in MuJoCo); sliding ``friction`` on both geoms (MuJoCo takes the
    larger of the two); timestep ``dt`` [s], implicitfast integrator. Raises DanoError if
    MuJoCo cannot compile it."""
    spec = mujoco.MjSpec()
    spec.option.timestep = dt
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    add_ground(spec)
    spec.geom("ground").friction = [friction, 0.005, 0.0001]
    body = spec.worldbody.add_body(name="mesh", pos=list(pos))
    body.add_freejoint(name="mesh_free")
    volume = float(sum(p.volume for p in pieces))
    add_collision_geoms(spec, body, "mesh", pieces, density=mass / volume, friction=friction,
                        rgba=(0.45, 0.6, 0.85, 1.0))
    try:
        return spec.compile()
    except Exception as exc:
        raise DanoError(f"MuJoCo cannot compile the mesh collider ({exc})") from exc


def _advance(m: mujoco.MjModel, d: mujoco.MjData, seconds: float) -> None:
    """Step ``d`` forward by ``seconds`` with MuJoCo's C rollout (warm start carried over)."""
    from mujoco import rollout

    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    state = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, state, spec)
    states, _ = rollout.rollout(m, d, state[None], nstep=int(round(seconds / m.opt.timestep)),
                                initial_warmstart=d.qacc_warmstart[None].copy())
    mujoco.mj_setState(m, d, states[0, -1], spec)
    mujoco.mj_forward(m, d)


def _simulate_mujoco(m: mujoco.MjModel, qpos0: np.ndarray, sc: ScenarioConfig):
    """Rest then slide in MuJoCo C; returns (rest qpos (7,), slide displacement (3,) [m])."""
    d = mujoco.MjData(m)
    d.qpos[:] = qpos0
    mujoco.mj_forward(m, d)
    _advance(m, d, sc.rest_time)
    rest = d.qpos.copy()
    d.qvel[:] = 0.0
    d.qvel[0] = sc.slide_speed
    _advance(m, d, sc.slide_time)
    if not np.all(np.isfinite(d.qpos)):
        raise DanoError("the MuJoCo mesh simulation became non-finite")
    return rest, d.qpos[:3] - rest[:3]


class _DanoRuns:
    """The DANO in dano on the plane: one scene (one compilation) for every run."""

    def __init__(self, asset, sc: ScenarioConfig, contact_model: str):
        self.sc = sc
        self.scene = compose([DanoObject("dano", asset)], dt=sc.dt, name="mesh-route-dano", contact_model=contact_model)
        # MuJoCo's condim-3 contact: Coulomb sliding friction, no drags, no rolling friction.
        # The paper's torsional friction (0.01) stays: the centroid model's single contact
        # point has no other resistance to spinning about the normal (MuJoCo's several contact
        # points have); without it the resting bunny creeps in yaw at ~0.1 deg/s.
        self.params = self.scene.default_params(sliding_friction=sc.friction, sliding_drag=0.0,
                                                rolling_friction=0.0)

    def _run(self, pos, quat, v, seconds: float) -> np.ndarray:
        state = initial_state(self.scene, {"dano": (pos, quat)}, {"dano": (v, (0.0, 0.0, 0.0))})
        return rollout(self.scene, state, params=self.params, steps=int(round(seconds / self.sc.dt))).qpos[-1, :7]

    def rest(self, z0: float, quat) -> np.ndarray:
        """qpos (7,) after settling from (0, 0, z0), ``quat`` at rest."""
        return self._run((0.0, 0.0, z0), quat, (0.0, 0.0, 0.0), self.sc.rest_time)

    def slide(self, rest: np.ndarray) -> np.ndarray:
        """Displacement (3,) [m] of the slide from the rest pose ``rest``."""
        return self._run(rest[:3], rest[3:7], (self.sc.slide_speed, 0.0, 0.0), self.sc.slide_time)[:3] - rest[:3]


def _start_height(asset, pieces, quat: np.ndarray, clearance: float) -> float:
    """Body-origin height at which the DANO's lowest sample and every collider's lowest
    vertex are at least ``clearance`` × the object's size above z = 0."""
    up = quat_to_matrix(quat)[2]
    lowest = max([resting_height(asset, quat)] + [-float(np.min(p.vertices @ up)) for ps in pieces for p in ps])
    return lowest + clearance * float(np.ptp(asset.points, axis=0).max())


def _mesh_stats(level: Level) -> dict:
    m = level.mesh.copy()
    m.merge_vertices()
    return {
        "label": level.label,
        "level": level.level,
        "file": level.file,
        "vertices": int(len(m.vertices)),
        "faces": int(len(m.faces)),
        "components": int(len(m.split(only_watertight=False))),
        "watertight": bool(m.is_watertight),
        "volume": float(abs(m.volume)),
    }


def compare_mesh(
    asset,
    levels: Sequence[Level],
    *,
    collisions: Sequence[str] = COLLISIONS,
    scenario: ScenarioConfig = ScenarioConfig(),
    decomposition: Decomposition = Decomposition(),
    contact_model: str = "centroid",
    progress: Callable[[int, int, str], None] | None = None,
) -> dict:
    """Compare level-set mesh colliders in MuJoCo C against the DANO in dano (module doc).

    asset: the :class:`~dano.asset.DanoAsset`; levels: meshes in the object frame; collisions:
    subset of ("hull", "decomposition"). Returns a JSON-able report {"source", "scenario",
    "dano": {...}, "levels": [{mesh stats, "collision": {mode: {metrics}}}]} plus, under the
    private key "_models", what :func:`render_rest_figure` needs. Raises DanoError for an
    unknown mode, an empty level list or a collider MuJoCo cannot compile.
    """
    if not levels:
        raise DanoError("no level-set meshes to compare")
    for c in collisions:
        if c not in COLLISIONS:
            raise DanoError(f"unknown collision mode {c!r}; choose from {', '.join(COLLISIONS)}")
    sc = scenario
    quat = np.asarray(sc.quat, dtype=np.float64)
    if quat.shape != (4,) or not np.all(np.isfinite(quat)) or np.linalg.norm(quat) < 1e-12:
        raise DanoError(f"the drop orientation must be a non-zero wxyz quaternion, got {list(sc.quat)}")
    quat = quat / np.linalg.norm(quat)
    total = len(levels) * len(collisions) + 2
    pieces_by = {}
    for i, lv in enumerate(levels):
        for c in collisions:
            pieces_by[i, c] = body_meshes(asset, c, mesh=lv.mesh, decomposition=decomposition).collision
            if progress:
                progress(len(pieces_by), total, "colliders, DANO runs")
    # the DANO first settles from `quat`; every body is then dropped from that stable pose
    runs = _DanoRuns(asset, sc, contact_model)
    settled = runs.rest(_start_height(asset, [], quat, sc.clearance), quat)[3:7]
    settled = settled / np.linalg.norm(settled)
    z0 = _start_height(asset, pieces_by.values(), settled, sc.clearance)
    qpos0 = np.r_[0.0, 0.0, z0, settled]
    d_rest = runs.rest(z0, settled)
    d_disp = runs.slide(d_rest)
    if progress:
        progress(total, total, "colliders, DANO runs")
    rho = None
    if asset.field is not None:
        rho = asset.alpha * interior_density(asset.field)
    report_levels, models = [], {}
    for i, lv in enumerate(levels):
        entry = _mesh_stats(lv)
        entry["collision"] = {}
        for c in collisions:
            pieces = pieces_by[i, c]
            m = mesh_body_model(pieces, asset.mass, sc.friction, sc.mujoco_dt)
            volume = float(sum(p.volume for p in pieces))
            J = _full_inertia(m, 1)
            rest, disp = _simulate_mujoco(m, qpos0, sc)
            entry["collision"][c] = {
                "pieces": len(pieces),
                "collider_volume": volume,
                "mass_error": None if rho is None else float((rho * volume - asset.mass) / asset.mass),
                "com_error": float(np.linalg.norm(m.body_ipos[1])),
                "inertia_error": float(np.linalg.norm(J - asset.inertia) / np.linalg.norm(asset.inertia)),
                "rest_height": float(rest[2]),
                "rest_height_error": float(rest[2] - d_rest[2]),
                "rest_tilt_deg": _tilt_deg(rest[3:7], d_rest[3:7]),
                "rest_rotation_deg": _quat_angle_deg(rest[3:7], d_rest[3:7]),
                "slide_distance": float(np.linalg.norm(disp)),
                "slide_divergence": float(np.linalg.norm(disp - d_disp)),
            }
            models[(lv.label, c)] = (m, rest)
        report_levels.append(entry)
    return {
        "source": asset.name,
        "scenario": {k: getattr(sc, k) for k in sc.__dataclass_fields__},
        "contact_model": contact_model,
        "decomposition": {k: getattr(decomposition, k) for k in decomposition.__dataclass_fields__},
        "dano": {
            "mass": asset.mass,
            "num_samples": asset.num_samples,
            "start_height": z0,
            "start_quat": settled.tolist(),
            "rest_height": float(d_rest[2]),
            "rest_tilt_deg": _tilt_deg(d_rest[3:7], settled),
            "rest_rotation_deg": _quat_angle_deg(d_rest[3:7], settled),
            "slide_distance": float(np.linalg.norm(d_disp)),
        },
        "levels": report_levels,
        "_models": {"mesh": models, "dano_rest": d_rest},
    }


def render_rest_figure(asset, report: dict, path, width: int = 320, height: int = 240, levels=None) -> None:
    """A figure like the paper's Fig. 8: each collider at rest (MuJoCo's renderer,
    collision geometry shown) and the DANO at its rest pose (its visual mesh, else the
    first level mesh, drawn at the DANO's pose). Written atomically (PNG/PDF by suffix).
    Raises DanoError if no OpenGL context can be created (set MUJOCO_GL=egl or osmesa)."""
    from matplotlib.figure import Figure

    models = report["_models"]["mesh"]
    panels = []

    def shot(m, qpos, title):
        d = mujoco.MjData(m)
        d.qpos[:7] = qpos
        mujoco.mj_forward(m, d)
        try:
            r = mujoco.Renderer(m, height, width)
        except Exception as exc:
            raise DanoError(f"cannot create an OpenGL context for rendering: {exc}") from exc
        cam = mujoco.MjvCamera()
        cam.lookat[:] = d.qpos[:3]
        cam.lookat[2] = 0.6 * d.qpos[2]
        extent = float(np.ptp(asset.points, axis=0).max())
        cam.distance, cam.azimuth, cam.elevation = 2.6 * extent, 90.0, -10.0
        opt = mujoco.MjvOption()
        opt.geomgroup[:] = 1
        r.update_scene(d, cam, opt)
        panels.append((r.render().copy(), title))
        r.close()

    spec = mujoco.MjSpec()
    add_ground(spec)
    vis = None
    if not len(asset.mesh_faces) and levels:
        vis = BodyMeshes(trimesh.Trimesh(np.asarray(levels[0].mesh.vertices) - asset.center_of_mass,
                                         levels[0].mesh.faces, process=False), (), "first level mesh")
    add_to_spec(spec, asset, "dano", meshes=vis)
    drawn = f", drawn with the {levels[0].label} mesh" if vis is not None else ""
    shot(spec.compile(), report["_models"]["dano_rest"], f"DANO{drawn}\nrest {report['dano']['rest_height']:.3f}")
    for entry in report["levels"]:
        for c, res in entry["collision"].items():
            m, rest = models[(entry["label"], c)]
            shot(m, rest, f"{entry['label']} {c}\nrest {res['rest_height']:.3f}, tilt {res['rest_tilt_deg']:.1f}°")
    cols = min(len(panels), 4)
    rows = -(-len(panels) // cols)
    fig = Figure(figsize=(3.2 * cols, 2.8 * rows))
    for k, (img, title) in enumerate(panels):
        ax = fig.add_subplot(rows, cols, k + 1)
        ax.axis("off")
        ax.imshow(img)
        ax.set_title(title, fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)


@dataclass(frozen=True)
class CompareMeshConfig:
    """Level-set meshes of a density field as MuJoCo colliders (convex hull, CoACD decomposition) against the
    DANO: mesh pieces, mass-property errors, rest height and tilt, slide divergence (docs/mesh-route.md)."""

    source: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="SOURCE")]
    """a .dano file (or builtin:NAME, e.g. builtin:bluesoap for the paper's real soap)."""
    levels: tuple[float, ...] = ()
    """densities whose level sets are extracted from the stored field (marching cubes). With --mesh, both are
    compared."""
    mesh: Annotated[tuple[str, ...], tyro.conf.UseAppendAction, tyro.conf.arg(metavar="[LABEL=]FILE")] = ()
    """a level-set mesh file in the object frame, FILE or LABEL=FILE (e.g. the paper's bluesoap_level_70.stl);
    repeat the option for several. Default, when neither --levels nor --mesh is given: 0.1, 0.5 and 0.9 of
    the field's interior density, or the asset's visual mesh if it has no field."""
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    """orientation w x y z of the drop (object axes in the world)."""
    collision: tuple[Literal["hull", "decomposition"], ...] = ("hull", "decomposition")
    """collider kinds to build."""
    friction: float = 0.2
    """sliding friction in both engines (Coulomb only)."""
    slide_speed: float = 1.0
    """initial speed of the slide [m/s]."""
    rest_time: float = 3.0
    """settling time of the drop [s]."""
    slide_time: float = 2.0
    """duration of the slide [s]."""
    resolution: int = 96
    """marching-cubes nodes along the longest axis."""
    threshold: float = 0.1
    """CoACD concavity threshold."""
    max_pieces: int = -1
    """CoACD: merge down to at most this many pieces (-1: no limit)."""
    contact_model: str = "centroid"
    """dano's contact model for the DANO."""
    figure: Path | None = None
    """write renders of every collider at rest (like the paper's Fig. 8) to this image."""
    out: Annotated[Path | None, tyro.conf.arg(aliases=("-o",))] = None
    """also write the JSON report to this file."""
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False
    """print the report as one JSON object instead of a table."""
    quiet: bool = False
    """no progress bar."""

    def __post_init__(self):
        if self.contact_model not in CONTACT_MODELS:
            raise DanoError(f"unknown --contact-model {self.contact_model!r}; available: {', '.join(CONTACT_MODELS)}")
        check_resolution(self.resolution)
        if not 0 < self.threshold < float("inf"):
            raise DanoError(f"--threshold must be a finite positive number, got {self.threshold}")
        self.scenario()  # its own ranges

    def scenario(self) -> ScenarioConfig:
        """The rest-and-slide scenario of these options."""
        return ScenarioConfig(quat=self.quat, friction=self.friction, rest_time=self.rest_time,
                              slide_time=self.slide_time, slide_speed=self.slide_speed)


def level_meshes(paths) -> list[Level]:
    """``[LABEL=]FILE`` mesh files (object frame; open, noisy level sets allowed) -> :class:`Level` list."""
    levels = []
    for p in paths:
        label, eq, file = str(p).rpartition("=")
        path = Path(file)
        levels.append(Level(label if eq else path.stem, load_mesh(path, require_watertight=False), file=path.name))
    return levels


def compare_mesh_command(config: CompareMeshConfig, progress=None) -> tuple[dict, list[Path]]:
    """``dano compare-mesh``: the levels (``--mesh`` files, ``--levels`` extracted from the
    field, else :func:`default_levels`) compared with the DANO (:func:`compare_mesh`); the
    rest figure and the JSON report written (both or neither). Returns (report, paths)."""
    import json
    from contextlib import ExitStack

    asset = load_asset(config.source)
    lv = level_meshes(config.mesh) + (extract_levels(asset, config.levels, config.resolution) if config.levels else [])
    lv = lv or default_levels(asset, config.resolution)
    report = compare_mesh(asset, lv, collisions=config.collision, scenario=config.scenario(),
                          contact_model=config.contact_model,
                          decomposition=Decomposition(threshold=config.threshold, max_pieces=config.max_pieces),
                          progress=progress)
    with ExitStack() as stack:  # the figure and the report: both or neither
        if config.figure is not None:
            render_rest_figure(asset, report, stack.enter_context(atomic_path(config.figure)), levels=lv)
        report.pop("_models")
        if config.out is not None:
            stack.enter_context(atomic_path(config.out)).write_text(json.dumps(report, indent=1))
    return report, [p for p in (config.figure, config.out) if p is not None]

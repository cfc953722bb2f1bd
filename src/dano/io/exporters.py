"""Exporters: a DANO as a rigid body for any MuJoCo or URDF tool (MJCF, URDF, MjSpec).

The exported body is the DANO's *body frame* (object axes, origin at the centre of
mass, the frame dano's free bodies and trajectories use), so a dano ``qpos`` places
the exported body exactly. It carries:

* the inertial: mass [kg], centre of mass (0 in the body frame) and the full inertia
  tensor [kg m²] of the ``.dano``, written with 17 significant digits;
* the visual mesh (the asset's, or a level set of its field);
* collision geometry from a level-set mesh: its convex hull (``"hull"``), an approximate
  convex decomposition with CoACD (``"decomposition"``, Wei et al., SIGGRAPH 2022), or
  nothing (``"none"``). MuJoCo collides every mesh geom as its convex hull, so a
  non-convex level set needs the decomposition to keep its concavities.

MJCF is one self-contained file (meshes inline); URDF refers to OBJ files in a folder
``<stem>_meshes`` beside it. Output is published only after MuJoCo has compiled it from
a temporary copy: on any error nothing is left behind.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import trimesh

from .._files import atomic_path
from ..asset import visual_mesh
from ..errors import DanoError, FileFormatError

COLLISION_MODES = ("hull", "decomposition", "none")
VISUAL_RGBA = (0.85, 0.65, 0.45, 1.0)
COLLISION_RGBA = (0.4, 0.6, 0.9, 0.5)
EXPORT_SUFFIXES = (".xml", ".urdf")


@dataclass(frozen=True)
class Decomposition:
    """Settings of CoACD's approximate convex decomposition.

    threshold: concavity threshold (CoACD's; smaller: more, tighter pieces; 0.01–1);
    max_pieces: merge down to at most this many convex pieces (−1: no limit);
    preprocess_resolution: CoACD's manifold-remeshing resolution; seed: its random seed.
    Defaults trade detail for time (the paper bunny: 15 pieces in about 25 s on one core).
    """

    threshold: float = 0.1
    max_pieces: int = -1
    preprocess_resolution: int = 30
    seed: int = 0


@dataclass(frozen=True)
class BodyMeshes:
    """The geometry of an exported body, body frame [m].

    visual: the visual mesh (None: no mesh to draw); collision: convex pieces (possibly
    empty); source: a one-line description of where the collision geometry came from."""

    visual: trimesh.Trimesh | None
    collision: tuple[trimesh.Trimesh, ...]
    source: str


def _check_mode(collision: str) -> str:
    if collision not in COLLISION_MODES:
        raise DanoError(f"unknown collision mode {collision!r}; choose one of {', '.join(COLLISION_MODES)}")
    return collision


def level_mesh(asset, level: float | None = None, resolution: int = 96, mesh=None) -> trimesh.Trimesh:
    """The level-set mesh collision geometry is made from, body frame [m].

    mesh: a mesh (:class:`trimesh.Trimesh`, object frame) given explicitly, e.g. one of the
    paper's level sets; else level: a density φ whose level set is extracted from the
    asset's field with marching cubes at ``resolution`` nodes along the longest axis;
    else the asset's stored visual mesh. Raises DanoError if the asset has neither the
    field nor a visual mesh needed, or the level is outside the field's range.
    """
    if mesh is not None:
        m = trimesh.Trimesh(np.asarray(mesh.vertices) - asset.center_of_mass, np.asarray(mesh.faces), process=False)
    elif level is not None:
        if asset.field is None:
            raise DanoError(f"{asset.name}: a level set needs the density field, and this asset has none stored "
                            "(give a level-set mesh instead)")
        v, f = visual_mesh(asset.field, float(level), resolution)
        m = trimesh.Trimesh(v - asset.center_of_mass, f, process=False)
    elif len(asset.mesh_faces):
        m = trimesh.Trimesh(asset.mesh_vertices, asset.mesh_faces, process=False)
    else:
        raise DanoError(f"{asset.name}: no visual mesh stored and no level or mesh given to make collision "
                        "geometry from (use collision 'none', a level with a queryable field, or a mesh)")
    m.merge_vertices()
    if m.volume < 0:
        m.invert()
    return m


def convex_decomposition(mesh: trimesh.Trimesh, settings: Decomposition = Decomposition()) -> list[trimesh.Trimesh]:
    """Approximate convex decomposition of ``mesh`` with CoACD; returns convex pieces in
    the mesh's frame. Raises DanoError if CoACD returns nothing."""
    import coacd

    coacd.set_log_level("error")
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32)),
        threshold=settings.threshold, max_convex_hull=settings.max_pieces,
        preprocess_resolution=settings.preprocess_resolution, seed=settings.seed,
    )
    pieces = [trimesh.Trimesh(np.asarray(v), np.asarray(f), process=False) for v, f in parts]
    pieces = [p for p in pieces if len(p.faces) >= 4 and p.volume > 0]
    if not pieces:
        raise DanoError("the convex decomposition (CoACD) returned no solid piece")
    return pieces


def body_meshes(asset, collision: str = "hull", *, level: float | None = None, mesh=None, resolution: int = 96,
                decomposition: Decomposition = Decomposition()) -> BodyMeshes:
    """Visual and collision meshes of ``asset`` (body frame); see :func:`level_mesh` for
    ``level``, ``mesh`` and ``resolution``. Raises DanoError for an unknown mode."""
    _check_mode(collision)
    visual = trimesh.Trimesh(asset.mesh_vertices, asset.mesh_faces, process=False) if len(asset.mesh_faces) else None
    if collision == "none":
        return BodyMeshes(visual, (), "none")
    if collision == "hull" and visual is None and level is None and mesh is None:
        # no mesh stored (e.g. a paper .jld2 collider): the hull of the boundary samples (body frame)
        hull = trimesh.convex.convex_hull(np.asarray(asset.points, dtype=np.float64))
        return BodyMeshes(hull, (hull,), "convex hull of the boundary samples")
    src = level_mesh(asset, level, resolution, mesh)
    if visual is None:
        visual = src
    what = "given mesh" if mesh is not None else (f"level set φ = {level:g}" if level is not None else "visual mesh")
    if collision == "hull":
        return BodyMeshes(visual, (src.convex_hull,), f"convex hull of the {what}")
    pieces = convex_decomposition(src, decomposition)
    return BodyMeshes(visual, tuple(pieces), f"CoACD decomposition of the {what} (threshold "
                      f"{decomposition.threshold:g}, {len(pieces)} pieces)")


def _fullinertia(J: np.ndarray) -> list[float]:
    return [J[0, 0], J[1, 1], J[2, 2], J[0, 1], J[0, 2], J[1, 2]]


def add_collision_geoms(spec, body, name: str, pieces: Sequence[trimesh.Trimesh], *, density: float = 0.0,
                        friction: float | None = None, rgba: Sequence[float] = COLLISION_RGBA) -> None:
    """Add convex ``pieces`` (body frame [m]) to ``body`` as mesh geoms ``<name>_collision_<kkk>``
    (group 3) of ``density`` [kg/m³] (0: massless, the body's inertial is explicit) and sliding
    ``friction`` (MuJoCo's default when None)."""
    import mujoco

    for k, piece in enumerate(pieces):
        mname = f"{name}_collision_{k:03d}"
        spec.add_mesh(name=mname, uservert=np.asarray(piece.vertices).ravel().tolist(),
                      userface=np.asarray(piece.faces).ravel().tolist())
        geom = body.add_geom(name=mname, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mname, group=3,
                             density=float(density), rgba=list(rgba))
        if friction is not None:
            geom.friction = [float(friction), geom.friction[1], geom.friction[2]]


def add_to_spec(spec, asset, name: str | None = None, *, meshes: BodyMeshes | None = None,
                pos: Sequence[float] = (0.0, 0.0, 0.0), quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0),
                free: bool = True, rgba: Sequence[float] = VISUAL_RGBA, friction: float | None = None,
                parent=None):
    """Add ``asset`` as a body to a :class:`mujoco.MjSpec` and return the body.

    name: body name (default the asset's); meshes: from :func:`body_meshes` (default: the
    visual mesh only, no collision geometry); pos: (3,) body-frame origin (the centre of
    mass) in the parent frame [m]; quat: (4,) wxyz; free: add a free joint ``<name>_free``;
    friction: sliding friction of the collision geoms (MuJoCo's default when None);
    parent: the parent body (default the world). The inertial is explicit (mass, centre of
    mass at the origin, full inertia), so geoms do not change it. Geom names: ``<name>_visual``
    (group 1, no collisions), ``<name>_collision_000``, ``_001``, … (group 3), as in the
    exported MJCF. Without a visual mesh, a
    translucent ellipsoid spanning the samples is drawn.
    """
    import mujoco

    name = name or asset.name or "dano"
    q = np.asarray(quat, dtype=np.float64)
    if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-12:
        raise DanoError(f"{name}: quat must be a non-zero wxyz quaternion, got {list(quat)}")
    meshes = meshes or body_meshes(asset, "none")
    body = (parent or spec.worldbody).add_body(name=name, pos=[float(p) for p in pos], quat=list(q / np.linalg.norm(q)))
    if free:
        body.add_freejoint(name=f"{name}_free")
    body.explicitinertial = True
    body.mass = asset.mass
    body.ipos = [0.0, 0.0, 0.0]
    body.fullinertia = _fullinertia(asset.inertia)
    if meshes.visual is not None:
        spec.add_mesh(name=f"{name}_visual", uservert=np.asarray(meshes.visual.vertices).ravel().tolist(),
                      userface=np.asarray(meshes.visual.faces).ravel().tolist())
        body.add_geom(name=f"{name}_visual", type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f"{name}_visual", contype=0,
                      conaffinity=0, group=1, density=0, rgba=list(rgba))
    else:
        half = 0.5 * np.ptp(asset.points, axis=0)
        body.add_geom(name=f"{name}_visual", type=mujoco.mjtGeom.mjGEOM_ELLIPSOID, size=list(half),
                      pos=list(0.5 * (asset.points.min(0) + asset.points.max(0))), contype=0, conaffinity=0, group=1,
                      density=0, rgba=list(rgba))
    add_collision_geoms(spec, body, name, meshes.collision, friction=friction)
    return body


# --------------------------------------------------------------------------- files


def _num(x) -> str:
    return repr(float(x))


def _nums(xs) -> str:
    return " ".join(_num(x) for x in np.ravel(xs))


def _mesh_files(meshes: BodyMeshes) -> dict[str, trimesh.Trimesh]:
    files = {"visual": meshes.visual} if meshes.visual is not None else {}
    files.update({f"collision_{k:03d}": p for k, p in enumerate(meshes.collision)})
    return files


#: identified contact parameters that MuJoCo's geom ``friction`` (slide, torsion, roll) carries
FRICTION_KEYS = ("sliding_friction", "torsional_friction", "rolling_friction")
MUJOCO_DEFAULT_FRICTION = (1.0, 0.005, 0.0001)


def read_contact_params(path: str | Path) -> dict[str, float]:
    """The contact parameters in a JSON file: ``dano sysid``'s ``result.json`` (estimates as
    top-level keys; a pair-prefixed key such as ``soap/ground:sliding_friction`` counts when
    it is the only one of its name) or any JSON table of names to numbers. Returns the
    finite numbers among :data:`dano.contact.ContactParams` names. Raises FileFormatError
    when the file cannot be read or holds none."""
    import json

    path = Path(path)
    try:
        table = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FileFormatError(f"{path}: cannot read the parameters ({exc})") from exc
    if not isinstance(table, dict):
        raise FileFormatError(f"{path}: expected a JSON table of parameter names to values")
    return contact_params(table, source=str(path), error=FileFormatError)


def contact_params(contact, source: str = "contact", error: type[DanoError] = DanoError) -> dict[str, float]:
    """The contact parameters in ``contact``: an identification's answer
    (:class:`dano.sysid.SysIdResult`, or its ``as_dict()``, estimates under ``"parameters"``),
    ``dano sysid``'s ``result.json`` table (estimates as top-level keys) or any mapping of
    names to numbers. A pair-prefixed key such as ``soap/ground:sliding_friction`` counts
    when it is the only one of its name. Returns {name: value} of the finite numbers among
    :data:`dano.contact.ContactParams` names. Raises ``error`` (naming ``source``) when there
    are none, or when a name is given for several pairs."""
    import dataclasses

    from ..contact.params import ContactParams  # not at the top: `import dano` loads io, not contact

    if hasattr(contact, "labels") and hasattr(contact, "estimates"):  # a SysIdResult
        table = dict(zip(contact.labels, np.asarray(contact.estimates, dtype=np.float64).tolist()))
    elif isinstance(contact, dict):
        nested = contact.get("parameters")
        table = {**nested, **contact} if isinstance(nested, dict) else dict(contact)
    else:
        raise error(f"{source}: expected an identification's result or a table of parameter names to values, "
                    f"got {type(contact).__name__}")

    def number(v) -> bool:  # a finite real scalar: Python's, NumPy's or a 0-d (JAX) array
        if isinstance(v, (bool, np.bool_, str, bytes)) or np.ndim(v) != 0:
            return False
        try:
            x = np.asarray(v)
        except Exception:  # noqa: BLE001 (an object NumPy cannot take is no number)
            return False
        return x.dtype.kind in "iuf" and bool(np.isfinite(x))

    params = {}
    for base in (f.name for f in dataclasses.fields(ContactParams)):
        if base in table and number(table[base]):
            params[base] = float(table[base])
            continue
        keys = [k for k, v in table.items() if str(k).endswith(":" + base) and number(v)]
        if len(keys) > 1:
            raise error(f"{source}: {base} is given for several pairs ({', '.join(keys)}); an export "
                        "carries one value: give a table with the one to use")
        if keys:
            params[base] = float(table[keys[0]])
    if not params:
        raise error(f"{source}: no contact parameter found (keys such as {', '.join(FRICTION_KEYS)})")
    return params


def friction_note(contact: dict[str, float], mjcf: bool = True) -> tuple[str, str]:
    """(MuJoCo's geom friction "slide torsion roll", the XML comment on what was carried).

    Where a friction coefficient is carried, the MJCF's collision geoms also get
    ``priority="1"``: MuJoCo otherwise gives a contact the larger friction of its two geoms,
    and a floor with MuJoCo's default friction (1) would override the identified value. Their
    condim stays MuJoCo's 3, so MuJoCo uses the torsional and rolling coefficients only where
    a user raises it to 4 or 6; the comment says so (``mjcf`` False: a URDF's comment, which
    leaves both to whoever loads it)."""
    values = [contact.get(k, d) for k, d in zip(FRICTION_KEYS, MUJOCO_DEFAULT_FRICTION)]
    carried = [k for k in FRICTION_KEYS if k in contact]
    left = sorted(set(contact) - set(FRICTION_KEYS))
    # (said whether or not the parameters hold them: a reader of the file should know that
    # only the friction coefficients cross over)
    note = (f" dano: friction = {', '.join(carried) or 'none'} identified by dano"
            f"{'' if len(carried) == 3 else ' (the rest: MuJoCo defaults)'}. "
            + (PRIORITY_NOTE if carried and mjcf else "")
            + (f"Not carried: {', '.join(left)}. " if left else "")
            + "dano's contact spring, damper and drags act on the density overlap psi, which MuJoCo's soft "
              "contact does not have: solref/solimp keep MuJoCo's defaults. ")
    return _nums(values), note


#: what the export's comment says of priority and condim where friction is carried
PRIORITY_NOTE = (
    "priority=1 on the collision geoms: their friction (and condim) is the one MuJoCo uses in their contacts; "
    "without it MuJoCo takes the larger friction of the two geoms, and a floor's default 1 would win. "
    "condim stays MuJoCo's 3 (sliding friction only): MuJoCo uses the torsional coefficient only at condim 4 "
    "and the rolling one at 6. With condim 3 a face resting on the floor resists spinning through the sliding "
    "friction of its several contact points; dano's centroid contact model stands in for that with "
    "torsional_friction, so a value identified with it need not carry over; set condim=\"4\" (or \"6\") on "
    "these geoms to apply it. ")


def _mjcf(asset, name: str, meshes: dict, free: bool, contact: dict | None = None) -> ET.ElementTree:
    root = ET.Element("mujoco", model=name)
    ET.SubElement(root, "compiler", angle="radian")
    assets = ET.SubElement(root, "asset")
    for stem, m in meshes.items():
        ET.SubElement(assets, "mesh", name=f"{name}_{stem}",
                      vertex=" ".join(f"{x:.10g}" for x in np.ravel(m.vertices)),
                      face=" ".join(str(int(i)) for i in np.ravel(m.faces)))
    world = ET.SubElement(root, "worldbody")
    body = ET.SubElement(world, "body", name=name)
    if free:
        ET.SubElement(body, "freejoint", name=f"{name}_free")
    ET.SubElement(body, "inertial", pos="0 0 0", mass=_num(asset.mass), fullinertia=_nums(_fullinertia(asset.inertia)))
    friction, note = friction_note(contact) if contact else (None, None)
    carried = {"priority": "1"} if contact and any(k in contact for k in FRICTION_KEYS) else {}  # (PRIORITY_NOTE)
    for stem in meshes:
        attrs = {"name": f"{name}_{stem}", "type": "mesh", "mesh": f"{name}_{stem}", "density": "0"}
        if stem == "visual":
            attrs.update(contype="0", conaffinity="0", group="1", rgba=_nums(VISUAL_RGBA))
        else:
            attrs.update(group="3", rgba=_nums(COLLISION_RGBA))
            if contact:
                attrs.update(friction=friction, **carried)
        ET.SubElement(body, "geom", attrs)
    if contact:
        body.insert(0, ET.Comment(note))
    return ET.ElementTree(root)


def _urdf(asset, name: str, meshdir: str, files: dict, contact: dict | None = None) -> ET.ElementTree:
    root = ET.Element("robot", name=name)
    if contact:  # URDF has no friction element; MuJoCo's URDF reader takes geom defaults from none
        friction, note = friction_note(contact, mjcf=False)
        root.append(ET.Comment(note + f"URDF cannot state friction: set geom friction {friction!r} and priority 1 "
                               "on this link's collision geoms when loading it (MuJoCo otherwise gives a contact the "
                               "larger friction of its two geoms). "))
    # MuJoCo's URDF reader: keep visuals, keep the jointless root body (do not fuse it into
    # the world), use the stated inertia as given, resolve mesh paths relative to this file
    mj = ET.SubElement(root, "mujoco")
    ET.SubElement(mj, "compiler", discardvisual="false", fusestatic="false", balanceinertia="false",
                  strippath="false")
    link = ET.SubElement(root, "link", name=name)
    inertial = ET.SubElement(link, "inertial")
    ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=_num(asset.mass))
    J = asset.inertia
    ET.SubElement(inertial, "inertia", ixx=_num(J[0, 0]), ixy=_num(J[0, 1]), ixz=_num(J[0, 2]), iyy=_num(J[1, 1]),
                  iyz=_num(J[1, 2]), izz=_num(J[2, 2]))
    for stem in files:
        el = ET.SubElement(link, "visual" if stem == "visual" else "collision", name=f"{name}_{stem}")
        ET.SubElement(el, "origin", xyz="0 0 0", rpy="0 0 0")
        geom = ET.SubElement(el, "geometry")
        ET.SubElement(geom, "mesh", filename=f"{meshdir}/{stem}.obj")
    return ET.ElementTree(root)


def _safe_name(name: str) -> str:
    cleaned = "".join(c if c.isalnum() or c in "_-" else "_" for c in name)
    return cleaned or "dano"


def _compiles(path: Path, shown: Path) -> None:
    import mujoco

    try:
        mujoco.MjModel.from_xml_path(str(path))
    except Exception as exc:
        raise DanoError(f"{shown}: MuJoCo cannot compile the exported model ({exc})") from exc


def export(asset, path: str | Path, *, meshes: BodyMeshes | None = None, collision: str = "hull",
           name: str | None = None, free: bool = True, contact: dict | None = None, **mesh_options) -> Path:
    """Write ``asset`` as MJCF (``.xml``) or URDF (``.urdf``); returns ``path``.

    MJCF: one self-contained file, meshes inline. URDF: the file plus a folder
    ``<stem>_meshes/`` of OBJ meshes it refers to by relative path (a ``<mujoco>`` element
    tells MuJoCo's URDF reader to keep the visual geoms and the jointless root link).
    meshes: from :func:`body_meshes`; otherwise made with ``collision`` and ``mesh_options``
    (``level``, ``mesh``, ``resolution``, ``decomposition``). free: MJCF only, give the
    body a free joint (a URDF root link has no joint; add one when loading, e.g.
    ``spec.body(name).add_freejoint()``). contact: identified contact parameters: an
    identification's answer (``dano.sysid.identify(...)``, a :class:`~dano.sysid.SysIdResult`, or its
    ``as_dict()``), :func:`dano.io.read_contact_params` of a ``result.json``, or a table such as
    ``{"sliding_friction": 0.5}`` (:func:`contact_params`; None or {}: none): MJCF collision geoms get
    ``friction`` = sliding, torsional,
    rolling friction (MuJoCo's defaults for any not given) and ``priority="1"``
    (:func:`friction_note`), and a comment says what is not
    carried (the spring, damper and drags); URDF gets the comment only (it has no friction
    element). MuJoCo compiles the result from a temporary
    location before it is published.
    Raises DanoError for an unknown suffix or mode, a ``contact`` with no contact parameter
    in it, or if MuJoCo cannot compile the result (nothing is written then).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in EXPORT_SUFFIXES:
        raise DanoError(f"{path}: unknown export format {suffix!r}; use .xml (MJCF) or .urdf (URDF)")
    contact = None if contact is None or (isinstance(contact, dict) and not contact) else contact_params(contact)
    meshes = meshes or body_meshes(asset, collision, **mesh_options)
    name = _safe_name(name or asset.name)
    files = _mesh_files(meshes)
    if suffix == ".xml":
        tree = _mjcf(asset, name, files, free, contact)
        ET.indent(tree)
        with atomic_path(path) as tmp:
            tree.write(tmp, encoding="unicode")
            _compiles(tmp, path)
        return path
    meshdir = f"{path.stem}_meshes"
    tree = _urdf(asset, name, meshdir, files, contact)
    ET.indent(tree)
    path.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{path.stem}.", dir=path.parent))
    try:
        (staging / meshdir).mkdir()
        for stem, m in files.items():
            m.export(staging / meshdir / f"{stem}.obj", file_type="obj", digits=10)
        tree.write(staging / path.name, encoding="unicode")
        _compiles(staging / path.name, path)
        final_dir = path.parent / meshdir
        if final_dir.exists():
            shutil.rmtree(final_dir)
        os.replace(staging / meshdir, final_dir)
        os.replace(staging / path.name, path)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return path

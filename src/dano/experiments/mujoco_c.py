"""A user's own object simulated by another engine: slides made with plain MuJoCo C.

:func:`mujoco_c_slides` makes a system-identification data set that dano did not simulate:
a mesh is scaled and centred, simulated by MuJoCo (``mujoco.MjModel`` + ``mj_step``, the C
engine, not MJX) sliding on a ground plane, and written as CSV trajectories next to the DANO
built from the same OBJ and a ``problem.toml`` with defaults only (what a new user writes first).

Units SI (m, kg, s), world z up, the ground is z = 0, quaternions w, x, y, z. The recorded pose is
MuJoCo's body frame (the free joint's qpos): the mesh's own axes with origin at its volume centroid,
i.e. the object-frame pose of the DANO of the written OBJ (whose centre of mass is that centroid).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from ..asset import build, save
from ..fields import mesh_field

_XML = """<mujoco model="toy">
  <option timestep="{timestep}" cone="elliptic"/>
  <asset><mesh name="toy" file="toy.obj" inertia="exact"/></asset>
  <worldbody>
    <geom name="ground" type="plane" size="0 0 1" friction="{friction} 0.005 0.0001"/>
    <body name="toy">
      <freejoint/>
      <geom name="toy" type="mesh" mesh="toy" mass="{mass}" friction="{friction} 0.005 0.0001"/>
    </body>
  </worldbody>
</mujoco>
"""


def mujoco_c_slides(out_dir, mesh="bunny_lowpoly.obj", size=0.2, mass=0.7, friction=0.5, slides=3, rate=100.0,
                    duration=1.0, timestep=0.002, seed=0, num_samples=2000, max_tilt=10.0, max_draws=20,
                    push=0.1) -> dict:
    """Write ``slides`` MuJoCo slides of ``mesh`` and the matching dano problem into ``out_dir``.

    mesh: a watertight mesh file (pass its path, e.g. the shared ``data/meshes/bunny_lowpoly.obj``),
    scaled uniformly so that its longest bounding-box extent is ``size`` [m] and translated so that
    its volume centroid is the origin (written as ``toy.obj``). ``scene.xml``: a ground plane and one
    free body of mass ``mass`` [kg] (MuJoCo collides with the mesh's convex hull; inertia from the
    exact mesh volume); sliding friction ``friction`` on both geoms (MuJoCo takes the larger of a pair),
    elliptic friction cone (a Coulomb cone, not the default pyramid), time step ``timestep`` [s].

    The body rests on the face of its convex hull that best resists tipping by friction (largest
    d/h: centroid to the face's nearest edge over centroid height; a friction above it tips the
    object; returned as tip_friction), settled in MuJoCo for 0.5 s. Each slide: from that rest pose
    (x = y = 0) a horizontal force through the centre of mass pushes it for ``push`` s up to
    1.0-1.6 m/s in a random direction; at release (t = 0) a yaw rate of up to 0.5 rad/s is added
    (``seed``); recorded for ``duration`` s at ``rate`` Hz as ``slide_k.csv`` (columns
    t,x,y,z,qw,qx,qy,qz). A slide in which the object tilts by ``max_tilt`` [deg] or more is
    redrawn, at most ``max_draws`` times (then RuntimeError). ``toy.dano``: ``dano.build`` of the
    mesh's density field with the same mass. ``problem.toml``: scene (dt = 1/rate, the rest pose),
    the trajectories and sliding_friction to identify (defaults otherwise: no [contact], [options]).

    Returns a dict: out_dir, obj, xml, dano, toml, csv (list of paths), friction (the true value),
    tip_friction, speeds [m/s] (at release), stop_distances [m] (first to last position of each
    slide), max_tilts_deg (each slide's largest tilt), size [m] (bounding-box extents), mass [kg]
    (MuJoCo's body mass), dano_com [m] (the DANO's centre of mass, object frame), rest_pose (x, y, z,
    qw, qx, qy, qz).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    m = trimesh.load(mesh, process=False, force="mesh")
    m.merge_vertices(merge_tex=True, merge_norm=True)
    m.apply_scale(size / float(np.max(m.extents)))
    m.apply_translation(-m.center_mass)
    obj = out / "toy.obj"
    m.export(obj)

    hull = m.convex_hull  # rest on the hull face that resists tipping by friction best: largest d/h
    best = (-np.inf, 0.0, None)
    for f in list(hull.facets) + [[i] for i in range(len(hull.faces))]:
        n = hull.face_normals[f[0]]
        h = float(n @ hull.triangles[f[0], 0])  # centroid height above the face [m]
        basis = np.linalg.svd(n[None])[2][1:]  # the face plane's axes; the centroid projects to (0, 0)
        d = float(np.min(-ConvexHull(hull.triangles[f].reshape(-1, 3) @ basis.T).equations[:, 2]))
        best = max(best, (d / h, h, n), key=lambda b: b[0])  # d: centroid to the face's nearest edge [m]
    tip_friction, h, n = best  # a slide with friction above d/h tips the object over
    q = np.zeros(4)
    mujoco.mju_quatZ2Vec(q, -n)  # rotates z onto -n; its inverse turns the face normal n down
    q[1:] *= -1
    xml = out / "scene.xml"
    xml.write_text(_XML.format(timestep=timestep, friction=friction, mass=mass))
    model = mujoco.MjModel.from_xml_path(str(xml))
    data = mujoco.MjData(model)
    body = model.body("toy").id
    data.qpos[2:] = [h + 1e-3, *q]
    for _ in range(int(round(0.5 / timestep))):  # settle into MuJoCo's soft contact
        mujoco.mj_step(model, data)
    rest = data.qpos.copy()
    rest[:2] = 0.0
    rest[3:] /= np.linalg.norm(rest[3:])
    R0 = np.zeros(9)
    mujoco.mju_quat2Mat(R0, rest[3:])
    up = R0.reshape(3, 3)[2]  # the world's up direction in the body frame at rest

    rng = np.random.default_rng(seed)
    every = max(1, int(round(1.0 / (rate * timestep))))
    frames = int(round(duration * rate)) + 1
    csvs, stops, tilts, speeds = [], [], [], []
    for k in range(slides):
        for draw in range(max_draws):  # a slide in which the object tips is drawn again
            mujoco.mj_resetData(model, data)
            data.qpos[:] = rest
            heading = 2 * np.pi * ((k + rng.uniform()) / slides if draw == 0 else rng.uniform())
            u = np.array([np.cos(heading), np.sin(heading), 0.0])
            # pushed through the centre of mass for `push` s up to the speed, then released at t = 0
            # (a velocity set impulsively at rest makes MuJoCo's soft contact throw the object up)
            data.xfrc_applied[body, :3] = mass * (rng.uniform(1.0, 1.6) / push - friction * model.opt.gravity[2]) * u
            tilt = 0.0
            for _ in range(int(round(push / timestep))):
                mujoco.mj_step(model, data)
                tilt = max(tilt, float(np.arccos(np.clip(data.xmat[body].reshape(3, 3)[2] @ up, -1, 1))))
            data.xfrc_applied[:] = 0.0
            mujoco.mj_forward(model, data)  # (after mj_step, x* quantities lag qpos by one step)
            data.qvel[3:] += data.xmat[body].reshape(3, 3)[2] * rng.uniform(-0.5, 0.5)  # yaw rate, body frame
            data.time = 0.0
            mujoco.mj_forward(model, data)
            speeds.append(float(np.linalg.norm(data.qvel[:2])))
            rows = []
            for i in range(frames):
                for _ in range(every if i else 0):
                    mujoco.mj_step(model, data)
                    tilt = max(tilt, float(np.arccos(np.clip(data.xmat[body].reshape(3, 3)[2] @ up, -1, 1))))
                rows.append([data.time, *data.qpos[:7]])  # the free joint: body position, quaternion
            if tilt < np.radians(max_tilt):
                break
            speeds.pop()
        else:
            raise RuntimeError(f"slide {k}: the object tipped over {max_tilt} deg in each of {max_draws} draws")
        rows = np.array(rows)
        csvs.append(out / f"slide_{k}.csv")
        np.savetxt(csvs[-1], rows, delimiter=",", header="t,x,y,z,qw,qx,qy,qz", comments="", fmt="%.9g")
        stops.append(float(np.linalg.norm(rows[-1, 1:4] - rows[0, 1:4])))
        tilts.append(float(np.degrees(tilt)))

    asset = build(mesh_field(obj), mass=mass, num_samples=num_samples, seed=seed, name="toy")
    dano_path = save(asset, out / "toy.dano")

    toml = out / "problem.toml"
    fmt = lambda v: "[" + ", ".join(f"{x:.9g}" for x in v) + "]"  # noqa: E731
    lines = ["[scene]", f"dt = {1.0 / rate!r}", "", "[[scene.object]]", 'name = "toy"', 'asset = "toy.dano"',
             f"pos = {fmt(rest[:3])}", f"quat = {fmt(rest[3:])}", ""]
    for p in csvs:
        lines += ["[[trajectory]]", f'file = "{p.name}"', 'object = "toy"', ""]
    lines += ["[[parameter]]", 'name = "sliding_friction"', "initial = 0.3", "lower = 0.0", "upper = 2.0"]
    toml.write_text("\n".join(lines) + "\n")
    return {"out_dir": out, "obj": obj, "xml": xml, "dano": dano_path, "toml": toml, "csv": csvs,
            "friction": friction, "tip_friction": tip_friction, "speeds": speeds, "stop_distances": stops,
            "max_tilts_deg": tilts,            "size": m.extents.tolist(), "mass": float(model.body_mass[body]),
            "dano_com": asset.center_of_mass.tolist(), "rest_pose": rest.tolist()}

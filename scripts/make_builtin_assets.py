"""Regenerate the assets shipped in src/dano/data from ../shared/data.

Run from the repository root: ``python scripts/make_builtin_assets.py``. Needs the
``fast-simplification`` package (only here, to decimate the bunny's visual mesh).
"""

from pathlib import Path

import numpy as np
import trimesh

import dano
from dano.asset import build, save
from dano.fields import mesh_field
from dano.io import load_paper_collider

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT / ".." / "shared" / "data"
OUT = ROOT / "src" / "dano" / "data"


def paper_bunny():
    """The paper's collider, with its level-set mesh (iso 105) decimated to 3000 faces as
    the visual mesh. That mesh is wound inward: flip it so its normals point out."""
    mesh = trimesh.load(SHARED / "dano" / "bunny_high.obj", process=False)
    mesh.merge_vertices()
    if mesh.volume < 0:
        mesh.invert()
    small = mesh.simplify_quadric_decimation(face_count=3000)
    path = OUT / "_bunny_visual.obj"
    small.export(path)
    try:
        return load_paper_collider(SHARED / "dano" / "bunny.jld2", visual_mesh=path, name="bunny")
    finally:
        path.unlink()


def lowpoly_bunny():
    """A queryable DANO from the watertight low-poly Stanford bunny (pybullet_data, zlib):
    turned upright (ears along +z: +90° about x) and scaled by 0.5 (0.72 units tall), uniform
    density, mass 3.2 (like the paper bunny), SDF grid of 64 nodes."""
    mesh = trimesh.load(SHARED / "meshes" / "bunny_lowpoly.obj", process=False)
    mesh.merge_vertices()
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    mesh.apply_scale(0.5)
    field = mesh_field(mesh, resolution=64)
    return build(field, mass=3.2, num_samples=5000, seed=0, name="bunny_lowpoly", mesh_resolution=48,
                 source="bunny_lowpoly.obj (pybullet_data, zlib licence; Stanford 3D Scanning Repository), "
                        "rotated +90 deg about x, scaled 0.5")


def bluesoap():
    """The paper's real-soap collider. Its stored gradients are all zero (an export bug), so
    normals come from the paper's φ = 0.70 level-set mesh (bluesoap_level_70.stl)."""
    return load_paper_collider(SHARED / "dano" / "bluesoap.jld2", name="bluesoap",
                               normals_mesh=SHARED / "dano" / "bluesoap_level_70.stl")


if __name__ == "__main__":
    import shutil

    print(save(bluesoap(), OUT / "bluesoap.dano"))
    shutil.copyfile(SHARED / "real" / "soap_pose_traj.csv", OUT / "soap_pose_traj.csv")
    print(save(paper_bunny(), OUT / "bunny.dano"), dano.__version__)
    print(save(lowpoly_bunny(), OUT / "bunny_lowpoly.dano"))

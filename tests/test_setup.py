"""Process set-up done on import: the XLA flag trap is handled or reported, and MuJoCo gets
an OpenGL back-end it can load."""

import os
import subprocess
import sys

import pytest

from dano._jax_setup import jaxlib_has_fusion_flag

# a minimal environment (no user XLA_FLAGS, no display); PYTHONPATH kept for installs that use it
BARE = {"PATH": "/usr/bin:/bin", "JAX_PLATFORMS": "cpu",
        **({"PYTHONPATH": os.environ["PYTHONPATH"]} if "PYTHONPATH" in os.environ else {})}


def test_warns_when_jax_started_before_dano_without_the_flag():
    code = "import jax, jax.numpy as jnp; jnp.ones(2) + 1; import dano.sim"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=BARE, timeout=300)
    assert res.returncode == 0, res.stderr
    # jaxlib 0.11 has no such flag: nothing to warn about
    assert ("xla_cpu_use_fusion_emitters=false" in res.stderr) is jaxlib_has_fusion_flag()


def test_sets_the_flag_when_imported_first():
    code = "import os, dano, dano.sim; print(os.environ['XLA_FLAGS'])"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=BARE, timeout=300)
    assert res.returncode == 0, res.stderr
    assert ("--xla_cpu_use_fusion_emitters=false" in res.stdout) is jaxlib_has_fusion_flag()
    assert "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=" in res.stdout
    assert "RuntimeWarning" not in res.stderr


def test_keeps_the_users_own_backend_options():
    code = "import os, dano, dano.sim; print(os.environ['XLA_FLAGS'])"
    own = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=0"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**BARE, "XLA_FLAGS": own}, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.count("xla_backend_extra_options") == 1 and own in res.stdout


def test_fusion_flag_only_for_a_jaxlib_that_knows_it(monkeypatch):
    """jaxlib 0.11 removed --xla_cpu_use_fusion_emitters and aborts on it: dano sets it only
    for older jaxlib (read from the package metadata)."""
    import importlib.metadata

    from dano._jax_setup import jaxlib_has_fusion_flag

    for installed, expected in (("0.10.2", True), ("0.8.0", True), ("0.11.2", False), ("0.12.0rc1", False)):
        monkeypatch.setattr(importlib.metadata, "version", lambda name, v=installed: v)
        assert jaxlib_has_fusion_flag() is expected


def test_headless_gl_backend_is_one_the_system_can_load(monkeypatch):
    """EGL where libEGL is found, else OSMesa, else none: MuJoCo told to use EGL without
    libEGL failed at ``import mujoco`` (PyOpenGL's AttributeError), seen on a CUDA machine."""
    import ctypes.util

    from dano._jax_setup import headless_gl_backend

    for found, expected in (({"EGL", "OSMesa"}, "egl"), ({"OSMesa"}, "osmesa"), (set(), "disable")):
        monkeypatch.setattr(ctypes.util, "find_library", lambda name, f=found: f"lib{name}.so" if name in f else None)
        assert headless_gl_backend() == expected


@pytest.mark.parametrize("user_value", [None, "disable"])
def test_without_opengl_dano_simulates_and_a_video_is_a_clear_error(tmp_path, user_value):
    """With MuJoCo's OpenGL disabled (what dano picks on a machine without libEGL or libOSMesa),
    a simulation still runs and writes its trajectory; asking for a video fails with one line
    naming MUJOCO_GL, non-zero, and leaves no file. The user's own MUJOCO_GL is kept."""
    env = {**BARE, "MUJOCO_GL": "disable"} if user_value else BARE
    code = "import os, dano.sim; print(os.environ['MUJOCO_GL'])"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr
    from dano._jax_setup import headless_gl_backend

    assert res.stdout.strip() == (user_value or headless_gl_backend())
    if user_value:
        out, video = tmp_path / "t.npz", tmp_path / "v.mp4"
        args = ["simulate", "bunny-drop", "--duration", "0.05", "--out", str(out)]
        res = subprocess.run([sys.executable, "-m", "dano.cli", *args], capture_output=True, text=True, env=env,
                             timeout=300)
        assert res.returncode == 0, res.stderr
        assert out.is_file()
        out.unlink()
        res = subprocess.run([sys.executable, "-m", "dano.cli", *args, "--video", str(video)], capture_output=True,
                             text=True, env=env, timeout=300)
        assert res.returncode != 0
        assert "MUJOCO_GL=disable" in res.stderr and "Traceback" not in res.stderr
        assert not video.exists() and not out.exists()

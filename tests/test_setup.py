"""Process set-up done on import: the XLA flag trap is handled or reported."""

import subprocess
import sys


def test_warns_when_jax_started_before_dano_without_the_flag():
    code = "import jax, jax.numpy as jnp; jnp.ones(2) + 1; import dano.sim"
    env = {"PATH": "/usr/bin:/bin", "JAX_PLATFORMS": "cpu"}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "xla_cpu_use_fusion_emitters=false" in res.stderr


def test_sets_the_flag_when_imported_first():
    code = "import os, dano, dano.sim; print(os.environ['XLA_FLAGS'])"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PATH": "/usr/bin:/bin", "JAX_PLATFORMS": "cpu"}, timeout=300)
    assert res.returncode == 0, res.stderr
    assert "--xla_cpu_use_fusion_emitters=false" in res.stdout
    assert "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=" in res.stdout
    assert "RuntimeWarning" not in res.stderr


def test_keeps_the_users_own_backend_options():
    code = "import os, dano, dano.sim; print(os.environ['XLA_FLAGS'])"
    own = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=0"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={"PATH": "/usr/bin:/bin", "JAX_PLATFORMS": "cpu", "XLA_FLAGS": own}, timeout=300)
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

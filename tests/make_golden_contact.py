"""Make tests/data/golden_contact.npz: the golden trajectory of the bunny drop WITH contact.

The built-in scene ``bunny-drop`` (the paper's bunny thrown from 1.1 m, tumbling to rest on
the ground, 500 steps of 10 ms) simulated in float64 with each contact model (centroid,
per_sample); qpos, qvel and ψ every EVERY-th step are stored (about 40 kB). The test
``tests/test_sim_physics.py::test_paper_bunny_drop_matches_the_golden_trajectory``
re-simulates the drop and compares; tests/test_float32.py takes its float64 resting pose as
the reference for float32. (tests/test_golden_mujoco.py is the contact-free golden, against
MuJoCo C.)

When to regenerate: only after a deliberate change of what the drop simulates (the step,
the contact law or its parameters, the bunny asset, the scene), never to make the test
pass after an unexplained change. Run the test first and look at how far it is off.

How, from the repository root (a few seconds after the compilation):

    PYTHONPATH=src .venv/bin/python tests/make_golden_contact.py

and commit the new .npz with the change that explains it.
"""

from __future__ import annotations

import os
from pathlib import Path

GOLDEN = Path(__file__).resolve().parent / "data" / "golden_contact.npz"
MODELS = ("centroid", "per_sample")
STEPS = 500  # 5 s: the drop, the first impacts, the tumbling and the rest
EVERY = 5  # store every 5th step (101 rows per model)


def simulate_drop(contact_model: str):
    """(setup, trajectory) of the built-in bunny drop, STEPS steps, in JAX's current float
    type (the caller turns float64 on)."""
    from dano.sim import rollout
    from dano.sim.scenes import load_scene

    setup = load_scene("bunny-drop", contact_model=contact_model)
    return setup, rollout(setup.scene, setup.state0, None, setup.params, STEPS)


def golden_arrays(traj, contact_model: str) -> dict:
    """What the .npz stores for one contact model."""
    import numpy as np

    return {f"{contact_model}_{key}": np.asarray(getattr(traj, key))[::EVERY] for key in ("qpos", "qvel", "psi")}


def main() -> None:
    os.environ.setdefault("NPROC", "1")
    import jax
    import mujoco
    import numpy as np

    import dano

    dano.enable_float64()
    arrays = {}
    for model in MODELS:
        setup, traj = simulate_drop(model)
        assert traj.qpos.dtype == np.float64, traj.qpos.dtype
        arrays.update(golden_arrays(traj, model))
    versions = f"jax {jax.__version__}, mujoco {mujoco.__version__}, dano {getattr(dano, '__version__', '?')}"
    GOLDEN.parent.mkdir(exist_ok=True)
    np.savez_compressed(GOLDEN, steps=STEPS, every=EVERY, models=np.array(MODELS), versions=versions, **arrays)
    print(f"wrote {GOLDEN} ({GOLDEN.stat().st_size} bytes; {versions})")


if __name__ == "__main__":
    main()

"""``mujoco.mjx``, imported with its start-up chatter silenced.

mujoco-mjx 3.17 *prints* "Failed to import warp" to standard output when the optional
Warp backend is absent (always, on CPU machines), which would corrupt machine-readable
output such as ``dano ... --json``. Import MJX through this module.
"""

import contextlib
import io

with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # noqa: F401

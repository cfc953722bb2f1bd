"""Mechanical energy of a free DANO (a check of the contact solve: without actuation it
must not grow)."""

from __future__ import annotations

import numpy as np

from ..pose import quat_to_matrix


def mechanical_energy(scene, qpos: np.ndarray, qvel: np.ndarray, alpha: float | None = None,
                      gravity: float = 9.81) -> np.ndarray:
    """Kinetic + gravitational potential energy [J] of the scene's single free DANO,
    (..., T) from qpos (..., T, 7) and qvel (..., T, 6) (angular velocity in the body frame);
    potential m·g·z with z the centre-of-mass height above z = 0."""
    m = scene.mj_model
    body = scene.body_names.index(scene.dano_names[0])
    scale = 1.0 if alpha is None else alpha / scene.assets[0].alpha
    mass, I = m.body_mass[body] * scale, m.body_inertia[body] * scale
    Ri = quat_to_matrix(m.body_iquat[body])
    w = qvel[..., 3:6] @ Ri  # body-frame angular velocity in principal axes
    return (0.5 * mass * np.sum(qvel[..., :3] ** 2, -1) + 0.5 * np.sum(I * w**2, -1)
            + mass * gravity * qpos[..., 2])

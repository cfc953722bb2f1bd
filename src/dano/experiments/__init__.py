"""The paper's reproductions and dano's studies, as named experiments built on the library.

The library (``dano.fields`` … ``dano.tracking``) never imports this package; the command
line resolves built-in names through :data:`EXPERIMENTS` (``dano sysid soap``, ``dano
trajopt push-sphere``, ``dano real2sim synthetic-slide``), and ``dano bench`` runs the
studies. Each experiment is registered here with the verb that runs it, a one-line
summary, its typed configuration class (a frozen dataclass, or None when it takes no
settings) and the function that runs it, imported only when it runs (in the spirit of
nerfstudio's ``method_configs``).

Modules: :mod:`.sysid_examples` (the soap video, the bunny pushes, the ContactNets cube,
coverage studies), :mod:`.mujoco_c` (slides recorded in plain MuJoCo C), :mod:`.push` and
:mod:`.grasp` (the push and grasp tasks), :mod:`.trajopt_run` (their runs and outputs),
:mod:`.slide` and :mod:`.real2sim` (the synthetic slide video and video → physics),
:mod:`.nerf_loop` (the NeRF ground-truth loop), :mod:`.meshroute` (DANO vs mesh, the paper's
Fig. 8), :mod:`.energy` (random drops and the energy check), :mod:`.tracking_curves`
(tracking success curves).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable

from ..errors import DanoError


@dataclass(frozen=True)
class Experiment:
    """A registered experiment.

    name: its built-in name (``soap``); verb: the ``dano`` verb that runs it (``sysid``);
    summary: one line for help texts; runner: ``"module:function"`` inside this package;
    config: ``"module:Class"`` of its typed configuration, or None.
    """

    name: str
    verb: str
    summary: str
    runner: str
    config: str | None = None

    def _load(self, ref: str):
        module, attr = ref.split(":")
        return getattr(importlib.import_module(f"{__name__}.{module}"), attr)

    @property
    def run(self) -> Callable:
        """The function that runs it (its module imported now)."""
        return self._load(self.runner)

    @property
    def config_class(self) -> type | None:
        """Its configuration class (its module imported now), or None."""
        return None if self.config is None else self._load(self.config)


_ALL = (
    Experiment("soap", "sysid", "friction of the paper's real soap video (bluesoap collider, 120 fps)",
               "sysid_examples:run_example"),
    Experiment("bunny-pushes", "sysid", "the bunny's mass scale and friction from 10 simulated pushes",
               "sysid_examples:run_example"),
    Experiment("bunny-dynamics", "sysid", "the same pushes with the bunny's centre of mass and inertia unknown too",
               "sysid_examples:run_example"),
    Experiment("contactnets-cube", "sysid", "real cube tosses (ContactNets): fit half, predict the other half",
               "sysid_examples:run_contactnets", "sysid_examples:ContactNetsConfig"),
    Experiment("push-sphere", "trajopt", "the paper's Fig. 7: a floating sphere pushes the bunny to a goal",
               "trajopt_run:run", "push:PushSphereConfig"),
    Experiment("push-panda", "trajopt", "the Panda's joint torques push the bunny to a goal",
               "trajopt_run:run", "push:PushPandaConfig"),
    Experiment("grasp-panda", "trajopt", "the Panda's hand grasps, lifts and holds the bunny",
               "trajopt_run:run", "grasp:GraspPandaConfig"),
    Experiment("synthetic-slide", "real2sim", "a rendered slide video -> poses -> friction, and pixels -> friction",
               "real2sim:synthetic_slide_real2sim"),
)

#: every registered experiment, by (verb, name)
EXPERIMENTS: dict[tuple[str, str], Experiment] = {(e.verb, e.name): e for e in _ALL}


def names(verb: str) -> tuple[str, ...]:
    """The built-in names a verb resolves (``names("sysid")`` → soap, bunny-pushes, ...)."""
    return tuple(name for v, name in EXPERIMENTS if v == verb)


def get(verb: str, name: str) -> Experiment:
    """The experiment ``name`` of ``verb``. Raises DanoError listing the verb's names."""
    try:
        return EXPERIMENTS[(verb, name)]
    except KeyError:
        raise DanoError(f"unknown {verb} experiment {name!r}: one of {', '.join(names(verb))}") from None


def is_experiment(verb: str, name: str) -> bool:
    """Whether ``name`` is a built-in experiment of ``verb`` (else a file, e.g. a TOML problem)."""
    return (verb, name) in EXPERIMENTS


def run_sysid(name: str, **options):
    """Run a built-in identification: ``soap``, ``bunny-pushes``, ``bunny-dynamics``
    (options ``jacobian``, ``noise``) or ``contactnets-cube`` (options of
    :class:`~dano.experiments.sysid_examples.ContactNetsConfig`). Returns (problem, result,
    {"report", "config"}) as :func:`dano.sysid.config.run`."""
    exp = get("sysid", name)
    if exp.config is None:
        return exp.run(name, **options)
    return exp.run(exp.config_class(**options))


__all__ = ["EXPERIMENTS", "Experiment", "get", "is_experiment", "names", "run_sysid"]

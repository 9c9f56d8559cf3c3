"""The controller interface: ``reset()``, then ``controller(observation, info) -> action``.

Controllers are vectorised: one controller drives any number of rigs. Given one observation,
shape (10,), it returns one action, shape (1,); given n observations, (n, 10), of rigs ``ids``
(default 0 to n-1), it returns their n actions, (n, 1), and keeps each rig's state apart, so a
comparison over many seeds, or a vector environment, never loops over rigs in Python.
Every controller (the baselines and learned policies) reads only the observation, what the rig's
sensors give, never the simulator's truth, so that they are compared on equal terms by one harness.
What an observation holds and what an action means is :mod:`microg_env.interface`'s (its
:class:`~microg_env.interface.Readings` decodes observations into SI units). A controller that
closes its loop on x may take a setpoint (:class:`SetpointController`): the residual mode of the environment moves it.
"""

from __future__ import annotations

from typing import Any, ClassVar, Protocol

import numpy as np

from microg_env.params import RigParams


class Controller(Protocol):
    """What the environment, the CLI and the evaluation harness drive."""

    def reset(self, ids: np.ndarray | None = None) -> None:
        """Forget the previous episode of rigs ``ids`` (None: of every rig)."""

    def __call__(self, observation: np.ndarray, info: Any = None, ids: np.ndarray | None = None) -> np.ndarray:
        """The action for this observation, (1,), or for n observations of rigs ``ids``, (n, 1); in [-1, 1]."""


class SetpointController(Controller, Protocol):
    """A controller holding each rig's x at ``setpoint_m[rig]`` (0 for the rig's purpose, x = 0)."""

    setpoint_m: np.ndarray


def tell_plants(controller: Controller, ids: np.ndarray, plants: list[RigParams], *, ideal_drive: bool) -> None:
    """Tell a controller that takes it (the ``oracle``: ``know_plants``) the true plants of its rigs
    ``ids`` after their reset, and whether their drive is ideal (a speed source); every other
    controller is told nothing."""
    know = getattr(controller, "know_plants", None)
    if know is not None:
        know(ids, plants, ideal_drive=ideal_drive)


class VectorController:
    """Per-rig state for a vectorised controller: the arrays named in :attr:`STATE`, each with the
    value an episode starts from, grown to the rigs the controller has seen. ``parts`` are the
    controllers it drives inside (a feedback loop, a base controller): they are reset and grown with it."""

    STATE: ClassVar[dict[str, float]] = {}

    def __init__(self, *parts: VectorController) -> None:
        self.parts = parts
        self.size = 1  # how many rigs the state arrays hold
        for name, start in self.STATE.items():
            setattr(self, name, np.full(1, start))

    def reset(self, ids: np.ndarray | None = None) -> None:
        for part in self.parts:
            part.reset(ids)
        if ids is None:
            for name, start in self.STATE.items():
                getattr(self, name)[:] = start
            return
        ids = np.asarray(ids, dtype=np.int64)
        self.grow(int(ids.max(initial=-1)) + 1)
        for name, start in self.STATE.items():
            getattr(self, name)[ids] = start

    def grow(self, count: int) -> None:
        """Make room for rigs 0 to ``count`` - 1 (new rigs start an episode)."""
        if count <= self.size:
            return
        for part in self.parts:
            part.grow(count)
        for name, start in self.STATE.items():
            setattr(self, name, np.concatenate([getattr(self, name), np.full(count - self.size, start)]))
        self.size = count

    def __call__(self, observation: np.ndarray, info: Any = None, ids: np.ndarray | None = None) -> np.ndarray:
        observation = np.asarray(observation)
        rows = observation[None] if observation.ndim == 1 else observation
        if ids is None:  # rigs 0 to n-1
            self.grow(len(rows))
            index = _RIGS[: len(rows)] if len(rows) <= _RIGS.size else np.arange(len(rows))
        else:
            index = np.asarray(ids, dtype=np.int64)
            self.grow(int(index.max(initial=-1)) + 1)
        actions = np.asarray(self.act(rows, index), dtype=np.float32)
        return actions if observation.ndim == 1 else actions[:, None]

    def act(self, rows: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """The actions (n,) for observations ``rows`` (n, 10) of rigs ``ids`` (an index array), float32
        (the action space's type)."""
        raise NotImplementedError


#: Rig numbers 0, 1, ... as an index array (the rigs a call with ``ids=None`` drives).
_RIGS = np.arange(4096)

"""The controller interface: ``reset()``, then ``controller(observation, info) -> action``.

Controllers are vectorised: one controller drives any number of rigs. Given one observation,
shape (10,), it returns one action, shape (1,); given n observations, (n, 10), of rigs ``ids``
(default 0 to n-1), it returns their n actions, (n, 1), and keeps each rig's state apart, so a
comparison over many seeds, or a vector environment, never loops over rigs in Python.
Every controller (the baselines and learned policies) reads only the observation, what the rig's
sensors give, never the simulator's truth, so that they are compared on equal terms by one harness.
:class:`Readings` decodes an observation into SI units. A controller that closes its loop on x
may take a setpoint (:class:`SetpointController`): the residual mode of the environment moves it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np

from microg_env.envs.observation import OBSERVATION_INDEX
from microg_env.envs.observation import SCALES as _SCALES
from microg_env.params import RigParams, ScrewStageParams

#: Drive speed that the action +-1 stands for, m/s: the paper's rig's maximum (Section 4.1), a
#: fixed unit of the action whatever rig is simulated (a slower drive saturates on its own).
MAX_SPEED_M_S = ScrewStageParams().max_speed_m_per_s


class Controller(Protocol):
    """What the environment, the CLI and the evaluation harness drive."""

    def reset(self, ids: np.ndarray | None = None) -> None:
        """Forget the previous episode of rigs ``ids`` (None: of every rig)."""

    def __call__(self, observation: np.ndarray, info: Any = None, ids: np.ndarray | None = None) -> np.ndarray:
        """The action for this observation, (1,), or for n observations of rigs ``ids``, (n, 1); in [-1, 1]."""


class SetpointController(Controller, Protocol):
    """A controller holding each rig's x at ``setpoint_m[rig]`` (0 for the rig's purpose, x = 0)."""

    setpoint_m: np.ndarray


def tell_plants(controller: Controller, ids: np.ndarray, plants: list[RigParams]) -> None:
    """Tell a controller that takes it (the ``oracle``: ``know_plants``) the true plants of its rigs
    ``ids`` after their reset; every other controller is told nothing."""
    know = getattr(controller, "know_plants", None)
    if know is not None:
        know(ids, plants)


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


@dataclass(frozen=True)
class Readings:
    """Observations (n, 10) in SI units (OBSERVATION_SCALES), one (n,) array per reading."""

    x_m: np.ndarray  # grating ruler
    x_rate_m_s: np.ndarray
    support_position_m: np.ndarray  # servo encoder, above touchdown
    support_velocity_m_s: np.ndarray
    lander_accel_m_s2: np.ndarray  # accelerometer, g removed, up positive
    pad_force_n: np.ndarray
    foot_height_m: np.ndarray
    placed_load_kg: np.ndarray

    @classmethod
    def of(cls, observations: np.ndarray) -> Readings:
        si = observations * _SCALES  # float64

        def get(name: str) -> np.ndarray:
            return si[:, OBSERVATION_INDEX[name]]

        return cls(
            get("x"),
            get("x_rate"),
            get("support_position"),
            get("support_velocity"),
            get("lander_accel"),
            get("pad_force"),
            get("height"),
            get("placed_load"),
        )

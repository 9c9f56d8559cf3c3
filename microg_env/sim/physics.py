"""The physics of N rigs of one compiled model: state as (N, ...) arrays, per-rig model fields, stepping.

Two backends give the same interface, so everything above them (:mod:`microg_env.envs.core`) is one
code path for one rig and for many:

* :class:`ModelPhysics`: one rig, the model and one ``MjData`` (N = 1); the arrays are views of them,
  so rendering, copying and pickling see the rig as it is.
* :class:`BatchPhysics`: N rigs on :class:`mujoco.batch.Batch`, stepped on a thread pool; per-rig
  model fields are the batch's expanded fields (``Batch.expand``), so no rig's episode touches the
  shared model and nothing is recompiled.

MuJoCo promises the batch bit-identical to a loop of ``mj_step``; the batch is persistent so that
its sensors and accelerations are those of the last substep, as ``MjData``'s are.

A forked child inherits every batch of its parent but none of their threads, and freeing such a
batch waits on those threads (it hung, or aborted): a child keeps its inherited batches until it
exits, and must not step one (make a new environment in the child).
"""

from __future__ import annotations

import os
import weakref

import mujoco
import mujoco.batch
import numpy as np

from microg_env.workers import usable_cores

#: Data fields the rig core reads or writes, each (N, size).
STATE_FIELDS = ("qpos", "qvel", "act", "ctrl", "qfrc_applied", "qacc", "sensordata", "actuator_force")

#: A model field write: (MjModel field name, index into one rig's field, value).
FieldWrite = tuple[str, tuple | int | np.ndarray, float | np.ndarray]


class ModelPhysics:
    """One rig: ``model`` and ``data``, with (1, ...) views of their fields."""

    num_rigs = 1

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self._bind()

    def _bind(self) -> None:
        for name in STATE_FIELDS:
            setattr(self, name, getattr(self.data, name)[None])

    def field(self, name: str) -> np.ndarray:
        """The model field ``name`` as a live (1, ...) array."""
        return getattr(self.model, name)[None]

    def write(self, rig: int, writes: list[FieldWrite]) -> None:
        for name, index, value in writes:
            getattr(self.model, name)[index] = value

    def reset(self, ids: np.ndarray) -> None:
        mujoco.mj_resetData(self.model, self.data)

    def forward(self, ids: np.ndarray) -> None:
        mujoco.mj_forward(self.model, self.data)

    def step(self, ids: np.ndarray, nstep: int) -> None:
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def __getstate__(self) -> dict:
        return {"model": self.model, "data": self.data}

    def __setstate__(self, state: dict) -> None:
        self.model, self.data = state["model"], state["data"]
        self._bind()


#: Every live :class:`BatchPhysics` of this process, and the batches a forked child inherited
#: (kept, never freed: see the module's docstring).
_LIVE_BATCHES: weakref.WeakSet[BatchPhysics] = weakref.WeakSet()
_INHERITED_BATCHES: list[mujoco.batch.Batch] = []


def _keep_inherited_batches() -> None:
    _INHERITED_BATCHES.extend(physics.batch for physics in _LIVE_BATCHES)


os.register_at_fork(after_in_child=_keep_inherited_batches)


class BatchPhysics:
    """N rigs on a persistent :class:`mujoco.batch.Batch` of ``model`` on ``nthread`` threads (0: one
    per core this process may run on, :func:`~microg_env.workers.usable_cores`, not MuJoCo's every
    core of the machine)."""

    def __init__(self, model: mujoco.MjModel, num_rigs: int, nthread: int = 0) -> None:
        self.model = model
        self.num_rigs = num_rigs
        self.batch = mujoco.batch.Batch(model, num_rigs, nthread=nthread or usable_cores(), persistent=True)
        _LIVE_BATCHES.add(self)
        for name in STATE_FIELDS:
            setattr(self, name, self.batch.bind(name))
        self._fields: dict[str, np.ndarray] = {}

    def field(self, name: str) -> np.ndarray:
        """The model field ``name``, per rig, as a live (N, ...) array."""
        if name not in self._fields:
            self._fields[name] = self.batch.expand(name)
        return self._fields[name]

    def write(self, rig: int, writes: list[FieldWrite]) -> None:
        for name, index, value in writes:
            self.field(name)[rig][index] = value

    def reset(self, ids: np.ndarray) -> None:
        self.batch.reset(ids=ids, stage=mujoco.mjtStage.mjSTAGE_NONE)

    def forward(self, ids: np.ndarray) -> None:
        self.batch.forward(ids=ids)

    def step(self, ids: np.ndarray, nstep: int) -> None:
        self.batch.step(ids=None if ids.size == self.num_rigs else ids, nstep=nstep)

    def __getstate__(self) -> dict:
        raise TypeError("a batch of rigs cannot be copied or pickled; make a new vector environment")

"""The controller interface: ``reset()``, then ``controller(observation, info) -> action``.

Every controller (the baselines and learned policies) reads only the observation, what the rig's
sensors give, never the simulator's truth, so that they are compared on equal terms by one harness.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np


class Controller(Protocol):
    """What the environment, the CLI and the evaluation harness drive."""

    def reset(self) -> None:
        """Forget the previous episode."""

    def __call__(self, observation: np.ndarray, info: dict[str, Any]) -> np.ndarray:
        """The action for this observation, shape (1,), in [-1, 1]."""

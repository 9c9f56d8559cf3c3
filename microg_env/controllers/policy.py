"""A learned policy behind the controller interface."""

from __future__ import annotations

from typing import Any

import numpy as np


class PolicyController:
    """A learned policy (anything with ``predict(obs, deterministic=True)``, e.g. stable-baselines3)."""

    def __init__(self, policy: Any, deterministic: bool = True) -> None:
        self.policy = policy
        self.deterministic = deterministic

    def reset(self) -> None:
        """Policies here are feed-forward; nothing to forget."""

    def __call__(self, observation: np.ndarray, info: dict[str, Any]) -> np.ndarray:
        action, _ = self.policy.predict(observation, deterministic=self.deterministic)
        return np.asarray(action, dtype=np.float32).reshape(1)

"""The ids the package no longer makes: each refuses, naming the last release that has it and the id
that follows it (Gymnasium's way: the id stays registered and raises ``DeprecatedEnv``)."""

from __future__ import annotations

from gymnasium.error import DeprecatedEnv

#: Each retired id: the last microg-env release that has it, and its successor.
RETIRED = {
    f"MicroGravityLanding-Residual-v{version}": ("0.25.0", "MicroGravityLanding-Residual-v7") for version in range(1, 6)
}


def retirement(env_id: str) -> str:
    """Why ``env_id`` (retired) is refused, and where to find it."""
    release, successor = RETIRED[env_id]
    return (
        f"{env_id} is retired: microg-env {release} has it (pip install 'microg-env=={release}'); "
        f"its successor is {successor}"
    )


def refuse(env_id: str, **_kwargs) -> None:
    """A retired id's entry point (single and vector): raises ``DeprecatedEnv``."""
    raise DeprecatedEnv(retirement(env_id))

"""Gymnasium environments of pirl_sim (optional extra ``pirl_sim[highway]``: highway-env and gymnasium).

``pirl_sim/Roundabout-v0`` (:class:`~pirl_sim.envs.roundabout.PirlRoundaboutEnv`): drive through
highway-env's roundabout among PIRL drivers of known, diverse weights. Importing this package registers it
(:func:`register_envs`, idempotent, a lazy string entry point: highway-env is imported only when an env is
made), so with ``pirl_sim`` importing it::

    import gymnasium, pirl_sim
    gymnasium.register_envs(pirl_sim)   # a no-op that keeps linters from flagging the import
    env = gymnasium.make("pirl_sim/Roundabout-v0", config={"initial_vehicles": 12})

Gymnasium 1.x ignores ``gymnasium.envs`` entry points, hence the registration on import; without
gymnasium installed this package registers nothing.
"""

from __future__ import annotations

__all__ = ["ENV_IDS", "register_envs", "PirlRoundaboutEnv"]

#: registered environment ids -> entry points
ENV_IDS: dict[str, str] = {
    "pirl_sim/Roundabout-v0": "pirl_sim.envs.roundabout:PirlRoundaboutEnv",
}


def register_envs() -> bool:
    """Register :data:`ENV_IDS` with gymnasium (idempotent: ids already registered are left alone).

    Returns
    -------
    bool
        False when gymnasium is not installed (nothing registered), else True.
    """
    try:
        from gymnasium.envs.registration import register, registry
    except ImportError:
        return False
    for env_id, entry_point in ENV_IDS.items():
        if env_id not in registry:
            register(id=env_id, entry_point=entry_point)
    return True


register_envs()


def __getattr__(name: str):
    if name == "PirlRoundaboutEnv":  # imports highway-env: only on use
        from .roundabout import PirlRoundaboutEnv

        return PirlRoundaboutEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

"""Gymnasium environments of pirl_sim (optional extra ``pirl_sim[highway]``: highway-env and gymnasium).

``pirl_sim/Roundabout-v0``: drive through a roundabout among PIRL drivers of known, diverse weights, on
highway-env (:class:`~pirl_sim.envs.roundabout.PirlRoundaboutEnv`, the default) or, with
``config={"backend": "sumo"}``, on SUMO (:class:`~pirl_sim.envs.sumo_roundabout.PirlRoundaboutSumoEnv`,
extra ``pirl_sim[sumo]``); :func:`make_roundabout` picks the backend. Importing this package registers it
(:func:`register_envs`, idempotent, a lazy entry point), so with ``pirl_sim`` importing it::

    import gymnasium, pirl_sim
    gymnasium.register_envs(pirl_sim)   # a no-op that keeps linters from flagging the import
    env = gymnasium.make("pirl_sim/Roundabout-v0", config={"initial_vehicles": 12})

The env and its registration are explained in the documentation's "The gymnasium environment" page.
"""

from __future__ import annotations

__all__ = ["ENV_IDS", "BACKENDS", "register_envs", "make_roundabout", "PirlRoundaboutEnv"]

#: registered environment ids -> entry points
ENV_IDS: dict[str, str] = {
    "pirl_sim/Roundabout-v0": "pirl_sim.envs:make_roundabout",
}
BACKENDS = ("highway", "sumo")  #: values of the roundabout env's ``backend`` option


def make_roundabout(config: dict | None = None, render_mode: str | None = None):
    """``pirl_sim/Roundabout-v0`` on the backend that ``config["backend"]`` names (default ``"highway"``)."""
    from collections.abc import Mapping

    backend = config.get("backend", "highway") if isinstance(config, Mapping) else "highway"
    if backend == "highway":
        from .roundabout import PirlRoundaboutEnv

        return PirlRoundaboutEnv(config=config, render_mode=render_mode)
    if backend == "sumo":
        from .sumo_roundabout import PirlRoundaboutSumoEnv

        return PirlRoundaboutSumoEnv(config=config, render_mode=render_mode)
    raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")


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

"""What both backends of ``pirl_sim/Roundabout-v0`` are checked with (tests/envs/test_roundabout.py: highway-env,
tests/envs/test_sumo_roundabout.py: SUMO): bad actions and bad env configs with the errors they raise, and a spy on
the scenario adapters' ``start``. Test modules ``from env_checks import ...`` (tests/conftest.py puts tests/ on
sys.path)."""

import numpy as np

#: (action, error type, message regex) of actions ``step`` rejects
BAD_ACTIONS = [
    (None, TypeError, "action must be a finite number"),
    ("0.5", TypeError, "action must be a finite number"),
    (np.array([np.nan], dtype=np.float32), ValueError, "action must be a finite number"),
    (np.array([np.inf]), ValueError, "action must be a finite number"),
    (np.array([0.1, 0.2]), ValueError, r"got shape \(2,\)"),
    (np.zeros((1, 1)), ValueError, r"got shape \(1, 1\)"),
]

#: (env config, message regex) of configs the env rejects, naming the key
ENV_CONFIG_ERRORS = [
    ({"observation": {"type": "Kinematics", "vehicles_count": "8"}}, r"vehicles_count must be an integer >= 1"),
    ({"observation": {"type": "Kinematics", "vehicles_count": 0}}, r"vehicles_count must be an integer >= 1"),
    ({"observation": {"type": "Kinematics", "features": ["warp"]}}, r"features.*'warp'.*valid: presence"),
    ({"observation": {"type": "Kinematics", "features": "x"}}, r"features must be a non-empty list"),
    ({"observation": {"type": "Kinematics", "features_range": {"x": [5, -5]}}}, r"features_range\['x'\]"),
    ({"observation": {"type": "Kinematics", "order": "random"}}, r"order must be one of"),
    ({"action": {"type": "LongitudinalAcceleration", "acceleration_range": None}},
     r"acceleration_range must be \[a_min < 0, a_max > 0\]"),
    ({"action": {"type": "LongitudinalAcceleration", "acceleration_range": [None, 3]}},
     r"acceleration_range\[0\] must be a finite number"),
    ({"ego_speed": 1e9}, r"ego_speed must be in \[0, 30\] m/s"),
]


def spy_on_start(monkeypatch, adapter_type):
    """Record every ``adapter_type.start`` call (keywords and the simulation it returned), and count the steps
    of the simulations it returns; the real start runs."""
    calls, steps = [], []
    real_start = adapter_type.start

    def start(self, config, seed, plan, **kwargs):
        sim = real_start(self, config, seed, plan, **kwargs)
        if not calls:  # the simulation type's step, counted once
            real_step = type(sim).step
            monkeypatch.setattr(type(sim), "step", lambda s: (steps.append(s), real_step(s))[1])
        calls.append({"config": config, "seed": seed, "plan": plan, "sim": sim, **kwargs})
        return sim

    monkeypatch.setattr(adapter_type, "start", start)
    return calls, steps

"""Registration of ``pirl_sim/Roundabout-v0`` (pirl_sim/envs/__init__.py): idempotent and lazy, through the
package, and by a module-prefixed id."""

import subprocess
import sys

import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("highway_env")

import pirl_sim.envs  # noqa: E402,F401  (registers the env ids)
from pirl_sim.envs import ENV_IDS, register_envs  # noqa: E402


def test_registration_is_idempotent_and_lazy():
    assert register_envs() and register_envs()  # twice: no duplicate-registration error
    for env_id, entry_point in ENV_IDS.items():
        assert gym.spec(env_id).entry_point == entry_point
    # registering imports neither highway-env nor the env module
    code = ("import sys, pirl_sim.envs, gymnasium; assert 'pirl_sim/Roundabout-v0' in gymnasium.registry; "
            "print('highway_env' in sys.modules, 'pirl_sim.envs.roundabout' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False"]


def _wired() -> bool:
    code = "import sys, pirl_sim; print('pirl_sim.envs' in sys.modules)"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout.strip() == "True"


@pytest.mark.xfail(not _wired(), strict=True,
                   reason="pirl_sim/__init__.py does not import pirl_sim.envs yet")
def test_register_envs_of_the_package_makes_the_env():
    code = ("import gymnasium, pirl_sim; gymnasium.register_envs(pirl_sim); "
            "env = gymnasium.make('pirl_sim/Roundabout-v0'); env.reset(seed=0); print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.stdout.strip() == "ok", out.stderr[-2000:]


def test_module_prefixed_id_imports_the_package_itself():
    code = "import gymnasium; env = gymnasium.make('pirl_sim.envs:pirl_sim/Roundabout-v0'); env.reset(seed=0)"
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)

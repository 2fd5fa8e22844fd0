"""Executors (pirl_sim.engine.executors): the local start method, the parent watch, and no worker left behind when
the sweep's main process is killed."""

import os
import signal
import subprocess
import sys
import time

import pytest

from sweep_configs import sweep_toml


# A sweep whose cells take long enough that the workers are busy when the main process is killed.
_ORPHAN_CONFIG = sweep_toml("orphans", [0, 1, 2, 3], """
scenario = "synthetic"
params = { n_trajectories = 600, n_train = 500 }
protocols = ["paper"]
learners = ["tirl", "pirl-dpgmm", { name = "pirl-gmm", grid = { n_components = [2, 3] } }]
""")


def _group_members(pgid: int) -> list[int]:
    """Live (not zombie) processes of process group ``pgid`` (Linux /proc)."""
    members = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) "
        state, group = fields[0], int(fields[2])
        if group == pgid and state != "Z":
            members.append(int(entry))
    return members

def _watching(pid: int) -> bool:
    """Whether process ``pid`` runs a second thread: a spawn worker's parent watch has started (its BLAS runs one
    thread, the resource tracker has no other thread)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return any(line.startswith("Threads:") and int(line.split()[1]) >= 2 for line in f)
    except OSError:
        return False


@pytest.mark.skipif(not os.path.isdir("/proc") or not hasattr(os, "killpg"), reason="needs Linux /proc")
@pytest.mark.parametrize("busy", [False, True], ids=["idle-workers", "busy-workers"])
def test_sigkill_of_sweep_main_process_leaves_no_worker(tmp_path, busy):
    """Killing only the main process (not its group) ends its spawn workers and the resource tracker too, within
    seconds once the workers have started (their parent watch running), however loaded the machine."""
    cfg = tmp_path / "orphans.toml"
    cfg.write_text(_ORPHAN_CONFIG)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "pirl_sim", "sweep", str(cfg), "--out", str(out), "--workers", "2", "--quiet"],
        start_new_session=True,  # its own process group, so that the test can find (and at the end clean up) children
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            children = [p for p in _group_members(proc.pid) if p != proc.pid]
            started = (out / "cells").is_dir() and any((out / "cells").glob("*.json"))
            watching = sum(_watching(p) for p in children)
            if len(children) >= 3 and watching >= 2 and (started or not busy):  # two workers and the tracker
                break
            time.sleep(0.05)
        assert proc.poll() is None, f"the sweep ended before it could be killed: {proc.stderr.read().decode()}"
        children = [p for p in _group_members(proc.pid) if p != proc.pid]
        assert len(children) >= 3, children
        os.kill(proc.pid, signal.SIGKILL)  # the main process only
        proc.wait(timeout=30)
        deadline = time.monotonic() + 30.0  # a poll every PARENT_POLL_SECONDS, then os._exit; slack for load
        while time.monotonic() < deadline and _group_members(proc.pid):
            time.sleep(0.05)
        survivors = _group_members(proc.pid)
        assert not survivors, f"processes left running after the sweep's main process died: {survivors}"
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        if proc.poll() is None:
            proc.wait(timeout=30)


def test_watch_parent_rejects_bad_arguments():
    from pirl_sim.engine.executors import watch_parent

    with pytest.raises(ValueError, match="parent_pid"):
        watch_parent(0)
    with pytest.raises(ValueError, match="parent_pid"):
        watch_parent(True)
    with pytest.raises(ValueError, match="interval"):
        watch_parent(os.getppid(), interval=0.0)


def test_local_executor_start_method_is_spawn_or_fork():
    from pirl_sim.engine.executors import LocalExecutor

    with pytest.raises(ValueError, match="start_method must be 'spawn' or 'fork', got 'forkserver'"):
        LocalExecutor(1, start_method="forkserver")
    with LocalExecutor(1, start_method="fork") as ex:  # a forked worker runs a task like a spawned one
        assert ex.submit(sum, [1, 2]).result() == 3

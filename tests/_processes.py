"""Child processes of the tests: a training command signalled once it is under way."""

import signal
import subprocess
import time

from gof_warp.training.checkpoint import list_checkpoints


def signal_after_first_checkpoint(cmd, cwd, run, sig: int, timeout: float) -> tuple[subprocess.Popen, str]:
    """Start ``cmd`` (a training into ``run``) with the default disposition of ``sig`` (even where this runner ignores
    it, e.g. a background job), send ``sig`` once the run's first checkpoint exists, and wait for the process to end.
    Returns the process and its standard error; fails if it ends before a checkpoint or takes over ``timeout`` s."""
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(sig, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + timeout
        while not list_checkpoints(run):
            assert proc.poll() is None, f"training ended before its first checkpoint: {proc.communicate()}"
            assert time.monotonic() < deadline, f"no checkpoint after {timeout} s"
            time.sleep(0.05)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc, err

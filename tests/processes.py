"""A process killed at a controlled moment, for tests of interrupted work (no timing guesses)."""

import signal
import subprocess
import sys


def kill_when_it_says(code: str, *args: str, line: str) -> None:
    """Run ``python -c code *args``, wait until it prints ``line`` (the moment to kill it at), then SIGKILL it."""
    proc = subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == line
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        proc.kill()
        proc.wait()

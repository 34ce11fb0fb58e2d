"""A module that sends SIGINT to its own process as it is imported: a Ctrl-C that reaches a process while it
imports (tests/test_worker_pools.py preloads it into the solver pool's forkserver)."""

import os
import signal

os.kill(os.getpid(), signal.SIGINT)

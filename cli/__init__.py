"""The `vpp` command line."""

import time

STARTED = time.perf_counter()
"""When the command started (before its heavy imports): a plan's time budget counts from here."""

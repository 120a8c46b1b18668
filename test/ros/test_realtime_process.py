"""A node of a realtime loop is scheduled as a whole process (ros/realtime_process.py): the nice
value reaches every thread, the middleware's too, and bad settings are refused in one line."""

from __future__ import annotations

import subprocess
import sys

import pytest

from elastic_pm_dyn.ros.realtime_process import refusal

CHILD = """
import os, threading, time
from elastic_pm_dyn.ros.realtime_process import prepare
started = threading.Event()
threading.Thread(target=lambda: (started.set(), time.sleep(5)), daemon=True).start()  # a receive thread
started.wait()
class Log:
    def warning(self, text): print("WARNING", text)
print(prepare(Log(), [], 0, False, nice=7))
print(sorted({os.getpriority(os.PRIO_PROCESS, int(t)) for t in os.listdir('/proc/self/task')}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="threads listed in /proc (Linux)")
def test_nice_reaches_every_thread_of_the_process() -> None:
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    applied, nices = out.stdout.strip().splitlines()[-2:]
    assert applied == "['nice 7']"
    assert nices == "[7]"  # the thread started before prepare too: a setting per thread would leave it at 0


@pytest.mark.parametrize("values, word", [({"realtime.nice": -21}, "realtime.nice"),
                                          ({"realtime.nice": 20}, "realtime.nice"),
                                          ({"realtime.priority": 100}, "realtime.priority"),
                                          ({"realtime.cpu_affinity": [-1]}, "realtime.cpu_affinity")])
def test_out_of_range_settings_are_one_line(values: dict, word: str) -> None:
    p = {"realtime.nice": 0, "realtime.priority": 0, "realtime.cpu_affinity": []} | values
    why = refusal(p)
    assert why is not None and word in why and "\n" not in why
    assert refusal({"realtime.nice": -5, "realtime.priority": 10, "realtime.cpu_affinity": [0]}) is None

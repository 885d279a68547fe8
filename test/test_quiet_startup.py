"""Loading the body model prints nothing on stdout / stderr: Warp's banner is switched off and what its
native library still prints (the CUDA driver warning on a CPU machine) goes to the logger instead.

Both claims are read from one fresh process (Warp initializes once per process): it loads the model with
every log record captured in memory, prints `loaded`, then the captured records after a separator line.
Whatever else reaches stdout or stderr before the separator was printed by the load."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SEPARATOR = "----- log -----"
LOAD = f"""
import io, logging, sys
buffer = io.StringIO()
handler = logging.StreamHandler(buffer)
handler.setFormatter(logging.Formatter('%(levelno)s|%(name)s|%(message)s'))
logging.getLogger().addHandler(handler)
logging.getLogger().setLevel(logging.DEBUG)
from smplify3d_ros.body import load_body_model
load_body_model('anny')
print('loaded')
sys.stdout.flush(); sys.stderr.flush()
print({SEPARATOR!r})
print(buffer.getvalue(), end='')
"""


@pytest.fixture(scope="module")
def load_output() -> tuple[str, list[tuple[int, str, str]]]:
    """(what the load printed, the log records as (level, logger, message))."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, "-c", LOAD], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    printed, _, log = proc.stdout.partition(SEPARATOR + "\n")
    records = [tuple(line.split("|", 2)) for line in log.splitlines() if line.count("|") >= 2]
    return printed + proc.stderr, [(int(level), name, message) for level, name, message in records]


def test_loading_the_body_model_is_quiet(load_output):
    printed, records = load_output
    assert printed.strip() == "loaded", printed
    # without a logging setup, Python prints records of WARNING and above on stderr: none may come
    loud = [r for r in records if r[0] >= 30 and ("Warp" in r[2] or "CUDA" in r[2])]
    assert not loud, loud


def test_what_warp_prints_reaches_the_log(load_output):
    _, records = load_output
    lines = [r for r in records if "Warp" in r[2] or "CUDA" in r[2]]
    if not lines:
        pytest.skip("Warp prints nothing on this machine (a CUDA driver is there): nothing to route")
    assert all(name == "smplify3d_ros.body" for _, name, _ in lines), lines
    assert not any("initialized:" in message for _, _, message in lines), "the banner is off, not only captured"

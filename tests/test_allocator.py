"""streamfix.allocator: a process that keeps its freed memory maps no new pages for arrays it
allocates again (measured in fresh processes: the setting is process-wide and set once)."""
from __future__ import annotations

import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc",
                                reason="the thresholds are glibc's")

# what a window solve does: a dozen arrays of 1.7 MB each (a 120 Hz take's window) made, used and
# freed, again and again; the page faults of the cycles after a warm-up one are printed
CYCLES = """
import resource, sys
import numpy as np
from streamfix.allocator import keep_freed_memory
if sys.argv[1] == "keep":
    print(keep_freed_memory())
def cycle():
    arrays = [np.ones((2241, 93)) for _ in range(12)]
    del arrays
cycle()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(5):
    cycle()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _run(code: str, *args: str, env: dict | None = None) -> list[str]:
    env = dict(os.environ if env is None else env, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, env=env,
                         timeout=120, check=True)
    return out.stdout.split()


def _clean_env() -> dict:
    return {k: v for k, v in os.environ.items() if not k.startswith(("MALLOC_", "GLIBC_TUNABLES"))}


def test_kept_memory_is_reused_without_page_faults():
    default = int(_run(CYCLES, "default", env=_clean_env())[-1])
    applied, kept = _run(CYCLES, "keep", env=_clean_env())
    assert applied == "True"
    assert default > 5 * 2000  # glibc's defaults: most of the 5 x 20 MB mapped afresh (4 KiB pages)
    assert int(kept) < default / 20


def test_the_users_own_malloc_settings_win():
    env = dict(_clean_env(), MALLOC_TRIM_THRESHOLD_="1000000")
    assert _run("from streamfix.allocator import keep_freed_memory; print(keep_freed_memory())", env=env) == ["False"]


def test_the_streamfix_command_keeps_freed_memory(tmp_path):
    code = ("import streamfix.allocator as a, sys; from streamfix.cli import main; "
            "rc = main(['keys', sys.argv[1]]); print(rc, a._applied)")
    assert _run(code, str(tmp_path / "keys"), env=_clean_env())[-2:] == ["0", "True"]

"""``arsurf warmup`` builds numba's cache so that the demo after it compiles nothing (issue 28).

Two fresh processes on one cache folder, as after an install: the warm-up, then the demo with a
listener on numba's ``numba:compile`` event (it fires only when a kernel is compiled, never when
one is loaded from the cache). A kernel the warm-up misses, a signature the demo reaches that the
warm-up does not (another dtype, layout or literal), or a cache entry the demo cannot load shows
up here by name.
"""
import json
import os
import subprocess
import sys

import pytest

_DEMO_COUNTING_COMPILES = r"""
import json, sys
from numba.core import event

compiled = []


class Count(event.Listener):
    def on_start(self, ev):
        pass

    def on_end(self, ev):
        d = ev.data["dispatcher"]
        compiled.append(f"{d.py_func.__module__}.{d.py_func.__qualname__}{tuple(ev.data['args'])}"[:300])


event.register("numba:compile", Count())  # for the whole process (install_listener is a context manager)
from arsurf.cli import main

code = main(["demo", "--no-images", "--out", sys.argv[1]])
print("##" + json.dumps({"code": code, "compiled": compiled}))
"""


@pytest.mark.slow
def test_the_demo_after_the_warmup_compiles_nothing(tmp_path):
    env = dict(os.environ)  # the cache folder arsurf chooses (keyed on its sources), or the one set
    warm = subprocess.run([sys.executable, "-m", "arsurf", "warmup"], capture_output=True, text=True, env=env,
                          timeout=3600)
    assert warm.returncode == 0, warm.stderr[-3000:]
    assert warm.stdout.startswith("arsurf warm-up: numba cache built in "), warm.stdout
    demo = subprocess.run([sys.executable, "-c", _DEMO_COUNTING_COMPILES, str(tmp_path / "demo")],
                          capture_output=True, text=True, env=env, timeout=1200)
    line = next((x for x in demo.stdout.splitlines() if x.startswith("##")), None)
    assert demo.returncode == 0 and line is not None, demo.stderr[-3000:]
    result = json.loads(line[2:])
    assert result["code"] == 0
    assert result["compiled"] == [], f"the demo compiled {len(result['compiled'])} kernels the warm-up did not " \
        f"cache: {result['compiled']}"

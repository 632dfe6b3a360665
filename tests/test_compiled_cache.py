"""Compiled kernels follow the sources they inline (`workers.backends.compiled`)."""

import os
import subprocess
import sys
import textwrap

from conftest import ROOT

from workers.backends.compiled import sources_digest
from workers.montecarlo import photons

KERNEL = """
import sys
from pathlib import Path

import numba

sys.path.insert(0, str(Path(__file__).parent))
from helper import value  # noqa: E402

from workers.backends.compiled import refresh_stale  # noqa: E402


@numba.njit(cache=True)
def kernel():
    return value() + 1.0


refresh_stale((kernel,), sources=[Path(__file__).parent / "helper.py", __file__])
print(kernel())
"""


def helper(number):
    """A helper module the kernel inlines, returning `number`."""
    return textwrap.dedent(
        f"""
        import numba


        @numba.njit(cache=True)
        def value():
            return {number}
        """
    )


def run_kernel(folder):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_CACHE_DIR": str(folder / "cache")}
    done = subprocess.run(
        [sys.executable, str(folder / "kernel.py")],
        capture_output=True,
        text=True,
        env=env,
        check=True,
        timeout=120,
    )
    return float(done.stdout.split()[-1])


def test_a_kernel_compiles_again_when_a_source_it_inlines_changes(tmp_path):
    # numba keys a cached kernel by its own file alone: an edited helper in another file
    # kept running compiled into it (the fifteen-bug harness's restored plant failed a
    # Monte Carlo test on pristine code). The kernel's cache is flushed when the digest
    # of what it inlines changes.
    (tmp_path / "kernel.py").write_text(KERNEL)
    (tmp_path / "helper.py").write_text(helper(1.0))
    assert run_kernel(tmp_path) == 2.0
    assert run_kernel(tmp_path) == 2.0  # from the cache
    (tmp_path / "helper.py").write_text(helper(5.0))
    stamp = os.stat(tmp_path / "helper.py").st_mtime + 10.0
    os.utime(tmp_path / "helper.py", (stamp, stamp))  # the helper recompiles on its own
    assert run_kernel(tmp_path) == 6.0


def test_the_photon_kernels_are_guarded_by_every_source_they_inline():
    inlined = {path.resolve() for path in photons.INLINED}
    targets = ROOT / "workers" / "targets"
    assert {p.resolve() for p in targets.glob("*.py")} <= inlined
    assert (ROOT / "workers" / "optics" / "fresnel.py").resolve() in inlined
    assert (ROOT / "workers" / "montecarlo" / "scattering.py").resolve() in inlined
    stamp = photons.transport._cache._cache_path
    name = "workers.montecarlo.photons.transport.sources"
    assert open(os.path.join(stamp, name)).read() == sources_digest(photons.INLINED)

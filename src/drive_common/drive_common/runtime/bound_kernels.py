"""Kernels that take an estimator's step kernel as their first argument, bound to one step and cached on disk.
numba types a kernel passed as an argument by its dispatcher object, named after the function's address in this
process: a kernel taking it is a cache miss in every process and compiles anew (the runner's loop: seconds per
`drive run`). Bound here, the step and the kernel are globals of a small caller named after both and after a
digest of the project's sources, which numba caches like any other kernel (an edit to any source file gives
new names: never a stale kernel). Only the project's own steps are bound; a plugin's step is passed as an
argument (compiled in each process: numba would not see its source change)."""
import functools
import hashlib
import importlib.util
import types
from pathlib import Path

from numba import njit

PACKAGES = ("drive_common", "hf_estimator", "foc_controller", "pmsm_plant", "drive_bridge", "drive_tools")
"""The project's packages: a step from one of them is bound; their sources make the digest."""
CARRIED_OPTIONS = ("_nrt", "nogil", "boundscheck", "fastmath", "error_model")
"""The kernel's compile options the bound caller takes over (not ``inline``: the caller is called from Python)."""


def _calls_with_step_4(a, b, c, d):
    return KERNEL(STEP, a, b, c, d)  # noqa: F821 (bound: a global of each copy)


def _calls_with_step_7(a, b, c, d, e, f, g):
    return KERNEL(STEP, a, b, c, d, e, f, g)  # noqa: F821 (bound: a global of each copy)


CALLERS = {4: _calls_with_step_4, 7: _calls_with_step_7}
"""The caller per number of arguments after the step."""


@functools.cache
def sources_digest():
    """A digest of every Python source of the project's packages (12 hex digits)."""
    digest = hashlib.sha1()
    for package in PACKAGES:
        for folder in importlib.util.find_spec(package).submodule_search_locations:
            for path in sorted(Path(folder).rglob("*.py")):
                digest.update(str(path.relative_to(folder)).encode())
                digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


@functools.cache
def bound(kernel, step):
    """``kernel`` (a numba dispatcher whose first parameter takes a step kernel) with ``step`` bound: a callable
    taking the rest of its arguments, cached on disk when ``step`` is the project's own."""
    if step.__module__.split(".")[0] not in PACKAGES:
        return functools.partial(kernel, step)
    n = kernel.py_func.__code__.co_argcount - 1
    if n not in CALLERS:
        raise ValueError(f"bound: {kernel.__name__} takes {n} arguments after the step; callers exist for "
                         f"{sorted(CALLERS)}")
    template = CALLERS[n]
    caller = types.FunctionType(template.__code__, {"__name__": __name__, "KERNEL": kernel, "STEP": step},
                                template.__name__)
    caller.__qualname__ = (f"{kernel.__module__}.{kernel.__name__}[{step.__module__}.{step.__name__}]"
                           f"{sources_digest()}")
    options = {key: value for key, value in kernel.targetoptions.items() if key in CARRIED_OPTIONS}
    return njit(cache=True, **options)(caller)

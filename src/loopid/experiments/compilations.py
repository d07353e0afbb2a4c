"""How many XLA programs a process built: compiled anew, or loaded from JAX's persistent
compilation cache (:func:`loopid.experiments.backend.compile_cache`).

JAX reports every program it builds for a ``jit`` call it has not seen in this process (an event
around its backend compile, which a persistent-cache hit short-circuits) and every persistent-cache
hit; :func:`programs` counts both since :func:`install` in this process. A program reused within
the process (JAX's in-memory cache) is neither: it costs nothing. A cell records the difference
over its run (:mod:`loopid.experiments.cell`), and ``report.md`` sums them.

Counting uses :mod:`jax.monitoring`'s listeners, the interface JAX offers for it: the counts are
process-wide, so cells that run at once as threads of one process (one GPU) share theirs.
"""

import threading
from typing import NamedTuple

from jax import monitoring

#: The event JAX records around building one program (its compilation or its cache load).
BUILD_EVENT = "/jax/core/compile/backend_compile_duration"
#: The event JAX records when a program came from the persistent compilation cache.
CACHE_HIT_EVENT = "/jax/compilation_cache/cache_hits"

_lock = threading.Lock()
_built = [0, 0]  # programs built, of which loaded from the persistent cache
_installed = [False]


class Programs(NamedTuple):
    """Programs built: ``compiled`` anew, ``loaded`` from the persistent compilation cache."""

    compiled: int
    loaded: int

    def __sub__(self, other: "Programs") -> "Programs":
        return Programs(self.compiled - other.compiled, self.loaded - other.loaded)


def _on_duration(event: str, duration: float, **kwargs) -> None:
    if event == BUILD_EVENT:
        with _lock:
            _built[0] += 1


def _on_event(event: str, **kwargs) -> None:
    if event == CACHE_HIT_EVENT:
        with _lock:
            _built[1] += 1


def install() -> None:
    """Start counting in this process (once; later calls do nothing)."""
    with _lock:
        if _installed[0]:
            return
        _installed[0] = True
    monitoring.register_event_duration_secs_listener(_on_duration)
    monitoring.register_event_listener(_on_event)


def programs() -> Programs:
    """The programs this process built since :func:`install` (installs it on first use)."""
    install()
    with _lock:
        built, loaded = _built
    return Programs(built - loaded, loaded)

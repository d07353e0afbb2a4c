"""What a learned policy actually flies: the helicopter's closed-loop path under a saved policy,
``trajectories.png`` of a helicopter run, and ``loopid animate``'s GIF.

:func:`fly` is the test trajectory of :mod:`loopid.algorithms.plant` with its states kept: from
the task's start ``x_0``, ``Δu_t = −K_t Δx_t`` (under the ``latency`` reading ``−K_{t−d}
Δx_{t−d}``, applied at once; under ``fifo`` applied d steps later), process noise ``[T, 6]``,
one ``lax.scan``. The figures use one test trajectory's noise of the seed (the run's own first
test trajectory), the same for every method, so the paths differ by the policy alone.

- hover: position error (m) and attitude error (the error quaternion's vector part, ≈ half the
  rotation angle in rad) over time, per method;
- funnel: the flown path seen from above (east against north) beside the target circle, and
  the altitude over time.
"""

import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from loopid.algorithms.closed_loop import DelayedLoop
from loopid.systems import helicopter as h


def fly(task, K, noise, delay_mode: str = "fifo") -> np.ndarray:
    """States ``X [T+1, 21]`` of policy ``K [T, 4, 21]`` flying ``task`` under ``noise [T, 6]``,
    the delay acting as ``delay_mode`` reads it
    (:class:`~loopid.algorithms.closed_loop.DelayedLoop`)."""
    loop = DelayedLoop(delay_mode, int(task.delay))
    X = _fly(jnp.asarray(task.target), jnp.asarray(task.x0), jnp.asarray(K), jnp.asarray(noise),
             loop=loop)  # fmt: skip
    return np.asarray(X)


@functools.partial(jax.jit, static_argnames=("loop",))
def _fly(target, x0, K, noise, *, loop: DelayedLoop):
    T = K.shape[0]

    def body(carry, inp):
        x, memory = carry
        t, w = inp
        dx = h.to_error(x, target[t])
        seen, t_gain, memory = loop.sense(memory, dx, t)
        x, memory = loop.act(h.step_delayed, x, memory, -K[t_gain] @ seen, w)
        return (x, memory), x

    memory0 = loop.memory0(h.N_STATE, h.N_ACTION)
    _, X = jax.lax.scan(body, (x0, memory0), (jnp.arange(T), noise[:T]))
    return jnp.concatenate([x0[None], X], axis=0)


def errors(task, X) -> tuple[np.ndarray, np.ndarray]:
    """Position error ``[T+1, 3]`` (m, NED) and attitude error ``[T+1, 3]`` of states ``X``."""
    target = np.asarray(task.target)[: X.shape[0]]
    dX = np.asarray(jax.vmap(h.to_error)(jnp.asarray(X), jnp.asarray(target)))
    return dX[:, h.NED], dX[:, 17:20]


def trajectories_figure(panels: list[tuple], path) -> Path:
    """``trajectories.png``: one row per ``(task, flights, title)`` panel, ``flights``
    ``{label: X [T+1, 21]}`` against the task's target (module docstring)."""
    import io

    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from loopid.files import write_atomic_bytes

    fig, grid = plt.subplots(
        len(panels), 2, figsize=(11, 4.0 * len(panels)), squeeze=False, layout="constrained"
    )
    for axes, (task, flights, title) in zip(grid, panels, strict=True):
        _panel(axes, task, flights, title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    path = Path(path)
    write_atomic_bytes(buf.getvalue(), path)
    return path


def _panel(axes, task, flights, title) -> None:
    target = np.asarray(task.target)
    dt = h.DT
    if task.time_varying:  # the funnel: top view and altitude
        ax, ax_alt = axes
        ned = target[:, h.NED]
        ax.plot(ned[:, 1], ned[:, 0], "k--", lw=1.0, label="target")
        ax_alt.plot(np.arange(len(ned)) * dt, -ned[:, 2], "k--", lw=1.0, label="target")
        for k, (label, X) in enumerate(flights.items()):
            p = np.where(np.isfinite(X[:, h.NED]), X[:, h.NED], np.nan)
            p = np.where(np.abs(p) < 1e3, p, np.nan)  # a diverged flight leaves the axes
            ax.plot(p[:, 1], p[:, 0], color=f"C{k}", lw=1.2, label=label)
            ax_alt.plot(np.arange(len(p)) * dt, -p[:, 2], color=f"C{k}", lw=1.0, label=label)
        ne = ned[:, [1, 0]]  # the view is the target's: a diverging flight leaves it
        center = 0.5 * (ne.min(axis=0) + ne.max(axis=0))
        span = 1.5 * float(np.max(np.abs(ne - center))) + 1.0
        ax.set(xlabel="east (m)", ylabel="north (m)", title=f"{title}: path from above",
               xlim=(center[0] - span, center[0] + span), ylim=(center[1] - span, center[1] + span),
               aspect="equal")  # fmt: skip
        alt = -ned[:, 2]
        ax_alt.set_ylim(alt.min() - 5.0, alt.max() + 5.0)
        ax_alt.set(xlabel="time (s)", ylabel="altitude (m)", title=f"{title}: altitude")
    else:  # hover: position and attitude errors over time
        ax, ax_att = axes
        for k, (label, X) in enumerate(flights.items()):
            pos, att = errors(task, X)
            t = np.arange(len(pos)) * dt
            with np.errstate(over="ignore", invalid="ignore"):  # a diverged flight: inf, drawn off
                size = np.linalg.norm(pos, axis=1), np.linalg.norm(att, axis=1)
            ax.plot(t, size[0], color=f"C{k}", lw=1.0, label=label)
            ax_att.plot(t, size[1], color=f"C{k}", lw=1.0, label=label)
        ax.set(xlabel="time (s)", ylabel="|position error| (m)", yscale="log", ylim=(1e-3, 1e3),
               title=f"{title}: position error")  # fmt: skip
        ax_att.set(xlabel="time (s)", ylabel="|attitude error| (quaternion vector)",
                   yscale="log", title=f"{title}: attitude error")  # fmt: skip
    axes[0].legend(fontsize=7)


def animate(task, flights: dict[str, np.ndarray], path, *, every: int = 4, fps: int = 20) -> Path:
    """An animated GIF (matplotlib + Pillow) of ``flights`` seen from above (funnel) or of their
    position error (hover): each helicopter a dot with its trail, every ``every``-th step."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    target = np.asarray(task.target)
    fig, ax = plt.subplots(figsize=(5.5, 5.5), layout="constrained")
    paths = {}
    for label, X in flights.items():
        if task.time_varying:
            p = X[:, h.NED][:, [1, 0]]  # east, north
        else:
            pos, _ = errors(task, X)
            p = pos[:, [1, 0]]
        paths[label] = np.where(np.isfinite(p) & (np.abs(p) < 1e3), p, np.nan)
    if task.time_varying:
        ax.plot(target[:, h.NED][:, 1], target[:, h.NED][:, 0], "k--", lw=0.8, label="target")
        ax.set(xlabel="east (m)", ylabel="north (m)")
    else:
        ax.plot([0], [0], "k+", ms=12, label="target")
        ax.set(xlabel="east error (m)", ylabel="north error (m)")
    if task.time_varying:  # the view is the target's: a diverging flight leaves it
        ne = target[:, h.NED][:, [1, 0]]  # east, north
        center = 0.5 * (ne.min(axis=0) + ne.max(axis=0))
        span = 1.5 * float(np.max(np.abs(ne - center))) + 1.0
    else:  # hover: the errors, at most 10 m either way
        finite = np.concatenate([p[np.all(np.isfinite(p), axis=1)] for p in paths.values()])
        span = min(float(np.max(np.abs(finite))) if finite.size else 1.0, 10.0)
        center = np.zeros(2)
    ax.set(xlim=(center[0] - 1.1 * span, center[0] + 1.1 * span),
           ylim=(center[1] - 1.1 * span, center[1] + 1.1 * span), aspect="equal")  # fmt: skip
    trails = {lab: ax.plot([], [], color=f"C{k}", lw=1.0)[0] for k, lab in enumerate(paths)}
    dots = {lab: ax.plot([], [], "o", color=f"C{k}", label=lab)[0] for k, lab in enumerate(paths)}
    ax.legend(fontsize=8, loc="upper right")
    clock = ax.set_title("")
    T = max(len(p) for p in paths.values())
    frames = range(0, T, every)

    def draw(i):
        for lab, p in paths.items():
            j = min(i, len(p) - 1)
            trails[lab].set_data(p[: j + 1, 0], p[: j + 1, 1])
            dots[lab].set_data(p[j : j + 1, 0], p[j : j + 1, 1])
        clock.set_text(f"t = {i * h.DT:5.1f} s")
        return [*trails.values(), *dots.values(), clock]

    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp.gif")
    FuncAnimation(fig, draw, frames=frames, blit=False).save(tmp, writer=PillowWriter(fps=fps))
    plt.close(fig)
    tmp.replace(path)
    return path

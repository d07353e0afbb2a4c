"""The paper's helicopter as the loop's plant, and the initial model every method starts from.

The JAX helicopter (:mod:`loopid.systems.helicopter`, 21 error-state entries, 4 actions) under a
task (:mod:`loopid.systems.helicopter.tasks`: hover or the funnel, with its noise, delay and
quadratic cost) is a :class:`loopid.algorithms.plant.Plant` by :func:`helicopter_plant`. The initial
model of Algorithm 1 (the model iteration 1 solves, and the one every learned offset adds to) is
:func:`helicopter_nominal_model`:

- hover tasks: ``A = I [21, 21]`` and ``B [21, 4]`` adding ``Δu`` into the previous-action and
  previous-action-change entries (:func:`loopid.models.linear_offset.hover_nominal`);
- the funnel: a time-varying nominal ``A [T, 21, 21]``, ``B [T, 21, 4]`` of one reading of the
  paper's funnel model (:func:`loopid.systems.helicopter.funnel_nominal.funnel_nominal`;
  ``"spec"``: the simulator linearised about hover trim, the same at every step, plus the
  target's own motion ``−(x*_{t+1} ⊖ x*_t)``).

The experiments' helicopter family builds its scenarios from these two; the engine's tests use
them directly.
"""

from loopid.algorithms.plant import Plant, make_plant
from loopid.models.linear_offset import LinearOffsetModel, hover_nominal
from loopid.systems import helicopter
from loopid.systems.base import Task
from loopid.systems.helicopter.funnel_nominal import funnel_nominal
from loopid.systems.helicopter.tasks import is_hover


def helicopter_plant(task: Task, **options) -> Plant:
    """The helicopter under ``task`` as the loop's plant (``options``: the keywords of
    :func:`loopid.algorithms.plant.make_plant`: ``stop_norm``, ``nu_pending``, ``cost_cap``,
    ``delay_mode``)."""
    return make_plant(task, helicopter.DYNAMICS, **options)


def helicopter_nominal_model(plant: Plant, funnel: str = "spec") -> LinearOffsetModel:
    """The initial linear offset model of ``plant``'s task (module docstring). ``funnel``: the
    reading of the funnel's nominal, one of
    :data:`loopid.systems.helicopter.funnel_nominal.FUNNEL_NOMINALS` (ignored for hover tasks);
    ``ValueError`` for another."""
    if is_hover(plant.task):
        return hover_nominal(helicopter.N_STATE, helicopter.N_ACTION)
    return funnel_nominal(funnel, plant.task)


__all__ = ["helicopter_nominal_model", "helicopter_plant"]

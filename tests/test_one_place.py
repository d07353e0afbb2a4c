"""One place for each idea the engine batches, read from the sources (``ast``):

- the closed-loop step: outside the systems themselves, a system's step (``step_delayed``) is
  called only by :class:`loopid.algorithms.closed_loop.DelayedLoop` (through ``act``) and by the
  plant's one-step generative query, which is not a closed loop;
- agent assembly: the agents (``linear_agent``, ``planning_agent``, ``ilqr_plan``) are built only
  by :func:`loopid.algorithms.agents.make_agent`, which every family calls (the helicopter's
  assembly, and the observed systems' :mod:`loopid.algorithms.host_agent` that the Gymnasium
  family and the round directories share), and by the library's documented ``gym_agent`` (the
  paper's agent for a Gymnasium system).
"""

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parent.parent / "src" / "loopid"


def _calls(name: str) -> list[tuple[str, str]]:
    """``(file, enclosing function)`` of every call of a function called ``name`` in ``src/``."""
    found = []
    for path in sorted(SRC.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if not isinstance(node, ast.FunctionDef):
                continue
            for call in ast.walk(node):
                if not isinstance(call, ast.Call):
                    continue
                f = call.func
                called = f.id if isinstance(f, ast.Name) else getattr(f, "attr", None)
                if called == name:
                    found.append((str(path.relative_to(SRC)), node.name))
    return sorted(set(found))


def _files(found) -> set[str]:
    """The files of the places :func:`_calls` found."""
    return {f for f, _ in found}


def test_a_systems_step_is_called_only_by_the_delayed_loop_and_the_one_step_query():
    files = _files(_calls("step_delayed"))
    allowed = {
        "algorithms/plant.py",  # query: one generative step, no controller
        "systems/helicopter/dynamics.py",  # its own simulate (an open-loop action sequence)
        "systems/helicopter/gymnasium_env.py",  # the Gymnasium env's own step
    }
    assert files <= allowed, files - allowed
    # the closed loops step through DelayedLoop.act
    acting = _files(_calls("act"))
    for f in [
        "algorithms/plant.py",
        "algorithms/mpc_plant.py",
        "algorithms/policy_gradient_rollouts.py",
        "experiments/families/helicopter/flights.py",
    ]:
        assert f in acting, f


def test_agents_are_assembled_in_one_place():
    for constructor in ("linear_agent", "planning_agent", "ilqr_plan"):
        places = _calls(constructor)
        assert {f for f, _ in places} <= {"algorithms/agents.py"}, (constructor, places)
        assert all(fn in ("make_agent", "paper_agent") for _, fn in places), (constructor, places)
    for caller in ("experiments/families/helicopter/assembly.py", "algorithms/host_agent.py"):
        assert caller in _files(_calls("make_agent")), caller

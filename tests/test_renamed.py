"""Names renamed for one idea per name still work for one release, with a ``DeprecationWarning``
that names the new one, and give the very object of the new name."""

import importlib

import pytest

RENAMED = [
    ("loopid.systems.from_gymnasium", "QuadraticCost", "ObservationCost"),
    ("loopid.systems.from_gymnasium", "quadratic_cost", "observation_cost"),
    ("loopid.systems", "QuadraticCost", "ObservationCost"),
    ("loopid.systems", "quadratic_cost", "observation_cost"),
    ("loopid.algorithms.host_loop", "run_learning_host", "run_learning_host"),
    ("loopid.algorithms.host_loop", "nominal_model", "gym_nominal_model"),
    ("loopid.experiments.families.gym", "Learner", "CompiledAgent"),
    ("loopid.experiments.study", "SPEC_PREDICTION", "INDEPENDENT_PREDICTION"),
    ("loopid.experiments.study", "study_text", "study_text"),
    ("loopid.experiments.families.helicopter", "helicopter_plant", "helicopter_plant"),
    ("loopid.experiments.families.helicopter", "nominal_model", "helicopter_nominal_model"),
    ("loopid.experiments.executors", "spread", "spread"),
    ("loopid.experiments.executors", "core_shares", "core_shares"),
    ("loopid.algorithms.loop", "batch_losses", "batch_losses"),
    ("loopid.algorithms.loop", "LearnStats", "LearnStats"),
]
NEW_HOME = {
    "loopid.algorithms.host_loop": "loopid.algorithms.gym_loop",
    "loopid.experiments.study": "loopid.experiments.study_report",
    "loopid.experiments.families.helicopter": "loopid.algorithms.helicopter_plant",
    "loopid.experiments.executors": "loopid.experiments.pool",
    "loopid.algorithms.loop": "loopid.algorithms.loop_program",
}


#: Renamed in their own module: the compiled loop (was "cell", like the unit of work).
RENAMED_IN_PLACE = [
    ("loopid.algorithms.loop", "Cell", "LoopProgram"),
    ("loopid.algorithms.loop", "make_cell", "make_loop_program"),
    ("loopid.algorithms.loop", "cell_memory", "program_memory"),
    ("loopid.algorithms.gym_loop", "HostCell", "HostLoopProgram"),
    ("loopid.algorithms.gym_loop", "make_host_cell", "make_host_program"),
    ("loopid.experiments.families.helicopter", "cell", "loop_program"),
]


@pytest.mark.parametrize(("module", "old", "new"), RENAMED)
def test_an_old_name_warns_and_is_the_new_object(module, old, new):
    with pytest.warns(DeprecationWarning, match=new):
        obj = getattr(importlib.import_module(module), old)
    assert obj is getattr(importlib.import_module(NEW_HOME.get(module, module)), new)


@pytest.mark.parametrize(("module", "old", "new"), RENAMED_IN_PLACE)
def test_a_name_renamed_in_place_warns_and_is_the_new_object(module, old, new):
    with pytest.warns(DeprecationWarning, match=new):
        obj = getattr(importlib.import_module(module), old)
    assert obj is getattr(importlib.import_module(module), new)
    assert old not in getattr(importlib.import_module(module), "__all__", ())


def test_the_old_cell_keyword_warns_and_is_the_program():
    from loopid._renamed import renamed_argument

    program = object()
    with pytest.warns(DeprecationWarning, match="program="):
        assert renamed_argument("run_learning", "cell", "program", program, None) is program
    assert renamed_argument("run_learning", "cell", "program", None, program) is program
    with pytest.raises(TypeError, match="both"):
        renamed_argument("run_learning", "cell", "program", program, program)


def test_an_unknown_name_is_still_an_attribute_error():
    for module in {m for m, _, _ in RENAMED + RENAMED_IN_PLACE}:
        with pytest.raises(AttributeError):
            _ = importlib.import_module(module).no_such_name


def test_the_control_cost_and_the_observation_cost_are_different_names():
    import loopid.control
    import loopid.systems

    assert not hasattr(loopid.systems, "__all__") or "QuadraticCost" not in loopid.systems.__all__
    assert loopid.control.QuadraticCost is not loopid.systems.ObservationCost

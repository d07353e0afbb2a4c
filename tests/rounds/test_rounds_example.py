"""The worked example (examples/rounds/engineer.py) runs and its controllers improve; the
``loopid round`` commands run end to end in a fresh process."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rounds_helpers import transitions, write_config, write_round

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "rounds" / "engineer.py"


def test_example_improves_round_by_round(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("engineer", EXAMPLE)
    engineer = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(engineer)
    costs = engineer.main(["--rounds", "3", "--dir", str(tmp_path / "rig")])
    assert len(costs) == 4
    assert costs[-1] < 0.2 * costs[0]  # controller 1 knows nothing; the learned ones hold
    out = capsys.readouterr().out
    assert "controller 4 as C" in out and (tmp_path / "rig" / "controller-004.h").is_file()


@pytest.mark.slow
def test_round_commands_in_a_fresh_process(tmp_path):
    rng = np.random.default_rng(7)
    root = tmp_path / "dir"

    def loopid(*args):
        cmd = [sys.executable, "-m", "loopid", "round", *map(str, args)]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=300)

    assert loopid("init", root, "--config", write_config(tmp_path / "c.toml")).returncode == 0
    data = write_round(tmp_path / "r.csv", transitions(rng, 40))
    done = loopid("update", root, data)
    assert done.returncode == 0 and done.stdout.startswith("controller 2: loss before"), done
    again = loopid("update", root, data)
    assert again.returncode == 2 and again.stderr.count("\n") == 1, again.stderr
    header = loopid("export", root, "--format", "c")
    assert header.returncode == 0 and header.stdout.strip().endswith("controller-002.h")
    assert (
        "loopid_action(const double *x, int t, double *u)"
        in Path(header.stdout.strip()).read_text()
    )

"""The one policy grammar (coopsumo/policy_spec.py): valid strings to typed specs, invalid strings to messages;
the same message from the command line (one line, exit code 2, nothing written) and from the Gymnasium env."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from coopsumo.errors import USAGE_EXIT
from coopsumo.policy_spec import ADAPTIVE, PolicySpec, PolicySpecError, model_file, parse_policy

REPO = Path(__file__).resolve().parent.parent

VALID: list[tuple[str, PolicySpec]] = [
    ("keep", PolicySpec("keep")),
    ("random", PolicySpec("random")),
    ("greedy", PolicySpec("greedy")),
    ("mobil", PolicySpec("mobil")),
    ("mobil:p=0", PolicySpec("mobil", (("p", 0.0),))),
    ("mobil:b_safe=6,p=0.25", PolicySpec("mobil", (("b_safe", 6.0), ("p", 0.25)))),
    ("mobil:p=1,threshold=0.2,b_safe=3,bias=-0.1",
     PolicySpec("mobil", (("p", 1.0), ("threshold", 0.2), ("b_safe", 3.0), ("bias", -0.1)))),
    ("sumo", PolicySpec("sumo")),
    ("sumo:lcCooperative=0.5,lcSpeedGain=1", PolicySpec("sumo", (("lcCooperative", 0.5), ("lcSpeedGain", 1.0)))),
    ("dqn:m.pt", PolicySpec("dqn", model="m.pt")),
    ("dqn:results/train/run", PolicySpec("dqn", model="results/train/run")),
    ("dqn:a/model.pt,alpha=2", PolicySpec("dqn", model="a/model.pt", alpha=2.0)),
    ("dqn:a/model.pt,alpha=1000", PolicySpec("dqn", model="a/model.pt", alpha=1000.0)),
    ("dqn:a/model.pt,alpha=adaptive", PolicySpec("dqn", model="a/model.pt", alpha=ADAPTIVE)),
    ("dqn:a/model.pt,margin=2", PolicySpec("dqn", model="a/model.pt", margin=2.0)),
    ("dqn:a,margin=0,alpha=adaptive", PolicySpec("dqn", model="a", alpha=ADAPTIVE, margin=0.0)),
    ("dqn:a,noreturn=10,margin=2", PolicySpec("dqn", model="a", margin=2.0, noreturn=10.0)),
    ("dqn:a,restart=5", PolicySpec("dqn", model="a", restart=5.0)),
    ("dqn:a,queue=5,noreturn=10", PolicySpec("dqn", model="a", noreturn=10.0, queue=5.0)),
]  # fmt: skip

INVALID: list[tuple[str, str]] = [
    ("", "policy must be one of"),
    ("dqn:m.pt,alpha=2,alpha=3", "parameter 'alpha' is given twice"),
    ("dqn:m.pt, alpha=2", "has a space"),
    ("dqn:m.pt,", "has an empty parameter"),
    ("dqn:", "dqn needs a model"),
    ("dqn", "dqn needs a model"),
    ("dqn:a,b/model.pt", "a model path cannot hold ','"),
    ("dqn:m.pt,beta=1", "unknown parameter 'beta' of dqn"),
    ("dqn:m.pt,alpha=", "parameter 'alpha' has no value"),
    ("dqn:m.pt,alpha=-1", "alpha must be"),
    ("dqn:m.pt,alpha=nan", "alpha must be"),
    ("dqn:m.pt,margin=-1", "margin must be a finite number >= 0 and <= 100, got '-1'"),
    ("dqn:m.pt,margin=adaptive", "margin must be"),
    ("dqn:m.pt,margin=1,margin=2", "parameter 'margin' is given twice"),
    ("dqn:m.pt,cooldown=10", "cooldown was retired (tried, not adopted: results/history); drive without it"),
    ("dqn:m.pt,noreturn=601", "noreturn must be a finite number >= 0 and <= 600, got '601'"),
    ("dqn:m.pt,noreturn=-1", "noreturn must be a finite number >= 0"),
    ("dqn:m.pt,restart=51", "restart must be a finite number >= 0 and <= 50, got '51'"),
    ("dqn:m.pt,queue=-1", "queue must be a finite number >= 0 and <= 50, got '-1'"),
    ("dqn:m.pt,ensemble=3", "ensemble was retired"),
    ("fast", "unknown policy 'fast'"),
    ("Keep", "unknown policy 'Keep'"),
    ("keep:", "keep takes no parameters"),
    ("random:3", "random takes no parameters"),
    ("mobil:", "nothing after ':'"),
    ("mobil:p=", "parameter 'p' has no value"),
    ("mobil:p=x", "p must be"),
    ("mobil:p", "'p' is not KEY=VALUE"),
    ("mobil:=1", "unknown parameter ''"),
    ("mobil:p=1,,bias=0", "has an empty parameter"),
    ("mobil:p=1,p=2", "parameter 'p' is given twice"),
    ("mobil:p=11", "p must be"),
    ("mobil:q=1", "unknown parameter 'q' of mobil"),
    ("sumo:lcFoo=1", "unknown parameter 'lcFoo' of sumo"),
    ("sumo:lcCooperative=2", "lcCooperative must be"),
    (" keep", "has a space"),
    ("mobil:p=0\t", "has a space"),
]


@pytest.mark.parametrize(("text", "spec"), VALID)
def test_valid_strings_parse_to_their_spec(text: str, spec: PolicySpec) -> None:
    assert parse_policy(text) == spec


@pytest.mark.parametrize(("text", "fragment"), INVALID)
def test_invalid_strings_give_one_line_naming_the_problem(text: str, fragment: str) -> None:
    with pytest.raises(PolicySpecError) as err:
        parse_policy(text)
    message = str(err.value)
    assert fragment in message and "\n" not in message, message
    if text:
        assert repr(text) in message  # the string as the user wrote it


def test_a_folder_stands_for_its_model(tmp_path: Path) -> None:
    (tmp_path / "run").mkdir()
    assert model_file(str(tmp_path / "run")) == str(tmp_path / "run" / "model.pt")
    assert model_file(str(tmp_path / "m.pt")) == str(tmp_path / "m.pt")


CLI_CASES = ["dqn:m.pt,alpha=2,alpha=3", "dqn:m.pt, alpha=2", "dqn:m.pt,", "dqn:a,b/model.pt", "dqn:", "fast",
             "mobil:p=", "mobil:p=x", "sumo:lcFoo=1", "keep:", "mobil:p=1,,bias=0", "dqn:m.pt,beta=1"]  # fmt: skip


def test_the_command_line_and_the_gymnasium_env_give_the_same_line(tmp_path: Path) -> None:
    """One process per command would cost seconds each: the commands run in one Python via runpy."""
    from coopsumo.envs.highway_env import HighwayEnv

    code = (
        "import sys\nfrom coopsumo.simulate import main\n"
        "for i, spec in enumerate(sys.argv[2:]):\n"
        "    code = main(['--policy', spec, '--steps', '10', '--quiet', '--out', sys.argv[1] + f'/run{i}'])\n"
        "    print(code, file=sys.stderr)\n"
    )
    res = subprocess.run([sys.executable, "-c", code, str(tmp_path), *CLI_CASES], capture_output=True, text=True,
                         cwd=REPO, timeout=300)  # fmt: skip
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 2 * len(CLI_CASES), res.stderr  # one error line and the exit code per case
    for i, spec in enumerate(CLI_CASES):
        error, code = lines[2 * i], lines[2 * i + 1]
        assert code == str(USAGE_EXIT), (spec, error)
        with pytest.raises(ValueError) as err:
            HighwayEnv(background=spec)
        assert error.startswith("simulate: error: --policy") and error.endswith(str(err.value)), (spec, error)
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_a_training_folder_drives_as_its_model(tmp_path: Path) -> None:
    """`dqn:FOLDER` loads FOLDER/model.pt; a folder without one is named in the error."""
    from coopsumo.agents.dqn import QNetwork
    from coopsumo.agents.dqn_policy import DQNPolicy
    from coopsumo.agents.model_file import save_model
    from coopsumo.config import to_dict
    from coopsumo.dqn_config import DQN_PRESETS

    run = tmp_path / "run"
    run.mkdir()
    save_model(run / "model.pt", QNetwork(30.0, dueling=False), {"config": {"dqn": to_dict(DQN_PRESETS["paper"])}})
    assert DQNPolicy.from_spec(f"dqn:{run}").net is not None
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="model.pt"):
        DQNPolicy.from_spec(f"dqn:{tmp_path / 'empty'}")


def test_margin_replaces_the_change_margin_a_model_was_saved_with(tmp_path: Path) -> None:
    from dataclasses import replace

    from coopsumo.agents.dqn import QNetwork
    from coopsumo.agents.dqn_policy import DQNPolicy
    from coopsumo.agents.model_file import save_model
    from coopsumo.config import SimConfig, TrainConfig, to_dict
    from coopsumo.dqn_config import DQN_PRESETS

    dqn = replace(DQN_PRESETS["default"], observation="paper")
    model = tmp_path / "model.pt"
    net = QNetwork(30.0, dueling=dqn.dueling, observation="paper")
    save_model(model, net, {"config": to_dict(TrainConfig(sim=SimConfig(policy="dqn"), dqn=dqn))})
    assert DQNPolicy.from_spec(f"dqn:{model}").change_margin == dqn.change_margin == 1.0
    driven = DQNPolicy.from_spec(f"dqn:{model},margin=2.5")
    assert driven.change_margin == 2.5 and driven.trained_on is not None
    assert driven.trained_on["change_margin"] == 1.0 and driven.trained_on["driven_change_margin"] == 2.5

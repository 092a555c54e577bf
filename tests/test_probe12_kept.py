"""Issue 82, probe 12: a user's files named like ones coopsumo writes and removes are kept: a JSON file named as the
marker's temporary whose first key is a marker's (N2), files named like a training's temporaries on a resume (N3)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import interrupted_at_step_20

from coopsumo.agents import train_cli
from coopsumo.config import SimConfig, TrainConfig
from coopsumo.dqn_config import DQN_PRESETS
from coopsumo.errors import UsageError
from coopsumo.run_dirs import finished_run, mark_run_dir, study_root
from coopsumo.run_markers import RUN_MARKER, marker_text

OWN = ("sweep.json", "report.md", "*.tmp")


@pytest.mark.parametrize("data", [{"version": 2, "chapters": ["a"]}, {"kind": "my survey"}, {"study": "my notes"},
                                  {"finished": False, "todo": "chapter 4"}, {"version": 7, "my": "data"},
                                  {"finished": False, "kind": "mine", "notes": "x"}])  # fmt: skip
def test_a_users_json_file_named_as_the_markers_temporary_is_kept(data: dict[str, object], tmp_path: Path) -> None:
    """N2: a user's indented JSON file of that name whose first key is one a marker has was taken for a killed
    marking, and a rerun deleted it; only a start of the text coopsumo writes for a marker is taken now."""
    root = tmp_path / "X"
    root.mkdir()
    user = root / "..coopsumo-run.json.abcdefgh.tmp"
    user.write_text(json.dumps(data, indent=2) + "\n")
    for _ in range(2):
        with pytest.raises(UsageError, match=r"holds \.\.coopsumo-run\.json\.abcdefgh\.tmp"):
            with study_root(root, "scenario2", OWN):
                pass
    assert user.read_text() == json.dumps(data, indent=2) + "\n"
    assert [p.name for p in root.iterdir()] == [user.name]


def test_every_start_of_a_markers_own_text_is_a_killed_marking(tmp_path: Path) -> None:
    """What a marker's write may leave, cut anywhere, is still taken for it (and a lone "{" or nothing, as before)."""
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / 'a "b"').write_text("x")
    temporary = tmp_path / "t.tmp"
    for finished, study in ((False, None), (False, "the quick profile's study"), (True, None), (True, "s é")):
        mark_run_dir(tmp_path / "run", "scenario2", finished=finished, study=study)
        text = (tmp_path / "run" / RUN_MARKER).read_text()
        for end in range(len(text) + 1):
            temporary.write_text(text[:end])
            assert marker_text(temporary), text[:end]
        temporary.write_text(text + "x")
        assert not marker_text(temporary)
    root = tmp_path / "X"
    root.mkdir()
    (root / "..coopsumo-run.json.abcdefgh.tmp").write_text('{\n  "finished": false,\n  "kind": "scen')
    with study_root(root, "scenario2", OWN):
        assert (root / RUN_MARKER).is_file()


def test_a_resume_keeps_a_users_files_named_like_its_temporaries_and_finishes(tmp_path: Path) -> None:
    """N3: `train --resume` deleted a user's .checkpoint.pt.ABCDEFGH.tmp, .train_log.csv.thesis01.tmp and
    .model.pt.ABCDEFGH.tmp, whatever they held; they stay now, and the training's own writes take fresh names."""
    out = tmp_path / "run"
    cfg = TrainConfig(sim=SimConfig(steps=40, seed=3, policy="dqn"), dqn=DQN_PRESETS["paper"], eval_steps=0,
                      log_every_steps=10, checkpoint_every_steps=20)  # fmt: skip
    interrupted_at_step_20(cfg, out).replace(out / "checkpoint.pt")
    users = {".checkpoint.pt.ABCDEFGH.tmp": '{"x":1}\n', ".train_log.csv.thesis01.tmp": "my thesis draft\n",
             ".model.pt.ABCDEFGH.tmp": "draft\n"}  # fmt: skip
    for name, text in users.items():
        (out / name).write_text(text)
    assert train_cli.main(["--resume", "--quiet", "--out", str(out)]) == 0
    assert finished_run(out, "train") and (out / "model.pt").is_file() and not (out / "checkpoint.pt").exists()
    assert {name: (out / name).read_text() for name in users} == users
    assert sorted(p.name for p in out.glob(".*.tmp")) == sorted(users)

"""A policy of one's own (py:MODULE:CLASS) and a Stable-Baselines3 model (sb3:PATH): the grammar, the checks a class
and a zip pass before they drive (each refusal one line), the decisions checked while driving, and `simulate` driven
by a class of one's own in a real SUMO run, a bad one refused with exit code 2 and nothing written. docs/extending.md's
examples (the SB3 model in simulate and beside keep in scenario I) run in tests/test_extending.py."""

from __future__ import annotations

import json
import os
import sys
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from coopsumo.agents.policies import make_policy
from coopsumo.agents.sb3_policy import SB3ModelError, check_model
from coopsumo.agents.user_policy import UserPolicy, UserPolicyError, checked_actions
from coopsumo.policy_spec import PolicySpecError, parse_policy, policy_file
from coopsumo.run_dirs import finished_run

POLICIES = '''
import numpy as np


class Right:
    needs_grids = False
    decision_interval = 5

    def act(self, obs):
        return np.full(len(obs), 1)


class Drawing:
    def __init__(self, rng):
        self.rng = rng

    def act(self, obs):
        return self.rng.integers(0, 4, size=len(obs))


class NoAct:
    pass


class Sevens:
    def act(self, obs):
        return np.full(len(obs), 7)


class Broken:
    def act(self, obs):
        raise ValueError("my policy broke")


class Endless:
    def act(self, obs):
        return self.act(obs)


class Needy:
    def __init__(self, size):
        pass

    def act(self, obs):
        return []


class BadInterval:
    decision_interval = 0

    def act(self, obs):
        return []


NOT_A_CLASS = 3
'''


@pytest.fixture
def folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A working folder holding the module mine.py, made the current folder."""
    (tmp_path / "mine.py").write_text(POLICIES)
    (tmp_path / "broken.py").write_text("import numpy as np\nraise RuntimeError('half written')\n")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_the_grammar_of_own_policies() -> None:
    spec = parse_policy("py:mine:Right")
    assert (spec.name, spec.module, spec.class_name) == ("py", "mine", "Right")
    spec = parse_policy("py:lib/my_policies.py:KeepRight")
    assert (spec.module, spec.class_name) == ("lib/my_policies.py", "KeepRight")
    assert parse_policy("sb3:runs/a/model.zip").model == "runs/a/model.zip"
    for text, fragment in (("py", "needs a module and a class"), ("py:mine", "names no class"),
                           ("py::X", "names no class"), ("py:mine:1x", "not a Python class name"),
                           ("py:mine:X,a=1", "takes no parameters"), ("sb3", "needs a model"),
                           ("sb3:a,b.zip", "takes no parameters"), ("sb3:", "needs a model")):  # fmt: skip
        with pytest.raises(PolicySpecError) as err:
            parse_policy(text)
        assert fragment in str(err.value) and len(str(err.value).splitlines()) == 1, text


def test_the_file_a_policy_drives_is_known(folder: Path) -> None:
    assert policy_file("py:mine:Right") == "mine.py"  # MODULE.py in the current folder
    assert policy_file("py:sub/x.py:Right") == "sub/x.py"
    assert policy_file("py:json:JSONDecoder") is None  # an installed module: Python finds it
    assert policy_file("sb3:m.zip") == "m.zip" and policy_file("keep") is None


def test_a_class_of_ones_own_is_a_policy(folder: Path) -> None:
    rng = np.random.default_rng(0)
    policy = make_policy("py:mine:Right", rng)
    assert isinstance(policy, UserPolicy)
    assert (policy.name, policy.needs_grids, policy.decision_interval) == ("Right", False, 5)
    assert policy.trained_on["policy_file"] == str(folder / "mine.py")
    assert len(str(policy.trained_on["model_sha256"])) == 64
    same = make_policy(f"py:{folder / 'mine.py'}:Right", rng)  # the same file by its path
    assert same.trained_on["model_sha256"] == policy.trained_on["model_sha256"]
    drawing = make_policy("py:mine:Drawing", np.random.default_rng([4, 3]))
    assert drawing.inner.rng.integers(1 << 30) == np.random.default_rng([4, 3]).integers(1 << 30)  # the run's stream


@pytest.mark.parametrize(("spec", "fragment"), [
    ("py:nowhere:X", "no module 'nowhere': neither nowhere.py in the current folder nor an importable module"),
    ("py:nowhere.py:X", "no file nowhere.py"),
    ("py:mine:Missing", "mine.py defines no 'Missing' (it defines BadInterval, Broken, Drawing, Endless, Needy, NoAct, "
                        "Right, Sevens)"),
    ("py:mine:NoAct", "class NoAct has no act(obs) method"),
    ("py:mine:NOT_A_CLASS", "NOT_A_CLASS in mine.py is not a class (it is int 3)"),
    ("py:mine:Needy", "Needy() failed: TypeError"),
    ("py:mine:BadInterval", "its decision_interval must be an integer from 1 to 600, got 0"),
    ("py:broken:X", "running broken.py failed: RuntimeError: half written"),
    ("py:json.nothere:X", "no module 'json.nothere'"),
    ("py:json:JSONDecoder", "class JSONDecoder has no act(obs) method"),
])  # fmt: skip
def test_what_a_class_lacks_is_said_in_one_line(folder: Path, spec: str, fragment: str) -> None:
    with pytest.raises(UserPolicyError) as err:
        make_policy(spec, np.random.default_rng(0))
    assert fragment in str(err.value) and str(err.value).startswith(spec), str(err.value)
    assert len(str(err.value).splitlines()) == 1


def test_every_decision_is_checked() -> None:
    assert checked_actions([0, 1, 2, 3], 4, "p").dtype == np.int64
    assert len(checked_actions(np.zeros(0), 0, "p")) == 0  # an empty road: an empty answer of any dtype
    for actions, fragment in (([0, 1], "of shape (2,); it must give 3 integers"),
                              ([0.0, 1.0, 2.0], "gave float64"), ([0, 1, 7], "gave the action 7"),
                              ([0, -1, 2], "gave the action -1"), ([[0, 1, 2]], "of shape (1, 3)")):  # fmt: skip
        with pytest.raises(UserPolicyError) as err:
            checked_actions(actions, 3, "py:m:P")
        assert fragment in str(err.value) and "0 left, 1 right, 2 speed-up, 3 none" in str(err.value)


def _zip(path: Path, data: object) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("data", json.dumps(data))
    return path


def test_a_zip_that_is_no_highway_dqn_is_refused_before_sb3_reads_it(tmp_path: Path) -> None:
    highway = {"spaces": "{'grids': Box(0, 1, (3, 3, 20), uint8), 'speed_err': Box(-inf, inf, (3,), float32)}"}
    ppo = _zip(tmp_path / "ppo.zip", {"policy_class": {"__module__": "stable_baselines3.common.policies"},
                                      "observation_space": highway})  # fmt: skip
    other = _zip(tmp_path / "other.zip", {"policy_class": {"__module__": "stable_baselines3.dqn.policies"},
                                          "observation_space": {"spaces": "Box(0, 1, (4,))"}})  # fmt: skip
    (tmp_path / "notzip.zip").write_text("not a zip")
    nodata = tmp_path / "nodata.zip"
    with zipfile.ZipFile(nodata, "w") as archive:
        archive.writestr("policy.pth", b"")
    for path, fragment in ((tmp_path / "missing.zip", "model file not found"),
                           (tmp_path, "is not a file"),
                           (tmp_path / "notzip.zip", "is not a Stable-Baselines3 model"),
                           (nodata, "is not a Stable-Baselines3 model"),
                           (ppo, "is not a Stable-Baselines3 DQN (its policy comes from stable_baselines3.common"),
                           (other, "was not trained on coopsumo/Highway-v0")):  # fmt: skip
        with pytest.raises(SB3ModelError) as err:
            check_model(str(path), f"sb3:{path}")
        assert fragment in str(err.value) and len(str(err.value).splitlines()) == 1, path


def test_checking_a_zip_and_parsing_import_no_stable_baselines3() -> None:
    import subprocess

    code = ("import sys; from coopsumo.agents import policies, sb3_policy; from coopsumo import simulate; "
            "policies.make_policy('keep', None); print('stable_baselines3' in sys.modules)")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


@pytest.mark.sumo
def test_simulate_drives_a_class_of_ones_own_and_refuses_a_bad_one(
    folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from coopsumo import simulate

    assert simulate.main(["--policy", "py:mine:Right", "--steps", "400", "--t-up", "1", "--quiet",
                          "--out", "run"]) == 0  # fmt: skip
    summary = json.loads((folder / "run" / "summary.json").read_text())
    config = json.loads((folder / "run" / "config.json").read_text())
    assert summary["policy"] == "py:mine:Right" and summary["decision_interval_steps"] == 5
    assert summary["lane_changes"] > 0 and summary["collisions"] == 0  # it asked right; the controller let some
    assert config["model_trained_on"]["policy_file"] == str(folder / "mine.py")
    capsys.readouterr()
    for spec, fragment in (("py:mine:NoAct", "has no act(obs) method"), ("py:mine:Sevens", "gave the action 7"),
                           ("py:nowhere:X", "no module 'nowhere'"),
                           ("py:mine:Broken", f"act(obs) raised ValueError: my policy broke ({folder / 'mine.py'}"),
                           ("py:mine:Endless", "act(obs) raised RecursionError")):  # fmt: skip  (probe 9: tracebacks)
        assert simulate.main(["--policy", spec, "--steps", "50", "--quiet", "--out", "bad"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and fragment in err[0], err
        assert not (folder / "bad").exists() and not list(folder.glob(".bad*"))  # nothing written


@pytest.mark.parametrize(("baselines", "fragment"), [
    (["py:mine:NoAct"], "--baseline py:mine:NoAct: py:mine:NoAct: class NoAct has no act(obs) method"),
    (["py:nowhere:X"], "no module 'nowhere'"),
    (["py:mine"], "names no class"),
    (["sb3:none.zip"], "model file not found: none.zip"),
    (["keep"], "its name in the tables, keep, is another policy's of the study"),
    (["py:mine:Right", f"py:{'mine.py'}:Right"], "its name in the tables, py_Right, is another policy's"),
])  # fmt: skip
def test_scenario1_refuses_a_bad_baseline_before_it_writes(baselines: list[str], fragment: str, folder: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    from coopsumo.studies.scenario1 import study

    argv = ["--quick", *[a for b in baselines for a in ("--baseline", b)], "--out", "s1"]
    assert study.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0], err
    assert sorted(p.name for p in folder.iterdir()) == ["broken.py", "mine.py"]  # nothing written


def test_scenario1_takes_baselines_of_ones_own_beside_keep(folder: Path) -> None:
    from coopsumo.studies.scenario1 import study

    args = study.build_parser().parse_args(["--quick", "--baseline", "py:mine:Right", "--baseline", "mobil:p=0.25"])
    plan = study.plan_from_args(args)
    assert plan.baseline_policies() == ("keep", "greedy", "py:mine:Right", "mobil:p=0.25", "mobil:p=0", "mobil:p=0.5",
                                        "sumo")  # fmt: skip
    assert study.label_for("py:mine:Right") == "py_Right" and study.label_for("sb3:a/b/model.zip") == "sb3_b"
    assert study.label_for("sb3:runs/highway.zip") == "sb3_highway"


HOSTILE = '''
class Mine(BaseException):
    pass


class Renumbering:
    def act(self, obs):
        obs.nums[:] = 10**9
        return [3] * len(obs)


class Unlocking:
    def act(self, obs):
        obs.nums.flags.writeable = True
        obs.nums[:] = 10**9
        return [3] * len(obs)


class Resetting:
    def act(self, obs):
        obs.nums.setflags(write=True)
        obs.nums[:] = -5
        obs.grids.setflags(write=True)
        obs.grids[:] = 255
        return [3] * len(obs)


class ThroughBase:
    def act(self, obs):
        if obs.nums.base is not None:
            obs.nums.base.setflags(write=True)
            obs.nums.base[...] = -5
        return [3] * len(obs)


class Ragged:
    def act(self, obs):
        return [[1] * (i + 1) for i in range(len(obs))] if len(obs) > 1 else [1] * len(obs)


class Unreadable:
    def __array__(self, *args, **kwargs):
        raise RuntimeError("no array here")


class GivesUnreadable:
    def act(self, obs):
        return Unreadable()


class Grids:
    @property
    def needs_grids(self):
        raise KeyError("grids")

    def act(self, obs):
        return [1] * len(obs)


class Label:
    @property
    def name(self):
        raise KeyError("name")

    def act(self, obs):
        return [1] * len(obs)


class Lookup:
    def __getattr__(self, key):
        raise RuntimeError("no " + key)

    def act(self, obs):
        return [1] * len(obs)


class Shown(int):
    def __repr__(self):
        raise RuntimeError("no repr")


class Interval:
    decision_interval = Shown(0)

    def act(self, obs):
        return [1] * len(obs)


class Closing:
    def act(self, obs):
        raise GeneratorExit("closed")


class Own:
    def act(self, obs):
        raise Mine("mine")


class Interrupted:
    def act(self, obs):
        raise KeyboardInterrupt


class Exiting:
    def act(self, obs):
        raise SystemExit(5)


class Deleting:
    def __del__(self):
        raise RuntimeError("del failed")

    def act(self, obs):
        return [1] * len(obs)
'''


@pytest.fixture
def hostile(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A working folder holding hostile.py, classes whose attributes, decisions or act raise (probe 10, L4)."""
    (tmp_path / "hostile.py").write_text(HOSTILE)
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize(("cls", "fragment"), [
    ("Grids", "its needs_grids raised KeyError: 'grids' ("),
    ("Label", "its name raised KeyError: 'name' ("),
    ("Lookup", "its name raised RuntimeError: no name ("),
    ("Interval", "its decision_interval raised RuntimeError: no repr ("),
])  # fmt: skip
def test_an_attribute_that_raises_is_refused_in_one_line(hostile: Path, cls: str, fragment: str) -> None:
    with pytest.raises(UserPolicyError) as err:  # issue 82, probe 10, L4: tracebacks
        make_policy(f"py:hostile:{cls}", np.random.default_rng(0))
    assert fragment in str(err.value) and f"{hostile / 'hostile.py'}:" in str(err.value), str(err.value)
    assert len(str(err.value).splitlines()) == 1


def test_what_act_gives_or_raises_ends_in_one_line_but_an_interrupt(hostile: Path) -> None:
    obs: Any = [0, 0, 0]  # act sees only len(obs)
    for cls, fragment in (("Ragged", "act(obs) gave a list that is no array of 3 integers, one per vehicle (0 left, "
                                     "1 right, 2 speed-up, 3 none): ValueError: setting an array element"),
                          ("GivesUnreadable", "gave a Unreadable that is no array of 3 integers"),
                          ("Closing", "act(obs) raised GeneratorExit: closed ("),
                          ("Own", "act(obs) raised Mine: mine (")):  # fmt: skip
        with pytest.raises(UserPolicyError) as err:
            make_policy(f"py:hostile:{cls}", np.random.default_rng(0)).act(obs)
        assert fragment in str(err.value) and len(str(err.value).splitlines()) == 1, str(err.value)
    with pytest.raises(KeyboardInterrupt):  # Ctrl-C stops the run as a signal does
        make_policy("py:hostile:Interrupted", np.random.default_rng(0)).act(obs)
    with pytest.raises(UserPolicyError) as err:  # probe 18, O3: passed on, it ended simulate silently with exit 0
        make_policy("py:hostile:Exiting", np.random.default_rng(0)).act(obs)
    assert str(err.value).startswith("py:hostile:Exiting: act(obs) raised SystemExit: 5 (") and \
        len(str(err.value).splitlines()) == 1, str(err.value)  # fmt: skip


def test_a_del_that_raises_is_said_in_one_line(hostile: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import gc

    policy = make_policy("py:hostile:Deleting", np.random.default_rng(0))
    del policy
    gc.collect()
    err = capsys.readouterr().err.strip().splitlines()
    line = HOSTILE.splitlines().index('        raise RuntimeError("del failed")') + 1
    where = f"{hostile / 'hostile.py'}:{line}"
    assert err == [f"py:hostile:Deleting: its __del__ raised RuntimeError: del failed ({where})"]


LEFT_BEHIND = '''
import atexit, threading, weakref


def boom():
    raise RuntimeError("boom")


class AtExit:
    def __init__(self):
        atexit.register(boom)

    def act(self, obs):
        return [3] * len(obs)


class Thread:
    def act(self, obs):
        t = threading.Thread(target=boom)
        t.start()
        t.join()
        return [3] * len(obs)


class Finalized:
    def __init__(self):
        weakref.finalize(self, boom)

    def act(self, obs):
        return [3] * len(obs)


def interrupt():
    raise KeyboardInterrupt


class Starting:
    def __init__(self):
        t = threading.Thread(target=boom)
        t.start()
        t.join()

    def act(self, obs):
        return [3] * len(obs)


class Interrupting:
    def act(self, obs):
        t = threading.Thread(target=interrupt)
        t.start()
        t.join()
        return [3] * len(obs)


class Helping:
    def __init__(self):
        import helper

        atexit.register(helper.fail)

    def act(self, obs):
        return [3] * len(obs)
'''

DRIVE = """
import sys, threading, numpy as np
from coopsumo.agents.policies import make_policy
policy = make_policy(sys.argv[1], np.random.default_rng(0))
for _ in range(3):
    policy.act([0, 0])
if sys.argv[2] == "other":  # an error outside the user's file keeps Python's own report
    t = threading.Thread(target=lambda: 1 / 0)
    t.start()
    t.join()
"""


@pytest.mark.parametrize(("cls", "said"), [
    ("AtExit", "its atexit callback raised RuntimeError: boom (behind.py:6)"),
    ("Thread", "a thread it started raised RuntimeError: boom (behind.py:6)"),
    ("Finalized", "its weakref.finalize callback raised RuntimeError: boom (behind.py:6)"),
    ("Starting", "a thread it started raised RuntimeError: boom (behind.py:6)"),  # probe 12, N7: before the hooks
    ("Interrupting", "a thread it started raised KeyboardInterrupt: KeyboardInterrupt (behind.py:34)"),
    ("Helping", "its atexit callback raised ValueError: helped (sub/helper.py:2)"),  # a module beside it
])  # fmt: skip
def test_an_error_left_behind_by_the_users_code_is_said_once_in_one_line(tmp_path: Path, cls: str, said: str) -> None:
    import subprocess

    (tmp_path / "behind.py").write_text(LEFT_BEHIND)  # issue 82, probe 11, M4: Python's tracebacks at exit, rc 0
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "helper.py").write_text('def fail():\n    raise ValueError("helped")\n')
    env = {**os.environ, "PYTHONPATH": os.pathsep.join((str(tmp_path / "sub"), *sys.path))}
    done = subprocess.run([sys.executable, "-c", DRIVE, f"py:behind:{cls}", "own"], cwd=tmp_path, text=True,
                          capture_output=True, check=False, env=env)  # fmt: skip
    text, where = said.rsplit(" (", 1)
    assert (done.returncode, done.stderr.splitlines()) == (0, [f"py:behind:{cls}: {text} ({tmp_path}/{where}"]), \
        done.stderr


def test_an_error_not_the_users_keeps_pythons_report(tmp_path: Path) -> None:
    import subprocess

    (tmp_path / "behind.py").write_text(LEFT_BEHIND)
    done = subprocess.run([sys.executable, "-c", DRIVE, "py:behind:Thread", "other"], cwd=tmp_path, text=True,
                          capture_output=True, check=False)  # fmt: skip
    assert "ZeroDivisionError: division by zero" in done.stderr and "Traceback" in done.stderr
    assert done.stderr.count("py:behind:Thread: a thread it started raised") == 1


@pytest.mark.sumo
def test_simulate_ends_a_hostile_policy_in_one_line(hostile: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from coopsumo import simulate

    for cls, fragment in (("Ragged", "act(obs) gave a list that is no array of"),
                          ("GivesUnreadable", "RuntimeError: no array here"), ("Grids", "its needs_grids raised"),
                          ("Closing", "act(obs) raised GeneratorExit: closed"),
                          ("Own", "act(obs) raised Mine: mine"),
                          ("Renumbering", "act(obs) raised ValueError: assignment destination is read-only")
                          ):  # fmt: skip  (probe 10, L4: tracebacks; probe 11, M5: a hang)
        assert simulate.main(["--policy", f"py:hostile:{cls}", "--steps", "60", "--quiet", "--out", "bad"]) == 2, cls
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and fragment in err[0] and "Traceback" not in err[0], err
        assert sorted(p.name for p in hostile.iterdir()) == ["hostile.py"]  # nothing written


@pytest.mark.sumo
def test_an_act_that_unlocks_its_observation_writes_only_its_own_copy(hostile: Path) -> None:
    """Issue 82, probe 12, N5: the read-only views were one flag (or their base) away from the run's arrays: a
    traceback, or an 8 GB allocation that SIGTERM could not stop. Now the run drives on."""
    from coopsumo import simulate

    for cls in ("Unlocking", "Resetting", "ThroughBase"):
        assert simulate.main(["--policy", f"py:hostile:{cls}", "--steps", "60", "--quiet", "--out", cls]) == 0, cls
        assert finished_run(hostile / cls, "simulate"), cls


def test_scenario1_refuses_a_baseline_whose_name_raises(hostile: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from coopsumo.studies.scenario1 import study

    assert study.main(["--quick", "--baseline", "py:hostile:Label", "--out", "s1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--baseline py:hostile:Label: py:hostile:Label: its name raised KeyError" in err[0], err
    assert sorted(p.name for p in hostile.iterdir()) == ["hostile.py"]


ODD = '''
def __getattr__(name):
    raise RuntimeError("no " + name)


class Meta(type):
    def __getattr__(cls, name):
        raise RuntimeError("meta " + name)


class NoAct(metaclass=Meta):
    pass


class StrBoom:
    def __str__(self):
        raise RuntimeError("no str")


Inst = StrBoom()


class NameMeta(type):
    @property
    def __name__(cls):
        raise RuntimeError("no name")


class NameBoom(metaclass=NameMeta):
    def __init__(self):
        raise ValueError("no init")

    def act(self, obs):
        return [3] * len(obs)


class TbErr(Exception):
    __traceback__ = property(lambda self: 5)


class TbPol:
    def act(self, obs):
        raise TbErr("odd traceback")
'''
"""a module whose reading (a module __getattr__, a metaclass's, an object's __str__, a __name__ that raises, an
exception whose __traceback__ is no traceback) broke coopsumo's own messages (issue 82, probe 11, M3)"""


@pytest.mark.sumo
def test_simulate_reads_an_odd_policy_module_in_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    from coopsumo import simulate

    (tmp_path / "odd.py").write_text(ODD)
    monkeypatch.chdir(tmp_path)
    for cls, fragment in (("Missing", "reading Missing raised RuntimeError: no Missing"),
                          ("NoAct", "reading NoAct raised RuntimeError: meta act"),
                          ("Inst", "reading Inst raised RuntimeError: no str"),
                          ("NameBoom", "NameBoom() failed: ValueError: no init"),
                          ("TbPol", "act(obs) raised TbErr: odd traceback")):  # fmt: skip
        assert simulate.main(["--policy", f"py:odd:{cls}", "--steps", "30", "--quiet", "--out", "o"]) == 2, cls
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and fragment in err[0] and "Traceback" not in err[0], (cls, err)
        assert sorted(p.name for p in tmp_path.iterdir() if p.name != "__pycache__") == ["odd.py"]


HASH_BOMB = '''
class MyBase(BaseException):
    pass


class HashBomb(str):
    def __hash__(self):
        raise MyBase("hash bomb")


class ModHash:
    def act(self, obs):
        return [3] * len(obs)


ModHash.__module__ = HashBomb("zz")
'''


def test_a_class_whose_module_name_cannot_be_hashed_still_drives(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:  # fmt: skip
    """Issue 82, probe 12, N8: reading the class's file (to say its errors in one line) looked its __module__ up in
    sys.modules and caught only Exception: a 47-line traceback."""
    (tmp_path / "hb.py").write_text(HASH_BOMB)
    monkeypatch.chdir(tmp_path)
    policy = make_policy("py:hb.py:ModHash", np.random.default_rng(0))
    assert list(policy.act([0, 0])) == [3, 3]  # act sees only len(obs)


FORKING = '''
import os
import numpy as np

class ForkInAct:
    done = False

    def act(self, obs):
        if not ForkInAct.done:
            ForkInAct.done = True
            os.fork()
        return np.full(len(obs), 3)

class Forking:
    done = False

    def __array__(self, dtype=None, copy=None):
        if not Forking.done:
            Forking.done = True
            os.fork()
        return np.full(self.n, 3)

class ForkInArray:
    def act(self, obs):
        forking = Forking()
        forking.n = len(obs)
        return forking

class ForkInInit:
    def __init__(self):
        os.fork()

    def act(self, obs):
        return np.full(len(obs), 3)
'''


@pytest.mark.sumo
@pytest.mark.parametrize(("cls", "where"), [("ForkInAct", "act(obs)"), ("ForkInInit", "its module or constructor"),
                                           ("ForkInArray", "what act(obs) gave")])  # probe 20, TR1: its __array__
def test_a_policy_that_forks_the_run_leaves_it_whole(cls: str, where: str, tmp_path: Path) -> None:
    """Issue 82, probe 19, TR1: a py: policy that forked once had two copies of the run drive SUMO, both writing the
    run's detectors.xml (every interval twice) and racing to finish its folder; the copy ends now, in one line, as it
    returns into the run, and the run is the one a policy that never forked makes."""
    import json
    import subprocess
    import sys

    from coopsumo.studies.engine.run_checks import detectors_problem

    (tmp_path / "forking.py").write_text(FORKING)
    (tmp_path / "plain.py").write_text(FORKING.replace("os.fork()", "pass"))  # the same decisions, never forked
    outs = {}
    for name, policy in (("forked", f"py:forking.py:{cls}"), ("plain", f"py:plain.py:{cls}")):
        done = subprocess.run([sys.executable, "-m", "coopsumo", "simulate", "--steps", "120", "--lanes", "2",
                               "--quiet", "--policy", policy, "--out", name], cwd=tmp_path, capture_output=True,
                              text=True, timeout=300, check=False)  # fmt: skip
        assert done.returncode == 0, done.stderr
        lines = done.stderr.strip().splitlines()
        assert lines == ([] if name == "plain" else [line for line in lines if f"{where} forked it; " in line])
        assert len(lines) == (0 if name == "plain" else 1), lines
        config = json.loads((tmp_path / name / "config.json").read_text())["config"]
        assert detectors_problem(tmp_path / name / "detectors.xml", config, 12.0) is None
        text = (tmp_path / name / "detectors.xml").read_text()
        outs[name] = text[text.index("<interval"):]  # SUMO's header carries the time it ran
    assert outs["forked"] == outs["plain"]


def test_a_copy_of_a_run_forked_by_its_code_neither_finishes_nor_discards_the_run(tmp_path: Path) -> None:
    """Issue 82, probe 20, TR1: a copy a policy forked where no check caught it finished or discarded the run's folder
    too (a run folder gone after exit 0); run_dirs.atomic_run_dir ends such a copy as it leaves the block."""
    import subprocess
    import sys

    script = (
        "import os, sys, time\n"
        "from pathlib import Path\n"
        "from coopsumo.run_dirs import atomic_run_dir\n"
        "with atomic_run_dir(Path(sys.argv[1])) as tmp:\n"
        "    (tmp / 'summary.json').write_text('{}')\n"
        "    os.fork()\n"
        "time.sleep(0.3)\n"
        "print('finished')\n"
    )  # fmt: skip
    done = subprocess.run([sys.executable, "-c", script, str(tmp_path / "run")], capture_output=True, text=True,
                          timeout=120, check=False)  # fmt: skip
    assert done.returncode == 0 and done.stdout == "finished\n", done.stderr
    line, = done.stderr.strip().splitlines()
    assert "forked by code the run ran, ends here without touching" in line, line
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == [".coopsumo-run.json", "summary.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]

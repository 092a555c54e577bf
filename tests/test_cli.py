"""The console command `coopsumo`: its subcommands, their --help (every default, every policy form), the older
`python -m coopsumo.<command>` spellings, the Makefile's use of it, and where the networks are built."""

from __future__ import annotations

import argparse
import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

import coopsumo
from coopsumo import cli, simulate
from coopsumo.config import AccidentConfig
from coopsumo.policy_spec import KEYS
from coopsumo.runio import DefaultsHelpFormatter
from coopsumo.sim import network

ROOT = Path(__file__).resolve().parent.parent
POLICY_FORMS = ("keep", "random", "greedy", "mobil[:", "sumo[:", "dqn:PATH")


def parsers() -> dict[str, argparse.ArgumentParser]:
    return {name: importlib.import_module(module).build_parser() for name, (module, _) in cli.COMMANDS.items()}


def test_the_commands_are_the_issue_s_six_the_protocol_and_the_studies_beside_them() -> None:
    assert list(cli.COMMANDS) == ["simulate", "train", "scenario1", "scenario2", "protocol", "history", "models",
                                  "bench"]  # fmt: skip


def test_help_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        cli.main(["--help"])
    assert stop.value.code == 0
    out = capsys.readouterr().out
    assert all(re.search(rf"^  {name} ", out, flags=re.M) for name in cli.COMMANDS), out
    assert "--nets-dir" in out


@pytest.mark.parametrize("name", list(cli.COMMANDS))
def test_every_option_that_takes_a_value_shows_its_default(name: str) -> None:
    parser = parsers()[name]
    formatter = DefaultsHelpFormatter(parser.prog)
    missing = [a.option_strings[0] for a in parser._actions
               if a.option_strings and a.nargs != 0 and not a.required and a.help != argparse.SUPPRESS
               and "default" not in (formatter._get_help_string(a) or "").lower()]  # fmt: skip
    assert not missing, f"coopsumo {name}: no default shown for {missing}"
    assert parser.prog == f"coopsumo {name}"
    text = parser.format_help()
    for action in parser._actions:  # a value default is printed as the help says it
        if action.option_strings and action.nargs != 0 and action.default not in (None, argparse.SUPPRESS):
            assert "default" in text


def test_simulate_help_lists_every_policy_form() -> None:
    text = " ".join(parsers()["simulate"].format_help().split())
    assert all(form in text for form in POLICY_FORMS), text
    assert "(default: keep)" in text and "(default: 9000)" in text


def test_simulate_help_names_the_dqn_folder_form_and_every_drive_modifier() -> None:
    text = " ".join(parsers()["simulate"].format_help().split())
    assert "dqn:FOLDER" in text
    missing = [key for key in KEYS["dqn"] if f",{key}=" not in text]
    assert not missing, text


def test_simulate_accident_defaults_follow_the_run_length(tmp_path: Path) -> None:
    """Without --accident-start/--accident-steps the accident is the paper's window scaled to --steps (issue 68: the
    bare default and the README's --steps 20000 were refused), and --help states the default 9,000-step run's."""
    out = str(tmp_path / "run")

    def window(*extra: str) -> tuple[int, int]:
        cfg = simulate.config_from_args(simulate.build_parser().parse_args(["--scenario", "accident", "--out", out,
                                                                             *extra]))  # fmt: skip
        assert cfg.accident.enabled
        return cfg.accident.start_step, cfg.accident.duration_steps

    assert window("--steps", "90000") == (AccidentConfig.start_step, AccidentConfig.duration_steps)  # the paper's
    assert window() == (2000, 5000)
    assert window("--steps", "20000") == (4444, 11111)
    assert window("--steps", "1") == (0, 1)
    assert window("--accident-start", "100") == (100, 5000)
    assert window("--accident-steps", "7") == (2000, 7)
    text = " ".join(parsers()["simulate"].format_help().split())
    assert "2,000 of the default 9,000" in text and "5,000 of the default 9,000" in text


def test_dispatch_hands_the_rest_of_the_line_to_the_command(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    seen: list[list[str]] = []
    module = importlib.import_module(cli.COMMANDS["train"][0])
    monkeypatch.setattr(module, "main", lambda argv: seen.append(argv) or 7)
    monkeypatch.setenv(network.NETS_ENV, "")  # so that teardown restores it: cli.main below sets it
    monkeypatch.delenv(network.NETS_ENV)
    assert cli.main(["train", "--steps", "5", "--out", "x"]) == 7
    assert seen == [["--steps", "5", "--out", "x"]]
    monkeypatch.chdir(tmp_path)  # a relative --nets-dir is resolved against the current folder
    assert cli.main(["--nets-dir", "some/where", "train", "--help"]) == 7
    assert seen[-1] == ["--help"]
    assert network.nets_dir() == (tmp_path / "some/where").resolve()  # --nets-dir sets COOPSUMO_NETS_DIR


@pytest.mark.parametrize("argv", [[], ["bogus"], ["--nets-dir"]])
def test_bad_command_lines_are_one_line_and_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    try:
        code = cli.main(argv)
    except SystemExit as stop:
        code = stop.code
    assert code == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(err) == 1


SPELLINGS = [["-m", "coopsumo", "train"], ["-m", "coopsumo.train"], ["-m", "coopsumo.simulate"],
             ["-m", "coopsumo", "scenario1"], ["-m", "coopsumo.bench"]]  # fmt: skip


@pytest.mark.parametrize("spelling", SPELLINGS)
def test_python_m_spellings_show_the_same_help(spelling: list[str]) -> None:
    res = subprocess.run([sys.executable, *spelling, "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-1500:]
    name = spelling[-1].split(".")[-1]
    assert res.stdout.startswith(f"usage: coopsumo {name} ")


def test_makefile_targets_call_the_console_command() -> None:
    make = (ROOT / "Makefile").read_text()
    for target, command in (("demo", "simulate"), ("bench", "bench"), ("scenario1", "scenario1"),
                            ("scenario2", "scenario2"), ("learning", "protocol --profile learning"),
                            ("protocol", "protocol"),
                            ("regime-map", "scenario1 --regime-map")):  # fmt: skip
        recipe = re.search(rf"^{target}: .*\n(?:\t\$\(if .*\n)?\t(.*)$", make, flags=re.M)  # after a guard
        assert recipe is not None and recipe.group(1).startswith(f"$(BIN)/coopsumo {command}"), target
    assert "python -m coopsumo." not in make
    # the learning study's QUICK and PROFILE are refused, not ignored (the whole ablation would run instead)
    for given in ("QUICK=1", "PROFILE=conditioned"):
        res = subprocess.run(["make", "-n", "learning", given], cwd=ROOT, capture_output=True, text=True, check=False)
        assert res.returncode == 2 and "make learning takes no QUICK or PROFILE" in res.stderr, res.stderr
    assert 'pip install --quiet torch==2.13.0' in make and "tensorboard" in make


def test_pyproject_declares_the_console_command_and_finds_every_subpackage() -> None:
    text = (ROOT / "pyproject.toml").read_text()
    assert re.search(r'^\[project\.scripts\]\ncoopsumo = "coopsumo\.cli:main"$', text, flags=re.M)
    assert 'include = ["coopsumo*"]' in text


# -- where the networks are built ----------------------------------------------------------------------------
def test_a_checkout_builds_into_its_top_level_sumo_nets() -> None:
    assert network.checkout_root() == ROOT
    assert network.nets_dir({}) == ROOT / "sumo_nets"
    assert not (Path(coopsumo.__file__).parent / "sumo_nets").exists()  # nothing inside the package


def test_the_environment_variable_comes_first(tmp_path: Path) -> None:
    assert network.nets_dir({network.NETS_ENV: str(tmp_path)}) == tmp_path


@pytest.mark.parametrize("kind", ["file", "empty", "blank", "comma", "unwritable"])
def test_a_bad_networks_folder_is_one_line_and_exit_2_by_flag_and_by_environment(
    kind: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """unwritable: /proc, where no file can be made even by root (for whom os.access says yes); issue 82 (wp16): its
    line was 'No such file or directory: /proc/highway_...nod.xml', naming neither the variable nor the cause."""
    (tmp_path / "afile").write_text("x")
    value = {"file": str(tmp_path / "afile"), "empty": "", "blank": " ", "comma": str(tmp_path / "a,b"),
             "unwritable": "/proc"}[kind]  # fmt: skip
    out = tmp_path / "run"
    monkeypatch.delenv(network.NETS_ENV, raising=False)
    try:
        code = cli.main(["--nets-dir", value, "simulate", "--steps", "5", "--out", str(out)])
    except SystemExit as stop:
        code = stop.code
    flag = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    monkeypatch.setenv(network.NETS_ENV, value)
    code_env = cli.main(["simulate", "--steps", "5", "--out", str(out)])
    env = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == code_env == 2
    assert len(flag) == 1 and "--nets-dir" in flag[0], flag
    assert len(env) == 1 and "$COOPSUMO_NETS_DIR" in env[0], env
    assert flag[0].split("--nets-dir", 1)[1] == env[0].split("$COOPSUMO_NETS_DIR", 1)[1]  # the same problem
    assert kind != "unwritable" or "cannot be written" in env[0], env
    assert not out.exists()


def test_an_installed_package_builds_into_the_per_user_cache(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setattr(network, "SOURCE_ROOT", tmp_path)  # site-packages' parent: no pyproject.toml of coopsumo
    assert network.checkout_root() is None
    assert network.nets_dir({"XDG_CACHE_HOME": str(tmp_path / "c")}) == tmp_path / "c" / "coopsumo" / "sumo_nets"
    assert network.nets_dir({}) == Path.home() / ".cache" / "coopsumo" / "sumo_nets"
    (tmp_path / "pyproject.toml").write_text('[project]\nname = "other"\n')
    assert network.checkout_root() is None  # another project's checkout is not ours


@pytest.mark.parametrize("error", [OSError(28, "No space left on device"),
                                   RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 17280")])
def test_bench_with_a_full_temporary_folder_is_one_line(error: Exception, monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str]) -> None:  # fmt: skip
    """Issue 82: `bench` with a 64 KB TMPDIR ended in two tracebacks (torch's writer failing, a full disk); its
    writes fail so here (measured on a 64 KB and a 4 KB tmpfs: these two errors), and the command says so in one
    line, exit code 1."""
    from coopsumo.bench import figures as bench

    def full(*_args: object) -> None:
        raise error

    monkeypatch.setattr(bench, "learner_lines", full)
    assert cli.main(["bench", "--quick", "--learner"]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("bench: error: ") and "Traceback" not in err, err


@pytest.mark.parametrize("kind", ["store", "in the store", "study", "training", "run"])
def test_a_networks_folder_in_a_folder_coopsumo_owns_is_refused_by_flag_and_by_environment(
    kind: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 82, probe 4, F18: a networks folder that was a model store (every study then refused the store, "holds
    highway_4lanes_...edg.xml"), a study's, a training's or a simulate run's folder was written into. Refused as an
    --out there is (owners.owned_problem): one line naming the flag or the variable, exit 2, nothing written."""
    from coopsumo.run_dirs import mark_run_dir

    store = tmp_path / "store"
    (store / "default_a0_seed100_0123456789ab").mkdir(parents=True)
    for name, marked in (("study", "scenario2"), ("training", "train"), ("run", "simulate")):
        (tmp_path / name).mkdir()
        mark_run_dir(tmp_path / name, marked, finished=marked == "simulate")
    value = str({"store": store, "in the store": store / "nets", "study": tmp_path / "study" / "nets",
                 "training": tmp_path / "training", "run": tmp_path / "run" / "nets"}[kind])  # fmt: skip
    out = tmp_path / "out"
    before = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*"))
    monkeypatch.setenv(network.NETS_ENV, "")  # restored at teardown: cli.main sets it from --nets-dir
    try:
        code = cli.main(["--nets-dir", value, "simulate", "--steps", "5", "--quiet", "--out", str(out)])
    except SystemExit as stop:
        code = stop.code
    flag = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    monkeypatch.setenv(network.NETS_ENV, value)
    code_env = cli.main(["simulate", "--steps", "5", "--quiet", "--out", str(out)])
    env = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == code_env == 2
    assert len(flag) == 1 and f"--nets-dir {value!r}" in flag[0], flag
    assert len(env) == 1 and f"$COOPSUMO_NETS_DIR {value!r}" in env[0], env
    assert "pick a networks folder elsewhere" in env[0], env
    assert sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")) == before
